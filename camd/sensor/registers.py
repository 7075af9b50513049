"""Typed, validated access to a sensor's registers through a ``RegisterBridge``.

``SensorRegisters`` speaks names (``WIN_START``, ``GAIN.analog``, groups such as ``EXPOSURE``)
and addresses (``16``, ``"0x10"``), and keeps the device in a known state:

- Everything is validated before anything is written: widths, every field's range or enum,
  access (RO refused), the window against the pixel array. A refused request raises
  ``RegisterValueError`` / ``RegisterAccessError`` naming the register, the value and the
  valid range, and sends no write.
- Field writes are read-modify-write, from a fresh read (or, for write-only registers, from
  the host's shadow copy). Write-1-to-clear fields are written alone: a read-modify-write
  would clear every flag that happened to be set.
- One call, one ``write_burst``. A group value (or any write to a group's registers) goes out as
  hold = 1, the parts most significant first, hold = 0, so the sensor applies it atomically.
- RW non-volatile registers are read back afterwards; a mismatch raises ``VerifyError``.
  Volatile, WO and W1C registers are not verified (they cannot or need not read back);
  self-clearing (pulse) bits are left out of the comparison.

The shadow copy holds what the host believes the registers hold: reset values at first (or what
``sync()`` reads), updated by every write. ``stage()`` changes only the shadow and marks registers
dirty; ``flush()`` sends every dirty register in one burst. Reads do not change the shadow; write-
only registers are reported from it (``RegisterReading.from_shadow``).

Diffs: ``diff("reset")`` compares every non-volatile register (RO ones too, so a wrong chip ID
shows) except W1C flags with its reset value; ``diff(path)`` and ``diff(mapping)`` compare just
the names given. Write-only registers are compared through the shadow copy.

Thread-safety is the caller's job: one ``SensorRegisters`` per bridge, one call at a time.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from camd.sensor.bridge import BridgeError, RegisterBridge
from camd.sensor.config_file import ConfigFileError, format_configuration, parse_configuration
from camd.sensor.regmap import (
    FieldSpec,
    GroupSpec,
    RegisterAccessError,
    RegisterMap,
    RegisterSpec,
    RegisterValueError,
)
from camd.sensor.timing_view import SensorTiming, sensor_timing

Value = int | str


@dataclass(frozen=True, slots=True)
class RegisterReading:
    """A register (or field, or group) value with its decoded fields.

    ``from_shadow`` is True when the value is the host's last written value of a write-only
    register (the sensor cannot return it), not something read from the device.
    """

    name: str
    address: int
    value: int
    fields: dict[str, int | str]
    from_shadow: bool = False

    def as_dict(self) -> dict[str, Any]:
        """``{"name", "address", "value", "fields"}``: the `camctl reg read --json` contract."""
        return {
            "name": self.name,
            "address": self.address,
            "value": self.value,
            "fields": dict(self.fields),
        }


@dataclass(frozen=True, slots=True)
class RegisterDiff:
    """A register (or field or group) whose actual value differs from the expected one."""

    name: str
    address: int
    expected: int
    actual: int

    def as_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "address": self.address,
            "expected": self.expected,
            "actual": self.actual,
        }


class VerifyError(BridgeError):
    """Registers read back differently from what was written."""

    def __init__(self, mismatches: Sequence[RegisterDiff]) -> None:
        self.mismatches = list(mismatches)
        parts = "; ".join(
            f"{d.name} (0x{d.address:02X}) written 0x{d.expected:04X}, read back 0x{d.actual:04X}"
            for d in self.mismatches
        )
        super().__init__(
            f"verify failed: {parts}. The sensor did not keep the value; check the SPI mode, "
            "clock and wiring, then write again"
        )


@dataclass(frozen=True, slots=True)
class _Target:
    """What a key names: a register, one of its fields, or a group."""

    name: str
    reg: RegisterSpec | None = None
    field: FieldSpec | None = None
    group: GroupSpec | None = None


@dataclass
class _Plan:
    """Validated new register values of one write (or stage, or flush)."""

    values: dict[str, int]
    named: list[str]
    holds: dict[str, list[GroupSpec]] = field(default_factory=dict)


def _coerce(value: object) -> object:
    """CLI values arrive as text: numbers become ints ("0x2F5", "757"), labels stay text."""
    if isinstance(value, str):
        text = value.strip()
        try:
            return int(text, 0)
        except ValueError:
            return text
    return value


def _hex(reg: RegisterSpec, value: int) -> str:
    return f"0x{value:0{(reg.width + 3) // 4}X}"


class SensorRegisters:
    """Register access for one sensor (``regmap``) through ``bridge``; see the module doc."""

    def __init__(self, regmap: RegisterMap, bridge: RegisterBridge) -> None:
        self.regmap = regmap
        self.bridge = bridge
        self._shadow: dict[str, int] = {reg.name: reg.reset for reg in regmap.registers}
        self._dirty: set[str] = set()

    # -- shadow copy ------------------------------------------------------------------------------

    @property
    def dirty(self) -> tuple[str, ...]:
        """Registers staged but not yet flushed, in address order."""
        return tuple(r.name for r in self.regmap.by_address() if r.name in self._dirty)

    def shadow_value(self, key: str | int) -> int:
        """The shadow copy of one register (by name or address)."""
        return self._shadow[self._register(key).name]

    def sync(self) -> list[RegisterReading]:
        """Read every readable register into the shadow copy; clears the dirty marks."""
        readings = []
        for reg in self.regmap.by_address():
            if reg.readable:
                self._shadow[reg.name] = self.bridge.read(reg.address)
            readings.append(self._reading(reg, self._shadow[reg.name]))
        self._dirty.clear()
        return readings

    def stage(self, assignments: Mapping[str, Value]) -> list[RegisterReading]:
        """Validate and apply ``assignments`` to the shadow copy only; mark them dirty.

        Nothing is sent until ``flush()``. Actions (soft reset, self-clearing bits, clearing
        W1C flags) cannot be staged: they would be lost in the shadow; use ``write``.
        """
        plan = self._plan(assignments, self._shadow_of, staging=True)
        for name, value in plan.values.items():
            self._apply(self.regmap.register(name), value)
            self._dirty.add(name)
        return [self._reading(self.regmap.register(n), self._shadow[n]) for n in plan.named]

    def flush(self, *, verify: bool = True) -> list[RegisterReading]:
        """Send every dirty register in one burst (group hold around dirty groups), verify."""
        if not self._dirty:
            return []
        names = list(self.dirty)
        for group in self.regmap.groups:
            if any(member in self._dirty for member in group.registers):
                names += [m for m in group.registers if m not in names]
        values = {name: self._shadow[name] for name in names}
        plan = _Plan(values, names, self._holds(values))
        burst = self._burst(plan, self._shadow_of)
        self.bridge.write_burst([(reg.address, value) for reg, value in burst])
        written = self._after_burst(burst)
        read_back = self._verify(written) if verify else {}
        return self._readings(plan.named, read_back)

    # -- reads ------------------------------------------------------------------------------------

    def read(self, key: str | int) -> RegisterReading:
        """Read a register, a field (``REG.field``) or a group (``EXPOSURE``) from the device.

        A write-only register (or a field or group of one) cannot be read from the sensor:
        its reading is the host's copy of the last value written (``from_shadow``), as in
        ``dump()``, and nothing is sent (docs/cli.md, camctl reg read). Raises
        RegisterAccessError for unknown names or addresses.
        """
        target = self._target(key)
        if target.group is not None:
            regs = self.regmap.group_registers(target.group)
            values = {reg.name: self._read_or_shadow(reg) for reg in regs}
            joined = self.regmap.join_group(target.group, values)
            shadowed = not all(reg.readable for reg in regs)
            return RegisterReading(
                target.name, regs[0].address, joined, dict(values), from_shadow=shadowed
            )
        reg = target.reg
        assert reg is not None
        raw = self._read_or_shadow(reg)
        if target.field is None:
            return self._reading(reg, raw)
        part = target.field.extract(raw)
        label = target.field.label(part)
        return RegisterReading(
            target.name,
            reg.address,
            part,
            {target.field.name: label if label is not None else part},
            from_shadow=not reg.readable,
        )

    def _read_or_shadow(self, reg: RegisterSpec) -> int:
        """The sensor's value, or for a write-only register the host's last written one."""
        return self.bridge.read(reg.address) if reg.readable else self._shadow[reg.name]

    def read_value(self, name: str) -> Value:
        """The device's value of ``REG`` (raw), ``REG.field`` (enum label or raw) or ``GROUP``."""
        target = self._target(name)
        return self.regmap.value_of(target.name, self._read_device)

    def dump(self) -> list[RegisterReading]:
        """Every register in address order; write-only ones from the shadow (``from_shadow``)."""
        readings = []
        for reg in self.regmap.by_address():
            if reg.readable:
                readings.append(self._reading(reg, self.bridge.read(reg.address)))
            else:
                readings.append(self._reading(reg, self._shadow[reg.name]))
        return readings

    def timing(self) -> SensorTiming:
        """The timing the device's registers set now (camd.sensor.timing_view)."""
        raw = self._cached_reader()

        return sensor_timing(self.regmap, lambda name: self.regmap.value_of(name, raw))

    # -- writes -----------------------------------------------------------------------------------

    def write(
        self, assignments: Mapping[str, Value], *, verify: bool = True
    ) -> list[RegisterReading]:
        """Validate every assignment, write them all in one burst, read back and verify.

        Keys are ``REG``, ``REG.field``, group names or addresses; values raw integers (or
        numeric text such as ``"0x2F5"``) or enum labels for enum fields. On any validation
        error nothing is written. Returns the registers the assignments named, as read back
        (or as written, for registers that are not verified).
        """
        current = self._cached_reader()

        plan = self._plan(assignments, current, staging=False)
        burst = self._burst(plan, current)
        self.bridge.write_burst([(reg.address, value) for reg, value in burst])
        written = self._after_burst(burst)
        read_back = self._verify(written) if verify else {}
        return self._readings(plan.named, read_back)

    def raw_values(self) -> dict[str, int]:
        """Every register's raw value now: read from the device, write-only ones from the
        shadow copy. A snapshot to plan against (``preview``) and to restore from."""
        raw = self._cached_reader()
        return {reg.name: raw(reg) for reg in self.regmap.by_address()}

    def preview(
        self, assignments: Mapping[str, Value], current: Mapping[str, int]
    ) -> tuple[dict[str, int], SensorTiming]:
        """What ``write(assignments)`` would do over the raw values ``current`` (a
        ``raw_values()`` snapshot), without sending anything: the registers' new raw values and
        the timing they set. Raises as ``write`` does for anything it would refuse."""

        def raw(reg: RegisterSpec) -> int:
            return current[reg.name]

        plan = self._plan(assignments, raw, staging=False)
        after = {**current, **plan.values}
        timing = sensor_timing(
            self.regmap, lambda name: self.regmap.value_of(name, lambda reg: after[reg.name])
        )
        return dict(plan.values), timing

    # -- configurations ---------------------------------------------------------------------------

    def configuration(self) -> dict[str, int]:
        """The configurable registers' values now (device; shadow for write-only ones).

        Configurable: RW and WO non-volatile registers, except the soft-reset register (an
        action, not a setting).
        """
        reset_reg = self.regmap.soft_reset_register()
        values: dict[str, int] = {}
        for reg in self.regmap.by_address():
            if not reg.configurable or reg is reset_reg:
                continue
            values[reg.name] = self._read_device(reg) if reg.readable else self._shadow[reg.name]
        return values

    def save(self, path: str | Path) -> dict[str, int]:
        """Write the configuration (``configuration()``) to a TOML file; returns what was saved."""
        values = self.configuration()
        note = (
            f"{self.regmap.description or self.regmap.sensor}. Write-only registers hold the "
            "host's last written value."
        )
        text = format_configuration(self.regmap.sensor, values, note=note)
        Path(path).write_text(text, encoding="utf-8")
        return values

    def load(self, path: str | Path, *, verify: bool = True) -> list[RegisterReading]:
        """Validate a saved configuration file whole, then write it in one burst and verify.

        A file for another sensor, unknown or non-configurable names and invalid values are
        refused before anything is written.
        """
        sensor, values = self._read_configuration_file(path)
        return self.load_configuration(sensor, values, source=str(path), verify=verify)

    def load_configuration(
        self, sensor: str, values: Mapping[str, int], *, source: str, verify: bool = True
    ) -> list[RegisterReading]:
        """Write a configuration (``sensor`` and register values) checked whole first.

        ``source`` (a file name, "request") prefixes the error messages.
        """
        self.check_configuration(sensor, values, source=source)
        try:
            return self.write(dict(values), verify=verify)
        except RegisterAccessError as exc:
            raise RegisterAccessError(f"{source}: {exc}; nothing was written") from None
        except RegisterValueError as exc:
            raise RegisterValueError(f"{source}: {exc}; nothing was written") from None

    def diff(self, against: str | Path | Mapping[str, Value]) -> list[RegisterDiff]:
        """Registers (or the fields/groups named) whose device value differs from ``against``.

        ``against``: ``"reset"`` (reset values), the path of a saved configuration, or a
        mapping name -> expected value. Sorted by address.
        """
        expected: list[tuple[_Target, int]]
        if isinstance(against, str) and against.strip().lower() == "reset":
            expected = [
                (_Target(reg.name, reg), reg.reset)
                for reg in self.regmap.by_address()
                if not reg.volatile and reg.access != "w1c"
            ]
        elif isinstance(against, str | Path):
            sensor, values = self._read_configuration_file(against)
            self.check_configuration(sensor, values, source=str(against))
            expected = [(self._target(name), value) for name, value in values.items()]
        else:
            expected = [self._expectation(key, value) for key, value in against.items()]
        raw = self._cached_reader()

        diffs = []
        for target, want in expected:
            got = self._raw_value(target, raw)
            if got != want:
                diffs.append(RegisterDiff(target.name, self._address(target), want, got))
        return sorted(diffs, key=lambda d: (d.address, d.name))

    # -- resolution -------------------------------------------------------------------------------

    def _cached_reader(self) -> Callable[[RegisterSpec], int]:
        """Register values for one operation: each readable register read from the device at
        most once, write-only ones from the shadow copy."""
        cache: dict[str, int] = {}

        def raw(reg: RegisterSpec) -> int:
            if not reg.readable:
                return self._shadow[reg.name]
            if reg.name not in cache:
                cache[reg.name] = self.bridge.read(reg.address)
            return cache[reg.name]

        return raw

    def _register(self, key: str | int) -> RegisterSpec:
        target = self._target(key)
        if target.reg is None or target.field is not None:
            raise RegisterAccessError(f"{target.name} is not a register")
        return target.reg

    def _target(self, key: str | int) -> _Target:
        if isinstance(key, bool) or not isinstance(key, int | str):
            raise RegisterAccessError(f"{key!r} is not a register name or address")
        if isinstance(key, str):
            with contextlib.suppress(ValueError):
                key = int(key.strip(), 0)
        if isinstance(key, int):
            reg = self.regmap.register(key)
            return _Target(reg.name, reg)
        target, field_spec = self.regmap.resolve(key)
        if isinstance(target, GroupSpec):
            return _Target(target.name, group=target)
        if field_spec is None:
            return _Target(target.name, target)
        return _Target(f"{target.name}.{field_spec.name}", target, field_spec)

    def _address(self, target: _Target) -> int:
        if target.group is not None:
            return self.regmap.group_registers(target.group)[0].address
        assert target.reg is not None
        return target.reg.address

    def _raw_value(self, target: _Target, raw: Callable[[RegisterSpec], int]) -> int:
        if target.group is not None:
            regs = self.regmap.group_registers(target.group)
            return self.regmap.join_group(target.group, {reg.name: raw(reg) for reg in regs})
        assert target.reg is not None
        value = raw(target.reg)
        return target.field.extract(value) if target.field is not None else value

    def _expectation(self, key: str, value: Value) -> tuple[_Target, int]:
        target = self._target(key)
        coerced = _coerce(value)
        if isinstance(coerced, str):
            if target.field is None:
                raise RegisterValueError(f"{target.name}: {coerced!r} is not a number")
            return target, target.field.to_raw(coerced, target.name)
        if isinstance(coerced, bool) or not isinstance(coerced, int):
            raise RegisterValueError(f"{target.name}: expected an integer, got {value!r}")
        return target, coerced

    # -- device and shadow access -------------------------------------------------------------------

    def _read_device(self, reg: RegisterSpec) -> int:
        if not reg.readable:
            raise RegisterAccessError(
                f"{reg.name} (0x{reg.address:02X}) is write-only: the sensor cannot return its "
                f"value. The host's last written value is {_hex(reg, self._shadow[reg.name])} "
                "(shadow copy; `camctl reg dump` lists it)"
            )
        return self.bridge.read(reg.address)

    def _shadow_of(self, reg: RegisterSpec) -> int:
        return self._shadow[reg.name]

    def _reading(self, reg: RegisterSpec, value: int) -> RegisterReading:
        return RegisterReading(
            reg.name, reg.address, value, reg.decode(value), from_shadow=not reg.readable
        )

    def _readings(
        self, names: Iterable[str], read_back: Mapping[str, int]
    ) -> list[RegisterReading]:
        out = []
        for name in dict.fromkeys(names):
            reg = self.regmap.register(name)
            out.append(self._reading(reg, read_back.get(name, self._shadow[name])))
        return out

    def _apply(self, reg: RegisterSpec, value: int) -> None:
        """What one write does to the registers, as the sensor would do it (shadow side)."""
        if reg.access == "w1c":
            return  # flags belong to the sensor; the shadow does not track them
        if self.regmap.is_soft_reset(reg, value):
            for other in self.regmap.registers:
                self._shadow[other.name] = other.reset
            if reg.readable:
                self._shadow[reg.name] = value & reg.kept_mask
            return
        self._shadow[reg.name] = value & reg.kept_mask
        for name in reg.mirrors:
            target = self.regmap.register(name)
            self._shadow[name] = value & target.kept_mask

    def _after_burst(self, burst: Sequence[tuple[RegisterSpec, int]]) -> list[RegisterSpec]:
        """Update the shadow for a sent burst; the registers to verify, in burst order."""
        written: dict[str, RegisterSpec] = {}
        for reg, value in burst:
            if self.regmap.is_soft_reset(reg, value):
                self._dirty.clear()  # the sensor is back at reset: staged values are gone
            self._apply(reg, value)
            written[reg.name] = reg
            for name in reg.mirrors:
                written[name] = self.regmap.register(name)
        self._dirty.difference_update(written)
        return list(written.values())

    def _verify(self, regs: Iterable[RegisterSpec]) -> dict[str, int]:
        read_back: dict[str, int] = {}
        mismatches = []
        for reg in regs:
            if not reg.verify_after_write:
                continue
            got = self.bridge.read(reg.address)
            read_back[reg.name] = got
            want = self._shadow[reg.name]
            if got & reg.kept_mask != want & reg.kept_mask:
                mismatches.append(RegisterDiff(reg.name, reg.address, want, got))
        if mismatches:
            raise VerifyError(mismatches)
        return read_back

    # -- planning ---------------------------------------------------------------------------------

    def _check_writable(self, reg: RegisterSpec, name: str, *, staging: bool) -> None:
        if not reg.writable:
            raise RegisterAccessError(
                f"{name} (0x{reg.address:02X}) is read-only; it cannot be written"
            )
        if staging and reg.access == "w1c":
            raise RegisterAccessError(
                f"{name}: clearing flags is an action, it cannot be staged; use write"
            )

    def _plan(
        self,
        assignments: Mapping[str, Value],
        current: Callable[[RegisterSpec], int],
        *,
        staging: bool,
    ) -> _Plan:
        if not assignments:
            raise RegisterValueError("nothing to write: give one or more NAME=VALUE")
        parsed: list[tuple[_Target, Any]] = []
        for key, given in assignments.items():  # every pure check before any bus access
            target = self._target(key)
            value = _coerce(given)
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
                        f"{_hex(reg, reg.reset)}) or set a field by name, e.g. "
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
        plan = _Plan(values, named, self._holds(values))
        self._check_window(plan, current)
        return plan

    def _check_stageable(self, values: Mapping[str, int]) -> None:
        for name, value in values.items():
            reg = self.regmap.register(name)
            if self.regmap.is_soft_reset(reg, value) or value & reg.pulse_mask:
                raise RegisterAccessError(
                    f"{name} = {_hex(reg, value)} is an action (reset or self-clearing bit), "
                    "which cannot be staged; use write"
                )

    def _holds(self, values: Mapping[str, int]) -> dict[str, list[GroupSpec]]:
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

    def _check_window(self, plan: _Plan, current: Callable[[RegisterSpec], int]) -> None:
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

    def _burst(
        self, plan: _Plan, current: Callable[[RegisterSpec], int]
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

    @staticmethod
    def _read_configuration_file(path: str | Path) -> tuple[str, dict[str, int]]:
        try:
            text = Path(path).read_text(encoding="utf-8")
        except OSError as exc:
            raise RegisterValueError(
                f"{path}: cannot read the configuration: {exc.strerror or exc}"
            ) from None
        try:
            return parse_configuration(text, source=str(path))
        except ConfigFileError as exc:
            raise RegisterValueError(str(exc)) from None
