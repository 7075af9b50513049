"""The simulated stage's commanded profile: a closed loop's trims cost the same at any age.

A scan's closed loop trims the stage's rate with MOTOR_SET_RATE every few tens of ms, and the
stage keeps 120 s of commanded segments (``HISTORY_S``). A command must not walk that history:
it held the simulator's interpreter lock against the frame renderer (3.7 ms per command at
first, 27.5 ms after 4,000 trims). The derived columns of the profile (which segments move, when
the current run started) must stay what a recomputation from the whole kept history gives,
also after the old history is dropped.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from functools import partial
from pathlib import Path
from types import FrameType

import numpy as np
import pytest

import firmware_models
from camd.motion.stage_profile import load_stage_profile
from firmware_models.motor import MotorController
from firmware_models.stage import Segment, StageFaults, StepperStage

RAIL = load_stage_profile("linear_rail")
SIMULATOR_DIR = str(Path(firmware_models.__file__).parent)
TRIM_PERIOD_S = 0.03  # a closed loop's trim every 30 ms
RATE_HZ = 2_000.0  # 0.2 m in 100 s: within the rail from mid-travel


def trimmed(trims: int) -> tuple[MotorController, float]:
    """A motor jogging with ``trims`` closed-loop trims behind it; (motor, the next trim's time)."""
    motor = MotorController(RAIL, seed=1)
    motor.motor_enable(0.0, enable="on")
    t_s = 0.01
    for i in range(trims):
        motor.motor_set_rate(t_s, rate_hz=RATE_HZ * (1.0 + 1e-3 * (i % 7 - 3)))
        t_s += TRIM_PERIOD_S
    return motor, t_s


def lines_run(call: Callable[[], object]) -> int:
    """How many lines of the simulator's code (firmware_models) ``call`` runs: a count of the
    work a command does that, unlike its time, a busy machine cannot change."""
    count = 0

    def local(frame: FrameType, event: str, arg: object) -> object:
        nonlocal count
        if event == "line":
            count += 1
        return local

    def enter(frame: FrameType, event: str, arg: object) -> object:
        return local if frame.f_code.co_filename.startswith(SIMULATOR_DIR) else None

    sys.settrace(enter)
    try:
        call()
    finally:
        sys.settrace(None)
    return count


def test_a_trim_runs_the_same_code_after_thousands_of_trims() -> None:
    # The old history has 3,000 trims behind it (90 s, under the 120 s kept), 6,000 segments.
    # Walking them ran the stage's code once per segment: 55,150 lines of the simulator for a
    # trim on the old history against 2,080 on the young one (and 10-15 times the CPU). Kept
    # columns make a trim the same work at any age (244-276 lines on either); counted, not
    # timed, so a busy machine cannot change the answer.
    young, t_young = trimmed(100)
    old, t_old = trimmed(3000)
    assert len(old.stage.segments) > 20 * len(young.stage.segments)
    for i in range(5):
        rate = RATE_HZ * (1.0 + 1e-3 * (i - 2))
        lines = {
            name: lines_run(partial(motor.motor_set_rate, t_s + i * TRIM_PERIOD_S, rate_hz=rate))
            for name, motor, t_s in (("young", young, t_young), ("old", old, t_old))
        }
        assert lines["young"] > 50, lines  # the trace sees the simulator's code
        assert lines["old"] <= lines["young"] + 40, f"trim {i}: {lines}"


def reference_columns(stage: StepperStage) -> tuple[np.ndarray, np.ndarray]:
    """(moving count before each segment, run start carried into each) recomputed from the
    whole kept profile, as one walk (the rule ``_Segments`` keeps row by row)."""
    segs = stage.segments
    t0 = np.array([s.t0_s for s in segs])
    v0 = np.array([s.v0 for s in segs])
    a = np.array([s.a for s in segs])
    moving = (v0 != 0.0) | (a != 0.0)
    prefix = np.concatenate([[0.0], np.cumsum(moving)])
    carry = np.empty_like(t0)
    for j in range(len(t0)):
        if v0[j] == 0.0 or j == 0:
            carry[j] = t0[j]
            continue
        tau_end = t0[j] - t0[j - 1]
        rate_end = v0[j - 1] + a[j - 1] * tau_end
        if a[j - 1] != 0.0 and v0[j - 1] * a[j - 1] < 0.0:
            crossing = -v0[j - 1] / a[j - 1]
            if crossing <= tau_end:
                carry[j] = t0[j - 1] + crossing
                continue
        still_before = v0[j - 1] == 0.0 and a[j - 1] == 0.0
        carry[j] = t0[j] if rate_end == 0.0 or still_before else carry[j - 1]
    return prefix, carry


@pytest.mark.parametrize("history_s", [120.0, 2.0])
def test_kept_columns_equal_a_recomputation_also_after_history_is_dropped(
    history_s: float,
) -> None:
    # Jog, trim, reverse through zero, stop and start again, with drift (which reads the run
    # start); with 2 s of history the old segments are dropped on the way.
    motor = MotorController(RAIL, seed=3, faults=StageFaults(drift=0.01), history_s=history_s)
    motor.motor_enable(0.0, enable="on")
    t_s = 0.0
    rates = [8000.0, 8100.0, -6000.0, 0.0, 0.0, 5000.0, 5050.0, -5000.0, 0.0, 9000.0]
    for i in range(120):
        t_s += 0.05 + 0.01 * (i % 3)
        motor.motor_set_rate(t_s, rate_hz=rates[i % len(rates)])
        motor.stage.position_m(np.array([t_s]))  # "now" moves on: old history is pruned
    stage = motor.stage
    t0, _, _, _, moving_through, carry = stage._segments.arrays()
    expected_prefix, expected_carry = reference_columns(stage)
    np.testing.assert_array_equal(carry, expected_carry)
    np.testing.assert_array_equal(moving_through, expected_prefix[1:])
    if history_s < 10.0:
        assert stage.kept_from_s > 1.0  # the history was pruned on the way
    # The run time drift reads is the one a recomputation gives.
    times = np.linspace(stage.kept_from_s, t_s + 1.0, 2001)
    run = stage._segments.run_time(times)
    assert np.all(run >= 0.0)
    j = np.maximum(np.searchsorted(t0, times, side="right") - 1, 0)
    still = (np.array([s.v0 for s in stage.segments])[j] == 0.0) & (
        np.array([s.a for s in stage.segments])[j] == 0.0
    )
    assert np.all(run[still] == 0.0)


def test_segments_from_a_time_are_the_tail_of_the_profile() -> None:
    stage = StepperStage(RAIL)
    stage.set_profile(1.0, [Segment(1.0, 0.0, 0.0, 1000.0), Segment(2.0, 500.0, 1000.0, 0.0)])
    stage.set_profile(3.0, [Segment(3.0, 2500.0, 1000.0, -500.0), Segment(5.0, 3500.0)])
    everything = stage.segments
    assert [s.t0_s for s in everything] == [0.0, 1.0, 2.0, 3.0, 5.0]
    assert stage.segments_from(2.5) == everything[2:]  # the one active at 2.5 s, and on
    assert stage.segments_from(3.0) == everything[3:]
    assert stage.segments_from(-1.0) == everything
    assert stage.segments_from(9.0) == everything[4:]
