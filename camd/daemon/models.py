"""Request and response bodies of the HTTP API (docs/api.md), as pydantic models.

These are the contract clients build against: FastAPI publishes them in /openapi.json, and
``camd.client`` parses responses with them. Requests forbid unknown keys so that a typo is a
400 naming the key rather than a silently ignored parameter.
"""

from __future__ import annotations

import math
import sys
import types
from typing import Any, Literal, Union, get_args, get_origin

import annotated_types
from pydantic import BaseModel, ConfigDict, Field, ValidationInfo, field_validator
from pydantic.fields import FieldInfo

Mode = Literal["area", "tdi"]
StateName = Literal["disconnected", "idle", "streaming", "fault"]
LimitLevel = Literal["ok", "yellow", "red"]

PING_COUNT_MAX = 100_000
PING_SIZE_MAX = 256
HISTORY_LIMIT_MAX = 1_000_000
EVENTS_LIMIT_MAX = 100_000
LIVE_LINES_MAX = 2048  # lines the live view's waterfall keeps, and the most one request gets
LIVE_WAIT_MAX_S = 5.0  # longest a live-view request waits for something newer
ACTIVITY_TEXT_MAX = 200
SCAN_LINE_PERIOD_MAX_S = 10.0  # the longest TDI line period a scan takes, given or implied


FLOAT_NORMAL_MIN = sys.float_info.min
"""The smallest magnitude a request's number may have besides 0 (2.2e-308): below it a float
is subnormal, and what it is turned into (a period from a speed, a rate, a register count)
overflows or loses its precision."""


def _numbers(value: object) -> list[float]:
    """The floats in a field's value, entries of lists and objects included."""
    if isinstance(value, float):
        return [value]
    if isinstance(value, list | tuple):
        return [x for item in value for x in _numbers(item)]
    if isinstance(value, dict):
        return [x for item in value.values() for x in _numbers(item)]
    return []  # a nested request model checks its own fields


class _Request(BaseModel):
    # Strict: a boolean is not an integer and "3" is not a number (a JSON integer is still a
    # number); NaN and infinities are refused. 400 messages give each field's valid values
    # (valid_values below), read from its own type and constraints.
    model_config = ConfigDict(extra="forbid", strict=True, allow_inf_nan=False)

    @field_validator("*", mode="after")
    @classmethod
    def _no_subnormal_numbers(cls, value: Any) -> Any:
        """Every number of every request is 0 or normal: one check for all fields (a speed of
        5e-324 passed "more than 0" and turned into an infinite line period, a 500)."""
        for number in _numbers(value):
            if number != 0.0 and math.isfinite(number) and abs(number) < FLOAT_NORMAL_MIN:
                raise ValueError(
                    f"{number!r} is too small to compute with: a subnormal number, below "
                    f"{FLOAT_NORMAL_MIN:.3g}; give 0 where 0 is allowed, or a value in range"
                )
        return value


class LinkCommandRequest(_Request):
    """POST /api/v1/link/command: one COMMAND frame, for conformance tests (docs/api.md)."""

    command: str | None = Field(
        default=None,
        max_length=64,
        description="a command of the dictionary by name (config/protocol.toml); or give opcode",
    )
    opcode: int | None = Field(
        default=None, ge=0, le=255, description="the opcode byte, 0..255, any (or give command)"
    )
    fields: dict[str, int | float | str] | None = Field(
        default=None,
        description="request fields by name, encoded and range-checked by the dictionary "
        "(needs command); bytes fields as hex strings",
    )
    payload_hex: str | None = Field(
        default=None,
        max_length=2 * 1024,
        pattern=r"^([0-9a-fA-F]{2})*$",
        description="the payload as hex, sent as it is, unchecked (0..1024 bytes); or fields",
    )
    repeat: bool = Field(
        default=False,
        description="send the identical frame (same sequence number) again after the answer, "
        "as a retry after a lost answer would; both answers are returned",
    )


class LinkAnswer(BaseModel):
    """One answer frame of POST /api/v1/link/command."""

    type: Literal["ack", "nak"]
    seq: int
    payload_hex: str
    error_code: int | None = Field(description="NAK: the error code; ACK: null")
    error_name: str | None = Field(description="NAK: the code's name in the dictionary")
    detail: str | None = Field(description="NAK: the device's detail text")
    values: dict[str, int | float | str] | None = Field(
        description="ACK: the response fields as the dictionary decodes them (bytes as hex); "
        "null for a NAK or when they do not decode (see decode_error)"
    )
    decode_error: str | None = Field(description="why the ACK payload did not decode; else null")


class LinkCommandResponse(BaseModel):
    """POST /api/v1/link/command: the frame sent and the device's answer(s)."""

    command: str | None = Field(description="the opcode's name; null if the dictionary has none")
    opcode: int
    seq: int = Field(description="sequence number of the frame (both sends with repeat)")
    request_hex: str = Field(description="the payload sent")
    answers: list[LinkAnswer] = Field(description="one per send: ACK or NAK")
    attempts: int = Field(description="frames written, retries after a timeout included")
    rtt_s: float = Field(description="from the first send to the last answer")


class PingRequest(_Request):
    """POST /api/v1/ping."""

    count: int = Field(default=10, ge=1, le=PING_COUNT_MAX, description="number of PINGs")
    size: int = Field(default=16, ge=0, le=PING_SIZE_MAX, description="payload bytes per PING")


class ModeRequest(_Request):
    """POST /api/v1/mode."""

    mode: Mode = Field(description="area (staring, for focusing) or tdi (push-broom)")


# What a field's type and constraints do not say, for 400 messages: appended in parentheses to
# the valid values read from the field itself (valid_values). Keyed by field name, so each entry
# must hold for every request model and query parameter of that name.
ALLOWED: dict[str, str] = {
    "size": "bytes",
    "channel": "a telemetry channel name (GET /api/v1/telemetry lists them)",
    "since_s": "a Unix time in seconds, or a negative number of seconds before now",
    "speed_deg_s": "a wheel speed in deg/s, 0 stops the wheel",
    "channels": "wheel channel numbers, each 0..12",
    "angle_deg": "the polariser's axis in deg; null takes it out of the beam",
    "max": "lines",
    "text": "printable characters: no newlines or tabs",
    "done": "at most total",
    "total": "at least done",
    "values": "register name -> raw integer, or enum name for an enum field",
}


def _number(value: Any) -> str:
    return f"{value:g}" if isinstance(value, float) else str(value)


def _kind(annotation: Any) -> str:
    """What a value of this (non-null) type is, in words."""
    if get_origin(annotation) is Literal:
        names = [str(v) for v in get_args(annotation)]
        return names[0] if len(names) == 1 else f"{', '.join(names[:-1])} or {names[-1]}"
    origin = get_origin(annotation) or annotation
    if origin in (Union, types.UnionType):
        return " or ".join(_kind(a) for a in get_args(annotation))
    words = {
        bool: "true or false",
        int: "an integer",
        float: "a number",
        str: "a string",
        list: "a list",
        dict: "an object",
    }
    if isinstance(origin, type) and issubclass(origin, BaseModel):
        return f"an object with keys {', '.join(origin.model_fields)}"
    return words.get(origin, "a value") if isinstance(origin, type) else "a value"


def valid_values(field: FieldInfo) -> str:
    """The values ``field`` takes, in words, from its own type and constraints (so that they
    cannot drift from what is enforced): e.g. "an integer in 1..4096", "a number more than 0
    and at most 10", "sum or mean", "null or a string of at most 240 characters"."""
    annotation: Any = field.annotation
    nullable = False
    if get_origin(annotation) in (Union, types.UnionType):
        args = [a for a in get_args(annotation) if a is not type(None)]
        nullable = len(args) < len(get_args(annotation))
        annotation = args[0] if len(args) == 1 else Union[tuple(args)]  # noqa: UP007
    words = _kind(annotation)
    low: Any = None
    high: Any = None
    low_incl = high_incl = True
    min_len = max_len = None
    for item in field.metadata:
        if isinstance(item, annotated_types.Ge):
            low = item.ge
        elif isinstance(item, annotated_types.Gt):
            low, low_incl = item.gt, False
        elif isinstance(item, annotated_types.Le):
            high = item.le
        elif isinstance(item, annotated_types.Lt):
            high, high_incl = item.lt, False
        elif isinstance(item, annotated_types.MinLen):
            min_len = item.min_length
        elif isinstance(item, annotated_types.MaxLen):
            max_len = item.max_length
    if low is not None and high is not None:
        if low_incl and high_incl:
            words += f" in {_number(low)}..{_number(high)}"
        else:
            words += (
                f" {'from' if low_incl else 'more than'} {_number(low)} "
                f"{'to' if low_incl else 'and'} {'at most' if high_incl else 'below'} "
                f"{_number(high)}"
            )
    elif low is not None:
        words += f" {'>=' if low_incl else '>'} {_number(low)}"
    elif high is not None:
        words += f" {'<=' if high_incl else '<'} {_number(high)}"
    if min_len is not None or max_len is not None:
        origin: Any = get_origin(annotation) or annotation
        unit = {str: "characters", dict: "entries"}.get(origin, "items")
        if min_len is not None and max_len is not None:
            words += f" of {min_len} to {max_len} {unit}"
        elif min_len == 1:
            words = f"a non-empty {words.removeprefix('a ').removeprefix('an ')}"
        elif min_len is not None:
            words += f" of at least {min_len} {unit}"
        else:
            words += f" of at most {max_len} {unit}"
    if not nullable:
        return words
    if " or " in words:  # a choice of values: true, false or null
        return f"{words.replace(' or ', ', ')} or null"
    return f"null or {words}"


class ErrorResponse(BaseModel):
    """The body of every error response."""

    error: str = Field(description="what went wrong and what to change")
    code: str = Field(
        description="what kind of error, for programs: each response status of each route "
        "lists the codes it may carry (docs/api.md, Errors, says what each means)"
    )


class LinkInfo(BaseModel):
    """The link part of the status."""

    port: str = Field(description="serial device, pyserial URL, or the simulator's pty link")
    connected: bool
    last_error: str | None = Field(default=None, description="why the port is not open")
    sim_pid: int | None = Field(
        default=None, description="pid of the simulator this daemon spawned, while it runs"
    )
    sim_state: Literal["running", "restarting", "exited", "gave_up"] | None = Field(
        default=None,
        description="the spawned simulator: running, restarting (it died; waiting out the "
        "backoff or starting again), exited (not restarted: sim.restart = false), gave_up (too "
        "many failures in a row); null on hardware",
    )
    sim_restarts: int | None = Field(
        default=None,
        description="times the daemon restarted its simulator after it died; null on hardware",
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
    scheduling: dict[str, str] = Field(
        description="what each of the threads the hardware waits on runs at, e.g. "
        '{"frame_reader": "SCHED_RR 10", "command_link": ..., "service_loop": ..., '
        '"closed_loop": ...} (each once it has run), and "why" one got no more than shown '
        "(docs/config.md, daemon.realtime)"
    )


class ControlActivity(BaseModel):
    """What the controlling client says it is doing (PUT /api/v1/control/activity)."""

    text: str = Field(description="e.g. 'campaign mtf: step 3/12 acquire scan_m8'")
    done: int | None = Field(description="steps done so far (null: not given)")
    total: int | None = Field(description="steps in all (null: not given)")
    t_s: float = Field(description="Unix time it was set")


class ControlInfo(BaseModel):
    """Who holds control of the camera (docs/api.md#control)."""

    holder: str | None = Field(description="the controlling client; null: nobody holds control")
    since_t_s: float | None = Field(description="Unix time the holder took control")
    why: str | None = Field(
        description="'lease' (taken with POST /api/v1/control), or the acquisition it started"
    )
    expires_t_s: float | None = Field(
        description="Unix time the lease ends unless renewed; null while an acquisition holds it"
    )
    you: str = Field(description="the client name this request was made under (X-Camd-Client)")
    activity: ControlActivity | None = Field(
        default=None,
        description="what the holder last said it is doing (PUT /api/v1/control/activity); "
        "null: nothing said, or control was given back or taken over since",
    )


class ControlRequest(_Request):
    """POST /api/v1/control: take (or renew) control."""

    ttl_s: float = Field(
        default=60.0, gt=0.0, le=86400.0, description="lease length; ask again to renew"
    )
    force: bool = Field(
        default=False, description="take control from another client (logged as an event)"
    )


class ActivityRequest(_Request):
    """PUT /api/v1/control/activity: what the controlling client is doing, for observers."""

    text: str = Field(
        min_length=1,
        max_length=ACTIVITY_TEXT_MAX,
        description=f"what it is doing, 1 to {ACTIVITY_TEXT_MAX} printable characters",
    )
    done: int | None = Field(default=None, ge=0, description="steps done so far")
    total: int | None = Field(default=None, ge=0, description="steps in all (>= done)")

    @field_validator("text")
    @classmethod
    def _printable(cls, text: str) -> str:
        if not text.isprintable():
            raise ValueError("text must be printable (no newlines, tabs or control characters)")
        return text

    @field_validator("total")
    @classmethod
    def _done_within_total(cls, total: int | None, info: ValidationInfo) -> int | None:
        done = info.data.get("done")
        if total is not None and done is not None and done > total:
            raise ValueError(f"done = {done} is more than total = {total}")
        return total


class AcquisitionInfo(BaseModel):
    """The acquisition slot's current or last acquisition."""

    kind: Literal["scan", "stare", "stream", "wheel"]
    description: str
    client: str = Field(description="who started it ('' for the daemon itself)")
    started_t_s: float
    ended_t_s: float | None = Field(description="null while it runs")
    running: bool


class EstopState(BaseModel):
    """GET /api/v1/estop, POST /api/v1/estop/release: the emergency-stop latch."""

    latched: bool = Field(
        description="true from an emergency stop until a client with control releases it: "
        "nothing moves or acquires meanwhile (409 estop_latched)"
    )
    since_t_s: float | None = Field(description="when this latch began (Unix time)")
    by: str | None = Field(description="the client that asked for the stop")
    last_t_s: float | None = Field(description="the newest emergency stop (Unix time)")
    stopped: list[str] = Field(description="what the newest stop stopped")
    failed: list[str] = Field(description="what it could not stop, with why")
    count: int = Field(description="emergency stops asked for on this data directory")
    released_t_s: float | None = Field(description="when the last latch was released")
    released_by: str | None = Field(description="who released it")
    how_to_release: str = Field(description="what to do to release it")


class BackendInfo(BaseModel):
    """How the daemon reaches one of the camera's interfaces (docs/hardware.md)."""

    kind: Literal["sim", "hardware"] = Field(
        description="the simulated camera's interface, or real hardware"
    )
    backend: Literal["sim", "serial", "libusb", "fpga", "usb-spi"] = Field(
        description="link: sim or serial; stream: sim or libusb; registers: fpga (REG_* over "
        "the link) or usb-spi (an MCP2210)"
    )
    detail: str = Field(description="the port, the socket or the USB id it uses")


class BackendsInfo(BaseModel):
    """The status's backends: which camera each interface talks to (docs/config.md, "Hardware
    or simulator")."""

    camera: Literal["sim", "hardware", "mixed"] = Field(
        description="all simulated, all hardware, or mixed (a config that sets a stream or "
        "bridge backend against its link)"
    )
    link: BackendInfo = Field(description="the RS-422 command link")
    stream: BackendInfo = Field(description="the USB frame stream")
    registers: BackendInfo = Field(description="the sensor's register bridge")


class StatusResponse(BaseModel):
    """GET /api/v1/status and POST /api/v1/reset."""

    state: StateName
    reason: str | None = Field(description="why the daemon is in this state (null when idle)")
    mode: Mode | None = Field(description="imaging mode last known, null before first contact")
    link: LinkInfo
    device: DeviceStatus | None = Field(description="null when the device cannot be asked")
    daemon: DaemonInfo
    control: ControlInfo
    acquisition: AcquisitionInfo | None = Field(
        description="the running acquisition, or the last started one (null before the first)"
    )
    estop: EstopState = Field(description="the emergency-stop latch")
    backends: BackendsInfo = Field(description="simulated or real: each interface's backend")


class EstopResponse(BaseModel):
    """POST /api/v1/estop: what the emergency stop did, and the latch it set."""

    stopped: list[str] = Field(
        description="what was stopped (stage, acquisition, wheel, campaign job)"
    )
    failed: list[str] = Field(description="what could not be stopped, with why")
    latch: EstopState


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
    archive_error: str | None = Field(
        default=None,
        description="why the archive cannot be written now (a full disk, a read-only or corrupt "
        "file), null while it can: the limits are still checked and the events kept in memory",
    )


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

    model_config = ConfigDict(extra="forbid", strict=True)  # as _Request: true is not 1

    sensor: str
    registers: dict[str, int]


class TimingResponse(BaseModel):
    """GET /api/v1/timing: the sensor timing its registers set (docs/physics.md §2, §3)."""

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
    exposure_register: str | None = Field(
        default=None,
        description="the register (or REG.field) that sets exposure_lines: write it with "
        "POST /api/v1/registers to change the exposure",
    )


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
    t_s: float | None = Field(
        description="Unix time of the last training; None if the daemon has not trained since it "
        "started (or the interface has nothing to train)"
    )
    lost_t_s: float | None = Field(
        description="Unix time the link lost that training (LINK_LOST, a camera restart): "
        "`trained` is then false and the rest describes the last training; None while it holds"
    )
    summary: str = Field(description="the link's training in one sentence")


# -- the frame stream ---------------------------------------------------------------------------

Binning = Literal["off", "2x2"]


class StreamStartRequest(_Request):
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


# -- the live view's background ------------------------------------------------------------------

BACKGROUND_FRAMES_MAX = 1000  # = camd.pipeline.background.FRAMES_MAX
BACKGROUND_FRAMES_DEFAULT = 16


class BackgroundRequest(_Request):
    """POST /api/v1/live/background."""

    frames: int = Field(
        default=BACKGROUND_FRAMES_DEFAULT,
        ge=1,
        le=BACKGROUND_FRAMES_MAX,
        description=f"frames to average, 1..{BACKGROUND_FRAMES_MAX}",
    )


class BackgroundStatus(BaseModel):
    """GET /api/v1/live/background, and the answer of POST and DELETE there. While capturing
    (and after a failure) the geometry and counters are those of the frames taken so far; a
    field that does not apply is null."""

    state: Literal["none", "capturing", "ready", "failed"] = Field(
        description="none: no background; capturing: averaging frames; ready: the mean is "
        "there (GET /api/v1/live/background/frame); failed: see error"
    )
    frames_wanted: int | None = Field(description="frames the capture averages")
    frames_done: int | None = Field(description="frames averaged so far")
    rows: int | None
    cols: int | None
    mode: str | None = Field(description="the frames' mode (area, tdi)")
    stages: int | None = Field(description="TDI stages in the frame headers (0 in area mode)")
    first_counter: int | None = Field(description="the device's counter of the first frame")
    last_counter: int | None = Field(description="... and of the last frame averaged so far")
    captured_t_s: float | None = Field(description="Unix time the capture completed")
    seq: int | None = Field(description="completed captures since the daemon started")
    mean_dn: float | None = Field(description="spatial mean of the background, DN")
    std_dn: float | None = Field(description="spatial standard deviation of the background, DN")
    saved_to: list[str] = Field(
        description="recordings started since it was captured, which hold it as /background "
        "(newest last, the last 20)"
    )
    error: str | None = Field(description="why the capture failed, and what to do")


class SceneRequest(_Request):
    """PUT /api/v1/sim/scene."""

    spec: str = Field(min_length=1, max_length=240, description="scene spec, e.g. 'bars:lux=3'")


class SeedRequest(_Request):
    """PUT /api/v1/sim/seed."""

    seed: int = Field(ge=0, le=0xFFFFFFFF, description="seed of the restarted random streams")


class StageRequest(_Request):
    """PUT /api/v1/sim/stage."""

    track: bool = Field(default=True, description="follow the synchronous speed")
    speed_m_s: float = Field(default=0.0, ge=0.0, le=10.0, description="speed when not tracking")


class StageResponse(BaseModel):
    speed_m_s: float
    sync_speed_m_s: float
    track: bool


class SimStreamStats(BaseModel):
    """GET /api/v1/sim/stream: what the simulated camera's stream engine did and injected."""

    produced: int
    sent: int
    dropped: int
    corrupted: int
    shortened: int
    stalls: int
    undelivered: int


TdiMode = Literal["sum", "mean"]
ScanState = Literal["none", "starting", "running", "done", "stopped", "ended_early", "failed"]


class ScanRequest(_Request):
    """POST /api/v1/scan/start: a push-broom scan with host TDI (docs/scan.md)."""

    stages: int = Field(ge=1, le=4096, description="TDI stages M (1..window rows)")
    lines: int = Field(
        ge=0,
        le=10_000_000,
        description="complete TDI lines wanted; the scan takes lines + M - 1 frames because the "
        "first M - 1 lines lack stages; 0 = until /scan/stop",
    )
    out: str | None = Field(
        default=None,
        description="the new HDF5 file, on the daemon's host: relative = in <data_dir>/scans; "
        "absolute = inside the data directory or daemon.record_dirs (docs/api.md, Files); "
        "null = <data_dir>/scans/scan-<UTC time>.h5",
    )
    scene: str | None = Field(
        default=None, max_length=240, description="simulated camera only: set this scene first"
    )
    speed_m_s: float | None = Field(
        default=None,
        gt=0.0,
        le=10.0,
        description="stage speed: the TDI line period follows from it (docs/physics.md §2); null = "
        "keep the registers' line period and run the stage at the synchronous speed",
    )
    line_period_s: float | None = Field(
        default=None,
        gt=0.0,
        le=SCAN_LINE_PERIOD_MAX_S,
        description="TDI line period to set (docs/physics.md §2 eqs 6-9); exclusive with speed_m_s",
    )
    drive_stage: bool = Field(
        default=True,
        description="drive the scan stage at the synchronous speed (docs/motion.md); false = "
        "leave it alone (an external stage; on the simulator, an ideal one)",
    )
    closed_loop: bool | None = Field(
        default=None, description="correct from the encoder while scanning; null = config"
    )
    dv_over_v: float = Field(
        default=0.0,
        ge=-2.0,
        lt=1.0,
        description="deliberate velocity mismatch (V - V_m)/V: the stage runs at "
        "(1 - dv_over_v) x the synchronous speed (MTF against mismatch, docs/physics.md §6); "
        "a driven stage takes -0.5 .. 0.5, the simulator's ideal stage (drive_stage false, "
        "forwards only) -2 .. below 1",
    )
    mode: TdiMode = Field(default="sum", description="sum (uint32, eq 12) or mean (float32)")
    out_bits: int | None = Field(
        default=None, ge=1, le=32, description="clip sums to 2^out_bits - 1 (eq 12); null = none"
    )
    rows_per_line: float = Field(
        default=1.0, ge=0.0, le=64.0, description="rows the image moves per line (docs/tdi.md)"
    )
    cols_per_line: float = Field(
        default=0.0, ge=-64.0, le=64.0, description="columns of drift per line (docs/tdi.md)"
    )
    reverse: bool = Field(default=False, description="the scene moves from row 1 towards row M")
    binning: Binning = Field(default="off", description="FPGA-side 2x2 binning")
    quicklook: bool = Field(default=True, description="write a PNG quicklook beside the file")


class StagesRequest(_Request):
    """PUT /api/v1/scan/stages."""

    stages: int = Field(ge=1, le=4096, description="new TDI stage count, from the next frame")


class ScanTiming(BaseModel):
    """The timing a scan runs at (docs/physics.md §2 eqs 5-9, 13)."""

    tdi_line_period_s: float = Field(description="T_line,TDI: the frame period the registers set")
    row_period_s: float = Field(description="T_line,roll: the sensor's row time")
    n_lines: int = Field(description="window rows, eq 8")
    back_path_s: float = Field(description="T_back, eq 9")
    max_stages: int = Field(description="M0 = n_lines, eq 13")
    exposure_s: float
    sync_speed_m_s: float = Field(description="stage speed that moves the image one row a period")
    stage_speed_m_s: float | None = Field(
        description="the stage speed the scan runs at (null: not known to camd)"
    )
    dv_over_v: float | None = Field(
        description="(V - V_m) / V, docs/physics.md §6; null if unknown"
    )


class ScanMotionInfo(BaseModel):
    """How a scan drove the stage (docs/motion.md)."""

    closed_loop: str = Field(description="off, step_rate or line_period")
    stage_speed_m_s: float = Field(
        description="signed speed the stage was commanded: sync x (1 - dv_over_v)"
    )
    target_speed_m_s: float = Field(description="the speed the closed loop held")
    loop_samples: int = Field(description="closed-loop polls recorded")
    loop_error: str | None = Field(description="why the loop stopped early, if it did")
    line_period_limited: bool = Field(
        description="line-period correction hit n_lines = M (it could not shorten further)"
    )


class ScanResponse(BaseModel):
    """GET /api/v1/scan, and the answer of /scan/start, /stop and /stages."""

    state: ScanState
    file: str | None = Field(description="the HDF5 file of the current or last scan")
    quicklook: str | None = Field(description="its PNG quicklook, once written")
    stages: int = Field(description="M now")
    lines_wanted: int = Field(description="complete lines asked for; 0 = until stopped")
    frames_requested: int
    lines: int = Field(description="TDI lines recorded so far")
    complete_lines: int = Field(description="lines with all M stages from consecutive frames")
    lines_flushed: int = Field(
        default=0,
        description="lines on disk: what the file keeps if the daemon dies now (flushed at "
        'least once a second; docs/stream.md "Crash safety")',
    )
    lost_frames: int = Field(description="frames the stream never delivered")
    not_sent_frames: int = Field(
        default=0,
        description="once ended: frames the scan asked for that the camera never sent (the "
        "scan was stopped, failed or ended early: state and error say why), by its own count or, "
        "if it could not say (it died), those the host never accounted for",
    )
    stage_changes: list[tuple[int, int]] = Field(
        description="[line index, stages] for the start and every change"
    )
    mode: TdiMode
    width: int
    elapsed_s: float
    lines_per_s: float
    cpu_load: float = Field(
        description="the daemon's CPU time over the scan's wall time (1.0 = one core busy)"
    )
    tdi_cpu_s: float = Field(description="CPU time of the TDI worker thread")
    backlog_frames: int = Field(description="frames received but not yet through the engine")
    timing: ScanTiming | None
    error: str | None = Field(description="why the scan failed, if it did")
    stream: StreamStats
    mismatch_max: float | None = Field(
        description="largest M |dV/V| of a line (pixels of smear; docs/physics.md §6), from the "
        "encoder counts in the frame headers; null without encoder data"
    )
    mismatch_rms: float | None = Field(description="RMS of M dV/V over the scan's lines")
    mismatch_level: str = Field(description="ok, yellow or red: the worst level reached")
    motion: ScanMotionInfo | None = Field(description="the stage's part of the scan, if driven")


# -- motion (docs/motion.md) --------------------------------------------------------------------


class StageReadingModel(BaseModel):
    """The scan stage at one device time (SI: m, m/s)."""

    state: str = Field(description="disabled, idle, ramping, running, moving, homing, estop")
    homed: bool
    position_m: float = Field(description="commanded position (step count)")
    encoder_m: float = Field(description="measured position (encoder)")
    speed_m_s: float = Field(description="commanded speed now, ramps included")
    encoder_speed_m_s: float = Field(description="the encoder's speed over the last 10 ms")
    at_limit: str = Field(description="none, low or high: a soft limit the stage stands at")
    time_s: float = Field(description="device time of the sample")


class StageLimitsModel(BaseModel):
    """Soft travel limits, speed limit and ramp acceleration in force."""

    low_m: float
    high_m: float
    max_speed_m_s: float
    accel_m_s2: float


class StageOperationModel(BaseModel):
    """The last move or homing started through the API, for a client to follow it
    (docs/motion.md, "Waiting for a move or a homing"). Times are the device's clock."""

    seq: int = Field(description="numbers the moves and homings since the daemon started")
    kind: Literal["move", "home"] = Field(description="move (to target_m) or home")
    active: bool = Field(
        description="still under way: the stage is moving (homing) for this operation"
    )
    start_m: float = Field(description="commanded position when it started")
    target_m: float | None = Field(description="move: the target; home: null (0 once homed)")
    speed_m_s: float = Field(description="move: cruise speed; home: the homing speed")
    expected_duration_s: float = Field(description="the device's estimate of its duration")
    started_time_s: float = Field(description="device time when it started")
    elapsed_s: float = Field(description="device time since it started, at this reading")
    remaining_s: float = Field(description="expected_duration_s - elapsed_s, at least 0")
    fraction_done: float = Field(
        description="0..1: move, distance covered of the whole; home, time elapsed of the "
        "expected (1 once finished)"
    )


class MotionStatus(BaseModel):
    """GET /api/v1/motion: the stage, its limits and the synchronisation settings."""

    profile: str = Field(description="config/stages/<profile>.toml")
    kind: str = Field(description="linear or turntable")
    reading: StageReadingModel
    limits: StageLimitsModel
    closed_loop: str = Field(description="what a scan's closed loop trims, or off")
    yellow: float = Field(description="M |dV/V| yellow limit")
    red: float = Field(description="M |dV/V| red limit")
    operation: StageOperationModel | None = Field(
        default=None,
        description="the last move or homing started through the API (null: none since the "
        "daemon started, or a scan or a jog took the stage since)",
    )


class MotionEnableRequest(_Request):
    """POST /api/v1/motion/enable."""

    on: bool = Field(default=True, description="energise (true) or release (false) the motor")


class MotionRunRequest(_Request):
    """POST /api/v1/motion/run: hold a constant signed speed."""

    speed_m_s: float = Field(ge=-10.0, le=10.0, description="signed speed; 0 stops")


class MotionMoveRequest(_Request):
    """POST /api/v1/motion/move: go to a position and stop."""

    position_m: float = Field(ge=-100.0, le=100.0, description="target, metres from home")
    speed_m_s: float | None = Field(
        default=None, gt=0.0, le=10.0, description="cruise speed; null = the speed limit"
    )
    wait: bool = Field(
        default=True,
        description="answer once the stage has stopped (kept for old clients: a long move "
        "holds the request; false answers at once, then poll GET /api/v1/motion)",
    )


class MotionHomeRequest(_Request):
    """POST /api/v1/motion/home."""

    wait: bool = Field(
        default=True,
        description="answer once homing has finished (kept for old clients; false answers at "
        "once, then poll GET /api/v1/motion)",
    )


class SyncResponse(BaseModel):
    """GET /api/v1/motion/sync: the open-loop synchronisation (docs/physics.md §2 eqs 5-9, 13; §6).

    The first ten keys are the contract of ``camctl sync --json``.
    """

    line_period_s: float = Field(description="TDI line period")
    row_time_s: float = Field(description="rolling line period T_line,roll (eq 4)")
    n_lines: int = Field(description="window rows (eq 8)")
    back_path_s: float = Field(description="back path (eq 9)")
    m0: int = Field(description="largest stage count (eq 13)")
    stages: int = Field(description="M")
    sync_speed: float = Field(description="synchronous stage speed, m/s (§6 eq 9)")
    step_rate_hz: float = Field(description="stepper rate for it, microsteps/s")
    dv_over_v: float = Field(description="mismatch of the stage speed given, (V - V_m)/V")
    m_dv_over_v: float = Field(description="M dV/V: smear over M stages, pixels")
    image_speed_m_s: float = Field(description="image speed on the focal plane at sync speed")
    stage_speed_m_s: float = Field(description="the stage speed the mismatch is for")
    stage_profile: str
    image_scale: float = Field(description="focal-plane metres per metre of stage travel")
    pixel_pitch_m: float = Field(description="pitch on the focal plane (doubled when binned)")
    angular_velocity_rad_s: float | None = Field(
        description="turntable only: table speed for the line period (eq 5)"
    )
    tolerance_ok: bool = Field(description="|M dV/V| within the yellow limit")


class SimStageFaultsRequest(_Request):
    """PUT /api/v1/sim/stage/faults: the simulated stage's imperfections."""

    error: float = Field(default=0.0, ge=-0.1, le=0.1, description="relative step-rate error")
    ripple: float = Field(default=0.0, ge=0.0, le=0.2, description="relative ripple amplitude")
    jitter: float = Field(default=0.0, ge=0.0, le=0.2, description="relative RMS speed jitter")
    drift: float = Field(default=0.0, ge=-0.1, le=0.1, description="relative drift per second")
    load: float = Field(default=0.0, ge=0.0, le=3.0, description="load / pull-out torque")


class SimFailNextRequest(_Request):
    """POST /api/v1/sim/fail-next: make one coming command fail (SIM_FAIL_NEXT), with a NAK
    (``error``), a dropped line (``duration_s``), or a stream the camera ends early
    (``end_after_frames``)."""

    command: str = Field(
        min_length=1, max_length=40, description="the command to fail, e.g. REG_WRITE_BURST"
    )
    skip: int = Field(
        default=0, ge=0, le=65535, description="commands of that kind to let through first"
    )
    error: str | None = Field(
        default=None, description="answer it with a NAK of this error, e.g. BUSY (docs/protocol.md)"
    )
    duration_s: float | None = Field(
        default=None, gt=0.0, le=600.0, description="or: drop off the line for this long, s"
    )
    end_after_frames: int | None = Field(
        default=None,
        ge=0,
        le=0xFFFF_FFFF,
        description="or: the command (START_STREAM, WHEEL_ACQUIRE) executes, and the camera ends "
        "the stream it starts after this many frames (STREAM_DONE)",
    )


class SimStageTruth(BaseModel):
    """GET /api/v1/sim/stage/truth: what the simulated stage really does."""

    position_m: float
    velocity_m_s: float
    missed_steps: int
    time_s: float


class SimSettings(BaseModel):
    """GET /api/v1/sim: what this daemon last set on the simulated camera (the simulator
    cannot be asked), so that a client can put it back."""

    available: bool = Field(description="false on real hardware (every sim request is refused)")
    scene: str = Field(description="the scene spec in front of the camera")
    ideal_stage: StageRequest = Field(description="the ideal scan stage: track, or a speed")
    polarizer_deg: float | None = Field(description="reference polariser axis; null: out")
    stage_faults: SimStageFaultsRequest = Field(description="the stepper stage's imperfections")


# -- the filter wheel (docs/wheel.md) -------------------------------------------------------------


class WheelChannelInfo(BaseModel):
    """One channel of the wheel (config/wheel.toml)."""

    channel: int = Field(description="index, 0 .. channel_count - 1")
    name: str
    band: str
    centre_deg: float = Field(description="wheel angle of the channel centre")
    polarizer_deg: float | None = Field(
        description="transmission axis of its polariser when centred; null: no polariser"
    )


class WheelExposureInfo(BaseModel):
    """camd's computation for one exposure through the wheel (docs/physics.md §4 eqs 1, 4-6, 8)."""

    exposure_s: float = Field(description="T_exp = n T_line")
    exposure_lines: int = Field(description="n")
    window_rows: int = Field(description="k")
    line_period_s: float = Field(description="T_line")
    frame_time_s: float = Field(description="T_frame = (n + k + 1) T_line (eq 6)")
    delay_s: float = Field(
        description="T_delay = T_center - T_frame / 2 (eq 5), negative when it cannot be centred"
    )
    compensated: bool = Field(description="whether the delay is applied")
    fits: bool = Field(description="the frame fits the light window (and T_delay >= 0 if on)")
    refusal: str | None = Field(description="why it does not fit, with the numbers; else null")
    applied_delay_s: float | None = Field(
        description="delay waited after each entry pulse: T_delay on, 0 off; null if no fit"
    )
    centre_offset_deg: float | None = Field(
        description="imaging centre minus channel centre (eq 4; eq 1 without compensation)"
    )
    centre_error_deg: float | None = Field(description="its uncertainty (eq 8)")


class WheelStatus(BaseModel):
    """GET /api/v1/wheel and the answers of PUT /wheel/speed and /wheel/compensation."""

    wheel: str = Field(description="config/wheel.toml's wheel name")
    speed_deg_s: float = Field(description="angular speed now (0: stopped)")
    nominal_speed_deg_s: float = Field(description="the wheel file's w, for which T_center holds")
    period_s: float | None = Field(description="time per revolution; null when stopped")
    angle_deg: float = Field(description="wheel angle from channel 0's centre, 0 .. 360")
    channel: int | None = Field(description="channel whose light window is in front; else null")
    compensation: bool = Field(description="exposure delay compensation on")
    t_center_s: float = Field(description="entry pulse to channel centre")
    window_s: float = Field(description="light window of a channel")
    device_frame_time_s: float = Field(description="T_frame as the FPGA computes it")
    device_delay_s: float = Field(description="T_delay as the FPGA computes it")
    exposure: WheelExposureInfo = Field(description="camd's numbers for the registers now")
    channels: list[WheelChannelInfo]
    time_s: float = Field(description="device time of the reading")


class WheelSpeedRequest(_Request):
    """PUT /api/v1/wheel/speed."""

    speed_deg_s: float = Field(ge=0.0, le=360.0, description="angular speed, deg/s; 0 stops")


class WheelCompensationRequest(_Request):
    """PUT /api/v1/wheel/compensation."""

    on: bool = Field(description="exposure delay compensation on (true) or off (false)")


class WheelRegion(_Request):
    """A rectangle of the frame whose mean is reported (rows and columns from 0)."""

    row: int = Field(default=0, ge=0, le=4095, description="first row")
    rows: int = Field(ge=1, le=4096, description="rows")
    col: int = Field(default=0, ge=0, le=4095, description="first column")
    cols: int = Field(ge=1, le=4096, description="columns")


class WheelAcquireRequest(_Request):
    """POST /api/v1/wheel/acquire: one frame per channel per pass (docs/wheel.md)."""

    channels: list[int] = Field(
        min_length=1, max_length=13, description="channels in acquisition order, 0 .. 12"
    )
    passes: int = Field(default=1, ge=1, le=1000, description="times through the channel list")
    exposure_s: float | None = Field(
        default=None,
        gt=0.0,
        le=30.0,
        description="set this exposure first (whole lines: round(T_exp / T_line)); null keeps "
        "the registers'",
    )
    compensated: bool | None = Field(
        default=None, description="set compensation first; null keeps the wheel's setting"
    )
    record: str | None = Field(
        default=None,
        description="new HDF5 file for the frames, on the daemon's host: relative = in "
        "<data_dir>/recordings; absolute = inside the data directory or daemon.record_dirs "
        "(docs/api.md, Files); null: none",
    )
    region: WheelRegion | None = Field(
        default=None, description="report the mean of this region; null: of the whole frame"
    )
    timeout_s: float | None = Field(
        default=None,
        gt=0,
        le=86_400,
        description="give up after this long (default: twice a revolution per frame + 10 s)",
    )


class WheelFrame(BaseModel):
    """One frame of a wheel acquisition."""

    counter: int = Field(description="frame counter")
    channel: int
    name: str = Field(description="channel name")
    start_angle_deg: float = Field(
        description="wheel angle at the exposure start, from the frame header (1e-4 deg)"
    )
    centre_deg: float = Field(
        description="predicted imaging-centre angle: channel centre + centre_offset_deg"
    )
    centre_offset_deg: float = Field(description="imaging centre minus channel centre (eq 4)")
    centre_error_deg: float = Field(description="uncertainty of the imaging centre (eq 8)")
    header_centre_deg: float = Field(
        description="imaging centre from the header: start angle + w T_frame / 2"
    )
    mean: float = Field(description="mean signal of the frame (or region), DN")
    timestamp_s: float = Field(description="device time at the end of row 0's exposure")


class WheelAcquireResponse(BaseModel):
    """POST /api/v1/wheel/acquire: per frame, where it was taken and its mean signal."""

    channels: list[int]
    passes: int
    speed_deg_s: float = Field(description="wheel speed during the acquisition")
    exposure: WheelExposureInfo = Field(description="the exposure the frames were taken with")
    device_frame_time_s: float | None = Field(
        description="T_frame as the FPGA computes it (WHEEL_GET after the frames; null if unread)"
    )
    device_delay_s: float | None = Field(
        description="delay the FPGA applies after each entry pulse (0 with compensation off)"
    )
    region: WheelRegion | None
    frames: list[WheelFrame] = Field(description="the frames received, in order")
    stream: StreamResponse = Field(description="the stream document: counters, recording")


class PolarizerRequest(_Request):
    """PUT /api/v1/sim/polarizer: the simulated scene's reference polariser."""

    angle_deg: float | None = Field(
        ge=0.0,
        le=360.0,
        description="transmission axis, deg; null takes the polariser out of the beam",
    )


# -- campaign jobs (docs/campaigns.md, "Campaign jobs") -------------------------------------------

CampaignJobState = Literal[
    "running", "pausing", "paused", "aborting", "aborted", "passed", "failed", "error",
    "interrupted",
]  # fmt: skip


class CampaignStartRequest(_Request):
    """POST /api/v1/campaigns/jobs."""

    campaign: str = Field(
        min_length=1,
        max_length=100,
        description="the campaign's name (lowercase letters, digits, _): one of the daemon's "
        "campaign directories ([campaigns] dirs in camd.toml, then the shipped ones; "
        "`camctl campaign list`); never a path: the daemon runs no file a client names",
    )
    out: str | None = Field(
        default=None,
        # No max_length: the path rules (camd.daemon.output_paths) bound it, in bytes.
        description="output directory on the daemon's host: relative = in <data_dir>/campaigns; "
        "absolute = inside the data directory or daemon.record_dirs (docs/api.md, Files); "
        "null = <data_dir>/campaigns/<id>-<campaign>",
    )
    quick: bool = Field(default=False, description="the campaign's CI-sized overrides")


class CampaignActionRequest(_Request):
    """POST /api/v1/campaigns/jobs/{id}/pause and /abort."""

    force: bool = Field(
        default=False,
        description="pause or abort a job another client started (logged as a warning)",
    )


class CampaignJob(BaseModel):
    """One campaign job: what runs, where its files go, how far it is."""

    id: int
    campaign: str = Field(description="the campaign's name")
    profile: str = Field(description="the camera profile it is written for")
    file: str = Field(description="the campaign file it runs")
    out_dir: str = Field(description="its output directory: state, raw files, results, report")
    quick: bool
    started_by: str = Field(description="the client that started it (it may pause and abort)")
    state: CampaignJobState
    steps: int | None = Field(description="step instances in a run; null: not known ahead")
    done: int | None = Field(default=None, description="steps done, as its worker last said")
    activity: str | None = Field(default=None, description="what its worker last said it does")
    created_t_s: float = Field(description="Unix time it was started")
    requested: Literal["pause", "abort"] | None = Field(
        description="a pause or abort asked for and not yet done (the worker reads it)"
    )
    run_time_s: float = Field(description="its workers' wall time, summed over resumes")
    runs: int = Field(description="workers started: 1, plus 1 per resume")
    message: str | None = Field(description="why it paused, failed or ended")
    passed: bool | None = Field(description="every check passed (null until it has ended)")
    report: str | None = Field(description="its HTML report, once written")


class CampaignJobsResponse(BaseModel):
    """GET /api/v1/campaigns/jobs."""

    jobs: list[CampaignJob]
