"""Limiting resolution by Rose's criterion and the velocity-mismatch MTF of a rolling-shutter
TDI scan (docs/physics.md §6, YUAN13 §4; camd.analysis.mtf, docs/mtf.md).

Synthetic data whose answer is known: bar targets built from exact pixel integrals of square
bars plus Gaussian noise of a known sigma (so Rose's d, and the limit, follow by hand), edges
rendered exactly (tests.test_mtf.render_edge) or by the simulator's exact scene integral with a
known motion smear, and the complete MTF model against closed forms worked out here.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
import pytest

from camd.analysis.mtf import (
    ROSE_THRESHOLD,
    USAF_BAR_ASPECT,
    bar_detectability,
    bar_target_resolution,
    combined_edge_mtf,
    find_edge_regions,
    limiting_frequency,
    lp_per_mm_on_target,
    mtf_detector,
    mtf_rolling_tdi_model,
    mtf_tdi_model,
    pixel_noise_dn,
    slanted_edge_mtf,
)
from firmware_models.scene import build_scene
from firmware_models.scene_spec import SceneSpec
from tests.test_mtf import render_edge

FloatArray = npt.NDArray[np.float64]
GROUPS = [0.05, 0.1, 0.2, 0.25, 0.3, 0.4, 0.5]  # the simulator's bar groups, cycles per pixel
BAND = 32  # lines per group band (the simulator's `bars` scene, orientation=across)


def sinc(x: float) -> float:
    return 1.0 if x == 0 else math.sin(math.pi * x) / (math.pi * x)


# -- Rose's criterion ----------------------------------------------------------------------------


def test_bar_detectability_is_rose_snr_over_a_usaf_bar() -> None:
    # d = delta sqrt(A) / sigma, A = 5 w^2, w = 1 / (2 f): at 0.25 cy/px w = 2 px, A = 20.
    assert bar_detectability(2.0, 1.0, 0.25) == pytest.approx(2.0 * math.sqrt(20.0), rel=1e-12)
    # At Nyquist a bar is one pixel wide: A = 5; a square bar (aspect 1) of it: A = 1.
    assert bar_detectability(3.0, 1.5, 0.5) == pytest.approx(2.0 * math.sqrt(5.0), rel=1e-12)
    assert bar_detectability(3.0, 1.5, 0.5, bar_aspect=1.0) == pytest.approx(2.0)
    assert ROSE_THRESHOLD == 5.0 and USAF_BAR_ASPECT == 5.0
    with pytest.raises(ValueError, match=r"frequency_cy_per_px must be in \(0, 0.5\]"):
        bar_detectability(1.0, 1.0, 0.6)
    with pytest.raises(ValueError, match="noise_dn must be > 0"):
        bar_detectability(1.0, 0.0, 0.25)


def test_limiting_frequency_reads_up_from_the_coarsest_group() -> None:
    d = [40.0, 20.0, 9.0, 6.0, 4.9, 7.0, 2.0]
    # 0.3 fails (4.9 < 5): 0.4 resolved above it does not count.
    assert limiting_frequency(GROUPS, d) == 0.25
    assert limiting_frequency(GROUPS, d, threshold=4.0) == 0.4
    assert limiting_frequency(GROUPS[::-1], d[::-1]) == 0.25  # order of the lists is free
    assert limiting_frequency(GROUPS, [4.0] * 7) == 0.0  # not even the coarsest
    assert limiting_frequency(GROUPS, [9.0, float("nan"), 9, 9, 9, 9, 9]) == 0.05
    with pytest.raises(ValueError, match="1-D of one length"):
        limiting_frequency(GROUPS, [1.0])


def test_line_pairs_per_mm_on_the_target() -> None:
    # MT9M001 5.2 um pixels through a 1:10 objective: 52 um on the target, so Nyquist
    # (0.5 cycles per pixel) is 0.5 / 0.052 mm = 9.615 lp/mm.
    assert lp_per_mm_on_target(0.5, pitch_m=5.2e-6, magnification=0.1) == pytest.approx(
        9.615384615, rel=1e-9
    )
    with pytest.raises(ValueError, match="magnification > 0"):
        lp_per_mm_on_target(0.5, pitch_m=5.2e-6, magnification=0.0)


def _bright_fraction(lo: FloatArray, hi: FloatArray, period: float) -> FloatArray:
    """Exact fraction of [lo, hi) in the bright half [0, period/2) mod period."""

    def up_to(u: FloatArray) -> FloatArray:
        whole = np.floor(u / period)
        result: FloatArray = whole * period / 2 + np.clip(u - whole * period, 0.0, period / 2)
        return result

    result: FloatArray = (up_to(hi) - up_to(lo)) / (hi - lo)
    return result


def bar_target(
    lines: int, cols: int, *, offset: int, dark: float, bright: float, sigma: float, seed: int
) -> FloatArray:
    """Bars varying across (axis 1), groups in bands of 32 lines along axis 0 in the order of
    GROUPS, the image starting ``offset`` lines into the pattern; each pixel the exact
    integral of square bars over its width, plus Gaussian noise."""
    x = np.arange(cols, dtype=np.float64)
    profiles = [dark + (bright - dark) * _bright_fraction(x, x + 1, 1 / f) for f in GROUPS]
    period = len(GROUPS) * BAND
    image = np.array([profiles[((line + offset) % period) // BAND] for line in range(lines)])
    noisy: FloatArray = image + np.random.default_rng(seed).normal(0.0, sigma, image.shape)
    return noisy


# The bars' bright-minus-dark level as the pixels see it: 1 for bars of whole pixels or
# aligned with them (0.05, 0.1, 0.25, 0.5) and where a pixel still falls wholly inside each
# bar (0.2: 2.5-px bars, 0.3: 1.67-px bars); at 0.4 (1.25-px bars) the pixels of a bar pair
# read 1, 0.25, 0.5 or 0.5, 0.75, 0: 0.75.
DELTA = [1.0, 1.0, 1.0, 1.0, 1.0, 0.75, 1.0]


@pytest.mark.parametrize(("sigma", "limit"), [(0.3, 0.5), (0.6, 0.3), (2.0, 0.1)])
@pytest.mark.parametrize("offset", [0, 37])
def test_bar_target_resolution_on_synthetic_bars(sigma: float, limit: float, offset: int) -> None:
    image = bar_target(448, 640, offset=offset, dark=10.0, bright=11.0, sigma=sigma, seed=3)
    result = bar_target_resolution(image, GROUPS, band_lines=BAND)
    assert result.band_offset_lines == offset
    # Known d = DELTA sqrt(5) / (2 f) / sigma: sigma 0.3 resolves every group (0.4: 6.99),
    # 0.6 up to 0.3 (6.21; 0.4: 3.49), 2.0 up to 0.1 (5.59; 0.2: 2.80).
    assert result.limit_cy_per_px == limit
    for group, f, delta in zip(result.groups, GROUPS, DELTA, strict=True):
        assert group.frequency_cy_per_px == f
        assert group.noise_dn == pytest.approx(sigma, rel=0.03)  # about 26 k samples
        expected = delta * math.sqrt(5.0) / (2 * f) / sigma
        # The levels come from a profile folded over its pixel-phase cycle: its noise is
        # sigma / sqrt(lines x cols / cycle), which biases the maxima and minima upwards by
        # about 1.5 times that where a bar spans many pixels (0.05: +15 % at sigma 2).
        tolerance = 0.05 + 2.5 * sigma / math.sqrt(52 * 640 / (2 / f)) / delta
        assert group.delta_dn == pytest.approx(delta, rel=tolerance), f
        assert group.detectability == pytest.approx(expected, rel=tolerance + 0.03), f
        assert 48 <= group.lines <= 56  # 2 bands of 32 lines, 3 dropped at each end


def test_bar_target_resolution_refusals() -> None:
    image = bar_target(448, 640, offset=0, dark=10.0, bright=11.0, sigma=0.3, seed=1)
    with pytest.raises(ValueError, match="take at least 224"):
        bar_target_resolution(image[:200], GROUPS, band_lines=BAND)
    with pytest.raises(ValueError, match="fewer than 2 lines per band"):
        bar_target_resolution(image, GROUPS, band_lines=BAND, margin_lines=16)
    with pytest.raises(ValueError, match=r"outside \(0, 0.5\]"):
        bar_target_resolution(image, [*GROUPS[:-1], 0.6], band_lines=BAND)


# -- the complete velocity-mismatch model ----------------------------------------------------------


def test_rolling_tdi_model_against_closed_forms() -> None:
    q, r = math.sqrt(0.5), 8 / 9

    def model(
        *,
        stages: int = 8,
        dv_over_v: float = 0.0,
        fill_width: float = 1.0,
        integration_ratio: float = 0.0,
        row_skew: float = 0.0,
        cell_px: float = 0.0,
    ) -> float:
        return mtf_rolling_tdi_model(
            0.5,
            stages=stages,
            dv_over_v=dv_over_v,
            fill_width=fill_width,
            integration_ratio=integration_ratio,
            row_skew=row_skew,
            cell_px=cell_px,
        )

    # Synchronous, global shutter: eq 3 exactly, sinc(q/2) sinc(r/2) = 0.8066 x 0.7053.
    assert model(fill_width=q, integration_ratio=r) == pytest.approx(
        sinc(q / 2) * sinc(r / 2), rel=1e-12
    )
    assert model(fill_width=q, integration_ratio=r) == pytest.approx(
        mtf_detector(0.5, fill_width=q, integration_ratio=r), rel=1e-12
    )
    # 8 stages slipping 1/8 row each: |sin(pi 8 x) / (8 sin(pi x))| at x = 1/16 is
    # 1 / (8 sin(pi/16)) = 0.64072, times the pixel's 2/pi (eq 8's sinc(1/2) = 0.63662).
    assert model(dv_over_v=0.125) == pytest.approx(
        (2 / math.pi) / (8 * math.sin(math.pi / 16)), rel=1e-12
    )
    # The rolling shutter alone: each stage read T_row/T_L later slips that much:
    # 108-row line period, x = 0.5/108.
    x = 0.5 / 108
    rolling = math.sin(math.pi * 8 * x) / (8 * math.sin(math.pi * x))
    assert model(row_skew=1 / 108) == pytest.approx((2 / math.pi) * rolling, rel=1e-12)
    assert rolling == pytest.approx(0.99778, abs=1e-5)
    # Both: the slip is 1 - (1 - dV/V)(1 - T_row/T_L) = 0.125 + 0.875/108 per stage.
    s = 1 - 0.875 * (1 - 1 / 108)
    both = math.sin(math.pi * 8 * s / 2) / (8 * math.sin(math.pi * s / 2))
    assert model(dv_over_v=0.125, row_skew=1 / 108) == pytest.approx(
        (2 / math.pi) * both, rel=1e-12
    )
    # The exposure smear at the image's actual speed: (1 - dV/V) T_int/T_L rows.
    assert model(stages=1, dv_over_v=0.5, integration_ratio=1.0) == pytest.approx(
        (2 / math.pi) * sinc(0.25), rel=1e-12
    )
    # The scene's cells: sinc(f c)^2.
    assert model(cell_px=0.25) == pytest.approx((2 / math.pi) * sinc(0.125) ** 2, rel=1e-12)
    # M dV/V = 10 at M = 8 either way round: 8 x 1.25 / 2 = 5 whole cycles, zero.
    assert model(dv_over_v=1.25) < 1e-12 and model(dv_over_v=-1.25) < 1e-12


def test_rolling_tdi_model_tends_to_eq_8() -> None:
    # Many stages with a small slip each: the M samples fill eq 8's rectangle.
    for m_dv in (0.5, 1.0, 1.5, 2.0):
        exact = mtf_rolling_tdi_model(
            0.5, stages=96, dv_over_v=m_dv / 96, fill_width=1.0, integration_ratio=0.0
        )
        sec6 = mtf_tdi_model(
            0.5, stages=96, dv_over_v=m_dv / 96, fill_width=1.0, integration_ratio=0.0
        )
        assert exact == pytest.approx(sec6, abs=2e-4)
    curve = mtf_rolling_tdi_model(
        np.linspace(0, 1, 11), stages=8, dv_over_v=0.1, fill_width=0.7, integration_ratio=0.9
    )
    assert curve.shape == (11,) and curve[0] == 1.0
    with pytest.raises(ValueError, match="row_skew must be in"):
        mtf_rolling_tdi_model(
            0.5, stages=8, dv_over_v=0, fill_width=1, integration_ratio=0, row_skew=2
        )
    with pytest.raises(ValueError, match="cell_px must be in"):
        mtf_rolling_tdi_model(
            0.5, stages=8, dv_over_v=0, fill_width=1, integration_ratio=0, cell_px=-1
        )


def test_rolling_tdi_model_sees_an_across_slip_along_a_slanted_edges_normal() -> None:
    # M = 96 at the synchronous speed of a 97-row window: the rolling shutter's 96/97 pixel of
    # slip; the image drifting tan(0.3 deg) columns a stage seen by edges at 4.7 deg to the
    # rows adds 96 tan(0.3 deg) tan(4.7 deg) = 0.0412 pixel inside the Dirichlet kernel.
    c, t = math.tan(math.radians(0.3)), math.tan(math.radians(4.7))
    slip = 1 / 97 + c * t
    kernel = abs(math.sin(math.pi * 0.5 * 96 * slip) / (96 * math.sin(math.pi * 0.5 * slip)))
    model = mtf_rolling_tdi_model(
        0.5, stages=96, dv_over_v=0, fill_width=1.0, integration_ratio=0.0, row_skew=1 / 97,
        across_slip_px=c, edge_tan=t,
    )  # fmt: skip
    assert model == pytest.approx(sinc(0.5) * kernel, rel=1e-12)
    along = mtf_rolling_tdi_model(
        0.5, stages=96, dv_over_v=0, fill_width=1.0, integration_ratio=0.0, row_skew=1 / 97
    )
    assert model / along == pytest.approx(0.959, abs=0.001)  # 4 % at 0.99 pixel of slip
    # An edge along the rows (tan 0) sees none of it.
    assert mtf_rolling_tdi_model(
        0.5, stages=96, dv_over_v=0, fill_width=1.0, integration_ratio=0.0, row_skew=1 / 97,
        across_slip_px=c,
    ) == along  # fmt: skip


# -- several edges at once -----------------------------------------------------------------------


def test_combined_edge_mtf_of_identical_edges_is_the_edges() -> None:
    result = slanted_edge_mtf(render_edge((40, 64), 5.0, 20.3), axis="along")
    combined = combined_edge_mtf([result, result, result])
    cos = math.cos(math.radians(result.edge_angle_deg))
    n = result.frequencies_cy_per_px.size
    assert combined.edges == 3
    assert np.allclose(combined.frequencies_cy_per_px[:n], result.frequencies_cy_per_px * cos)
    assert np.allclose(combined.mtf[:n], result.mtf, atol=1e-12)
    assert np.allclose(combined.mtf_std_error, 0.0, atol=1e-12)
    # Lines 2.25 pixels apart on the focal plane: the frequencies per pixel scale down, and
    # the curve reaches past 1 cycle per line (1.2 at 4x oversampling).
    coarse = combined_edge_mtf([result], line_pitch_px=2.25)
    assert 1.15 * cos / 2.25 < coarse.frequencies_cy_per_px[-1] <= 1.2 * cos / 2.25
    assert coarse.mtf_at(0.25) == pytest.approx(result.mtf_at(0.25 * 2.25 / cos), abs=1e-9)
    assert math.isnan(coarse.std_error_at(0.25))
    with pytest.raises(ValueError, match="at least one edge"):
        combined_edge_mtf([])


def test_combined_edge_mtf_keeps_noise_out_of_a_small_mtf() -> None:
    # An edge smeared by 2 rows along track (M dV/V = 2): its MTF at Nyquist is
    # |sinc(2 cos a / 2)| x the pixel's, 0.002 at 5 deg. 40 edges with noise of 3 % of the
    # step: each edge's own MTF carries the noise's power (its mean is biased upwards); the
    # mean LSF does not, and its jackknife error covers what is left.
    a = math.radians(5.0)
    true = abs(sinc(math.cos(a)) * sinc(0.5 * math.cos(a)) * sinc(0.5 * math.sin(a)))
    rng = np.random.default_rng(7)
    clean = render_edge((40, 128), 5.0, 20.3, smear=2.0, lo=100.0, hi=1100.0)
    results = [
        slanted_edge_mtf(clean + rng.normal(0.0, 30.0, clean.shape), axis="along")
        for _ in range(40)
    ]
    each = float(np.mean([r.mtf_nyquist for r in results]))
    combined = combined_edge_mtf(results)
    assert true == pytest.approx(0.0024, abs=1e-4)
    assert each > true + 0.02
    assert combined.mtf_at(0.5) == pytest.approx(true, abs=3 * combined.std_error_at(0.5) + 0.005)
    assert combined.std_error_at(0.5) < 0.01


def _smeared_scene(smear_rows: float) -> FloatArray:
    """The simulator's edge scene (fine cells), 384 rows x 256 columns, integrated exactly
    over a full-fill pixel moving ``smear_rows`` rows during the exposure (a box LSF)."""
    spec = SceneSpec.parse("edge:photons=1000,angle_deg=5,oversample=16,period=128")
    scene = build_scene(spec, columns=256, pitch_m=5.2e-6, default_photons=1e3)
    image = scene.integrate(0, 384, 256, 0.0, smear_rows, None, 1.0, 1.0, dtype=np.float64)
    return np.asarray(image, dtype=np.float64)


def test_edge_regions_of_a_smeared_target() -> None:
    # A smear of 12 rows (M dV/V = 12) gives each edge's derivative a flat top 12 rows wide
    # (before the runs were merged, its noise-free ripples were taken for several edges and
    # no region was left): one region per edge, the ESF reaching its levels inside it, and
    # the measured MTF the box's, |sinc(f 12)| x the pixel's sinc(f) sinc(f tan a) at
    # 0.125 cycles per pixel along track (sinc(1.5) = 0.212).
    image = _smeared_scene(12.0)
    regions = find_edge_regions(image, axis="along")
    positions = sorted({round(r.position_px) for r in regions})
    # An edge every 64 rows (period 128), once each; the one nearest the top (at 8 - 3
    # rows, the smear moving it) has no room above it for half the spacing.
    assert len(positions) == 5 and set(np.diff(positions)) == {64}
    results = [slanted_edge_mtf(image[r.slices], axis="along") for r in regions]
    combined = combined_edge_mtf(results)
    f, a = 0.125, math.radians(5.0)
    box = abs(sinc(f * 12)) * sinc(f) * sinc(f * math.tan(a))
    assert box == pytest.approx(0.2068, abs=1e-4)
    assert combined.mtf_at(f) == pytest.approx(box, abs=0.01)


def test_pixel_noise_of_an_image_of_edges() -> None:
    # Whole-DN data with 1.7 DN of noise: sqrt(1.7^2 + 1/12) = 1.724 DN; the edges (steps of
    # 1000 DN) are left out of the differences.
    rng = np.random.default_rng(2)
    image = np.round(_smeared_scene(0.0) * 1000 + rng.normal(100.0, 1.7, (384, 256)))
    assert pixel_noise_dn(image, axis="across") == pytest.approx(1.724, rel=0.03)
    assert pixel_noise_dn(image, axis="along") == pytest.approx(1.724, rel=0.1)
