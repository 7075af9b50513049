"""The command link as docs/protocol.md §1 to §4 describe it, payloads laid out by the
dictionary a vendor gets (config/protocol.toml).

Nothing here comes from camd's code: the frame layout is §1's table, the CRC is §1 "CRC"
(CRC-16/CCITT-FALSE; `binascii.crc_hqx(data, 0xFFFF)` as the document says), the receiver is
§3's six rules, the payload types are §1 "Payload fields".
"""

from __future__ import annotations

import binascii
import math
import struct
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[2]
PROTOCOL_TOML = REPO / "config" / "protocol.toml"

SYNC = b"\xeb\x90"
HEADER_BYTES = 7  # sync word, type, sequence number, opcode, payload length
MAX_PAYLOAD = 1024
COMMAND, ACK, NAK, TELEMETRY, EVENT = 1, 2, 3, 4, 5
FRAME_TYPES = (COMMAND, ACK, NAK, TELEMETRY, EVENT)

_INT_FORMATS = {
    "u8": ">B", "u16": ">H", "u32": ">I", "u64": ">Q",
    "i8": ">b", "i16": ">h", "i32": ">i", "i64": ">q",
}  # fmt: skip


def crc16(data: bytes) -> int:
    """§1 CRC: CRC-16/CCITT-FALSE (0x1021, initial 0xFFFF, not reflected, no final XOR)."""
    return binascii.crc_hqx(data, 0xFFFF)


@dataclass(frozen=True, slots=True)
class Frame:
    """One frame of §1: type, sequence number, opcode, payload."""

    type: int
    seq: int
    opcode: int
    payload: bytes = b""

    def encode(self) -> bytes:
        """The frame's bytes: sync word, header, payload, CRC of everything after the sync."""
        body = struct.pack(">BBBH", self.type, self.seq, self.opcode, len(self.payload))
        body += self.payload
        return SYNC + body + struct.pack(">H", crc16(body))


@dataclass(slots=True)
class ReceiverCounters:
    """The receiver's counts that GET_LINK_STATS reports (§3's table, §5 GET_LINK_STATS)."""

    frames: int = 0
    crc_errors: int = 0
    resyncs: int = 0
    bytes_dropped: int = 0


class Receiver:
    """§3 "Receiving: resynchronisation", rules 1 to 6 (rule 5 with ``expire``)."""

    def __init__(self) -> None:
        self.buffer = bytearray()
        self.counters = ReceiverCounters()
        self._head_since_s: float | None = None  # when the candidate at the head arrived

    def feed(self, data: bytes, now_s: float) -> list[Frame]:
        """Bytes in, valid frames out (in order)."""
        self.buffer += data
        frames: list[Frame] = []
        while True:
            start = self.buffer.find(SYNC)
            if start < 0:
                # Rule 1: drop what cannot start a frame; a trailing EB may be half a sync word.
                keep = 1 if self.buffer.endswith(SYNC[:1]) else 0
                self._drop(len(self.buffer) - keep)
                break
            if start:
                self._drop(start)
            if len(self.buffer) < HEADER_BYTES:
                break
            kind, length = self.buffer[2], struct.unpack(">H", self.buffer[5:7])[0]
            if kind not in FRAME_TYPES or length > MAX_PAYLOAD:
                self._reject()  # rule 2, from the header alone
                continue
            total = HEADER_BYTES + length + 2
            if len(self.buffer) < total:
                if self._head_since_s is None:
                    self._head_since_s = now_s
                break
            body = bytes(self.buffer[2 : HEADER_BYTES + length])
            sent_crc = struct.unpack(">H", self.buffer[HEADER_BYTES + length : total])[0]
            if crc16(body) != sent_crc:
                self.counters.crc_errors += 1
                self._reject()  # rule 3, rule 4: costs one byte
                continue
            frames.append(Frame(body[0], body[1], body[2], body[5:]))
            self.counters.frames += 1
            del self.buffer[:total]
            self._head_since_s = None
        return frames

    def expire(self, now_s: float, max_wait_s: float) -> list[Frame]:
        """Rule 5: a candidate that waited longer than a maximum-size frame takes loses its
        first byte, and the bytes after it are scanned again."""
        since = self._head_since_s
        if since is None or now_s - since <= max_wait_s or not self.buffer:
            return []
        self._reject()
        return self.feed(b"", now_s)

    def _reject(self) -> None:
        self._drop(1)

    def _drop(self, count: int) -> None:
        if count <= 0:
            return
        del self.buffer[:count]
        self.counters.resyncs += 1
        self.counters.bytes_dropped += count
        self._head_since_s = None


# -- payloads ----------------------------------------------------------------------------------


class BadLength(ValueError):
    """The payload's length does not match the command's definition (NAK BAD_LENGTH)."""


class OutOfRange(ValueError):
    """A value outside its enum or range (NAK OUT_OF_RANGE)."""


@dataclass(frozen=True, slots=True)
class Field:
    """One payload field of the dictionary (§1 "Payload fields")."""

    name: str
    type: str
    scale: float | None = None
    enum: dict[str, int] | None = None
    min: float | None = None
    max: float | None = None
    max_len: int = 0

    @property
    def size(self) -> int | None:
        """Bytes on the wire; None for the variable-length ``bytes`` / ``str``."""
        if self.type in ("bytes", "str"):
            return None
        return 4 if self.type == "f32" else struct.calcsize(_INT_FORMATS[self.type])

    def encode(self, value: Any) -> bytes:
        if self.type == "bytes":
            return bytes(value)
        if self.type == "str":
            return str(value).encode()
        if self.enum is not None:
            value = self.enum[value] if isinstance(value, str) else int(value)
        if self.type == "f32":
            return struct.pack(">f", float(value))
        raw = round(float(value) / self.scale) if self.scale else int(value)
        fmt = _INT_FORMATS[self.type]
        bits = struct.calcsize(fmt) * 8
        lo, hi = (-(1 << (bits - 1)), (1 << (bits - 1)) - 1) if self.type[0] == "i" else (
            0, (1 << bits) - 1)  # fmt: skip
        return struct.pack(fmt, min(max(raw, lo), hi))

    def decode(self, data: bytes) -> Any:
        if self.type == "bytes":
            return bytes(data)
        if self.type == "str":
            try:
                return data.decode()
            except UnicodeDecodeError:
                raise OutOfRange(f"{self.name}: not UTF-8") from None
        if self.type == "f32":
            value: Any = struct.unpack(">f", data)[0]
        else:
            value = struct.unpack(_INT_FORMATS[self.type], data)[0]
        if self.enum is not None:
            names = {raw: name for name, raw in self.enum.items()}
            if value not in names:
                raise OutOfRange(f"{self.name}: {value} is none of {sorted(names)}")
            return names[value]
        if self.scale:
            value = value * self.scale
        lo = -math.inf if self.min is None else self.min
        hi = math.inf if self.max is None else self.max
        if self.type == "f32" and (self.min is not None or self.max is not None):
            # A bound as it looks after the trip through binary32 (0.01 is not exact).
            lo, hi = (struct.unpack(">f", struct.pack(">f", b))[0] for b in (lo, hi))
        if not lo <= value <= hi:  # NaN fails too
            raise OutOfRange(f"{self.name}: {value} is outside {lo:g} .. {hi:g}")
        return value


@dataclass(frozen=True, slots=True)
class Layout:
    """A payload: fields in order, the last one possibly variable."""

    fields: tuple[Field, ...] = ()

    def bounds(self) -> tuple[int, int]:
        fixed = sum(f.size or 0 for f in self.fields)
        variable = sum(f.max_len for f in self.fields if f.size is None)
        return fixed, fixed + variable

    def decode(self, payload: bytes) -> dict[str, Any]:
        shortest, longest = self.bounds()
        if not shortest <= len(payload) <= longest:
            raise BadLength(f"{len(payload)} bytes; it takes {shortest} .. {longest}")
        values: dict[str, Any] = {}
        offset = 0
        for f in self.fields:
            size = f.size if f.size is not None else len(payload) - offset
            values[f.name] = f.decode(payload[offset : offset + size])
            offset += size
        return values

    def encode(self, **values: Any) -> bytes:
        return b"".join(f.encode(values[f.name]) for f in self.fields)


@dataclass(frozen=True, slots=True)
class Command:
    name: str
    opcode: int
    request: Layout
    response: Layout


@dataclass(slots=True)
class Dictionary:
    """config/protocol.toml: commands, telemetry, events, errors."""

    commands: dict[int, Command] = field(default_factory=dict)
    by_name: dict[str, Command] = field(default_factory=dict)
    telemetry: dict[str, tuple[int, Layout]] = field(default_factory=dict)
    events: dict[str, tuple[int, Layout]] = field(default_factory=dict)
    errors: dict[str, int] = field(default_factory=dict)

    def nak_payload(self, error: str, detail: str = "") -> bytes:
        """§4 "NAK payload": u16 code, then UTF-8 detail cut at a character boundary."""
        text = detail.encode()[: MAX_PAYLOAD - 2].decode(errors="ignore").encode()
        return struct.pack(">H", self.errors[error]) + text


def _layout(items: list[dict[str, Any]]) -> Layout:
    return Layout(
        tuple(
            Field(
                name=i["name"],
                type=i["type"],
                scale=i.get("scale"),
                enum=i.get("enum"),
                min=i.get("min"),
                max=i.get("max"),
                max_len=int(i.get("max_len", 0)),
            )
            for i in items
        )
    )


def load_dictionary(path: Path = PROTOCOL_TOML) -> Dictionary:
    """The command dictionary as its header comment describes it."""
    data = tomllib.loads(path.read_text())
    d = Dictionary()
    for p in data.get("telemetry", []):
        d.telemetry[p["name"]] = (int(p["opcode"]), _layout(p.get("fields", [])))
    for p in data.get("events", []):
        d.events[p["name"]] = (int(p["opcode"]), _layout(p.get("fields", [])))
    for e in data["errors"]:
        d.errors[e["name"]] = int(e["code"])
    for c in data["commands"]:
        telemetry = c.get("response_from_telemetry")
        response = d.telemetry[telemetry][1] if telemetry else _layout(c.get("response", []))
        command = Command(c["name"], int(c["opcode"]), _layout(c.get("request", [])), response)
        d.commands[command.opcode] = command
        d.by_name[command.name] = command
    return d
