"""Sensor register maps as data: ``config/sensors/<sensor>.toml``, validated by pydantic.

A map declares the sensor's SPI frame layout, its registers (address, width, access, reset value,
named bit fields with enums, units, scales and valid ranges), multi-register groups that must
change atomically (group hold), and the roles that say which register holds the window, the
exposure, the gain and so on. The host (``camd.sensor``), the simulated sensor
(``firmware_models``) and the docs all load the same file through ``load_register_map``.

Pure: no I/O beyond reading the file. Raw register values are unsigned integers; a field's
physical value is ``raw * scale`` in its ``unit``; a counted quantity (rows, columns, lines) is
``raw + bias`` (the MT9M001's row size register holds rows - 1: bias 1).

A map that does not validate raises ``RegisterMapError`` naming the file, the line of the
offending key (the register's ``reset`` line, the field's inline table, the role's line; the
``[[registers]]`` header when nothing narrower applies) and the register, e.g.::

    config/sensors/hr400.toml:176: register GAIN: field 'digital' bits 8..0 overlap field 'analog' bits 9..8
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, Literal

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    PrivateAttr,
    StrictInt,
    model_validator,
)

from camd.datafile import DataFileError, DataFileKind, KeyedError
from camd.paths import config_dir

Access = Literal["ro", "rw", "wo", "w1c"]

# The FPGA bridge's REG_READ / REG_WRITE carry a u16 address and a u16 value.
MAX_ADDRESS_BITS = 16
MAX_DATA_BITS = 16

_NAME = r"^[A-Z][A-Z0-9_]*$"
_FIELD_NAME = r"^[a-z][a-z0-9_]*$"

ROLES = (
    "window_start_row",
    "window_rows",
    "window_start_column",
    "window_columns",
    "exposure_lines",
    "gain",
    "offset",
    "readout_mode",
    "test_pattern",
    "training_word",
    "lvds_lanes",
    "lvds_clock",
    "line_clocks",
    "row_blanking",
    "back_path",
    "frame_counter",
    "spi_error_flag",
)
"""Roles a map may assign to a value name (register, ``REGISTER.field`` or group)."""

ROLE_DOCS: dict[str, str] = {
    "window_start_row": "first row of the readout window (array row address)",
    "window_rows": "rows in the window, k (raw + bias)",
    "window_start_column": "first column of the readout window (array column address)",
    "window_columns": "columns read per row, n_pixels of docs/physics.md §2 eq 4 (raw + bias); "
    "the map's `columns` when absent",
    "exposure_lines": "exposure n in whole line periods (docs/physics.md §3)",
    "gain": "gain setting (reported by `camctl timing`)",
    "offset": "black-level offset (reported by `camctl timing`)",
    "readout_mode": "readout mode (reported by `camctl timing`)",
    "test_pattern": "output source: pixels, training word or a test image",
    "training_word": "word sent on every LVDS lane in training mode",
    "lvds_lanes": "bit per LVDS data lane, 1 = the lane sends data (a disabled lane cannot "
    "lock in training)",
    "lvds_clock": "LVDS clock lane on (1) or off (0): no lane can lock while it is off",
    "line_clocks": "sequencer clocks per line (sequencer model); `timing.clocks_per_line` "
    "when absent",
    "row_blanking": "row blanking t_rb in clocks of `timing.clock_hz` (row_blanking model)",
    "back_path": "idle time at the end of each TDI line period, in clocks of `timing.clock_hz` "
    "(docs/physics.md §2 eqs 6-9)",
    "frame_counter": "field the sensor advances by itself once per frame read out",
    "spi_error_flag": "write-1-to-clear flag the sensor sets when a write hits a read-only "
    "register",
}

COUNT_ROLES = frozenset(
    {
        "window_start_row",
        "window_rows",
        "window_start_column",
        "window_columns",
        "exposure_lines",
        "line_clocks",
        "row_blanking",
        "back_path",
        "frame_counter",
    }
)
"""Roles whose value is a number (never an enum label)."""

CLOCK_ROLES = ("row_blanking", "back_path")
"""Roles counted in clocks of ``timing.clock_hz``; a field in seconds must scale by 1/clock_hz."""


class RegisterMapError(DataFileError):
    """A register map file is invalid; the message starts with ``file:line:``."""


class RegisterAccessError(ValueError):
    """A request breaks a register's access rule (write to RO, read of WO, unknown name)."""


class RegisterValueError(ValueError):
    """A value does not fit the register or field it is meant for; nothing was written."""


class _Located(KeyedError):
    """A validation error that knows which entry and key of the file it belongs to.

    ``table``/``index`` name a ``[[registers]]`` / ``[[groups]]`` entry (or a plain table such
    as ``roles`` with ``index`` None); ``key`` the key inside it; ``field`` the index of an
    inline field table. Raised inside a RegisterSpec, the entry comes from pydantic's location.
    """

    def __init__(
        self,
        message: str,
        *,
        table: str | None = None,
        index: int | None = None,
        key: str | None = None,
        field: int | None = None,
    ) -> None:
        loc = tuple(part for part in (table, index, key) if part is not None)
        if field is not None:
            loc += ("fields", field)
        # A role's messages name the role themselves ("role gain: ...").
        super().__init__(loc, message, label="" if table == "roles" else None)


class SpiLayout(BaseModel):
    """How one register access is framed on the SPI bus (both the FPGA's master and a USB bridge).

    A frame is ``rw_bits`` of command (``read_code`` for a read, ``write_code`` for a write),
    then ``address_bits`` of address, then ``data_bits`` of data, most significant bit first,
    in one chip-select-low transaction. The total must be whole bytes. On a read the master
    sends zeros in the data slot and the sensor drives the value on MISO during it.
    """

    model_config = ConfigDict(extra="forbid", frozen=True, strict=True)

    mode: int = Field(ge=0, le=3, description="SPI mode: CPOL = mode >> 1, CPHA = mode & 1")
    rw_bits: int = Field(default=1, ge=1, le=8, description="bits of the command slot")
    read_code: int = Field(default=1, ge=0, description="command slot value of a read")
    write_code: int = Field(default=0, ge=0, description="command slot value of a write")
    address_bits: int = Field(ge=1, le=MAX_ADDRESS_BITS, description="bits of the address slot")
    data_bits: int = Field(ge=1, le=MAX_DATA_BITS, description="bits of the data slot")
    max_clock_hz: float = Field(gt=0, description="fastest SPI clock the sensor accepts")
    doc: str = Field(default="", description="notes on the bus (e.g. a bridge's framing)")

    @model_validator(mode="after")
    def _check(self) -> SpiLayout:
        limit = 1 << self.rw_bits
        if not (self.read_code < limit and self.write_code < limit):
            raise ValueError(f"read_code/write_code must fit rw_bits={self.rw_bits}")
        if self.read_code == self.write_code:
            raise ValueError("read_code and write_code must differ")
        if self.frame_bits % 8:
            raise ValueError(
                f"an SPI frame of rw_bits + address_bits + data_bits = {self.frame_bits} bits "
                "is not whole bytes"
            )
        return self

    @property
    def cpol(self) -> int:
        return self.mode >> 1

    @property
    def cpha(self) -> int:
        return self.mode & 1

    @property
    def frame_bits(self) -> int:
        return self.rw_bits + self.address_bits + self.data_bits

    @property
    def frame_bytes(self) -> int:
        return self.frame_bits // 8


class FieldSpec(BaseModel):
    """A named bit field of a register: bits ``[msb, lsb]`` inclusive."""

    model_config = ConfigDict(extra="forbid", frozen=True, strict=True)

    name: str = Field(pattern=_FIELD_NAME, description="lower-case field name")
    # A TOML array is a list: the pair is taken from one (strict=False), its items strictly.
    bits: tuple[StrictInt, StrictInt] = Field(strict=False, description="[msb, lsb], inclusive")
    doc: str = Field(default="", description="what the field does")
    unit: str = Field(default="", description="unit of the physical value raw * scale")
    scale: float = Field(default=1.0, gt=0, description="physical value per raw step")
    min: int | None = Field(default=None, ge=0, description="smallest valid raw value")
    max: int | None = Field(default=None, ge=0, description="largest valid raw value")
    enum: dict[str, int] | None = Field(
        default=None, description="named raw values; only these are valid"
    )
    bias: int = Field(
        default=0, description="a counted quantity is raw + bias (e.g. 1 for a 'rows - 1' field)"
    )
    pulse: bool = Field(
        default=False,
        description="self-clearing: writing 1 triggers an action and the bit reads back 0",
    )

    @model_validator(mode="after")
    def _check(self) -> FieldSpec:
        msb, lsb = self.bits
        if not 0 <= lsb <= msb:
            raise ValueError(f"field {self.name!r}: bits must be [msb, lsb] with msb >= lsb >= 0")
        top = self.raw_max
        for label, raw in (self.enum or {}).items():
            if not 0 <= raw <= top:
                raise ValueError(
                    f"field {self.name!r}: enum {label}={raw} does not fit {self.width} bits"
                )
        if self.enum is not None and len(set(self.enum.values())) != len(self.enum):
            raise ValueError(f"field {self.name!r}: enum values are not unique")
        for bound in (self.min, self.max):
            if bound is not None and bound > top:
                raise ValueError(
                    f"field {self.name!r}: bound {bound} does not fit {self.width} bits"
                )
        if self.min is not None and self.max is not None and self.min > self.max:
            raise ValueError(f"field {self.name!r}: min {self.min} > max {self.max}")
        return self

    @property
    def msb(self) -> int:
        return self.bits[0]

    @property
    def lsb(self) -> int:
        return self.bits[1]

    @property
    def width(self) -> int:
        return self.msb - self.lsb + 1

    @property
    def raw_max(self) -> int:
        return (1 << self.width) - 1

    @property
    def mask(self) -> int:
        """The field's bits within the register."""
        return self.raw_max << self.lsb

    @property
    def lo(self) -> int:
        return self.min if self.min is not None else 0

    @property
    def hi(self) -> int:
        return self.max if self.max is not None else self.raw_max

    def extract(self, register_value: int) -> int:
        return (register_value >> self.lsb) & self.raw_max

    def insert(self, register_value: int, value: int) -> int:
        return (register_value & ~self.mask) | ((value & self.raw_max) << self.lsb)

    def valid_range(self) -> str:
        """The accepted values, for error messages and docs."""
        if self.enum is not None:
            return "one of " + ", ".join(f"{k} ({v})" for k, v in self.enum.items())
        # The physical range counts the bias: raw 2 .. 1023 of a rows-minus-1 field is 3 .. 1024
        # rows.
        unit = (
            f" ({self.count(self.lo) * self.scale:g} .. {self.count(self.hi) * self.scale:g} "
            f"{self.unit})"
            if self.unit
            else ""
        )
        return f"{self.lo} .. {self.hi}{unit}"

    def label(self, raw: int) -> str | None:
        """The enum name of a raw value, if the field has one."""
        for name, value in (self.enum or {}).items():
            if value == raw:
                return name
        return None

    def to_raw(self, value: int | str, where: str) -> int:
        """Check a value (raw integer or enum name) against the field; return the raw integer."""
        if isinstance(value, str):
            if self.enum is None or value not in self.enum:
                raise RegisterValueError(
                    f"{where}: {value!r} is not valid; use {self.valid_range()}"
                )
            return self.enum[value]
        if isinstance(value, bool) or not isinstance(value, int):
            raise RegisterValueError(f"{where}: expected an integer, got {value!r}")
        if self.enum is not None and value not in self.enum.values():
            raise RegisterValueError(f"{where}: {value} is not valid; use {self.valid_range()}")
        if not self.lo <= value <= self.hi:
            raise RegisterValueError(
                f"{where}: {value} is out of range (valid: {self.valid_range()})"
            )
        return value

    def physical(self, raw: int) -> float:
        return raw * self.scale

    def count(self, raw: int) -> int:
        """The counted quantity a raw value stands for (``raw + bias``)."""
        return raw + self.bias


class RegisterSpec(BaseModel):
    """One sensor register. Registers without ``fields`` behave as one field named ``value``."""

    model_config = ConfigDict(extra="forbid", frozen=True, strict=True)

    name: str = Field(pattern=_NAME, description="upper-case register name")
    address: int = Field(ge=0, description="register address on the SPI bus")
    width: int = Field(ge=1, le=MAX_DATA_BITS, description="bits of the register")
    access: Access = Field(description="ro, rw, wo or w1c (write 1 to a bit to clear it)")
    volatile: bool = Field(
        default=False, description="the sensor changes it by itself: never verified or saved"
    )
    reset: int = Field(default=0, ge=0, description="value after power-on or soft reset")
    doc: str = Field(default="", description="what the register does")
    fields: list[FieldSpec] = Field(
        default_factory=list, description="named bit fields (inline tables, see below)"
    )
    mirrors: list[str] = Field(
        default_factory=list,
        description="a write also writes these registers; a read returns the first of them "
        "(the register must be volatile)",
    )

    @model_validator(mode="after")
    def _check(self) -> RegisterSpec:
        if self.reset >= 1 << self.width:
            raise _Located(
                f"reset value 0x{self.reset:X} does not fit the register's {self.width} bits",
                key="reset",
            )
        names: set[str] = set()
        for i, f in enumerate(self.fields):
            if f.name in names:
                raise _Located(f"duplicate field name {f.name!r}", field=i)
            names.add(f.name)
            if f.msb >= self.width:
                raise _Located(
                    f"field {f.name!r} bits {f.msb}..{f.lsb} exceed the register's "
                    f"{self.width} bits",
                    field=i,
                )
            for other in self.fields[:i]:
                if f.mask & other.mask:
                    raise _Located(
                        f"field {f.name!r} bits {f.msb}..{f.lsb} overlap field {other.name!r} "
                        f"bits {other.msb}..{other.lsb}",
                        field=i,
                    )
            if f.pulse and self.access == "ro":
                raise _Located(
                    f"field {f.name!r} is a pulse field in a read-only register", field=i
                )
            if f.pulse and f.extract(self.reset):
                raise _Located(
                    f"reset value 0x{self.reset:X} sets pulse field {f.name!r}, which always "
                    "reads 0",
                    key="reset",
                )
        stray = self.reset & ~self.fields_mask
        if stray:
            raise _Located(
                f"reset value 0x{self.reset:X} sets bits (0x{stray:X}) that no field covers",
                key="reset",
            )
        if self.access != "w1c":  # flag registers hold whatever the sensor raised
            for f in self.fields:
                raw = f.extract(self.reset)
                try:
                    f.to_raw(raw, f"field {f.name!r}")
                except RegisterValueError as exc:
                    raise _Located(
                        f"reset value 0x{self.reset:X} is invalid: {exc}", key="reset"
                    ) from None
        if self.mirrors and not self.volatile:
            raise _Located(
                "a register that mirrors others reads back what they hold: declare it "
                "volatile = true",
                key="mirrors",
            )
        if self.mirrors and self.access not in ("rw", "wo"):
            raise _Located("only a RW or WO register can mirror others", key="mirrors")
        return self

    @property
    def readable(self) -> bool:
        return self.access != "wo"

    @property
    def writable(self) -> bool:
        return self.access != "ro"

    @property
    def verify_after_write(self) -> bool:
        """Whether a write is checked by reading back: RW registers that do not change by themselves."""
        return self.access == "rw" and not self.volatile

    @property
    def configurable(self) -> bool:
        """Whether the register belongs in a saved configuration (written by the host, kept)."""
        return self.access in ("rw", "wo") and not self.volatile

    @property
    def mask(self) -> int:
        return (1 << self.width) - 1

    @property
    def pulse_mask(self) -> int:
        """Bits of self-clearing (pulse) fields: written as 1, always read as 0."""
        bits = 0
        for f in self.fields:
            if f.pulse:
                bits |= f.mask
        return bits

    @property
    def kept_mask(self) -> int:
        """Bits the register keeps after a write (all but the pulse bits)."""
        return self.mask & ~self.pulse_mask

    def all_fields(self) -> list[FieldSpec]:
        """The declared fields, or one implicit ``value`` field covering the register."""
        if self.fields:
            return list(self.fields)
        return [FieldSpec(name="value", bits=(self.width - 1, 0))]

    def field(self, name: str) -> FieldSpec:
        for f in self.all_fields():
            if f.name == name.lower():
                return f
        known = ", ".join(f.name for f in self.all_fields())
        raise RegisterAccessError(f"register {self.name} has no field {name!r}; fields: {known}")

    def decode(self, value: int) -> dict[str, int | str]:
        """Field values of a register value (enum fields by name when the value is defined)."""
        out: dict[str, int | str] = {}
        for f in self.all_fields():
            raw = f.extract(value)
            label = f.label(raw)
            out[f.name] = label if label is not None else raw
        return out

    def check_value(self, value: int, where: str | None = None) -> int:
        """Check a whole-register value against the width and every field's range.

        Bits that no declared field covers must be 0. A register with one field starting at
        bit 0 is a plain number: its value is checked as that field's value.
        """
        where = where or self.name
        if isinstance(value, bool) or not isinstance(value, int):
            raise RegisterValueError(f"{where}: expected an integer, got {value!r}")
        if len(self.fields) == 1 and self.fields[0].lsb == 0 and self.access != "w1c":
            only = self.fields[0]
            return only.to_raw(value, f"{self.name}.{only.name}")
        if not 0 <= value <= self.mask:
            # A negative value has no hex form a user would recognise ("0x-1").
            shown = f"0x{value:X} ({value})" if value >= 0 else f"{value}"
            raise RegisterValueError(
                f"{where}: {shown} does not fit {self.width} bits (valid: 0 .. 0x{self.mask:X})"
            )
        stray = value & ~self.fields_mask if self.fields else 0
        if stray:
            bits = ", ".join(str(b) for b in range(self.width) if stray >> b & 1)
            layout = ", ".join(f"{f.name} {f.msb}..{f.lsb}" for f in self.fields)
            raise RegisterValueError(
                f"{where}: 0x{value:X} sets bit(s) {bits}, which no field uses; they must be 0 "
                f"(fields: {layout})"
            )
        if self.access == "w1c":
            return value  # bits written as 1 clear flags; any pattern is meaningful
        for f in self.fields:
            f.to_raw(f.extract(value), f"{self.name}.{f.name}")
        return value

    @property
    def fields_mask(self) -> int:
        """Bits covered by the declared fields (the whole register if none are declared)."""
        if not self.fields:
            return self.mask
        bits = 0
        for f in self.fields:
            bits |= f.mask
        return bits


class GroupSpec(BaseModel):
    """A value spread over several registers (most significant first) that changes atomically.

    With ``hold`` (``REGISTER.field``), the sensor latches writes to the group's registers while
    the hold bit is set and applies them together when it is cleared (group hold).
    """

    model_config = ConfigDict(extra="forbid", frozen=True, strict=True)

    name: str = Field(pattern=_NAME, description="upper-case group name")
    registers: list[str] = Field(
        min_length=2, description="member registers, most significant first"
    )
    hold: str | None = Field(default=None, description="REGISTER.field of the group-hold bit")
    doc: str = Field(default="", description="what the value is")
    unit: str = Field(default="", description="unit of the value")
    min: int | None = Field(default=None, ge=0, description="smallest valid value")
    max: int | None = Field(default=None, ge=0, description="largest valid value")


class TimingSpec(BaseModel):
    """How the sensor's line period follows from its clock (see camd.sensor.timing_view).

    ``sequencer``: ``T_line = clocks_per_line / clock_hz`` (docs/physics.md §3).
    ``row_blanking``: ``T_line = t_rb + n_pixels / f_s`` (docs/physics.md §2 eq 4) with
    ``t_rb = (fixed_row_overhead_clocks + max(row_blanking, row_blanking_min_clocks)) / clock_hz``
    and ``f_s = clock_hz * pixels_per_clock``.
    """

    model_config = ConfigDict(extra="forbid", frozen=True, strict=True)

    model: Literal["sequencer", "row_blanking"] = Field(description="sequencer or row_blanking")
    clock_hz: float = Field(
        gt=0, description="sequencer clock (sequencer) or pixel clock (row_blanking)"
    )
    clocks_per_line: int | None = Field(
        default=None, ge=1, description="sequencer clocks per line (sequencer model)"
    )
    pixels_per_clock: float = Field(
        default=1.0, gt=0, description="pixels read per clock (row_blanking model)"
    )
    fixed_row_overhead_clocks: int = Field(
        default=0, ge=0, description="clocks added to the row blanking in every row"
    )
    row_blanking_min_clocks: int = Field(
        default=0, ge=0, description="row-blanking values below this are taken as this value"
    )
    dummy_row: int | None = Field(
        default=None, description="row address read or reset when no window row is due"
    )
    exposure_remainder_s: float = Field(
        default=0.0, ge=0, description="T_RES added to n whole lines of exposure"
    )
    doc: str = Field(default="", description="where the timing comes from")


class OutputSpec(BaseModel):
    """The sensor's pixel output interface to the FPGA: LVDS lanes to train, or a parallel bus."""

    model_config = ConfigDict(extra="forbid", frozen=True, strict=True)

    interface: Literal["lvds", "parallel"] = Field(description="lvds (needs training) or parallel")
    lanes: int = Field(default=1, ge=1, le=32, description="LVDS data lanes (1 for parallel)")
    word_bits: int = Field(ge=1, le=16, description="bits per pixel word on the interface")
    doc: str = Field(default="", description="notes on the output")

    @property
    def needs_training(self) -> bool:
        """LVDS links must be trained (bit, word, channel alignment) before imaging."""
        return self.interface == "lvds"


class SoftResetSpec(BaseModel):
    """Which write returns every register to its reset value."""

    model_config = ConfigDict(extra="forbid", frozen=True, strict=True)

    field: str = Field(description="REGISTER.field written to reset")
    value: int = Field(ge=0, description="raw field value that triggers the reset")


class RegisterMap(BaseModel):
    """A sensor's whole register map, as loaded from ``config/sensors/<sensor>.toml``."""

    model_config = ConfigDict(extra="forbid", frozen=True, strict=True)

    sensor: str = Field(pattern=r"^[a-z0-9][a-z0-9_]*$", description="sensor name (file stem)")
    description: str = Field(default="", description="one line on the sensor")
    modelled: bool = Field(
        description="true when no public register map exists and this one is a model"
    )
    source: str = Field(default="", description="where the facts come from")
    rows: int = Field(ge=1, description="active rows of the pixel array")
    columns: int = Field(ge=1, description="active columns of the pixel array")
    first_row: int = Field(
        default=0, ge=0, description="row address of the first active row (window start minimum)"
    )
    first_column: int = Field(
        default=0, ge=0, description="column address of the first active column"
    )
    spi: SpiLayout = Field(description="SPI frame layout (table [spi])")
    timing: TimingSpec = Field(description="line-period model (table [timing])")
    output: OutputSpec = Field(description="pixel output interface (table [output])")
    soft_reset: SoftResetSpec | None = Field(
        default=None, description="the write that resets every register (table [soft_reset])"
    )
    roles: dict[str, str] = Field(
        default_factory=dict, description="role -> REGISTER, REGISTER.field or GROUP"
    )
    registers: list[RegisterSpec] = Field(description="the registers ([[registers]] entries)")
    groups: list[GroupSpec] = Field(
        default_factory=list, description="multi-register values ([[groups]] entries)"
    )

    _by_name: dict[str, RegisterSpec] = PrivateAttr(default_factory=dict)
    _by_address: dict[int, RegisterSpec] = PrivateAttr(default_factory=dict)
    _groups: dict[str, GroupSpec] = PrivateAttr(default_factory=dict)
    _group_of: dict[str, GroupSpec] = PrivateAttr(default_factory=dict)

    def model_post_init(self, __context: Any) -> None:
        for reg in self.registers:
            self._by_name[reg.name] = reg
            self._by_address[reg.address] = reg
        for group in self.groups:
            self._groups[group.name] = group
            for name in group.registers:
                self._group_of[name] = group

    # -- look-up ----------------------------------------------------------------------------

    def register(self, key: str | int) -> RegisterSpec:
        """A register by name (case-insensitive) or address."""
        if isinstance(key, int):
            reg = self._by_address.get(key)
            if reg is None:
                raise RegisterAccessError(
                    f"{self.sensor} has no register at address 0x{key:02X}; "
                    "`camctl reg dump` lists them"
                )
            return reg
        reg = self._by_name.get(key.upper())
        if reg is None:
            raise RegisterAccessError(
                f"{self.sensor} has no register named {key!r}; `camctl reg dump` lists them"
            )
        return reg

    def has_register(self, key: str | int) -> bool:
        return (key in self._by_address) if isinstance(key, int) else key.upper() in self._by_name

    def group(self, name: str) -> GroupSpec:
        group = self._groups.get(name.upper())
        if group is None:
            raise RegisterAccessError(f"{self.sensor} has no register group named {name!r}")
        return group

    def has_group(self, name: str) -> bool:
        return name.upper() in self._groups

    def group_of(self, register: str) -> GroupSpec | None:
        """The group a register belongs to, if any."""
        return self._group_of.get(register.upper())

    def group_registers(self, group: GroupSpec) -> list[RegisterSpec]:
        return [self._by_name[name] for name in group.registers]

    def group_width(self, group: GroupSpec) -> int:
        return sum(reg.width for reg in self.group_registers(group))

    def group_range(self, group: GroupSpec) -> tuple[int, int]:
        """The smallest and largest valid group value."""
        top = (1 << self.group_width(group)) - 1
        lo = group.min if group.min is not None else 0
        hi = group.max if group.max is not None else top
        return lo, hi

    def split_group(self, group: GroupSpec, value: int) -> list[tuple[RegisterSpec, int]]:
        """A group value as (register, value) pairs, most significant register first."""
        regs = self.group_registers(group)
        lo, hi = self.group_range(group)
        if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
            unit = f" {group.unit}" if group.unit else ""
            raise RegisterValueError(
                f"{group.name}: {value!r} is out of range (valid: {lo} .. {hi}{unit})"
            )
        pairs: list[tuple[RegisterSpec, int]] = []
        shift = self.group_width(group)
        for reg in regs:
            shift -= reg.width
            pairs.append((reg, (value >> shift) & reg.mask))
        return pairs

    def join_group(self, group: GroupSpec, values: dict[str, int]) -> int:
        """The group value from its registers' values (by register name)."""
        total = 0
        for reg in self.group_registers(group):
            total = (total << reg.width) | (values[reg.name] & reg.mask)
        return total

    def hold_of(self, group: GroupSpec) -> tuple[RegisterSpec, FieldSpec] | None:
        """The group-hold register and bit field of a group, if it has one."""
        if group.hold is None:
            return None
        reg_name, _, field_name = group.hold.partition(".")
        reg = self.register(reg_name)
        return reg, reg.field(field_name) if field_name else reg.all_fields()[0]

    def resolve(self, name: str) -> tuple[RegisterSpec | GroupSpec, FieldSpec | None]:
        """A value name -> (register, field) for ``REG`` / ``REG.field``, or (group, None)."""
        reg_name, _, field_name = name.strip().partition(".")
        if not field_name and self.has_group(reg_name):
            return self.group(reg_name), None
        reg = self.register(reg_name)
        return reg, (reg.field(field_name) if field_name else None)

    def canonical(self, name: str) -> str:
        """A value name as the map spells it (``win_start`` -> ``WIN_START``)."""
        target, field_spec = self.resolve(name)
        return f"{target.name}.{field_spec.name}" if field_spec is not None else target.name

    def value_of(self, name: str, raw: Callable[[RegisterSpec], int]) -> int | str:
        """The value of ``REG`` (raw), ``REG.field`` (enum label or raw) or ``GROUP`` (joined).

        ``raw`` gives a register's raw value (read from a device, a shadow copy or a model).
        """
        target, field_spec = self.resolve(name)
        if isinstance(target, GroupSpec):
            regs = self.group_registers(target)
            return self.join_group(target, {reg.name: raw(reg) for reg in regs})
        value = raw(target)
        if field_spec is None:
            return value
        part = field_spec.extract(value)
        label = field_spec.label(part)
        return label if label is not None else part

    def role(self, role: str) -> str | None:
        """The value name that plays ``role`` (see ROLES), or None if the sensor has none."""
        return self.roles.get(role)

    def role_count(self, role: str, value: Callable[[str], int | str]) -> int | None:
        """The counted quantity of a numeric role (raw + the field's bias); None if absent.

        ``value`` gives a value name's value (``value_of`` over some source of raw values).
        """
        name = self.role(role)
        if name is None:
            return None
        raw = value(name)
        if isinstance(raw, str):
            raise RegisterValueError(
                f"role {role} ({name}) has the enum value {raw!r}; it must be a number"
            )
        _, field_spec = self.resolve(name)
        return field_spec.count(raw) if field_spec is not None else raw

    def role_write(self, role: str, count: int) -> tuple[str, int] | None:
        """(value name, raw value) that sets a numeric role to the counted quantity ``count``
        (raw = count - the field's bias: ``role_count``'s inverse); None if absent."""
        name = self.role(role)
        if name is None:
            return None
        _, field_spec = self.resolve(name)
        return name, count - (field_spec.bias if field_spec is not None else 0)

    def is_soft_reset(self, reg: RegisterSpec, value: int) -> bool:
        """Whether writing ``value`` to ``reg`` resets every register (``soft_reset``)."""
        if self.soft_reset is None:
            return False
        target, field_spec = self.resolve(self.soft_reset.field)
        if target is not reg:
            return False
        assert field_spec is not None
        return field_spec.extract(value) == self.soft_reset.value

    def soft_reset_register(self) -> RegisterSpec | None:
        """The register whose write resets the sensor, if the map declares one."""
        if self.soft_reset is None:
            return None
        target, _ = self.resolve(self.soft_reset.field)
        assert isinstance(target, RegisterSpec)
        return target

    def check_window(self, value: Callable[[str], int | str]) -> None:
        """Raise RegisterValueError if the window runs off the pixel array.

        Checks ``window_start_row`` + ``window_rows`` against ``first_row`` and ``rows`` (and
        the same for columns when the map has column roles); ``value`` gives value names'
        values as they would be after the write.
        """
        axes = (
            ("window_start_row", "window_rows", self.first_row, self.rows, "row"),
            ("window_start_column", "window_columns", self.first_column, self.columns, "column"),
        )
        for start_role, size_role, first, total, what in axes:
            start_name, size_name = self.role(start_role), self.role(size_role)
            if start_name is None or size_name is None:
                continue
            start = self.role_count(start_role, value)
            size = self.role_count(size_role, value)
            assert start is not None and size is not None
            last_valid = first + total - 1
            if start < first:
                raise RegisterValueError(
                    f"{start_name} = {value(start_name)}: the window starts at {what} {start}, "
                    f"before the first active {what} {first} (valid: {first} .. {last_valid})"
                )
            last = start + size - 1
            if last > last_valid:
                raise RegisterValueError(
                    f"{start_name} = {value(start_name)} and {size_name} = {value(size_name)}: "
                    f"the window's last {what} would be {last}, beyond the sensor's last {what} "
                    f"{last_valid}; lower {start_name} or {size_name} (the window must fit "
                    f"{what}s {first} .. {last_valid})"
                )

    def by_address(self) -> Iterator[RegisterSpec]:
        """The registers in address order."""
        return iter(sorted(self.registers, key=lambda r: r.address))

    # -- validation across registers ------------------------------------------------------------

    @model_validator(mode="after")
    def _check(self) -> RegisterMap:
        names = self._check_registers()
        groups = self._check_groups(names)
        self._check_roles(names, groups)
        self._check_soft_reset(names)
        self._check_output()
        by_name = {reg.name: reg for reg in self.registers}

        def reset_value(name: str) -> int | str:
            return self.value_of(name, lambda reg: by_name[reg.name].reset)

        try:
            self.check_window(reset_value)
        except RegisterValueError as exc:
            start = self.roles.get("window_start_row", "").partition(".")[0]
            index = names.get(start)
            if index is None:
                raise _Located(f"reset values: {exc}", table="roles") from None
            raise _Located(
                f"reset values: {exc}", table="registers", index=index, key="reset"
            ) from None
        return self

    def _check_registers(self) -> dict[str, int]:
        names: dict[str, int] = {}
        addresses: dict[int, str] = {}
        for i, reg in enumerate(self.registers):
            if reg.name in names:
                raise _Located(
                    f"duplicate register name (also entry #{names[reg.name] + 1} of [[registers]])",
                    table="registers",
                    index=i,
                    key="name",
                )
            names[reg.name] = i
            if reg.address in addresses:
                raise _Located(
                    f"address 0x{reg.address:02X} is already register {addresses[reg.address]}",
                    table="registers",
                    index=i,
                    key="address",
                )
            addresses[reg.address] = reg.name
            if reg.address >= 1 << self.spi.address_bits:
                raise _Located(
                    f"address 0x{reg.address:X} does not fit the SPI frame's "
                    f"{self.spi.address_bits} address bits",
                    table="registers",
                    index=i,
                    key="address",
                )
            if reg.width > self.spi.data_bits:
                raise _Located(
                    f"width {reg.width} exceeds the SPI frame's {self.spi.data_bits} data bits",
                    table="registers",
                    index=i,
                    key="width",
                )
        for i, reg in enumerate(self.registers):
            for target in reg.mirrors:
                other = self.registers[names[target]] if target in names else None
                if other is None:
                    raise _Located(
                        f"mirrors {target}, which is not a register",
                        table="registers",
                        index=i,
                        key="mirrors",
                    )
                if other.width != reg.width or other.mirrors or other.access not in ("rw", "wo"):
                    raise _Located(
                        f"mirrors {target}, which must be a RW/WO register of the same width "
                        "that mirrors nothing",
                        table="registers",
                        index=i,
                        key="mirrors",
                    )
        return names

    def _check_groups(self, names: dict[str, int]) -> set[str]:
        seen: set[str] = set()
        member_of: dict[str, str] = {}
        for i, group in enumerate(self.groups):
            if group.name in names or group.name in seen:
                raise _Located("name already used", table="groups", index=i, key="name")
            seen.add(group.name)
            for member in group.registers:
                if member not in names:
                    raise _Located(
                        f"no register {member}", table="groups", index=i, key="registers"
                    )
                reg = self.registers[names[member]]
                if not reg.writable or reg.access == "w1c" or reg.volatile:
                    raise _Located(
                        f"member {member} must be a non-volatile RW or WO register",
                        table="groups",
                        index=i,
                        key="registers",
                    )
                if member in member_of:
                    raise _Located(
                        f"register {member} is already in group {member_of[member]}",
                        table="groups",
                        index=i,
                        key="registers",
                    )
                member_of[member] = group.name
            width = sum(self.registers[names[m]].width for m in group.registers)
            top = (1 << width) - 1
            for bound in (group.min, group.max):
                if bound is not None and bound > top:
                    raise _Located(
                        f"bound {bound} does not fit the group's {width} bits",
                        table="groups",
                        index=i,
                    )
            reset = 0
            for member in group.registers:
                reg = self.registers[names[member]]
                reset = (reset << reg.width) | reg.reset
            lo = group.min if group.min is not None else 0
            hi = group.max if group.max is not None else top
            if not lo <= reset <= hi:
                raise _Located(
                    f"the members' reset values make {reset}, out of range (valid: {lo} .. {hi})",
                    table="groups",
                    index=i,
                )
            if group.hold is not None:
                hold_reg, _, hold_field = group.hold.partition(".")
                if hold_reg not in names:
                    raise _Located(
                        f"no hold register {hold_reg}", table="groups", index=i, key="hold"
                    )
                reg = self.registers[names[hold_reg]]
                if hold_field and hold_field not in {f.name for f in reg.all_fields()}:
                    raise _Located(
                        f"register {hold_reg} has no field {hold_field}",
                        table="groups",
                        index=i,
                        key="hold",
                    )
                if hold_reg in group.registers or reg.access != "rw" or reg.volatile:
                    raise _Located(
                        f"hold register {hold_reg} must be a non-volatile RW register outside "
                        "the group",
                        table="groups",
                        index=i,
                        key="hold",
                    )
        return seen

    def _check_roles(self, names: dict[str, int], groups: set[str]) -> None:
        for role, target in self.roles.items():
            if role not in ROLES:
                raise _Located(
                    f"unknown role {role!r}; roles are {', '.join(ROLES)}", table="roles", key=role
                )
            reg_name, _, field_name = target.partition(".")
            if reg_name in groups and not field_name:
                if role not in COUNT_ROLES:
                    raise _Located(
                        f"role {role}: group {reg_name} cannot play this role",
                        table="roles",
                        key=role,
                    )
                continue
            if reg_name not in names:
                raise _Located(
                    f"role {role}: no register or group {reg_name}", table="roles", key=role
                )
            reg = self.registers[names[reg_name]]
            fields = {f.name: f for f in reg.all_fields()}
            if field_name and field_name not in fields:
                raise _Located(
                    f"role {role}: register {reg_name} has no field {field_name}",
                    table="roles",
                    key=role,
                )
            field_spec = fields[field_name] if field_name else None
            if role in COUNT_ROLES and field_spec is not None and field_spec.enum is not None:
                raise _Located(
                    f"role {role}: field {target} is an enum; the role needs a number",
                    table="roles",
                    key=role,
                )
            if role == "spi_error_flag" and reg.access != "w1c":
                raise _Located(
                    f"role {role}: {reg_name} must be a write-1-to-clear register",
                    table="roles",
                    key=role,
                )
            if role in CLOCK_ROLES and field_spec is not None and field_spec.unit == "s":
                clock_s = 1.0 / self.timing.clock_hz
                if not math.isclose(field_spec.scale, clock_s, rel_tol=1e-9):
                    raise _Located(
                        f"field {field_spec.name!r} plays the {role} role, which counts clocks "
                        f"of timing.clock_hz = {self.timing.clock_hz:g} Hz, so its scale must be "
                        f"{clock_s:g} s, not {field_spec.scale:g}",
                        table="registers",
                        index=names[reg_name],
                        field=reg.fields.index(field_spec),
                    )
        sequencer = self.timing.model == "sequencer"
        if sequencer and self.timing.clocks_per_line is None and "line_clocks" not in self.roles:
            raise _Located(
                "the sequencer model needs clocks_per_line or a line_clocks role",
                table="timing",
            )

    def _check_soft_reset(self, names: dict[str, int]) -> None:
        if self.soft_reset is None:
            return
        reg_name, _, field_name = self.soft_reset.field.partition(".")
        if reg_name not in names:
            raise _Located(f"no register {reg_name}", table="soft_reset", key="field")
        reg = self.registers[names[reg_name]]
        fields = {f.name: f for f in reg.all_fields()}
        if field_name and field_name not in fields:
            raise _Located(
                f"register {reg_name} has no field {field_name}", table="soft_reset", key="field"
            )
        if not reg.writable or reg.access == "w1c":
            raise _Located(
                f"register {reg_name} cannot be written", table="soft_reset", key="field"
            )
        field_spec = fields[field_name] if field_name else reg.all_fields()[0]
        if self.soft_reset.value > field_spec.raw_max:
            raise _Located(
                f"value {self.soft_reset.value} does not fit {self.soft_reset.field}",
                table="soft_reset",
                key="value",
            )

    def _check_output(self) -> None:
        if not self.output.needs_training:
            return
        word = self.roles.get("training_word")
        pattern = self.roles.get("test_pattern")
        if word is None or pattern is None:
            raise _Located(
                "an lvds output needs the training_word and test_pattern roles "
                "(the FPGA trains the lanes on the training word)",
                table="output",
                key="interface",
            )
        reg_name, _, field_name = pattern.partition(".")
        reg = next((r for r in self.registers if r.name == reg_name), None)
        field_spec = None
        if reg is not None:
            field_spec = next((f for f in reg.all_fields() if f.name == field_name), None)
        labels = set((field_spec.enum or {}) if field_spec is not None else {})
        if not {"training", "prbs"} <= labels:
            raise _Located(
                f"role test_pattern: {pattern} needs enum values 'training' and 'prbs' for "
                "LVDS training",
                table="roles",
                key="test_pattern",
            )


# -- loading --------------------------------------------------------------------------------


def sensors_dir() -> Path:
    return config_dir() / "sensors"


def list_sensors() -> list[str]:
    """Names of the shipped register maps."""
    return _MAPS.names()


def load_register_map(sensor_or_path: str | Path) -> RegisterMap:
    """Load and validate a register map by sensor name (``hr400``) or by file path."""
    return _MAPS.find(sensor_or_path)


_MAPS = DataFileKind(
    RegisterMap,
    RegisterMapError,
    # A message calls an entry by its name: "register GAIN: field 'digital': ...".
    named={"registers": "register {}", "groups": "group {}", "fields": "field {!r}"},
    folder=sensors_dir,
    noun="register map",
    name_of="sensor",
)
