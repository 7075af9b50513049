"""The FPGA's stepper controller: MOTOR_* commands, ramps, limits, homing, stalls, events.

Rail numbers by hand (config/stages/linear_rail.toml): 1.5625 um per microstep, 640000
microsteps/m, travel 1.2 m = 768000 microsteps, maximum 64000 microsteps/s (0.1 m/s),
acceleration 320000 microsteps/s^2 (0.5 m/s^2), homing at 12800 microsteps/s (0.02 m/s),
encoder 1e6 counts/m, power-on at mid-travel: 384000 microsteps, 600000 counts.
"""

from __future__ import annotations

import itertools
import math
from typing import Any

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from camd.motion.stage_profile import load_stage_profile
from camd.protocol import load_dictionary
from firmware_models.errors import Nak
from firmware_models.motor import (
    MotorController,
    move_profile,
    trapezoid_time_s,
)
from firmware_models.stage import StageFaults

RAIL = load_stage_profile("linear_rail")
TABLE = load_stage_profile("turntable")
D = 0.005 / 3200
A = 320000.0
VMAX = 64000.0
HIGH = 768000
MID = 384000


def enabled(**faults: float) -> MotorController:
    motor = MotorController(RAIL, seed=1, faults=StageFaults(**faults))
    motor.motor_enable(0.0, enable="on")
    return motor


def nak(call: Any, *args: Any, **kwargs: Any) -> Nak:
    with pytest.raises(Nak) as info:
        call(*args, **kwargs)
    return info.value


def due(motor: MotorController) -> float:
    """When the next event is due (there must be one)."""
    t_s = motor.next_event_s()
    assert t_s is not None
    return t_s


def true_x(motor: MotorController, t_s: float) -> float:
    return float(motor.stage.position_m(np.array([t_s]))[0])


# -- power-on ---------------------------------------------------------------------------------


def test_power_on_state() -> None:
    motor = MotorController(RAIL)
    got = motor.motor_get(0.0)
    assert got == {
        "state": "disabled",
        "homed": "no",
        "steps": MID,
        "encoder": 600000,
        "rate_hz": 0.0,
        "encoder_rate_hz": 0.0,
        "at_limit": "none",
        "time_s": 0.0,
    }
    assert motor.motor_get_limits(0.0) == {
        "low_steps": 0,
        "high_steps": HIGH,
        "max_rate_hz": VMAX,
        "accel_hz_per_s": 320000,
    }
    assert true_x(motor, 0.0) == pytest.approx(0.6)
    assert motor.poll_events(1.0) == [] and motor.next_event_s() is None


def test_turntable_power_on_limits_are_the_i32_range() -> None:
    motor = MotorController(TABLE)
    limits = motor.motor_get_limits(0.0)
    assert (limits["low_steps"], limits["high_steps"]) == (-(2**31), 2**31 - 1)
    assert motor.motor_get(0.0)["steps"] == 288000  # half of 200 x 16 x 180


# -- refusals ---------------------------------------------------------------------------------


def test_motion_needs_the_driver_enabled() -> None:
    motor = MotorController(RAIL)
    for call, kwargs in [
        (motor.motor_set_rate, {"rate_hz": 1000.0}),
        (motor.motor_move, {"target_steps": 1000, "rate_hz": 0.0}),
        (motor.motor_home, {}),
    ]:
        error = nak(call, 0.0, **kwargs)
        assert error.error == "ILLEGAL_STATE"
        assert "the driver is disabled; send MOTOR_ENABLE on" in error.detail


def test_move_outside_the_soft_limits_is_refused_with_the_numbers() -> None:
    motor = enabled()
    error = nak(motor.motor_move, 0.1, target_steps=812345, rate_hz=0.0)
    assert error.error == "OUT_OF_RANGE"
    assert error.detail == (
        "MOTOR_MOVE refused: target 812345 microsteps is above the high soft limit 768000; "
        "move within [0, 768000] or widen the limits with MOTOR_SET_LIMITS"
    )
    error = nak(motor.motor_move, 0.1, target_steps=-5, rate_hz=0.0)
    assert "target -5 microsteps is below the low soft limit 0" in error.detail
    assert motor.motor_get(0.2)["state"] == "idle"  # nothing moved


def test_rates_above_the_programmed_maximum_are_refused() -> None:
    motor = enabled()
    error = nak(motor.motor_set_rate, 0.1, rate_hz=-70000.0)
    assert error.error == "OUT_OF_RANGE"
    assert "70000 microsteps/s (0.109375 m/s) is above the programmed maximum 64000" in (
        error.detail
    )
    assert "MOTOR_SET_LIMITS" in error.detail
    error = nak(motor.motor_move, 0.1, target_steps=1000, rate_hz=64001.0)
    assert "rate 64001 microsteps/s" in error.detail
    motor.motor_set_limits(0.2, low_steps=0, high_steps=HIGH, max_rate_hz=1000.0, accel_hz_per_s=A)
    error = nak(motor.motor_set_rate, 0.3, rate_hz=1500.0)
    assert "above the programmed maximum 1000 microsteps/s" in error.detail


@pytest.mark.parametrize(
    ("kwargs", "expected"),
    [
        ({"low_steps": 500, "high_steps": 500}, "low_steps 500 must be below high_steps 500"),
        ({"low_steps": -1}, "[-1, 768000] microsteps goes beyond the mechanical range [0, 768000]"),
        ({"high_steps": 800000}, "(1.2 m of travel)"),
        ({"max_rate_hz": 64000.5}, "max_rate_hz 64000.5 microsteps/s (0.100001 m/s) is above"),
        ({"accel_hz_per_s": 320001}, "accel_hz_per_s 320001 microsteps/s^2"),
        ({"low_steps": 400000}, "the stage stands at 384000 microsteps, outside [400000, 768000]"),
    ],
)
def test_bad_limits_are_refused(kwargs: dict[str, float], expected: str) -> None:
    motor = enabled()
    request: dict[str, Any] = {
        "low_steps": 0,
        "high_steps": HIGH,
        "max_rate_hz": VMAX,
        "accel_hz_per_s": A,
    }
    error = nak(motor.motor_set_limits, 0.1, **{**request, **kwargs})
    assert error.error == "OUT_OF_RANGE"
    assert expected in error.detail
    assert motor.motor_get_limits(0.2)["high_steps"] == HIGH  # unchanged


def test_state_refusals_while_moving() -> None:
    motor = enabled()
    motor.motor_set_rate(1.0, rate_hz=10000.0)
    cases: list[tuple[Any, dict[str, Any], str]] = [
        (motor.motor_enable, {"enable": "off"}, "MOTOR_ENABLE off refused: the stage is"),
        (motor.motor_home, {}, "MOTOR_HOME refused: the stage is running"),
        (
            motor.motor_set_limits,
            {"low_steps": 0, "high_steps": HIGH, "max_rate_hz": VMAX, "accel_hz_per_s": A},
            "MOTOR_SET_LIMITS refused: the stage is running",
        ),
    ]
    for call, kwargs, words in cases:
        error = nak(call, 2.0, **kwargs)
        assert error.error == "ILLEGAL_STATE"
        assert words in error.detail
    assert motor.motor_get(2.0)["state"] == "running"


# -- moves ------------------------------------------------------------------------------------


def test_trapezoid_against_hand_computed_values() -> None:
    # 100000 microsteps at 20000/s and 320000/s^2: ramps of 1/16 s over 625 microsteps each,
    # cruise (100000 - 1250) / 20000 = 4.9375 s; total 5.0625 s = d / v + v / a.
    assert trapezoid_time_s(100000, 20000, A) == pytest.approx(5.0625, rel=1e-12)
    segments = move_profile(2.0, 100.0, 0.0, 100100.0, 20000.0, A)
    assert [s.t0_s for s in segments] == pytest.approx([2.0, 2.0625, 7.0, 7.0625])
    assert [s.p0 for s in segments] == pytest.approx([100.0, 725.0, 99475.0, 100100.0])
    assert [s.v0 for s in segments] == pytest.approx([0.0, 20000.0, 20000.0, 0.0])
    assert segments[-1].p0 == 100100.0  # exactly the target
    # Short: 1000 microsteps never reach 20000/s: a triangle of 2 sqrt(d / a) = 0.1118 s,
    # peaking at sqrt(a d) = 17889 microsteps/s.
    short = move_profile(0.0, 0.0, 0.0, -1000.0, 20000.0, A)
    assert len(short) == 3
    assert short[-1].t0_s == pytest.approx(2 * math.sqrt(1000 / A), rel=1e-12)
    assert short[1].v0 == pytest.approx(-math.sqrt(A * 1000), rel=1e-12)


@given(
    start=st.floats(-1e6, 1e6),
    distance=st.floats(-1e6, 1e6),
    vmax=st.floats(1.0, 4e5),
    accel=st.floats(1.0, 1e7),
)
def test_rest_to_rest_moves_take_the_trapezoid_time(
    start: float, distance: float, vmax: float, accel: float
) -> None:
    target = start + distance
    segments = move_profile(0.0, start, 0.0, target, vmax, accel)
    assert segments[-1].p0 == target and segments[-1].v0 == 0.0
    moved = target - start
    expected = trapezoid_time_s(moved, vmax, accel) if abs(moved) > 1e-9 else 0.0  # "there"
    assert segments[-1].t0_s == pytest.approx(expected, rel=1e-9, abs=1e-12)
    # Continuity, to the rounding of the segment times (a ulp of t times the acceleration).
    slack = 1e-15 * accel * segments[-1].t0_s
    for seg, nxt in itertools.pairwise(segments):
        p, v = seg.at(nxt.t0_s)
        assert abs(v - nxt.v0) <= 1e-6 * vmax + 4 * slack
        assert abs(p - nxt.p0) <= 1e-6 * max(1.0, abs(distance))
        assert abs(seg.v0) <= vmax * (1 + 1e-9) and abs(seg.a) <= accel * (1 + 1e-9)


def test_move_runs_and_reports_done_once() -> None:
    motor = enabled()
    answer = motor.motor_move(1.0, target_steps=MID + 100000, rate_hz=20000.0)
    assert answer == {"duration_s": pytest.approx(5.0625, rel=1e-12)}
    assert motor.next_event_s() == pytest.approx(6.0625)
    assert motor.motor_get(3.0)["state"] == "moving"
    assert motor.motor_get(3.0)["rate_hz"] == 20000.0
    assert motor.poll_events(6.0) == []
    events = motor.poll_events(6.1)
    assert events == [
        ("MOTOR_STOPPED", {"reason": "done", "steps": MID + 100000, "encoder": 756250})
    ]
    assert motor.poll_events(7.0) == []
    assert true_x(motor, 7.0) == pytest.approx(0.6 + 100000 * D, abs=1e-12)
    assert motor.motor_get(7.0)["state"] == "idle"


def test_move_with_rate_zero_uses_the_maximum_and_a_move_to_here_is_done_at_once() -> None:
    motor = enabled()
    answer = motor.motor_move(1.0, target_steps=MID - 300000, rate_hz=0.0)
    assert answer["duration_s"] == pytest.approx(trapezoid_time_s(300000, VMAX, A))
    motor.poll_events(20.0)
    assert motor.motor_move(21.0, target_steps=MID - 300000, rate_hz=0.0) == {"duration_s": 0.0}
    assert motor.poll_events(21.0) == [
        ("MOTOR_STOPPED", {"reason": "done", "steps": MID - 300000, "encoder": 131250})
    ]


def test_a_move_while_moving_away_brakes_then_returns() -> None:
    motor = enabled()
    motor.motor_set_rate(1.0, rate_hz=VMAX)
    duration = motor.motor_move(2.0, target_steps=MID, rate_hz=0.0)["duration_s"]
    p_now = motor.steps(2.0)
    overshoot = VMAX**2 / (2 * A)  # 6400 microsteps of braking
    back = p_now + overshoot - MID
    expected = VMAX / A + trapezoid_time_s(back, VMAX, A)
    assert duration == pytest.approx(expected, rel=1e-9)
    assert motor.poll_events(2.0 + duration)[0][1]["steps"] == MID


# -- jogs, ramps, limits --------------------------------------------------------------------------


def test_jog_ramps_then_runs_and_a_trim_is_a_short_ramp() -> None:
    motor = enabled()
    answer = motor.motor_set_rate(1.0, rate_hz=35840.0)
    assert answer == {"ramp_s": pytest.approx(0.112), "steps": MID}  # 56 mm/s at 0.5 m/s^2
    assert motor.motor_get(1.05)["state"] == "ramping"
    assert motor.motor_get(1.05)["rate_hz"] == pytest.approx(16000.0)
    assert motor.motor_get(2.0)["state"] == "running"
    # Trim by 0.1 %: a ramp of 35.84 / 320000 = 112 us, then the new rate: no stop.
    trim = motor.motor_set_rate(2.0, rate_hz=35875.84)
    assert trim["ramp_s"] == pytest.approx(35.84 / A)
    assert motor.motor_get(2.00005)["state"] == "ramping"
    got = motor.motor_get(2.001)
    assert got["state"] == "running" and got["rate_hz"] == pytest.approx(35875.84)
    assert motor.poll_events(2.5) == []
    # Measured on the true stage: 56.056 mm/s.
    v = motor.stage.velocity_m_s(np.array([2.5]))[0]
    assert v == pytest.approx(35875.84 * D, rel=1e-9)


def test_reversing_a_jog_ramps_through_zero() -> None:
    motor = enabled()
    motor.motor_set_rate(1.0, rate_hz=32000.0)
    answer = motor.motor_set_rate(2.0, rate_hz=-32000.0)
    assert answer["ramp_s"] == pytest.approx(0.2)  # 64000 / 320000
    assert motor.motor_get(2.1)["rate_hz"] == pytest.approx(0.0, abs=1e-6)
    assert motor.motor_get(2.2)["rate_hz"] == pytest.approx(-32000.0)
    assert motor.poll_events(2.3) == []  # passing through zero is not a stop


@pytest.mark.parametrize("rate", [VMAX, 20000.0, -45000.0, 80.0])
def test_jog_stops_exactly_at_the_soft_limit(rate: float) -> None:
    motor = enabled()
    low, high = MID - 4000, MID + 5000  # close: the jog must brake in time
    motor.motor_set_limits(0.5, low_steps=low, high_steps=high, max_rate_hz=VMAX, accel_hz_per_s=A)
    motor.motor_set_rate(1.0, rate_hz=rate)
    # At 80 microsteps/s the limit is 62.5 s away, beyond the controller's 60 s look ahead:
    # next_event_s then says when to look again.
    events: list[Any] = []
    end: float | None = None
    while not events:
        end = due(motor)
        events = motor.poll_events(end)
    assert end is not None
    limit, reason = (high, "limit_high") if rate > 0 else (low, "limit_low")
    ((name, values),) = events
    assert (name, values["reason"], values["steps"]) == ("MOTOR_STOPPED", reason, limit)
    # The commanded position never passed the limit, and the carriage stands on it.
    times = np.linspace(1.0, end + 1.0, 20001)
    p, _, _ = motor.stage.commanded(times)
    assert np.all(p <= high + 1e-6) and np.all(p >= low - 1e-6)
    assert true_x(motor, end + 1.0) == pytest.approx(limit * D, abs=1e-12)
    got = motor.motor_get(end + 1.0)
    assert got["at_limit"] == ("high" if rate > 0 else "low")
    assert got["state"] == "idle"
    error = nak(motor.motor_set_rate, end + 2.0, rate_hz=rate)
    assert error.error == "OUT_OF_RANGE"
    assert f"stands at the {got['at_limit']} soft limit {limit} microsteps" in error.detail
    motor.motor_set_rate(end + 2.0, rate_hz=-rate)  # the other way is allowed


def test_stop_brakes_at_the_programmed_acceleration() -> None:
    motor = enabled()
    motor.motor_set_rate(1.0, rate_hz=32000.0)
    answer = motor.motor_stop(2.0)
    assert answer["stop_s"] == pytest.approx(0.1)
    assert answer["steps"] == round(MID + 32000 * 0.9 + 0.5 * 32000 * 0.1)
    ((_, values),) = motor.poll_events(2.2)
    assert values["reason"] == "done"
    assert values["steps"] == round(MID + 32000 * 0.9 + 0.5 * 32000 * 0.1 + 1600)
    assert motor.motor_stop(3.0) == {"steps": values["steps"], "stop_s": 0.0}
    assert motor.poll_events(4.0) == []


# -- estop, enable, home ------------------------------------------------------------------------


def test_estop_stops_the_pulses_at_once_and_latches() -> None:
    motor = enabled()
    motor.motor_set_rate(1.0, rate_hz=32000.0)
    answer = motor.motor_estop(2.0)
    steps = MID + round(32000 * 0.9 + 0.5 * 32000 * 0.1)
    assert answer == {"steps": steps, "encoder": math.floor((0.6 + (steps - MID) * D) * 1e6)}
    assert motor.poll_events(2.0) == [("MOTOR_STOPPED", {"reason": "estop", **answer})]
    assert motor.motor_get(2.0)["rate_hz"] == 0.0
    assert motor.motor_get(5.0)["steps"] == steps  # no ramp: not one pulse more
    assert motor.motor_get(5.0)["state"] == "estop"
    error = nak(motor.motor_move, 5.0, target_steps=MID, rate_hz=0.0)
    assert "emergency stop; MOTOR_ENABLE on clears it" in error.detail
    motor.motor_enable(6.0, enable="off")
    assert motor.motor_get(6.0)["state"] == "estop"  # only ENABLE on clears it
    motor.motor_enable(6.0, enable="on")
    assert motor.motor_get(6.0)["state"] == "idle"
    motor.motor_enable(7.0, enable="off")
    assert motor.motor_get(7.0)["state"] == "disabled"


def test_home_finds_the_switch_and_zeroes_steps_and_encoder() -> None:
    motor = enabled()
    answer = motor.motor_home(1.0)
    # 0.6 m at 0.02 m/s after a 0.04 s ramp (0.4 mm), brake 0.04 s, back 0.4 mm.
    run = 0.04 + (0.6 - 0.0004) / 0.02
    back = trapezoid_time_s(0.0004 * 640000, 12800, A)
    assert answer["duration_s"] == pytest.approx(run + 0.04 + back, rel=1e-6)
    assert motor.motor_get(10.0)["state"] == "homing"
    assert motor.motor_get(10.0)["homed"] == "no"
    end = due(motor)
    assert end == pytest.approx(1.0 + answer["duration_s"])
    assert motor.poll_events(end) == [
        ("MOTOR_STOPPED", {"reason": "homed", "steps": 0, "encoder": 0})
    ]
    got = motor.motor_get(end + 1.0)
    assert (got["state"], got["homed"], got["steps"], got["encoder"]) == ("idle", "yes", 0, 0)
    assert true_x(motor, end + 1.0) == pytest.approx(0.0, abs=1e-12)
    assert motor.motor_get_limits(end + 1.0)["low_steps"] == 0  # the limits stay
    motor.motor_move(end + 1.0, target_steps=64000, rate_hz=0.0)
    motor.poll_events(end + 5.0)
    assert motor.encoder_count(end + 5.0) == 100000  # 0.1 m from home


def test_home_with_a_speed_error_trips_at_the_switch_all_the_same() -> None:
    motor = enabled(error=0.01)
    answer = motor.motor_home(1.0)
    end = due(motor)
    assert end == pytest.approx(1.0 + answer["duration_s"])
    ((_, values),) = motor.poll_events(end)
    assert values == {"reason": "homed", "steps": 0, "encoder": 0}
    # The carriage went back to the switch within the 1 % of the 0.4 mm return.
    assert abs(true_x(motor, end)) < 0.01 * 0.0004 + 1e-12


def test_faults_changed_while_homing_move_the_predicted_trip() -> None:
    motor = enabled()
    motor.motor_home(1.0)
    motor.set_faults(5.0, error=0.05)  # 5 % faster from 5 s: the switch comes sooner
    end = due(motor)
    # At 5 s the carriage is 0.6 - 0.0004 (ramp) - 0.02 x 3.96 m from the switch, then runs
    # at 0.021 m/s; after the trip: brake 0.04 s, back 256 microsteps (a triangle).
    left = 0.6 - 0.0004 - 0.02 * 3.96
    trip = 5.0 + left / 0.021
    assert end == pytest.approx(trip + 0.04 + 2 * math.sqrt(256 / A), rel=1e-9)
    ((_, values),) = motor.poll_events(end)
    assert values == {"reason": "homed", "steps": 0, "encoder": 0}


def test_turntable_homes_to_the_index_below() -> None:
    motor = MotorController(TABLE)
    motor.motor_enable(0.0, enable="on")
    motor.motor_set_rate(0.0, rate_hz=9000.0)
    motor.motor_stop(10.0)  # about 0.1 m of arc on from the power-on half turn
    motor.poll_events(11.0)
    x_before = true_x(motor, 11.0)
    circumference = 2 * math.pi * 0.1
    assert circumference / 2 < x_before < circumference
    motor.motor_home(11.0)
    end = due(motor)
    ((_, values),) = motor.poll_events(end)
    assert values == {"reason": "homed", "steps": 0, "encoder": 0}
    assert true_x(motor, end) == pytest.approx(0.0, abs=1e-12)  # the index at angle 0


def test_stop_while_homing_keeps_the_old_reference() -> None:
    motor = enabled()
    motor.motor_home(1.0)
    motor.motor_stop(5.0)
    ((_, values),) = motor.poll_events(6.0)
    assert values["reason"] == "done"
    got = motor.motor_get(6.0)
    assert got["homed"] == "no" and got["steps"] > 300000
    assert motor.motor_move(6.0, target_steps=MID, rate_hz=0.0)["duration_s"] > 0


# -- imperfections through the controller -------------------------------------------------------


def test_speed_error_shows_in_the_encoder_rate() -> None:
    motor = enabled(error=0.005)
    motor.motor_set_rate(1.0, rate_hz=32000.0)
    got = motor.motor_get(3.0)
    assert got["rate_hz"] == 32000.0
    # 32000 x 1.5625 um x 1.005 = 50.25 mm/s = 50250 counts/s (to one count per 10 ms window).
    assert got["encoder_rate_hz"] == pytest.approx(50250.0, abs=100.0)


def test_overload_stalls_and_the_following_error_check_reports_it() -> None:
    motor = enabled(load=1.2)
    motor.motor_set_rate(1.0, rate_hz=35840.0)
    stall = due(motor)
    # The first 20 ms check window after the start: 0.5 a t^2 = 64 microsteps = 100 counts
    # commanded, 0 moved.
    assert stall == pytest.approx(1.02)
    ((_, values),) = motor.poll_events(2.0)
    assert values == {"reason": "stall", "steps": MID + 64, "encoder": 600000}
    state = motor.sim_get_stage(2.0)
    assert state["missed_steps"] == 64 and state["position_m"] == pytest.approx(0.6)
    assert motor.motor_get(2.0)["state"] == "idle"


def test_missed_steps_without_a_stall_leave_a_lag() -> None:
    """Load 0.8: the ramp's last stretch (above 0.05 / (0.8 + 0.2) m/s... up to 56 mm/s)
    overloads the motor, but only briefly; at 56 mm/s (0.8 < 0.05 / 0.056) it runs again."""
    motor = enabled(load=0.8)
    motor.motor_set_rate(1.0, rate_hz=35840.0)
    assert motor.poll_events(3.0) == []
    state = motor.sim_get_stage(3.0)
    # Overloaded from 32000 microsteps/s (need 1.0 > avail 1.0 just above) to the end of the
    # ramp at 35840: (35840^2 - 32000^2) / (2 a) = 407 microsteps, to the grid.
    assert state["missed_steps"] == pytest.approx((35840**2 - 32000**2) / (2 * A), abs=80)
    got = motor.motor_get(3.0)
    lag_counts = (got["steps"] - MID) * D * 1e6 - (got["encoder"] - 600000)
    assert lag_counts == pytest.approx(state["missed_steps"] * D * 1e6, abs=2)
    assert state["velocity_m_s"] == pytest.approx(0.056, rel=1e-9)


def test_faults_set_while_running_can_stall_it_later() -> None:
    motor = enabled()
    motor.motor_set_rate(1.0, rate_hz=35840.0)
    assert due(motor) > 10.0  # the limit
    motor.sim_set_stage_faults(2.0, error=0.0, ripple=0.0, jitter=0.0, drift=0.0, load=2.0)
    stall = due(motor)
    assert stall is not None and 2.0 < stall <= 2.04 + 1e-9
    assert motor.poll_events(stall)[0][1]["reason"] == "stall"


def test_a_predicted_stall_is_withdrawn_when_the_load_goes_before_it() -> None:
    motor = enabled(load=2.0)
    motor.motor_move(1.0, target_steps=MID + 1000, rate_hz=0.0)
    assert motor.next_event_s() == pytest.approx(1.02)  # would stall
    motor.set_faults(1.01, load=0.0)
    end = due(motor)
    assert end == pytest.approx(1.0 + trapezoid_time_s(1000, VMAX, A))
    ((_, values),) = motor.poll_events(end)
    assert values["reason"] == "done" and values["steps"] == MID + 1000


def test_stage_faults_are_range_checked() -> None:
    motor = enabled()
    error = nak(
        motor.sim_set_stage_faults, 0.0, error=0.0, ripple=0.5, jitter=0.0, drift=0.0, load=0.0
    )
    assert error.error == "OUT_OF_RANGE"
    assert "ripple = 0.5 is out of range" in error.detail


def test_history_of_the_true_stage_survives_later_commands() -> None:
    motor = enabled(ripple=0.01, jitter=0.01)
    motor.motor_set_rate(1.0, rate_hz=35840.0)
    frames = np.linspace(1.0, 3.0, 2001)
    before = motor.stage.position_m(frames)
    encoders = [motor.encoder_count(t) for t in (1.5, 2.5)]
    motor.motor_set_rate(3.0, rate_hz=-10000.0)
    motor.motor_estop(3.5)
    motor.motor_enable(4.0, enable="on")
    np.testing.assert_array_equal(motor.stage.position_m(frames), before)
    assert [motor.encoder_count(t) for t in (1.5, 2.5)] == encoders


def test_deterministic_per_seed() -> None:
    def run(seed: int) -> list[Any]:
        motor = MotorController(RAIL, seed=seed, faults=StageFaults(jitter=0.02, ripple=0.01))
        motor.motor_enable(0.0, enable="on")
        motor.motor_set_rate(0.5, rate_hz=30000.0)
        out: list[Any] = [motor.motor_get(t) for t in (1.0, 2.0)]
        motor.motor_move(2.0, target_steps=MID, rate_hz=0.0)
        out.append(motor.poll_events(10.0))
        out.append(motor.sim_get_stage(10.0))
        return out

    assert run(4) == run(4)
    assert run(4) != run(5)


# -- the wire contract --------------------------------------------------------------------------


def test_every_motor_command_round_trips_through_the_dictionary() -> None:
    """Request fields decoded by camd.protocol go in, the response encodes: the names and
    units of config/protocol.toml (MOTOR_HOME: see test_long_durations_fit_the_wire)."""
    dictionary = load_dictionary()
    motor = MotorController(RAIL)
    requests: list[tuple[str, dict[str, Any]]] = [
        ("MOTOR_GET", {}),
        ("MOTOR_ENABLE", {"enable": "on"}),
        (
            "MOTOR_SET_LIMITS",
            {"low_steps": 0, "high_steps": HIGH, "max_rate_hz": VMAX, "accel_hz_per_s": 320000},
        ),
        ("MOTOR_GET_LIMITS", {}),
        ("MOTOR_SET_RATE", {"rate_hz": -1234.567}),
        ("MOTOR_STOP", {}),
        ("MOTOR_MOVE", {"target_steps": MID + 20000, "rate_hz": 0.0}),
        ("MOTOR_GET", {}),
        (
            "SIM_SET_STAGE_FAULTS",
            {"error": 0.005, "ripple": 0.01, "jitter": 0.0, "drift": 0.0, "load": 0.0},
        ),
        ("SIM_GET_STAGE", {}),
        ("MOTOR_ESTOP", {}),
        ("MOTOR_ENABLE", {"enable": "on"}),
        ("MOTOR_MOVE", {"target_steps": MID, "rate_hz": 5000.0}),
    ]
    t = 0.0
    for name, values in requests:
        spec = dictionary.command(name)
        decoded = spec.decode_request(spec.encode_request(**values))
        result = motor.handle(name, t, decoded)
        assert set(result) == {f.name for f in spec.response}, name
        spec.encode_response(**result)  # fits the wire types and ranges
        t += 0.5
    wire = {c.name for c in dictionary.commands}
    motion = {n for n in wire if n.startswith("MOTOR_")} | {"SIM_SET_STAGE_FAULTS", "SIM_GET_STAGE"}
    assert set(motor.commands) == motion
    event = dictionary.event("MOTOR_STOPPED")
    for _, (kind, values) in zip(range(10), motor.poll_events(t), strict=False):
        assert kind == "MOTOR_STOPPED"
        assert set(values) == {f.name for f in event.fields}
        event.encode(**values)


def test_long_durations_fit_the_wire() -> None:
    # MOTOR_MOVE / MOTOR_HOME duration_s is u32 x 1e-6 s (up to 4295 s): homing from
    # mid-travel takes 31.5 s, a 0.6 m move 6.2 s.
    dictionary = load_dictionary()
    motor = enabled()
    result = motor.motor_home(1.0)
    dictionary.command("MOTOR_HOME").encode_response(**result)
    result = motor.motor_stop(2.0)
    motor.poll_events(3.0)
    result = motor.motor_move(3.0, target_steps=HIGH, rate_hz=0.0)  # 0.6 m: 6.2 s
    dictionary.command("MOTOR_MOVE").encode_response(**result)


_COMMAND = st.one_of(
    st.tuples(st.just("rate"), st.floats(-VMAX, VMAX).filter(lambda r: abs(r) >= 500 or r == 0)),
    st.tuples(st.just("move"), st.integers(MID - 30000, MID + 30000)),
    st.tuples(st.just("stop"), st.just(0)),
)


@given(
    commands=st.lists(st.tuples(st.floats(0.0, 0.3), _COMMAND), min_size=1, max_size=8),
)
def test_any_command_sequence_respects_limits_rates_and_ramps(
    commands: list[tuple[float, tuple[str, float]]],
) -> None:
    motor = enabled()
    low, high = MID - 20000, MID + 20000
    motor.motor_set_limits(0.0, low_steps=low, high_steps=high, max_rate_hz=VMAX, accel_hz_per_s=A)
    t = 0.1
    for dt, (kind, arg) in commands:
        t += dt
        try:
            if kind == "rate":
                motor.motor_set_rate(t, rate_hz=arg)
            elif kind == "move":
                motor.motor_move(t, target_steps=int(arg), rate_hz=0.0)
            else:
                motor.motor_stop(t)
        except Nak as error:  # only the refusals the rules allow
            assert error.error == "OUT_OF_RANGE"
            assert "soft limit" in error.detail
    # Every command's profile ends: at a target, at a limit or at rest.
    events: list[Any] = []
    for _ in range(20):
        when = motor.next_event_s()
        if when is None:
            break
        events += motor.poll_events(when)
    assert motor.next_event_s() is None
    assert motor.motor_get(t + 100.0)["state"] == "idle"
    assert all(values["reason"] in {"done", "limit_low", "limit_high"} for _, values in events)
    times = np.linspace(0.0, t + 50.0, 40001)
    p, rate, acc = motor.stage.commanded(times)
    assert np.all(p >= low - 1e-6) and np.all(p <= high + 1e-6)
    assert np.all(np.abs(rate) <= VMAX * (1 + 1e-9))
    assert np.all(np.abs(acc) <= A * (1 + 1e-9))
    # The rate is continuous: the profile only ramps (no jump between segments).
    segments = motor.stage.segments
    for seg, nxt in itertools.pairwise(segments):
        assert seg.at(nxt.t0_s)[1] == pytest.approx(nxt.v0, abs=1e-6 * VMAX)
    # A perfect stage is where the pulses say.
    x = motor.stage.position_m(times[::400])
    np.testing.assert_allclose(x, p[::400] * D, rtol=0, atol=1e-12)
