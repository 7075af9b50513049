"""The daemon's state machine, declared as data.

``LEGAL`` says which API request is allowed in which state; ``TRANSITIONS`` says where each trigger
leads from each state. Adding a state (e.g. scanning) means adding it to ``State``, to the
requests it permits in ``LEGAL``, to ``HOW_TO_LEAVE`` and to the transitions that enter and leave
it; nothing else changes. An illegal request is refused by ``check`` before the device is touched.

Legal requests per state:

================  ============  ====  =========  =====
request           disconnected  idle  streaming  fault
================  ============  ====  =========  =====
status            yes           yes   yes        yes
link              yes           yes   yes        yes
telemetry         yes           yes   yes        yes
events            yes           yes   yes        yes
ping                            yes   yes        yes
link_command                    yes              yes
mode                            yes
reset                           yes   yes        yes
registers_read                  yes   yes        yes
registers_write                 yes
train                           yes
stream_start                    yes
stream_stop                     yes   yes        yes
stream_read       yes           yes   yes        yes
sim                             yes   yes        yes
motion_read                     yes   yes        yes
motion_move                     yes
motion_stop                     yes   yes        yes
wheel_read                      yes   yes        yes
wheel_set                       yes
live_background                       yes
================  ============  ====  =========  =====

``link_command`` (one raw frame, for conformance tests) may change anything, so not while
streaming; in fault, so that a faulty unit can be examined.
Register reads are harmless at any time the camera answers; writes and training change what the
sensor sends, so they wait until the stream stops. ``stream_read`` (the ingest counters) needs no
device; ``sim`` (scene, stage, fault injection of the simulated camera) changes only the world
in front of the camera, so it is legal while streaming. The stage moves on request only when
idle (a scan drives it itself while streaming); stopping it, and its emergency stop, are always
allowed while the camera answers. The filter wheel's speed and delay compensation change only
when idle (a wheel acquisition streams, and is a ``stream_start``); reading it is harmless.
Capturing the live view's background averages frames of the running stream, so it needs one.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from enum import StrEnum


class State(StrEnum):
    """What the daemon knows about the camera."""

    DISCONNECTED = "disconnected"  # no port, or the device does not answer (status.reason: which)
    IDLE = "idle"  # connected, ready for commands
    STREAMING = "streaming"  # the sequencer runs and frames stream over USB (START_STREAM)
    FAULT = "fault"  # the device reported a fault or a red limit tripped; RESET clears it


class Request(StrEnum):
    """API requests whose legality depends on the state."""

    STATUS = "status"
    LINK = "link"
    TELEMETRY = "telemetry"
    EVENTS = "events"
    PING = "ping"
    LINK_COMMAND = "link_command"
    MODE = "mode"
    RESET = "reset"
    REGISTERS_READ = "registers_read"
    REGISTERS_WRITE = "registers_write"
    TRAIN = "train"
    STREAM_START = "stream_start"
    STREAM_STOP = "stream_stop"
    STREAM_READ = "stream_read"
    SIM = "sim"
    MOTION_READ = "motion_read"
    MOTION_MOVE = "motion_move"
    MOTION_STOP = "motion_stop"
    WHEEL_READ = "wheel_read"
    WHEEL_SET = "wheel_set"
    LIVE_BACKGROUND = "live_background"


class Trigger(StrEnum):
    """What moves the state machine."""

    PROBE_IDLE = "probe_idle"  # GET_STATUS answered after (re)connecting: device idle/busy
    PROBE_FAULT = "probe_fault"  # GET_STATUS answered with device_state = fault
    # the port closed, a request failed with LinkDown, or the camera stopped answering on an
    # open port (a frozen camera: its polls unanswered for connection.SILENT_AFTER_S)
    LINK_LOST = "link_lost"
    DEVICE_FAULT = "device_fault"  # FAULT event, or the device says it is in fault
    RED_LIMIT = "red_limit"  # a telemetry channel went red (with telemetry.red_is_fault)
    RESET_OK = "reset_ok"  # RESET acknowledged
    STREAM_STARTED = "stream_started"  # START_STREAM acknowledged, or found streaming on connect
    STREAM_STOPPED = "stream_stopped"  # STOP_STREAM acknowledged, STREAM_DONE, or link lost


_ALWAYS = frozenset(State)

LEGAL: dict[Request, frozenset[State]] = {
    Request.STATUS: _ALWAYS,
    Request.LINK: _ALWAYS,
    Request.TELEMETRY: _ALWAYS,
    Request.EVENTS: _ALWAYS,
    Request.PING: frozenset({State.IDLE, State.STREAMING, State.FAULT}),
    Request.LINK_COMMAND: frozenset({State.IDLE, State.FAULT}),
    Request.MODE: frozenset({State.IDLE}),
    Request.RESET: frozenset({State.IDLE, State.STREAMING, State.FAULT}),
    Request.REGISTERS_READ: frozenset({State.IDLE, State.STREAMING, State.FAULT}),
    Request.REGISTERS_WRITE: frozenset({State.IDLE}),
    Request.TRAIN: frozenset({State.IDLE}),
    Request.STREAM_START: frozenset({State.IDLE}),
    Request.STREAM_STOP: frozenset({State.IDLE, State.STREAMING, State.FAULT}),
    Request.STREAM_READ: _ALWAYS,
    Request.SIM: frozenset({State.IDLE, State.STREAMING, State.FAULT}),
    Request.MOTION_READ: frozenset({State.IDLE, State.STREAMING, State.FAULT}),
    Request.MOTION_MOVE: frozenset({State.IDLE}),
    Request.MOTION_STOP: frozenset({State.IDLE, State.STREAMING, State.FAULT}),
    Request.WHEEL_READ: frozenset({State.IDLE, State.STREAMING, State.FAULT}),
    Request.WHEEL_SET: frozenset({State.IDLE}),
    Request.LIVE_BACKGROUND: frozenset({State.STREAMING}),
}

HOW_TO_LEAVE: dict[State, str] = {
    State.DISCONNECTED: "start the camera (or `camd sim`) or check the cable and the port name",
    State.IDLE: "start a stream (`camctl stream --start`), a stare or a scan",
    State.STREAMING: "stop the stream first (`camctl stream --stop`)",
    State.FAULT: "send `camctl reset` (and fix the cause first)",
}

_WHAT: dict[Request, str] = {
    Request.STATUS: "read the status",
    Request.LINK: "read the link counters",
    Request.TELEMETRY: "read telemetry",
    Request.EVENTS: "read events",
    Request.PING: "ping the camera",
    Request.LINK_COMMAND: "send a raw command",
    Request.MODE: "change the imaging mode",
    Request.RESET: "reset the camera",
    Request.REGISTERS_READ: "read sensor registers",
    Request.REGISTERS_WRITE: "write sensor registers",
    Request.TRAIN: "train the sensor link",
    Request.STREAM_START: "start a stream",
    Request.STREAM_STOP: "stop the stream",
    Request.STREAM_READ: "read the stream counters",
    Request.SIM: "change the simulated world",
    Request.MOTION_READ: "read the stage",
    Request.MOTION_MOVE: "move the stage",
    Request.MOTION_STOP: "stop the stage",
    Request.WHEEL_READ: "read the filter wheel",
    Request.WHEEL_SET: "change the filter wheel's speed or compensation",
    Request.LIVE_BACKGROUND: "capture a live-view background (it averages streamed frames)",
}

# (state, trigger) -> next state. A pair not listed leaves the state unchanged: e.g. a red limit
# while disconnected cannot happen, and a probe result while in fault must not clear the fault.
TRANSITIONS: dict[tuple[State, Trigger], State] = {
    (State.DISCONNECTED, Trigger.PROBE_IDLE): State.IDLE,
    (State.DISCONNECTED, Trigger.PROBE_FAULT): State.FAULT,
    (State.IDLE, Trigger.PROBE_FAULT): State.FAULT,
    (State.IDLE, Trigger.LINK_LOST): State.DISCONNECTED,
    (State.FAULT, Trigger.LINK_LOST): State.DISCONNECTED,
    (State.IDLE, Trigger.DEVICE_FAULT): State.FAULT,
    (State.IDLE, Trigger.RED_LIMIT): State.FAULT,
    (State.IDLE, Trigger.RESET_OK): State.IDLE,
    (State.FAULT, Trigger.RESET_OK): State.IDLE,
    (State.IDLE, Trigger.STREAM_STARTED): State.STREAMING,
    (State.STREAMING, Trigger.STREAM_STOPPED): State.IDLE,
    (State.STREAMING, Trigger.PROBE_IDLE): State.IDLE,  # a BOOT stops the sequencer
    (State.STREAMING, Trigger.PROBE_FAULT): State.FAULT,
    (State.STREAMING, Trigger.LINK_LOST): State.DISCONNECTED,
    (State.STREAMING, Trigger.DEVICE_FAULT): State.FAULT,
    (State.STREAMING, Trigger.RED_LIMIT): State.FAULT,
    (State.STREAMING, Trigger.RESET_OK): State.IDLE,
}


class IllegalState(Exception):
    """A request is not allowed in the current state; str() says which, why and how to leave."""

    def __init__(self, request: Request, state: State, reason: str | None) -> None:
        why = f" ({reason})" if reason else ""
        super().__init__(
            f"cannot {_WHAT[request]} while the daemon is {state.value}{why}; "
            f"to leave {state.value}: {HOW_TO_LEAVE[state]}"
        )
        self.request = request
        self.state = state
        self.reason = reason


def describe(request: Request) -> str:
    """What ``request`` does, in words ("change the imaging mode")."""
    return _WHAT[request]


def is_legal(request: Request, state: State) -> bool:
    """True if ``request`` is allowed in ``state``."""
    return state in LEGAL[request]


def check(request: Request, state: State, reason: str | None = None) -> None:
    """Raise IllegalState unless ``request`` is allowed in ``state``; ``reason`` says why the
    daemon is in that state (e.g. the fault) and goes into the message."""
    if not is_legal(request, state):
        raise IllegalState(request, state, reason)


def next_state(state: State, trigger: Trigger) -> State:
    """The state ``trigger`` leads to from ``state`` (unchanged if the table has no entry)."""
    return TRANSITIONS.get((state, trigger), state)


@dataclass(frozen=True, slots=True)
class Snapshot:
    """The state at one moment, with why it is so."""

    state: State
    reason: str | None  # why: the fault or the link error; None when idle
    since_t_s: float  # wall-clock time of the last change


@dataclass(frozen=True, slots=True)
class Change:
    """A transition that happened."""

    old: State
    new: State
    trigger: Trigger
    reason: str | None


class StateMachine:
    """The current state, changed only through ``fire``; safe to use from several threads."""

    def __init__(self, initial: State = State.DISCONNECTED, reason: str | None = None) -> None:
        self._lock = threading.Lock()
        self._snapshot = Snapshot(initial, reason, time.time())

    @property
    def snapshot(self) -> Snapshot:
        """State, reason and since when, read together."""
        with self._lock:
            return self._snapshot

    @property
    def state(self) -> State:
        """The current state."""
        return self.snapshot.state

    def fire(self, trigger: Trigger, reason: str | None = None) -> Change | None:
        """Apply ``trigger``; return the Change, or None if the state stayed the same.

        ``reason`` (why: the fault, the link error) is kept with the new state; entering idle
        clears it. A trigger that keeps the state (a second fault) leaves the first reason.
        """
        with self._lock:
            old = self._snapshot.state
            new = next_state(old, trigger)
            if new == old:
                return None
            self._snapshot = Snapshot(new, None if new == State.IDLE else reason, time.time())
            return Change(old, new, trigger, self._snapshot.reason)

    def check(self, request: Request) -> Snapshot:
        """Raise IllegalState unless ``request`` is legal now; return the snapshot checked."""
        snap = self.snapshot
        check(request, snap.state, snap.reason)
        return snap
