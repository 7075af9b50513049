"""The state machine: the legality table, the messages of refusals, the transitions."""

from __future__ import annotations

import threading

import pytest

from camd.daemon import state as state_module
from camd.daemon.state import (
    HOW_TO_LEAVE,
    LEGAL,
    TRANSITIONS,
    IllegalState,
    Request,
    State,
    StateMachine,
    Trigger,
    check,
    is_legal,
    next_state,
)

DIS, IDLE, STR, FLT = State.DISCONNECTED, State.IDLE, State.STREAMING, State.FAULT

EXPECTED_LEGAL = {
    Request.STATUS: {DIS, IDLE, STR, FLT},
    Request.LINK: {DIS, IDLE, STR, FLT},
    Request.TELEMETRY: {DIS, IDLE, STR, FLT},
    Request.EVENTS: {DIS, IDLE, STR, FLT},
    Request.PING: {IDLE, STR, FLT},
    Request.LINK_COMMAND: {IDLE, FLT},
    Request.MODE: {IDLE},
    Request.RESET: {IDLE, STR, FLT},
    Request.REGISTERS_READ: {IDLE, STR, FLT},
    Request.REGISTERS_WRITE: {IDLE},
    Request.TRAIN: {IDLE},
    Request.STREAM_START: {IDLE},
    Request.STREAM_STOP: {IDLE, STR, FLT},
    Request.STREAM_READ: {DIS, IDLE, STR, FLT},
    Request.SIM: {IDLE, STR, FLT},
    Request.MOTION_READ: {IDLE, STR, FLT},
    Request.MOTION_MOVE: {IDLE},
    Request.MOTION_STOP: {IDLE, STR, FLT},
    Request.WHEEL_READ: {IDLE, STR, FLT},
    Request.WHEEL_SET: {IDLE},
    Request.LIVE_BACKGROUND: {STR},
}


def test_legality_table_is_as_specified() -> None:
    assert {r: set(states) for r, states in LEGAL.items()} == EXPECTED_LEGAL


def test_every_request_and_state_is_covered() -> None:
    assert set(LEGAL) == set(Request)
    assert set(HOW_TO_LEAVE) == set(State)


def test_docstring_table_matches_the_data() -> None:
    # The module docstring lists legality for readers; it must say what the code does.
    # Its columns are fixed-width: request (18 chars), disconnected (14), idle (6),
    # streaming (11), fault.
    table = {}
    for line in (state_module.__doc__ or "").splitlines():
        name = line.split(" ", 1)[0]
        if name in {r.value for r in Request}:
            cols = [line[18:32].strip(), line[32:38].strip(), line[38:49].strip(),
                    line[49:].strip()]  # fmt: skip
            table[Request(name)] = {
                s for s, c in zip((DIS, IDLE, STR, FLT), cols, strict=True) if c == "yes"
            }
    assert table == EXPECTED_LEGAL


@pytest.mark.parametrize("request_", list(Request))
@pytest.mark.parametrize("state", list(State))
def test_check_allows_exactly_the_table(request_: Request, state: State) -> None:
    if state in EXPECTED_LEGAL[request_]:
        check(request_, state)
        assert is_legal(request_, state)
    else:
        with pytest.raises(IllegalState):
            check(request_, state, "why")


def test_refusal_in_fault_says_state_reason_and_way_out() -> None:
    with pytest.raises(IllegalState) as info:
        check(Request.MODE, FLT, "red limit: vcc_io_v = 3.3 V outside [0, 0.2]")
    msg = str(info.value)
    assert "change the imaging mode" in msg
    assert "fault" in msg and "red limit: vcc_io_v" in msg
    assert "camctl reset" in msg
    assert info.value.state == FLT and info.value.request == Request.MODE


def test_refusal_when_disconnected_says_how_to_connect() -> None:
    with pytest.raises(IllegalState) as info:
        check(Request.PING, DIS, "link lost: read failed")
    msg = str(info.value)
    assert "disconnected" in msg and "link lost" in msg
    assert "start the camera" in msg and "cable" in msg


def test_transition_table() -> None:
    assert next_state(DIS, Trigger.PROBE_IDLE) == IDLE
    assert next_state(DIS, Trigger.PROBE_FAULT) == FLT
    assert next_state(IDLE, Trigger.LINK_LOST) == DIS
    assert next_state(FLT, Trigger.LINK_LOST) == DIS
    assert next_state(IDLE, Trigger.DEVICE_FAULT) == FLT
    assert next_state(IDLE, Trigger.RED_LIMIT) == FLT
    assert next_state(FLT, Trigger.RESET_OK) == IDLE
    assert next_state(IDLE, Trigger.RESET_OK) == IDLE
    # Not listed: nothing happens.
    assert next_state(DIS, Trigger.RED_LIMIT) == DIS
    assert next_state(DIS, Trigger.RESET_OK) == DIS
    assert next_state(FLT, Trigger.PROBE_IDLE) == FLT  # only RESET clears a fault
    assert next_state(DIS, Trigger.LINK_LOST) == DIS
    # Streaming: entered and left by START/STOP; a fault, a reset or a reboot ends it.
    assert next_state(IDLE, Trigger.STREAM_STARTED) == STR
    assert next_state(STR, Trigger.STREAM_STOPPED) == IDLE
    assert next_state(STR, Trigger.DEVICE_FAULT) == FLT
    assert next_state(STR, Trigger.RED_LIMIT) == FLT
    assert next_state(STR, Trigger.RESET_OK) == IDLE
    assert next_state(STR, Trigger.PROBE_IDLE) == IDLE
    assert next_state(FLT, Trigger.STREAM_STARTED) == FLT


def test_link_loss_leads_to_disconnected_from_everywhere() -> None:
    for s in State:
        assert next_state(s, Trigger.LINK_LOST) == DIS


def test_transitions_only_use_known_states() -> None:
    for (s, t), new in TRANSITIONS.items():
        assert isinstance(s, State) and isinstance(t, Trigger) and isinstance(new, State)


def test_machine_session_story() -> None:
    m = StateMachine()
    assert m.state == DIS
    change = m.fire(Trigger.PROBE_IDLE)
    assert change is not None and (change.old, change.new) == (DIS, IDLE)
    assert m.snapshot.reason is None
    assert m.fire(Trigger.PROBE_IDLE) is None  # no change, no event

    change = m.fire(Trigger.RED_LIMIT, "red limit: fpga_temp_degc")
    assert change is not None and change.new == FLT and change.reason == "red limit: fpga_temp_degc"
    # A second fault keeps the first reason: it is what the operator must fix first.
    assert m.fire(Trigger.DEVICE_FAULT, "device fault") is None
    assert m.snapshot.reason == "red limit: fpga_temp_degc"
    with pytest.raises(IllegalState, match="fpga_temp_degc"):
        m.check(Request.MODE)
    assert m.check(Request.RESET).state == FLT

    change = m.fire(Trigger.RESET_OK, "reset")
    assert change is not None and change.new == IDLE and m.snapshot.reason is None

    change = m.fire(Trigger.LINK_LOST, "link lost: EIO")
    assert change is not None and change.new == DIS and m.snapshot.reason == "link lost: EIO"
    assert m.fire(Trigger.RESET_OK) is None and m.state == DIS


def test_snapshot_since_moves_on_change_only() -> None:
    m = StateMachine()
    t0 = m.snapshot.since_t_s
    m.fire(Trigger.RED_LIMIT)  # ignored while disconnected
    assert m.snapshot.since_t_s == t0
    m.fire(Trigger.PROBE_IDLE)
    assert m.snapshot.since_t_s >= t0


def test_concurrent_fires_report_each_change_once() -> None:
    m = StateMachine(IDLE)
    changes = []
    lock = threading.Lock()

    def worker() -> None:
        c = m.fire(Trigger.DEVICE_FAULT, "x")
        if c is not None:
            with lock:
                changes.append(c)

    threads = [threading.Thread(target=worker) for _ in range(16)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(changes) == 1 and m.state == FLT
