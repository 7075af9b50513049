"""camd.timing against hand-computed values from docs/physics.md §2-3, plus properties and errors.

Expected numbers are worked out by hand in the comments, never by calling the simulator.
"""

from __future__ import annotations

import math

import pytest
from hypothesis import assume, given
from hypothesis import strategies as st

from camd.timing import (
    EXACT_MULTIPLE_RTOL,
    HR400_CLOCKS_PER_LINE,
    TdiWindow,
    exposure_s,
    global_frame_time_s,
    max_rolling_integration_s,
    rolling_frame_time_s,
    rolling_line_period_s,
    sequencer_frame_period_lines,
    sequencer_frame_period_s,
    sequencer_frame_time_s,
    sequencer_line_period_s,
    synchronous_stage_speed_m_s,
    tdi_line_period_s,
    tdi_window,
    turntable_line_period_s,
)

# IBIS5 row period (docs/physics.md §2 eq 4): 3.5 us blanking + 1280 px / 40 MHz = 3.5 + 32 = 35.5 us.
IBIS5_ROW_S = 35.5e-6
# HR400 line period (docs/physics.md §3): 513 clocks / 25 MHz = 20.52 us.
HR400_LINE_S = 20.52e-6


# -- §2 eqs 1-4 ----------------------------------------------------------------------------------


def test_rolling_line_period_ibis5() -> None:
    assert rolling_line_period_s(3.5e-6, 1280, 40e6) == pytest.approx(IBIS5_ROW_S, rel=1e-12)


def test_rolling_line_period_without_blanking() -> None:
    # 1000 px at 10 MHz = 100 us
    assert rolling_line_period_s(0.0, 1000, 10e6) == pytest.approx(100e-6, rel=1e-12)


def test_rolling_frame_time() -> None:
    # eq 2: 100 rows x 35.5 us = 3.55 ms
    assert rolling_frame_time_s(IBIS5_ROW_S, 100) == pytest.approx(3.55e-3, rel=1e-12)


def test_global_frame_time() -> None:
    # eq 1: 1 ms integration + 100 x 35.5 us readout = 4.55 ms
    assert global_frame_time_s(1e-3, IBIS5_ROW_S, 100) == pytest.approx(4.55e-3, rel=1e-12)
    assert global_frame_time_s(0.0, IBIS5_ROW_S, 100) == pytest.approx(3.55e-3, rel=1e-12)


def test_max_rolling_integration() -> None:
    # eq 3: 35.5 us x (100 - 1) = 3.5145 ms; one row leaves no integration time
    assert max_rolling_integration_s(IBIS5_ROW_S, 100) == pytest.approx(3.5145e-3, rel=1e-12)
    assert max_rolling_integration_s(IBIS5_ROW_S, 1) == 0.0


# -- §2 eq 5 and T = p / v -------------------------------------------------------------------------


def test_synchronous_stage_speed() -> None:
    # MT9M001 on YUAN13's rail: 5.2 um pitch, 1 ms line period, image 1/20 of the object:
    # the image must move 5.2 mm/s, the stage 20 times that, 104 mm/s (docs/physics.md §6 eq 9).
    assert synchronous_stage_speed_m_s(5.2e-6, 1e-3) == pytest.approx(5.2e-3, rel=1e-12)
    assert synchronous_stage_speed_m_s(5.2e-6, 1e-3, 0.05) == pytest.approx(0.104, rel=1e-12)
    # The inverse of the line period from the image velocity.
    v = synchronous_stage_speed_m_s(11e-6, 100e-6)
    assert tdi_line_period_s(11e-6, v) == pytest.approx(100e-6, rel=1e-12)
    with pytest.raises(ValueError, match="magnification must be > 0"):
        synchronous_stage_speed_m_s(5.2e-6, 1e-3, 0.0)


def test_tdi_line_period_from_image_velocity() -> None:
    # 11 um pitch, image at 0.11 m/s on the focal plane: 100 us per line
    assert tdi_line_period_s(11e-6, 0.11) == pytest.approx(100e-6, rel=1e-12)


def test_turntable_line_period() -> None:
    # eq 5: a = 6.7 um, w = 0.01 rad/s, l = 0.5 m: 6.7e-6 / 0.005 = 1.34 ms
    assert turntable_line_period_s(6.7e-6, 0.01, 0.5) == pytest.approx(1.34e-3, rel=1e-12)


# -- §2 eqs 6-9, 13 ---------------------------------------------------------------------------------


def test_tdi_window_hand_computed() -> None:
    # 1340 us / 35.5 us = 37.75 -> 37 rows, back = 1340 - 37 x 35.5 = 1340 - 1313.5 = 26.5 us
    window = tdi_window(1.34e-3, IBIS5_ROW_S)
    assert isinstance(window, TdiWindow)
    assert window.n_lines == 37
    assert window.max_stages == 37
    assert window.back_path_s == pytest.approx(26.5e-6, rel=1e-9)
    assert window.frame_time_s == pytest.approx(37 * 35.5e-6, rel=1e-12)


@pytest.mark.parametrize("multiple", [1, 2, 3, 7, 10, 37, 100, 1000])
@pytest.mark.parametrize("row_s", [IBIS5_ROW_S, HR400_LINE_S, 0.1e-6 * 7, 1e-3 / 3])
def test_tdi_window_exact_multiples_give_zero_back_path(multiple: int, row_s: float) -> None:
    # e.g. 3 x 0.7e-6 / 0.7e-6 is 2.9999999999999996 in floats; it must still be 3 rows
    window = tdi_window(multiple * row_s, row_s)
    assert window.n_lines == multiple
    assert window.max_stages == multiple
    assert window.back_path_s == 0.0


def test_tdi_window_one_row() -> None:
    window = tdi_window(1.5 * IBIS5_ROW_S, IBIS5_ROW_S)
    assert window.n_lines == 1
    assert window.back_path_s == pytest.approx(0.5 * IBIS5_ROW_S, rel=1e-9)


def test_tdi_window_refuses_period_shorter_than_a_row() -> None:
    with pytest.raises(ValueError, match="shorter than one row period"):
        tdi_window(30e-6, IBIS5_ROW_S)


@given(
    row_s=st.floats(min_value=1e-7, max_value=1e-2),
    ratio=st.floats(min_value=1.0, max_value=5000.0),
)
def test_tdi_window_properties(row_s: float, ratio: float) -> None:
    tdi_s = row_s * ratio
    assume(tdi_s >= row_s)
    window = tdi_window(tdi_s, row_s)
    assert window.n_lines >= 1
    assert window.max_stages == window.n_lines
    assert 0.0 <= window.back_path_s < row_s
    assert window.n_lines * row_s + window.back_path_s == pytest.approx(tdi_s, rel=1e-8)
    assert window.frame_time_s == pytest.approx(window.n_lines * row_s, rel=1e-12)
    # n_lines is the floor of the quotient, up to the documented tolerance
    quotient = tdi_s / row_s
    assert abs(window.n_lines - math.floor(quotient)) <= 1
    if window.n_lines != math.floor(quotient):
        assert abs(quotient - window.n_lines) <= EXACT_MULTIPLE_RTOL * quotient


@given(row_s=st.floats(min_value=1e-7, max_value=1e-2), multiple=st.integers(1, 10_000))
def test_tdi_window_integer_multiples(row_s: float, multiple: int) -> None:
    window = tdi_window(multiple * row_s, row_s)
    assert (window.n_lines, window.back_path_s) == (multiple, 0.0)


# -- §3 ---------------------------------------------------------------------------------------------


def test_sequencer_line_period_hr400() -> None:
    assert HR400_CLOCKS_PER_LINE == 513
    assert sequencer_line_period_s(25e6) == pytest.approx(HR400_LINE_S, rel=1e-12)
    assert sequencer_line_period_s(10e6, clocks_per_line=1000) == pytest.approx(100e-6, rel=1e-12)


def test_exposure() -> None:
    # n = 2: 2 x 20.52 us = 41.04 us; with T_RES = 1 us: 42.04 us; n = 0: T_RES alone
    assert exposure_s(2, HR400_LINE_S) == pytest.approx(41.04e-6, rel=1e-12)
    assert exposure_s(2, HR400_LINE_S, t_res_s=1e-6) == pytest.approx(42.04e-6, rel=1e-12)
    assert exposure_s(0, HR400_LINE_S, t_res_s=1e-6) == pytest.approx(1e-6, rel=1e-12)


def test_sequencer_frame_time_mission_window() -> None:
    # k = 534 rows (757..1290); n = 2: (2 + 534 + 1) x 20.52 us = 537 x 20.52 us = 11.01924 ms
    assert sequencer_frame_time_s(2, 534, HR400_LINE_S) == pytest.approx(11.01924e-3, rel=1e-12)
    # n = 537: 1072 x 20.52 us = 21.99744 ms
    assert sequencer_frame_time_s(537, 534, HR400_LINE_S) == pytest.approx(21.99744e-3, rel=1e-12)


def test_sequencer_frame_period_lines() -> None:
    assert sequencer_frame_period_lines(2, 534) == 534  # n < k: the reset address never pauses
    assert sequencer_frame_period_lines(533, 534) == 534  # n + 1 == k: both rules agree
    assert sequencer_frame_period_lines(537, 534) == 538  # n >= k: n + 1 lines per row cycle
    assert sequencer_frame_period_lines(0, 1) == 1
    assert sequencer_frame_period_s(537, 534, HR400_LINE_S) == pytest.approx(
        538 * HR400_LINE_S, rel=1e-12
    )


# -- errors -------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (lambda: rolling_line_period_s(-1e-6, 1280, 40e6), "row_blanking_s must be >= 0"),
        (lambda: rolling_line_period_s(3.5e-6, 0, 40e6), "n_pixels must be >= 1"),
        (lambda: rolling_line_period_s(3.5e-6, 1280, 0.0), "pixel_rate_hz must be > 0"),
        (lambda: rolling_line_period_s(3.5e-6, 1280, math.nan), "pixel_rate_hz must be finite"),
        (lambda: rolling_line_period_s(3.5e-6, 12.5, 40e6), "n_pixels must be an integer"),  # type: ignore[arg-type]
        (lambda: rolling_frame_time_s(0.0, 10), "line_period_s must be > 0"),
        (lambda: rolling_frame_time_s(1e-5, 0), "n_lines must be >= 1"),
        (lambda: global_frame_time_s(-1.0, 1e-5, 10), "integration_s must be >= 0"),
        (lambda: max_rolling_integration_s(1e-5, 0), "n_lines must be >= 1"),
        (lambda: sequencer_line_period_s(0.0), "clock_hz must be > 0"),
        (lambda: sequencer_line_period_s(-25e6), "clock_hz must be > 0"),
        (lambda: sequencer_line_period_s(25e6, 0), "clocks_per_line must be >= 1"),
        (lambda: exposure_s(-1, 1e-5), "exposure_lines must be >= 0"),
        (lambda: exposure_s(True, 1e-5), "exposure_lines must be an integer"),
        (lambda: exposure_s(2, 1e-5, -1e-6), "t_res_s must be >= 0"),
        (lambda: sequencer_frame_time_s(2, 0, 1e-5), "window_rows must be >= 1"),
        (lambda: sequencer_frame_period_lines(-1, 10), "exposure_lines must be >= 0"),
        (lambda: tdi_line_period_s(0.0, 0.1), "pixel_pitch_m must be > 0"),
        (lambda: tdi_line_period_s(11e-6, -0.1), "image_velocity_m_per_s must be > 0"),
        (
            lambda: turntable_line_period_s(6.7e-6, 0.0, 0.5),
            "angular_velocity_rad_per_s must be > 0",
        ),
        (lambda: turntable_line_period_s(6.7e-6, 0.01, math.inf), "radius_m must be finite"),
        (lambda: tdi_window(1e-3, 0.0), "row_period_s must be > 0"),
        (lambda: tdi_window(-1e-3, 1e-5), "tdi_line_period_s must be > 0"),
    ],
)
def test_bad_inputs_raise_clear_errors(call: object, message: str) -> None:
    assert callable(call)
    with pytest.raises(ValueError, match=message):
        call()


def test_velocity_mismatch_is_yuan13_dv_over_v() -> None:
    # docs/physics.md §6: dV/V = (V - V_m) / V. A stage 2 % slow: +0.02; 1 % fast: -0.01.
    from camd.timing import velocity_mismatch

    assert velocity_mismatch(0.11, 0.1078) == pytest.approx(0.02, rel=1e-12)
    assert velocity_mismatch(0.5, 0.505) == pytest.approx(-0.01, rel=1e-12)
    assert velocity_mismatch(0.2, 0.2) == 0.0
    with pytest.raises(ValueError, match="sync_speed_m_s"):
        velocity_mismatch(0.0, 0.1)
