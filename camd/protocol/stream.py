"""Frame stream format: the 64-byte window-frame header and its payload (sans-I/O; docs/stream.md).

Every window frame on the USB bulk stream is one 64-byte little-endian header followed by
``rows * cols`` little-endian uint16 pixels::

    offset  size  field
    0       4     magic b"CAMF"
    4       2     version (1)
    6       2     header_bytes (64)
    8       4     counter, wraps at 2**32
    12      8     timestamp_ns: device clock, end of window row 0's exposure
    20      4     line_period_ns: TDI line period = frame period
    24      2     rows
    26      2     cols
    28      1     bits: significant bits per pixel (1 .. 16)
    29      1     mode (StreamMode)
    30      2     stages: TDI stage count configured, 0 in area mode
    32      4     stage_position: scan-stage encoder count at frame start (signed), 0 if none
    36      4     flags (FrameFlags)
    40      4     payload_bytes = rows * cols * 2
    44      4     payload_crc32: zlib.crc32 of the payload
    48      12    reserved, zero
    60      4     header_crc32: zlib.crc32 of bytes 0 .. 59

No sockets, no threads: bytes in, headers out. The transport is ``camd.link.frame_stream``.
"""

from __future__ import annotations

import enum
import struct
from typing import NamedTuple

import numpy as np
from zlib_ng import zlib_ng

MAGIC = b"CAMF"
VERSION = 1
HEADER_BYTES = 64
MAX_BITS = 16
U32_WRAP = 1 << 32  # the frame counter's modulus

# The whole header but its trailing CRC; "12x" keeps the reserved bytes zero on encode.
_BODY = struct.Struct("<4sHHIQIHHBBHiIII12x")
_HEADER_CRC = struct.Struct("<I")
_CRC_OFFSET = _BODY.size  # 60
_RESERVED = slice(48, 60)
assert _CRC_OFFSET + _HEADER_CRC.size == HEADER_BYTES

BytesLike = bytes | bytearray | memoryview


# The same CRC-32 as zlib.crc32 (IEEE 802.3, reflected, init and final XOR 0xFFFFFFFF), from
# zlib-ng: about 15x faster here than the zlib CPython links, which would otherwise cost the
# ingest a quarter of its throughput (docs/stream.md, "Throughput").
crc32 = zlib_ng.crc32

# zlib-ng (like zlib) lets go of Python's GIL for a buffer over 5 KiB. For a large frame that
# lets the reader go on while the dispatcher checks it; for a small one, taking the GIL back
# costs a thread hand-over (tens of microseconds when the reader holds it) where the CRC
# itself takes well under one. So payloads up to SMALL_PAYLOAD_BYTES are checked in pieces
# that keep the GIL.
SMALL_PAYLOAD_BYTES = 64 << 10
_GIL_PIECE_BYTES = 4 << 10


def payload_crc32(payload: memoryview) -> int:
    """``crc32(payload)`` (a 1-D byte view), computed without letting go of Python's GIL if
    the payload is small (``SMALL_PAYLOAD_BYTES``): the dispatcher's per-frame check."""
    n = payload.nbytes
    if n > SMALL_PAYLOAD_BYTES:
        return crc32(payload)
    crc = 0
    for start in range(0, n, _GIL_PIECE_BYTES):
        crc = crc32(payload[start : start + _GIL_PIECE_BYTES], crc)
    return crc


class StreamFormatError(ValueError):
    """A frame header (or payload) breaks the stream format; the message names field and values."""


class StreamMode(enum.IntEnum):
    """The header's mode byte."""

    AREA = 0  # staring: every frame is a snapshot of the window
    TDI = 1  # push-broom: the host accumulates frames along the scan


class FrameFlags(enum.IntFlag):
    """The header's flag bits."""

    BINNED_2X2 = 1 << 0
    TEST_PATTERN = 1 << 1
    SATURATED = 1 << 2  # some pixel is at the ADC maximum
    DEVICE_OVERFLOW = 1 << 3  # the device dropped frames before this one
    LAST = 1 << 4  # the last frame of a counted stream


_KNOWN_FLAGS = int(
    FrameFlags.BINNED_2X2
    | FrameFlags.TEST_PATTERN
    | FrameFlags.SATURATED
    | FrameFlags.DEVICE_OVERFLOW
    | FrameFlags.LAST
)

# (field, lowest, highest) of the unsigned and signed integer fields, for encode's checks.
_RANGES: tuple[tuple[str, int, int], ...] = (
    ("counter", 0, U32_WRAP - 1),
    ("timestamp_ns", 0, (1 << 64) - 1),
    ("line_period_ns", 0, U32_WRAP - 1),
    ("rows", 1, 0xFFFF),
    ("cols", 1, 0xFFFF),
    ("bits", 1, MAX_BITS),
    ("stages", 0, 0xFFFF),
    ("stage_position", -(1 << 31), (1 << 31) - 1),
    ("payload_bytes", 0, U32_WRAP - 1),
    ("payload_crc32", 0, U32_WRAP - 1),
)


class FrameHeader(NamedTuple):
    """One window frame's header (everything but magic, version, sizes and the header CRC).

    A named tuple, not a dataclass: the host decodes one per frame, tens of thousands a
    second at the smallest windows, and a tuple is built in a fraction of the time. Change a
    field with ``header._replace(flags=...)``."""

    counter: int
    timestamp_ns: int
    line_period_ns: int
    rows: int
    cols: int
    bits: int
    mode: StreamMode
    stages: int
    stage_position: int
    flags: FrameFlags
    payload_bytes: int
    payload_crc32: int

    @property
    def frame_bytes(self) -> int:
        """Header plus payload: the size of the frame's USB transfer."""
        return HEADER_BYTES + self.payload_bytes


def encode_header(h: FrameHeader) -> bytes:
    """The header's 64 wire bytes; ValueError naming the field if a value does not fit."""
    for name, lo, hi in _RANGES:
        value = getattr(h, name)
        if not lo <= value <= hi:
            raise StreamFormatError(f"header field {name} = {value} is outside {lo} .. {hi}")
    if int(h.flags) & ~_KNOWN_FLAGS:
        raise StreamFormatError(f"flags = 0x{int(h.flags):X} has bits outside 0x{_KNOWN_FLAGS:X}")
    _check_semantics(h)
    return pack_header(h)


def pack_header(h: FrameHeader) -> bytes:
    """``encode_header`` without its checks, for a header known to be valid (made by
    ``frame_header``, its flags since changed to known ones): a sender's per-frame path."""
    body = _BODY.pack(
        MAGIC,
        VERSION,
        HEADER_BYTES,
        h.counter,
        h.timestamp_ns,
        h.line_period_ns,
        h.rows,
        h.cols,
        h.bits,
        int(h.mode),
        h.stages,
        h.stage_position,
        int(h.flags),
        h.payload_bytes,
        h.payload_crc32,
    )
    return body + _HEADER_CRC.pack(crc32(body))


def decode_header(buf: BytesLike) -> FrameHeader:
    """Parse and check the first 64 bytes of ``buf``.

    Raises StreamFormatError, in this order of checks: too few bytes, bad magic, version,
    header size, header CRC, reserved bytes, mode, bits, flags, rows/cols, stages,
    payload_bytes != rows * cols * 2."""
    if len(buf) < HEADER_BYTES:
        raise StreamFormatError(f"a frame header is {HEADER_BYTES} bytes, got {len(buf)}")
    (
        magic,
        version,
        header_bytes,
        counter,
        timestamp_ns,
        line_period_ns,
        rows,
        cols,
        bits,
        mode,
        stages,
        stage_position,
        flags,
        payload_bytes,
        payload_crc32,
    ) = _BODY.unpack_from(buf)
    if magic != MAGIC:
        raise StreamFormatError(f"magic is {bytes(magic)!r}, expected {MAGIC!r}")
    if version != VERSION:
        raise StreamFormatError(f"version is {version}, this host reads version {VERSION}")
    if header_bytes != HEADER_BYTES:
        raise StreamFormatError(f"header_bytes is {header_bytes}, expected {HEADER_BYTES}")
    (stored,) = _HEADER_CRC.unpack_from(buf, _CRC_OFFSET)
    # The CRC runs on a view of the caller's buffer: no copy of the header.
    computed = crc32(memoryview(buf)[:_CRC_OFFSET])
    if stored != computed:
        raise StreamFormatError(
            f"header_crc32 is 0x{stored:08X}, the header's bytes 0..59 give 0x{computed:08X}"
        )
    if memoryview(buf)[_RESERVED] != _NO_RESERVED:
        raise StreamFormatError("reserved bytes 48..59 are not zero (version 1 has none set)")
    if mode not in _MODES:
        raise StreamFormatError(f"mode is {mode}, expected 0 (area) or 1 (tdi)")
    if not 1 <= bits <= MAX_BITS:
        raise StreamFormatError(f"bits is {bits}, expected 1 .. {MAX_BITS}")
    if flags & ~_KNOWN_FLAGS:
        raise StreamFormatError(f"flags = 0x{flags:X} has bits outside 0x{_KNOWN_FLAGS:X}")
    header = FrameHeader(
        counter,
        timestamp_ns,
        line_period_ns,
        rows,
        cols,
        bits,
        _MODES[mode],
        stages,
        stage_position,
        _FLAGS[flags],
        payload_bytes,
        payload_crc32,
    )
    _check_semantics(header)
    return header


_MODES = {int(m): m for m in StreamMode}
# Every combination of the known flag bits, made once (an IntFlag costs more to make than
# to look up).
_FLAGS = {bits: FrameFlags(bits) for bits in range(_KNOWN_FLAGS + 1) if not bits & ~_KNOWN_FLAGS}
_NO_RESERVED = bytes(_RESERVED.stop - _RESERVED.start)


def _check_semantics(h: FrameHeader) -> None:
    if h.rows < 1 or h.cols < 1:
        raise StreamFormatError(f"rows x cols is {h.rows} x {h.cols}; a window is at least 1 x 1")
    if h.mode == StreamMode.AREA and h.stages != 0:
        raise StreamFormatError(f"stages is {h.stages} in area mode, expected 0")
    if h.mode == StreamMode.TDI and h.stages < 1:
        raise StreamFormatError("stages is 0 in tdi mode, expected at least 1")
    expected = h.rows * h.cols * 2
    if h.payload_bytes != expected:
        raise StreamFormatError(
            f"payload_bytes is {h.payload_bytes}, but rows x cols = {h.rows} x {h.cols} "
            f"uint16 pixels is {expected}"
        )


def frame_header(
    pixels: np.ndarray,
    *,
    counter: int,
    timestamp_ns: int,
    line_period_ns: int,
    bits: int,
    mode: StreamMode,
    stages: int = 0,
    stage_position: int = 0,
    flags: FrameFlags | int = 0,
) -> FrameHeader:
    """The header for ``pixels`` (rows x cols, uint16, C order): sizes and payload CRC computed.

    ``counter`` is taken modulo 2**32. ValueError if ``pixels`` is not a C-contiguous 2-D
    little-endian uint16 array (a silent copy would hide its cost from the stream engine)."""
    if pixels.ndim != 2 or pixels.dtype != np.dtype("<u2"):
        raise StreamFormatError(
            f"pixels must be a 2-D little-endian uint16 array, got {pixels.ndim}-D {pixels.dtype}"
        )
    if not pixels.flags.c_contiguous:
        raise StreamFormatError("pixels must be C-contiguous (np.ascontiguousarray)")
    rows, cols = pixels.shape
    header = FrameHeader(
        counter=counter % U32_WRAP,
        timestamp_ns=timestamp_ns,
        line_period_ns=line_period_ns,
        rows=rows,
        cols=cols,
        bits=bits,
        mode=StreamMode(mode),
        stages=stages,
        stage_position=stage_position,
        flags=FrameFlags(flags),
        payload_bytes=pixels.nbytes,
        payload_crc32=crc32(pixels.data),
    )
    encode_header(header)  # every field checked now, not when the frame is sent
    return header


def payload_ok(header: FrameHeader, payload: BytesLike | np.ndarray) -> bool:
    """True if ``payload`` has the header's size and CRC."""
    view = payload.data if isinstance(payload, np.ndarray) else memoryview(payload)
    return view.nbytes == header.payload_bytes and crc32(view) == header.payload_crc32
