"""The command dictionary: opcodes, payload fields, units, ranges and error codes, as data.

Declared once in ``config/protocol.toml`` and validated here with pydantic. The host, the simulated
camera and the docs use the same objects: ``CommandSpec.encode_request`` / ``decode_response`` on
the host, ``decode_request`` / ``encode_response`` on the device. Values are physical (the field's
``unit``, after ``scale``); enum fields take and give their names.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, PrivateAttr, model_validator

from camd.datafile import DataFileError, DataFileKind
from camd.paths import config_dir
from camd.protocol.frame import MAX_PAYLOAD

FieldType = Literal["u8", "u16", "u32", "u64", "i8", "i16", "i32", "i64", "f32", "bytes", "str"]

_STRUCT_FORMAT: dict[str, str] = {
    "u8": ">B", "u16": ">H", "u32": ">I", "u64": ">Q",
    "i8": ">b", "i16": ">h", "i32": ">i", "i64": ">q", "f32": ">f",
}  # fmt: skip
_INT_RANGE: dict[str, tuple[int, int]] = {
    "u8": (0, 0xFF), "u16": (0, 0xFFFF), "u32": (0, 0xFFFF_FFFF), "u64": (0, 2**64 - 1),
    "i8": (-0x80, 0x7F), "i16": (-0x8000, 0x7FFF), "i32": (-0x8000_0000, 0x7FFF_FFFF),
    "i64": (-(2**63), 2**63 - 1),
}  # fmt: skip
_VARIABLE = frozenset({"bytes", "str"})

F32_SIGNIFICANT_DIGITS = 7
"""Decimal digits an f32 field carries: a value rounded to this many is the decimal sent."""


def f32_decimal(value: float) -> float:
    """A value that crossed the link in an f32 field, as the decimal it was sent as (73.245,
    not 73.24500274658203): predictions and comparisons must not carry the wire's rounding."""
    return float(f"{float(value):.{F32_SIGNIFICANT_DIGITS}g}")


FieldValue = int | float | str | bytes


class ProtocolError(Exception):
    """Base of the errors raised by the dictionary codec."""


class EncodeError(ProtocolError, ValueError):
    """A value cannot be sent as given; the message says which field and what is allowed."""


class PayloadError(ProtocolError):
    """A received payload does not match its definition."""


class DictionaryError(DataFileError, ProtocolError):
    """The dictionary file itself is invalid: ``file:line: key: what is wrong; what to do``."""


class FieldSpec(BaseModel):
    """One payload field."""

    model_config = ConfigDict(extra="forbid", frozen=True, strict=True)

    name: str = Field(pattern=r"^[a-z][a-z0-9_]*$")
    type: FieldType
    doc: str = ""
    unit: str = ""
    scale: float = Field(default=1.0, gt=0)
    min: float | None = None
    max: float | None = None
    enum: dict[str, int] | None = None
    max_len: int | None = Field(default=None, ge=0, le=MAX_PAYLOAD)

    @model_validator(mode="after")
    def _check(self) -> FieldSpec:
        if self.type in _VARIABLE:
            if self.max_len is None:
                raise ValueError(f"field {self.name!r}: {self.type} fields need max_len")
            if self.enum or self.scale != 1.0 or self.min is not None or self.max is not None:
                raise ValueError(
                    f"field {self.name!r}: {self.type} fields take no enum/scale/min/max"
                )
            return self
        if self.max_len is not None:
            raise ValueError(f"field {self.name!r}: max_len is only for bytes/str fields")
        if self.min is not None and self.max is not None and self.min > self.max:
            raise ValueError(f"field {self.name!r}: min {self.min} > max {self.max}")
        if self.type == "f32":
            if self.enum or self.scale != 1.0:
                raise ValueError(f"field {self.name!r}: f32 fields take no enum or scale")
            return self
        lo, hi = _INT_RANGE[self.type]
        if self.enum is not None:
            for label, raw in self.enum.items():
                if not lo <= raw <= hi:
                    raise ValueError(
                        f"field {self.name!r}: enum {label}={raw} does not fit {self.type}"
                    )
            if len(set(self.enum.values())) != len(self.enum):
                raise ValueError(f"field {self.name!r}: enum values are not unique")
        for bound in (self.min, self.max):
            if bound is not None and not lo <= round(bound / self.scale) <= hi:
                raise ValueError(
                    f"field {self.name!r}: bound {bound} is not representable in {self.type} "
                    f"with scale {self.scale}"
                )
        return self

    @property
    def size(self) -> int | None:
        """Encoded size in bytes, or None for a variable-length field."""
        return None if self.type in _VARIABLE else struct.calcsize(_STRUCT_FORMAT[self.type])

    @property
    def max_size(self) -> int:
        return (
            self.max_len if self.max_len is not None else struct.calcsize(_STRUCT_FORMAT[self.type])
        )

    def valid_range(self) -> str:
        """Human description of the accepted values, for error messages and docs."""
        if self.enum is not None:
            return "one of " + ", ".join(self.enum)
        if self.type in _VARIABLE:
            return f"at most {self.max_len} bytes"
        unit = f" {self.unit}" if self.unit else ""
        if self.type == "f32":
            lo_f = -math.inf if self.min is None else self.min
            hi_f = math.inf if self.max is None else self.max
            return f"{lo_f:.10g} .. {hi_f:.10g}{unit}"
        lo, hi = _INT_RANGE[self.type]
        lo_p = self.min if self.min is not None else lo * self.scale
        hi_p = self.max if self.max is not None else hi * self.scale
        return f"{lo_p:.10g} .. {hi_p:.10g}{unit}"

    def encode(self, value: Any, where: str) -> bytes:
        """Encode one physical value; EncodeError names the field and the accepted values."""
        label = f"{where}.{self.name}"
        if self.type in _VARIABLE:
            raw_bytes = value.encode() if self.type == "str" and isinstance(value, str) else value
            if not isinstance(raw_bytes, bytes | bytearray):
                raise EncodeError(f"{label}: expected {self.type}, got {type(value).__name__}")
            if self.max_len is not None and len(raw_bytes) > self.max_len:
                raise EncodeError(
                    f"{label}: {len(raw_bytes)} bytes is too long ({self.valid_range()})"
                )
            return bytes(raw_bytes)
        if self.enum is not None:
            if not isinstance(value, str) or value not in self.enum:
                raise EncodeError(f"{label}: {value!r} is not valid; use {self.valid_range()}")
            return struct.pack(_STRUCT_FORMAT[self.type], self.enum[value])
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise EncodeError(f"{label}: expected a number, got {value!r}")
        if math.isnan(value) or math.isinf(value):
            raise EncodeError(f"{label}: {value!r} is not a finite number")
        if (self.min is not None and value < self.min) or (
            self.max is not None and value > self.max
        ):
            raise EncodeError(f"{label}: {value:.10g} is out of range ({self.valid_range()})")
        if self.type == "f32":
            try:
                return struct.pack(">f", value)
            except OverflowError:
                raise EncodeError(f"{label}: {value:.10g} does not fit in f32") from None
        raw = round(value / self.scale)
        lo, hi = _INT_RANGE[self.type]
        if not lo <= raw <= hi:
            raise EncodeError(f"{label}: {value:.10g} is out of range ({self.valid_range()})")
        return struct.pack(_STRUCT_FORMAT[self.type], raw)

    def decode(self, payload: bytes, offset: int, where: str) -> tuple[FieldValue, int]:
        """Decode this field at ``offset``; return (value, next offset)."""
        label = f"{where}.{self.name}"
        if self.type in _VARIABLE:
            data = payload[offset:]
            if self.max_len is not None and len(data) > self.max_len:
                raise PayloadError(f"{label}: {len(data)} bytes exceeds max_len {self.max_len}")
            if self.type == "str":
                try:
                    return data.decode(), len(payload)
                except UnicodeDecodeError as exc:
                    raise PayloadError(f"{label}: not valid UTF-8 ({exc.reason})") from None
            return bytes(data), len(payload)
        size = self.size
        assert size is not None
        if offset + size > len(payload):
            raise PayloadError(f"{label}: payload too short ({len(payload)} bytes)")
        (raw,) = struct.unpack_from(_STRUCT_FORMAT[self.type], payload, offset)
        if self.enum is not None:
            for label_name, enum_raw in self.enum.items():
                if enum_raw == raw:
                    return label_name, offset + size
            raise PayloadError(f"{label}: raw value {raw} is not {self.valid_range()}")
        if self.type == "f32" or self.scale == 1.0:
            return raw, offset + size
        return raw * self.scale, offset + size


def _check_layout(fields: list[FieldSpec], where: str) -> None:
    names = [f.name for f in fields]
    if len(set(names)) != len(names):
        raise ValueError(f"{where}: duplicate field names in {names}")
    for f in fields[:-1]:
        if f.size is None:
            raise ValueError(f"{where}: variable-length field {f.name!r} must be the last field")
    total = sum(f.max_size for f in fields)
    if total > MAX_PAYLOAD:
        raise ValueError(
            f"{where}: up to {total} bytes exceeds the {MAX_PAYLOAD}-byte payload limit"
        )


def encode_fields(fields: list[FieldSpec], values: Mapping[str, Any], where: str) -> bytes:
    """Encode ``values`` (field name -> physical value) in field order."""
    expected = {f.name for f in fields}
    unknown = set(values) - expected
    if unknown:
        allowed = ", ".join(sorted(expected)) or "none"
        raise EncodeError(
            f"{where}: unknown field(s) {', '.join(sorted(unknown))}; fields: {allowed}"
        )
    missing = [f.name for f in fields if f.name not in values]
    if missing:
        raise EncodeError(f"{where}: missing field(s) {', '.join(missing)}")
    return b"".join(f.encode(values[f.name], where) for f in fields)


def decode_fields(fields: list[FieldSpec], payload: bytes, where: str) -> dict[str, FieldValue]:
    """Decode a payload laid out as ``fields``; PayloadError if it does not fit exactly."""
    out: dict[str, FieldValue] = {}
    offset = 0
    for f in fields:
        out[f.name], offset = f.decode(payload, offset, where)
    if offset != len(payload):
        raise PayloadError(f"{where}: {len(payload) - offset} unexpected trailing byte(s)")
    return out


class ErrorSpec(BaseModel):
    """An error code a NAK can carry."""

    model_config = ConfigDict(extra="forbid", frozen=True, strict=True)

    code: int = Field(ge=1, le=0xFFFF)
    name: str = Field(pattern=r"^[A-Z][A-Z0-9_]*$")
    message: str


class CommandSpec(BaseModel):
    """A command and the layout of its request and acknowledge payloads."""

    model_config = ConfigDict(extra="forbid", strict=True)

    name: str = Field(pattern=r"^[A-Z][A-Z0-9_]*$")
    opcode: int = Field(ge=0, le=0xFF)
    doc: str = ""
    request: list[FieldSpec] = []
    response: list[FieldSpec] = []
    response_from_telemetry: str | None = None

    @property
    def simulator_only(self) -> bool:
        return self.opcode >= 0xF0

    def encode_request(self, **values: Any) -> bytes:
        return encode_fields(self.request, values, self.name)

    def decode_request(self, payload: bytes) -> dict[str, FieldValue]:
        return decode_fields(self.request, payload, self.name)

    def encode_response(self, **values: Any) -> bytes:
        return encode_fields(self.response, values, self.name)

    def decode_response(self, payload: bytes) -> dict[str, FieldValue]:
        return decode_fields(self.response, payload, self.name)


class PacketSpec(BaseModel):
    """A telemetry packet or an event: an id (the frame's opcode) and its fields."""

    model_config = ConfigDict(extra="forbid", strict=True)

    name: str = Field(pattern=r"^[A-Z][A-Z0-9_]*$")
    opcode: int = Field(ge=0, le=0xFF)
    doc: str = ""
    fields: list[FieldSpec] = []

    def encode(self, **values: Any) -> bytes:
        return encode_fields(self.fields, values, self.name)

    def decode(self, payload: bytes) -> dict[str, FieldValue]:
        return decode_fields(self.fields, payload, self.name)


_NAK_HEADER = struct.Struct(">H")


class Dictionary(BaseModel):
    """The whole command dictionary, with lookups by name and by opcode."""

    model_config = ConfigDict(extra="forbid", strict=True)

    version: int = Field(ge=1)
    errors: list[ErrorSpec]
    commands: list[CommandSpec]
    telemetry: list[PacketSpec] = []
    events: list[PacketSpec] = []

    _commands_by_name: dict[str, CommandSpec] = PrivateAttr(default_factory=dict)
    _commands_by_opcode: dict[int, CommandSpec] = PrivateAttr(default_factory=dict)
    _telemetry_by_opcode: dict[int, PacketSpec] = PrivateAttr(default_factory=dict)
    _events_by_opcode: dict[int, PacketSpec] = PrivateAttr(default_factory=dict)
    _errors_by_code: dict[int, ErrorSpec] = PrivateAttr(default_factory=dict)

    @model_validator(mode="after")
    def _index(self) -> Dictionary:
        def unique(items: list[Any], key: str, kind: str) -> None:
            seen: dict[Any, str] = {}
            for item in items:
                k = getattr(item, key)
                if k in seen:
                    raise ValueError(f"{kind} {item.name!r} repeats {key} {k!r} of {seen[k]!r}")
                seen[k] = item.name

        for items, kind in ((self.commands, "command"), (self.telemetry, "telemetry packet"),
                            (self.events, "event")):  # fmt: skip
            unique(items, "name", kind)
            unique(items, "opcode", kind)
        unique(self.errors, "code", "error")
        unique(self.errors, "name", "error")

        tlm = {p.name: p for p in self.telemetry}
        for cmd in self.commands:
            if cmd.response_from_telemetry is not None:
                if cmd.response:
                    raise ValueError(
                        f"command {cmd.name}: give response or response_from_telemetry"
                    )
                if cmd.response_from_telemetry not in tlm:
                    raise ValueError(
                        f"command {cmd.name}: no telemetry packet {cmd.response_from_telemetry!r}"
                    )
                cmd.response = list(tlm[cmd.response_from_telemetry].fields)
            _check_layout(cmd.request, f"command {cmd.name} request")
            _check_layout(cmd.response, f"command {cmd.name} response")
        for pkt in [*self.telemetry, *self.events]:
            _check_layout(pkt.fields, f"packet {pkt.name}")

        self._commands_by_name = {c.name: c for c in self.commands}
        self._commands_by_opcode = {c.opcode: c for c in self.commands}
        self._telemetry_by_opcode = {p.opcode: p for p in self.telemetry}
        self._events_by_opcode = {p.opcode: p for p in self.events}
        self._errors_by_code = {e.code: e for e in self.errors}
        return self

    def command(self, key: str | int) -> CommandSpec:
        """Look a command up by name or opcode; KeyError with the known names otherwise."""
        found = (
            self._commands_by_name.get(key)
            if isinstance(key, str)
            else self._commands_by_opcode.get(key)
        )
        if found is None:
            known = ", ".join(self._commands_by_name)
            raise KeyError(f"unknown command {key!r}; the dictionary has: {known}")
        return found

    def command_for_opcode(self, opcode: int) -> CommandSpec | None:
        return self._commands_by_opcode.get(opcode)

    def telemetry_packet(self, key: str | int) -> PacketSpec:
        return self._lookup_packet(
            self.telemetry, self._telemetry_by_opcode, key, "telemetry packet"
        )

    def event(self, key: str | int) -> PacketSpec:
        return self._lookup_packet(self.events, self._events_by_opcode, key, "event")

    @staticmethod
    def _lookup_packet(
        items: list[PacketSpec], by_opcode: dict[int, PacketSpec], key: str | int, kind: str
    ) -> PacketSpec:
        if isinstance(key, int):
            if key in by_opcode:
                return by_opcode[key]
        else:
            for p in items:
                if p.name == key:
                    return p
        raise KeyError(f"unknown {kind} {key!r}")

    def error(self, key: str | int) -> ErrorSpec:
        """Look an error up by name or code."""
        if isinstance(key, int):
            if key in self._errors_by_code:
                return self._errors_by_code[key]
        else:
            for e in self.errors:
                if e.name == key:
                    return e
        raise KeyError(f"unknown error {key!r}")

    def describe_error(self, code: int, detail: str = "") -> str:
        """The words a user sees for a NAK: name, code, meaning and the device's detail."""
        try:
            spec = self.error(code)
            text = f"{spec.name} ({code}): {spec.message}"
        except KeyError:
            text = f"error code {code} (not in the dictionary)"
        return f"{text}: {detail}" if detail else text

    def encode_nak(self, error: str | int, detail: str = "") -> bytes:
        """NAK payload: u16 error code, then UTF-8 detail text (truncated to fit)."""
        code = self.error(error).code
        room = MAX_PAYLOAD - _NAK_HEADER.size
        # Cut at a character boundary so that the truncated detail still decodes cleanly.
        text = detail.encode()[:room].decode(errors="ignore").encode()
        return _NAK_HEADER.pack(code) + text

    @staticmethod
    def decode_nak(payload: bytes) -> tuple[int, str]:
        """Return (error code, detail) of a NAK payload."""
        if len(payload) < _NAK_HEADER.size:
            raise PayloadError(f"NAK payload of {len(payload)} bytes has no error code")
        (code,) = _NAK_HEADER.unpack_from(payload)
        return code, payload[_NAK_HEADER.size :].decode(errors="replace")


def load_dictionary(path: Path | str | None = None) -> Dictionary:
    """Load and validate a dictionary file (default: the shipped config/protocol.toml)."""
    file = config_dir() / "protocol.toml" if path is None else Path(path)
    try:
        return _DICTIONARIES.shipped(file) if path is None else _DICTIONARIES.load(file)
    except OSError as exc:
        raise DictionaryError(
            file, None, f"cannot read the command dictionary: {exc.strerror or exc}"
        ) from None


_DICTIONARIES = DataFileKind(
    Dictionary,
    DictionaryError,
    # Entries of the dictionary's arrays are called by their names in its errors.
    named={k: f"{k.rstrip('s')} {{}}" for k in ("errors", "commands", "telemetry", "events")},
)
