"""Request and response bodies of the HTTP API (docs/api.md), as pydantic models.

These are the contract clients build against: FastAPI publishes them in /openapi.json, and
``camd.client`` parses responses with them. Requests forbid unknown keys so that a typo is a
400 naming the key rather than a silently ignored parameter.
"""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

Mode = Literal["area", "tdi"]
StateName = Literal["disconnected", "idle", "imaging", "fault"]
LimitLevel = Literal["ok", "yellow", "red"]

PING_COUNT_MAX = 100_000
PING_SIZE_MAX = 256
HISTORY_LIMIT_MAX = 1_000_000
EVENTS_LIMIT_MAX = 100_000


class _Request(BaseModel):
    model_config = ConfigDict(extra="forbid")


class PingRequest(_Request):
    """POST /api/v1/ping."""

    count: int = Field(default=10, ge=1, le=PING_COUNT_MAX, description="number of PINGs")
    size: int = Field(default=16, ge=0, le=PING_SIZE_MAX, description="payload bytes per PING")


class ModeRequest(_Request):
    """POST /api/v1/mode."""

    mode: Mode = Field(description="area (staring, for focusing) or tdi (push-broom)")


# Words for the allowed values of each request parameter, used in 400 messages.
ALLOWED: dict[str, str] = {
    "count": f"an integer in 1..{PING_COUNT_MAX}",
    "size": f"an integer in 0..{PING_SIZE_MAX} (bytes)",
    "mode": "area or tdi",
    "channel": "a telemetry channel name (GET /api/v1/telemetry lists them)",
    "since_s": "a Unix time in seconds, or a negative number of seconds before now",
    "limit": (
        f"an integer in 1..{HISTORY_LIMIT_MAX} for telemetry/history, "
        f"1..{EVENTS_LIMIT_MAX} for events"
    ),
}


class ErrorResponse(BaseModel):
    """The body of every error response."""

    error: str = Field(description="what went wrong and what to change")
    code: str = Field(
        description="bad_request, unauthorized, illegal_state, link_untrained, device_nak, "
        "disconnected, timeout"
    )


class LinkInfo(BaseModel):
    """The link part of the status."""

    port: str = Field(description="serial device, pyserial URL, or the simulator's pty link")
    connected: bool
    last_error: str | None = Field(default=None, description="why the port is not open")
    sim_pid: int | None = Field(
        default=None, description="pid of the simulator this daemon spawned, while it runs"
    )


class DeviceStatus(BaseModel):
    """GET_STATUS fields, as the device reported them."""

    mode: Mode
    device_state: Literal["idle", "busy", "fault"]
    fault_code: int = Field(description="error code of the active fault, 0 if none")
    uptime_s: float = Field(description="time since power-on or RESET")
    fw_version: int = Field(description="firmware version, major * 256 + minor")
    boot_count: int


class DaemonInfo(BaseModel):
    """The daemon process."""

    version: str
    pid: int
    uptime_s: float


class StatusResponse(BaseModel):
    """GET /api/v1/status and POST /api/v1/reset."""

    state: StateName
    reason: str | None = Field(description="why the daemon is in this state (null when idle)")
    mode: Mode | None = Field(description="imaging mode last known, null before first contact")
    link: LinkInfo
    device: DeviceStatus | None = Field(description="null when the device cannot be asked")
    daemon: DaemonInfo


class RttMs(BaseModel):
    """Round-trip times of the successful PINGs, milliseconds (null if none succeeded)."""

    p50: float | None
    p99: float | None
    max: float | None


class PingResponse(BaseModel):
    """POST /api/v1/ping."""

    count: int
    ok: int
    failed: int
    retries: int = Field(description="re-sends needed, summed over all PINGs")
    rtt_ms: RttMs
    errors: list[str] = Field(description="up to 5 distinct failure reasons")


class DeviceLinkStats(BaseModel):
    """GET_LINK_STATS fields, plus the simulator's injected faults (null on hardware)."""

    rx_frames: int
    crc_errors: int
    resyncs: int
    bytes_dropped: int
    executed: int
    replayed: int
    nacked: int
    tx_frames: int
    injected: dict[str, int] | None


class LinkResponse(BaseModel):
    """GET /api/v1/link."""

    host: dict[str, int] = Field(description="host-side link counters")
    device: DeviceLinkStats | None = Field(description="null when the device cannot be asked")


class ChannelLatest(BaseModel):
    """The newest sample of one channel."""

    value: float
    unit: str
    t_s: float = Field(description="Unix time of the sample, seconds")
    limit: LimitLevel


class TelemetryResponse(BaseModel):
    """GET /api/v1/telemetry."""

    latest: dict[str, ChannelLatest]
    samples: int = Field(description="samples in the archive")
    archive: str = Field(description="path of the SQLite archive")


class HistoryResponse(BaseModel):
    """GET /api/v1/telemetry/history."""

    channel: str
    unit: str
    t_s: list[float]
    value: list[float]


class EventItem(BaseModel):
    """One event."""

    t_s: float
    level: Literal["info", "warning", "error"]
    source: str
    message: str


class EventsResponse(BaseModel):
    """GET /api/v1/events."""

    events: list[EventItem] = Field(description="newest last")


class ModeResponse(BaseModel):
    """POST /api/v1/mode."""

    mode: Mode


# -- sensor registers, timing, link training, imaging -----------------------------------------

RegisterValue = int | str


class RegisterReading(BaseModel):
    """One register as read: raw value and its fields (enum fields by name)."""

    name: str
    address: int
    value: int
    fields: dict[str, RegisterValue]


class RegistersResponse(BaseModel):
    """GET /api/v1/registers: every register of the map, in address order."""

    sensor: str
    bridge: str
    registers: list[RegisterReading]


class RegisterWriteRequest(_Request):
    """POST /api/v1/registers: values by name (REG, REG.field or a group such as EXPOSURE)."""

    values: dict[str, RegisterValue] = Field(
        min_length=1, description="name -> raw integer (or enum name for an enum field)"
    )


class RegisterWriteResponse(BaseModel):
    """The registers written, as read back after the write (verified where the map allows)."""

    sensor: str
    written: list[RegisterReading]


class RegisterDiffRequest(_Request):
    """POST /api/v1/registers/diff: compare against reset values or given register values."""

    against: Literal["reset", "values"] = Field(default="reset")
    values: dict[str, int] | None = Field(
        default=None, description="register name -> expected raw value (with against = values)"
    )


class RegisterDifference(BaseModel):
    name: str
    address: int
    expected: int
    actual: int


class RegisterDiffResponse(BaseModel):
    sensor: str
    against: str
    differences: list[RegisterDifference]


class RegisterConfig(BaseModel):
    """A whole sensor configuration: the configurable (RW/WO, non-volatile) registers."""

    model_config = ConfigDict(extra="forbid")

    sensor: str
    registers: dict[str, int]


class TimingResponse(BaseModel):
    """GET /api/v1/timing: the sensor timing its registers set (physics.md §2, §3)."""

    sensor: str
    line_period_s: float
    window_start_row: int
    window_rows: int
    exposure_lines: int
    exposure_s: float
    frame_time_s: float
    frame_period_s: float
    back_path_s: float
    tdi_line_period_s: float
    max_stages: int
    gain: RegisterValue | None = None
    offset: RegisterValue | None = None
    readout_mode: RegisterValue | None = None
    test_pattern: RegisterValue | None = None


class LaneResult(BaseModel):
    lane: int
    tap: int
    eye_width: int
    slips: int
    shift: int
    locked: bool


class TrainResponse(BaseModel):
    """POST/GET /api/v1/train: the last LVDS link training."""

    sensor: str
    interface: str
    trained: bool = Field(description="locked on every lane and the PRBS check error-free")
    lanes: int
    locked_lanes: int
    locked: bool
    bit_errors: int
    verified_bits: int
    lane_results: list[LaneResult]
    t_s: float | None = Field(description="Unix time of the training; None if never trained")


class ImagingRequest(_Request):
    """POST /api/v1/imaging/start."""

    frames: int = Field(default=0, ge=0, le=0xFFFF_FFFF, description="0 = continuous")


class ImagingResponse(BaseModel):
    imaging: bool
    frames: int
