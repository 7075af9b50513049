"""What a register request names and what writing it takes, worked out before anything is
sent: the names and addresses resolved against the register map, every value checked (width,
range or enum, access, the window against the pixel array, group hold), the new register values
and the burst that writes them (plain registers, then each group inside its hold).

Pure: the registers' current values come in as a function (the device, the shadow copy or a
snapshot), and nothing here touches the bus. ``camd.sensor.registers.SensorRegisters`` plans
every write, stage and flush with a ``WritePlanner`` (the rules are in its module doc).
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

from camd.sensor.regmap import (
    FieldSpec,
    GroupSpec,
    RegisterAccessError,
    RegisterMap,
    RegisterSpec,
    RegisterValueError,
)

Value = int | str
"""A value as a request gives it: a raw integer, numeric text ("0x2F5") or an enum label."""


@dataclass(frozen=True, slots=True)
class Target:
    """What a key names: a register, one of its fields, or a group."""

    name: str
    reg: RegisterSpec | None = None
    field: FieldSpec | None = None
    group: GroupSpec | None = None


@dataclass
class WritePlan:
    """Validated new register values of one write (or stage, or flush)."""

    values: dict[str, int]
    named: list[str]
    holds: dict[str, list[GroupSpec]] = field(default_factory=dict)


def coerce_value(value: object) -> object:
    """CLI values arrive as text: numbers become ints ("0x2F5", "757"), labels stay text."""
    if isinstance(value, str):
        text = value.strip()
        try:
            return int(text, 0)
        except ValueError:
            return text
    return value


def hex_value(reg: RegisterSpec, value: int) -> str:
    """``value`` in hex, as many digits as the register is wide."""
    return f"0x{value:0{(reg.width + 3) // 4}X}"


class WritePlanner:
    """Resolves the names of one sensor's register map (``regmap``) and plans writes to them."""

    def __init__(self, regmap: RegisterMap) -> None:
        self.regmap = regmap

    def register(self, key: str | int) -> RegisterSpec:
        """The register ``key`` names (RegisterAccessError for a field or a group)."""
        target = self.target(key)
        if target.reg is None or target.field is not None:
            raise RegisterAccessError(f"{target.name} is not a register")
        return target.reg

    def target(self, key: str | int) -> Target:
        """What ``key`` names: a name (``REG``, ``REG.field``, ``GROUP``, any case), an address
        or an address as text (``"0x10"``); RegisterAccessError if it names nothing."""
        if isinstance(key, bool) or not isinstance(key, int | str):
            raise RegisterAccessError(f"{key!r} is not a register name or address")
        if isinstance(key, str):
            with contextlib.suppress(ValueError):
                key = int(key.strip(), 0)
        if isinstance(key, int):
            reg = self.regmap.register(key)
            return Target(reg.name, reg)
        target, field_spec = self.regmap.resolve(key)
        if isinstance(target, GroupSpec):
            return Target(target.name, group=target)
        if field_spec is None:
            return Target(target.name, target)
        return Target(f"{target.name}.{field_spec.name}", target, field_spec)

    def address(self, target: Target) -> int:
        """The address of a target (a group's: its first register's)."""
        if target.group is not None:
            return self.regmap.group_registers(target.group)[0].address
        assert target.reg is not None
        return target.reg.address

    def raw_value(self, target: Target, raw: Callable[[RegisterSpec], int]) -> int:
        """A target's raw value (a field's bits, a group joined) from the registers' ``raw``."""
        if target.group is not None:
            regs = self.regmap.group_registers(target.group)
            return self.regmap.join_group(target.group, {reg.name: raw(reg) for reg in regs})
        assert target.reg is not None
        value = raw(target.reg)
        return target.field.extract(value) if target.field is not None else value

    def expectation(self, key: str, value: Value) -> tuple[Target, int]:
        """(what ``key`` names, the raw value ``value`` means for it), for a diff."""
        target = self.target(key)
        coerced = coerce_value(value)
        if isinstance(coerced, str):
            if target.field is None:
                raise RegisterValueError(f"{target.name}: {coerced!r} is not a number")
            return target, target.field.to_raw(coerced, target.name)
        if isinstance(coerced, bool) or not isinstance(coerced, int):
            raise RegisterValueError(f"{target.name}: expected an integer, got {value!r}")
        return target, coerced

    def _check_writable(self, reg: RegisterSpec, name: str, *, staging: bool) -> None:
        if not reg.writable:
            raise RegisterAccessError(
                f"{name} (0x{reg.address:02X}) is read-only; it cannot be written"
            )
        if staging and reg.access == "w1c":
            raise RegisterAccessError(
                f"{name}: clearing flags is an action, it cannot be staged; use write"
            )

    def plan(
        self,
        assignments: Mapping[str, Value],
        current: Callable[[RegisterSpec], int],
        *,
        staging: bool,
    ) -> WritePlan:
        """Check ``assignments`` whole and work out the registers' new values over ``current``
        (read-modify-write of fields; a W1C field alone; a group split into its registers).
        ``staging``: refuse what cannot be staged (read-only, W1C, actions)."""
        if not assignments:
            raise RegisterValueError("nothing to write: give one or more NAME=VALUE")
        parsed: list[tuple[Target, Any]] = []
        for key, given in assignments.items():  # every pure check before any bus access
            target = self.target(key)
            value = coerce_value(given)
            if target.group is not None:
                if isinstance(value, str):
                    raise RegisterValueError(
                        f"{target.name}: {value!r} is not a number; give an integer"
                    )
                parsed.append((target, self.regmap.split_group(target.group, value)))  # type: ignore[arg-type]
                continue
            reg = target.reg
            assert reg is not None
            self._check_writable(reg, target.name, staging=staging)
            if target.field is None:
                if isinstance(value, str):
                    raise RegisterValueError(
                        f"{reg.name}: {value!r} is not a number; give an integer (e.g. "
                        f"{hex_value(reg, reg.reset)}) or set a field by name, e.g. "
                        f"{reg.name}.{reg.all_fields()[0].name}=..."
                    )
                raw = reg.check_value(value)  # type: ignore[arg-type]
            else:
                raw = target.field.to_raw(value, target.name)  # type: ignore[arg-type]
            parsed.append((target, raw))
        values: dict[str, int] = {}
        named: list[str] = []
        for target, raw in parsed:
            if target.group is not None:
                for reg, part in raw:
                    values[reg.name] = part
                    named.append(reg.name)
                continue
            reg = target.reg
            assert reg is not None
            named.append(reg.name)
            if target.field is None:
                values[reg.name] = raw
            elif reg.access == "w1c":  # alone: RMW would write back every set flag, clearing it
                values[reg.name] = target.field.insert(values.get(reg.name, 0), raw)
            else:
                base = values[reg.name] if reg.name in values else current(reg)
                values[reg.name] = target.field.insert(base, raw)
        if staging:
            self._check_stageable(values)
        plan = WritePlan(values, named, self.holds(values))
        self._check_window(plan, current)
        return plan

    def _check_stageable(self, values: Mapping[str, int]) -> None:
        for name, value in values.items():
            reg = self.regmap.register(name)
            if self.regmap.is_soft_reset(reg, value) or value & reg.pulse_mask:
                raise RegisterAccessError(
                    f"{name} = {hex_value(reg, value)} is an action (reset or self-clearing bit), "
                    "which cannot be staged; use write"
                )

    def holds(self, values: Mapping[str, int]) -> dict[str, list[GroupSpec]]:
        """Hold register -> groups with registers in ``values`` (which must leave hold at 0)."""
        holds: dict[str, list[GroupSpec]] = {}
        for group in self.regmap.groups:
            hold = self.regmap.hold_of(group)
            if hold is None or not any(m in values for m in group.registers):
                continue
            hold_reg, hold_field = hold
            if hold_reg.name in values and hold_field.extract(values[hold_reg.name]):
                raise RegisterValueError(
                    f"{hold_reg.name}.{hold_field.name} = 1 together with {group.name}: the "
                    f"group write sets and clears the hold itself; leave {hold_reg.name}."
                    f"{hold_field.name} at 0 or write it separately"
                )
            holds.setdefault(hold_reg.name, []).append(group)
        return holds

    def _check_window(self, plan: WritePlan, current: Callable[[RegisterSpec], int]) -> None:
        involved: set[str] = set()
        for role in ("window_start_row", "window_rows", "window_start_column", "window_columns"):
            name = self.regmap.role(role)
            if name is None:
                continue
            target, _ = self.regmap.resolve(name)
            if isinstance(target, GroupSpec):
                involved.update(target.registers)
            else:
                involved.add(target.name)
        if not involved & plan.values.keys():
            return

        def after(reg: RegisterSpec) -> int:
            return plan.values[reg.name] if reg.name in plan.values else current(reg)

        self.regmap.check_window(lambda name: self.regmap.value_of(name, after))

    def burst(
        self, plan: WritePlan, current: Callable[[RegisterSpec], int]
    ) -> list[tuple[RegisterSpec, int]]:
        """The writes in order: plain registers, then each hold: set, group parts, clear."""
        held = {m for groups in plan.holds.values() for g in groups for m in g.registers}
        burst = [
            (self.regmap.register(name), value)
            for name, value in plan.values.items()
            if name not in held and name not in plan.holds
        ]
        for hold_name, groups in plan.holds.items():
            hold_reg = self.regmap.register(hold_name)
            clear = plan.values[hold_name] if hold_name in plan.values else current(hold_reg)
            hold_set = clear
            for group in groups:
                hold = self.regmap.hold_of(group)
                assert hold is not None
                clear = hold[1].insert(clear, 0)
                hold_set = hold[1].insert(hold_set, 1)
            burst.append((hold_reg, hold_set))
            for group in groups:
                for reg in self.regmap.group_registers(group):
                    if reg.name in plan.values:
                        burst.append((reg, plan.values[reg.name]))
            burst.append((hold_reg, clear))
        return burst

    def check_configuration(self, sensor: str, values: Mapping[str, int], *, source: str) -> None:
        """Refuse a configuration for another sensor or with non-configurable registers."""
        mine = self.regmap.sensor
        if sensor != mine:
            raise RegisterValueError(
                f"{source} is a configuration for sensor {sensor!r}, but this camera's sensor is "
                f"{mine!r}; load a configuration saved from a {mine} (`camctl reg save FILE`)"
            )
        for name in values:
            if not self.regmap.has_register(name):
                raise RegisterAccessError(
                    f"{source}: registers.{name}: {mine} has no register named {name!r}; "
                    "remove it (`camctl reg dump` lists the registers)"
                )
            reg = self.regmap.register(name)
            if not reg.configurable:
                kind = f"{'volatile ' if reg.volatile else ''}{reg.access.upper()}"
                raise RegisterAccessError(
                    f"{source}: registers.{name}: a {kind} register is not part of a "
                    "configuration (only RW and WO non-volatile registers are); remove it"
                )
