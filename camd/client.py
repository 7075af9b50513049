"""A small typed client of the camd HTTP API (docs/api.md), for camctl and for any script.

Every method returns the API's JSON document as a plain dict, typed with the TypedDicts of
``camd.client_types``: those are generated from the API's pydantic models
(camd/daemon/models/) by ``python -m camd.daemon.client_types_gen``, so they name exactly the
keys the daemon sends, and are named after the models (``StatusResponse``, ``ScanResponse``, ...).
A request's optional keys are typed by ``camd.client_requests``, generated from the same models:
only the keys given are sent, so that each default is the daemon's model's.
Failures raise ``CamdError`` built from the API's ``{"error", "code"}`` body, or
``DaemonUnreachable`` when nothing answers at the URL::

    from camd.client import CamdClient, CamdError

    with CamdClient() as cam:                   # $CAMD_URL or http://127.0.0.1:8422
        print(cam.status()["state"])
        result = cam.ping(count=100)
        print(result["rtt_ms"]["p99"])
"""

from __future__ import annotations

import contextlib
import getpass
import json
import os
import socket
import threading
import time
from collections.abc import Callable, Iterator
from typing import TYPE_CHECKING, Any, Unpack, cast

import httpx

from camd.client_requests import ScanRequestOptions
from camd.client_types import (
    BackgroundStatus,
    CampaignJob,
    CampaignJobsResponse,
    ControlInfo,
    EstopResponse,
    EstopState,
    EventsResponse,
    HistoryResponse,
    LinkCommandResponse,
    LinkResponse,
    ModeResponse,
    MotionStatus,
    PingResponse,
    RegisterConfig,
    RegisterDiffResponse,
    RegisterReading,
    RegistersResponse,
    RegisterWriteResponse,
    ScanResponse,
    SimSettings,
    SimStageTruth,
    SimStreamStats,
    StageResponse,
    StatusResponse,
    StreamHeadersResponse,
    StreamResponse,
    SyncResponse,
    TelemetryResponse,
    TimingResponse,
    TrainResponse,
    WheelAcquireResponse,
    WheelRegion,
    WheelStatus,
)

if TYPE_CHECKING:
    import numpy as np
    import numpy.typing as npt

__all__ = [
    "DEFAULT_URL",
    "CamdClient",
    "CamdError",
    "DaemonUnreachable",
]

DEFAULT_URL = "http://127.0.0.1:8422"
API = "/api/v1"
CLIENT_HEADER = "X-Camd-Client"


def default_client_name() -> str:
    """``user@host``: the name a client is known by for control unless told otherwise."""
    try:
        user = getpass.getuser()
    except (KeyError, OSError):
        user = str(os.getuid())
    return f"{user}@{socket.gethostname()}"


# Upper bound on one ping's wall time used to size the HTTP timeout of a ping run: the daemon
# pings strictly one at a time and a lost frame costs at most a few link timeouts of ~0.1 s, so
# a long run must not be cut off by the client's ordinary per-request timeout.
_PING_ALLOWANCE_S = 0.05

# Waiting for a stage move or homing (``CamdClient.wait_stage``): the request that starts it
# answers at once and the client polls GET /motion. The wait lasts the daemon's estimate of the
# operation plus a margin; past that it goes on while the stage still makes progress, for at most
# as long again (and at least STAGE_EXTRA_MIN_S), then fails naming what to do.
STAGE_POLL_S = 0.2
STAGE_MARGIN_MIN_S = 5.0  # at least this beyond the estimate
STAGE_MARGIN_FRACTION = 0.1  # or this fraction of it, whichever is more
STAGE_EXTRA_MIN_S = 30.0
STAGE_STALL_S = 3.0  # past the estimate, no progress for this long is a stall
STAGE_PROGRESS_M = 1e-6  # a change of position that counts as progress
STAGE_WAIT_MAX_S = 600.0  # a daemon that gives no estimate (older camd): wait at most this
STOPPED_STATES = frozenset({"idle", "disabled", "estop"})  # camd.motion.stage.STOPPED_STATES

StageProgress = Callable[[MotionStatus], None]
"""Called with each motion document polled while ``wait_stage`` waits."""


# -- errors ---------------------------------------------------------------------------------------


class CamdError(Exception):
    """The daemon refused or failed a request.

    ``message`` is the API's ``error`` text (it says what to change), ``code`` its ``code``
    (``bad_request``, ``illegal_state``, ``device_nak``, ...; see docs/api.md) and
    ``http_status`` the HTTP status, or None when no HTTP answer was received.
    """

    def __init__(self, message: str, code: str = "error", http_status: int | None = None) -> None:
        super().__init__(message)
        self.message = message
        self.code = code
        self.http_status = http_status

    def __repr__(self) -> str:
        return (
            f"{type(self).__name__}({self.message!r}, code={self.code!r}, "
            f"http_status={self.http_status!r})"
        )


class DaemonUnreachable(CamdError):
    """Nothing answers at the daemon's URL (not running, wrong URL or port)."""

    def __init__(self, url: str, detail: str) -> None:
        super().__init__(
            f"no camd daemon answers at {url} ({detail}); is `camd serve` running? "
            "start it with `camd serve --sim`, or point --url / $CAMD_URL at it",
            code="unreachable",
            http_status=None,
        )
        self.url = url


# -- the client -----------------------------------------------------------------------------------


def normalise_url(url: str) -> str:
    """Return ``url`` with a scheme (``localhost:8422`` -> ``http://localhost:8422``), no trailing
    slash. Raises ValueError naming the URL if it cannot be an HTTP URL."""
    text = url.strip()
    if "://" not in text:
        text = "http://" + text
    try:
        parsed = httpx.URL(text)
    except httpx.InvalidURL as exc:
        raise ValueError(f"bad daemon URL {url!r} ({exc}); write e.g. {DEFAULT_URL}") from None
    if parsed.scheme not in ("http", "https") or not parsed.host:
        raise ValueError(f"bad daemon URL {url!r}; write e.g. {DEFAULT_URL}")
    return text.rstrip("/")


class CamdClient:
    """Client of one camd daemon.

    ``url`` defaults to ``$CAMD_URL``, else ``http://127.0.0.1:8422``; ``token`` to
    ``$CAMD_TOKEN`` (sent as ``Authorization: Bearer``). ``timeout_s`` bounds each request,
    except that ``ping`` extends it with the number of pings. ``client`` is the name the daemon
    knows this client by for control (``X-Camd-Client``): ``$CAMD_CLIENT``, else ``user@host``.
    """

    def __init__(
        self,
        url: str | None = None,
        *,
        token: str | None = None,
        timeout_s: float = 30.0,
        client: str | None = None,
    ) -> None:
        if timeout_s <= 0:
            raise ValueError(f"timeout_s must be > 0 seconds, got {timeout_s}")
        self.url = normalise_url(url or os.environ.get("CAMD_URL") or DEFAULT_URL)
        self.timeout_s = timeout_s
        self.client = client or os.environ.get("CAMD_CLIENT") or default_client_name()
        token = token if token is not None else os.environ.get("CAMD_TOKEN")
        headers = {"Accept": "application/json", CLIENT_HEADER: self.client}
        if token:
            headers["Authorization"] = f"Bearer {token}"
        self._http = httpx.Client(base_url=self.url, headers=headers, timeout=timeout_s)

    def close(self) -> None:
        """Close the connection pool."""
        self._http.close()

    def __enter__(self) -> CamdClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"CamdClient({self.url!r})"

    # -- endpoints ------------------------------------------------------------------------------

    def status(self) -> StatusResponse:
        """The daemon's state, mode, link, device status and identity."""
        return cast(StatusResponse, self._json("GET", f"{API}/status"))

    def ping(self, count: int = 10, size: int = 16) -> PingResponse:
        """Have the daemon ping the device ``count`` times with ``size``-byte payloads."""
        timeout = self.timeout_s + _PING_ALLOWANCE_S * max(count, 0)
        body = {"count": count, "size": size}
        return cast(PingResponse, self._json("POST", f"{API}/ping", json=body, timeout=timeout))

    def link_command(
        self,
        command: str | None = None,
        *,
        opcode: int | None = None,
        fields: dict[str, int | float | str] | None = None,
        payload: bytes | None = None,
        repeat: bool = False,
    ) -> LinkCommandResponse:
        """Send one COMMAND frame (POST /api/v1/link/command): ``command`` by name with
        ``fields`` (checked by the dictionary), or any ``opcode`` / ``payload`` unchecked; with
        ``repeat`` the identical frame goes twice. Returns the ACK or NAK (both with repeat);
        a NAK is an answer here, not an error. Needs control."""
        body: dict[str, Any] = {"repeat": repeat}
        if command is not None:
            body["command"] = command
        if opcode is not None:
            body["opcode"] = opcode
        if fields is not None:
            body["fields"] = fields
        if payload is not None:
            body["payload_hex"] = payload.hex()
        return cast(LinkCommandResponse, self._json("POST", f"{API}/link/command", json=body))

    def link(self) -> LinkResponse:
        """Host and device counters of the command link."""
        return cast(LinkResponse, self._json("GET", f"{API}/link"))

    def telemetry(self) -> TelemetryResponse:
        """Latest value of every telemetry channel, sample count and archive path."""
        return cast(TelemetryResponse, self._json("GET", f"{API}/telemetry"))

    def history(
        self, channel: str, since_s: float | None = None, limit: int | None = None
    ) -> HistoryResponse:
        """Archived samples of one telemetry channel. ``since_s`` is a Unix time, or a negative
        number of seconds before now; ``limit`` caps the number of samples."""
        params: dict[str, str | int | float] = {"channel": channel}
        if since_s is not None:
            params["since_s"] = since_s
        if limit is not None:
            params["limit"] = limit
        return cast(HistoryResponse, self._json("GET", f"{API}/telemetry/history", params=params))

    def events(self, limit: int | None = None) -> EventsResponse:
        """Recent events, newest last."""
        params: dict[str, int] = {} if limit is None else {"limit": limit}
        return cast(EventsResponse, self._json("GET", f"{API}/events", params=params))

    def set_mode(self, mode: str) -> ModeResponse:
        """Select the imaging mode, ``area`` or ``tdi`` (the daemon checks the value)."""
        return cast(ModeResponse, self._json("POST", f"{API}/mode", json={"mode": mode}))

    def reset(self) -> StatusResponse:
        """Soft-reset the device; returns the status afterwards."""
        return cast(StatusResponse, self._json("POST", f"{API}/reset"))

    # -- sensor -----------------------------------------------------------------------------------

    def registers(self) -> RegistersResponse:
        """Every sensor register, in address order."""
        return cast(RegistersResponse, self._json("GET", f"{API}/registers"))

    def read_register(self, key: str | int) -> RegisterReading:
        """One register by name or address."""
        return cast(RegisterReading, self._json("GET", f"{API}/registers/{key}"))

    def write_registers(self, values: dict[str, int | str]) -> RegisterWriteResponse:
        """Write registers by name (REG, REG.field, GROUP); all or nothing, verified."""
        return cast(
            RegisterWriteResponse, self._json("POST", f"{API}/registers", json={"values": values})
        )

    def diff_registers(self, values: dict[str, int] | None = None) -> RegisterDiffResponse:
        """Registers differing from their reset values, or from ``values`` when given."""
        body: dict[str, Any] = (
            {"against": "reset"} if values is None else {"against": "values", "values": values}
        )
        return cast(RegisterDiffResponse, self._json("POST", f"{API}/registers/diff", json=body))

    def register_config(self) -> RegisterConfig:
        """The whole configuration (RW and WO non-volatile registers)."""
        return cast(RegisterConfig, self._json("GET", f"{API}/registers/config"))

    def load_register_config(self, config: RegisterConfig) -> RegisterWriteResponse:
        """Write a whole configuration (refused whole if invalid or for another sensor)."""
        return cast(
            RegisterWriteResponse, self._json("PUT", f"{API}/registers/config", json=dict(config))
        )

    def timing(self) -> TimingResponse:
        """The timing the sensor's registers set."""
        return cast(TimingResponse, self._json("GET", f"{API}/timing"))

    def train(self) -> TrainResponse:
        """Train the sensor's LVDS link now."""
        return cast(TrainResponse, self._json("POST", f"{API}/train"))

    def last_training(self) -> TrainResponse:
        """The last training result."""
        return cast(TrainResponse, self._json("GET", f"{API}/train"))

    # -- the frame stream --------------------------------------------------------------------

    def stream(self) -> StreamResponse:
        """The current or last stream and the host's ingest counters."""
        return cast(StreamResponse, self._json("GET", f"{API}/stream"))

    def start_stream(
        self,
        frames: int = 0,
        *,
        mode: str | None = None,
        stages: int | None = None,
        binning: str = "off",
        record: str | None = None,
    ) -> StreamResponse:
        """Start streaming and return at once (0 frames = until ``stop_stream``)."""
        body = _stream_body(frames, mode, stages, binning, record, None)
        return cast(StreamResponse, self._json("POST", f"{API}/stream/start", json=body))

    def acquire(
        self,
        frames: int,
        *,
        mode: str | None = None,
        stages: int | None = None,
        binning: str = "off",
        record: str | None = None,
        timeout_s: float | None = None,
    ) -> StreamResponse:
        """Take ``frames`` frames (recording them to the new HDF5 file ``record`` on the daemon's
        host, if given: relative = in its data directory's recordings, docs/api.md "Files") and
        return the counters when the stream has ended."""
        body = _stream_body(frames, mode, stages, binning, record, timeout_s)
        # The daemon bounds the acquisition (by timeout_s, or twice the expected time); the
        # answer may take that long, so only connecting is bounded by the client's timeout.
        read_s = None if timeout_s is None else timeout_s + 30.0
        timeout = httpx.Timeout(self.timeout_s, read=read_s)
        return cast(
            StreamResponse, self._json("POST", f"{API}/stream/acquire", json=body, timeout=timeout)
        )

    def stop_stream(self) -> StreamResponse:
        """Stop the stream (harmless when not streaming)."""
        return cast(StreamResponse, self._json("POST", f"{API}/stream/stop"))

    def stream_headers(self) -> StreamHeadersResponse:
        """The headers of the first frames of the current or last stream, with the payload
        CRC the host computed for each (frames the payload CRC rejected included)."""
        return cast(StreamHeadersResponse, self._json("GET", f"{API}/stream/headers"))

    # -- the live view's background ------------------------------------------------------------

    def capture_background(self, frames: int = 16) -> BackgroundStatus:
        """Start averaging the next ``frames`` (1..1000) frames of the running stream into the
        live view's background and return at once; ``background()`` shows when it is ready."""
        return cast(
            BackgroundStatus,
            self._json("POST", f"{API}/live/background", json={"frames": frames}),
        )

    def background(self) -> BackgroundStatus:
        """The background's state: none, capturing, ready or failed."""
        return cast(BackgroundStatus, self._json("GET", f"{API}/live/background"))

    def background_frame(self) -> tuple[dict[str, Any], npt.NDArray[np.float32]]:
        """The ready background: its description (seq, frames, rows, cols, mode, stages,
        first_counter, last_counter, captured_t_s, mean_dn, std_dn, dtype) and its pixels,
        float32 DN, shape (rows, cols)."""
        import numpy as np  # only here: the rest of the client needs no numpy

        response = self._request("GET", f"{API}/live/background/frame")
        meta = json.loads(response.headers["X-Camd-Background"])
        pixels = np.frombuffer(response.content, dtype="<f4").reshape(meta["rows"], meta["cols"])
        return meta, pixels.astype(np.float32)

    def clear_background(self) -> BackgroundStatus:
        """Drop the background (and stop a capture)."""
        return cast(BackgroundStatus, self._json("DELETE", f"{API}/live/background"))

    def live_lines(
        self, after: int = -1, *, max_lines: int = 512, timeout_s: float = 0.0
    ) -> tuple[dict[str, Any], npt.NDArray[np.float32]]:
        """The live view's lines of the running (or last) TDI scan with index > ``after``:
        their description (scan, scan_seq, first_index, n, cols, index, complete, stages_used,
        skipped, lines_done, lines_planned, state, dtype) and the lines, float32, shape
        (n, cols). With none newer the daemon waits up to ``timeout_s`` (0..5) for one, then
        answers n = 0. CamdError ``no_scan`` before the daemon's first scan."""
        import numpy as np  # only here: the rest of the client needs no numpy

        params: dict[str, Any] = {"after": after, "max": max_lines, "timeout_s": timeout_s}
        timeout = self.timeout_s + max(0.0, timeout_s)
        response = self._request("GET", f"{API}/live/lines", params=params, timeout=timeout)
        meta = json.loads(response.headers["X-Camd-Lines"])
        lines = np.frombuffer(response.content, dtype="<f4").reshape(meta["n"], meta["cols"])
        return meta, lines.astype(np.float32)

    # -- the simulated camera -----------------------------------------------------------------

    def set_scene(self, spec: str) -> None:
        """Simulated camera only: the scene in front of it, e.g. ``"bars:lux=3"``."""
        self._request("PUT", f"{API}/sim/scene", json={"spec": spec})

    def set_sim_seed(self, seed: int) -> None:
        """Simulated camera only: restart its temporal noise and frame-fault random streams
        from ``seed`` (same seed, same following acquisitions; the fixed pattern is kept)."""
        self._request("PUT", f"{API}/sim/seed", json={"seed": seed})

    def set_stage(self, *, track: bool = True, speed_m_s: float = 0.0) -> StageResponse:
        """Simulated camera only: track the synchronous speed, or run at ``speed_m_s``."""
        body = {"track": track, "speed_m_s": speed_m_s}
        return cast(StageResponse, self._json("PUT", f"{API}/sim/stage", json=body))

    def scan(self) -> ScanResponse:
        """The current or last scan (``state`` "none" before the first)."""
        return cast(ScanResponse, self._json("GET", f"{API}/scan"))

    def start_scan(
        self, stages: int, lines: int, **options: Unpack[ScanRequestOptions]
    ) -> ScanResponse:
        """Start a push-broom scan of ``lines`` complete TDI lines at ``stages`` stages and
        return at once. ``options`` are ``ScanRequest``'s optional keys (camd/client_requests.py,
        with their defaults): only those given are sent, the daemon supplies the others.
        ``out`` is a path on the daemon's host (relative = in its data directory's scans;
        docs/api.md "Files"). The scan drives the stage at the synchronous speed
        (``drive_stage``), closed loop unless ``closed_loop`` is False (None: the config),
        offset by ``dv_over_v``."""
        body: dict[str, Any] = {"stages": stages, "lines": lines, **options}
        return cast(ScanResponse, self._json("POST", f"{API}/scan/start", json=body))

    def stop_scan(self) -> ScanResponse:
        """Stop the running scan; returns once its file is closed."""
        return cast(ScanResponse, self._json("POST", f"{API}/scan/stop"))

    # -- motion (docs/motion.md) -------------------------------------------------------------

    def motion(self) -> MotionStatus:
        """The scan stage: state, positions, speeds, limits."""
        return cast(MotionStatus, self._json("GET", f"{API}/motion"))

    def enable_stage(self, on: bool = True) -> MotionStatus:
        """Energise (or release) the stage motor; enabling clears an emergency stop."""
        return cast(MotionStatus, self._json("POST", f"{API}/motion/enable", json={"on": on}))

    def run_stage(self, speed_m_s: float) -> MotionStatus:
        """Ramp to a constant signed speed (m/s) and hold it; 0 stops."""
        body = {"speed_m_s": speed_m_s}
        return cast(MotionStatus, self._json("POST", f"{API}/motion/run", json=body))

    def move_stage(
        self,
        position_m: float,
        *,
        speed_m_s: float | None = None,
        wait: bool = True,
        progress: StageProgress | None = None,
    ) -> MotionStatus:
        """Move to ``position_m`` (metres from home) and stop. The request answers at once;
        with ``wait`` this then polls until the stage stands (``wait_stage``, which calls
        ``progress`` with each motion document) and returns the last document."""
        body = {"position_m": position_m, "speed_m_s": speed_m_s, "wait": False}
        doc = cast(MotionStatus, self._json("POST", f"{API}/motion/move", json=body))
        return self.wait_stage(doc, progress=progress) if wait else doc

    def stop_stage(self) -> MotionStatus:
        """Decelerate the stage to a stop."""
        return cast(MotionStatus, self._json("POST", f"{API}/motion/stop"))

    def home_stage(
        self, *, wait: bool = True, progress: StageProgress | None = None
    ) -> MotionStatus:
        """Find the home switch and zero the position there. The request answers at once;
        with ``wait`` this then polls until homing has finished (``wait_stage``)."""
        doc = cast(MotionStatus, self._json("POST", f"{API}/motion/home", json={"wait": False}))
        return self.wait_stage(doc, progress=progress) if wait else doc

    def wait_stage(
        self,
        started: MotionStatus | None = None,
        *,
        progress: StageProgress | None = None,
        poll_s: float = STAGE_POLL_S,
    ) -> MotionStatus:
        """Poll GET /motion until the move or homing of ``started`` (the answer that started it;
        default: the last one the daemon started) has finished and the stage stands; return
        that motion document. ``progress`` is called with every document polled.

        The wait follows the daemon's estimate (``operation.expected_duration_s``) plus a
        margin (10 %, at least 5 s); a stage still making progress past that is waited for
        longer, at most as long again (at least 30 s more). Raises CamdError ``timeout`` when
        the stage has not finished by then, or stopped making progress, and ``stage_taken``
        when another move, homing, jog or scan took the stage over; the stage is not stopped
        (``camctl stage stop`` does that).
        """
        doc = self.motion() if started is None else started
        op = doc.get("operation")
        seq = None if op is None else op["seq"]
        expected = None if op is None else op["expected_duration_s"]
        begun = time.monotonic()
        if expected is None:  # an older daemon gives no estimate: progress alone
            soft = hard = begun + STAGE_WAIT_MAX_S
        else:
            soft = begun + expected + max(STAGE_MARGIN_MIN_S, STAGE_MARGIN_FRACTION * expected)
            hard = soft + max(STAGE_EXTRA_MIN_S, expected)
        last_position = doc["reading"]["position_m"]
        moved_at = begun
        while True:
            if progress is not None:
                progress(doc)
            reading, now_op = doc["reading"], doc.get("operation")
            if seq is not None and (now_op is None or now_op["seq"] != seq):
                raise CamdError(
                    f"the stage's {op['kind'] if op else 'move'} was taken over by another "
                    f"command (the stage is {reading['state']} at "
                    f"{reading['position_m'] * 1e3:.3f} mm); see `camctl stage` and "
                    "`camctl events`; `camctl stage stop` stops it",
                    "stage_taken",
                )
            finished = now_op is None or not now_op["active"]
            if finished and reading["state"] in STOPPED_STATES:
                return doc
            now = time.monotonic()
            if abs(reading["position_m"] - last_position) > STAGE_PROGRESS_M:
                last_position, moved_at = reading["position_m"], now
            stalled = now - moved_at > STAGE_STALL_S
            if now > hard or (now > soft and stalled):
                what = "homing" if op is not None and op["kind"] == "home" else "moving"
                estimate = "" if expected is None else f" (expected {expected:.3g} s)"
                why = "" if not stalled else f", without progress for {now - moved_at:.3g} s"
                raise CamdError(
                    f"the stage is still {reading['state']} at "
                    f"{reading['position_m'] * 1e3:.3f} mm after {now - begun:.3g} s of "
                    f"{what}{estimate}{why}; it was not stopped: `camctl stage` shows it, "
                    "`camctl stage stop` stops it",
                    "timeout",
                )
            time.sleep(poll_s)
            doc = self.motion()

    def estop_stage(self) -> MotionStatus:
        """Emergency stop (no ramp, current cut) until ``enable_stage``."""
        return cast(MotionStatus, self._json("POST", f"{API}/motion/estop"))

    def sync(
        self,
        *,
        line_period_s: float | None = None,
        speed_m_s: float | None = None,
        stages: int | None = None,
        binning: bool = False,
    ) -> SyncResponse:
        """Open-loop synchronisation for a line period, a stage speed, both, or neither."""
        params: dict[str, Any] = {"binning": binning}
        for key, value in (
            ("line_period_s", line_period_s), ("speed_m_s", speed_m_s), ("stages", stages)
        ):  # fmt: skip
            if value is not None:
                params[key] = value
        return cast(SyncResponse, self._json("GET", f"{API}/motion/sync", params=params))

    def set_stage_faults(
        self,
        *,
        error: float = 0.0,
        ripple: float = 0.0,
        jitter: float = 0.0,
        drift: float = 0.0,
        load: float = 0.0,
    ) -> None:
        """Simulated camera only: the stepper stage's imperfections (as --inject stage_*)."""
        body = {"error": error, "ripple": ripple, "jitter": jitter, "drift": drift, "load": load}
        self._request("PUT", f"{API}/sim/stage/faults", json=body)

    def stage_truth(self) -> SimStageTruth:
        """Simulated camera only: the stage's true position, velocity and missed steps."""
        return cast(SimStageTruth, self._json("GET", f"{API}/sim/stage/truth"))

    def set_stages(self, stages: int) -> ScanResponse:
        """Change the running scan's TDI stage count from its next frame."""
        return cast(ScanResponse, self._json("PUT", f"{API}/scan/stages", json={"stages": stages}))

    def wait_scan(self, timeout_s: float | None = None, *, poll_s: float = 0.2) -> ScanResponse:
        """Poll until the current scan has ended; return its final document."""
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        while True:
            doc = self.scan()
            if doc["state"] not in ("starting", "running"):
                return doc
            if deadline is not None and time.monotonic() > deadline:
                raise CamdError(
                    f"the scan did not end within {timeout_s:g} s; see `camctl scan --status`",
                    "timeout",
                )
            time.sleep(poll_s)

    # -- the filter wheel (docs/wheel.md) ---------------------------------------------------

    def wheel(self) -> WheelStatus:
        """The filter wheel, with camd's numbers for the exposure in the registers."""
        return cast(WheelStatus, self._json("GET", f"{API}/wheel"))

    def set_wheel_speed(self, speed_deg_s: float) -> WheelStatus:
        """Turn the wheel at ``speed_deg_s`` (0 stops it)."""
        body = {"speed_deg_s": speed_deg_s}
        return cast(WheelStatus, self._json("PUT", f"{API}/wheel/speed", json=body))

    def set_wheel_compensation(self, on: bool) -> WheelStatus:
        """Exposure delay compensation on or off (refused if the exposure cannot fit)."""
        return cast(WheelStatus, self._json("PUT", f"{API}/wheel/compensation", json={"on": on}))

    def wheel_acquire(
        self,
        channels: list[int],
        *,
        passes: int = 1,
        exposure_s: float | None = None,
        compensated: bool | None = None,
        record: str | None = None,
        region: WheelRegion | None = None,
        timeout_s: float | None = None,
    ) -> WheelAcquireResponse:
        """One frame per channel per pass; returns each frame's imaging-centre angle, its
        uncertainty and mean. ``exposure_s`` / ``compensated`` are set first when given;
        ``record`` is a new HDF5 file on the daemon's host (as for ``acquire``)."""
        body: dict[str, Any] = {"channels": list(channels), "passes": passes}
        optional = {
            "exposure_s": exposure_s, "compensated": compensated, "record": record,
            "region": None if region is None else dict(region), "timeout_s": timeout_s,
        }  # fmt: skip
        body.update({k: v for k, v in optional.items() if v is not None})
        # The daemon bounds the acquisition itself (timeout_s, or per frame a revolution).
        read_s = None if timeout_s is None else timeout_s + 30.0
        timeout = httpx.Timeout(self.timeout_s, read=read_s)
        return cast(
            WheelAcquireResponse,
            self._json("POST", f"{API}/wheel/acquire", json=body, timeout=timeout),
        )

    def set_polarizer(self, angle_deg: float | None) -> None:
        """Simulated camera only: the reference polariser's axis in degrees (None: out)."""
        self._request("PUT", f"{API}/sim/polarizer", json={"angle_deg": angle_deg})

    def fail_next(
        self,
        command: str,
        *,
        skip: int = 0,
        error: str | None = None,
        duration_s: float | None = None,
        end_after_frames: int | None = None,
    ) -> None:
        """Simulated camera only: make the (skip + 1)-th next ``command`` (e.g.
        "REG_WRITE_BURST") fail, refused with a NAK of ``error`` (e.g. "BUSY"), lost because
        the camera drops off the line for ``duration_s``, or (START_STREAM, WHEEL_ACQUIRE)
        executed with the stream it starts ended by the camera after ``end_after_frames``
        frames; give one of the three."""
        body: dict[str, Any] = {"command": command, "skip": skip}
        if error is not None:
            body["error"] = error
        if duration_s is not None:
            body["duration_s"] = duration_s
        if end_after_frames is not None:
            body["end_after_frames"] = end_after_frames
        self._request("POST", f"{API}/sim/fail-next", json=body)

    def clear_fail_next(self) -> None:
        """Simulated camera only: disarm a failure armed with ``fail_next``."""
        self._request("DELETE", f"{API}/sim/fail-next")

    def sim_settings(self) -> SimSettings:
        """What the daemon last set on the simulated camera (scene, ideal stage, polariser,
        stage faults), so that it can be put back; ``available`` is false on hardware."""
        return cast(SimSettings, self._json("GET", f"{API}/sim"))

    def sim_stream_stats(self) -> SimStreamStats:
        """Simulated camera only: what its stream engine made, sent and injected."""
        return cast(SimStreamStats, self._json("GET", f"{API}/sim/stream"))

    def metrics(self) -> str:
        """The Prometheus text exposition."""
        return self._request("GET", "/metrics").text

    def control(self) -> ControlInfo:
        """Who holds control (reading needs none)."""
        return cast(ControlInfo, self._json("GET", f"{API}/control"))

    def take_control(self, ttl_s: float = 60.0, *, force: bool = False) -> ControlInfo:
        """Take (or renew) control for ``ttl_s`` seconds; CamdError ``not_in_control`` while
        another client holds it, unless ``force`` (a takeover the daemon logs)."""
        body = {"ttl_s": ttl_s, "force": force}
        return cast(ControlInfo, self._json("POST", f"{API}/control", json=body))

    def release_control(self) -> ControlInfo:
        """Give control back (harmless when this client holds none)."""
        return cast(ControlInfo, self._json("DELETE", f"{API}/control"))

    def set_activity(
        self, text: str, done: int | None = None, total: int | None = None
    ) -> ControlInfo:
        """Say what this client, holding control, is doing (``done`` of ``total`` steps), for
        observers to see in the control document until control is given back or taken over.
        CamdError ``not_in_control`` while another client holds control, ``no_control`` while
        nobody does."""
        body = {"text": text, "done": done, "total": total}
        return cast(ControlInfo, self._json("PUT", f"{API}/control/activity", json=body))

    @contextlib.contextmanager
    def holding_control(self, ttl_s: float = 60.0, *, force: bool = False) -> Iterator[ControlInfo]:
        """Hold control for a ``with`` block (a campaign, a script): taken at the start,
        renewed in the background every ``ttl_s / 3``, given back at the end."""
        doc = self.take_control(ttl_s, force=force)
        stop = threading.Event()
        renewer = CamdClient(self.url, timeout_s=self.timeout_s, client=self.client)
        renewer._http.headers.update(self._http.headers)

        def renew() -> None:
            while not stop.wait(ttl_s / 3):
                with contextlib.suppress(CamdError):
                    renewer.take_control(ttl_s)

        thread = threading.Thread(target=renew, name="camd-control-renew", daemon=True)
        thread.start()
        try:
            yield doc
        finally:
            stop.set()
            thread.join(5.0)
            renewer.close()
            with contextlib.suppress(CamdError):
                self.release_control()

    # -- campaign jobs (docs/campaigns.md, "Campaign jobs") ------------------------------------

    def campaign_jobs(self) -> CampaignJobsResponse:
        """Every campaign job the daemon knows, running or ended."""
        return cast(CampaignJobsResponse, self._json("GET", f"{API}/campaigns/jobs"))

    def campaign_job(self, job_id: int) -> CampaignJob:
        """One campaign job (CamdError ``not_found`` if there is none)."""
        return cast(CampaignJob, self._json("GET", f"{API}/campaigns/jobs/{job_id}"))

    def start_campaign(
        self, campaign: str, *, out: str | None = None, quick: bool = False
    ) -> CampaignJob:
        """Start a campaign job on the daemon (``campaign``: a campaign's name in the daemon's
        campaign directories, never a path; ``out``: its output directory there, relative = in
        the data directory's campaigns); returns at once with the job, which runs in the
        daemon's worker. Needs control (or free control), which passes to the job's worker."""
        body: dict[str, Any] = {"campaign": campaign, "quick": quick}
        if out is not None:
            body["out"] = out
        # The daemon checks the campaign in a process of its own first: allow it some time.
        timeout = httpx.Timeout(self.timeout_s, read=max(self.timeout_s, 90.0))
        return cast(
            CampaignJob, self._json("POST", f"{API}/campaigns/jobs", json=body, timeout=timeout)
        )

    def pause_campaign(self, job_id: int, *, force: bool = False) -> CampaignJob:
        """Pause a running job (its acquisition is stopped and done again on resume)."""
        path = f"{API}/campaigns/jobs/{job_id}/pause"
        return cast(CampaignJob, self._json("POST", path, json={"force": force}))

    def resume_campaign(self, job_id: int) -> CampaignJob:
        """Run a paused (or interrupted, or failed-with-an-error) job on from its state."""
        return cast(CampaignJob, self._json("POST", f"{API}/campaigns/jobs/{job_id}/resume"))

    def abort_campaign(self, job_id: int, *, force: bool = False) -> CampaignJob:
        """Abort a job (running: stopped as for a pause; paused: ended at once)."""
        path = f"{API}/campaigns/jobs/{job_id}/abort"
        return cast(CampaignJob, self._json("POST", path, json={"force": force}))

    def estop(self) -> EstopResponse:
        """Emergency stop (stage, acquisition, wheel, campaign job): never refused; it latches
        until ``release_estop``."""
        return cast(EstopResponse, self._json("POST", f"{API}/estop"))

    def estop_state(self) -> EstopState:
        """The emergency-stop latch."""
        return cast(EstopState, self._json("GET", f"{API}/estop"))

    def release_estop(self) -> EstopState:
        """Release the emergency-stop latch (needs control, or free control)."""
        return cast(EstopState, self._json("POST", f"{API}/estop/release"))

    def wait_ready(self, timeout_s: float = 10.0, *, poll_s: float = 0.1) -> StatusResponse:
        """Wait until the daemon answers and its camera is connected (state not
        ``disconnected``); return that status.

        Raises DaemonUnreachable if nothing answered within ``timeout_s``, CamdError (code
        ``timeout``) if the daemon answered but stayed disconnected, with its reason.
        """
        deadline = time.monotonic() + timeout_s
        last: CamdError | StatusResponse | None = None
        while True:
            try:
                doc = self.status()
                if doc.get("state") != "disconnected":
                    return doc
                last = doc
            except DaemonUnreachable as exc:
                last = exc
            if time.monotonic() >= deadline:
                break
            time.sleep(poll_s)
        if isinstance(last, CamdError):
            raise last
        reason = last.get("reason") if last is not None else None
        raise CamdError(
            f"the daemon at {self.url} is up but no camera connected within {timeout_s:g} s"
            f" ({reason or 'no reason given'}); check the camera link or start it with --sim",
            code="timeout",
        )

    # -- plumbing -------------------------------------------------------------------------------

    def _json(self, method: str, path: str, **kwargs: Any) -> dict[str, Any]:
        response = self._request(method, path, **kwargs)
        try:
            doc = response.json()
        except ValueError:
            raise CamdError(
                f"{method} {path}: the answer from {self.url} is not JSON "
                f"({_snippet(response.text)}); is this URL a camd daemon?",
                code="bad_response",
                http_status=response.status_code,
            ) from None
        if not isinstance(doc, dict):
            raise CamdError(
                f"{method} {path}: expected a JSON object from {self.url}, got {_snippet(doc)}",
                code="bad_response",
                http_status=response.status_code,
            )
        return doc

    def _request(self, method: str, path: str, **kwargs: Any) -> httpx.Response:
        try:
            response = self._http.request(method, path, **kwargs)
        except (httpx.ConnectError, httpx.ConnectTimeout) as exc:
            raise DaemonUnreachable(self.url, _reason(exc)) from None
        except httpx.TimeoutException:
            timeout = kwargs.get("timeout", self.timeout_s)
            raise CamdError(
                f"{method} {path}: the daemon at {self.url} did not answer within "
                f"{timeout:g} s; raise the timeout (camctl --timeout) or check the daemon's log",
                code="timeout",
            ) from None
        except httpx.TransportError as exc:
            # Connected but the exchange broke (daemon died mid-request, not an HTTP server).
            raise CamdError(
                f"{method} {path}: the connection to {self.url} failed ({_reason(exc)}); "
                "check that the daemon is still running and that the URL is camd's",
                code="transport",
            ) from None
        if response.is_success:
            return response
        raise _api_error(method, path, response)


def _api_error(method: str, path: str, response: httpx.Response) -> CamdError:
    """Build the CamdError of a non-2xx answer from its {"error", "code"} body."""
    try:
        body = response.json()
    except ValueError:
        body = None
    if isinstance(body, dict) and isinstance(body.get("error"), str):
        return CamdError(body["error"], str(body.get("code", "error")), response.status_code)
    if isinstance(body, dict) and "detail" in body:
        # A framework answer that bypassed camd's error handler (e.g. 404 for an unknown path).
        detail = body["detail"]
        text = detail if isinstance(detail, str) else json.dumps(detail)
        return CamdError(
            f"{method} {path}: HTTP {response.status_code}: {text}; is the daemon at "
            f"{response.url.copy_with(path='/')} a compatible camd version?",
            code="http_error",
            http_status=response.status_code,
        )
    return CamdError(
        f"{method} {path}: unexpected HTTP {response.status_code} "
        f"({_snippet(response.text) or 'empty body'}); is this URL a camd daemon?",
        code="http_error",
        http_status=response.status_code,
    )


def _reason(exc: Exception) -> str:
    text = str(exc).strip()
    return text or type(exc).__name__


def _snippet(value: object, limit: int = 120) -> str:
    text = value if isinstance(value, str) else repr(value)
    text = " ".join(text.split())
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _stream_body(
    frames: int,
    mode: str | None,
    stages: int | None,
    binning: str,
    record: str | None,
    timeout_s: float | None,
) -> dict[str, Any]:
    body: dict[str, Any] = {"frames": frames, "binning": binning}
    optional = {"mode": mode, "stages": stages, "record": record, "timeout_s": timeout_s}
    body.update({k: v for k, v in optional.items() if v is not None})
    return body
