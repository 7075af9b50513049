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

What a request names and what writing it takes (the checks, the new values, the burst) is
worked out before anything is sent by ``camd.sensor.write_plan.WritePlanner``, which touches no
bus; ``SensorRegisters`` keeps the shadow copy and talks to the bridge.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from camd.sensor.bridge import BridgeError, RegisterBridge
from camd.sensor.config_file import ConfigFileError, format_configuration, parse_configuration
from camd.sensor.regmap import (
    RegisterAccessError,
    RegisterMap,
    RegisterSpec,
    RegisterValueError,
)
from camd.sensor.timing_view import SensorTiming, sensor_timing
from camd.sensor.write_plan import Target, Value, WritePlan, WritePlanner, hex_value


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


class SensorRegisters:
    """Register access for one sensor (``regmap``) through ``bridge``; see the module doc."""

    def __init__(self, regmap: RegisterMap, bridge: RegisterBridge) -> None:
        self.regmap = regmap
        self.bridge = bridge
        self._shadow: dict[str, int] = {reg.name: reg.reset for reg in regmap.registers}
        self._dirty: set[str] = set()
        self._planner = WritePlanner(regmap)

    # -- shadow copy ------------------------------------------------------------------------------

    @property
    def dirty(self) -> tuple[str, ...]:
        """Registers staged but not yet flushed, in address order."""
        return tuple(r.name for r in self.regmap.by_address() if r.name in self._dirty)

    def shadow_value(self, key: str | int) -> int:
        """The shadow copy of one register (by name or address)."""
        return self._shadow[self._planner.register(key).name]

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
        plan = self._planner.plan(assignments, self._shadow_of, staging=True)
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
        plan = WritePlan(values, names, self._planner.holds(values))
        burst = self._planner.burst(plan, self._shadow_of)
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
        target = self._planner.target(key)
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
        target = self._planner.target(name)
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

        plan = self._planner.plan(assignments, current, staging=False)
        burst = self._planner.burst(plan, current)
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

        plan = self._planner.plan(assignments, raw, staging=False)
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
        expected: list[tuple[Target, int]]
        if isinstance(against, str) and against.strip().lower() == "reset":
            expected = [
                (Target(reg.name, reg), reg.reset)
                for reg in self.regmap.by_address()
                if not reg.volatile and reg.access != "w1c"
            ]
        elif isinstance(against, str | Path):
            sensor, values = self._read_configuration_file(against)
            self.check_configuration(sensor, values, source=str(against))
            expected = [(self._planner.target(name), value) for name, value in values.items()]
        else:
            expected = [self._planner.expectation(key, value) for key, value in against.items()]
        raw = self._cached_reader()

        diffs = []
        for target, want in expected:
            got = self._planner.raw_value(target, raw)
            if got != want:
                diffs.append(RegisterDiff(target.name, self._planner.address(target), want, got))
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

    # -- device and shadow access -------------------------------------------------------------------

    def _read_device(self, reg: RegisterSpec) -> int:
        if not reg.readable:
            raise RegisterAccessError(
                f"{reg.name} (0x{reg.address:02X}) is write-only: the sensor cannot return its "
                f"value. The host's last written value is {hex_value(reg, self._shadow[reg.name])} "
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

    def check_configuration(self, sensor: str, values: Mapping[str, int], *, source: str) -> None:
        """Refuse a configuration for another sensor or with non-configurable registers."""
        self._planner.check_configuration(sensor, values, source=source)

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
