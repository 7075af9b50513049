"""The scene: spec parsing, built-in targets, and the exact motion/aperture integral."""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from firmware_models.scene import Scene, blur_cells, build_scene, motion_weights
from firmware_models.scene_spec import (
    BAR_FREQUENCIES_CY_PER_PX,
    SceneSpec,
    SceneSpecError,
    lux_to_photons_per_pixel_s,
)

# -- the spec --------------------------------------------------------------------------------------


def test_parse_and_describe_round_trip() -> None:
    spec = SceneSpec.parse("bars:lux=3,contrast=0.8,drift_deg=0.5")
    assert (spec.kind, spec.lux, spec.contrast, spec.drift_deg) == ("bars", 3.0, 0.8, 0.5)
    assert spec.photons is None and spec.period_rows == 40
    assert SceneSpec.parse(spec.describe()) == spec
    assert SceneSpec.parse("") == SceneSpec() and SceneSpec().describe() == "flat"
    edge = SceneSpec.parse("edge: photons=1e6 , angle_deg=-3, period=32, oversample=8")
    assert SceneSpec.parse(edge.describe()) == edge
    assert edge.describe() == "edge:photons=1e+06,oversample=8,angle_deg=-3,period=32"
    assert SceneSpec.parse("bars:orientation=across").period_rows == 32 * 7
    assert SceneSpec.parse("star:size=128").period_rows == 128


@pytest.mark.parametrize(
    ("text", "message"),
    [
        (
            "bar:lux=3",
            "unknown scene kind 'bar'; kinds: flat, bars, edge, star, ramp, natural, image",
        ),
        (
            "bars:angle_deg=3",
            "unknown scene key 'angle_deg' for bars; keys for bars: photons, lux, drift_deg, "
            "blur_px, magnification_error, rotation_deg, yaw_deg_per_m, contrast, oversample, "
            "orientation, period",
        ),
        ("flat:contrast=0.5", "unknown scene key 'contrast' for flat; keys for flat: photons"),
        ("bars:lux=-1", "scene lux=-1 is invalid: lux (bright level as focal-plane illuminance"),
        ("edge:contrast=2", "contrast (Michelson contrast of the target's pattern): Input should"),
        ("edge:angle_deg=x", "scene angle_deg=x is invalid"),
        ("bars:period=30", "period 30 rows holds no whole number of cycles at 0.05 cy/pixel"),
        ("flat:lux=3,photons=4", "give the level as photons or lux, not both"),
        ("lux=3", "scene 'lux=3' has no kind; write e.g. 'bars:lux=3'"),
        ("image", "an image scene needs path=FILE"),
        ("ramp:period", "scene item 'period' is not key=value"),
        ("ramp:period=8,period=9", "scene key 'period' is given twice"),
    ],
)
def test_bad_specs_say_what_to_change(text: str, message: str) -> None:
    with pytest.raises(SceneSpecError) as info:
        SceneSpec.parse(text)
    assert message in str(info.value)


def test_lux_conversion_by_hand() -> None:
    # 1 lx at 555 nm = 1/683 W/m^2; a 555 nm photon carries h c / lambda = 3.5793e-19 J.
    photon_j = 6.62607015e-34 * 299792458.0 / 555e-9
    by_hand = (1.0 / 683.0) / photon_j * (11e-6) ** 2
    assert lux_to_photons_per_pixel_s(1.0, 11e-6) == pytest.approx(by_hand, rel=1e-12)
    assert by_hand == pytest.approx(4.9497e5, rel=1e-4)
    assert lux_to_photons_per_pixel_s(3.0, 5.2e-6) == pytest.approx(
        3.0 * by_hand * (5.2 / 11) ** 2, rel=1e-12
    )
    with pytest.raises(ValueError):
        lux_to_photons_per_pixel_s(1.0, 0.0)


# -- built-in targets -----------------------------------------------------------------------------


def build(text: str, columns: int = 280) -> Scene:
    return build_scene(SceneSpec.parse(text), columns=columns, pitch_m=11e-6, default_photons=1e3)


def test_levels_and_contrast() -> None:
    assert build("flat").peak_photons == 1e3  # the camera's default level
    assert build("flat:photons=5e5").radiance.tolist() == [[5e5]]
    assert build("flat:lux=2").peak_photons == pytest.approx(
        2 * lux_to_photons_per_pixel_s(1, 11e-6)
    )
    bars = build("bars:photons=100,contrast=0.5,oversample=1")
    low, high = bars.radiance.min(), bars.radiance.max()
    assert high == 100.0 and (high - low) / (high + low) == pytest.approx(0.5)


def test_bar_groups_reach_nyquist_along_track() -> None:
    scene = build("bars:photons=1,oversample=1", columns=7 * 40)
    assert scene.period_rows == 40 and scene.width_cols == 280
    assert BAR_FREQUENCIES_CY_PER_PX[-1] == 0.5
    fine = (np.arange(40 * 1000) + 0.5) / 1000  # 1000 samples per row
    for group, f in enumerate(BAR_FREQUENCIES_CY_PER_PX):
        column = scene.radiance[:, group * 40 + 20]  # the middle of the group
        # Each cell is the exact mean of the square wave (bright first) over its row.
        sampled = ((f * fine) % 1.0 < 0.5).reshape(40, 1000).mean(axis=1)
        assert np.allclose(column, sampled, atol=2e-3), f
        assert column.mean() == pytest.approx(0.5)
    nyquist = scene.radiance[:, 6 * 40 + 20]
    assert nyquist.tolist() == [1.0, 0.0] * 20  # one row bright, one dark
    across = build("bars:photons=1,oversample=1,orientation=across")
    assert across.radiance[0, :6].tolist() == [1.0] * 6  # 0.05 cy/px: 10 bright columns
    assert across.radiance[6 * 32, :4].tolist() == [1.0, 0.0, 1.0, 0.0]  # Nyquist band


def test_slanted_edge_moves_tan_angle_rows_per_column() -> None:
    scene = build("edge:photons=1,angle_deg=5,period=64,oversample=4", columns=200)
    # Bright for (y - x tan 5 deg) mod 64 < 32: in rows 20..49 of column x that is
    # 32 + x tan(5 deg) - 20 rows while the edge stays inside them.
    profile = scene.radiance.reshape(64, 4, 200, 4).mean(axis=(1, 3))  # per pixel
    edge_rows = profile[20:50].sum(axis=0)
    columns = np.arange(200)
    slope = np.polyfit(columns[10:150], edge_rows[10:150], 1)[0]
    assert slope == pytest.approx(math.tan(math.radians(5)), rel=1e-3)
    assert edge_rows[0] == pytest.approx(12.0 + 0.5 * math.tan(math.radians(5)), abs=1e-9)


def test_edge_texture_cols_put_the_natural_texture_in_the_central_columns() -> None:
    edges = build("edge:photons=1,period=64,oversample=4,x_oversample=1", columns=200)
    mixed = build(
        "edge:photons=1,period=64,oversample=4,x_oversample=1,texture_cols=60", columns=200
    )
    texture = build("natural:photons=1,period=64,seed=1", columns=60)
    # Columns 70..129 (the central 60 of 200) hold the texture, one value per pixel spread over
    # its 4 cells along; the edges stay either side.
    assert np.array_equal(mixed.radiance[:, :70], edges.radiance[:, :70])
    assert np.array_equal(mixed.radiance[:, 130:], edges.radiance[:, 130:])
    assert np.array_equal(mixed.radiance[::4, 70:130], texture.radiance)
    assert np.array_equal(mixed.radiance[3::4, 70:130], texture.radiance)
    with pytest.raises(SceneSpecError, match="unknown scene key 'texture_cols' for bars"):
        SceneSpec.parse("bars:texture_cols=8")


def test_star_and_ramp() -> None:
    star = build("star:photons=1,size=64,oversample=2")
    assert star.period_rows == 64 and star.width_cols == 64
    assert star.radiance.mean() == pytest.approx(0.5, abs=0.01)
    ramp = build("ramp:photons=8,period=8,oversample=1")
    assert ramp.radiance[:, 0].tolist() == [0.5, 1.5, 2.5, 3.5, 4.5, 5.5, 6.5, 7.5]


def test_image_files_become_grey_cells(tmp_path: Path) -> None:
    grey8 = np.array([[0, 255], [51, 102]], dtype=np.uint8)
    cv2.imwrite(str(tmp_path / "g8.png"), grey8)
    scene = build(f"image:path={tmp_path / 'g8.png'},photons=10")
    assert scene.radiance.tolist() == [[0.0, 10.0], [2.0, 4.0]]
    grey16 = np.array([[65535, 0]], dtype=np.uint16)
    cv2.imwrite(str(tmp_path / "g16.png"), grey16)
    assert build(f"image:path={tmp_path / 'g16.png'},photons=2").radiance.tolist() == [[2.0, 0.0]]
    colour = np.zeros((1, 2, 3), dtype=np.uint8)
    colour[0, 1] = 255
    cv2.imwrite(str(tmp_path / "c.png"), colour)
    assert build(f"image:path={tmp_path / 'c.png'},photons=1").radiance.tolist() == [[0.0, 1.0]]
    with pytest.raises(SceneSpecError, match="cannot read image"):
        build(f"image:path={tmp_path / 'missing.png'}")


# -- the integral ----------------------------------------------------------------------------------


def brute_force(
    cells: np.ndarray, over: int, row: int, col: int, d0: float, d1: float, q: float, T: float
) -> float:
    """Photons by direct numerical integration: midpoint rule in time (20000 steps), exact
    static overlap of the aperture square with the cells at each instant."""
    ny, nx = cells.shape
    steps = 20000
    d = d0 + (d1 - d0) * (np.arange(steps) + 0.5) / steps
    y_lo = row + (1 - q) / 2 + d
    # Across track: overlap of [col + (1-q)/2, col + (1+q)/2] with each column cell.
    x_edges = np.arange(nx + 1) / over
    x_over = np.clip(
        np.minimum(x_edges[1:], col + (1 + q) / 2) - np.maximum(x_edges[:-1], col + (1 - q) / 2),
        0.0,
        None,
    )
    line = cells @ x_over  # photons/s per row length, per cell along track
    # Along track: the periodic tiling; overlap of [y_lo, y_lo + q] with every cell near it.
    first = int(np.floor(min(y_lo.min(), 0) * over)) - 1
    last = int(np.ceil((y_lo.max() + q) * over)) + 1
    total = np.zeros(steps)
    for cell in range(first, last + 1):
        lo, hi = cell / over, (cell + 1) / over
        overlap = np.clip(np.minimum(hi, y_lo + q) - np.maximum(lo, y_lo), 0.0, None)
        total += overlap * line[cell % ny]
    return float(total.mean() * T)


def test_integral_is_exact_against_direct_integration() -> None:
    rng = np.random.default_rng(3)
    over = 3
    cells = rng.uniform(0.0, 1000.0, size=(5 * over, 4 * over))  # 5 rows x 4 columns, tiled
    scene = Scene(cells, oversample=over)
    rows = 6
    d0 = np.array([0.0, 0.3, -2.7, 1.1, 0.25, 7.9])
    d1 = np.array([0.0, 0.31, 0.4, -1.6, 0.25 + 1e-9, 14.2])  # static, small, large, backwards
    q, T = 0.83, 2e-3
    got = scene.integrate(2, rows, 4, d0, d1, None, T, q, first_col=1, dtype=np.float64)
    assert got.shape == (rows, 4)
    for i in range(rows):
        for j in range(4):
            want = brute_force(cells, over, 2 + i, (1 + j) % 4, d0[i], d1[i], q, T)
            assert got[i, j] == pytest.approx(want, rel=2e-6), (i, j)


def test_flat_field_collects_level_times_area_times_time_whatever_the_motion() -> None:
    scene = Scene(np.full((1, 1), 7.0))
    d0 = np.array([0.0, 0.5, 3.0])
    d1 = np.array([0.0, 2.25, -8.0])
    got = scene.integrate(10, 3, 5, d0, d1, None, 0.5, 0.9, dtype=np.float64)
    assert np.allclose(got, 7.0 * 0.9 * 0.9 * 0.5, rtol=1e-12)
    assert got.dtype == np.float64
    assert scene.integrate(10, 3, 5, d0, d1, None, 0.5, 0.9).dtype == np.float32


def test_motion_weights_conserve_the_aperture() -> None:
    rng = np.random.default_rng(0)
    start = rng.uniform(-50, 50, 200)
    end = start + rng.uniform(-20, 20, 200)
    end[:20] = start[:20]
    origin, weights = motion_weights(start, end, 3.3)
    assert np.allclose(weights.sum(axis=1), 3.3, rtol=1e-12)
    assert weights.min() >= -1e-12
    assert np.all(origin == np.floor(np.minimum(start, end)))


def test_scene_tiles_along_and_across_track() -> None:
    rng = np.random.default_rng(1)
    scene = Scene(rng.uniform(0, 1, (24, 10)), oversample=2)  # 12 rows x 5 columns
    assert (scene.period_rows, scene.width_cols) == (12.0, 5)
    a = scene.integrate(0, 4, 5, 0.3, 0.9, None, 1.0, 0.7, dtype=np.float64)
    b = scene.integrate(0, 4, 5, 12.3, 12.9, None, 1.0, 0.7, dtype=np.float64)
    c = scene.integrate(12, 4, 10, 0.3, 0.9, None, 1.0, 0.7, dtype=np.float64)
    assert np.allclose(a, b, rtol=1e-10) and np.allclose(np.hstack([a, a]), c, rtol=1e-10)


def test_lateral_shift_and_drift() -> None:
    rng = np.random.default_rng(2)
    pattern = rng.uniform(0, 1, (8, 16))
    scene = Scene.from_pattern(pattern, 100.0)
    base = scene.integrate(0, 8, 16, 0.0, 0.0, None, 1.0, 1.0, dtype=np.float64)
    # Column x sees scene column x + s: an integer shift is a roll of the columns.
    shifted = scene.integrate(0, 8, 16, 0.0, 0.0, np.full(8, 3.0), 1.0, 1.0, dtype=np.float64)
    assert np.allclose(shifted, np.roll(base, -3, axis=1), rtol=1e-12)
    half = scene.integrate(0, 8, 16, 0.0, 0.0, np.full(8, 0.5), 1.0, 1.0, dtype=np.float64)
    assert np.allclose(half, (base + np.roll(base, -1, axis=1)) / 2, rtol=1e-12)
    # Drift: tan(beta) columns per row of along-track displacement, at mid-exposure.
    beta = math.degrees(math.atan(0.25))
    drifting = Scene.from_pattern(pattern, 100.0, drift_deg=beta)
    moved = drifting.integrate(0, 8, 16, 8.0, 8.0, None, 1.0, 1.0, dtype=np.float64)
    assert np.allclose(moved, np.roll(base, -2, axis=1), rtol=1e-12)  # 8 rows -> 2 columns


# -- the optics' blur (blur_px) ----------------------------------------------------------------


def test_blur_px_is_a_key_of_every_kind_and_is_checked() -> None:
    spec = SceneSpec.parse("bars:blur_px=1.5,lux=3")
    assert spec.blur_px == 1.5 and SceneSpec.parse(spec.describe()) == spec
    assert SceneSpec.parse("flat:blur_px=2").blur_px == 2.0  # no effect on a flat field
    assert SceneSpec().blur_px == 0.0  # best focus by default
    with pytest.raises(SceneSpecError, match=r"scene blur_px=-1 is invalid: blur_px \(Gaussian"):
        SceneSpec.parse("bars:blur_px=-1")


def test_blur_is_a_gaussian_of_sigma_blur_px_pixels_on_the_cells() -> None:
    # One bright cell in a dark periodic scene, 4 cells per pixel both ways: the blurred scene is
    # a Gaussian of standard deviation 2 px = 8 cells along and across, with the light kept.
    sharp = np.zeros((256, 256))
    sharp[128, 128] = 1.0
    spot = blur_cells(sharp, 2.0, oversample=4, x_oversample=4)
    assert spot.sum() == pytest.approx(1.0, rel=1e-12)
    offsets = np.arange(256) - 128.0
    along = spot.sum(axis=1)
    across = spot.sum(axis=0)
    assert math.sqrt(float(np.sum(along * offsets**2))) == pytest.approx(8.0, rel=1e-6)
    assert math.sqrt(float(np.sum(across * offsets**2))) == pytest.approx(8.0, rel=1e-6)
    assert spot.min() >= 0.0


def test_blurred_bars_lose_modulation_as_the_gaussian_mtf_says() -> None:
    # Bars varying along track: the fundamental of the 0.1 cycles/pixel group (a 10-row period)
    # keeps exp(-2 pi^2 sigma^2 f^2) of its amplitude; blur 0 is the sharp scene itself.
    spec = SceneSpec(kind="bars", photons=1000.0)
    sharp = build_scene(spec, columns=700, pitch_m=11e-6, default_photons=1.0)
    same = build_scene(
        SceneSpec(kind="bars", photons=1000.0, blur_px=0.0),
        columns=700,
        pitch_m=11e-6,
        default_photons=1.0,
    )
    assert np.array_equal(sharp.radiance, same.radiance)
    sigma = 1.2
    blurry = build_scene(
        SceneSpec(kind="bars", photons=1000.0, blur_px=sigma),
        columns=700,
        pitch_m=11e-6,
        default_photons=1.0,
    )
    assert blurry.radiance.shape == sharp.radiance.shape
    assert blurry.radiance.mean() == pytest.approx(sharp.radiance.mean(), rel=1e-9)
    column = 150 * sharp.x_oversample  # inside the second group (0.1 cy/px) of seven
    period_cells = sharp.radiance.shape[0]  # 40 rows x 4 cells
    k = period_cells // (10 * sharp.oversample)  # the 0.1 cy/px fundamental's index: 4
    a_sharp = abs(np.fft.rfft(sharp.radiance[:, column])[k])
    a_blur = abs(np.fft.rfft(blurry.radiance[:, column])[k])
    assert a_blur / a_sharp == pytest.approx(math.exp(-2 * math.pi**2 * sigma**2 * 0.1**2), 1e-9)
