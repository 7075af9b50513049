"""camd.analysis.polarization: the sinusoid fit of docs/physics.md §4 on exact, noisy and wrapped data."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from camd.analysis.polarization import PolarizationFit, azimuth_spread_deg, fit_polarization

SCAN_DEG = np.arange(0.0, 360.0 + 1e-9, 15.0)  # the reference polariser, 0 .. 360 in 15 deg steps


def axial_difference(a: float, b: float) -> float:
    """a - b folded into [-90, 90)."""
    return (a - b + 90.0) % 180.0 - 90.0


def sinusoid(theta_deg: np.ndarray, a: float, b: float, phi_deg: float) -> np.ndarray:
    result: np.ndarray = a + b * np.cos(2.0 * np.deg2rad(theta_deg - phi_deg))
    return result


@pytest.mark.parametrize("phi", [0.0, 12.5, 60.0, 89.999, 90.0, 120.0, 179.5])
def test_exact_sinusoid_recovers_the_parameters(phi: float) -> None:
    fit = fit_polarization(SCAN_DEG, sinusoid(SCAN_DEG, 100.0, 40.0, phi))
    assert isinstance(fit, PolarizationFit)
    assert axial_difference(fit.azimuth_deg, phi) == pytest.approx(0.0, abs=1e-9)
    assert 0.0 <= fit.azimuth_deg < 180.0
    assert fit.offset == pytest.approx(100.0, rel=1e-12)
    assert fit.amplitude == pytest.approx(40.0, rel=1e-12)
    assert fit.residual_rms < 1e-9
    assert fit.points == 25


@given(
    phi=st.floats(min_value=-720.0, max_value=720.0),
    a=st.floats(min_value=1.0, max_value=1e4),
    ratio=st.floats(min_value=1e-3, max_value=1.0),
)
def test_exact_sinusoid_any_azimuth(phi: float, a: float, ratio: float) -> None:
    fit = fit_polarization(SCAN_DEG, sinusoid(SCAN_DEG, a, a * ratio, phi))
    assert abs(axial_difference(fit.azimuth_deg, phi)) < 1e-9
    assert 0.0 <= fit.azimuth_deg < 180.0


def test_negative_amplitude_is_a_quarter_turn() -> None:
    # a - b cos 2(theta - 10) = a + b cos 2(theta - 100)
    fit = fit_polarization(SCAN_DEG, sinusoid(SCAN_DEG, 5.0, -2.0, 10.0))
    assert fit.amplitude == pytest.approx(2.0)
    assert fit.azimuth_deg == pytest.approx(100.0, abs=1e-9)


@pytest.mark.parametrize("phi", [0.0, 179.9, 0.1])
def test_azimuth_near_the_wrap(phi: float) -> None:
    fit = fit_polarization(SCAN_DEG, sinusoid(SCAN_DEG, 1.0, 0.5, phi))
    assert abs(axial_difference(fit.azimuth_deg, phi)) < 1e-9
    assert 0.0 <= fit.azimuth_deg < 180.0


def test_noisy_scan_within_the_standard_error() -> None:
    """Seeded noise: the fit's standard error is right on average and the misses are normal."""
    rng = np.random.default_rng(20230476)
    a, b, phi, sigma = 1000.0, 300.0, 37.0, 10.0
    # The analytic error for 24 equally spaced angles over a half-turn-periodic sinusoid:
    # var(c) = var(s) = sigma^2 / (N / 2) with N = 25 points (24 distinct + the repeat of 0),
    # so sigma_phi = sigma / (b sqrt(2 N)) rad ~ (10 / (300 x 7.07)) rad = 0.27 deg.
    expected = math.degrees(sigma / (b * math.sqrt(2.0 * 25)))
    misses = []
    errors = []
    for _ in range(400):
        data = sinusoid(SCAN_DEG, a, b, phi) + rng.normal(0.0, sigma, SCAN_DEG.size)
        fit = fit_polarization(SCAN_DEG, data)
        misses.append(axial_difference(fit.azimuth_deg, phi) / fit.azimuth_error_deg)
        errors.append(fit.azimuth_error_deg)
        assert abs(axial_difference(fit.azimuth_deg, phi)) < 5.0 * fit.azimuth_error_deg
        assert fit.residual_rms == pytest.approx(sigma, rel=0.5)
    assert float(np.mean(errors)) == pytest.approx(expected, rel=0.1)
    assert float(np.std(misses)) == pytest.approx(1.0, abs=0.15)


def test_three_points_fit_exactly_without_an_error_estimate() -> None:
    theta = np.array([0.0, 60.0, 120.0])
    fit = fit_polarization(theta, sinusoid(theta, 2.0, 1.0, 33.0))
    assert fit.azimuth_deg == pytest.approx(33.0, abs=1e-9)
    assert math.isnan(fit.azimuth_error_deg)


def test_flat_data_has_no_azimuth() -> None:
    # A non-polarising channel: no modulation, so the azimuth is noise and its error says so.
    fit = fit_polarization(SCAN_DEG, np.full(SCAN_DEG.size, 7.0))
    assert fit.amplitude < 1e-12
    assert fit.offset == pytest.approx(7.0, rel=1e-12)
    assert fit.azimuth_error_deg > 10.0
    dark = fit_polarization(SCAN_DEG, np.zeros(SCAN_DEG.size))
    assert dark.amplitude == 0.0
    assert dark.azimuth_error_deg == math.inf


def test_refuses_fewer_than_three_distinct_angles_modulo_180() -> None:
    # 0, 180, 360 and 90, 270 are two polariser positions only
    with pytest.raises(
        ValueError, match=r"at least 3 distinct reference angles modulo 180 deg, got 2"
    ):
        fit_polarization([0.0, 90.0, 180.0, 270.0, 360.0], [1.0, 0.0, 1.0, 0.0, 1.0])
    with pytest.raises(ValueError, match="got 2 among 3 angles"):
        fit_polarization([10.0, 190.0 - 1e-12, 50.0], [1.0, 1.0, 0.5])


@pytest.mark.parametrize(
    ("theta", "intensity", "match"),
    [
        ([0.0, 45.0, 90.0], [1.0, math.nan, 0.0], r"intensity must be finite: 1 value\(s\)"),
        ([0.0, math.inf, 90.0], [1.0, 0.5, 0.0], "theta_deg must be finite"),
        ([0.0, 45.0, 90.0], [1.0, 0.5], "same length, got 3 angles and 2 intensities"),
        ([[0.0, 45.0, 90.0]], [[1.0, 0.5, 0.0]], "one-dimensional"),
        (["a", "b", "c"], [1.0, 0.5, 0.0], "real numbers"),
    ],
)
def test_refuses_bad_input(theta: object, intensity: object, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        fit_polarization(theta, intensity)  # type: ignore[arg-type]


def test_azimuth_spread_across_the_wrap() -> None:
    assert azimuth_spread_deg([179.0, 1.0]) == pytest.approx(2.0)
    assert azimuth_spread_deg([178.5, 0.5, 1.5, 179.5]) == pytest.approx(3.0)
    assert azimuth_spread_deg([10.0, 12.0, 11.0]) == pytest.approx(2.0)
    assert azimuth_spread_deg([-1.0, 361.0]) == pytest.approx(2.0)  # -1 = 179, 361 = 1
    assert azimuth_spread_deg([42.0]) == 0.0
    assert azimuth_spread_deg([90.0, 90.0]) == 0.0


@given(
    centre=st.floats(min_value=-360.0, max_value=360.0),
    offsets=st.lists(st.floats(min_value=-40.0, max_value=40.0), min_size=1, max_size=8),
)
def test_azimuth_spread_is_max_minus_min_around_the_circular_mean(
    centre: float, offsets: list[float]
) -> None:
    values = [(centre + o) % 180.0 for o in offsets]
    assert azimuth_spread_deg(values) == pytest.approx(max(offsets) - min(offsets), abs=1e-9)


def test_azimuth_spread_refuses_empty_and_non_finite() -> None:
    with pytest.raises(ValueError, match="at least one azimuth"):
        azimuth_spread_deg([])
    with pytest.raises(ValueError, match="values must be finite"):
        azimuth_spread_deg([1.0, math.nan])
