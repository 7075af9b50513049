"""The entries of a sensor register map file (``config/sensors/<sensor>.toml``), each validated
on its own by pydantic: the SPI frame layout, a register and its bit fields, a group, the timing
model, the output interface, the soft reset; the roles a value may play; the errors of a map.

``camd.sensor.regmap_checks`` checks the entries against each other and
``camd.sensor.regmap.RegisterMap`` holds them all (camd.sensor.regmap describes the file).
"""

from __future__ import annotations

from typing import Literal

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    StrictInt,
    model_validator,
)

from camd.datafile import DataFileError, KeyedError

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
