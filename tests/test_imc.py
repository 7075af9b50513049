"""Image motion compensation on a full-frame CCD (docs/physics.md §7, REN15).

The closed forms of camd.timing.imc against hand-computed values, then the numeric
charge-transfer model of firmware_models.ccd_imc against the closed forms: two independent
routes to the same modulation curves.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from fractions import Fraction
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from camd.timing.imc import (
    MEAN_ELECTRODE_STEP_MODULATION,
    MEAN_ROW_STEP_MODULATION,
    electrode_step_interval_s,
    electrode_step_modulation,
    image_velocity_m_s,
    mean_electrode_step_modulation,
    mean_row_step_modulation,
    row_step_interval_s,
    row_step_modulation,
)
from firmware_models.ccd_imc import (
    Method,
    mean_point_beam_modulation,
    modulation,
    point_beam_modulation,
    point_beam_profile,
)

W = 9e-6  # REN15's pixel (docs/physics.md §7)
# Offsets that avoid the model's time grid, so its discretisation error shows (on a grid aligned
# with the time steps the midpoint rule is exact): 997 is prime, the time steps 1/400 of a row.
A_GRID = (np.arange(997) + 0.5) * (W / 997)
STEPS = 400

ClosedForm = Callable[[Any, float], Any]
CLOSED_FORMS: list[tuple[Method, ClosedForm]] = [
    ("row", row_step_modulation),
    ("electrode", electrode_step_modulation),
]
# The model's largest error over A_GRID at 400 steps per row time is 3.1e-6 (row) and 1.25e-5
# (electrode), about 0.5 / STEPS**2 and 2.0 / STEPS**2 (docs/imc.md); 4x margin on the larger.
MODEL_TOL = 5e-5


# -- closed forms: clocking -----------------------------------------------------------------------


def test_image_velocity_ren15_rig() -> None:
    # f = 90 mm, V = 50 mm/s (the rig's top speed), H = 0.3 m: v = 0.09 * 0.05 / 0.3 = 15 mm/s
    assert image_velocity_m_s(0.09, 0.05, 0.3) == pytest.approx(0.015, rel=1e-12)
    # Aerial: f = 0.1 m, V = 200 m/s, H = 4000 m: v = 0.1 * 200 / 4000 = 5 mm/s
    assert image_velocity_m_s(0.1, 200.0, 4000.0) == pytest.approx(0.005, rel=1e-12)


def test_step_intervals_ren15_rig() -> None:
    # 9 um pixels at 15 mm/s: a row every 9e-6 / 0.015 = 600 us, an electrode (p = 4) every
    # 9e-6 / (4 * 0.015) = 150 us.
    assert row_step_interval_s(9e-6, 0.015) == pytest.approx(600e-6, rel=1e-12)
    assert electrode_step_interval_s(9e-6, 0.015) == pytest.approx(150e-6, rel=1e-12)
    assert electrode_step_interval_s(9e-6, 0.015, phases=3) == pytest.approx(200e-6, rel=1e-12)
    assert electrode_step_interval_s(9e-6, 0.015, phases=1) == row_step_interval_s(9e-6, 0.015)


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (lambda: image_velocity_m_s(0.0, 0.05, 0.3), "focal_length_m must be > 0, got 0.0"),
        (lambda: image_velocity_m_s(0.09, -0.05, 0.3), "ground_speed_m_s must be > 0"),
        (lambda: image_velocity_m_s(0.09, 0.05, math.inf), "height_m must be finite"),
        (lambda: row_step_interval_s(math.nan, 0.015), "pixel_m must be finite"),
        (lambda: row_step_interval_s(9e-6, 0.0), "image_velocity_m_s must be > 0"),
        (lambda: electrode_step_interval_s(9e-6, 0.015, phases=0), "phases must be >= 1, got 0"),
        (lambda: electrode_step_interval_s(9e-6, 0.015, True), "phases must be an integer"),
    ],
)
def test_clocking_refusals(call: Callable[[], float], message: str) -> None:
    with pytest.raises(ValueError, match=message):
        call()


# -- closed forms: modulation ---------------------------------------------------------------------


def test_row_step_modulation_hand_values() -> None:
    # M = 2a(w - a)/w^2: a = 0 -> 0; a = w/2 -> 2 (1/2)(1/2) = 1/2; a = w/4 -> 2 (1/4)(3/4) = 3/8
    assert row_step_modulation(0.0, W) == 0.0
    assert row_step_modulation(W / 2, W) == pytest.approx(0.5, abs=1e-15)
    assert row_step_modulation(W / 4, W) == pytest.approx(0.375, abs=1e-15)


def test_electrode_step_modulation_hand_values() -> None:
    # Low branch |3 - 8x|/4: x = 0 -> 3/4, x = 3/8 -> 0, x = 1/4 -> 1/4, x = 3/4 -> |3 - 6|/4 = 3/4.
    # High branch (56x - 32x^2 - 21)/4: x = 7/8 -> (49 - 24.5 - 21)/4 = 0.875 (the maximum),
    # x = 0.8 -> (44.8 - 20.48 - 21)/4 = 0.83.
    for x, expected in [(0, 0.75), (3 / 8, 0.0), (1 / 4, 0.25), (3 / 4, 0.75), (7 / 8, 0.875)]:
        assert electrode_step_modulation(x * W, W) == pytest.approx(expected, abs=1e-14)
    assert electrode_step_modulation(0.8 * W, W) == pytest.approx(0.83, abs=1e-14)


def test_modulation_is_vectorised() -> None:
    a = np.array([0.0, W / 2, 7 * W / 8])
    np.testing.assert_allclose(row_step_modulation(a, W), [0.0, 0.5, 0.21875], atol=1e-15)
    np.testing.assert_allclose(electrode_step_modulation(a, W), [0.75, 0.25, 0.875], atol=1e-14)
    assert row_step_modulation([0.0, W / 2], W).shape == (2,)
    assert isinstance(electrode_step_modulation(W / 2, W), float)


def test_electrode_branches_meet_and_wrap() -> None:
    # Continuous at a = 3w/4 and tending to M(0) = 0.75 as a -> w (the curve is periodic in a).
    below, above = np.nextafter(0.75 * W, 0.0), np.nextafter(0.75 * W, 1.0)
    m = electrode_step_modulation(np.array([below, above, np.nextafter(W, 0.0)]), W)
    np.testing.assert_allclose(m, 0.75, atol=1e-9)


@given(st.floats(min_value=0.0, max_value=1.0, exclude_max=True))
def test_closed_forms_stay_in_their_ranges(x: float) -> None:
    row = row_step_modulation(x * W, W)
    electrode = electrode_step_modulation(x * W, W)
    assert 0.0 <= row <= 0.5
    assert 0.0 <= electrode <= 0.875 + 1e-15
    # Row steps: symmetric about w/2 (mirror the beam's start about the pixel's middle).
    mirror = (1.0 - x) * W
    if x > 0.0 and mirror < W:  # a tiny x rounds 1 - x to 1: no offset mirrors it
        assert row == pytest.approx(row_step_modulation(mirror, W), abs=1e-12)


@pytest.mark.parametrize("function", [row_step_modulation, electrode_step_modulation])
@pytest.mark.parametrize("bad", [W, -1e-9, math.nan, math.inf, 2 * W])
def test_modulation_refuses_offsets_outside_the_pixel(function: ClosedForm, bad: float) -> None:
    with pytest.raises(ValueError, match=r"a_m must be finite and in \[0, pixel_m\)"):
        function(bad, W)
    with pytest.raises(ValueError, match="take the offset modulo the pixel"):
        function(np.array([0.0, bad]), W)


def test_modulation_refuses_bad_pixel_and_non_numbers() -> None:
    with pytest.raises(ValueError, match="pixel_m must be > 0"):
        row_step_modulation(0.0, 0.0)
    with pytest.raises(ValueError, match="a_m must be a number or an array of numbers"):
        electrode_step_modulation("half", W)
    with pytest.raises(ValueError, match="a_m must be a number or an array of numbers"):
        electrode_step_modulation(True, W)


def test_analytic_means_are_the_fractions() -> None:
    assert Fraction(1, 3) == MEAN_ROW_STEP_MODULATION
    assert Fraction(9, 64) + Fraction(9, 64) + Fraction(5, 24) == MEAN_ELECTRODE_STEP_MODULATION
    assert Fraction(47, 96) == MEAN_ELECTRODE_STEP_MODULATION
    assert mean_row_step_modulation() == 1 / 3
    assert mean_electrode_step_modulation() == 47 / 96


def test_analytic_means_against_quadrature_of_the_closed_forms() -> None:
    # Composite Simpson on a grid holding the breakpoints 3w/8 and 3w/4 (the pieces are
    # quadratics, so Simpson is exact on each up to rounding); the last node w itself lies
    # outside [0, w), so it takes the limit a -> w, which is M(0) for both forms.
    n = 9600  # even, and a multiple of 8 so that 3w/8 and 3w/4 are nodes
    a = np.arange(n) * (W / n)
    weights = np.ones(n + 1)
    weights[1:-1:2], weights[2:-1:2] = 4.0, 2.0
    for function, exact in [
        (row_step_modulation, 1 / 3),
        (electrode_step_modulation, 47 / 96),
    ]:
        m = np.append(function(a, W), function(0.0, W))
        assert float(weights @ m) / (3 * n) == pytest.approx(exact, abs=1e-12)


# -- the numeric charge-transfer model ------------------------------------------------------------


@pytest.mark.parametrize(("method", "closed_form"), CLOSED_FORMS)
def test_model_matches_the_closed_form(method: Method, closed_form: ClosedForm) -> None:
    # Two row times of exposure: the second cycle repeats the first, so nothing changes.
    m = point_beam_modulation(A_GRID, method=method, exposure_cycles=2, time_steps_per_cycle=STEPS)
    assert np.max(np.abs(m - closed_form(A_GRID, W))) < MODEL_TOL


def test_model_is_exact_where_the_time_grid_holds_every_kink() -> None:
    # a on a multiple of w/400 puts every beam-edge/electrode-edge crossing on a time-step
    # boundary: the midpoint rule is then exact. Hand values: electrode 3/4, 0, 7/8 and row 0, 1/2.
    a = np.array([0.0, 3 * W / 8, 7 * W / 8, W / 2])
    electrode = point_beam_modulation(a, method="electrode", time_steps_per_cycle=STEPS)
    row = point_beam_modulation(a, method="row", time_steps_per_cycle=STEPS)
    np.testing.assert_allclose(electrode, [0.75, 0.0, 0.875, 0.25], atol=1e-12)
    np.testing.assert_allclose(row, [0.0, 0.46875, 0.21875, 0.5], atol=1e-12)


def test_model_profile_splits_as_derived_by_hand() -> None:
    # Row steps, a = w/4, per row time (units of the beam's signal per row time, w = 1):
    # previous (1 - 1/4)^2/2 = 9/32, main 1/2 + 1/4 - 1/16 = 11/16, next (1/4)^2/2 = 1/32.
    profile = point_beam_profile(W / 4, method="row", exposure_cycles=3, time_steps_per_cycle=STEPS)
    np.testing.assert_allclose(profile[1:4] / 3, [9 / 32, 11 / 16, 1 / 32], atol=1e-12)
    # Electrode steps, a = 7w/8: first packet 2 (1/8)^2 = 1/32, third 2 (1/8)^2 = 1/32, main 15/16.
    profile = point_beam_profile(7 * W / 8, method="electrode", time_steps_per_cycle=STEPS)
    np.testing.assert_allclose(profile[1:4], [1 / 32, 15 / 16, 1 / 32], atol=1e-12)


def test_model_error_falls_as_the_square_of_the_time_step() -> None:
    a = A_GRID[::5]
    for method, closed_form in CLOSED_FORMS:
        coarse, fine = (
            np.max(
                np.abs(
                    point_beam_modulation(a, method=method, time_steps_per_cycle=n)
                    - closed_form(a, W)
                )
            )
            for n in (40, 400)
        )
        assert 50 < coarse / fine < 200  # 100 for second order


@pytest.mark.parametrize("method", ["none", "row", "electrode"])
@settings(max_examples=25, deadline=None)
@given(x=st.floats(0.0, 1.0, exclude_max=True), cycles=st.integers(1, 4))
def test_model_conserves_charge(method: Method, x: float, cycles: int) -> None:
    # The collection regions tile the column: every electron lands in some packet.
    profile = point_beam_profile(
        x * W, method=method, exposure_cycles=cycles, time_steps_per_cycle=16
    )
    assert profile.sum() == pytest.approx(cycles, rel=1e-12)
    assert np.all(profile >= 0.0)


def test_model_one_phase_electrode_steps_are_row_steps() -> None:
    a = A_GRID[::7]
    one_phase = point_beam_profile(a, phases=1, method="electrode", exposure_cycles=2)
    row = point_beam_profile(a, phases=1, method="row", exposure_cycles=2)
    np.testing.assert_allclose(one_phase, row, atol=1e-12)


def test_model_does_not_depend_on_scale() -> None:
    # The clocks follow v, so only a / w matters: REN15's rig vs 6.7 um pixels at 2 mm/s.
    x = (np.arange(50) + 0.3) / 50
    ren15 = point_beam_modulation(x * W, method="electrode")
    other = point_beam_modulation(x * 6.7e-6, pixel_m=6.7e-6, image_velocity_m_s=0.002)
    np.testing.assert_allclose(ren15, other, atol=1e-9)


def test_no_compensation_gives_lower_modulation() -> None:
    # Three row times without compensation smear the beam over four pixels: no packet holds
    # half the charge, so the modulation is negative, below both compensated curves everywhere.
    none, row, electrode = (
        point_beam_modulation(A_GRID, method=m, exposure_cycles=3, time_steps_per_cycle=STEPS)
        for m in ("none", "row", "electrode")
    )
    assert np.all(none < 0.0)
    assert np.all(none < row)
    assert np.all(none < electrode)
    # With one row time of exposure the first row step falls at its end: "none" is "row".
    np.testing.assert_allclose(
        point_beam_modulation(A_GRID, method="none", exposure_cycles=1),
        point_beam_modulation(A_GRID, method="row", exposure_cycles=1),
        atol=1e-12,
    )
    # Averages over a: none < row (1/3) < electrode (47/96), for every exposure longer than one.
    for cycles in (2, 4):
        means = [
            mean_point_beam_modulation(method=m, exposure_cycles=cycles, offsets=128)
            for m in ("none", "row", "electrode")
        ]
        assert means == sorted(means)
        assert means[0] < means[1] - 0.3


@pytest.mark.parametrize(
    ("method", "exact"),
    [("row", MEAN_ROW_STEP_MODULATION), ("electrode", MEAN_ELECTRODE_STEP_MODULATION)],
)
def test_model_mean_over_offsets_matches_the_analytic_fraction(
    method: Method, exact: Fraction
) -> None:
    # 512 offsets (midpoint rule, error ~ 6e-7) x 400 time steps (error ~ 1e-6): measured
    # 1.7e-6 for both (docs/imc.md).
    mean = mean_point_beam_modulation(method=method, offsets=512, time_steps_per_cycle=STEPS)
    assert mean == pytest.approx(float(exact), abs=1e-5)


def test_modulation_of_profiles() -> None:
    assert float(modulation([0.0, 1.0, 0.0])) == 1.0
    assert float(modulation([1.0, 1.0])) == 0.0
    assert float(modulation([1.0, 2.0, 1.0])) == 0.0
    np.testing.assert_allclose(modulation([[0.0, 3.0, 1.0], [1.0, 1.0, 1.0]]), [0.5, -1 / 3])


@pytest.mark.parametrize(
    ("profile", "message"),
    [
        ([0.0, 0.0], "profile holds no charge"),
        ([1.0, -0.5], "finite charges >= 0"),
        ([1.0, math.nan], "finite charges >= 0"),
        (5.0, "at least one pixel"),
    ],
)
def test_modulation_refusals(profile: Any, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        modulation(profile)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"method": "sideways"}, "method must be one of none, row, electrode"),
        ({"time_steps_per_cycle": 402}, r"must be a multiple of phases \(4\)"),
        ({"exposure_cycles": 0}, "exposure_cycles must be >= 1"),
        ({"phases": 0}, "phases must be >= 1"),
        ({"pixel_m": -9e-6}, "pixel_m must be > 0"),
        ({"image_velocity_m_s": math.nan}, "image_velocity_m_s must be finite"),
    ],
)
def test_model_refusals(kwargs: dict[str, Any], message: str) -> None:
    with pytest.raises(ValueError, match=message):
        point_beam_profile(W / 2, **kwargs)


def test_model_refuses_offsets_outside_the_pixel() -> None:
    with pytest.raises(ValueError, match="take the offset modulo the pixel"):
        point_beam_modulation(np.array([0.0, W]))
    with pytest.raises(ValueError, match="a_m must be a number or an array of numbers"):
        point_beam_profile("half")
    with pytest.raises(ValueError, match="a_m must be a number or an array of numbers"):
        point_beam_profile(False)


def test_model_profile_shape() -> None:
    assert point_beam_profile(W / 2, exposure_cycles=2).shape == (5,)
    assert point_beam_profile(np.full((3, 2), W / 2), exposure_cycles=1).shape == (3, 2, 4)
    assert point_beam_profile(np.array([]), exposure_cycles=1).shape == (0, 4)
    # The spare packet -1 stays empty; without compensation the beam reaches the last packet.
    profile = point_beam_profile(A_GRID, method="none", exposure_cycles=2, time_steps_per_cycle=8)
    assert np.all(profile[:, 0] == 0.0)
    assert np.any(profile[:, -1] > 0.0)
