"""RS-422 frame codec: pure bytes in, frames out (sans-I/O; see docs/protocol.md).

Wire layout (big-endian)::

    offset  size  field
    0       2     sync word 0xEB 0x90
    2       1     type      (FrameType)
    3       1     sequence  0..255
    4       1     opcode
    5       2     payload length n, 0..MAX_PAYLOAD
    7       n     payload
    7+n     2     CRC-16/CCITT-FALSE over bytes 2 .. 7+n-1 (everything after the sync word)

The decoder accepts any chunking of the byte stream, resynchronises after garbage by scanning
for the next sync word, and never raises on malformed input: it counts what it dropped.
"""

from __future__ import annotations

import binascii
import enum
import struct
from dataclasses import dataclass, field

SYNC = b"\xeb\x90"
HEADER_SIZE = 7  # sync(2) + type(1) + seq(1) + opcode(1) + length(2)
CRC_SIZE = 2
OVERHEAD = HEADER_SIZE + CRC_SIZE
MAX_PAYLOAD = 1024

_HEADER = struct.Struct(">2sBBBH")
_CRC = struct.Struct(">H")


class FrameType(enum.IntEnum):
    """The frame's type byte."""

    COMMAND = 0x01
    ACK = 0x02
    NAK = 0x03
    TELEMETRY = 0x04
    EVENT = 0x05


_VALID_TYPES = frozenset(int(t) for t in FrameType)


def crc16(data: bytes) -> int:
    """CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection, no final xor)."""
    return binascii.crc_hqx(data, 0xFFFF)


@dataclass(frozen=True, slots=True)
class Frame:
    """One decoded (or to-be-encoded) frame."""

    type: FrameType
    seq: int
    opcode: int
    payload: bytes = b""

    def encode(self) -> bytes:
        """Return the frame's wire bytes."""
        return encode_frame(self.type, self.seq, self.opcode, self.payload)


def encode_frame(type_: FrameType, seq: int, opcode: int, payload: bytes = b"") -> bytes:
    """Build one wire frame; raises ValueError for a field that does not fit its width."""
    if not 0 <= seq <= 0xFF:
        raise ValueError(f"sequence number {seq} does not fit in 8 bits (0..255)")
    if not 0 <= opcode <= 0xFF:
        raise ValueError(f"opcode {opcode} does not fit in 8 bits (0..255)")
    if len(payload) > MAX_PAYLOAD:
        raise ValueError(f"payload of {len(payload)} bytes exceeds the maximum of {MAX_PAYLOAD}")
    head = _HEADER.pack(SYNC, int(type_), seq, opcode, len(payload))
    body = head[2:] + payload
    return SYNC + body + _CRC.pack(crc16(body))


@dataclass(slots=True)
class DecoderStats:
    """What the decoder consumed and why it dropped what it dropped."""

    bytes_in: int = 0
    frames: int = 0
    crc_errors: int = 0
    bad_type: int = 0
    oversize: int = 0
    resyncs: int = 0
    bytes_dropped: int = 0
    partial_flushes: int = 0

    def as_dict(self) -> dict[str, int]:
        return {name: getattr(self, name) for name in self.__slots__}


@dataclass(slots=True)
class Decoder:
    """Incremental frame decoder.

    ``feed(chunk)`` returns the frames completed by that chunk, in order. A candidate frame
    that fails a check (unknown type, length above ``max_payload``, bad CRC) costs one byte:
    the scan restarts one byte after its sync word, so a real frame hidden inside the bytes
    of a false candidate is still found.
    """

    max_payload: int = MAX_PAYLOAD
    stats: DecoderStats = field(default_factory=DecoderStats)
    _buf: bytearray = field(default_factory=bytearray)
    _head_offset: int = -1
    _head_since_s: float = 0.0

    @property
    def pending(self) -> int:
        """Bytes held waiting for the rest of a frame."""
        return len(self._buf)

    @property
    def head_since_s(self) -> float | None:
        """When the candidate frame now waiting at the head got there (None if none waits)."""
        return self._head_since_s if self._buf else None

    def feed(self, data: bytes, now_s: float = 0.0) -> list[Frame]:
        """Consume a chunk of the byte stream; return the frames it completed.

        ``now_s`` (any monotonic clock) dates the candidate frame left waiting at the head of
        the buffer, for ``expire``; callers that never call ``expire`` may omit it."""
        self.stats.bytes_in += len(data)
        self._buf += data
        frames = self._drain()
        self._date_head(now_s)
        return frames

    def expire(self, now_s: float, max_age_s: float) -> list[Frame]:
        """Flush a candidate frame that has waited at the head longer than ``max_age_s``.

        A bit error in a length field makes the decoder wait for bytes that belong to later
        frames. An idle-line timeout alone does not catch that while traffic keeps arriving
        (retries every few tens of ms keep the line busy), so the age is measured from when the
        candidate reached the head, whatever arrived since. ``max_age_s`` should exceed the
        time a maximum-size frame takes on the line."""
        if not self._buf or now_s - self._head_since_s <= max_age_s:
            return []
        frames = self.flush_partial()
        self._date_head(now_s)
        return frames

    def flush_partial(self) -> list[Frame]:
        """Give up on a stalled partial frame (the transport saw an inter-byte timeout).

        A bit error in the length field can make the decoder wait for bytes that never come;
        the transport calls this when the line has gone idle with bytes pending. The stalled
        candidate's sync byte is dropped and the rest is scanned again; any complete frames the
        false candidate was hiding are returned."""
        if not self._buf:
            return []
        self.stats.partial_flushes += 1
        self._drop(1)
        return self._drain()

    def _date_head(self, now_s: float) -> None:
        if not self._buf:
            # Nothing waits: the next byte to arrive starts a new head and must be dated then,
            # not when the buffer emptied (that would age a fresh frame by the idle time).
            self._head_offset = -1
            return
        head = self.stats.bytes_in - len(self._buf)  # stream offset of the first pending byte
        if head != self._head_offset:
            self._head_offset = head
            self._head_since_s = now_s

    def _drop(self, n: int) -> None:
        del self._buf[:n]
        self.stats.bytes_dropped += n

    def _drain(self) -> list[Frame]:
        out: list[Frame] = []
        buf = self._buf
        while buf:
            start = buf.find(SYNC)
            if start < 0:
                # Keep a trailing first sync byte: its partner may be in the next chunk.
                keep = 1 if buf[-1] == SYNC[0] else 0
                if len(buf) > keep:
                    self.stats.resyncs += 1
                    self._drop(len(buf) - keep)
                break
            if start > 0:
                self.stats.resyncs += 1
                self._drop(start)
            if len(buf) < HEADER_SIZE:
                break
            _, type_, seq, opcode, length = _HEADER.unpack_from(buf)
            if type_ not in _VALID_TYPES:
                self.stats.bad_type += 1
                self._drop(1)
                continue
            if length > self.max_payload:
                self.stats.oversize += 1
                self._drop(1)
                continue
            end = HEADER_SIZE + length + CRC_SIZE
            if len(buf) < end:
                break
            (crc,) = _CRC.unpack_from(buf, end - CRC_SIZE)
            if crc16(bytes(buf[2 : end - CRC_SIZE])) != crc:
                self.stats.crc_errors += 1
                self._drop(1)
                continue
            out.append(
                Frame(FrameType(type_), seq, opcode, bytes(buf[HEADER_SIZE : end - CRC_SIZE]))
            )
            del buf[:end]
            self.stats.frames += 1
        return out
