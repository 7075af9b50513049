"""MTF models of docs/physics.md §6 and the slanted-edge and bar-target measurements.

The models are checked against hand-computed values. The slanted-edge measurement is checked
on edges rendered exactly (each pixel the exact integral of the edge over its area), blurred
analytically by a Gaussian or a motion box, whose MTF along the edge normal is known in
closed form. For a pixel (a unit square) and an edge slanted by ``a``, the normal frequency
``f`` meets the pixel's ``sinc(fx) sinc(fy)`` at ``fy = f cos a``, ``fx = f sin a``.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable

import numpy as np
import numpy.typing as npt
import pytest
from hypothesis import given
from hypothesis import strategies as st

from camd.analysis.mtf import (
    SQUARE_WAVE_FUNDAMENTAL,
    bar_modulation,
    edge_width_10_90_px,
    find_edge_regions,
    mtf_detector,
    mtf_from_bars,
    mtf_tdi_model,
    mtf_velocity_mismatch,
    sinc,
    sine_mtf_from_ctf,
    slanted_edge_mtf,
    tdi_integration_ratio,
)
from firmware_models.scene import build_scene
from firmware_models.scene_spec import SceneSpec

FloatArray = npt.NDArray[np.float64]
TWO_OVER_PI = 2.0 / math.pi  # sinc(0.5) = sin(pi/2) / (pi/2)

# -- exact edges ------------------------------------------------------------------------------------

_erf = np.frompyfunc(math.erf, 1, 1)


def _normal_cdf(u: FloatArray) -> FloatArray:
    return 0.5 * (1.0 + np.asarray(_erf(u / math.sqrt(2.0)), dtype=np.float64))


def render_edge(
    shape: tuple[int, int],
    angle_deg: float,
    y0: float,
    *,
    sigma: float = 0.0,
    smear: float = 0.0,
    lo: float = 0.0,
    hi: float = 1.0,
    nsub: int = 64,
) -> FloatArray:
    """An edge across track, bright where ``y < y0 + x tan(angle)`` (rows y, columns x).

    Pixel ``(r, c)`` spans ``[r, r+1) x [c, c+1)`` and holds the integral of the (blurred)
    edge over it. With ``v = y_edge(x) - y`` the edge profile ``E(v)`` is integrated over the
    pixel's rows exactly by its antiderivative ``P``: ``P(y_edge - r) - P(y_edge - r - 1)``.
    Ideal edge: ``P = max(v, 0)``, and its integral over the columns is also exact.
    Gaussian blur (isotropic, ``sigma`` px): ``E = Phi(v cos a / sigma)``. Motion smear
    (``smear`` px along the rows): ``E = clip((v + L/2) / L, 0, 1)``. The blurred ones are
    integrated over the columns by the midpoint rule on ``nsub`` points.
    """
    rows, cols = shape
    t = math.tan(math.radians(angle_deg))
    r = np.arange(rows, dtype=np.float64)[:, None]
    if sigma == 0.0 and smear == 0.0:
        c = np.arange(cols, dtype=np.float64)[None, :]

        def ramp2(u: FloatArray) -> FloatArray:  # antiderivative of max(u, 0)
            return np.maximum(u, 0.0) ** 2 / 2.0

        a = y0 - r
        exact = (
            ramp2(a + (c + 1) * t)
            - ramp2(a + c * t)
            - ramp2(a - 1 + (c + 1) * t)
            + ramp2(a - 1 + c * t)
        ) / t
        return lo + (hi - lo) * exact
    xs = (np.arange(cols * nsub, dtype=np.float64) + 0.5) / nsub
    y_edge = y0 + xs[None, :] * t
    antiderivative: Callable[[FloatArray], FloatArray]
    if sigma > 0.0:
        cos = math.cos(math.radians(angle_deg))

        def antiderivative(v: FloatArray) -> FloatArray:
            u = v * cos
            pdf = np.exp(-0.5 * (u / sigma) ** 2) / math.sqrt(2.0 * math.pi)
            return (u * _normal_cdf(u / sigma) + sigma * pdf) / cos

    else:

        def antiderivative(v: FloatArray) -> FloatArray:
            w = (v + smear / 2.0) / smear
            return smear * np.where(w < 0.0, 0.0, np.where(w > 1.0, w - 0.5, w * w / 2.0))

    sub = antiderivative(y_edge - r) - antiderivative(y_edge - r - 1.0)
    values: FloatArray = lo + (hi - lo) * sub.reshape(rows, cols, nsub).mean(axis=2)
    return values


def pixel_mtf(f: FloatArray, angle_deg: float) -> FloatArray:
    """The unit pixel's MTF along the normal of an edge slanted by ``angle_deg``."""
    a = math.radians(angle_deg)
    return np.abs(np.sinc(f * math.cos(a)) * np.sinc(f * math.sin(a)))


def max_error(result_f: FloatArray, measured: FloatArray, true: FloatArray, top: float) -> float:
    keep = result_f <= top + 1e-9
    return float(np.abs(measured - true)[keep].max())


# -- models -----------------------------------------------------------------------------------------


def test_sinc_and_velocity_mismatch_at_nyquist() -> None:
    assert sinc(0.0) == 1.0
    assert sinc(0.5) == pytest.approx(0.6366197723675814, rel=1e-15)  # 2 / pi
    assert abs(sinc(1.0)) < 1e-16
    assert np.allclose(sinc(np.array([0.0, 0.5, -0.5])), [1.0, TWO_OVER_PI, TWO_OVER_PI])
    # docs/physics.md §6 eq 8: M dV/V = 1 gives 0.64 at Nyquist, M dV/V = 2 gives 0; 0 gives 1.
    assert mtf_velocity_mismatch(0.5, 96, 1 / 96) == pytest.approx(TWO_OVER_PI, rel=1e-12)
    assert mtf_velocity_mismatch(0.5, 96, -1 / 96) == pytest.approx(TWO_OVER_PI, rel=1e-12)
    assert mtf_velocity_mismatch(0.5, 48, 2 / 48) == pytest.approx(0.0, abs=1e-15)
    assert mtf_velocity_mismatch(0.5, 96, 0.0) == 1.0
    # The 2 % rule of a 96-stage device: M |dV/V| = 1.92 leaves 0.04 at Nyquist.
    # sinc(0.96) = sin(0.96 pi) / (0.96 pi) = 0.12533 / 3.01593 = 0.041557
    assert mtf_velocity_mismatch(0.5, 96, 0.02) == pytest.approx(0.041557, abs=2e-6)
    # Beyond the first zero the modulus: sinc(1.5) = -1 / (1.5 pi) -> 0.21221.
    assert mtf_velocity_mismatch(0.5, 3, 1.0) == pytest.approx(1 / (1.5 * math.pi), rel=1e-12)
    curve = mtf_velocity_mismatch(np.array([0.0, 0.25, 0.5]), 10, 0.1)
    assert np.allclose(curve, [1.0, math.sin(math.pi / 4) / (math.pi / 4), TWO_OVER_PI])


def test_detector_terms_at_nyquist_for_96_stages() -> None:
    # docs/physics.md §6 eq 3 at Nyquist: sinc(q / 2p) sinc(T_int / 2 T_L), T_int / T_L = M / (M + 1).
    assert tdi_integration_ratio(96) == pytest.approx(96 / 97, rel=1e-15)
    assert tdi_integration_ratio(1) == 0.5
    # q / p = sqrt(0.8) = 0.894427: sinc(0.447214) = sin(80.50 deg) / 1.404963 = 0.701998
    # M = 96: sinc(0.494845) = sin(89.072 deg) / 1.554601 = 0.643167
    q = math.sqrt(0.8)
    geo = mtf_detector(0.5, fill_width=q, integration_ratio=0.0)
    assert geo == pytest.approx(0.701998, abs=1e-6)
    discrete = mtf_detector(0.5, fill_width=0.0, integration_ratio=96 / 97)
    assert discrete == pytest.approx(0.643167, abs=1e-6)
    both = mtf_detector(0.5, fill_width=q, integration_ratio=96 / 97)
    assert both == pytest.approx(0.701998 * 0.643167, abs=2e-6)  # 0.451502
    assert mtf_detector(0.5, fill_width=1.0, integration_ratio=1.0) == pytest.approx(TWO_OVER_PI**2)
    # eq 3 times eq 8: the default integration ratio is M / (M + 1).
    model = mtf_tdi_model(0.5, stages=96, dv_over_v=1 / 96, fill_width=q)
    assert model == pytest.approx(0.451502 * TWO_OVER_PI, abs=2e-6)  # 0.287435
    assert mtf_tdi_model(0.5, stages=96, dv_over_v=2 / 96, fill_width=q) == pytest.approx(
        0.0, abs=1e-15
    )
    assert mtf_tdi_model(
        0.5, stages=4, dv_over_v=0.0, fill_width=1.0, integration_ratio=0.0
    ) == pytest.approx(TWO_OVER_PI)
    arr = mtf_tdi_model(np.array([0.0, 0.5]), stages=96, dv_over_v=0.0, fill_width=q)
    assert arr.shape == (2,) and arr[0] == 1.0 and arr[1] == pytest.approx(0.451502, abs=2e-6)


@given(
    f=st.floats(0.0, 1.0),
    stages=st.integers(1, 256),
    dv=st.floats(-0.5, 0.5),
    q=st.floats(0.0, 1.0),
)
def test_model_is_a_bounded_product_even_in_dv(f: float, stages: int, dv: float, q: float) -> None:
    plus = mtf_tdi_model(f, stages=stages, dv_over_v=dv, fill_width=q)
    minus = mtf_tdi_model(f, stages=stages, dv_over_v=-dv, fill_width=q)
    assert 0.0 <= plus <= 1.0 and plus == minus
    assert plus == pytest.approx(
        mtf_detector(f, fill_width=q, integration_ratio=stages / (stages + 1))
        * mtf_velocity_mismatch(f, stages, dv),
        rel=1e-12,
        abs=1e-15,
    )


def test_models_refuse_bad_inputs() -> None:
    with pytest.raises(ValueError, match="stages must be a whole number >= 1"):
        mtf_velocity_mismatch(0.5, 0, 0.01)
    with pytest.raises(ValueError, match="stages must be a whole number >= 1"):
        tdi_integration_ratio(True)
    with pytest.raises(ValueError, match=r"fill_width must be in \[0, 1\]"):
        mtf_detector(0.5, fill_width=1.2, integration_ratio=0.5)
    with pytest.raises(ValueError, match="at most one line period"):
        mtf_detector(0.5, fill_width=1.0, integration_ratio=1.5)
    with pytest.raises(ValueError, match="f_cy_per_px must be finite"):
        mtf_velocity_mismatch(float("nan"), 4, 0.0)
    with pytest.raises(ValueError, match="dv_over_v must be finite"):
        mtf_tdi_model(0.5, stages=4, dv_over_v=float("inf"), fill_width=1.0)


# -- slanted edge: exact edges ----------------------------------------------------------------------


@pytest.mark.parametrize("y0", [20.0, 20.3, 20.6])
def test_ideal_edge_gives_the_pixel_sinc(y0: float) -> None:
    image = render_edge((40, 64), 5.0, y0)
    result = slanted_edge_mtf(image)
    f = result.frequencies_cy_per_px
    assert result.edge_angle_deg == pytest.approx(5.0, abs=1e-3)
    assert result.axis == "along" and not result.rising  # bright first along the rows
    assert result.mtf_at(0.0) == pytest.approx(1.0)
    # |sinc(0.5)| = 0.637 within 2 % (measured 0.628 .. 0.637: aliasing of the 4x ESF).
    assert result.mtf_nyquist == pytest.approx(TWO_OVER_PI, rel=0.02)
    truth = pixel_mtf(f, 5.0)
    assert max_error(f, result.mtf, truth, 0.5) < 0.015
    assert max_error(f, result.mtf, truth, 1.0) < 0.025
    assert f[-1] == pytest.approx(1.0)
    # A pixel-wide ramp: 10-90 % in 0.8 px, plus the 1/4 px bins (0.85 measured).
    assert result.edge_width_10_90_px == pytest.approx(0.85, abs=0.05)


@pytest.mark.parametrize("angle_deg", [2.0, 3.0, -5.0, 8.0, 15.0, 30.0, 44.0])
def test_ideal_edge_at_other_angles(angle_deg: float) -> None:
    t = abs(math.tan(math.radians(angle_deg)))
    cols = 128 if abs(angle_deg) < 3 else 64
    rows = round(cols * t) + 40
    y0 = 20.0 if angle_deg > 0 else rows - 20.0
    result = slanted_edge_mtf(render_edge((rows, cols), angle_deg, y0))
    assert result.edge_angle_deg == pytest.approx(angle_deg, abs=0.01)
    assert result.mtf_nyquist == pytest.approx(float(pixel_mtf(np.array(0.5), angle_deg)), rel=0.03)


@pytest.mark.parametrize(("sigma", "y0"), [(0.5, 20.0), (0.5, 20.4), (1.0, 20.0), (1.0, 20.7)])
def test_gaussian_blurred_edge(sigma: float, y0: float) -> None:
    result = slanted_edge_mtf(render_edge((40, 64), 5.0, y0, sigma=sigma))
    f = result.frequencies_cy_per_px
    truth = np.exp(-2.0 * math.pi**2 * sigma**2 * f**2) * pixel_mtf(f, 5.0)
    assert max_error(f, result.mtf, truth, 0.5) < 0.01
    assert max_error(f, result.mtf, truth, 1.0) < 0.02
    # exp(-2 pi^2 s^2 / 4) * 0.637: s = 0.5 -> 0.1855, s = 1 -> 0.0046
    assert result.mtf_nyquist == pytest.approx(float(np.interp(0.5, f, truth)), abs=0.006)


@pytest.mark.parametrize("length", [0.5, 1.0, 1.5, 2.0])
def test_motion_smeared_edge(length: float) -> None:
    result = slanted_edge_mtf(render_edge((40, 64), 5.0, 20.0, smear=length))
    f = result.frequencies_cy_per_px
    cos = math.cos(math.radians(5.0))  # the smear is along the rows, the MTF along the normal
    truth = np.abs(np.sinc(f * length * cos)) * pixel_mtf(f, 5.0)
    assert max_error(f, result.mtf, truth, 0.5) < 0.01
    assert max_error(f, result.mtf, truth, 1.0) < 0.02


@pytest.mark.parametrize("m_dv", [0.0, 1.0, 2.0])
def test_smear_of_m_dv_over_v_pixels_against_eq8_times_eq3(m_dv: float) -> None:
    # A scan with mismatch dV/V over M stages smears M dV/V pixels (docs/physics.md §6): here the
    # smear alone on a 100 % fill pixel with an instantaneous exposure.
    stages = 32
    image = (
        render_edge((40, 64), 5.0, 20.0, smear=m_dv) if m_dv else render_edge((40, 64), 5.0, 20.0)
    )
    measured = slanted_edge_mtf(image).mtf_nyquist
    model = mtf_tdi_model(
        0.5, stages=stages, dv_over_v=m_dv / stages, fill_width=1.0, integration_ratio=0.0
    )
    # Models: 0.637, 0.405, 0.000 (the 5 deg slant adds < 0.003).
    assert model == pytest.approx([TWO_OVER_PI, TWO_OVER_PI**2, 0.0][int(m_dv)], abs=1e-12)
    assert measured == pytest.approx(model, abs=0.012)


def test_rising_falling_and_both_axes_agree() -> None:
    image = render_edge((40, 64), 5.0, 20.3, lo=50.0, hi=850.0)
    falling = slanted_edge_mtf(image)
    rising = slanted_edge_mtf(900.0 - image)
    across = slanted_edge_mtf(image.T, axis="across")
    assert not falling.rising and rising.rising and not across.rising
    assert np.allclose(rising.mtf, falling.mtf, atol=1e-9)
    assert np.allclose(across.mtf, falling.mtf, atol=1e-12)
    assert across.edge_angle_deg == falling.edge_angle_deg
    assert falling.lsf.sum() > 0 and rising.lsf.sum() > 0
    # Scaling and offset do not change the MTF.
    assert np.allclose(slanted_edge_mtf(3.0 * image + 7.0).mtf, falling.mtf, atol=1e-9)


def test_noise_robustness() -> None:
    clean = render_edge((64, 128), 5.0, 32.0, lo=100.0, hi=1100.0)
    reference = slanted_edge_mtf(clean)
    rng = np.random.default_rng(20240607)
    for _ in range(5):
        noisy = clean + rng.normal(0.0, 2.0, clean.shape)  # step / noise = 500
        result = slanted_edge_mtf(noisy)
        assert result.edge_angle_deg == pytest.approx(5.0, abs=0.02)
        assert result.mtf_nyquist == pytest.approx(reference.mtf_nyquist, abs=0.025)
        assert result.mtf_at(0.25) == pytest.approx(reference.mtf_at(0.25), abs=0.01)


def test_options() -> None:
    image = render_edge((40, 120), 5.0, 20.0)
    base = slanted_edge_mtf(image)
    assert base.sample_spacing_px == 0.25 and base.lines_used == 114  # 10 phase cycles
    # Without the binning correction the 1/4 px bins cost sinc(1/8) = 0.974 at Nyquist.
    raw = slanted_edge_mtf(image, correct_binning=False)
    assert raw.mtf_nyquist == pytest.approx(base.mtf_nyquist * np.sinc(0.125), rel=1e-9)
    forward = slanted_edge_mtf(image, derivative="forward")
    assert forward.mtf_nyquist == pytest.approx(TWO_OVER_PI, rel=0.02)
    plain = slanted_edge_mtf(image, window=False)
    assert plain.mtf_nyquist == pytest.approx(base.mtf_nyquist, abs=0.003)
    eight = slanted_edge_mtf(image, oversample=8)
    assert eight.sample_spacing_px == 0.125
    assert eight.mtf_nyquist == pytest.approx(TWO_OVER_PI, rel=0.02)
    two = slanted_edge_mtf(image, oversample=2)
    assert two.frequencies_cy_per_px[-1] == pytest.approx(0.5)
    with pytest.raises(ValueError, match=r"freq_cy_per_px must be in \[0, 1\]"):
        base.mtf_at(1.5)


def test_refusals_say_what_to_change() -> None:
    edge = render_edge((40, 64), 5.0, 20.0, lo=100.0, hi=900.0)
    cases: list[tuple[object, dict[str, object], str]] = [
        (np.full((40, 64), 500.0), {}, r"flat \(every pixel 500 DN\)"),
        (
            500.0 + np.random.default_rng(1).normal(0, 3, (40, 64)),
            {},
            "no edge found: .* crop a region around one edge",
        ),
        (render_edge((40, 64), 0.5, 20.0), {}, r"edge angle 0\.50 deg is too close to 0"),
        (
            render_edge((200, 64), 50.0, 20.0),
            {},
            r"beyond 45 deg: .* measure it with axis='across'",
        ),
        (render_edge((40, 64), 5.0, 20.0)[:, :4], {}, "too few lines: 4 columns cross the edge"),
        (
            render_edge((40, 16), 1.5, 20.0),
            {},
            r"too few lines: at 1\.50 deg the edge moves 0\.42 px over 16 columns; "
            "one pixel of phase needs at least 39",
        ),
        (edge, {"saturation_dn": 900.0}, "pixels at or above saturation_dn=900"),
        (render_edge((40, 64), 5.0, 20.0)[:4], {}, "lines too short: 4 pixels"),
        (
            render_edge((40, 64), 20.0, 20.0),
            {},
            r"the edge leaves the region: line 48 \(column 48 of the region\)",
        ),
        (np.ones((4, 4, 4)), {}, "needs a 2-D image"),
        (np.where(np.eye(40, 64) > 0, np.nan, edge), {}, "NaN or infinite"),
        (edge, {"oversample": 1}, "oversample must be a whole number in 2 .. 16"),
        (edge, {"axis": "diagonal"}, "axis must be 'along'"),
    ]
    for image, kwargs, message in cases:
        with pytest.raises(ValueError, match=message):
            slanted_edge_mtf(image, **kwargs)  # type: ignore[arg-type]
    # A bright bar (two edges) is not one edge: both ends at the same level.
    bar = render_edge((48, 64), 5.0, 30.0) - render_edge((48, 64), 5.0, 14.0)
    with pytest.raises(ValueError, match="no edge found"):
        slanted_edge_mtf(bar)


# -- the simulator's edge scene ---------------------------------------------------------------------


def _scene_image(spec: str, *, aperture: float, exposure_rows: float) -> FloatArray:
    scene = build_scene(SceneSpec.parse(spec), columns=256, pitch_m=5.5e-6, default_photons=1e3)
    image = scene.integrate(0, 192, 256, 0.0, exposure_rows, None, 1.0, aperture, dtype=np.float64)
    return np.asarray(image, dtype=np.float64)


def test_edge_regions_of_the_simulated_edge_scene() -> None:
    # Edges every 32 rows, alternately rising and falling, slanted by 5 deg: over 256 columns
    # an edge drifts 22 rows, more than a 32-row region can hold, so each is cut into two
    # blocks of 128 columns.
    image = _scene_image("edge:photons=1000,angle_deg=5", aperture=1.0, exposure_rows=0.0)
    regions = find_edge_regions(image, axis="along")
    assert len(regions) >= 8
    positions = sorted({round(r.position_px) for r in regions})
    assert all(b - a >= 10 for a, b in itertools.pairwise(positions))
    for region in regions:
        rows, cols = region.slices
        assert rows.stop - rows.start == 32 and cols.stop - cols.start in (127, 128, 129)
        result = slanted_edge_mtf(image[region.slices], axis="along")
        assert result.rising == region.rising
        assert result.edge_angle_deg == pytest.approx(5.0, abs=0.02)
        # A 100 % fill pixel, no motion: sinc(0.5) (measured 0.633 .. 0.639).
        assert result.mtf_nyquist == pytest.approx(TWO_OVER_PI, rel=0.02)
    across = find_edge_regions(image.T, axis="across")
    assert [r.slices[::-1] for r in across] == [r.slices for r in regions]


@pytest.mark.parametrize(("fill", "exposure_rows"), [(0.8, 0.0), (1.0, 1.0), (1.0, 96 / 97)])
def test_simulated_edge_against_eq3(fill: float, exposure_rows: float) -> None:
    # The aperture sqrt(fill) and the motion during the exposure (T_int / T_L rows) are eq 3's
    # terms. The scene needs fine cells (oversample=16): its 1/4-row default cells add
    # sinc(f / 4) = 0.974 at Nyquist whenever the aperture or the motion is not cell-aligned.
    q = math.sqrt(fill)
    image = _scene_image(
        "edge:photons=1000,angle_deg=5,oversample=16", aperture=q, exposure_rows=exposure_rows
    )
    model = mtf_detector(0.5, fill_width=q, integration_ratio=exposure_rows)
    for region in find_edge_regions(image, axis="along"):
        measured = slanted_edge_mtf(image[region.slices], axis="along").mtf_nyquist
        assert measured == pytest.approx(model, rel=0.015)


def test_find_edge_regions_refusals() -> None:
    with pytest.raises(ValueError, match="no edges found"):
        find_edge_regions(np.full((64, 64), 10.0))
    with pytest.raises(ValueError, match="axis must be"):
        find_edge_regions(np.ones((8, 8)), axis="up")  # type: ignore[arg-type]
    single = render_edge((40, 64), 5.0, 20.0)
    (region,) = find_edge_regions(single)
    assert region.slices == (slice(0, 40), slice(0, 64)) and not region.rising


# -- edge width -------------------------------------------------------------------------------------


def test_edge_width_10_90() -> None:
    x = np.arange(-40, 41) * 0.05  # 0.05 px samples
    ramp = np.clip(x + 0.5, 0.0, 1.0)  # a pixel-wide box: 10 % at -0.4, 90 % at +0.4
    assert edge_width_10_90_px(ramp, 0.05) == pytest.approx(0.8, abs=1e-9)
    assert edge_width_10_90_px(1.0 - ramp, 0.05) == pytest.approx(0.8, abs=1e-9)
    sigma = 1.3
    gauss = _normal_cdf(np.arange(-1500, 1501, dtype=np.float64) * (0.01 / sigma))
    # 2 * 1.281552 sigma (the 90 % point of the normal distribution)
    assert edge_width_10_90_px(gauss, 0.01) == pytest.approx(2.563103 * sigma, abs=2e-3)
    with pytest.raises(ValueError, match="same level at both ends"):
        edge_width_10_90_px(np.ones(10), 1.0)
    with pytest.raises(ValueError, match="spacing_px must be > 0"):
        edge_width_10_90_px(ramp, 0.0)


# -- bar targets ------------------------------------------------------------------------------------


def square_wave(n: int, f: float, lo: float, hi: float, shift: float = 0.0) -> FloatArray:
    """Pixel-integrated square wave (bright first half-period), exact by 1000 sub-samples."""
    x = (np.arange(n * 1000) + 0.5) / 1000 + shift
    bright = (x * f) % 1.0 < 0.5
    profile: FloatArray = np.where(bright, hi, lo).reshape(n, 1000).mean(axis=1)
    return profile


@pytest.mark.parametrize("f", [0.05, 0.1, 0.125, 0.25, 0.5])
def test_bar_modulation_of_pixel_aligned_square_waves(f: float) -> None:
    # Bars of whole pixels: the samples are exactly lo and hi; contrast (900-100)/(900+100).
    profile = square_wave(80, f, 100.0, 900.0)
    assert bar_modulation(profile, f) == pytest.approx(0.8, abs=1e-9)
    assert bar_modulation(profile, f, method="halves") == pytest.approx(0.8, abs=1e-9)
    assert mtf_from_bars(bar_modulation(profile, f), 0.8) == pytest.approx(1.0, abs=1e-9)
    region = np.tile(profile[:, None], (1, 5))  # bars varying along axis 0
    assert bar_modulation(region, f, axis=0) == pytest.approx(0.8, abs=1e-9)


def test_bar_modulation_phase_and_fundamental() -> None:
    # At Nyquist half a pixel out of phase every pixel sees half a bar: no modulation.
    shifted = square_wave(40, 0.5, 100.0, 900.0, shift=0.5)
    assert bar_modulation(shifted, 0.5) == pytest.approx(0.0, abs=1e-12)
    # A sampled sine of modulation 0.3: the fundamental finds it; halves gives 2/pi of it.
    n = np.arange(200)
    sine = 500.0 * (1.0 + 0.3 * np.cos(2.0 * np.pi * 0.05 * n + 0.7))
    assert bar_modulation(sine, 0.05, method="fundamental") == pytest.approx(0.3, rel=1e-9)
    assert bar_modulation(sine, 0.05, method="halves") == pytest.approx(0.3 * TWO_OVER_PI, rel=0.01)
    assert bar_modulation(sine, 0.05) == pytest.approx(0.3, rel=0.01)
    # Square bars at 0.05 cy/px (10-pixel bars): the fundamental is 4/pi times the contrast,
    # times the pixel's sinc(0.05) = 0.99589 and an aliased harmonic or two.
    square = square_wave(200, 0.05, 100.0, 900.0, shift=0.3)
    fundamental = bar_modulation(square, 0.05, method="fundamental")
    assert fundamental == pytest.approx(SQUARE_WAVE_FUNDAMENTAL * 0.8 * 0.99589, rel=0.01)
    assert mtf_from_bars(fundamental, 0.8, fundamental=True) == pytest.approx(0.99589, rel=0.01)


def test_bar_refusals() -> None:
    with pytest.raises(ValueError, match=r"must be in \(0, 0\.5\] \(Nyquist\)"):
        bar_modulation(np.ones(10), 0.6)
    with pytest.raises(ValueError, match=r"holds no full period at 0\.05 cy/px"):
        bar_modulation(np.ones(10), 0.05)
    with pytest.raises(ValueError, match="levels must be above black"):
        bar_modulation(np.array([-1.0, 1.0] * 4), 0.5)
    with pytest.raises(ValueError, match="method must be"):
        bar_modulation(np.ones(10), 0.5, method="rms")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match=r"target_contrast must be in \(0, 1\]"):
        mtf_from_bars(0.5, 0.0)
    with pytest.raises(ValueError, match=r"modulation must be in \[0, 1\]"):
        mtf_from_bars(1.2, 0.8)


def test_coltman_series_inverts_the_square_wave_response() -> None:
    # A linear (cone) MTF 1 - f/fc; the square-wave CTF follows from the forward series
    # CTF(f) = 4/pi [MTF(f) - MTF(3f)/3 + MTF(5f)/5 - ...]; the inverse series recovers it.
    fc = 1.0
    f = np.linspace(0.01, 1.0, 100)

    def mtf(freq: FloatArray) -> FloatArray:
        return np.clip(1.0 - freq / fc, 0.0, None)

    ctf = (4.0 / math.pi) * sum((-1) ** ((k - 1) // 2) * mtf(k * f) / k for k in range(1, 200, 2))
    assert isinstance(ctf, np.ndarray)
    recovered = sine_mtf_from_ctf(f, ctf, terms=50)
    assert np.allclose(recovered, mtf(f), atol=0.01)
    # Above fc/3 only the first term: MTF = pi/4 CTF.
    high = f > fc / 3
    assert np.allclose(recovered[high], (math.pi / 4) * ctf[high], atol=1e-12)
    with pytest.raises(ValueError, match="increasing"):
        sine_mtf_from_ctf([0.2, 0.1], [0.5, 0.6])
