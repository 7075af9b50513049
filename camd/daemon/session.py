"""The device session: composes the daemon's parts, owns their lifecycle, keeps the state.

``DeviceSession(config)`` builds one ``DeviceAccess`` (link, FIFO lock, state machine, event
log) and the services on it, each handed the device access and its peers, never the session:
telemetry (samples, limits, the archive, the event log read back), sensor, stream, motion,
scan, wheel, simulator control, the live view's background, control, campaign jobs, the
emergency stop, the link commands (ping, raw commands, counters), and the ``Connection``: the
simulated camera when ``link.device = "sim"`` (the backends are chosen in
``camd.daemon.backends``), the CommandLink, the probe after a connect, the housekeeping polls
and the service loop. ``start`` opens the archive, repairs what the last daemon left open and
opens the connection; ``abort`` and ``stop`` are the ordered shutdown.

The session answers what concerns the camera's state: ``status`` (state and reason, link,
the device's GET_STATUS, the daemon, control, acquisition, the emergency-stop latch),
``set_mode``, ``reset``, and who holds control (``control_info``, ``take_control``); each
checks the state machine first, so an illegal request never reaches the device. The API
reaches everything else through the services (``session.link_commands``,
``session.telemetry``, ``session.background``, ``session.estop``, ``session.campaigns``,
``session.stream`` ...).

Threads: the link's reader thread and the service loop are the connection's
(``camd.daemon.connection``); API requests run on the HTTP server's worker threads. Device
requests go through one FIFO lock so that a long ping run cannot starve the poll (and with it
the watchdog).
"""

from __future__ import annotations

import contextlib
import datetime as dt
import logging
import os
import threading
import time
from typing import Any, cast

import camd
from camd.daemon import backends
from camd.daemon.background_service import BackgroundService
from camd.daemon.campaign_service import CampaignService
from camd.daemon.config import Config
from camd.daemon.connection import Connection
from camd.daemon.control import ANONYMOUS, Control
from camd.daemon.device import DeviceAccess
from camd.daemon.errors import SessionError
from camd.daemon.estop_service import EstopService
from camd.daemon.link_commands import LinkCommands
from camd.daemon.models import (
    LIVE_LINES_MAX,
    AcquisitionInfo,
    ControlActivity,
    ControlInfo,
    DaemonInfo,
    DeviceStatus,
    ModeResponse,
    StatusResponse,
)
from camd.daemon.motion_service import MotionService
from camd.daemon.output_paths import RECORDINGS_FOLDER, SCANS_FOLDER
from camd.daemon.realtime import REALTIME
from camd.daemon.roi_service import RoiService
from camd.daemon.scan_apply import ScanApply
from camd.daemon.scan_service import ScanService
from camd.daemon.sensor_service import SensorService
from camd.daemon.simulator import SimulatorProcess
from camd.daemon.state import Request, State, Trigger
from camd.daemon.stream_service import StreamService
from camd.daemon.telemetry_service import TelemetryService
from camd.daemon.transaction import apply_one
from camd.daemon.wheel_service import WheelService
from camd.link import CommandLink, Response
from camd.pipeline.background import BackgroundCapture
from camd.pipeline.focus import FocusMonitor
from camd.pipeline.image_motion import ImageMotionMonitor
from camd.pipeline.image_motion import warm_up as warm_image_motion
from camd.pipeline.live import LiveLines, LiveTap
from camd.pipeline.live_transport import TransportEncoder
from camd.pipeline.roi import RoiMonitor
from camd.protocol import Dictionary, load_dictionary
from camd.sensor.profile import list_profiles, load_profile
from camd.store.journal import recover_left_open
from camd.tdi import warm_up

log = logging.getLogger(__name__)

THREAD_JOIN_S = 5.0  # at shutdown, the longest wait for one of camd's threads to end
SHUTDOWN_ENDING_S = 15.0  # ... for the acquisition to end and a job's worker to stop (abort)


def _rolling_shutter(sensor: str) -> bool:
    """Whether the camera profile of ``sensor`` says its shutter rolls (False without one)."""
    if sensor not in list_profiles():
        return False
    return load_profile(sensor).shutter.value == "rolling"


def _join_camd_threads(timeout_s: float) -> None:
    """Wait (at most ``timeout_s`` in all) for camd's worker threads (named ``camd-*``) to end;
    log those that do not: nothing of camd may run on while the interpreter exits."""
    deadline = time.monotonic() + timeout_s
    me = threading.current_thread()
    for thread in threading.enumerate():
        if thread is not me and thread.name.startswith("camd-"):
            thread.join(max(0.0, deadline - time.monotonic()))
    left = [t.name for t in threading.enumerate() if t.name.startswith("camd-") and t.is_alive()]
    if left:
        log.warning("still running at shutdown after %g s: %s", timeout_s, ", ".join(left))


# -- the session ---------------------------------------------------------------------------------


class DeviceSession:
    """The daemon's view of one camera; see the module docstring."""

    def __init__(
        self,
        config: Config,
        *,
        dictionary: Dictionary | None = None,
        simulator: SimulatorProcess | None = None,
    ) -> None:
        self.config = config
        # `camd serve` spawns the simulated camera before it imports this module (serve.py);
        # otherwise ``start`` spawns it, as the config says.
        self._simulator = simulator or backends.simulator_process(config)
        self.dictionary = dictionary or load_dictionary()
        # Built first: the device access's event log writes into its archive.
        self.telemetry = TelemetryService(config, self._event, self._red_limit)
        self.device = DeviceAccess(config, self.dictionary, self._event)
        self.machine = self.device.machine
        self._started_mono = time.monotonic()
        self._ending: threading.Thread | None = None  # abort's: acquisitions and job ended
        self._ending_lock = threading.Lock()
        device = self.device
        self.sim = backends.simulator_control(device)
        self.sensor = SensorService(
            device, lambda regmap: backends.register_bridge(config, regmap, device.link)
        )
        # The live view's background: captured from any stream, stored in every recording
        # (stream, stare, wheel, scan) started while it is ready.
        background = BackgroundCapture()
        # The live view's ROIs: measured on every frame of every stream (not decimated), their
        # statistics stored in every recording made while there are some.
        roi_monitor = RoiMonitor(background.ready)
        # The image's motion: blocks of every stream's TDI windows, on its own thread, within
        # a CPU budget (docs/motion.md, "The image's motion from the frames"); told the row
        # time of a rolling shutter at every stream's start.
        sync = config.motion
        self.image_motion = ImageMotionMonitor(
            background.ready,
            enabled=sync.image_measure,
            frames_per_block=sync.image_frames_per_block,
            columns_max=sync.image_columns_max,
            cpu_fraction=sync.image_cpu_fraction,
        )
        rolling = _rolling_shutter(config.sensor.name)
        self.stream = StreamService(
            device,
            self.sensor,
            lambda: backends.frame_stream_backend(config),
            background=background,
            roi=roi_monitor,
            # a 2x2-binned frame's rows are two of the sensor's each: read twice as far apart
            on_timing=lambda timing, binned: self.image_motion.stream_started(
                timing.line_period_s * (2 if binned else 1) if rolling else None
            ),
        )
        # The live view's tap stays on every stream (stare, stream, scan, wheel).
        self.live = LiveTap()
        self.live_transport = TransportEncoder()  # the WebSocket viewers' binning, compression
        self.stream.add_consumer(self.live)
        self.stream.add_consumer(background)
        self.background = BackgroundService(device, background, self.stream)
        self.roi = RoiService(roi_monitor, self.stream)
        self.stream.add_consumer(self.roi.monitor)
        self.stream.add_consumer(self.image_motion)
        # The focus aid: sharpness of the live tap's frames, on its own thread while watched.
        self.focus = FocusMonitor(self.live.wait_newer, lambda: roi_monitor.rois)
        self.motion = MotionService(device, self.sensor)
        # The live view's waterfall: the newest integrated lines of the running or last scan.
        self.live_lines = LiveLines(LIVE_LINES_MAX)
        self.scan = ScanService(
            ScanApply(
                device,
                self.sensor,
                self.stream,
                self.motion,
                self.sim,
                background=background,
                live_lines=self.live_lines,
                image_motion=self.image_motion,
            )
        )
        self.wheel = WheelService(device, self.sensor, self.stream)
        self.control = Control(
            device.acquisition, lambda level, source, message: self._event(level, source, message)
        )
        self.campaigns = CampaignService(device, self.control, self._stop_acquisition_now)
        device.file_context = self._file_context
        self.estop = EstopService(
            device,
            self.motion,
            self.wheel,
            stop_acquisition=self._stop_acquisition_now,
            pause_job=self.campaigns.pause_for_estop,
        )
        self.connection = Connection(
            device, self.telemetry, self.sensor, self.stream, self.motion, self.estop
        )
        self.link_commands = LinkCommands(device, self.sim, self.connection.shutting_down)

    # -- lifecycle ------------------------------------------------------------------------------

    @property
    def port(self) -> str:
        """What the link opens: the simulator's pty symlink or the configured device."""
        return self.device.port

    @property
    def link(self) -> CommandLink | None:
        """The command link (None before ``start``)."""
        return self.device.link

    def start(self) -> None:
        """Open the archive, repair what the last daemon left open, spawn the simulator if
        configured, open the link, start the service loop (``Connection.open``).

        Raises SimulatorError if the simulator does not start, OSError or sqlite3.Error if the
        data directory or the archive cannot be written.
        """
        self.config.daemon.data_dir.mkdir(parents=True, exist_ok=True)
        # The folders that relative record and out paths go into (docs/api.md, "Files").
        daemon = self.config.daemon
        for folder in (RECORDINGS_FOLDER, SCANS_FOLDER):
            (daemon.data_dir / folder).mkdir(exist_ok=True)
        allowed = ", ".join(str(d) for d in (daemon.data_dir, *daemon.record_dirs))
        log.info("files that clients name are written only inside: %s", allowed)
        self.telemetry.open()
        self._event("info", "daemon", f"camd {camd.__version__} started (pid {os.getpid()})")
        self._recover_recordings()
        self.connection.open(self._simulator)
        # Compile (or load) the TDI kernels now rather than when the first scan starts.
        if self.config.daemon.tdi_warm_up:
            threading.Thread(target=_warm_tdi, name="camd-tdi-warm-up", daemon=True).start()

    def _recover_recordings(self) -> None:
        """Repair the recordings a previous daemon left open (killed or crashed mid-write) and
        say what was found; after a scan was cut off, the stage is stopped once the camera
        answers (a real stage would otherwise run on to its limit)."""
        for found in recover_left_open(self.device.recordings):
            self._event("warning", "daemon", f"found at start: {found.describe()}")
            if found.kind == "scan":
                self.connection.stop_stage_on_connect = True

    def abort(self) -> None:
        """Shutdown has begun (SIGTERM or SIGINT, before uvicorn's grace for open requests):
        ask long operations to end now, so that the requests waiting on them (a ping run, a
        stare's request waiting for its frames, a campaign worker's) answer within the grace
        instead of being cancelled at its end. The running acquisition is ended and a campaign
        job's worker stopped on a thread of their own (``stop`` waits for it)."""
        self.campaigns.jobs.stopping()
        self.connection.begin_shutdown()
        with self._ending_lock:
            if self._ending is None:
                self._ending = threading.Thread(
                    target=self._end_for_shutdown, name="camd-shutdown", daemon=True
                )
                self._ending.start()

    def _end_for_shutdown(self) -> None:
        for step in (self.scan.stopping, self.stream.shut_down, self.campaigns.jobs.close):
            try:
                step()
            except Exception:  # the ordered stop tries again and says what it could not do
                log.exception("ending %s at shutdown failed", step.__qualname__)

    def stop(self) -> None:
        """The ordered shutdown (docs/architecture.md, "Shutdown"), once the API has stopped
        taking requests: the service loop (telemetry poller, simulator supervisor); the
        acquisitions (the camera's stream stopped and ended on the host, its recording closed;
        a scan finished, its closed loop and stage stopped, its file closed); the USB reader;
        the archive; the links and the simulator; then every camd thread is joined. Each wait
        is bounded; a camera already gone costs one warning line per step it prevents.
        A campaign job's worker is stopped first, to be resumed at the next start."""
        self.abort()
        ending = self._ending
        if ending is not None:
            ending.join(SHUTDOWN_ENDING_S)
        self.campaigns.jobs.close()
        self.focus.close(THREAD_JOIN_S)
        self.connection.stop_loop(THREAD_JOIN_S)
        self.scan.stopping()
        self.stream.shut_down()
        self.scan.close()
        self.image_motion.close(THREAD_JOIN_S)
        self.stream.close()
        if self.telemetry.archive is not None:
            with contextlib.suppress(Exception):
                self._event("info", "daemon", "camd stopped: acquisitions ended, files closed")
            self.telemetry.close()
        self.sensor.close()
        self.connection.close(THREAD_JOIN_S)
        _join_camd_threads(THREAD_JOIN_S)

    def __enter__(self) -> DeviceSession:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # -- what the API reads cheaply (no device traffic) -------------------------------------------

    @property
    def state(self) -> State:
        """The daemon's current state."""
        return self.machine.state

    @property
    def uptime_s(self) -> float:
        """Seconds since this session was created."""
        return time.monotonic() - self._started_mono

    def _file_context(self) -> dict[str, dict[str, Any]]:
        """A new file's context (``DeviceAccess.file_context``): the simulated camera's scene
        (the file's NXsample) and what the client in control says it does, e.g. a campaign's
        step (its NXnote); camd.store.nexus."""
        context: dict[str, dict[str, Any]] = {}
        if self.sim.available:
            context["sample"] = {"scene": self.sim.scene}
        holder, said = self.control.holder(), self.control.activity()
        if holder is not None and said is not None and said.client == holder.client:
            context["activity"] = {
                "text": said.text,
                "done": said.done,
                "total": said.total,
                "client": said.client,
                "set_utc": dt.datetime.fromtimestamp(said.t_s, dt.UTC).isoformat(
                    timespec="milliseconds"
                ),
            }
        return context

    # -- operations for the API -----------------------------------------------------------------

    def control_info(self, client: str = ANONYMOUS) -> ControlInfo:
        """Who holds control now (no device traffic)."""
        holder = self.control.holder()
        if holder is None:
            return ControlInfo(holder=None, since_t_s=None, why=None, expires_t_s=None, you=client)
        said = self.control.activity()
        activity = (
            None
            if said is None or said.client != holder.client
            else ControlActivity(text=said.text, done=said.done, total=said.total, t_s=said.t_s)
        )
        return ControlInfo(
            holder=holder.client,
            since_t_s=holder.since_t_s,
            why=holder.why,
            expires_t_s=holder.expires_t_s,
            you=client,
            activity=activity,
        )

    def acquisition_info(self) -> AcquisitionInfo | None:
        """The running acquisition, or the last started one."""
        current = self.device.acquisition.current
        if current is None:
            return None
        return AcquisitionInfo(
            kind=cast(Any, current.kind),
            description=current.description,
            client=current.client,
            started_t_s=current.started_t_s,
            ended_t_s=current.ended_t_s,
            running=current.active,
        )

    def take_control(self, client: str, ttl_s: float, *, force: bool = False) -> None:
        """Take or renew a lease (``Control.take``); a campaign job's worker whose job no
        longer runs (paused by an emergency stop, ended) may not take it back."""
        self.campaigns.jobs.refuse_control(client)
        self.control.take(client, ttl_s, force=force)

    def _stop_acquisition_now(self) -> bool:
        # A scan first, through its own stop: stopping only its stream would end it "done".
        if self.scan.request_stop():
            return True
        if self.device.acquisition.active is None and not self.stream.streaming:
            return False
        if self.stream.streaming:
            self.stream.stop()
        return True

    def status(self, client: str = ANONYMOUS) -> StatusResponse:
        """State, reason, mode, link, the device's GET_STATUS (if it answers), the daemon,
        who holds control and the current or last acquisition."""
        device: DeviceStatus | None = None
        if self.machine.state != State.DISCONNECTED:
            try:
                values = self._request("GET_STATUS").values
                device = DeviceStatus.model_validate(values)
                self.device.note_mode(device.mode)
                if device.device_state == "fault":
                    # A FAULT event lost on a noisy line must not leave us believing idle.
                    self._fire(
                        Trigger.DEVICE_FAULT,
                        "device reports fault " + self.dictionary.describe_error(device.fault_code),
                    )
            except SessionError as exc:
                log.info("status: GET_STATUS failed: %s", exc)
        snap = self.machine.snapshot
        return StatusResponse(
            state=snap.state.value,
            reason=self.device.reason(snap.state, snap.reason),
            mode=cast(Any, self.device.mode),
            link=self.connection.link_info(),
            device=device,
            daemon=DaemonInfo(
                version=camd.__version__,
                pid=os.getpid(),
                uptime_s=self.uptime_s,
                scheduling=REALTIME.report(),
            ),
            control=self.control_info(client),
            acquisition=self.acquisition_info(),
            estop=self.estop.state(),
            backends=backends.describe(self.config),
        )

    @property
    def mode(self) -> str | None:
        """The imaging mode last known (None before first contact)."""
        return self.device.mode

    def set_mode(self, mode: str) -> ModeResponse:
        """Select the imaging mode (area or tdi). If the answer is lost (a lost link, a silent
        camera), the camera may have changed mode: the mode before is put back (``Apply``)."""
        self._require(Request.MODE)
        device = self.device
        before = device.mode or "area"
        now = apply_one(
            "mode change",
            self._event,
            lambda: device.set_mode(mode),
            lambda: device.set_mode(before),
            f"mode {before}",
        )
        return ModeResponse(mode=cast(Any, now))

    def reset(self) -> StatusResponse:
        """Soft-reset the device; on success the daemon is idle. Returns the status after."""
        self._require(Request.RESET)
        self._request("RESET")
        self.device.note_mode("area")  # RESET puts the device back in area mode
        self.stream.on_reset()  # and stops the sequencer; BOOT leads to a retrain
        still_red = self.telemetry.acknowledge_red()
        self._fire(Trigger.RESET_OK, "reset")
        note = f"; still red: {', '.join(still_red)}" if still_red else ""
        # The sensor keeps its registers through the camera's RESET: put back the values it
        # powers up with (the register map's reset values), so that a reset camera is a known one.
        try:
            changed = self.sensor.restore_defaults()
        except SessionError as exc:
            note += f"; the sensor's registers could NOT be put back to their defaults: {exc}"
        else:
            if changed:
                note += f"; registers back at their defaults: {', '.join(changed)}"
        # The camera announces its restart with a BOOT event, which leads to a retrain; but an
        # event is sent once and a lossy line may lose it: identify and retrain here, so that
        # the camera is ready to image when the reset answers (the BOOT's probe then finds it
        # trained).
        try:
            self.stream.on_connect(self.sensor.on_connect())
        except SessionError as exc:
            note += f"; the sensor check after the reset failed: {exc}"
        self._event("info", "api", f"camera reset{note}")
        return self.status()

    # -- internals: requests and state ----------------------------------------------------------

    def _require(self, request: Request) -> None:
        self.device.require(request)

    def _request(self, command: str, **fields: Any) -> Response:
        return self.device.request(command, **fields)

    def _fire(self, trigger: Trigger, reason: str | None) -> None:
        self.device.fire(trigger, reason)

    def _event(self, level: str, source: str, message: str, t_s: float | None = None) -> None:
        getattr(log, "error" if level == "error" else level)("%s: %s", source, message)
        self.telemetry.archive_event(level, source, message, t_s)

    def _red_limit(self, reason: str) -> None:
        """A red channel the operator has not acknowledged: fault, from idle or streaming."""
        if self.machine.state in (State.IDLE, State.STREAMING):
            self._fire(Trigger.RED_LIMIT, reason)


def _warm_tdi() -> None:
    """The TDI kernels loaded ahead of the first scan (``camd.tdi.warm_up``), and the image
    motion measurement (``camd.pipeline.image_motion.warm_up``: its imports, on the first
    block, would hold up the scan's closed loop)."""
    try:
        seconds = warm_up()
    except Exception:  # a scan would then compile them itself, and say why it cannot
        log.exception("could not load the TDI kernels ahead of the first scan")
    else:
        log.info("TDI kernels ready in %.2f s", seconds)
    try:
        seconds = warm_image_motion()
    except Exception:  # the first block would then load it, and say why it cannot
        log.exception("could not load the image motion measurement ahead of the first stream")
    else:
        log.info("image motion measurement ready in %.2f s", seconds)
