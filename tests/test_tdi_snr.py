"""The SNR-versus-stages models of docs/physics.md §5 and the scan SNR measurements."""

from __future__ import annotations

import math

import numpy as np
import pytest

from camd.analysis.tdi_snr import (
    QUANTISATION_SIGMA_DN,
    along_track_snr,
    db,
    periodic_snr,
    snr_gain_sqrt_m,
    snr_gain_tao12,
)


def test_tao12_gain_is_eq28_as_a_linear_ratio() -> None:
    # docs/physics.md §5 table, fig 6a: sigma_AD = 0.03104, sigma_CMOS = 1.42471, M = 10:
    # 10 * 1.45575 / (0.3104 + sqrt(10) * 1.42471) = 14.5575 / 4.815... = 3.0230
    gain = snr_gain_tao12(10, 0.03104, 1.42471)
    assert gain == pytest.approx(14.5575 / (0.3104 + math.sqrt(10) * 1.42471), rel=1e-12)
    assert gain == pytest.approx(3.0230, abs=5e-4)
    assert snr_gain_tao12(1, 0.5, 2.0) == 1.0
    # Quantisation alone adds linearly: no gain at all; sensor noise alone: sqrt(M).
    assert snr_gain_tao12(16, 1.0, 0.0) == pytest.approx(1.0)
    assert snr_gain_tao12(16, 0.0, 1.0) == pytest.approx(4.0)
    assert db(snr_gain_sqrt_m(100)) == pytest.approx(20.0)
    assert math.isclose(QUANTISATION_SIGMA_DN, 0.288675, abs_tol=1e-6)


def test_models_refuse_bad_inputs() -> None:
    with pytest.raises(ValueError, match="stages must be >= 1"):
        snr_gain_sqrt_m(0)
    with pytest.raises(ValueError, match="not both 0"):
        snr_gain_tao12(4, 0.0, 0.0)


def test_along_track_snr_measures_temporal_noise_under_fixed_pattern() -> None:
    rng = np.random.default_rng(1)
    pattern = 1000.0 + 50.0 * rng.standard_normal(500)  # per column, constant along track
    lines = pattern + 4.0 * rng.standard_normal((4000, 500)) + 100.0
    m = along_track_snr(lines, black_dn=100.0)
    assert m.noise_dn == pytest.approx(4.0, rel=0.01)
    assert m.signal_dn == pytest.approx(pattern.mean(), rel=1e-3)
    assert m.snr == pytest.approx(pattern.mean() / 4.0, rel=0.01)
    with pytest.raises(ValueError, match="lines >= 2"):
        along_track_snr(lines[:1], black_dn=0.0)


def test_periodic_snr_separates_a_repeating_scene_from_noise() -> None:
    rng = np.random.default_rng(2)
    period, n = 40, 64
    scene = np.where((np.arange(period)[:, None] // 10) % 2 == 0, 800.0, 200.0) * np.ones(n)
    index = np.sort(rng.choice(4000, size=2000, replace=False))  # lines with gaps
    lines = scene[index % period] + 3.0 * rng.standard_normal((index.size, n)) + 50.0
    m = periodic_snr(lines, index, period=period, black_dn=50.0, bright_fraction=0.5)
    assert m.signal_dn == pytest.approx(800.0, abs=0.5)
    assert m.noise_dn == pytest.approx(3.0, rel=0.02)
    with pytest.raises(ValueError, match="two lines"):
        periodic_snr(lines[:5], np.arange(5), period=period, black_dn=0.0)


def test_of_coinciding_model_curves_the_first_is_best() -> None:
    """tdi_snr_model's summary: quadrature is sqrt(M) when one conversion's noise is negligible,
    so their RMS against the measurement differ in the last bits of a float; which one is
    "best" then followed the rounding (one noise realisation in six said sqrt_m). The first
    listed of models equal to 1e-9 dB is best, however the rounding falls."""
    from camd.campaign.measurements.tdi import snr_model_summary

    measured = [[18.0, 21.0, 22.8], [24.3, 27.3, 29.1]]
    sqrt_m = [[18.0, 21.01, 22.77], [24.3, 27.31, 29.08]]
    for nudge in (-1e-14, 0.0, 1e-14):
        quadrature = [[x + nudge for x in row] for row in sqrt_m]
        r = snr_model_summary(
            {},
            stages=[1, 2, 3],
            measured_db=measured,
            tao12_db=[[x - 1.0 for x in row] for row in sqrt_m],
            sqrt_m_db=sqrt_m,
            quadrature_db=quadrature,
        )
        assert r["best_model"] == "sqrt_m", nudge
        assert r["best_rms_db"] == pytest.approx(r["overall_rms_db"]["quadrature"], abs=1e-12)
    # A real difference still decides.
    closer = [[18.0, 21.0, 22.8], [24.3, 27.3, 29.1]]
    r = snr_model_summary(
        {}, stages=[1, 2, 3], measured_db=measured, tao12_db=sqrt_m, sqrt_m_db=sqrt_m,
        quadrature_db=closer,
    )  # fmt: skip
    assert r["best_model"] == "quadrature"
