"""Open-loop synchronisation (docs/physics.md §2 eqs 5-9, 13; §6 eq 9) against hand-computed values."""

from __future__ import annotations

import math

import numpy as np
import pytest

from camd.timing import (
    line_mismatch,
    scan_speed,
    step_rate_hz,
    synchronous_motion,
    turntable_angular_velocity_rad_s,
    turntable_line_period_s,
)

# A 5 mm lead screw, 200 full steps x 16 microsteps: 5e-3 / 3200 = 1.5625 um per microstep.
UM_PER_MICROSTEP = 1.5625e-6


def test_hr400_from_line_period() -> None:
    # hr400: p = 11 um, magnification 0.1, row time 513 clocks; take T_row = 20 us by hand.
    sol = synchronous_motion(
        line_period_s=2e-3,
        row_time_s=20e-6,
        pixel_pitch_m=11e-6,
        image_scale=0.1,
        metres_per_microstep=UM_PER_MICROSTEP,
        stages=96,
    )
    # V = p / (m T) = 11e-6 / (0.1 * 2e-3) = 0.055 m/s; F = 0.055 / 1.5625e-6 = 35200 Hz.
    assert sol.sync_speed == pytest.approx(0.055, rel=1e-12)
    assert sol.step_rate_hz == pytest.approx(35200.0, rel=1e-12)
    # 2 ms / 20 us = 100 rows exactly: back path 0 (eqs 8, 9), M0 = 100 (eq 13).
    assert (sol.n_lines, sol.m0, sol.stages) == (100, 100, 96)
    assert sol.back_path_s == 0.0
    assert sol.dv_over_v == 0.0 and sol.m_dv_over_v == 0.0
    assert list(sol.as_dict()) == [
        "line_period_s",
        "row_time_s",
        "n_lines",
        "back_path_s",
        "m0",
        "stages",
        "sync_speed",
        "step_rate_hz",
        "dv_over_v",
        "m_dv_over_v",
    ]


def test_ibis5_from_stage_speed() -> None:
    # ibis5: p = 6.7 um, m = 0.1; stage at 20 mm/s -> image 2 mm/s -> T = 6.7e-6 / 2e-3 = 3.35 ms.
    # Row time 3.5 us + 1280 px / 40 MHz = 35.5 us: floor(3350 / 35.5) = 94 rows, back path
    # 3350 - 94 * 35.5 = 13 us.
    sol = synchronous_motion(
        stage_speed_m_s=0.02,
        row_time_s=35.5e-6,
        pixel_pitch_m=6.7e-6,
        image_scale=0.1,
        metres_per_microstep=UM_PER_MICROSTEP,
    )
    assert sol.line_period_s == pytest.approx(3.35e-3, rel=1e-12)
    assert (sol.n_lines, sol.m0, sol.stages) == (94, 94, 94)
    assert sol.back_path_s == pytest.approx(13e-6, rel=1e-9)
    assert sol.step_rate_hz == pytest.approx(0.02 / UM_PER_MICROSTEP, rel=1e-12)  # 12800 Hz


def test_mismatch_of_a_stage_off_speed() -> None:
    # mt9m001: p = 5.2 um, m = 0.1, T = 1 ms -> V = 52 mm/s; the stage runs 0.5 % fast.
    sol = synchronous_motion(
        line_period_s=1e-3,
        stage_speed_m_s=0.052 * 1.005,
        row_time_s=10e-6,
        pixel_pitch_m=5.2e-6,
        image_scale=0.1,
        metres_per_microstep=UM_PER_MICROSTEP,
        stages=96,
    )
    assert sol.sync_speed == pytest.approx(0.052, rel=1e-12)
    assert sol.dv_over_v == pytest.approx(-0.005, rel=1e-9)
    assert sol.m_dv_over_v == pytest.approx(-0.48, rel=1e-9)


def test_turntable_eq5_round_trip() -> None:
    # uvccd-size pixel 14 um on a table at l = 0.2 m, T = 5 ms: w = a / (T l) = 0.014 rad/s.
    w = turntable_angular_velocity_rad_s(14e-6, 5e-3, 0.2)
    assert w == pytest.approx(0.014, rel=1e-12)
    assert turntable_line_period_s(14e-6, w, 0.2) == pytest.approx(5e-3, rel=1e-12)
    # On the table the sensor rides at radius l: image scale 1, arc speed w l = 2.8 mm/s.
    sol = synchronous_motion(
        line_period_s=5e-3,
        row_time_s=50e-6,
        pixel_pitch_m=14e-6,
        image_scale=1.0,
        metres_per_microstep=0.2 * 2 * math.pi / (200 * 16 * 100),  # 1:100 worm gear
    )
    assert sol.sync_speed == pytest.approx(w * 0.2, rel=1e-12)


def test_refusals_say_what_to_change() -> None:
    with pytest.raises(ValueError, match="use at most 100 stages or a longer line period"):
        synchronous_motion(
            line_period_s=2e-3,
            row_time_s=20e-6,
            pixel_pitch_m=11e-6,
            image_scale=0.1,
            metres_per_microstep=UM_PER_MICROSTEP,
            stages=101,
        )
    with pytest.raises(ValueError, match="give line_period_s or stage_speed_m_s"):
        synchronous_motion(
            row_time_s=20e-6, pixel_pitch_m=11e-6, image_scale=0.1, metres_per_microstep=1e-6
        )
    with pytest.raises(ValueError, match="metres_per_microstep must be > 0"):
        step_rate_hz(0.05, 0.0)
    assert step_rate_hz(-0.05, 1e-6) == pytest.approx(-50000.0)


def test_scan_speed_for_a_line_period_by_eq9_with_the_deliberate_mismatch() -> None:
    # hr400: p = 11 um, m = 0.1, T = 2 ms: V = p / (m T) = 0.055 m/s (§6 eq 9, n_mag = 1 / m).
    exact = scan_speed(pixel_pitch_m=11e-6, image_scale=0.1, line_period_s=2e-3)
    assert exact.sync_speed_m_s == pytest.approx(0.055, rel=1e-12)
    assert exact.speed_m_s == exact.sync_speed_m_s and exact.dv_over_v == 0.0
    # A deliberate dV/V = 0.1: the stage runs at (1 - dV/V) V = 49.5 mm/s, 10 % slow.
    slow = scan_speed(pixel_pitch_m=11e-6, image_scale=0.1, line_period_s=2e-3, dv_over_v=0.1)
    assert slow.sync_speed_m_s == exact.sync_speed_m_s
    assert slow.speed_m_s == pytest.approx(0.0495, rel=1e-12)
    assert slow.dv_over_v == pytest.approx(0.1, rel=1e-12)
    # A stage that runs at its own speed: the mismatch is (V - V_m) / V, whatever its sign.
    mt9 = scan_speed(
        pixel_pitch_m=5.2e-6, image_scale=0.1, line_period_s=1e-3, stage_speed_m_s=-0.052 * 1.005
    )
    assert mt9.sync_speed_m_s == pytest.approx(0.052, rel=1e-12)
    assert mt9.speed_m_s == pytest.approx(0.052 * 1.005, rel=1e-12)
    assert mt9.dv_over_v == pytest.approx(-0.005, rel=1e-9)


def test_scan_speed_refuses_what_it_cannot_solve() -> None:
    with pytest.raises(ValueError, match=r"line_period_s must be > 0, got 0\.0"):
        scan_speed(pixel_pitch_m=11e-6, image_scale=0.1, line_period_s=0.0)
    with pytest.raises(ValueError, match="dv_over_v must be < 1"):
        scan_speed(pixel_pitch_m=11e-6, image_scale=0.1, line_period_s=2e-3, dv_over_v=1.0)
    with pytest.raises(ValueError, match="stage_speed_m_s must be finite"):
        scan_speed(
            pixel_pitch_m=11e-6, image_scale=0.1, line_period_s=2e-3, stage_speed_m_s=math.inf
        )


def test_camctl_sync_and_the_scan_planner_take_their_speed_from_the_one_solve() -> None:
    # synchronous_motion (camctl sync) reports scan_speed's numbers to the bit.
    sol = synchronous_motion(
        line_period_s=1e-3,
        stage_speed_m_s=0.0521,
        row_time_s=10e-6,
        pixel_pitch_m=5.2e-6,
        image_scale=0.1,
        metres_per_microstep=UM_PER_MICROSTEP,
    )
    solved = scan_speed(
        pixel_pitch_m=5.2e-6, image_scale=0.1, line_period_s=1e-3, stage_speed_m_s=0.0521
    )
    assert (sol.sync_speed, sol.dv_over_v) == (solved.sync_speed_m_s, solved.dv_over_v)


def test_line_mismatch_from_encoder_latches() -> None:
    # 10 counts per pixel; the image moves 1.01 pixels per frame (dV/V = -0.01).
    counters = np.arange(20)
    encoder = np.round(counters * 10.1 * 1000) / 1000
    smear = line_mismatch(encoder, counters, stages=8, counts_per_pixel=10.0)
    assert math.isnan(smear[0])
    # Early lines integrated k periods: k dV/V; from frame 8 on all M = 8: M dV/V = -0.08.
    np.testing.assert_allclose(smear[1:8], -0.01 * np.arange(1, 8), rtol=1e-9)
    np.testing.assert_allclose(smear[8:], -0.08, rtol=1e-9)
    # A lost frame: the span is the counters' difference, not the array distance.
    keep = np.r_[0:10, 11:20]
    gap = line_mismatch(encoder[keep], counters[keep], stages=8, counts_per_pixel=10.0)
    # Counter 18: the frames of counters 10..18 minus the lost 10 -> it spans 11..18, 7 periods.
    assert gap[list(keep).index(18)] == pytest.approx(-0.07, rel=1e-9)
    assert gap[list(keep).index(19)] == pytest.approx(-0.08, rel=1e-9)
    assert gap[list(keep).index(11)] == pytest.approx(-0.08, rel=1e-9)  # 3..11: still 8
    # Reverse travel: same magnitude.
    np.testing.assert_allclose(
        line_mismatch(-encoder, counters, stages=8, counts_per_pixel=10.0)[8:], -0.08, rtol=1e-9
    )
    with pytest.raises(ValueError, match="same length"):
        line_mismatch(encoder[:5], counters, stages=8, counts_per_pixel=10.0)
