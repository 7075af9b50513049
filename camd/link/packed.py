"""Packed transfers: several whole frames back to back in one USB transfer, checked at once.

At the fastest line rates a frame is a few KiB and comes every few tens of microseconds; one
bulk read, one header decode, one queue hand-over and one consumer call per frame then cost
more CPU than the line period leaves. A streamer that packs (docs/stream.md, "Packed
transfers") puts many frames in one transfer; ``FrameStream`` reads it in one call and this
module checks all its headers in one vectorised numpy pass (``check_frames``: every field
``camd.protocol.stream.decode_header`` checks, the header CRCs by zlib-ng in one loop), and
hands consumers a ``FrameBatch``: a run of consecutive frames as one (k, rows, cols) view.

A ``Run`` is what the reader queues: ``count`` frames of ``stride`` bytes each from ``offset``
in a slot, each accepted by the header checks and the counter bookkeeping, consecutive in the
slot. The dispatcher checks their payload CRCs and splits the run where one fails.
"""

from __future__ import annotations

import array
from dataclasses import dataclass
from typing import Union

import numpy as np
import numpy.typing as npt

from camd.protocol.stream import (
    HEADER_BYTES,
    MAGIC,
    MAX_BITS,
    U32_WRAP,
    VERSION,
    FrameFlags,
    FrameHeader,
    StreamFormatError,
    StreamMode,
    crc32,
    decode_header,
)

# The header's fields at their wire offsets (camd.protocol.stream), for a strided view over
# the headers of a packed transfer.
HEADER_DTYPE = np.dtype(
    {
        "names": [
            "magic",
            "version",
            "header_bytes",
            "counter",
            "timestamp_ns",
            "line_period_ns",
            "rows",
            "cols",
            "bits",
            "mode",
            "stages",
            "stage_position",
            "flags",
            "payload_bytes",
            "payload_crc32",
            "reserved",
            "header_crc32",
        ],
        "formats": [
            "S4",
            "<u2",
            "<u2",
            "<u4",
            "<u8",
            "<u4",
            "<u2",
            "<u2",
            "u1",
            "u1",
            "<u2",
            "<i4",
            "<u4",
            "<u4",
            "<u4",
            ("<u4", 3),
            "<u4",
        ],
        "offsets": [0, 4, 6, 8, 12, 20, 24, 26, 28, 29, 30, 32, 36, 40, 44, 48, 60],
        "itemsize": HEADER_BYTES,
    }
)
Buffer = Union["array.array[int]", bytearray, memoryview]  # what a slot's bytes are
_CRC_SPAN = 60  # the header CRC covers bytes 0 .. 59
_KNOWN_FLAGS = sum(int(flag) for flag in FrameFlags)  # one bit each
_MAGIC_U4 = np.frombuffer(MAGIC, dtype="S4")[0]
_MODES = {int(m): m for m in StreamMode}


def header_fields(buf: Buffer, offset: int, stride: int, count: int) -> npt.NDArray[np.void]:
    """The ``count`` headers at ``offset``, ``offset + stride``, ... of ``buf``, as a
    read-only structured view (no copy)."""
    view = np.ndarray(
        shape=(count,), dtype=HEADER_DTYPE, buffer=buf, offset=offset, strides=(stride,)
    )
    view.flags.writeable = False
    return view


def check_frames(
    buf: memoryview, fields: npt.NDArray[np.void], offset: int, stride: int
) -> npt.NDArray[np.bool_]:
    """Which of the headers in ``fields`` (``header_fields(buf, offset, stride, k)``) pass
    every check of ``decode_header`` and describe a frame of exactly ``stride`` bytes."""
    count = fields.shape[0]
    computed = np.fromiter(
        (crc32(buf[o : o + _CRC_SPAN]) for o in range(offset, offset + count * stride, stride)),
        dtype=np.uint32,
        count=count,
    )
    mode = fields["mode"]
    stages = fields["stages"]
    rows = fields["rows"].astype(np.uint64)
    cols = fields["cols"].astype(np.uint64)
    bits = fields["bits"]
    ok: npt.NDArray[np.bool_] = (
        (fields["magic"] == _MAGIC_U4)
        & (fields["version"] == VERSION)
        & (fields["header_bytes"] == HEADER_BYTES)
        & (fields["header_crc32"] == computed)
        & ~fields["reserved"].any(axis=1)
        & ((fields["flags"] & ~np.uint32(_KNOWN_FLAGS)) == 0)
        & (bits >= 1)
        & (bits <= MAX_BITS)
        & (rows >= 1)
        & (cols >= 1)
        & (((mode == 0) & (stages == 0)) | ((mode == 1) & (stages >= 1)))
        & (fields["payload_bytes"] == rows * cols * 2)
        & (fields["payload_bytes"] == stride - HEADER_BYTES)
    )
    return ok


# Below this many frames a loop of decode_header costs less than the numpy pass (about 35 us
# whatever the count, against 2.4 us a frame).
VECTOR_MIN_FRAMES = 16


def is_plain_run(buf: memoryview, fields: npt.NDArray[np.void], stride: int) -> bool:
    """True if the frames whose headers ``fields`` views (from offset 0, ``stride`` apart)
    are the usual run: every header good, every frame ``stride`` bytes of one shape, the
    counters one apart, LAST on none but the last. Checked in one numpy pass, or by
    ``decode_header`` for a few frames."""
    count = fields.shape[0]
    if count >= VECTOR_MIN_FRAMES:
        counters = fields["counter"].astype(np.int64)
        return bool(
            check_frames(buf, fields, 0, stride).all()
            and (fields["rows"] == fields["rows"][0]).all()
            and ((np.diff(counters) & 0xFFFFFFFF) == 1).all()
            and not (fields["flags"][:-1] & int(FrameFlags.LAST)).any()
        )
    try:
        headers = [
            decode_header(buf[o : o + HEADER_BYTES]) for o in range(0, count * stride, stride)
        ]
    except StreamFormatError:
        return False
    first = headers[0]
    return all(
        h.frame_bytes == stride
        and (h.rows, h.cols) == (first.rows, first.cols)
        and h.counter == (first.counter + i) % U32_WRAP
        and (i == count - 1 or not h.flags & FrameFlags.LAST)
        for i, h in enumerate(headers)
    )


def header_at(fields: npt.NDArray[np.void], i: int) -> FrameHeader:
    """The ``i``-th header of a checked ``fields`` view, as ``decode_header`` gives it."""
    f = fields[i]
    return FrameHeader(
        int(f["counter"]),
        int(f["timestamp_ns"]),
        int(f["line_period_ns"]),
        int(f["rows"]),
        int(f["cols"]),
        int(f["bits"]),
        _MODES[int(f["mode"])],
        int(f["stages"]),
        int(f["stage_position"]),
        FrameFlags(int(f["flags"])),
        int(f["payload_bytes"]),
        int(f["payload_crc32"]),
    )


@dataclass(slots=True)
class Run:
    """``count`` accepted frames of ``stride`` bytes, back to back from ``offset`` in a slot;
    ``fields``: their headers (a view into the slot, valid while the slot is held)."""

    offset: int
    stride: int
    count: int
    fields: npt.NDArray[np.void]


@dataclass(frozen=True, slots=True)
class FrameBatch:
    """Consecutive delivered frames (counters one apart), for a consumer's ``on_batch``.

    ``pixels`` is a read-only (k, rows, cols) uint16 view into the reader's slot, valid only
    during the call: copy what you keep. ``gap_before`` is the number of frames missing
    before the first one (as ``ReceivedFrame.gap_before``; the others follow on);
    ``first_index`` is the first frame's delivery index. ``counters`` and
    ``stage_positions`` are (k,) views of the headers' fields; ``header(i)`` gives a frame's
    whole header.
    """

    pixels: npt.NDArray[np.uint16]
    fields: npt.NDArray[np.void]
    received_ns: int
    gap_before: int
    first_index: int

    @property
    def count(self) -> int:
        return int(self.pixels.shape[0])

    @property
    def counters(self) -> npt.NDArray[np.uint32]:
        return self.fields["counter"]

    @property
    def stage_positions(self) -> npt.NDArray[np.int32]:
        return self.fields["stage_position"]

    def header(self, i: int) -> FrameHeader:
        """The ``i``-th frame's header."""
        return header_at(self.fields, i)


def run_pixels(buf: Buffer, run: Run, start: int, stop: int) -> npt.NDArray[np.uint16]:
    """Frames ``start .. stop - 1`` of ``run`` as a read-only (k, rows, cols) uint16 view."""
    rows = int(run.fields["rows"][0])
    cols = int(run.fields["cols"][0])
    pixels = np.ndarray(
        shape=(stop - start, rows, cols),
        dtype="<u2",
        buffer=buf,
        offset=run.offset + start * run.stride + HEADER_BYTES,
        strides=(run.stride, 2 * cols, 2),
    )
    pixels.flags.writeable = False
    return pixels
