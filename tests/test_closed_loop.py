"""The closed loop's pure logic (camd.motion.closed_loop), alone and against the simulated stage.

The daemon runs the same objects over the RS-422 link (tests/test_motion_stack.py); here the
loop drives firmware_models.motor.MotorController directly, with a fixed poll period and
latency, so its behaviour is deterministic.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from camd.motion.closed_loop import (
    EncoderSample,
    LinePeriodTrim,
    SpeedEstimator,
    SpeedTrim,
)
from camd.motion.stage_profile import load_stage_profile
from camd.timing import tdi_window
from firmware_models.motor import MotorController
from firmware_models.stage import StageFaults

RAIL = load_stage_profile("linear_rail")


def test_estimator_slopes_are_exact_whatever_the_command_did() -> None:
    est = SpeedEstimator(window_s=0.02)
    assert est.add(EncoderSample(0.0, 0.0, 0.0)) is None
    # The command doubled half-way through the interval: both positions saw it, the ratio
    # (encoder 1 % faster than commanded) stays exact.
    got = est.add(EncoderSample(0.01, 0.0101 * 1.5, 0.0100 * 1.5))
    assert got is not None
    measured, commanded = got
    assert measured / commanded == pytest.approx(1.01, rel=1e-12)
    assert est.centre_s == pytest.approx(0.005) and est.span_s == pytest.approx(0.01)


def test_estimator_window_spans_time_and_travel() -> None:
    est = SpeedEstimator(window_s=0.005, min_span_m=0.003)
    for k in range(10):  # 1 mm per 10 ms: the travel rule keeps 3 intervals
        est.add(EncoderSample(0.01 * k, 0.001 * k, 0.001 * k))
    assert est.span_s == pytest.approx(0.03)
    fine = SpeedEstimator(window_s=0.005)
    for k in range(10):
        fine.add(EncoderSample(0.01 * k, 0.001 * k, 0.001 * k))
    assert fine.span_s == pytest.approx(0.01)  # consecutive readings


def test_speed_trim_corrects_a_clock_error_in_one_step_and_clamps() -> None:
    trim = SpeedTrim(0.05, gain=1.0, max_trim=0.1)
    # The stage runs 0.5 % fast for what it is told: the next command is 0.05 / 1.005.
    assert trim.update(0.05 * 1.005, 0.05) == pytest.approx(0.05 / 1.005, rel=1e-12)
    # A stall (the encoder stands): the command is clamped to +10 %, not sent to infinity.
    stalled = SpeedTrim(0.05, gain=1.0, max_trim=0.1)
    assert stalled.update(0.0005, 0.05) == pytest.approx(0.055)
    reverse = SpeedTrim(-0.05, gain=1.0)
    assert reverse.update(-0.05 * 0.99, -0.05) == pytest.approx(-0.05 / 0.99, rel=1e-12)
    with pytest.raises(ValueError, match="use 0 < gain <= 1"):
        SpeedTrim(0.05, gain=1.5)
    with pytest.raises(ValueError, match="the stage must move"):
        SpeedTrim(0.0)


def test_prediction_cancels_the_lag_of_a_linear_drift() -> None:
    # The ratio rises 1 % per second; the estimate describes 10 ms ago and the correction
    # acts 10 ms ahead: extrapolating along the slope gives the ratio there exactly.
    trim = SpeedTrim(0.05, gain=1.0, predict=True)
    for k in range(5):
        t = 0.01 * k
        command = trim.update(0.05 * (1 + 0.01 * t), 0.05, at_s=t, until_s=t + 0.02)
    assert command == pytest.approx(0.05 / (1 + 0.01 * 0.06), rel=1e-12)


def test_line_period_trim_follows_the_image_speed_by_rows_and_back_path() -> None:
    row = 20.52e-6
    trim = LinePeriodTrim(pixel_pitch_m=11e-6, row_time_s=row, min_lines=96, max_lines=100)
    # 0.5 % slow: T = p / v = 2.052 ms x 1.005... = 100 rows + 10.26 us of back path (eqs 8, 9),
    # beyond the 100 rows the stream started with: the back path takes it.
    slow = trim.update(11e-6 / (100 * row) / 1.005)
    assert slow.line_period_s == pytest.approx(100 * row * 1.005, rel=1e-12)
    assert slow.n_lines == 100
    assert slow.back_path_s == pytest.approx(100 * row * 0.005, rel=1e-9)
    # 2 % fast: 98 rows and the rest as back path, as tdi_window gives.
    fast = LinePeriodTrim(pixel_pitch_m=11e-6, row_time_s=row, min_lines=96, gain=1.0)
    setting = fast.update(11e-6 / (100 * row) * 1.02)
    window = tdi_window(100 * row / 1.02, row)
    assert (setting.n_lines, setting.back_path_s) == (window.n_lines, window.back_path_s)
    assert not fast.limited
    # 10 % fast would need 90 rows < M = 96: clamped, and said so.
    clamp = LinePeriodTrim(pixel_pitch_m=11e-6, row_time_s=row, min_lines=96, gain=1.0)
    assert clamp.update(11e-6 / (100 * row) * 1.10).n_lines == 96 and clamp.limited


def run_loop(*, closed: bool, faults: StageFaults, latency_s: float = 0.003) -> float:
    """Largest |M dV/V| (M = 96, T = 2.052 ms) over 2 s of the loop driving the model."""
    motor = MotorController(RAIL, seed=3, faults=faults)
    per_m = RAIL.microsteps_per_m
    counts = RAIL.encoder_counts_per_m
    speed = 11e-6 / (0.1 * 2.052e-3)  # hr400 through the 1:10 objective, 100-row line
    motor.handle("MOTOR_ENABLE", 0.0, {"enable": "on"})
    ramp = motor.handle("MOTOR_SET_RATE", 0.0, {"rate_hz": speed * per_m})["ramp_s"]
    t0 = t = ramp + 0.05
    estimator = SpeedEstimator(0.005, min_span_m=500 / counts)
    trim = SpeedTrim(speed, gain=1.0, predict=True)
    while closed and t < t0 + 2.0:
        got = estimator.add(
            EncoderSample(t, motor.encoder_count(t) / counts, motor.steps(t) / per_m)
        )
        if got is not None:
            command = trim.update(
                *got,
                at_s=estimator.centre_s,
                until_s=t + latency_s + 0.005,
                baseline_s=estimator.span_s,
            )
            motor.handle("MOTOR_SET_RATE", t + latency_s, {"rate_hz": command * per_m})
        t += 0.01
    times = np.arange(t0 + 0.3, t0 + 2.0, 2.052e-3)
    x = np.array([motor.encoder_count(s) for s in times]) / counts
    moved = (x[96:] - x[:-96]) / (speed * 96 * 2.052e-3)
    return float(np.abs(96 * (1 - moved)).max())


def test_the_loop_holds_a_disturbed_stage_inside_the_tolerance() -> None:
    disturbed = StageFaults(error=-0.005, ripple=0.01)
    assert run_loop(closed=False, faults=disturbed) > 1.0  # 0.48 from the clock + ripple
    assert run_loop(closed=True, faults=disturbed) < 0.15
    assert run_loop(closed=True, faults=StageFaults()) < 0.15
    assert math.isfinite(run_loop(closed=True, faults=disturbed, latency_s=0.01))
