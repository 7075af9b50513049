# Generated from camd/daemon/models/ by `python -m camd.daemon.client_types_gen`: do not edit.
"""The JSON documents of the camd HTTP API as TypedDicts: the shapes ``camd.client`` returns.

Generated from the pydantic models of camd/daemon/models/ (the bodies the daemon publishes in
/openapi.json) by ``python -m camd.daemon.client_types_gen``: to change a shape, change the
model and run that command (tests/test_client_types.py fails while this file is stale).

One TypedDict per response model and per model nested in one, named after the model. Its keys
are the JSON keys the API emits; every key is always present, with null where the model allows
None. JSON has no tuples, so a model's ``tuple[...]`` is a ``list`` here. The module imports
nothing of camd, so a script can type the client's answers without loading the daemon.
"""

from __future__ import annotations

from typing import Literal, TypedDict


class LinkAnswer(TypedDict):
    """One answer frame of POST /api/v1/link/command."""

    type: Literal["ack", "nak"]
    seq: int
    payload_hex: str
    # NAK: the error code; ACK: null
    error_code: int | None
    # NAK: the code's name in the dictionary
    error_name: str | None
    # NAK: the device's detail text
    detail: str | None
    # ACK: the response fields as the dictionary decodes them (bytes as hex); null for a NAK or when
    # they do not decode (see decode_error)
    values: dict[str, int | float | str] | None
    # why the ACK payload did not decode; else null
    decode_error: str | None


class LinkCommandResponse(TypedDict):
    """POST /api/v1/link/command: the frame sent and the device's answer(s)."""

    # the opcode's name; null if the dictionary has none
    command: str | None
    opcode: int
    # sequence number of the frame (both sends with repeat)
    seq: int
    # the payload sent
    request_hex: str
    # one per send: ACK or NAK
    answers: list[LinkAnswer]
    # frames written, retries after a timeout included
    attempts: int
    # from the first send to the last answer
    rtt_s: float


class ErrorResponse(TypedDict):
    """The body of every error response."""

    # what went wrong and what to change
    error: str
    # what kind of error, for programs: each response status of each route lists the codes it may
    # carry (docs/api.md, Errors, says what each means)
    code: str


class LinkInfo(TypedDict):
    """The link part of the status."""

    # serial device, pyserial URL, or the simulator's pty link
    port: str
    connected: bool
    # why the port is not open
    last_error: str | None
    # pid of the simulator this daemon spawned, while it runs
    sim_pid: int | None
    # the spawned simulator: running, restarting (it died; waiting out the backoff or starting
    # again), exited (not restarted: sim.restart = false), gave_up (too many failures in a row);
    # null on hardware
    sim_state: Literal["running", "restarting", "exited", "gave_up"] | None
    # times the daemon restarted its simulator after it died; null on hardware
    sim_restarts: int | None


class DeviceStatus(TypedDict):
    """GET_STATUS fields, as the device reported them."""

    mode: Literal["area", "tdi"]
    device_state: Literal["idle", "busy", "fault"]
    # error code of the active fault, 0 if none
    fault_code: int
    # time since power-on or RESET
    uptime_s: float
    # firmware version, major * 256 + minor
    fw_version: int
    boot_count: int


class DaemonInfo(TypedDict):
    """The daemon process."""

    version: str
    pid: int
    uptime_s: float
    # what each of the threads the hardware waits on runs at, e.g. {"frame_reader": "SCHED_RR 10",
    # "command_link": ..., "service_loop": ..., "closed_loop": ...} (each once it has run), and
    # "why" one got no more than shown (docs/config.md, daemon.realtime)
    scheduling: dict[str, str]


class ControlActivity(TypedDict):
    """What the controlling client says it is doing (PUT /api/v1/control/activity)."""

    # e.g. 'campaign mtf: step 3/12 acquire scan_m8'
    text: str
    # steps done so far (null: not given)
    done: int | None
    # steps in all (null: not given)
    total: int | None
    # Unix time it was set
    t_s: float


class ControlInfo(TypedDict):
    """Who holds control of the camera (docs/api.md#control)."""

    # the controlling client; null: nobody holds control
    holder: str | None
    # Unix time the holder took control
    since_t_s: float | None
    # 'lease' (taken with POST /api/v1/control), or the acquisition it started
    why: str | None
    # Unix time the lease ends unless renewed; null while an acquisition holds it
    expires_t_s: float | None
    # the client name this request was made under (X-Camd-Client)
    you: str
    # what the holder last said it is doing (PUT /api/v1/control/activity); null: nothing said, or
    # control was given back or taken over since
    activity: ControlActivity | None


class AcquisitionInfo(TypedDict):
    """The acquisition slot's current or last acquisition."""

    kind: Literal["scan", "stare", "stream", "wheel"]
    description: str
    # who started it ('' for the daemon itself)
    client: str
    started_t_s: float
    # null while it runs
    ended_t_s: float | None
    running: bool


class EstopState(TypedDict):
    """GET /api/v1/estop, POST /api/v1/estop/release: the emergency-stop latch."""

    # true from an emergency stop until a client with control releases it: nothing moves or acquires
    # meanwhile (409 estop_latched)
    latched: bool
    # when this latch began (Unix time)
    since_t_s: float | None
    # the client that asked for the stop
    by: str | None
    # the newest emergency stop (Unix time)
    last_t_s: float | None
    # what the newest stop stopped
    stopped: list[str]
    # what it could not stop, with why
    failed: list[str]
    # emergency stops asked for on this data directory
    count: int
    # when the last latch was released
    released_t_s: float | None
    # who released it
    released_by: str | None
    # what to do to release it
    how_to_release: str


class BackendInfo(TypedDict):
    """How the daemon reaches one of the camera's interfaces (docs/hardware.md)."""

    # the simulated camera's interface, or real hardware
    kind: Literal["sim", "hardware"]
    # link: sim or serial; stream: sim or libusb; registers: fpga (REG_* over the link) or usb-spi
    # (an MCP2210)
    backend: Literal["sim", "serial", "libusb", "fpga", "usb-spi"]
    # the port, the socket or the USB id it uses
    detail: str


class BackendsInfo(TypedDict):
    """The status's backends: which camera each interface talks to (docs/config.md, "Hardware or
    simulator")."""

    # all simulated, all hardware, or mixed (a config that sets a stream or bridge backend against
    # its link)
    camera: Literal["sim", "hardware", "mixed"]
    # the RS-422 command link
    link: BackendInfo
    # the USB frame stream
    stream: BackendInfo
    # the sensor's register bridge
    registers: BackendInfo


class StatusResponse(TypedDict):
    """GET /api/v1/status and POST /api/v1/reset."""

    state: Literal["disconnected", "idle", "streaming", "fault"]
    # why the daemon is in this state (null when idle)
    reason: str | None
    # imaging mode last known, null before first contact
    mode: Literal["area", "tdi"] | None
    link: LinkInfo
    # null when the device cannot be asked
    device: DeviceStatus | None
    daemon: DaemonInfo
    control: ControlInfo
    # the running acquisition, or the last started one (null before the first)
    acquisition: AcquisitionInfo | None
    # the emergency-stop latch
    estop: EstopState
    # simulated or real: each interface's backend
    backends: BackendsInfo


class EstopResponse(TypedDict):
    """POST /api/v1/estop: what the emergency stop did, and the latch it set."""

    # what was stopped (stage, acquisition, wheel, campaign job)
    stopped: list[str]
    # what could not be stopped, with why
    failed: list[str]
    latch: EstopState


class RttMs(TypedDict):
    """Round-trip times of the successful PINGs, milliseconds (null if none succeeded)."""

    p50: float | None
    p99: float | None
    max: float | None


class PingResponse(TypedDict):
    """POST /api/v1/ping."""

    count: int
    ok: int
    failed: int
    # re-sends needed, summed over all PINGs
    retries: int
    rtt_ms: RttMs
    # up to 5 distinct failure reasons
    errors: list[str]


class DeviceLinkStats(TypedDict):
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


class LinkResponse(TypedDict):
    """GET /api/v1/link."""

    # host-side link counters
    host: dict[str, int]
    # null when the device cannot be asked
    device: DeviceLinkStats | None


class ChannelLatest(TypedDict):
    """The newest sample of one channel."""

    value: float
    unit: str
    # Unix time of the sample, seconds
    t_s: float
    limit: Literal["ok", "yellow", "red"]


class ChannelLimitRanges(TypedDict):
    """One channel's limits (``telemetry.limits``), in its unit, bounds inclusive: ``ok`` inside
    ``yellow``, ``yellow`` outside it but inside ``red``, ``red`` outside ``red``."""

    yellow: list[float]
    red: list[float]


class TelemetryResponse(TypedDict):
    """GET /api/v1/telemetry."""

    latest: dict[str, ChannelLatest]
    # every channel's configured limits (the defaults and the config's), so that a client draws them
    # as the daemon applies them
    limits: dict[str, ChannelLimitRanges]
    # samples in the archive
    samples: int
    # path of the SQLite archive
    archive: str
    # why the archive cannot be written now (a full disk, a read-only or corrupt file), null while
    # it can: the limits are still checked and the events kept in memory
    archive_error: str | None


class ChannelHistory(TypedDict):
    """One channel's samples over the range, or its buckets when ``bucket_s`` is set."""

    channel: str
    unit: str
    # each sample's Unix time, or each bucket's start, oldest first
    t_s: list[float]
    # where each sample (or bucket) came from: tlm (the camera's unsolicited packet) or poll (the
    # daemon's GET_HOUSEKEEPING)
    source: list[Literal["tlm", "poll"]]
    # each sample's value; empty with bucket_s
    value: list[float]
    # each bucket's minimum; empty without bucket_s
    min: list[float]
    # each bucket's mean; empty without bucket_s
    mean: list[float]
    # each bucket's maximum; empty without bucket_s
    max: list[float]
    # each bucket's number of samples; empty without bucket_s
    count: list[int]


class HistoryResponse(TypedDict):
    """GET /api/v1/telemetry/history."""

    # the range's start, Unix time (inclusive)
    start_s: float
    # the range's end, Unix time (exclusive)
    end_s: float
    # the bucket width, null for every sample
    bucket_s: float | None
    # in the order asked
    channels: list[ChannelHistory]


class EventItem(TypedDict):
    """One event."""

    t_s: float
    level: Literal["info", "warning", "error"]
    source: str
    message: str


class EventsResponse(TypedDict):
    """GET /api/v1/events."""

    # newest last
    events: list[EventItem]


class ModeResponse(TypedDict):
    """POST /api/v1/mode."""

    mode: Literal["area", "tdi"]


class RegisterReading(TypedDict):
    """One register as read: raw value and its fields (enum fields by name)."""

    name: str
    address: int
    value: int
    fields: dict[str, int | str]


class RegistersResponse(TypedDict):
    """GET /api/v1/registers: every register of the map, in address order."""

    sensor: str
    bridge: str
    registers: list[RegisterReading]


class RegisterWriteResponse(TypedDict):
    """The registers written, as read back after the write (verified where the map allows)."""

    sensor: str
    written: list[RegisterReading]


class RegisterDifference(TypedDict):
    """The ``RegisterDifference`` document (its model has no docstring)."""

    name: str
    address: int
    expected: int
    actual: int


class RegisterDiffResponse(TypedDict):
    """The ``RegisterDiffResponse`` document (its model has no docstring)."""

    sensor: str
    against: str
    differences: list[RegisterDifference]


class RegisterConfig(TypedDict):
    """A whole sensor configuration: the configurable (RW/WO, non-volatile) registers."""

    sensor: str
    registers: dict[str, int]


class TimingResponse(TypedDict):
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
    gain: int | str | None
    offset: int | str | None
    readout_mode: int | str | None
    test_pattern: int | str | None
    # the register (or REG.field) that sets exposure_lines: write it with POST /api/v1/registers to
    # change the exposure
    exposure_register: str | None


class LaneResult(TypedDict):
    """The ``LaneResult`` document (its model has no docstring)."""

    lane: int
    tap: int
    eye_width: int
    slips: int
    shift: int
    locked: bool


class TrainResponse(TypedDict):
    """POST/GET /api/v1/train: the last LVDS link training."""

    sensor: str
    interface: str
    # locked on every lane and the PRBS check error-free
    trained: bool
    lanes: int
    locked_lanes: int
    locked: bool
    bit_errors: int
    verified_bits: int
    lane_results: list[LaneResult]
    # Unix time of the last training; None if the daemon has not trained since it started (or the
    # interface has nothing to train)
    t_s: float | None
    # Unix time the link lost that training (LINK_LOST, a camera restart): `trained` is then false
    # and the rest describes the last training; None while it holds
    lost_t_s: float | None
    # the link's training in one sentence
    summary: str


class StreamStats(TypedDict):
    """The host side of the stream: what the reader received and delivered."""

    # frames delivered to consumers, valid and in order
    frames: int
    # bytes of delivered frames, headers included
    bytes: int
    # frames never received (gaps in the frame counter)
    lost: int
    # frames with a bad header or payload CRC, discarded
    corrupt: int
    # frames cut short by the device, discarded
    short: int
    # frames dropped because the queue to consumers was full
    overruns: int
    # endpoint stalls cleared
    stalls: int
    # bulk reads that timed out
    timeouts: int
    # frames whose counter went backwards, discarded
    out_of_order: int
    # from the first to the last frame received
    elapsed_s: float
    # delivered pixel rate
    mpix_per_s: float
    # delivered byte rate, 1 MB = 1e6 bytes
    mbyte_per_s: float


class StreamResponse(TypedDict):
    """GET /api/v1/stream, and the answer of /stream/start, /stop and /acquire."""

    streaming: bool
    # mode of the current or last stream
    mode: Literal["area", "tdi"] | None
    # rows per frame (after binning)
    rows: int
    # columns per frame (after binning)
    cols: int
    # significant bits per pixel
    bits: int
    # TDI stage count in the frame headers (0 in area mode)
    stages: int
    binning: Literal["off", "2x2"]
    # frame period = TDI line period
    frame_period_s: float
    # 0 = until stopped
    frames_requested: int
    first_counter: int
    # frames the device says it produced, once ended
    frames_sent: int | None
    # why the stream (once ended) ended before all its frames were sent and delivered: the camera
    # ended it, or went away, or its recording failed; null if it did not, or was stopped on request
    ended_early: str | None
    # once ended: frames asked for that the camera did not send, stopped or ended early (ended_early
    # says why), by its own count or, if it could not say, those the host never accounted for; 0 for
    # a stream until stopped
    frames_not_sent: int
    # HDF5 file being (or last) recorded
    recording: str | None
    # frames of the recording on disk: what the file keeps if the daemon dies now (flushed at least
    # once a second; docs/stream.md "Crash safety")
    frames_flushed: int
    stats: StreamStats


class StreamFrameHeader(TypedDict):
    """One frame's header as the host received it (docs/stream.md "Frame format (version 1)"), with
    the payload CRC the host computed."""

    counter: int
    # device clock, end of window row 0's exposure
    timestamp_ns: int
    line_period_ns: int
    rows: int
    cols: int
    bits: int
    mode: Literal["area", "tdi"]
    stages: int
    stage_position: int
    flags: int
    payload_bytes: int
    # the header's payload CRC-32
    payload_crc32: int
    # CRC-32 of the payload as the host received it
    payload_crc32_host: int


class StreamHeadersResponse(TypedDict):
    """GET /api/v1/stream/headers: the first frames of the current or last stream."""

    # headers kept per stream (the first ones)
    kept_max: int
    # every frame whose header passed its checks, in order of arrival, including those the payload
    # CRC then rejected
    frames: list[StreamFrameHeader]


class BackgroundStatus(TypedDict):
    """GET /api/v1/live/background, and the answer of POST and DELETE there. While capturing (and
    after a failure) the geometry and counters are those of the frames taken so far; a field that
    does not apply is null."""

    # none: no background; capturing: averaging frames; ready: the mean is there (GET
    # /api/v1/live/background/frame); failed: see error
    state: Literal["none", "capturing", "ready", "failed"]
    # frames the capture averages
    frames_wanted: int | None
    # frames averaged so far
    frames_done: int | None
    rows: int | None
    cols: int | None
    # the frames' mode (area, tdi)
    mode: str | None
    # TDI stages in the frame headers (0 in area mode)
    stages: int | None
    # the device's counter of the first frame
    first_counter: int | None
    # ... and of the last frame averaged so far
    last_counter: int | None
    # Unix time the capture completed
    captured_t_s: float | None
    # completed captures since the daemon started
    seq: int | None
    # spatial mean of the background, DN
    mean_dn: float | None
    # spatial standard deviation of the background, DN
    std_dn: float | None
    # recordings started since it was captured, which hold it as /background (newest last, the last
    # 20)
    saved_to: list[str]
    # why the capture failed, and what to do
    error: str | None


class RoiDefinition(TypedDict):
    """One ROI as the daemon measures it."""

    name: str
    x: int
    y: int
    width: int
    height: int


class RoiList(TypedDict):
    """GET /api/v1/live/roi, and the answer of POST and DELETE there."""

    # the ROIs measured on every frame
    rois: list[RoiDefinition]
    # the frame height the ROIs were checked against
    rows: int | None
    # the frame width the ROIs were checked against
    cols: int | None


class RoiFrameStats(TypedDict):
    """One ROI's statistics on one frame (DN; null where not defined)."""

    mean_dn: float
    std_dn: float
    min_dn: float
    max_dn: float
    sum_dn: float
    # mean / std; null when std is 0
    snr: float | None
    # pixels at or above full scale (2^bits - 1)
    saturated: float
    # mean minus the background's; null without one
    bg_mean_dn: float | None


class RoiLatest(TypedDict):
    """The newest measured frame's statistics of every ROI."""

    counter: int
    timestamp_ns: int
    rois: dict[str, RoiFrameStats]


class RoiHistorySeries(TypedDict):
    """One ROI's statistics over the newest frames, oldest first (one value per frame)."""

    counter: list[int]
    mean_dn: list[float]
    std_dn: list[float]
    min_dn: list[float]
    max_dn: list[float]
    sum_dn: list[float]
    snr: list[float | None]
    saturated: list[float]
    bg_mean_dn: list[float | None]


class RoiStatsResponse(TypedDict):
    """GET /api/v1/live/roi/stats."""

    # ROI sets so far: a change of the ROIs starts a new history
    rois_seq: int
    # frames measured since the ROIs were last changed
    measured: int
    # frames the ROIs did not fit (a smaller window): not measured
    unfit: int
    latest: RoiLatest | None
    # per ROI, the newest `history` frames (none unless asked)
    history: dict[str, RoiHistorySeries]


class LivePixel(TypedDict):
    """GET /api/v1/live/pixel: one pixel of a live frame, raw (a binned viewer's readout)."""

    # the live frame
    seq: int
    # its device frame counter
    counter: int
    row: int
    col: int
    # the pixel as the camera sent it, DN
    raw_dn: int


class SnapshotSaved(TypedDict):
    """The answer of POST /api/v1/live/snapshot: what was written, on the daemon's computer."""

    # the live frame saved
    seq: int
    # its device frame counter
    counter: int
    # the TIFF, and the ROI statistics' CSV when an ROI measured the frame
    files: list[str]


class FocusLatest(TypedDict):
    """The newest frame's focus figures."""

    # the live frame's seq (GET /api/v1/live/frame)
    seq: int
    # the device's frame counter
    counter: int
    # when it was measured, s since the epoch
    t_s: float
    # grey-gradient sharpness G per target: 'frame' and each ROI's name; null where there is none
    # (an ROI the frame does not hold, a frame of zeros)
    values: dict[str, float | None]


class FocusBestModel(TypedDict):
    """A target's best focus figure since the last reset, and its frame."""

    value: float
    counter: int
    seq: int
    t_s: float


class FocusHistory(TypedDict):
    """The newest focus figures, oldest first (one entry per measured frame)."""

    seq: list[int]
    counter: list[int]
    t_s: list[float]
    # per target, its figure at each entry (null where it had none)
    values: dict[str, list[float | None]]


class FocusResponse(TypedDict):
    """GET /api/v1/live/focus, and the answer of DELETE /api/v1/live/focus/best."""

    # figures a second at most (of the live view's frames)
    rate_hz: float
    # figures are being measured: someone asked within the last watch_s
    watching: bool
    # measuring goes on this long after the last GET
    watch_s: float
    # figures measured since the daemon started
    measured: int
    latest: FocusLatest | None
    # per target, the best since the reset
    best: dict[str, FocusBestModel]
    history: FocusHistory


class ImageMotionBlock(TypedDict):
    """One block of consecutive TDI window frames and the image's motion measured from it
    (docs/physics.md §10; docs/motion.md, "The image's motion from the frames"). The figures are
    null when the block was not measurable (``why`` says what was missing)."""

    # the block's first frame counter
    counter_first: int
    # ... and its last (a gap inside is a lost frame)
    counter_last: int
    frames: int
    # pairs of frames registered
    pairs: int
    # M, as the frames' headers give it
    stages: int
    # the columns [first, last) measured
    columns: list[int]
    # Unix time the measurement ended
    measured_t_s: float
    # CPU time the measurement took
    cpu_s: float
    measurable: bool
    # pairs registered, or why the block could not be measured
    why: str
    # rows the image moved per line
    shift_along_px_per_line: float | None
    # columns per line
    shift_across_px_per_line: float | None
    shift_along_stderr_px: float | None
    shift_across_stderr_px: float | None
    # 1 - shift along: > 0 when the image is slow
    dv_over_v: float | None
    # its standard error (the shift's, through the rolling shutter's lag; null with fewer than 3
    # pairs)
    dv_over_v_stderr: float | None
    # M dV/V: the along-track smear, pixels
    m_dv_over_v: float | None
    # the image's drift angle from the columns
    theta_deg: float | None
    # a rolling shutter's lag between two rows of the frames, in line periods (T_row / T; twice that
    # for 2x2-binned frames; negative for a reverse scan; 0 for a global shutter): what turned the
    # frames' step into the image's speed
    row_lag_lines: float


class ImageMotionResponse(TypedDict):
    """GET /api/v1/live/motion: the image's motion measured from the streams' TDI windows."""

    # motion.image_measure: measuring at all
    enabled: bool
    frames_per_block: int
    columns_max: int
    # the most of one core the measurement takes
    cpu_fraction: float
    # blocks measured since the daemon started
    blocks_measured: int
    # TDI frames the streams delivered meanwhile
    tdi_frames_seen: int
    # ... of which in a measured block
    frames_measured: int
    # CPU time of all the measurements
    cpu_s: float
    latest: ImageMotionBlock | None
    # the newest blocks, oldest first
    history: list[ImageMotionBlock]


class StageResponse(TypedDict):
    """The ``StageResponse`` document (its model has no docstring)."""

    speed_m_s: float
    sync_speed_m_s: float
    track: bool


class SimStreamStats(TypedDict):
    """GET /api/v1/sim/stream: what the simulated camera's stream engine did and injected."""

    produced: int
    sent: int
    dropped: int
    corrupted: int
    shortened: int
    stalls: int
    undelivered: int


class ScanTiming(TypedDict):
    """The timing a scan runs at (docs/physics.md §2 eqs 5-9, 13)."""

    # T_line,TDI: the frame period the registers set
    tdi_line_period_s: float
    # T_line,roll: the sensor's row time
    row_period_s: float
    # window rows, eq 8
    n_lines: int
    # T_back, eq 9
    back_path_s: float
    # M0 = n_lines, eq 13
    max_stages: int
    exposure_s: float
    # stage speed that moves the image one row a period
    sync_speed_m_s: float
    # the stage speed the scan runs at (null: not known to camd)
    stage_speed_m_s: float | None
    # (V - V_m) / V, docs/physics.md §6; null if unknown
    dv_over_v: float | None


class ScanImageLoopInfo(TypedDict):
    """A scan's image loop (docs/motion.md, "Closing the loop on the image")."""

    # blocks it has acted on
    updates: int
    # the line period it set last
    line_period_s: float
    # the drift taps' columns per line it set last
    cols_per_line: float
    # a limit (motion.max_trim, the drift's) held it back
    limited: bool
    # why it stopped, if it did (the scan goes on)
    error: str | None


class ScanImageMotion(TypedDict):
    """The image's motion measured from blocks of a scan's frames (docs/motion.md, "The image's
    motion from the frames"): the newest block and the means over the measurable ones (null
    before the first)."""

    # blocks of the scan's frames measured
    blocks: int
    # ... of which measurable
    measurable_blocks: int
    # mean dV/V (> 0: the image is slow)
    dv_over_v_mean: float | None
    # mean M dV/V, pixels of smear
    m_dv_over_v_mean: float | None
    # mean drift angle, degrees
    theta_deg_mean: float | None
    # standard error of the mean dV/V from the blocks' scatter (2 blocks or more)
    dv_over_v_sem: float | None
    latest: ImageMotionBlock | None
    # the image loop's state (null: the scan does not run one)
    loop: ScanImageLoopInfo | None


class ScanMotionInfo(TypedDict):
    """How a scan drove the stage (docs/motion.md)."""

    # off, step_rate or line_period
    closed_loop: str
    # signed speed the stage was commanded: sync x (1 - dv_over_v)
    stage_speed_m_s: float
    # the speed the closed loop held
    target_speed_m_s: float
    # closed-loop polls recorded
    loop_samples: int
    # why the loop stopped early, if it did
    loop_error: str | None
    # line-period correction hit n_lines = M (it could not shorten further)
    line_period_limited: bool


class ScanResponse(TypedDict):
    """GET /api/v1/scan, and the answer of /scan/start, /stop and /stages."""

    state: Literal["none", "starting", "running", "done", "stopped", "ended_early", "failed"]
    # the HDF5 file of the current or last scan
    file: str | None
    # its PNG quicklook, once written
    quicklook: str | None
    # M now
    stages: int
    # complete lines asked for; 0 = until stopped
    lines_wanted: int
    frames_requested: int
    # TDI lines recorded so far
    lines: int
    # lines with all M stages from consecutive frames
    complete_lines: int
    # lines on disk: what the file keeps if the daemon dies now (flushed at least once a second;
    # docs/stream.md "Crash safety")
    lines_flushed: int
    # frames the stream never delivered
    lost_frames: int
    # once ended: frames the scan asked for that the camera never sent (the scan was stopped, failed
    # or ended early: state and error say why), by its own count or, if it could not say (it died),
    # those the host never accounted for
    not_sent_frames: int
    # [line index, stages] for the start and every change
    stage_changes: list[list[int]]
    mode: Literal["sum", "mean"]
    width: int
    elapsed_s: float
    lines_per_s: float
    # the daemon's CPU time over the scan's wall time (1.0 = one core busy)
    cpu_load: float
    # CPU time of the TDI worker thread
    tdi_cpu_s: float
    # frames received but not yet through the engine
    backlog_frames: int
    timing: ScanTiming | None
    # why the scan failed, if it did
    error: str | None
    stream: StreamStats
    # largest M |dV/V| of a line (pixels of smear; docs/physics.md §6), from the encoder counts in
    # the frame headers; null without encoder data
    mismatch_max: float | None
    # RMS of M dV/V over the scan's lines
    mismatch_rms: float | None
    # the last graded batch's largest M |dV/V| (pixels): the figure now, beside the scan's max and
    # RMS; null without encoder data
    mismatch_last: float | None
    # ok, yellow or red: the worst level reached
    mismatch_level: str
    # the stage's part of the scan, if driven
    motion: ScanMotionInfo | None
    # the image's motion measured from the scan's frames (null: not measured, motion.image_measure =
    # false)
    image_motion: ScanImageMotion | None


class StageReadingModel(TypedDict):
    """The scan stage at one device time (SI: m, m/s)."""

    # disabled, idle, ramping, running, moving, homing, estop
    state: str
    homed: bool
    # commanded position (step count)
    position_m: float
    # measured position (encoder)
    encoder_m: float
    # commanded speed now, ramps included
    speed_m_s: float
    # the encoder's speed over the last 10 ms
    encoder_speed_m_s: float
    # none, low or high: a soft limit the stage stands at
    at_limit: str
    # device time of the sample
    time_s: float


class StageLimitsModel(TypedDict):
    """Soft travel limits, speed limit and ramp acceleration in force."""

    low_m: float
    high_m: float
    max_speed_m_s: float
    accel_m_s2: float


class StageOperationModel(TypedDict):
    """The last move or homing started through the API, for a client to follow it (docs/motion.md,
    "Waiting for a move or a homing"). Times are the device's clock."""

    # numbers the moves and homings since the daemon started
    seq: int
    # move (to target_m) or home
    kind: Literal["move", "home"]
    # still under way: the stage is moving (homing) for this operation
    active: bool
    # commanded position when it started
    start_m: float
    # move: the target; home: null (0 once homed)
    target_m: float | None
    # move: cruise speed; home: the homing speed
    speed_m_s: float
    # the device's estimate of its duration
    expected_duration_s: float
    # device time when it started
    started_time_s: float
    # device time since it started, at this reading
    elapsed_s: float
    # expected_duration_s - elapsed_s, at least 0
    remaining_s: float
    # 0..1: move, distance covered of the whole; home, time elapsed of the expected (1 once
    # finished)
    fraction_done: float


class MotionStatus(TypedDict):
    """GET /api/v1/motion: the stage, its limits and the synchronisation settings."""

    # config/stages/<profile>.toml
    profile: str
    # linear or turntable
    kind: str
    reading: StageReadingModel
    limits: StageLimitsModel
    # what a scan's closed loop trims, or off
    closed_loop: str
    # M |dV/V| yellow limit
    yellow: float
    # M |dV/V| red limit
    red: float
    # the last move or homing started through the API (null: none since the daemon started, or a
    # scan or a jog took the stage since)
    operation: StageOperationModel | None


class SyncResponse(TypedDict):
    """GET /api/v1/motion/sync: the open-loop synchronisation (docs/physics.md §2 eqs 5-9, 13; §6)."""

    # TDI line period
    line_period_s: float
    # rolling line period T_line,roll (eq 4)
    row_time_s: float
    # window rows (eq 8)
    n_lines: int
    # back path (eq 9)
    back_path_s: float
    # largest stage count (eq 13)
    m0: int
    # M
    stages: int
    # synchronous stage speed, m/s (§6 eq 9)
    sync_speed: float
    # stepper rate for it, microsteps/s
    step_rate_hz: float
    # mismatch of the stage speed given, (V - V_m)/V
    dv_over_v: float
    # M dV/V: smear over M stages, pixels
    m_dv_over_v: float
    # image speed on the focal plane at sync speed
    image_speed_m_s: float
    # the stage speed the mismatch is for
    stage_speed_m_s: float
    stage_profile: str
    # focal-plane metres per metre of stage travel
    image_scale: float
    # pitch on the focal plane (doubled when binned)
    pixel_pitch_m: float
    # turntable only: table speed for the line period (eq 5)
    angular_velocity_rad_s: float | None
    # |M dV/V| within the yellow limit
    tolerance_ok: bool


class SimStageTruth(TypedDict):
    """GET /api/v1/sim/stage/truth: what the simulated stage really does."""

    position_m: float
    velocity_m_s: float
    missed_steps: int
    time_s: float


class StageRequest(TypedDict):
    """PUT /api/v1/sim/stage."""

    # follow the synchronous speed
    track: bool
    # speed when not tracking
    speed_m_s: float


class SimStageFaultsRequest(TypedDict):
    """PUT /api/v1/sim/stage/faults: the simulated stage's imperfections."""

    # relative step-rate error
    error: float
    # relative ripple amplitude
    ripple: float
    # relative RMS speed jitter
    jitter: float
    # relative drift per second
    drift: float
    # load / pull-out torque
    load: float


class SimSettings(TypedDict):
    """GET /api/v1/sim: what this daemon last set on the simulated camera (the simulator cannot be
    asked), so that a client can put it back."""

    # false on real hardware (every sim request is refused)
    available: bool
    # the scene spec in front of the camera
    scene: str
    # the ideal scan stage: track, or a speed
    ideal_stage: StageRequest
    # reference polariser axis; null: out
    polarizer_deg: float | None
    # the stepper stage's imperfections
    stage_faults: SimStageFaultsRequest


class WheelChannelInfo(TypedDict):
    """One channel of the wheel (config/wheel.toml)."""

    # index, 0 .. channel_count - 1
    channel: int
    name: str
    band: str
    # wheel angle of the channel centre
    centre_deg: float
    # transmission axis of its polariser when centred; null: no polariser
    polarizer_deg: float | None


class WheelExposureInfo(TypedDict):
    """camd's computation for one exposure through the wheel (docs/physics.md §4 eqs 1, 4-6, 8)."""

    # T_exp = n T_line
    exposure_s: float
    # n
    exposure_lines: int
    # k
    window_rows: int
    # T_line
    line_period_s: float
    # T_frame = (n + k + 1) T_line (eq 6)
    frame_time_s: float
    # T_delay = T_center - T_frame / 2 (eq 5), negative when it cannot be centred
    delay_s: float
    # whether the delay is applied
    compensated: bool
    # the frame fits the light window (and T_delay >= 0 if on)
    fits: bool
    # why it does not fit, with the numbers; else null
    refusal: str | None
    # delay waited after each entry pulse: T_delay on, 0 off; null if no fit
    applied_delay_s: float | None
    # imaging centre minus channel centre (eq 4; eq 1 without compensation)
    centre_offset_deg: float | None
    # its uncertainty (eq 8)
    centre_error_deg: float | None


class WheelStatus(TypedDict):
    """GET /api/v1/wheel and the answers of PUT /wheel/speed and /wheel/compensation."""

    # config/wheel.toml's wheel name
    wheel: str
    # angular speed now (0: stopped)
    speed_deg_s: float
    # the wheel file's w, for which T_center holds
    nominal_speed_deg_s: float
    # time per revolution; null when stopped
    period_s: float | None
    # wheel angle from channel 0's centre, 0 .. 360
    angle_deg: float
    # channel whose light window is in front; else null
    channel: int | None
    # exposure delay compensation on
    compensation: bool
    # entry pulse to channel centre
    t_center_s: float
    # light window of a channel
    window_s: float
    # T_frame as the FPGA computes it
    device_frame_time_s: float
    # T_delay as the FPGA computes it
    device_delay_s: float
    # camd's numbers for the registers now
    exposure: WheelExposureInfo
    channels: list[WheelChannelInfo]
    # device time of the reading
    time_s: float


class WheelFrame(TypedDict):
    """One frame of a wheel acquisition."""

    # frame counter
    counter: int
    channel: int
    # channel name
    name: str
    # wheel angle at the exposure start, from the frame header (1e-4 deg)
    start_angle_deg: float
    # predicted imaging-centre angle: channel centre + centre_offset_deg
    centre_deg: float
    # imaging centre minus channel centre (eq 4)
    centre_offset_deg: float
    # uncertainty of the imaging centre (eq 8)
    centre_error_deg: float
    # imaging centre from the header: start angle + w T_frame / 2
    header_centre_deg: float
    # mean signal of the frame (or region), DN
    mean: float
    # device time at the end of row 0's exposure
    timestamp_s: float


class WheelRegion(TypedDict):
    """A rectangle of the frame whose mean is reported (rows and columns from 0)."""

    # first row
    row: int
    # rows
    rows: int
    # first column
    col: int
    # columns
    cols: int


class WheelAcquireResponse(TypedDict):
    """POST /api/v1/wheel/acquire: per frame, where it was taken and its mean signal."""

    channels: list[int]
    passes: int
    # wheel speed during the acquisition
    speed_deg_s: float
    # the exposure the frames were taken with
    exposure: WheelExposureInfo
    # T_frame as the FPGA computes it (WHEEL_GET after the frames; null if unread)
    device_frame_time_s: float | None
    # delay the FPGA applies after each entry pulse (0 with compensation off)
    device_delay_s: float | None
    region: WheelRegion | None
    # the frames received, in order
    frames: list[WheelFrame]
    # the stream document: counters, recording
    stream: StreamResponse


class CampaignJob(TypedDict):
    """One campaign job: what runs, where its files go, how far it is."""

    id: int
    # the campaign's name
    campaign: str
    # the camera profile it is written for
    profile: str
    # the campaign file it runs
    file: str
    # its output directory: state, raw files, results, report
    out_dir: str
    quick: bool
    # the client that started it (it may pause and abort)
    started_by: str
    state: Literal[
        "running",
        "pausing",
        "paused",
        "aborting",
        "aborted",
        "passed",
        "failed",
        "error",
        "interrupted",
    ]
    # step instances in a run; null: not known ahead
    steps: int | None
    # steps done, as its worker last said
    done: int | None
    # what its worker last said it does
    activity: str | None
    # Unix time it was started
    created_t_s: float
    # a pause or abort asked for and not yet done (the worker reads it)
    requested: Literal["pause", "abort"] | None
    # its workers' wall time, summed over resumes
    run_time_s: float
    # workers started: 1, plus 1 per resume
    runs: int
    # why it paused, failed or ended
    message: str | None
    # every check passed (null until it has ended)
    passed: bool | None
    # its HTML report, once written
    report: str | None


class CampaignJobsResponse(TypedDict):
    """GET /api/v1/campaigns/jobs."""

    jobs: list[CampaignJob]
