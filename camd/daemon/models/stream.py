"""Bodies of the frame stream's routes: start, acquire, stop, its counters and headers."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, Field

from camd.daemon.models.common import Mode, _Compressed

Binning = Literal["off", "2x2"]


class StreamStartRequest(_Compressed):
    """POST /api/v1/stream/start (returns at once) and /stream/acquire (returns when done)."""

    frames: int = Field(
        default=0, ge=0, le=0xFFFF_FFFF, description="frames to take; 0 = until stopped (start)"
    )
    mode: Mode | None = Field(
        default=None, description="set this imaging mode first; null keeps the current one"
    )
    stages: int | None = Field(
        default=None,
        ge=0,
        le=4096,
        description="TDI stage count recorded with the frames (tdi mode: 1..window rows; "
        "null = all window rows); ignored in area mode",
    )
    binning: Binning = Field(default="off", description="FPGA-side 2x2 binning")
    record: str | None = Field(
        default=None,
        description="new HDF5 file to record the frames to, on the daemon's host: relative = in "
        "<data_dir>/recordings; absolute = inside the data directory or daemon.record_dirs "
        "(docs/api.md, Files); null records nothing",
    )
    timeout_s: float | None = Field(
        default=None,
        gt=0,
        le=86_400,
        description="acquire only: give up after this long (default: twice the expected time "
        "plus 10 s)",
    )


class StreamStats(BaseModel):
    """The host side of the stream: what the reader received and delivered."""

    frames: int = Field(description="frames delivered to consumers, valid and in order")
    bytes: int = Field(description="bytes of delivered frames, headers included")
    lost: int = Field(description="frames never received (gaps in the frame counter)")
    corrupt: int = Field(description="frames with a bad header or payload CRC, discarded")
    short: int = Field(description="frames cut short by the device, discarded")
    overruns: int = Field(description="frames dropped because the queue to consumers was full")
    stalls: int = Field(description="endpoint stalls cleared")
    timeouts: int = Field(description="bulk reads that timed out")
    out_of_order: int = Field(description="frames whose counter went backwards, discarded")
    elapsed_s: float = Field(description="from the first to the last frame received")
    mpix_per_s: float = Field(description="delivered pixel rate")
    mbyte_per_s: float = Field(description="delivered byte rate, 1 MB = 1e6 bytes")


class StreamResponse(BaseModel):
    """GET /api/v1/stream, and the answer of /stream/start, /stop and /acquire."""

    streaming: bool
    mode: Mode | None = Field(description="mode of the current or last stream")
    rows: int = Field(description="rows per frame (after binning)")
    cols: int = Field(description="columns per frame (after binning)")
    bits: int = Field(description="significant bits per pixel")
    stages: int = Field(description="TDI stage count in the frame headers (0 in area mode)")
    binning: Binning
    frame_period_s: float = Field(description="frame period = TDI line period")
    frames_requested: int = Field(description="0 = until stopped")
    first_counter: int
    frames_sent: int | None = Field(description="frames the device says it produced, once ended")
    ended_early: str | None = Field(
        default=None,
        description="why the stream (once ended) ended before all its frames were sent and "
        "delivered: the camera ended it, or went away, or its recording failed; null if it did "
        "not, or was stopped on request",
    )
    frames_not_sent: int = Field(
        default=0,
        description="once ended: frames asked for that the camera did not send, stopped or "
        "ended early (ended_early says why), by its own count or, if it could not say, those "
        "the host never accounted for; 0 for a stream until stopped",
    )
    recording: str | None = Field(description="HDF5 file being (or last) recorded")
    frames_flushed: int = Field(
        default=0,
        description="frames of the recording on disk: what the file keeps if the daemon dies "
        'now (flushed at least once a second; docs/stream.md "Crash safety")',
    )
    stats: StreamStats


class StreamFrameHeader(BaseModel):
    """One frame's header as the host received it (docs/stream.md "Frame format (version 1)"),
    with the payload CRC the host computed."""

    counter: int
    timestamp_ns: int = Field(description="device clock, end of window row 0's exposure")
    line_period_ns: int
    rows: int
    cols: int
    bits: int
    mode: Mode
    stages: int
    stage_position: int
    flags: int
    payload_bytes: int
    payload_crc32: int = Field(description="the header's payload CRC-32")
    payload_crc32_host: int = Field(description="CRC-32 of the payload as the host received it")


class StreamHeadersResponse(BaseModel):
    """GET /api/v1/stream/headers: the first frames of the current or last stream."""

    kept_max: int = Field(description="headers kept per stream (the first ones)")
    frames: list[StreamFrameHeader] = Field(
        description="every frame whose header passed its checks, in order of arrival, "
        "including those the payload CRC then rejected"
    )
