"""camd.analysis.image_motion against windows shifted by known sub-pixel amounts (issue 35 item 1).

The windows are cut from firmware_models' scenes (the natural texture and the bar target, built
by ``build_scene``) rendered once at the pixel grid over one period of the scene (both scenes
tile periodically), then shifted exactly by a Fourier phase ramp (an exact shift of the
band-limited image: the simulator's own sub-pixel shift interpolates linearly, which is not an
exact shift), with Poisson shot noise and Gaussian read noise, quantised to uint16. The scenes'
component at the Nyquist frequency (period 2 pixels; the bar target's finest bars, 18 % of its
power) is left out: shifted by a fraction ``f`` of a pixel its samples ``cos(pi (n + f))`` =
``cos(pi n) cos(pi f)`` change in contrast and not in position (docs/physics.md §10), so it is
not a translation for any registration to find.

Tolerances (docs/physics.md §10, "Image motion from the frames"): one pair's shift has the standard
deviation ``sigma_pair = sqrt(2 sigma_n^2 / sum g^2)`` (``sigma_n^2`` the noise variance per pixel,
here the mean signal plus the read noise squared; ``g`` the noise-free gradient along the axis
over the overlap); the rate fitted from the pairs the measurement registered has
``sqrt(sum c_k^2 sigma_k^2)`` (``rate_sigma``, the fit's coefficients ``c_k``). The noise moves
the rate within 5 of those from the noise-free windows' (a chance of 6e-7 per check). The
noise-free rate is off the truth by the bicubic interpolation's bias alone, at most
``sum |c_k|`` times the worst pair bias ``interpolation_bias_px`` predicts from the scene's own
power spectrum over the fractions of a pixel (§10 "Interpolation bias"); a check passes within
5 sigma plus that bound.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
import numpy.typing as npt
import pytest

from camd.analysis.image_motion import (
    ImageMotion,
    cubic_response,
    interpolation_bias_px,
    measure_area_motion,
    measure_tdi_motion,
    rate_coefficients,
    rate_sigma,
)
from firmware_models.scene import build_scene
from firmware_models.scene_spec import SceneSpec

COLS = 256
FRAMES = 30
READ_NOISE_E = 5.0
OFFSET_DN = 100.0
PHOTONS = 2000.0
SIGMAS = 5.0

Image = npt.NDArray[np.float64]


def _base(spec: str) -> Image:
    """One period of the scene at the pixel grid (photons per pixel in one exposure), without
    its Nyquist components (module doc)."""
    scene = build_scene(SceneSpec.parse(spec), columns=COLS, pitch_m=5.5e-6, default_photons=1.0)
    period = round(scene.period_rows)
    image = scene.integrate(0, period, COLS, 0.0, 0.0, 0.0, 1.0, 1.0, dtype=np.float64)
    spectrum = np.fft.fft2(image)
    for axis, size in enumerate(spectrum.shape):
        if size % 2 == 0:
            np.moveaxis(spectrum, axis, 0)[size // 2] = 0.0
    out: Image = np.fft.ifft2(spectrum).real
    # photons cannot be negative, and the band-limited scene rings below its samples between
    # them: raised by its lowest value over a quarter-pixel grid (shifted windows lie within it)
    period, cols = out.shape
    fy = np.fft.fftfreq(period)[:, None]
    fx = np.fft.fftfreq(cols)[None, :]
    lowest = min(
        float(np.fft.ifft2(spectrum * np.exp(2j * np.pi * (fy * i + fx * j) / 4)).real.min())
        for i in range(4)
        for j in range(4)
    )
    out += max(0.0, -1.1 * lowest)
    return out


_BASES: dict[str, Image] = {}


def base(kind: str) -> Image:
    if kind not in _BASES:
        _BASES[kind] = _base(f"{kind}:photons={PHOTONS:g}")
    return _BASES[kind]


def shifted(image: Image, along: float, across: float, rows: int) -> Image:
    """``out(r, c) = image(r + along, c + across)``, exactly (periodic), the first ``rows``."""
    period, cols = image.shape
    fy = np.fft.fftfreq(period)[:, None]
    fx = np.fft.fftfreq(cols)[None, :]
    ramp = np.exp(2j * np.pi * (fy * along + fx * across))
    moved = np.fft.ifft2(np.fft.fft2(image) * ramp).real
    out: Image = np.take(moved, np.arange(rows) % period, axis=0)
    return out


def noisy(clean: Image, rng: np.random.Generator) -> npt.NDArray[np.uint16]:
    electrons = rng.poisson(np.maximum(clean, 0.0)) + rng.normal(
        OFFSET_DN, READ_NOISE_E, clean.shape
    )
    return np.clip(np.rint(electrons), 0, 65535).astype(np.uint16)


def tdi_windows(
    kind: str, rows: int, along: float, across: float, counters: list[int], seed: int = 0
) -> tuple[list[npt.NDArray[np.uint16]], list[Image]]:
    rng = np.random.default_rng(seed)
    clean = [shifted(base(kind), c * along, c * across, rows) for c in counters]
    return [noisy(c, rng) for c in clean], clean


def pair_sigma(first: Image, shift_rows: float) -> tuple[float, float]:
    """The physics section's precision of one pair's shift (along, across), the later frame
    ``shift_rows`` rows on: the noise over the gradient energy of the rows both frames see."""
    rows = first.shape[0]
    overlap = first[: rows - math.ceil(shift_rows) - 2, 2:-2]
    g_rows = np.gradient(overlap, axis=0)
    g_cols = np.gradient(overlap, axis=1)
    sigma_n2 = float(np.mean(first)) + READ_NOISE_E**2
    along_sigma = math.sqrt(2 * sigma_n2 / float(np.sum(g_rows**2)))
    across_sigma = math.sqrt(2 * sigma_n2 / float(np.sum(g_cols**2)))
    return along_sigma, across_sigma


def predicted_sigma(result: ImageMotion, clean: list[Image], along: float) -> tuple[float, float]:
    """The physics section's precision of the per-line rate fitted from the pairs the
    measurement registered: each pair's ``pair_sigma`` at its shift, through ``rate_sigma``."""
    pairs = result.registered
    sigmas = [pair_sigma(clean[p.reference], p.baseline * along) for p in pairs]
    return (
        rate_sigma(pairs, [s[0] for s in sigmas]),
        rate_sigma(pairs, [s[1] for s in sigmas]),
    )


_WORST_BIAS: dict[str, tuple[float, float]] = {}


def worst_pair_bias(kind: str) -> tuple[float, float]:
    """The largest interpolation bias (along, across) ``interpolation_bias_px`` gives a pair in
    this scene over the fractions of a pixel, 0 to 1 in twentieths, along and across at once."""
    if kind not in _WORST_BIAS:
        fractions = np.linspace(0.0, 1.0, 21)
        biases = [interpolation_bias_px(base(kind), 5 + f, 0.3 + f) for f in fractions]
        _WORST_BIAS[kind] = (max(abs(b[0]) for b in biases), max(abs(b[1]) for b in biases))
    return _WORST_BIAS[kind]


def bias_bound(result: ImageMotion, kind: str) -> tuple[float, float]:
    """The most the interpolation can bias the rate: every pair biased by the scene's worst
    (``worst_pair_bias``) with the sign that adds up, through the fit (``sum |c_k|``)."""
    total = float(np.sum(np.abs(rate_coefficients(result.registered))))
    worst = worst_pair_bias(kind)
    return total * worst[0], total * worst[1]


def test_cubic_response_is_opencvs_bicubic() -> None:
    # cv2.remap (INTER_CUBIC) of a sampled sinusoid read a fraction f past each sample is the
    # sinusoid times H_f: the kernel the bias prediction rests on is OpenCV's
    n = np.arange(64)
    for omega in (0.3, 1.4, 2.6):
        wave = np.cos(omega * n + 0.4).astype(np.float32)[None, :].repeat(4, axis=0)
        for fraction in (0.013, 0.25, 0.6, 0.98):
            map_x = (n[8:-8] + fraction).astype(np.float32)[None, :].repeat(4, axis=0)
            map_y = np.full_like(map_x, 1.0)
            warped = cv2.remap(wave, map_x, map_y, cv2.INTER_CUBIC)[1]
            want = (cubic_response(fraction, omega) * np.exp(1j * (omega * n[8:-8] + 0.4))).real
            # float32 maps: a position near column 56 is rounded by up to 2e-6 px
            assert np.max(np.abs(warped - want)) < 1e-5


@pytest.mark.parametrize("kind", ["natural", "bars"])
@pytest.mark.parametrize("stages", [8, 32, 96])
@pytest.mark.parametrize(("dv_over_v", "theta_deg"), [(-0.02, -1.0), (0.013, 0.5), (0.02, 1.0)])
def test_dv_over_v_and_theta_within_the_precision_formula(
    kind: str, stages: int, dv_over_v: float, theta_deg: float
) -> None:
    along = 1.0 - dv_over_v  # docs/physics.md §6: dV/V = (V - V_m) / V, V_m / V = along
    across = along * math.tan(math.radians(theta_deg))  # columns per line
    counters = list(range(FRAMES))
    frames, clean = tdi_windows(kind, stages, along, across, counters, seed=stages)
    background = np.full(frames[0].shape, OFFSET_DN)
    result = measure_tdi_motion(frames, counters, background=background)
    assert result.measurable, result.why
    assert result.frames_used == FRAMES and result.pairs_used == len(result.registered)
    # every frame registered at most once; most of them (a reference's pairs need 2 or more)
    registered = [p.frame for p in result.registered]
    assert len(set(registered)) == len(registered) >= FRAMES // 2
    sigma_along, sigma_across = predicted_sigma(result, clean, along)
    bound_along, bound_across = bias_bound(result, kind)
    # the noise-free windows: the interpolation's bias alone, within its bound
    exact = measure_tdi_motion(clean, counters, background=np.zeros(clean[0].shape))
    assert abs(exact.shift_along_px_per_line - along) < bound_along
    assert abs(exact.shift_across_px_per_line - across) < bound_across
    # the noise: within 5 sigma of the noise-free result (the same pairs registered)
    if exact.registered == result.registered:
        assert abs(result.shift_along_px_per_line - exact.shift_along_px_per_line) < (
            SIGMAS * sigma_along
        )
        assert abs(result.shift_across_px_per_line - exact.shift_across_px_per_line) < (
            SIGMAS * sigma_across
        )
    tol_along = SIGMAS * sigma_along + bound_along
    tol_across = SIGMAS * sigma_across + bound_across
    assert abs(result.dv_over_v - dv_over_v) < tol_along
    assert abs(result.shift_across_px_per_line - across) < tol_across
    assert abs(result.m_dv_over_v(stages) - stages * dv_over_v) < stages * tol_along
    if kind == "natural":
        # the reported standard errors (the pairs' scatter) agree with the formula
        assert 0.25 < result.shift_along_stderr_px / sigma_along < 2.0
        assert 0.25 < result.shift_across_stderr_px / sigma_across < 2.0
    # theta = atan2(across, along): d theta = (along d across - across d along) / along^2, the
    # along term below 0.02 of the across one here
    assert abs(result.theta_deg - theta_deg) < math.degrees(1.1 * tol_across / along)


def test_flat_scene_is_not_measurable() -> None:
    rng = np.random.default_rng(3)
    frames = [noisy(np.full((32, COLS), PHOTONS), rng) for _ in range(FRAMES)]
    result = measure_tdi_motion(frames, list(range(FRAMES)))
    assert not result.measurable
    assert math.isnan(result.dv_over_v) and math.isnan(result.theta_deg)
    assert result.why.startswith("scene texture too low")


def test_dropped_frames_are_longer_steps_not_motion() -> None:
    # frames 5, 6 and 12 lost: the counters jump by 3 and by 2 there
    counters = [c for c in range(FRAMES + 3) if c not in (5, 6, 12)]
    along, across = 1.01, math.tan(math.radians(0.5))
    frames, clean = tdi_windows("natural", 32, along, across, counters, seed=11)
    result = measure_tdi_motion(frames, counters, background=np.full(frames[0].shape, OFFSET_DN))
    assert result.measurable and result.pairs_used == len(counters) - 1
    # the baselines are the counters' distances: the lost frames are longer steps
    baselines = {p.baseline for p in result.registered}
    assert 7.0 in baselines and 13.0 in baselines
    sigma_along, sigma_across = predicted_sigma(result, clean, along)
    bound_along, bound_across = bias_bound(result, "natural")
    tol_along = SIGMAS * sigma_along + bound_along
    tol_across = SIGMAS * sigma_across + bound_across
    assert abs(result.shift_along_px_per_line - along) < tol_along
    assert abs(result.shift_across_px_per_line - across) < tol_across
    # the same frames read as consecutive would measure the gaps as motion
    naive = measure_tdi_motion(frames, list(range(len(frames))), background=None)
    assert naive.pairs_used < len(counters) - 1 or naive.shift_along_px_per_line > along + 0.02


def test_fixed_pattern_noise_is_removed() -> None:
    rng = np.random.default_rng(5)
    column_offsets = rng.normal(0.0, 200.0, COLS)  # DN, far above the scene's own contrast
    along, across = 1.015, math.tan(math.radians(-0.7))
    counters = list(range(FRAMES))
    frames, clean = tdi_windows("natural", 32, along, across, counters, seed=5)
    with_pattern = [np.clip(f + column_offsets, 0, 65535).astype(np.uint16) for f in frames]
    # the dark frame given: subtracted first
    dark = np.clip(OFFSET_DN + column_offsets, 0, 65535)[None, :].repeat(32, axis=0)
    given = measure_tdi_motion(with_pattern, counters, background=dark)
    # no dark frame: the per-column mean over the sequence
    own = measure_tdi_motion(with_pattern, counters)
    for result in (given, own):
        assert result.measurable, result.why
        sigma_along, sigma_across = predicted_sigma(result, clean, along)
        bias_along, bias_across = bias_bound(result, "natural")
        assert abs(result.shift_along_px_per_line - along) < SIGMAS * sigma_along + abs(bias_along)
        assert abs(result.shift_across_px_per_line - across) < SIGMAS * sigma_across + abs(
            bias_across
        )
    # a background of zeros leaves the pattern, which pulls the shift towards 0 columns
    kept = measure_tdi_motion(with_pattern, counters, background=np.zeros((32, COLS)))
    assert abs(kept.shift_across_px_per_line - across) > abs(own.shift_across_px_per_line - across)


def test_area_mode_from_stage_steps() -> None:
    magnification_error = 0.005
    steps = [20.0, 25.0, 20.0, 30.0, 20.0, 22.0, 20.0, 24.0]
    positions = np.concatenate([[0.0], np.cumsum(steps)])
    across_per_row = math.tan(math.radians(0.3))
    rng = np.random.default_rng(9)
    image = base("natural")
    frames = [
        noisy(shifted(image, p * (1 + magnification_error), p * across_per_row, 128), rng)
        for p in positions
    ]
    result = measure_area_motion(frames, steps, background=np.full((128, COLS), OFFSET_DN))
    assert result.measurable and result.pairs_used == len(result.registered) >= 4
    # physics §10: each pair has its own sigma (the rows both frames see), through the fit
    along = 1 + magnification_error
    clean = [shifted(image, p * along, p * across_per_row, 128) for p in positions]
    sigma_along, sigma_across = predicted_sigma(result, clean, along)
    bound_along, bound_across = bias_bound(result, "natural")
    tol_along = SIGMAS * sigma_along + bound_along
    tol_across = SIGMAS * sigma_across + bound_across
    assert abs(result.dv_over_v + magnification_error) < tol_along
    assert abs(result.shift_across_px_per_line - across_per_row) < tol_across
    theta_deg = math.degrees(math.atan2(across_per_row, along))
    assert abs(result.theta_deg - theta_deg) < math.degrees(1.1 * tol_across / along)


def test_bad_inputs_say_what_to_change() -> None:
    frames = [np.zeros((8, 16), np.uint16)] * 3
    with pytest.raises(ValueError, match="3 frames but 2 frame counters"):
        measure_tdi_motion(frames, [0, 1])
    with pytest.raises(ValueError, match="must increase strictly"):
        measure_tdi_motion(frames, [0, 2, 2])
    with pytest.raises(ValueError, match="background is \\(4, 16\\), the frames \\(8, 16\\)"):
        measure_tdi_motion(frames, [0, 1, 2], background=np.zeros((4, 16)))
    with pytest.raises(ValueError, match="3 frames need 2 steps"):
        measure_area_motion(frames, [1.0])
    with pytest.raises(ValueError, match="need at least 2 frames"):
        measure_tdi_motion(frames[:1], [0])


def rolling_windows(
    kind: str, rows: int, v: float, drift: float, lag: float, counters: list[int], seed: int
) -> tuple[list[npt.NDArray[np.uint16]], list[Image]]:
    """Windows of a rolling shutter, exactly: row ``i`` of frame ``k`` is read ``i lag`` line
    periods after its row 0, so it shows the scene moved ``v (k + i lag)`` rows along and
    ``drift`` times that across (physics §10, "A rolling shutter")."""
    rng = np.random.default_rng(seed)
    image = base(kind)
    period, cols = image.shape
    spectrum = np.fft.fft2(image)
    fy = np.fft.fftfreq(period)
    fx = np.fft.fftfreq(cols)
    clean: list[Image] = []
    for k in counters:
        frame = np.empty((rows, cols))
        for i in range(rows):
            moved = v * (k + i * lag)
            # the row at y = i + moved, its columns moved drift * moved: one row of the
            # Fourier-shifted image
            row_spectrum = np.exp(2j * np.pi * fy * (i + moved)) @ spectrum / period
            frame[i] = np.fft.ifft(row_spectrum * np.exp(2j * np.pi * fx * drift * moved)).real
        clean.append(frame)
    return [noisy(c, rng) for c in clean], clean


@pytest.mark.parametrize("rows", [32, 96])
@pytest.mark.parametrize("magnification_error", [-0.02, 0.01])
def test_a_rolling_shutters_shift_is_turned_into_the_image_speed(
    rows: int, magnification_error: float
) -> None:
    # hr400-like: the row time 1/rows of the line period; the image 1 + e rows per line, drifting
    # tan(0.5 deg) columns per row of its motion
    lag, v = 1.0 / rows, 1.0 + magnification_error
    drift = math.tan(math.radians(0.5))
    counters = list(range(FRAMES))
    frames, clean = rolling_windows("natural", rows, v, drift, lag, counters, seed=rows)
    background = np.full(frames[0].shape, OFFSET_DN)
    result = measure_tdi_motion(frames, counters, background=background, row_lag_lines=lag)
    assert result.measurable, result.why
    # the frames move s = v / (1 + v lag) rows (physics §10), which the fit finds ...
    s = v / (1 + v * lag)
    sigma_along, sigma_across = predicted_sigma(result, clean, s)
    bound_along, bound_across = bias_bound(result, "natural")
    assert abs(result.shift_along_px_per_line - s) < SIGMAS * sigma_along + bound_along
    # ... and dV/V = 1 - v = -e comes back through v = s / (1 - s lag)
    stretch = (1 - s * lag) ** 2
    assert (
        abs(result.dv_over_v + magnification_error) < (SIGMAS * sigma_along + bound_along) / stretch
    )
    # the drift angle needs no conversion: t = s tan(theta)
    assert abs(result.shift_across_px_per_line - s * drift) < SIGMAS * sigma_across + bound_across
    # read as a global shutter, the same frames would say the image is slow by about lag
    plain = measure_tdi_motion(frames, counters, background=background)
    assert plain.dv_over_v - result.dv_over_v == pytest.approx(
        lag * s * s / (1 - s * lag), rel=0.01
    )
