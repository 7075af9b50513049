"""The narrow way the daemon's services reach the camera.

``DeviceAccess`` holds the command link, a FIFO lock around it (one operation at a time, in
arrival order), the state machine, the event log and the imaging mode. Every service (sensor,
stream, scan, motion, wheel) is handed this object and the peer services it needs, never the
whole session: ``request`` sends one command with link errors mapped to the API's errors,
``device_op`` holds the device for several back to back, ``require`` checks the state machine
before anything is sent, ``fire`` moves it, ``log_event`` logs and archives. A request that
failed on a lost link or a silent device carries ``wait_usable`` (its error's ``link_wait``), so
that what it had changed is put back once the camera answers again.
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any

from camd.daemon import notify
from camd.daemon.acquisition import AcquisitionSlot
from camd.daemon.config import Config
from camd.daemon.errors import (
    BadRequest,
    DeviceRejected,
    DeviceTimeout,
    Disconnected,
)
from camd.daemon.estop import EstopLatch
from camd.daemon.state import (
    HOW_TO_LEAVE,
    IllegalState,
    Request,
    State,
    StateMachine,
    Trigger,
    describe,
    is_legal,
)
from camd.link import (
    CommandLink,
    CommandRejected,
    CommandTimeout,
    LinkDown,
    LinkError,
    Response,
)
from camd.protocol import Dictionary, EncodeError
from camd.sensor.bridge import BridgeError
from camd.sensor.regmap import RegisterAccessError, RegisterValueError
from camd.store.journal import RecordingJournal

log = logging.getLogger(__name__)

DISTURBING = frozenset(
    {
        Request.MODE,
        Request.LINK_COMMAND,
        Request.RESET,
        Request.REGISTERS_WRITE,
        Request.TRAIN,
        Request.STREAM_START,
        Request.MOTION_MOVE,
        Request.WHEEL_SET,
    }
)
"""Requests refused (Busy) while an acquisition runs or sets itself up."""

LATCHED_OUT = frozenset({Request.STREAM_START, Request.MOTION_MOVE})
"""Requests refused while the emergency stop is latched (camd.daemon.estop); the wheel's
speed is refused there only when it would turn the wheel (``WheelService``)."""

EventSink = Callable[[str, str, str, float | None], None]
"""``(level, source, message, t_s)``: log and archive one event (t_s None: now)."""

SIM_DEVICE = "sim"

RESTORE_GRACE_S = 5.0
"""After a link failure, how long beyond the link's own reconnect backoff and one command's
attempts an undo waits for the camera to answer again, seconds."""
LINK_POLL_S = 0.1  # between checks while waiting for the link to be usable


class FairLock:
    """A FIFO lock: waiters get it in arrival order.

    threading.Lock lets a thread that releases and re-acquires in a loop (a 100000-PING run)
    win every time; the service loop's poll, and so the watchdog, would then starve.
    """

    def __init__(self) -> None:
        self._cond = threading.Condition(threading.Lock())
        self._next_ticket = 0
        self._serving = 0

    @contextlib.contextmanager
    def hold(self) -> Iterator[None]:
        """Hold the lock for a ``with`` block, after every earlier waiter."""
        with self._cond:
            ticket = self._next_ticket
            self._next_ticket += 1
            while ticket != self._serving:
                self._cond.wait()
        try:
            yield
        finally:
            with self._cond:
                self._serving += 1
                self._cond.notify_all()


class DeviceAccess:
    """The command link, the state machine, the event log and the mode (module docstring)."""

    def __init__(self, config: Config, dictionary: Dictionary, events: EventSink) -> None:
        self.config = config
        self.dictionary = dictionary
        self.machine = StateMachine(State.DISCONNECTED, "not connected yet")
        self.link: CommandLink | None = None
        self.probe_error: str | None = None  # why the device is silent on an open port
        # What is wrong with a camera that answers (the sensor it reports is not sensor.name):
        # status.reason while the state itself has no reason (idle, streaming).
        self.sensor_problem: str | None = None
        self.acquisition = AcquisitionSlot()
        # Nothing moves or acquires while an emergency stop is latched (kept across restarts).
        self.estop = EstopLatch(
            config.daemon.data_dir / "estop.json",
            lambda level, source, message: events(level, source, message, None),
        )
        # The recordings open for writing, on disk: what a restart after a crash must repair.
        self.recordings = RecordingJournal(config.daemon.data_dir / "open-recordings")
        # What every new recording's and scan's file says of its context, as metadata groups:
        # the scene in front of the camera ("sample") and the campaign step asking for it
        # ("activity"); the session sets it once the simulator and control exist.
        self.file_context: Callable[[], dict[str, dict[str, Any]]] = dict
        self._events = events
        self._lock = FairLock()
        self._mode: str | None = None

    @property
    def port(self) -> str:
        """What the link opens: the simulator's pty symlink or the configured device."""
        if self.config.link.device == SIM_DEVICE:
            return str(self.config.sim_link_path)
        return self.config.link.device

    @property
    def simulated(self) -> bool:
        """True when the camera is the simulated one this daemon spawns."""
        return self.config.link.device == SIM_DEVICE

    # -- the state machine ---------------------------------------------------------------------

    @property
    def state(self) -> State:
        return self.machine.state

    def require(self, request: Request) -> None:
        """Raise Disconnected or IllegalState unless ``request`` is legal now; Busy, naming
        it, when a running acquisition is what makes it illegal."""
        snap = self.machine.snapshot
        if request in LATCHED_OUT:
            self.estop.check(describe(request))
        if snap.state == State.DISCONNECTED and not is_legal(request, snap.state):
            raise Disconnected(self.disconnected_message())
        if request in DISTURBING or not is_legal(request, snap.state):
            self.acquisition.check_free(describe(request))
        if not is_legal(request, snap.state):
            raise IllegalState(request, snap.state, snap.reason)

    def fire(self, trigger: Trigger, reason: str | None) -> None:
        """Move the state machine (and log the change as an event)."""
        change = self.machine.fire(trigger, reason)
        if change is None:
            return
        level = {State.FAULT: "error", State.DISCONNECTED: "warning"}.get(change.new, "info")
        why = f": {change.reason}" if change.reason else ""
        self.log_event(level, "daemon", f"state {change.old.value} -> {change.new.value}{why}")
        notify.status(f"camera {change.new.value}{why}")

    def reason(self, state: State, reason: str | None) -> str | None:
        """Why the daemon is in ``state``; for disconnected, what the link says; else the
        state's reason, or what is wrong with the camera (a sensor other than configured)."""
        if state != State.DISCONNECTED:
            return reason or self.sensor_problem
        link = self.link
        if link is not None and link.connected:
            return self.probe_error or "link open; waiting for the device to answer GET_STATUS"
        if link is not None and link.last_error:
            return f"last link error: {link.last_error}"
        return reason

    def disconnected_message(self) -> str:
        why = self.reason(State.DISCONNECTED, self.machine.snapshot.reason)
        hint = HOW_TO_LEAVE[State.DISCONNECTED]
        if self.simulated and self.config.sim.restart:
            hint += (
                "; the daemon restarts its simulated camera when it dies (`camctl status`: "
                "link.sim_state, link.sim_restarts; `camctl events` says why)"
            )
        elif self.simulated:
            hint += f"; to attach a new simulator: `camd sim --link {self.port}`"
        return f"no camera on {self.port} ({why}); {hint}"

    # -- events --------------------------------------------------------------------------------

    def log_event(self, level: str, source: str, message: str, t_s: float | None = None) -> None:
        """Log and archive an event."""
        self._events(level, source, message, t_s)

    # -- device requests -------------------------------------------------------------------------

    @contextlib.contextmanager
    def device_op(self) -> Iterator[CommandLink]:
        """Hold the device (FIFO) for one operation; link and register errors become
        SessionErrors. Several requests inside one ``device_op`` run back to back."""
        link = self.link
        if link is None:
            raise Disconnected(self.disconnected_message())
        with self._lock.hold():
            try:
                yield link
            except LinkDown as exc:
                if not link.connected:  # else the link came back meanwhile; keep its state
                    self.fire(Trigger.LINK_LOST, f"link lost: {link.last_error}")
                lost = Disconnected(str(exc))
                lost.link_wait = self.wait_usable
                raise lost from None
            except CommandTimeout as exc:
                silent = DeviceTimeout(str(exc))
                silent.link_wait = self.wait_usable
                raise silent from None
            except CommandRejected as exc:
                if exc.name == "DEVICE_FAULT":
                    self.fire(Trigger.DEVICE_FAULT, str(exc))
                raise DeviceRejected(str(exc), exc.name) from None
            except (EncodeError, RegisterAccessError, RegisterValueError) as exc:
                raise BadRequest(str(exc)) from None
            except LinkError as exc:
                raise DeviceRejected(str(exc), "UNDECODABLE") from None
            except BridgeError as exc:
                raise DeviceRejected(str(exc), type(exc).__name__) from None

    def request(self, command: str, **fields: Any) -> Response:
        """One device request through the FIFO lock, errors mapped to SessionErrors; a command
        that starts motion or acquisition is refused while the emergency stop is latched
        (EstopLatched), whatever checks the request that sends it passed before the stop."""
        self.estop.check_command(command, fields)
        with self.device_op() as link:
            return link.request(command, **fields)

    # -- after a link failure ----------------------------------------------------------------------

    @property
    def restore_wait_s(self) -> float:
        """How long ``wait_usable`` waits: the longest reconnect backoff, one command's attempts
        (``link.reconnect_max_s``, ``link.timeout_s``, ``link.retries`` or ``sim.link_retries``)
        and a grace, seconds."""
        cfg = self.config.link
        return (
            cfg.reconnect_max_s + (1 + self.config.link_retries) * cfg.timeout_s + RESTORE_GRACE_S
        )

    def wait_usable(self) -> str | None:
        """Wait until the camera answers again after a lost link or a silent device: the port
        open, the daemon past its re-probe (not disconnected), a PING answered. Returns None
        once it is usable, else (after ``restore_wait_s``) why it is not, in words."""
        wait_s = self.restore_wait_s
        deadline = time.monotonic() + wait_s
        while True:
            why = self._unusable()
            if why is None:
                return None
            if time.monotonic() >= deadline:
                return f"the camera did not answer again within {wait_s:.3g} s: {why}"
            time.sleep(LINK_POLL_S)

    def _unusable(self) -> str | None:
        link = self.link
        if link is None:
            return "the link is not open"
        if not link.connected:
            return f"{self.port} is closed ({link.last_error})"
        if self.machine.state == State.DISCONNECTED:  # the probe's reason: e.g. a frozen camera
            return self.probe_error or (
                f"{self.port} is open again; the camera has not answered GET_STATUS yet"
            )
        try:
            with self._lock.hold():
                link.request("PING", data=b"")
        except CommandRejected:
            return None  # refused, but it answers
        except LinkError as exc:
            return str(exc)
        return None

    # -- the imaging mode ------------------------------------------------------------------------

    @property
    def mode(self) -> str | None:
        """The imaging mode last known (None before first contact)."""
        return self._mode

    def note_mode(self, mode: str | None) -> None:
        """Record the mode the device reported (GET_STATUS, MODE_CHANGED, BOOT)."""
        self._mode = mode

    def set_mode(self, mode: str) -> str:
        """SET_MODE on the device; returns the mode it confirms. No state check: callers
        check first (the mode request, or an acquisition's plan)."""
        response = self.request("SET_MODE", mode=mode)
        self._mode = str(response.values["mode"])
        self.log_event("info", "api", f"mode set to {self._mode}")
        return self._mode
