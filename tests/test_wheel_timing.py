"""camd.timing.wheel against hand-computed values of docs/physics.md §4 (eqs 1, 4, 5, 8), and refusals.

The HR400 numbers: T_line = 513 clocks / 25 MHz = 20.52 us (config/sensors/hr400.toml), a window
of k = 534 rows (YE23's mission example), so T_frame = (n + 535) x 20.52 us (eq 6). Exposures
n x T_line near 1, 3, 15 and 60 ms (n = 49, 146, 731, 2924) give by hand:

    n      T_exp (ms)   T_frame (ms)   T_delay = 60 - T_frame/2 (ms)   w (T_frame/2 - T_c) (deg)
    49      1.00548      11.98368        54.00816                        -3.9558276792
    146     2.99592      13.97412        53.01294                        -3.8829327903
    731    15.00012      25.97832        47.01084                        -3.4433089758
    2924   60.00048      70.97868        24.51066                        -1.7952832917

(w = 73.245 deg/s, T_c = 60 ms.) The longest frame that fits the 120 ms window: n + 535 <=
120 ms / 20.52 us = 5847.95, so n = 5312 (T_frame 119.98044 ms) fits and n = 5313 (120.00096
ms) does not.
"""

from __future__ import annotations

import math
import re

import pytest
from hypothesis import given
from hypothesis import strategies as st

from camd.motion.wheel_profile import load_wheel_profile
from camd.timing import sequencer_frame_time_s, sequencer_line_period_s
from camd.timing.wheel import (
    WheelExposure,
    check_wheel_exposure,
    exposure_delay_s,
    imaging_centre_angle_deg,
    imaging_centre_error_deg,
    wheel_exposure,
)

W = 73.245  # deg/s
T_CENTER = 0.060
WINDOW = 0.120
T_LINE = 20.52e-6
K = 534
INSTRUMENT = {
    "speed_deg_s": W,
    "t_center_s": T_CENTER,
    "window_s": WINDOW,
    "entry_angle_error_deg": 0.087,
    "speed_error_deg_s": 0.03,
    "clock_stability": 20e-6,
}

# n, T_frame (s), T_delay (s), w (T_frame / 2 - T_center) (deg): the table above.
HAND = [
    (49, 11.98368e-3, 54.00816e-3, -3.9558276792),
    (146, 13.97412e-3, 53.01294e-3, -3.8829327903),
    (731, 25.97832e-3, 47.01084e-3, -3.4433089758),
    (2924, 70.97868e-3, 24.51066e-3, -1.7952832917),
]


def test_hr400_line_period_from_the_sequencer_clock() -> None:
    assert sequencer_line_period_s(25e6) == pytest.approx(T_LINE, rel=1e-12)


@pytest.mark.parametrize(("n", "frame_s", "delay_s", "drift_deg"), HAND)
def test_eq5_delay_for_hr400_exposures(
    n: int, frame_s: float, delay_s: float, drift_deg: float
) -> None:
    frame = sequencer_frame_time_s(n, K, T_LINE)  # eq 6, reused
    assert frame == pytest.approx(frame_s, rel=1e-12)
    assert exposure_delay_s(T_CENTER, frame) == pytest.approx(delay_s, rel=1e-12)


def test_eq5_returns_negative_delays() -> None:
    # 130 ms frame: 60 - 65 = -5 ms
    assert exposure_delay_s(0.060, 0.130) == pytest.approx(-0.005, rel=1e-12)


def test_eq1_centre_of_a_frame_started_at_the_pulse() -> None:
    # entry at 10 deg, T_frame 70.97868 ms: 10 + 73.245 x 0.03548934 = 12.5994167083 deg
    assert imaging_centre_angle_deg(10.0, W, 0.0, 70.97868e-3) == pytest.approx(
        12.5994167083, abs=1e-10
    )


def test_eq4_centre_with_the_delay_is_the_channel_centre() -> None:
    # entry 4.3947 deg before the centre at 100 deg: 95.6053 + 73.245 (24.51066 + 35.48934) ms
    # = 95.6053 + 4.3947 = 100 deg
    centre = imaging_centre_angle_deg(95.6053, W, 24.51066e-3, 70.97868e-3)
    assert centre == pytest.approx(100.0, abs=1e-10)


def test_eq8_with_the_instrument_values() -> None:
    # sqrt(0.087^2 + (0.06 x 0.03)^2 + (73.245 x 1.2e-6)^2)
    # = sqrt(0.007569 + 3.24e-6 + 7.7254e-9) = sqrt(0.0075722477) = 0.0870187 deg
    error = imaging_centre_error_deg(0.087, 0.060, 0.03, W, 20e-6 * 0.060)
    assert error == pytest.approx(0.08701866, abs=1e-8)
    assert error == pytest.approx(0.08702, abs=5e-6)


def test_eq8_single_terms() -> None:
    assert imaging_centre_error_deg(0.0, 0.5, 0.02, 10.0, 0.0) == pytest.approx(0.01)  # T_c dw
    assert imaging_centre_error_deg(0.0, 0.5, 0.0, 10.0, 1e-3) == pytest.approx(0.01)  # w dT_c
    assert imaging_centre_error_deg(0.3, 0.5, 0.0, 10.0, 0.0) == pytest.approx(0.3)


@pytest.mark.parametrize(("n", "frame_s", "delay_s", "drift_deg"), HAND)
def test_wheel_exposure_compensated_is_centred(
    n: int, frame_s: float, delay_s: float, drift_deg: float
) -> None:
    exposure = wheel_exposure(sequencer_frame_time_s(n, K, T_LINE), compensated=True, **INSTRUMENT)
    assert isinstance(exposure, WheelExposure)
    assert exposure.frame_time_s == pytest.approx(frame_s, rel=1e-12)
    assert exposure.delay_s == pytest.approx(delay_s, rel=1e-12)
    assert exposure.centre_offset_deg == pytest.approx(0.0, abs=1e-12)
    assert exposure.centre_error_deg == pytest.approx(0.08701866, abs=1e-8)


@pytest.mark.parametrize(("n", "frame_s", "delay_s", "drift_deg"), HAND)
def test_wheel_exposure_uncompensated_drifts_as_w_tframe_over_2(
    n: int, frame_s: float, delay_s: float, drift_deg: float
) -> None:
    exposure = wheel_exposure(sequencer_frame_time_s(n, K, T_LINE), compensated=False, **INSTRUMENT)
    assert exposure.delay_s == 0.0
    assert exposure.centre_offset_deg == pytest.approx(drift_deg, abs=1e-10)
    # eq 8 with T_frame / 2 in place of T_center
    half = frame_s / 2
    expected = math.sqrt(0.087**2 + (half * 0.03) ** 2 + (W * 20e-6 * half) ** 2)
    assert exposure.centre_error_deg == pytest.approx(expected, rel=1e-12)


@given(st.integers(min_value=49, max_value=2924))  # exposures 1 .. 60 ms
def test_centre_independent_of_exposure_with_compensation(n: int) -> None:
    frame = sequencer_frame_time_s(n, K, T_LINE)
    on = wheel_exposure(frame, compensated=True, **INSTRUMENT)
    off = wheel_exposure(frame, compensated=False, **INSTRUMENT)
    assert on.centre_offset_deg == pytest.approx(0.0, abs=1e-12)
    assert off.centre_offset_deg == pytest.approx(W * (frame / 2 - T_CENTER), abs=1e-12)
    # without compensation the centre moves by w dT_frame / 2 per change of exposure
    longer = wheel_exposure(frame + 10 * T_LINE, compensated=False, **INSTRUMENT)
    assert longer.centre_offset_deg - off.centre_offset_deg == pytest.approx(
        W * 5 * T_LINE, rel=1e-6
    )


def test_the_longest_frame_that_fits() -> None:
    fits = sequencer_frame_time_s(5312, K, T_LINE)
    assert fits == pytest.approx(119.98044e-3, rel=1e-12)
    for compensated in (True, False):
        check_wheel_exposure(fits, t_center_s=T_CENTER, window_s=WINDOW, compensated=compensated)
    too_long = sequencer_frame_time_s(5313, K, T_LINE)
    assert too_long == pytest.approx(120.00096e-3, rel=1e-12)
    for compensated in (True, False):
        with pytest.raises(ValueError, match=re.escape("120.001 ms exceeds")):
            check_wheel_exposure(
                too_long, t_center_s=T_CENTER, window_s=WINDOW, compensated=compensated
            )


def test_frame_longer_than_the_window_is_refused_with_the_numbers() -> None:
    with pytest.raises(ValueError) as info:
        wheel_exposure(0.130, compensated=False, **INSTRUMENT)
    message = str(info.value)
    assert "T_frame = (n + k + 1) T_line = 130 ms exceeds" in message
    assert "light window of 120 ms" in message
    assert "shorten the exposure or use fewer window rows" in message
    assert "by at least 10 ms of frame time" in message


def test_negative_delay_is_refused_only_with_compensation() -> None:
    # A 100 ms window with T_center 40 ms: a 90 ms frame fits the window but needs
    # T_delay = 40 - 45 = -5 ms.
    check_wheel_exposure(0.090, t_center_s=0.040, window_s=0.100, compensated=False)
    with pytest.raises(ValueError) as info:
        check_wheel_exposure(0.090, t_center_s=0.040, window_s=0.100, compensated=True)
    message = str(info.value)
    assert "T_delay = T_center - T_frame / 2 = 40 ms - 90 ms / 2 = -5 ms is negative" in message
    assert "T_frame <= 2 T_center = 80 ms" in message
    assert "shorten the exposure or use fewer window rows" in message


def test_the_profile_applies_the_instrument_values() -> None:
    profile = load_wheel_profile()
    frame = sequencer_frame_time_s(2924, K, T_LINE)
    assert profile.exposure(frame, compensated=True) == wheel_exposure(
        frame, compensated=True, **INSTRUMENT
    )
    with pytest.raises(ValueError, match="exceeds the channel's light window"):
        profile.exposure(0.121, compensated=True)


@pytest.mark.parametrize(
    ("call", "match"),
    [
        (lambda: exposure_delay_s(0.06, 0.0), "frame_time_s must be > 0"),
        (lambda: exposure_delay_s(-0.01, 0.05), "t_center_s must be >= 0"),
        (lambda: exposure_delay_s(math.nan, 0.05), "t_center_s must be finite"),
        (lambda: imaging_centre_angle_deg(0.0, W, -0.001, 0.01), "delay_s must be >= 0"),
        (lambda: imaging_centre_angle_deg(0.0, W, 0.0, -0.01), "frame_time_s must be > 0"),
        (lambda: imaging_centre_error_deg(-0.1, 0.06, 0.03, W, 0.0), "entry_angle_error_deg"),
        (
            lambda: check_wheel_exposure(0.01, t_center_s=0.06, window_s=0.0, compensated=True),
            "window_s must be > 0",
        ),
        (
            lambda: wheel_exposure(0.01, compensated=True, **{**INSTRUMENT, "clock_stability": -1}),
            "clock_stability must be >= 0",
        ),
    ],
)
def test_bad_arguments_are_named(call: object, match: str) -> None:
    assert callable(call)
    with pytest.raises(ValueError, match=match):
        call()
