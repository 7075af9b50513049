"""The device session: composes the daemon's parts and owns their lifecycle.

``DeviceSession(config)`` spawns the simulated camera when ``link.device = "sim"`` (the
backends are chosen in ``camd.daemon.backends``), opens the CommandLink inside a
``DeviceAccess`` (link, FIFO lock, state machine, event log), builds the services on it (sensor,
stream, motion, scan, wheel, simulator control: each handed the device access and its peers,
never the session), follows the link's connection changes, telemetry and events, and runs a
service loop that polls housekeeping and pets the systemd watchdog. The API calls its
operations (``status``, ``ping``, ``link_stats``, ``telemetry``, ``history``, ``events``,
``set_mode``, ``reset``); each checks the state machine first, so an illegal request never
reaches the device.

Threads: the link's reader thread calls ``_on_message`` (quick work only: archive, limits,
state); the service loop thread does everything that waits for the device outside requests
(probing after a connect, polling); API requests run on the HTTP server's worker threads. Device
requests go through one FIFO lock so that a long ping run cannot starve the poll (and with it
the watchdog).
"""

from __future__ import annotations

import contextlib
import logging
import os
import threading
import time
from collections.abc import Mapping
from typing import Any, cast

import camd
from camd.daemon import backends, heap, notify
from camd.daemon.background_service import BackgroundService
from camd.daemon.campaign_service import CampaignService
from camd.daemon.config import HOUSEKEEPING_PACKET, Config
from camd.daemon.control import ANONYMOUS, Control
from camd.daemon.device import DeviceAccess
from camd.daemon.errors import (
    DeviceRejected,
    DeviceTimeout,
    Disconnected,
    SessionError,
)
from camd.daemon.estop_service import EstopService
from camd.daemon.link_commands import LinkCommands
from camd.daemon.models import (
    LIVE_LINES_MAX,
    AcquisitionInfo,
    ControlActivity,
    ControlInfo,
    DaemonInfo,
    DeviceStatus,
    LinkInfo,
    ModeResponse,
    StatusResponse,
)
from camd.daemon.motion_service import MotionService
from camd.daemon.output_paths import RECORDINGS_FOLDER, SCANS_FOLDER
from camd.daemon.realtime import REALTIME
from camd.daemon.scan_service import ScanService
from camd.daemon.sensor_service import SensorService
from camd.daemon.sim_supervisor import RestartPolicy, SimSupervisor
from camd.daemon.simulator import SimulatorProcess
from camd.daemon.state import Request, State, Trigger
from camd.daemon.stream_service import StreamService
from camd.daemon.telemetry_service import TelemetryService
from camd.daemon.transaction import Apply
from camd.daemon.wheel_service import WheelService
from camd.link import (
    CommandLink,
    ConnectionChange,
    Message,
    Response,
    Unsolicited,
)
from camd.pipeline.background import BackgroundCapture
from camd.pipeline.live import LiveLines, LiveTap
from camd.protocol import (
    Dictionary,
    FrameType,
    load_dictionary,
)
from camd.protocol.dictionary import FieldValue
from camd.store.journal import recover_left_open
from camd.tdi import warm_up

log = logging.getLogger(__name__)

PROBE_RETRY_S = 1.0  # after a GET_STATUS probe went unanswered
MAX_LOOP_SLEEP_S = 0.25  # the service loop wakes at least this often (stop, sim exit, probes)
# A camera whose housekeeping polls have gone unanswered (no answer at all, not a NAK) for this
# long, on a port that stays open, is taken as frozen: the state goes disconnected with the
# reason (docs/api.md, "Details"). Short silences (a line that drops for a couple of seconds)
# stay below it.
SILENT_AFTER_S = 5.0
PRUNE_PERIOD_S = 3600.0  # how often old telemetry samples are deleted
HEAP_TRIM_PERIOD_S = 30.0  # how often the C heap's free pages go back to the system (heap.py)


THREAD_JOIN_S = 5.0  # at shutdown, the longest wait for one of camd's threads to end
SHUTDOWN_ENDING_S = 15.0  # ... for the acquisition to end and a job's worker to stop (abort)


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

    def __init__(self, config: Config, *, dictionary: Dictionary | None = None) -> None:
        self.config = config
        self.dictionary = dictionary or load_dictionary()
        # Built first: the device access's event log writes into its archive.
        self.telemetry = TelemetryService(config, self._event, self._red_limit)
        self.sim_process: SimulatorProcess | None = None
        self.sim_supervisor: SimSupervisor | None = None
        self.device = DeviceAccess(config, self.dictionary, self._event)
        self.machine = self.device.machine

        self._stop = threading.Event()
        self._wake = threading.Event()
        self._probe_needed = threading.Event()
        self._thread: threading.Thread | None = None
        self._unsubscribe: Any = None
        self._started_mono = time.monotonic()
        self._stop_stage_on_connect = False  # a scan was cut off: see _recover_recordings
        self._poll_error: str | None = None
        self._unanswered_since: float | None = None  # monotonic: the first unanswered poll's
        self._silent_reason: str | None = None  # why a camera on an open port is disconnected
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
        self.stream = StreamService(
            device,
            self.sensor,
            lambda: backends.frame_stream_backend(config),
            background=background,
        )
        # The live view's tap stays on every stream (stare, stream, scan, wheel).
        self.live = LiveTap()
        self.stream.add_consumer(self.live)
        self.stream.add_consumer(background)
        self.background = BackgroundService(device, background, self.stream)
        self.motion = MotionService(device, self.sensor)
        # The live view's waterfall: the newest integrated lines of the running or last scan.
        self.live_lines = LiveLines(LIVE_LINES_MAX)
        self.scan = ScanService(
            device,
            self.sensor,
            self.stream,
            self.motion,
            self.sim,
            background=background,
            live_lines=self.live_lines,
        )
        self.wheel = WheelService(device, self.sensor, self.stream)
        self.link_commands = LinkCommands(device, self.sim, self._stop.is_set)
        self.control = Control(
            device.acquisition, lambda level, source, message: self._event(level, source, message)
        )
        self.campaigns = CampaignService(device, self.control, self._stop_acquisition_now)
        self.estop = EstopService(
            device,
            self.motion,
            self.wheel,
            stop_acquisition=self._stop_acquisition_now,
            pause_job=self.campaigns.pause_for_estop,
        )

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
        """Open the archive, spawn the simulator if configured, open the link, start the loop.

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
        self.sim_process = backends.simulator_process(self.config)
        if self.sim_process is not None:
            self.config.sim_socket_dir.mkdir(mode=0o700, parents=True, exist_ok=True)
            info = self.sim_process.start()
            self._event("info", "daemon", f"simulated camera started: pid {info.get('pid')}, "
                        f"tty {info.get('tty')}, link {self.port}")  # fmt: skip
            self.sim_supervisor = self._sim_supervisor(self.sim_process)
        cfg = self.config.link
        link = self.device.link = CommandLink(
            self.port,
            dictionary=self.dictionary,
            baudrate=cfg.baudrate,
            timeout_s=cfg.timeout_s,
            retries=cfg.retries,
            reconnect_min_s=cfg.reconnect_min_s,
            reconnect_max_s=cfg.reconnect_max_s,
            thread_start=REALTIME.enter,
            may_open=self.sim_supervisor.refuses_link if self.sim_supervisor is not None else None,
        )
        self._unsubscribe = link.subscribe(self._on_message)
        link.open()
        self._stop.clear()
        self._thread = threading.Thread(target=self._service_loop, name="camd-service", daemon=True)
        self._thread.start()
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
                self._stop_stage_on_connect = True

    def _stop_stage_left_running(self) -> None:
        if not self._stop_stage_on_connect:
            return
        self._stop_stage_on_connect = False
        try:
            status = self.motion.stop()
        except SessionError as exc:
            self._event(
                "warning", "motion", f"could not stop the stage after the cut-off scan: {exc}"
            )
            return
        self._event(
            "info",
            "motion",
            "a scan was cut off when the last daemon stopped: stage stopped at "
            f"{status.reading.position_m * 1e3:.3f} mm",
        )

    def abort(self) -> None:
        """Shutdown has begun (SIGTERM or SIGINT, before uvicorn's grace for open requests):
        ask long operations to end now, so that the requests waiting on them (a ping run, a
        stare's request waiting for its frames, a campaign worker's) answer within the grace
        instead of being cancelled at its end. The running acquisition is ended and a campaign
        job's worker stopped on a thread of their own (``stop`` waits for it)."""
        self.campaigns.jobs.stopping()
        self._stop.set()
        self._wake.set()
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
        if self._thread is not None:
            self._thread.join(timeout=THREAD_JOIN_S)
            self._thread = None
        if self._unsubscribe is not None:
            self._unsubscribe()  # no "link lost" for our own close
            self._unsubscribe = None
        self.scan.stopping()
        self.stream.shut_down()
        self.scan.close()
        self.stream.close()
        if self.telemetry.archive is not None:
            with contextlib.suppress(Exception):
                self._event("info", "daemon", "camd stopped: acquisitions ended, files closed")
            self.telemetry.close()
        self.sensor.close()
        if self.link is not None:
            self.link.close()
        if self.sim_process is not None:
            self.sim_process.stop()
        if self.sim_supervisor is not None:
            self.sim_supervisor.close(THREAD_JOIN_S)
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
        link = self.link
        return StatusResponse(
            state=snap.state.value,
            reason=self.device.reason(snap.state, snap.reason),
            mode=cast(Any, self.device.mode),
            link=LinkInfo(
                port=self.port,
                connected=link is not None and link.connected,
                last_error=link.last_error if link is not None else "not opened",
                sim_pid=self.sim_process.pid if self.sim_process is not None else None,
                sim_state=self.sim_supervisor.state if self.sim_supervisor is not None else None,
                sim_restarts=(
                    self.sim_supervisor.restarts if self.sim_supervisor is not None else None
                ),
            ),
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
        with Apply("mode change", self._event) as apply:
            now = apply.step(
                lambda: device.set_mode(mode), lambda: device.set_mode(before), f"mode {before}"
            )
            apply.done()
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

    # -- internals: link messages (reader thread) -----------------------------------------------

    def _on_message(self, message: Message) -> None:
        if isinstance(message, ConnectionChange):
            if message.connected:
                self._event("info", "link", f"link open on {self.port}")
                self.telemetry.on_connect()  # maybe another camera: start its limits afresh
                self.device.probe_error = self._silent_reason = None
                self._probe_needed.set()
                self._wake.set()
            else:
                self._event("warning", "link", f"link on {self.port} lost: {message.reason}")
                self._fire(Trigger.LINK_LOST, f"link lost: {message.reason}")
            return
        if message.kind == FrameType.TELEMETRY:
            if message.name == HOUSEKEEPING_PACKET:
                self.telemetry.record(message.values, message.t_s, "tlm")
            return
        self._on_device_event(message)

    def _on_device_event(self, message: Unsolicited) -> None:
        values = message.values
        handled = self.sensor.on_event(message.name, dict(values))
        handled = self.stream.on_event(message.name, dict(values)) or handled
        if handled:
            return
        if message.name == "FAULT":
            text = self.dictionary.describe_error(int(values.get("fault_code", 0)))
            self._event("error", "device", f"the camera entered fault (FAULT): {text}", message.t_s)
            self._fire(Trigger.DEVICE_FAULT, f"device fault {text}")
        elif message.name == "MODE_CHANGED":
            self.device.note_mode(str(values.get("mode")))
            self._event("info", "device", f"mode changed to {self.device.mode}", message.t_s)
        elif message.name == "BOOT":
            self.device.note_mode("area")
            self._event(
                "info",
                "device",
                f"the camera restarted (BOOT): boot count {values.get('boot_count', 0)!s}",
                message.t_s,
            )
            self._probe_needed.set()  # learn its state afresh
            self._wake.set()
        else:
            level, text = device_event_text(
                message.name, values, self.motion.profile.microsteps_per_m
            )
            self._event(level, "device", text, message.t_s)

    # -- internals: the service loop --------------------------------------------------------------

    def _service_loop(self) -> None:
        REALTIME.enter("service_loop")
        watchdog_s = notify.watchdog_interval_s()
        pet_every_s = watchdog_s / 2 if watchdog_s else None
        next_pet = next_poll = next_probe = next_prune = next_trim = time.monotonic()
        while not self._stop.is_set():
            now = time.monotonic()
            if pet_every_s is not None and now >= next_pet:
                # Petted from this loop, not a timer: if the loop wedges, systemd restarts us.
                notify.watchdog()
                next_pet = now + pet_every_s
            try:
                self._check_sim()
                self.stream.check_reader()
                if self._wants_probe() and now >= next_probe:
                    if self._probe():
                        next_poll = now  # a first sample right away, not a period later
                    else:
                        next_probe = time.monotonic() + PROBE_RETRY_S
                if now >= next_prune:
                    next_prune = now + PRUNE_PERIOD_S
                    self.telemetry.prune()
                if now >= next_trim:
                    next_trim = now + HEAP_TRIM_PERIOD_S
                    heap.give_back()
                if now >= next_poll:
                    # Skip missed periods instead of bursting to catch up.
                    next_poll = max(next_poll + self.config.telemetry.poll_period_s, now)
                    self._poll()
            except Exception:
                log.exception("service loop iteration failed; continuing")
            deadlines = [next_poll, now + MAX_LOOP_SLEEP_S]
            if pet_every_s is not None:
                deadlines.append(next_pet)
            if self._wants_probe():
                deadlines.append(next_probe)
            self._wake.wait(max(0.0, min(deadlines) - time.monotonic()))
            self._wake.clear()

    def _wants_probe(self) -> bool:
        link = self.link
        if link is None or not link.connected:
            return False
        # Also re-probe if we believe we are disconnected while the port is open: a LinkDown
        # seen by a request can race with the reconnect that followed it.
        return self._probe_needed.is_set() or self.machine.state == State.DISCONNECTED

    def _sim_supervisor(self, process: SimulatorProcess) -> SimSupervisor:
        sim = self.config.sim
        policy = RestartPolicy(
            backoff_min_s=sim.restart_backoff_min_s,
            backoff_max_s=sim.restart_backoff_max_s,
            stable_s=sim.restart_stable_s,
            limit=sim.restart_limit,
        )
        return SimSupervisor(process, policy, self._event, restart=sim.restart)

    def _check_sim(self) -> None:
        if self.sim_supervisor is not None:
            self.sim_supervisor.check()  # restarts a simulator that died (sim_supervisor.py)

    def _probe(self) -> bool:
        """GET_STATUS after a (re)connect or a BOOT; sets idle or fault. True if answered."""
        self._probe_needed.clear()
        try:
            values = self._request("GET_STATUS").values
        except (DeviceTimeout, DeviceRejected) as exc:
            self.device.probe_error = (
                self._silent_reason or f"link open but the device did not answer GET_STATUS: {exc}"
            )
            self._probe_needed.set()
            log.warning("%s", self.device.probe_error)
            return False
        except Disconnected:
            return False  # the reconnect will set _probe_needed again
        # Until the sensor is checked (and its link trained) and the state is set.
        self.device.probe_error = "the camera answered GET_STATUS; checking its sensor"
        self._silent_reason = None
        self._unanswered_since = None
        device = DeviceStatus.model_validate(values)
        self.device.note_mode(device.mode)
        fw = f"{device.fw_version >> 8}.{device.fw_version & 0xFF}"
        was = self.machine.state
        if device.device_state == "fault":
            self._fire(
                Trigger.PROBE_FAULT,
                "device reports fault " + self.dictionary.describe_error(device.fault_code),
            )
        else:
            # Identify the sensor and train its link before announcing idle, so that a client
            # that waits for idle finds the camera ready to image.
            try:
                self.stream.on_connect(self.sensor.on_connect())
            except SessionError as exc:
                self._event("warning", "sensor", f"sensor check after connect failed: {exc}")
            self._fire(Trigger.PROBE_IDLE, None)
            self._stop_stage_left_running()
            self.estop.hold()
        if was == State.DISCONNECTED:
            self._event(
                "info",
                "device",
                f"camera answered: firmware {fw}, mode {device.mode}, state "
                f"{device.device_state}, boot count {device.boot_count}",
            )
        self.telemetry.check_red()  # a red sample that arrived before the probe counts now
        return True

    def _poll(self) -> None:
        if self.machine.state == State.DISCONNECTED:
            return
        sent_mono = time.monotonic()
        try:
            response = self._request("GET_HOUSEKEEPING")
        except (DeviceTimeout, DeviceRejected) as exc:
            if self._poll_error is None:
                self._event("warning", "daemon", f"housekeeping poll failing: {exc}")
            self._poll_error = str(exc)
            if isinstance(exc, DeviceTimeout):
                self._unanswered(sent_mono, exc)
            else:
                self._unanswered_since = None  # a NAK is an answer
            return
        except Disconnected:
            return
        self._unanswered_since = None
        if self._poll_error is not None:
            self._event("info", "daemon", "housekeeping poll answered again")
            self._poll_error = None
        self.telemetry.record(response.values, time.time(), "poll")
        self.stream.check_ended()

    def _unanswered(self, sent_mono: float, exc: DeviceTimeout) -> None:
        """A poll went unanswered: once nothing has answered for ``SILENT_AFTER_S`` while the
        port stays open, the camera is frozen (not unplugged): say so with the state."""
        if self._unanswered_since is None:
            self._unanswered_since = sent_mono
        silent_s = time.monotonic() - self._unanswered_since
        if silent_s < SILENT_AFTER_S:
            return
        period_s = self.config.telemetry.poll_period_s
        reason = (
            f"the camera stopped answering on an open port: nothing answered for {silent_s:.1f} s "
            f"(GET_HOUSEKEEPING every {period_s:g} s; last: {exc}); {self.port} is still open, "
            "so it is not unplugged: check its power and firmware (a frozen camera) or "
            "power-cycle it; the daemon goes back to idle as soon as it answers"
        )
        self._unanswered_since = None
        self._silent_reason = self.device.probe_error = reason  # status.reason until it answers
        self._fire(Trigger.LINK_LOST, reason)


# Why MOTOR_STOPPED says the stage stopped (its ``reason`` field), and how loud: a stop the
# operator did not ask for is a warning.
_STAGE_STOPS: dict[str, tuple[str, str]] = {
    "done": ("info", "its move finished"),
    "homed": ("info", "homing finished"),
    "limit_low": ("warning", "it reached its low soft limit"),
    "limit_high": ("warning", "it reached its high soft limit"),
    "estop": ("warning", "an emergency stop"),
    "stall": ("warning", "the motor stalled"),
}


def device_event_text(
    name: str, values: Mapping[str, FieldValue], microsteps_per_m: float
) -> tuple[str, str]:
    """An event of the camera that no service handles, as ``(level, sentence)``: the stage's
    stop in words, at its position in mm; any other event by name with its fields listed
    (never a Python dict)."""
    words = {
        key: value.hex() if isinstance(value, bytes) else str(value)
        for key, value in values.items()
    }
    if name == "MOTOR_STOPPED":
        reason = words.get("reason", "unknown")
        level, why = _STAGE_STOPS.get(reason, ("warning", f"reason {reason}"))
        steps = values.get("steps")
        where = (
            f"{float(steps) / microsteps_per_m * 1e3:.3f} mm"
            if isinstance(steps, int | float)
            else "an unknown position"
        )
        return level, (
            f"the stage stopped (MOTOR_STOPPED): {why} at {where} "
            f"(encoder count {words.get('encoder')})"
        )
    fields = ", ".join(f"{key} {value}" for key, value in words.items())
    return "info", f"the camera sent {name}" + (f": {fields}" if fields else "")


def _warm_tdi() -> None:
    """The TDI kernels loaded ahead of the first scan (``camd.tdi.warm_up``)."""
    try:
        seconds = warm_up()
    except Exception:  # a scan would then compile them itself, and say why it cannot
        log.exception("could not load the TDI kernels ahead of the first scan")
    else:
        log.info("TDI kernels ready in %.2f s", seconds)
