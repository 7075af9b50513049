"""The simulated sensor's register file: the sensor end of the SPI bus.

``SensorModel`` holds the registers a register map (``config/sensors/<sensor>.toml``) declares
and behaves as silicon does, not as the host would like it to:

- writes to read-only registers are ignored (and raise the map's ``spi_error_flag``);
  reads of write-only registers and of unknown addresses return 0; writes to unknown
  addresses are ignored;
- write-1-to-clear: each 1 written clears that flag bit;
- the map's soft-reset write returns every register to its reset value;
- group hold: while a group's hold bit is set, writes to its registers are latched and
  applied together when the bit is cleared; reads return the value in force meanwhile;
- self-clearing (pulse) bits act and read back 0; a register that ``mirrors`` others writes
  them too and reads back the first of them;
- volatile status fields change by themselves (``note_frame`` advances the frame counter).

``writes`` and ``reads`` count the SPI accesses that reached the sensor, per address, so a
test can prove that a command retried on the link was applied once.

The window, exposure, line period and gain the registers hold are what the simulated camera
uses to make frames and what ``timing()`` reports (camd.sensor.timing_view, camd.timing).
Imports only camd's pure layers.
"""

from __future__ import annotations

import contextlib
import copy
import random
from collections import Counter
from typing import Literal

from camd.sensor.regmap import FieldSpec, GroupSpec, RegisterMap, RegisterSpec
from camd.sensor.timing_view import SensorTiming, line_period_s, sensor_timing


class SensorModel:
    """The register file of one simulated sensor described by ``regmap``.

    ``seed`` seeds the sensor's random processes (``rng``), e.g. pixel noise when it makes
    frames; the register file itself is deterministic.
    """

    def __init__(self, regmap: RegisterMap, *, seed: int = 0) -> None:
        self.regmap = regmap
        self.seed = seed
        self.rng = random.Random(seed)
        self.writes: Counter[int] = Counter()
        self.reads: Counter[int] = Counter()
        self._values: dict[int, int] = {}
        self._latched: dict[int, int] = {}  # address -> value written while its group was held
        self.version = 0  # counts register changes (the imaging path notices them)
        # timing() of the registers at a version: every frame asks, and the registers that
        # set it change only when a command writes them.
        self._timing: tuple[int, SensorTiming] | None = None
        # note_frame's register and field (False: not looked up yet; None: no such role).
        self._frame_counter: tuple[RegisterSpec, FieldSpec] | Literal[False] | None = False
        self.power_on_reset()

    def snapshot(self) -> SensorModel:
        """A copy of the register file as it is now, for rendering a frame without holding
        up commands (counters and random state are shared, not copied)."""
        snap = copy.copy(self)
        snap._values = dict(self._values)
        snap._latched = dict(self._latched)
        return snap

    # -- the SPI bus ------------------------------------------------------------------------------

    def spi_read(self, address: int) -> int:
        """A register read as the bus sees it: 0 for write-only and unknown addresses."""
        self.reads[address] += 1
        if not self.regmap.has_register(address):
            return 0
        reg = self.regmap.register(address)
        if not reg.readable:
            return 0
        return self._effective(reg)

    def spi_write(self, address: int, value: int) -> None:
        """A register write as the bus delivers it; the register's access rules apply."""
        self.writes[address] += 1
        if not self.regmap.has_register(address):
            return
        reg = self.regmap.register(address)
        value &= reg.mask  # a frame's data slot may be wider than the register
        if reg.access == "ro":
            self._raise_role_flag("spi_error_flag")
            return
        if reg.access == "w1c":
            self._values[address] &= ~value
            return
        if self.regmap.is_soft_reset(reg, value):
            self._reset_all()
            if reg.readable:
                self._values[address] = value & reg.kept_mask
            return
        group = self.regmap.group_of(reg.name)
        if group is not None and self._held(group):
            self._latched[address] = value & reg.kept_mask
            return
        self._store(reg, value)
        self._release_unheld()

    # -- state ------------------------------------------------------------------------------------

    def power_on_reset(self) -> None:
        """Every register to its reset value, nothing latched (the access counters are kept)."""
        self._reset_all()

    def register_value(self, key: str | int) -> int:
        """A register's raw value by name or address ("0x10" too), without bus side effects.

        Write-only registers give the last value written; latched group writes are not yet
        in force and do not show.
        """
        if isinstance(key, str):
            with contextlib.suppress(ValueError):
                key = int(key.strip(), 0)
        return self._effective(self.regmap.register(key))

    def value(self, name: str) -> int | str:
        """``REG`` (raw), ``REG.field`` (enum label or raw) or ``GROUP`` (joined), in force now."""
        return self.regmap.value_of(name, self._effective)

    def note_frame(self, frames: int = 1) -> None:
        """Frames were read out: the frame counter (``frame_counter`` role) advances by
        ``frames``, wrapping."""
        counter = self._frame_counter_field()
        if counter is None:
            return
        reg, field_spec = counter
        count = (field_spec.extract(self._values[reg.address]) + frames) & field_spec.raw_max
        self._values[reg.address] = field_spec.insert(self._values[reg.address], count)

    def set_status(self, name: str, value: int) -> None:
        """The sensor itself sets a field (``REG.field``) of a read-only or volatile register."""
        reg, field_spec = self._field(name)
        if reg.access not in ("ro", "w1c") and not reg.volatile:
            raise ValueError(f"{name} is a setting, not status: write it over SPI")
        if not 0 <= value <= field_spec.raw_max:
            raise ValueError(f"{name}: {value} does not fit {field_spec.width} bits")
        self._values[reg.address] = field_spec.insert(self._values[reg.address], value)

    def raise_flag(self, name: str) -> None:
        """The sensor sets a write-1-to-clear flag (``REG.field``), e.g. an overexposure."""
        reg, field_spec = self._field(name)
        if reg.access != "w1c":
            raise ValueError(f"{name} is not a write-1-to-clear flag")
        self._values[reg.address] |= field_spec.mask

    # -- what the registers set -------------------------------------------------------------------

    def timing(self) -> SensorTiming:
        """Line period, exposure, frame time, TDI line period the registers set now."""
        cached = self._timing
        if cached is not None and cached[0] == self.version:
            return cached[1]
        timing = sensor_timing(self.regmap, self.value)
        self._timing = (self.version, timing)
        return timing

    @property
    def window_start_row(self) -> int:
        return self._count("window_start_row")

    @property
    def window_rows(self) -> int:
        return self._count("window_rows")

    @property
    def exposure_lines(self) -> int:
        return self._count("exposure_lines")

    @property
    def gain(self) -> int | str:
        return self._setting("gain")

    @property
    def offset(self) -> int | str:
        return self._setting("offset")

    @property
    def readout_mode(self) -> int | str:
        return self._setting("readout_mode")

    @property
    def test_pattern(self) -> int | str:
        return self._setting("test_pattern")

    @property
    def line_period_s(self) -> float:
        return line_period_s(self.regmap, self.value)

    # -- internals --------------------------------------------------------------------------------

    def _reset_all(self) -> None:
        self._values = {reg.address: reg.reset for reg in self.regmap.registers}
        self._latched.clear()
        self.version += 1

    def _effective(self, reg: RegisterSpec) -> int:
        if reg.mirrors:
            return self._values[self.regmap.register(reg.mirrors[0]).address]
        return self._values[reg.address]

    def _store(self, reg: RegisterSpec, value: int) -> None:
        # Pulse bits act at once and never stick.
        self.version += 1
        self._values[reg.address] = value & reg.kept_mask
        for name in reg.mirrors:
            target = self.regmap.register(name)
            self._values[target.address] = value & target.kept_mask

    def _held(self, group: GroupSpec) -> bool:
        hold = self.regmap.hold_of(group)
        if hold is None:
            return False
        reg, field_spec = hold
        return field_spec.extract(self._values[reg.address]) != 0

    def _release_unheld(self) -> None:
        """Apply the latched writes of every group whose hold bit is now clear, together."""
        if not self._latched:
            return
        for group in self.regmap.groups:
            if self._held(group):
                continue
            for reg in self.regmap.group_registers(group):
                if reg.address in self._latched:
                    self._values[reg.address] = self._latched.pop(reg.address)
                    self.version += 1

    def _raise_role_flag(self, role: str) -> None:
        name = self.regmap.role(role)
        if name is not None:
            self.raise_flag(name)

    def _field(self, name: str) -> tuple[RegisterSpec, FieldSpec]:
        target, field_spec = self.regmap.resolve(name)
        if not isinstance(target, RegisterSpec):
            raise ValueError(f"{name} is a group, not a register field")
        return target, field_spec if field_spec is not None else target.all_fields()[0]

    def _frame_counter_field(self) -> tuple[RegisterSpec, FieldSpec] | None:
        """The ``frame_counter`` role's register and field, found once (a stream advances it
        for every frame; the map does not change)."""
        if self._frame_counter is False:
            name = self.regmap.role("frame_counter")
            self._frame_counter = None if name is None else self._field(name)
        return self._frame_counter

    def _count(self, role: str) -> int:
        count = self.regmap.role_count(role, self.value)
        if count is None:
            raise LookupError(f"sensor {self.regmap.sensor}'s register map has no {role} role")
        return count

    def _setting(self, role: str) -> int | str:
        name = self.regmap.role(role)
        if name is None:
            raise LookupError(f"sensor {self.regmap.sensor}'s register map has no {role} role")
        return self.value(name)
