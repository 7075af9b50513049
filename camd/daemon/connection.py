"""The connection to the camera and what keeps it: link, probe, polls, the service loop.

``Connection`` spawns the simulated camera when the session hands it one (and supervises it:
``camd.daemon.sim_supervisor``), opens the ``CommandLink`` into the device access, and follows
what the link says: a connect asks for a probe, a lost link moves the state machine to
disconnected, housekeeping telemetry goes to the telemetry service, and the camera's events go
to the sensor and stream services first, then become state (FAULT, BOOT, MODE_CHANGED) or an
event in words. Its service loop does everything that waits for the device outside requests:
the probe after a connect or a BOOT (GET_STATUS; the sensor identified and its link trained
before idle is announced; the stage a cut-off scan left running stopped; the emergency stop
held), the housekeeping polls (a camera that leaves them unanswered for ``SILENT_AFTER_S`` on
an open port is frozen: disconnected, with the reason), the simulator's supervision, the
archive's pruning, the heap's trimming and the systemd watchdog.

It is handed the device access and the services the probe and the events reach (telemetry,
sensor, stream, motion, emergency stop), never the session.

Threads: the link's reader thread calls ``on_message`` (quick work only: archive, limits,
state); the service loop runs on ``camd-service``.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

from camd.daemon import heap, notify
from camd.daemon.config import HOUSEKEEPING_PACKET
from camd.daemon.device import DeviceAccess
from camd.daemon.errors import DeviceRejected, DeviceTimeout, Disconnected, SessionError
from camd.daemon.estop_service import EstopService
from camd.daemon.models import DeviceStatus, LinkInfo
from camd.daemon.motion_service import MotionService
from camd.daemon.realtime import REALTIME
from camd.daemon.sensor_service import SensorService
from camd.daemon.sim_supervisor import RestartPolicy, SimSupervisor
from camd.daemon.simulator import SimulatorProcess
from camd.daemon.state import State, Trigger
from camd.daemon.stream_service import StreamService
from camd.daemon.telemetry_service import TelemetryService
from camd.link import CommandLink, ConnectionChange, Message, Unsolicited
from camd.protocol import FrameType
from camd.protocol.dictionary import FieldValue

# The session's logger: these lines kept the name they had before the connection was a class
# of its own (log filters select the daemon's lines by it).
log = logging.getLogger("camd.daemon.session")

PROBE_RETRY_S = 1.0  # after a GET_STATUS probe went unanswered
MAX_LOOP_SLEEP_S = 0.25  # the service loop wakes at least this often (stop, sim exit, probes)
# A camera whose housekeeping polls have gone unanswered (no answer at all, not a NAK) for this
# long, on a port that stays open, is taken as frozen: the state goes disconnected with the
# reason (docs/api.md, "Details"). Short silences (a line that drops for a couple of seconds)
# stay below it.
SILENT_AFTER_S = 5.0
PRUNE_PERIOD_S = 3600.0  # how often old telemetry samples are deleted
HEAP_TRIM_PERIOD_S = 30.0  # how often the C heap's free pages go back to the system (heap.py)


@dataclass(eq=False)
class Connection:
    """The link to one camera, its probe, polls and service loop (module docstring)."""

    device: DeviceAccess
    telemetry: TelemetryService
    sensor: SensorService
    stream: StreamService
    motion: MotionService
    estop: EstopService
    sim_process: SimulatorProcess | None = field(default=None, init=False)
    sim_supervisor: SimSupervisor | None = field(default=None, init=False)
    # A scan was cut off (DeviceSession.start).
    stop_stage_on_connect: bool = field(default=False, init=False)
    _stop: threading.Event = field(default_factory=threading.Event, init=False)
    _wake: threading.Event = field(default_factory=threading.Event, init=False)
    _probe_needed: threading.Event = field(default_factory=threading.Event, init=False)
    _thread: threading.Thread | None = field(default=None, init=False)
    _unsubscribe: Callable[[], None] | None = field(default=None, init=False)
    _poll_error: str | None = field(default=None, init=False)
    # Monotonic: the first unanswered poll's.
    _unanswered_since: float | None = field(default=None, init=False)
    # Why a camera on an open port is disconnected.
    _silent_reason: str | None = field(default=None, init=False)

    # -- lifecycle ------------------------------------------------------------------------------

    def open(self, sim_process: SimulatorProcess | None) -> None:
        """Spawn the simulator (if given) under supervision, open the link, start the loop.
        Raises SimulatorError if the simulator does not start."""
        device = self.device
        config = device.config
        self.sim_process = sim_process
        if sim_process is not None:
            config.sim_socket_dir.mkdir(mode=0o700, parents=True, exist_ok=True)
            info = sim_process.start()
            device.log_event("info", "daemon", f"simulated camera started: pid "
                             f"{info.get('pid')}, tty {info.get('tty')}, link {device.port}")  # fmt: skip
            self.sim_supervisor = self._sim_supervisor(sim_process)
        cfg = config.link
        link = device.link = CommandLink(
            device.port,
            dictionary=device.dictionary,
            baudrate=cfg.baudrate,
            timeout_s=cfg.timeout_s,
            retries=config.link_retries,
            reconnect_min_s=cfg.reconnect_min_s,
            reconnect_max_s=cfg.reconnect_max_s,
            thread_start=REALTIME.enter,
            may_open=self.sim_supervisor.refuses_link if self.sim_supervisor is not None else None,
        )
        self._unsubscribe = link.subscribe(self.on_message)
        link.open()
        self._stop.clear()
        self._thread = threading.Thread(target=self._service_loop, name="camd-service", daemon=True)
        self._thread.start()

    def shutting_down(self) -> bool:
        """True once the shutdown has begun (``begin_shutdown``)."""
        return self._stop.is_set()

    def begin_shutdown(self) -> None:
        """The service loop ends at its next wake, which is now."""
        self._stop.set()
        self._wake.set()

    def stop_loop(self, timeout_s: float) -> None:
        """Join the service loop (``begin_shutdown`` first) and stop following the link: no
        "link lost" for our own close."""
        if self._thread is not None:
            self._thread.join(timeout=timeout_s)
            self._thread = None
        if self._unsubscribe is not None:
            self._unsubscribe()
            self._unsubscribe = None

    def close(self, timeout_s: float) -> None:
        """Close the link, stop the simulator and its supervisor."""
        if self.device.link is not None:
            self.device.link.close()
        if self.sim_process is not None:
            self.sim_process.stop()
        if self.sim_supervisor is not None:
            self.sim_supervisor.close(timeout_s)

    def link_info(self) -> LinkInfo:
        """The link as the status shows it (no device traffic)."""
        link = self.device.link
        supervisor = self.sim_supervisor
        return LinkInfo(
            port=self.device.port,
            connected=link is not None and link.connected,
            last_error=link.last_error if link is not None else "not opened",
            sim_pid=self.sim_process.pid if self.sim_process is not None else None,
            sim_state=supervisor.state if supervisor is not None else None,
            sim_restarts=supervisor.restarts if supervisor is not None else None,
        )

    # -- link messages (reader thread) ------------------------------------------------------------

    def on_message(self, message: Message) -> None:
        """What the link says: a connection change, telemetry or an event of the camera."""
        device = self.device
        if isinstance(message, ConnectionChange):
            if message.connected:
                device.log_event("info", "link", f"link open on {device.port}")
                self.telemetry.on_connect()  # maybe another camera: start its limits afresh
                device.probe_error = self._silent_reason = None
                self._probe_needed.set()
                self._wake.set()
            else:
                device.log_event("warning", "link", f"link on {device.port} lost: {message.reason}")
                device.fire(Trigger.LINK_LOST, f"link lost: {message.reason}")
            return
        if message.kind == FrameType.TELEMETRY:
            if message.name == HOUSEKEEPING_PACKET:
                self.telemetry.record(message.values, message.t_s, "tlm")
            return
        self._on_device_event(message)

    def _on_device_event(self, message: Unsolicited) -> None:
        device = self.device
        values = message.values
        handled = self.sensor.on_event(message.name, dict(values))
        handled = self.stream.on_event(message.name, dict(values)) or handled
        if handled:
            return
        if message.name == "FAULT":
            text = device.dictionary.describe_error(int(values.get("fault_code", 0)))
            device.log_event(
                "error", "device", f"the camera entered fault (FAULT): {text}", message.t_s
            )
            device.fire(Trigger.DEVICE_FAULT, f"device fault {text}")
        elif message.name == "MODE_CHANGED":
            device.note_mode(str(values.get("mode")))
            device.log_event("info", "device", f"mode changed to {device.mode}", message.t_s)
        elif message.name == "BOOT":
            device.note_mode("area")
            device.log_event(
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
            device.log_event(level, "device", text, message.t_s)

    # -- the service loop -------------------------------------------------------------------------

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
                    next_poll = max(next_poll + self.device.config.telemetry.poll_period_s, now)
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
        link = self.device.link
        if link is None or not link.connected:
            return False
        # Also re-probe if we believe we are disconnected while the port is open: a LinkDown
        # seen by a request can race with the reconnect that followed it.
        return self._probe_needed.is_set() or self.device.state == State.DISCONNECTED

    def _sim_supervisor(self, process: SimulatorProcess) -> SimSupervisor:
        sim = self.device.config.sim
        policy = RestartPolicy(
            backoff_min_s=sim.restart_backoff_min_s,
            backoff_max_s=sim.restart_backoff_max_s,
            stable_s=sim.restart_stable_s,
            limit=sim.restart_limit,
        )
        return SimSupervisor(process, policy, self.device.log_event, restart=sim.restart)

    def _check_sim(self) -> None:
        if self.sim_supervisor is not None:
            self.sim_supervisor.check()  # restarts a simulator that died (sim_supervisor.py)

    # -- the probe and the polls ------------------------------------------------------------------

    def _probe(self) -> bool:
        """GET_STATUS after a (re)connect or a BOOT; sets idle or fault. True if answered."""
        self._probe_needed.clear()
        access = self.device
        try:
            values = access.request("GET_STATUS").values
        except (DeviceTimeout, DeviceRejected) as exc:
            access.probe_error = (
                self._silent_reason or f"link open but the device did not answer GET_STATUS: {exc}"
            )
            self._probe_needed.set()
            log.warning("%s", access.probe_error)
            return False
        except Disconnected:
            return False  # the reconnect will set _probe_needed again
        # Until the sensor is checked (and its link trained) and the state is set.
        access.probe_error = "the camera answered GET_STATUS; checking its sensor"
        self._silent_reason = None
        self._unanswered_since = None
        device = DeviceStatus.model_validate(values)
        access.note_mode(device.mode)
        fw = f"{device.fw_version >> 8}.{device.fw_version & 0xFF}"
        was = access.state
        if device.device_state == "fault":
            access.fire(
                Trigger.PROBE_FAULT,
                "device reports fault " + access.dictionary.describe_error(device.fault_code),
            )
        else:
            # Identify the sensor and train its link before announcing idle, so that a client
            # that waits for idle finds the camera ready to image.
            try:
                self.stream.on_connect(self.sensor.on_connect())
            except SessionError as exc:
                access.log_event("warning", "sensor", f"sensor check after connect failed: {exc}")
            access.fire(Trigger.PROBE_IDLE, None)
            self._stop_stage_left_running()
            self.estop.hold()
        if was == State.DISCONNECTED:
            access.log_event(
                "info",
                "device",
                f"camera answered: firmware {fw}, mode {device.mode}, state "
                f"{device.device_state}, boot count {device.boot_count}",
            )
        self.telemetry.check_red()  # a red sample that arrived before the probe counts now
        return True

    def _stop_stage_left_running(self) -> None:
        """After a scan was cut off, the stage is stopped once the camera answers (a real
        stage would otherwise run on to its limit)."""
        if not self.stop_stage_on_connect:
            return
        self.stop_stage_on_connect = False
        try:
            status = self.motion.stop()
        except SessionError as exc:
            self.device.log_event(
                "warning", "motion", f"could not stop the stage after the cut-off scan: {exc}"
            )
            return
        self.device.log_event(
            "info",
            "motion",
            "a scan was cut off when the last daemon stopped: stage stopped at "
            f"{status.reading.position_m * 1e3:.3f} mm",
        )

    def _poll(self) -> None:
        device = self.device
        if device.state == State.DISCONNECTED:
            return
        sent_mono = time.monotonic()
        try:
            response = device.request("GET_HOUSEKEEPING")
        except (DeviceTimeout, DeviceRejected) as exc:
            if self._poll_error is None:
                device.log_event("warning", "daemon", f"housekeeping poll failing: {exc}")
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
            device.log_event("info", "daemon", "housekeeping poll answered again")
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
        period_s = self.device.config.telemetry.poll_period_s
        reason = (
            f"the camera stopped answering on an open port: nothing answered for {silent_s:.1f} s "
            f"(GET_HOUSEKEEPING every {period_s:g} s; last: {exc}); {self.device.port} is still "
            "open, so it is not unplugged: check its power and firmware (a frozen camera) or "
            "power-cycle it; the daemon goes back to idle as soon as it answers"
        )
        self._unanswered_since = None
        self._silent_reason = self.device.probe_error = reason  # status.reason until it answers
        self.device.fire(Trigger.LINK_LOST, reason)


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
