"""Image motion compensation on the simulated full-frame ftf5066 (docs/physics.md §7, REN15 §3).

The campaign ``motion_compensation`` in its --quick form through `camctl campaign run --sim`
(its own `camd serve --sim` with the ftf5066 profile: the RS-422 link, the IMC registers over
the SPI bridge, USB frames, stares recorded to HDF5, the report), its numbers against the
closed forms; then the camera's full-frame IMC rendering against closed forms and the two
point-beam models (the exact one of camd.timing.imc and the time-stepped charge-transfer model
of firmware_models.ccd_imc), which must agree with the image the camera renders.

Tolerances: the renders below are noise-free (``expected_electrons``, float64), so the camera
agrees with the exact model to rounding (1e-9 where the scene's cells put the edge exactly;
tests say where they do not). The campaign's frames carry noise; its checks and the asserts
here allow what the scene's cells and the noise explain (comments at each).
"""

from __future__ import annotations

import math
from fractions import Fraction
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import pytest

from camd.analysis.imc import edge_line_modulations, periodic_edge_sharpness
from camd.analysis.sharpness import grey_gradient_sharpness
from camd.datafile import Sourced
from camd.sensor.profile import CameraProfile, load_profile
from camd.sensor.regmap import load_register_map
from camd.sensor.timing_view import reset_timing
from camd.timing.imc import (
    MAX_CHARGE_SHIFTS,
    ImcMode,
    charge_shift_schedule,
    electrode_step_modulation,
    mean_electrode_step_modulation,
    mean_row_step_modulation,
    point_beam_means,
    point_beam_profile,
    profile_modulation,
    row_step_modulation,
)
from firmware_models import ccd_imc
from firmware_models.camera import CameraModel
from firmware_models.camera_imc import merge_pieces
from firmware_models.scene import Scene, build_scene
from firmware_models.scene_spec import SceneSpec, SceneSpecError
from firmware_models.sensor import SensorModel
from tests.campaign_support import report_images, run_shipped

W = 9e-6  # REN15's pixel (docs/physics.md §7)
CLOCK_HZ = 25e6  # ftf5066.toml timing.clock_hz: IMC_STEP counts it
EXPOSURE_S = 0.01  # 40 lines x 250 us at reset

# <sum q^2> of the point-beam profile over a uniform offset, integrated by hand from the
# profiles of docs/imc.md (x = a / w). Row steps, one row time: (1 - x)^2 / 2, 1/2 + x - x^2,
# x^2 / 2 -> 2 * 1/20 + 9/20 = 11/20. Electrode steps: (7/8 - x), (x + 1/8) for x <= 3/4, then
# 2 (1 - x)^2, 1 - 2 (1 - x)^2 - 2 (x - 3/4)^2, 2 (x - 3/4)^2 -> 841/1280. Still: 2/3.
SQUARE_SUM_ROW = Fraction(11, 20)
SQUARE_SUM_ELECTRODE = Fraction(841, 1280)


# -- the campaign, through the CLI -----------------------------------------------------------------


def test_motion_compensation_campaign_quick(tmp_path: Path) -> None:
    out = tmp_path / "run"
    doc = run_shipped("motion_compensation", out)
    r = doc["results"]
    # The result names and shapes (the quick form's two speeds).
    assert r["speed_mm_s"] == [0.9, 1.5]
    assert set(r["sharpness"]) == {"none", "row", "electrode"}
    assert all(len(v) == 2 for v in r["sharpness"].values())
    assert set(r["modulation_mean"]) == {"row", "electrode"}
    # Clocking: dt = w / (p v) in 40 ns clocks; the stage at v / (f / H) = v / 0.3.
    assert r["imc_step_clocks"] == [62500, 37500]
    assert r["stage_speed_m_s"] == pytest.approx([0.003, 0.005], rel=1e-12)
    # At 0.9 mm/s the image moves one pixel in the 10 ms exposure: the mean modulations are
    # the closed forms' means. The scene's cells (1/16 row) lower them by 0.0013 (docs/imc.md);
    # over ~1e5 edges the noise is below 0.001: 0.004 allows both three times over.
    assert r["modulation_mean"]["row"] == pytest.approx(1 / 3, abs=0.004)
    assert r["modulation_mean"]["electrode"] == pytest.approx(47 / 96, abs=0.004)
    # Sharpness at 0.9 mm/s against the hand-integrated profiles: G = 8 c^2 <sum q^2> / P
    # (P = 16, c = 1) plus the measured noise floor; the cells cost 0.2 %, allow 1 %.
    floor = r["sharpness_floor"][0]  # per mode: none, row, electrode
    expect = {
        "none": 8 * float(SQUARE_SUM_ROW) / 16,  # one row time: the row step falls at its end
        "row": 8 * float(SQUARE_SUM_ROW) / 16,
        "electrode": 8 * float(SQUARE_SUM_ELECTRODE) / 16,
    }
    for i, mode in enumerate(("none", "row", "electrode")):
        assert r["sharpness"][mode][0] == pytest.approx(expect[mode] + floor[i], rel=0.01), mode
    # At 1.5 mm/s (1.67 pixels of motion) the three modes separate as the physics says.
    s = {mode: values[1] for mode, values in r["sharpness"].items()}
    assert s["electrode"] > 1.1 * s["row"] > 1.1 * 1.1 * s["none"]
    for mode in ("none", "row", "electrode"):
        assert r["sharpness_error"][mode] == pytest.approx([0.0, 0.0], abs=0.01)
    assert len(report_images(out)) == 2
    md = (out / "report.md").read_text()
    assert "| modulation_mean.row | modulation_closed_form.row |" in md
    assert "datasheet-class assumptions" in md  # the assumptions are listed


# -- the simulated camera's full-frame IMC rendering ---------------------------------------------


def quiet_profile(**values: float) -> CameraProfile:
    """The ftf5066 profile without fixed pattern and dark current (noise-free geometry)."""
    update = {"prnu_fraction": 0.0, "dsnu_e_per_s": 0.0, "dark_current_e_per_s": 0.0, **values}
    fields = {k: Sourced[Any](value=v, assumed="test") for k, v in update.items()}
    return load_profile("ftf5066").model_copy(update=fields)


def make_camera(rows: int = 64, *, profile: CameraProfile | None = None) -> CameraModel:
    sensor = SensorModel(load_register_map("ftf5066"))
    camera = CameraModel(profile or quiet_profile(), sensor, seed=5)
    set_reg(camera, "WIN_ROWS", rows)
    return camera


def set_reg(camera: CameraModel, name: str, value: int) -> None:
    """Write a register over the simulated SPI bus, as the FPGA would."""
    sensor = camera.sensor
    sensor.spi_write(sensor.regmap.register(name).address, value)


def set_imc(camera: CameraModel, mode: ImcMode, clocks: int) -> None:
    modes = {"none": 0, "row": 1, "electrode": 2}
    set_reg(camera, "IMC_CTRL", modes[mode])
    set_reg(camera, "IMC_STEP_HI", clocks >> 16)
    set_reg(camera, "IMC_STEP_LO", clocks & 0xFFFF)


def set_image_speed(camera: CameraModel, image_m_s: float) -> None:
    camera.stage_speed_m_s = image_m_s / camera.profile.magnification.value


def slanted_scene(period: int, bright_rows: float, tan: float, cols: int, over: int) -> Scene:
    """Bright where ``(y - x tan) mod period < bright_rows``: exact cell averages along the
    track (``over`` cells per row), one cell per column (its centre), 1e7 photons/pixel/s."""
    y = np.arange(period * over + 1) / over
    x = np.arange(cols) + 0.5

    def bright_up_to(u: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        whole = np.floor(u / period)
        result: npt.NDArray[np.float64] = whole * bright_rows + np.clip(
            u - whole * period, 0.0, bright_rows
        )
        return result

    lo = y[:-1, None] - x[None, :] * tan
    hi = y[1:, None] - x[None, :] * tan
    return Scene(
        (bright_up_to(hi) - bright_up_to(lo)) * over * 1e7, oversample=over, x_oversample=1
    )


@pytest.mark.parametrize("mode", ["none", "row", "electrode"])
def test_moving_flat_field_keeps_its_mean(mode: ImcMode) -> None:
    """Clocking moves charge, it does not make or lose any: a flat field gives QE L T."""
    camera = make_camera(16)
    camera.set_scene("flat:photons=2e6")
    set_image_speed(camera, 1.5e-3)
    set_imc(camera, mode, 37500)
    electrons = camera.expected_electrons(2.0, dtype=np.float64)
    expected = camera.profile.quantum_efficiency.value * 2e6 * EXPOSURE_S
    # The response map (QE) is float32: 2e-8 of rounding.
    assert electrons == pytest.approx(np.full(electrons.shape, expected), rel=1e-7)


@pytest.mark.parametrize(
    ("mode", "width_px"),
    [("none", 10.0), ("row", 1.0), ("electrode", 0.25)],
)
def test_moving_edge_blur_width(mode: ImcMode, width_px: float) -> None:
    """A moving edge's smear: v T without compensation, w with row steps when T >> dt, w / 4
    with electrode steps (docs/physics.md §7). At 9 mm/s a 10 ms exposure is 10 row times (whole
    sawtooth teeth). Measured as ``sqrt(12 (var - 1/6))`` of the edge's line profile (the
    first difference along the column), averaged over columns that sample the edge's offset
    uniformly: a uniform smear of width ``L`` has variance ``L^2 / 12``, and the pixel box and
    the sampling add 1/12 each."""
    camera = make_camera(128)
    camera.set_scene(slanted_scene(64, 32.0, 1 / 64, 256, 256))
    set_image_speed(camera, 9e-3)
    set_imc(camera, mode, 6250)  # dt = 9 um / (4 x 9 mm/s) = 250 us
    image = camera.expected_electrons(3.0, dtype=np.float64)[:, :256]
    variances = []
    for column in np.diff(image, axis=0).T:
        for lobe in (column, -column):
            # Runs of positive differences: one per edge (the plateaus between are flat).
            inside = np.concatenate([[0], lobe > 1e-9 * np.abs(column).max(), [0]])
            change = np.diff(inside.astype(np.int8))
            starts, stops = np.flatnonzero(change == 1), np.flatnonzero(change == -1)
            for start, stop in zip(starts, stops, strict=True):
                if start == 0 or stop == lobe.size:
                    continue  # cut by the window: part of the profile is missing
                q = lobe[start:stop] / lobe[start:stop].sum()
                k = np.arange(q.size)
                variances.append(float(np.sum(q * k * k) - np.sum(q * k) ** 2))
    assert len(variances) > 700  # about 4 edges x 256 columns, minus those cut
    width = math.sqrt(12 * (np.mean(variances) - 1 / 6))
    # 64 equally spaced offsets sample the average: 1 % covers that quadrature error.
    assert width == pytest.approx(width_px, rel=0.01)


@pytest.mark.parametrize(
    ("mode", "closed_form"),
    [("row", row_step_modulation), ("electrode", electrode_step_modulation)],
)
def test_line_target_gives_the_point_beam_modulation(mode: ImcMode, closed_form: Any) -> None:
    """A one-row line moving one pixel in the exposure, through the camera: each column's
    profile has the closed-form modulation at that column's offset, which agrees with the
    time-stepped charge-transfer model (ccd_imc) too. The line's lower edge sits at scene row
    ``x tan`` in column ``x``; with the image displaced by ``d0`` rows when the exposure
    starts, the beam starts ``a = (d0 - x tan) mod 1`` pixels from a packet edge, counted in
    the direction the image moves (towards row 0)."""
    cols, tan = 512, 1 / 128
    camera = make_camera(64)
    camera.set_scene(slanted_scene(32, 1.0, tan, cols, 256))
    set_image_speed(camera, 0.9e-3)  # one pixel in 10 ms
    set_imc(camera, mode, 62500)
    t_s = 1.234
    image = camera.expected_electrons(t_s, dtype=np.float64)[:, :cols]
    d0 = float(camera.image_rows(t_s - EXPOSURE_S))
    a = np.mod(d0 - (np.arange(cols) + 0.5) * tan, 1.0) * W
    peak = np.argmax(image[4:-4], axis=0) + 4
    profiles = np.stack([image[k - 3 : k + 4, j] for j, k in enumerate(peak)])
    measured = profile_modulation(profiles)
    assert np.abs(measured - closed_form(a, W)).max() < 1e-9
    stepped = ccd_imc.point_beam_modulation(a, method=mode, time_steps_per_cycle=400)
    assert np.abs(measured - stepped).max() < 5e-5  # the time-stepped model's own error


def test_mismatched_clock_agrees_with_the_exact_model() -> None:
    """IMC_STEP 2.4 % slow for 0.9 mm/s (64000 clocks, not 62500): the sawtooth drifts and its
    pieces differ; the camera's profiles are still the exact model's, column by column."""
    cols, tan = 256, 1 / 64
    camera = make_camera(64)
    camera.set_scene(slanted_scene(32, 1.0, tan, cols, 256))
    set_image_speed(camera, 1.5e-3)
    set_imc(camera, "electrode", 64000)
    t_s = 0.5
    image = camera.expected_electrons(t_s, dtype=np.float64)[:, :cols]
    d0 = float(camera.image_rows(t_s - EXPOSURE_S))
    a = np.mod(d0 - (np.arange(cols) + 0.5) * tan, 1.0) * W
    _, exact = point_beam_profile(
        a, pixel_m=W, image_velocity_m_s=1.5e-3, exposure_s=EXPOSURE_S, mode="electrode",
        electrode_interval_s=64000 / CLOCK_HZ,
    )  # fmt: skip
    peak = np.argmax(image[4:-4], axis=0) + 4
    profiles = np.stack([image[k - 3 : k + 4, j] for j, k in enumerate(peak)])
    assert np.abs(profile_modulation(profiles) - profile_modulation(exact)).max() < 1e-9
    # The brightest packet's share of the beam, too (the profile itself, not only its shape).
    share = profiles.max(axis=1) / profiles.sum(axis=1)
    assert np.abs(share - exact.max(axis=1)).max() < 1e-9


def test_rendered_edge_measures_like_the_models() -> None:
    """The campaign's target (a 1 deg slanted edge, period 16, 16 cells per row), rendered
    noise-free at 1.5 mm/s: the edge modulations average to the exact model's and the
    grey-gradient sharpness is 8 <sum q^2> / P; both to the cell smear's 0.2 % (docs/imc.md)."""
    camera = make_camera(64)
    camera.set_scene("edge:photons=1.4e7,period=16,angle_deg=1,oversample=16,x_oversample=1")
    set_image_speed(camera, 1.5e-3)
    for mode in ("none", "row", "electrode"):
        set_imc(camera, mode, 37500)
        image = camera.expected_electrons(1.0, dtype=np.float64)
        model = point_beam_means(
            pixel_m=W, image_velocity_m_s=1.5e-3, exposure_s=EXPOSURE_S, mode=mode
        )
        assert edge_line_modulations(image).mean() == pytest.approx(model.modulation, abs=0.002)
        sharpness = grey_gradient_sharpness(image, axis="along")
        assert sharpness == pytest.approx(periodic_edge_sharpness(model.square_sum, 16), rel=0.004)


def test_imc_registers_reset_and_decode() -> None:
    camera = make_camera()
    assert camera.imc() == ("none", 62500 / CLOCK_HZ, 4)  # reset: off, dt for 0.9 mm/s, p = 4
    set_imc(camera, "electrode", 312500)  # 12.5 ms needs the high word
    assert camera.imc() == ("electrode", 0.0125, 4)
    other = CameraModel(load_profile("uvccd"), SensorModel(load_register_map("uvccd")))
    assert other.imc()[0] == "none"  # a sensor without IMC registers never compensates


def test_large_array_fixed_pattern_is_drawn_per_band_consistently() -> None:
    """The 33 Mpixel array's PRNU map is drawn per 256-row band: the same rows read through
    different windows (one crossing a band edge) see the same pattern, and it is 1 % rms."""
    profile = load_profile("ftf5066")
    flat = "flat:photons=1e7"
    a = make_camera(32, profile=profile)
    set_reg(a, "WIN_START", 240)  # rows 240 .. 271: bands 0 and 1
    a.set_scene(flat)
    b = make_camera(16, profile=profile)
    set_reg(b, "WIN_START", 256)  # rows 256 .. 271: band 1 alone
    b.set_scene(flat)
    ea = a.expected_electrons(1.0, dtype=np.float64)
    eb = b.expected_electrons(1.0, dtype=np.float64)
    assert np.array_equal(ea[16:], eb)
    assert sorted(a._frames.fixed.bands) == [0, 1] and sorted(b._frames.fixed.bands) == [
        1
    ]  # no other band
    relative = ea / ea.mean()
    assert relative.std() == pytest.approx(profile.prnu_fraction.value, rel=0.05)


def test_edge_scene_with_one_cell_per_column() -> None:
    """The campaign's target: 16 cells per row along the track, one per column across, the
    cell values the exact bright fraction of the edge at the column's centre."""
    spec = SceneSpec.parse("edge:period=16,angle_deg=1,oversample=16,x_oversample=1")
    assert spec.describe() == "edge:oversample=16,angle_deg=1,period=16,x_oversample=1"
    scene = build_scene(spec, columns=5000, pitch_m=W, default_photons=1.0)
    assert scene.radiance.shape == (16 * 16, 5000) and scene.x_oversample == 1
    # Column 0's edge is at y = 0.5 tan(1 deg) = 0.00873 rows: the first cell (1/16 row) is
    # bright from there on, and half of every period is bright.
    edge_y = 0.5 * math.tan(math.radians(1.0))
    assert scene.radiance[0, 0] == pytest.approx((1 / 16 - edge_y) * 16, rel=1e-12)
    assert scene.radiance[:, 0].sum() / 16 == pytest.approx(8.0, rel=1e-12)
    with pytest.raises(SceneSpecError, match="unknown scene key 'x_oversample' for bars"):
        SceneSpec.parse("bars:x_oversample=1")


# -- the clocking schedule and the exact model ----------------------------------------------------


def test_charge_shift_schedule_counts_the_moves_inside_the_exposure() -> None:
    electrode = charge_shift_schedule(0.01, 0.0025, "electrode")
    # Moves at 2.5, 5 and 7.5 ms; the one at 10 ms falls at the end and moves nothing.
    assert electrode.bounds_s == pytest.approx([0.0, 0.0025, 0.005, 0.0075, 0.01])
    assert electrode.electrodes.tolist() == [0, 1, 2, 3]
    assert electrode.shift_px.tolist() == [0.0, 0.25, 0.5, 0.75]
    row = charge_shift_schedule(0.01, 0.0015, "row")  # a row every 6 ms
    assert row.bounds_s == pytest.approx([0.0, 0.006, 0.01]) and row.electrodes.tolist() == [0, 4]
    assert charge_shift_schedule(0.01, 0.0025, "row").pieces == 1  # first row step at the end
    assert charge_shift_schedule(0.01, 1e-9, "none").pieces == 1


@pytest.mark.parametrize(
    ("args", "message"),
    [
        ((0.01, 0.001, "diagonal"), "mode must be one of none, row, electrode"),
        ((0.0, 0.001, "row"), "exposure_s must be > 0"),
        ((0.01, 0.0, "electrode"), "electrode_interval_s must be > 0"),
        ((10.0, 1e-6, "electrode"), f"more than the {MAX_CHARGE_SHIFTS} modelled"),
    ],
)
def test_charge_shift_schedule_refusals(args: tuple[Any, ...], message: str) -> None:
    with pytest.raises(ValueError, match=message):
        charge_shift_schedule(*args)


def test_exact_model_reproduces_the_closed_forms_and_their_means() -> None:
    a = (np.arange(997) + 0.5) * (W / 997)
    forms: list[tuple[ImcMode, Any]] = [
        ("row", row_step_modulation),
        ("electrode", electrode_step_modulation),
    ]
    for mode, closed_form in forms:
        for cycles in (1, 3):  # a whole number of row times: identical cycles
            _, q = point_beam_profile(
                a, pixel_m=W, image_velocity_m_s=0.9e-3, exposure_s=cycles * EXPOSURE_S,
                mode=mode,
            )  # fmt: skip
            assert np.abs(q.sum(axis=-1) - 1.0).max() < 1e-12
            assert np.abs(profile_modulation(q) - closed_form(a, W)).max() < 1e-12
    row = point_beam_means(pixel_m=W, image_velocity_m_s=0.9e-3, exposure_s=EXPOSURE_S, mode="row")
    electrode = point_beam_means(
        pixel_m=W, image_velocity_m_s=0.9e-3, exposure_s=EXPOSURE_S, mode="electrode"
    )
    # Midpoint rule over 1024 offsets: error ~ 1 / 1024^2.
    assert row.modulation == pytest.approx(mean_row_step_modulation(), abs=1e-5)
    assert electrode.modulation == pytest.approx(mean_electrode_step_modulation(), abs=1e-5)
    assert row.square_sum == pytest.approx(float(SQUARE_SUM_ROW), abs=1e-5)
    assert electrode.square_sum == pytest.approx(float(SQUARE_SUM_ELECTRODE), abs=1e-5)
    still = point_beam_means(pixel_m=W, image_velocity_m_s=0.0, exposure_s=EXPOSURE_S, mode="none")
    assert still.square_sum == pytest.approx(2 / 3, abs=1e-5) and still.modulation == pytest.approx(
        0.5, abs=1e-5
    )  # (1 - x)^2 + x^2 and |1 - 2x| averaged


@pytest.mark.parametrize("mode", ["none", "row", "electrode"])
def test_exact_model_agrees_with_the_time_stepped_model(mode: ccd_imc.Method) -> None:
    """Two independent integrations of the same geometry (ccd_imc steps time; this one
    integrates each piece in closed form), for 1 and 2 row times of exposure."""
    a = (np.arange(997) + 0.5) * (W / 997)
    for cycles in (1, 2):
        first, exact = point_beam_profile(
            a, pixel_m=W, image_velocity_m_s=0.9e-3, exposure_s=cycles * EXPOSURE_S, mode=mode
        )
        stepped = ccd_imc.point_beam_profile(a, method=mode, exposure_cycles=cycles) / cycles
        aligned = np.zeros_like(stepped)  # ccd_imc's index i is packet i - 1
        for i in range(exact.shape[-1]):
            aligned[:, first + i + 1] += exact[:, i]
        assert np.abs(aligned - stepped).max() < 1e-5  # the stepped model's 400 steps/row


def test_merge_pieces_keeps_the_time_integral() -> None:
    """Identical teeth merge into one piece; many distinct pieces become intervals of constant
    occupation (exact) or, beyond 64, equal bins (approximate within a bin)."""
    teeth = merge_pieces(np.zeros(6), np.full(6, 0.25), np.full(6, 1.5e-3))
    assert len(teeth) == 1 and teeth[0][:2] == (0.0, 0.25)
    assert teeth[0][2] == pytest.approx(9e-3, rel=1e-12)

    def integral(pieces: list[tuple[float, float, float]]) -> float:
        # Time integral of f(r) = sin(3r) + r^2 over linear sweeps (exact antiderivative).
        def anti(r: float) -> float:
            return -math.cos(3 * r) / 3 + r**3 / 3

        return sum(
            tau * (anti(hi) - anti(lo)) / (hi - lo) if hi > lo else tau * (math.sin(3 * lo) + lo**2)
            for lo, hi, tau in pieces
        )

    # 78 distinct pieces between 13 positions, 10 of them still: few intervals, exact.
    grid = np.linspace(0.0, 2.0, 13)
    lo, hi = np.meshgrid(grid, grid, indexing="ij")
    keep = lo <= hi
    start, end = lo[keep], hi[keep]
    tau = np.linspace(0.1, 1.0, start.size)
    pieces = merge_pieces(end, start, tau)  # direction does not matter
    assert len(pieces) <= 64
    reference = integral(list(zip(start.tolist(), end.tolist(), tau.tolist(), strict=True)))
    assert integral(pieces) == pytest.approx(reference, rel=1e-12)
    assert sum(p[2] for p in pieces) == pytest.approx(tau.sum(), rel=1e-12)
    # 300 random pieces: binned onto 64 bins of 1/32 row; the integral to 1e-3.
    rng = np.random.default_rng(1)
    start = rng.uniform(0.0, 2.0, 300)
    end = start + rng.uniform(-0.3, 0.3, 300)
    tau = rng.uniform(0.0, 1.0, 300)
    binned = merge_pieces(start, end, tau)
    assert len(binned) <= 64
    reference = integral(
        [(min(s, e), max(s, e), t) for s, e, t in zip(start, end, tau, strict=True)]
    )
    assert integral(binned) == pytest.approx(reference, rel=1e-3)
    assert sum(p[2] for p in binned) == pytest.approx(tau.sum(), rel=1e-12)


# -- the ftf5066 profile and map ------------------------------------------------------------------


def test_ftf5066_profile_and_map_numbers() -> None:
    profile = load_profile("ftf5066")
    assert profile.pitch_m.value == 9e-6 and profile.shutter.value == "full_frame"
    assert profile.magnification.value == pytest.approx(0.09 / 0.3)  # f / H of REN15's rig
    # K = 18 uV/e- * 4096 / 2 V; the full well stays inside the ADC above the black level.
    k = profile.system_gain_dn_per_e()
    assert k == pytest.approx(18e-6 * 4096 / 2.0, rel=1e-12)
    assert profile.full_well_e.value * k + 100 < profile.adc_max_dn
    timing = reset_timing(load_register_map("ftf5066"))
    assert timing.line_period_s == pytest.approx(50e-6 + 5000 / 25e6, rel=1e-12)
    assert timing.exposure_s == pytest.approx(EXPOSURE_S, rel=1e-12)  # REN15's 10 ms
