"""The simulated camera against the noise model of docs/physics.md §5 and exact motion geometry.

Statistics: every noise test uses 200 frames and estimates a per-pixel temporal variance over
many pixels, so the relative standard error of a noise estimate is about
``1 / sqrt(2 * pixels * 199)`` (0.11 % for 2048 pixels). The tolerances (2 % on noise, 0.5-2 %
on means) are at least ten standard errors wide: a failure is a model error, not bad luck (and
the seeds are fixed, so the numbers do not change between runs anyway).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from camd.analysis import sensor_noise as model
from camd.sensor.profile import CameraProfile, Sourced, load_profile
from camd.sensor.regmap import load_register_map
from camd.tdi import bin2x2
from firmware_models.camera import CameraModel
from firmware_models.lvds import ramp_frame
from firmware_models.scene import Scene
from firmware_models.sensor import SensorModel

FRAMES = 200


def set_reg(sensor: SensorModel, name: str, value: int) -> None:
    """Write a register over the simulated SPI bus, as the FPGA would."""
    sensor.spi_write(sensor.regmap.register(name).address, value)


def set_exposure_lines(sensor: SensorModel, lines: int) -> None:
    set_reg(sensor, "EXP_HI", lines >> 16)
    set_reg(sensor, "EXP_LO", lines & 0xFFFF)


def variant(name: str, **values: float) -> CameraProfile:
    """A shipped profile with some values replaced (for geometry tests: no fixed pattern)."""
    profile = load_profile(name)
    update = {k: Sourced[Any](value=v, assumed="test variant") for k, v in values.items()}
    return profile.model_copy(update=update)


def make_camera(
    name: str, *, seed: int = 0, profile: CameraProfile | None = None, rows: int | None = None
) -> CameraModel:
    sensor = SensorModel(load_register_map(name))
    if rows is not None:
        set_reg(sensor, "WIN_ROWS", rows)
    return CameraModel(profile or load_profile(name), sensor, seed=seed)


def stack(camera: CameraModel, frames: int = FRAMES, period_s: float = 0.01) -> np.ndarray:
    return np.stack([camera.render(k * period_s) for k in range(frames)]).astype(np.float64)


def temporal_noise(frames: np.ndarray) -> float:
    """Root of the mean (over pixels) unbiased per-pixel temporal variance."""
    return float(np.sqrt(frames.var(axis=0, ddof=1).mean()))


# -- flat field and dark statistics -----------------------------------------------------------------


def test_flat_field_mean_and_temporal_noise_match_the_model() -> None:
    camera = make_camera("hr400", seed=11, rows=32)
    set_exposure_lines(camera.sensor, 100)  # 2.052 ms
    p = camera.profile
    exposure_s = camera.sensor.timing().exposure_s
    photons = 30000 / (p.quantum_efficiency.value * p.fill_factor.value * exposure_s)
    camera.set_scene(f"flat:photons={photons}")
    frames = stack(camera)[:, :, :64]  # a 32 x 64 region
    k_dn = p.system_gain_dn_per_e()
    signal_e = p.quantum_efficiency.value * p.fill_factor.value * photons * exposure_s
    dark_e = p.dark_current_e_per_s.value * exposure_s
    black = 100.0  # OFFSET at reset, 1 DN per code
    mean_dn = model.mean_signal_dn(signal_e, dark_e, k_dn, black)
    noise_dn = model.temporal_noise_dn(signal_e, dark_e, p.read_noise_e.value, k_dn)
    assert signal_e == pytest.approx(30000)
    assert frames.mean() == pytest.approx(mean_dn, rel=0.005)  # 1328.8 DN
    assert temporal_noise(frames) == pytest.approx(noise_dn, rel=0.02)  # 7.26 DN
    # The YE23 estimator (divides by A) agrees, with its (A-1)/A bias.
    ye23 = float(np.sqrt((model.emva_temporal_noise_dn(frames) ** 2).mean()))
    assert ye23 == pytest.approx(noise_dn * math.sqrt((FRAMES - 1) / FRAMES), rel=0.02)


def test_dark_noise_and_dark_current_match_the_model() -> None:
    """uvccd: 5.4 LSB at the staring settings; at 40 degC and 1 s the dark charge shows."""
    camera = make_camera("uvccd", seed=5, rows=32)
    camera.set_scene(Scene(np.zeros((1, 1))))
    p = camera.profile
    k_dn = p.system_gain_dn_per_e()
    black = 200.0
    staring = stack(camera)
    exposure_s = camera.sensor.timing().exposure_s
    dark_e = p.dark_current_e_per_s.value * exposure_s
    assert temporal_noise(staring) == pytest.approx(5.4, rel=0.02)
    assert temporal_noise(staring) == pytest.approx(
        model.dark_noise_dn(dark_e, p.read_noise_e.value, k_dn), rel=0.02
    )
    set_exposure_lines(camera.sensor, 9910)  # 1.0000 s
    camera.temperature_degc = 40.0
    exposure_s = camera.sensor.timing().exposure_s
    rate = model.dark_current_e_per_s(
        p.dark_current_e_per_s.value,
        p.dark_reference_temp_degc.value,
        p.dark_doubling_temp_degc.value,
        40.0,
    )
    assert rate == pytest.approx(100 * 2 ** (20 / 6))  # 1008 e-/s
    dark_e = rate * exposure_s
    hot = stack(camera)
    assert hot.mean() - black == pytest.approx(k_dn * dark_e, rel=0.02)  # 82.6 DN
    noise = model.dark_noise_dn(dark_e, p.read_noise_e.value, k_dn)
    assert noise == pytest.approx(5.99, abs=0.01)  # vs 5.40 without dark charge
    assert temporal_noise(hot) == pytest.approx(noise, rel=0.02)


def test_full_well_and_adc_clipping() -> None:
    camera = make_camera("hr400", rows=8)
    camera.set_scene("flat:photons=1e12")
    p = camera.profile
    k1 = p.system_gain_dn_per_e(1.0)
    full_well_code = model.saturation_dn(p.full_well_e.value, k1, 100.0, 12)
    assert full_well_code == pytest.approx(3376.8)  # full well below the ADC at x1
    assert np.all(camera.render(0.0) == round(full_well_code))
    set_reg(camera.sensor, "GAIN", (1 << 8) | 64)  # analog x2
    assert camera.sensor.gain == "x2"
    k2 = p.system_gain_dn_per_e(2.0)
    assert model.saturation_dn(p.full_well_e.value, k2, 100.0, 12) == 4095
    assert np.all(camera.render(0.01) == 4095)  # the ADC clips first at x2
    camera.set_scene(Scene(np.zeros((1, 1))))
    set_reg(camera.sensor, "OFFSET", 0)
    assert camera.render(0.02).min() == 0  # read noise below black clips at code 0


def test_ibis5_output_keeps_the_8_msbs() -> None:
    camera = make_camera("ibis5", rows=16)
    assert camera.bits == 8
    camera.set_scene("flat:photons=1e12")
    assert np.all(camera.render(0.0) == 960 >> 2)  # full well 896 DN + 64 DN black, /4
    set_reg(camera.sensor, "GAIN", 1)  # x2: the 10-bit ADC clips at 1023
    assert np.all(camera.render(0.01) == 255)
    set_reg(camera.sensor, "GAIN", 0)
    camera.set_scene("flat")  # the default level: a quarter of the range
    frames = stack(camera, frames=50)
    expected = camera.expected_dn(0.0)
    assert frames.max() <= 255
    # Dropping 2 LSBs floors: a uniform remainder of 0 .. 3/4 output DN, mean 3/8.
    assert frames.mean() == pytest.approx(expected.mean() - 3 / 8, abs=0.05)


# -- independence, determinism, binning -------------------------------------------------------------


def test_same_seed_same_frames_and_frames_are_independent() -> None:
    a = make_camera("hr400", seed=7, rows=16)
    b = make_camera("hr400", seed=7, rows=16)
    c = make_camera("hr400", seed=8, rows=16)
    for t in (0.0, 0.01, 0.02):
        fa, fb, fc = a.render(t), b.render(t), c.render(t)
        assert np.array_equal(fa, fb)
        assert not np.array_equal(fa, fc)
    frames = stack(a)[:, :, :128]
    residual = frames - frames.mean(axis=0)
    # Correlation of each frame's residual with the next one's, over 199 x 2048 pairs:
    # standard error 1 / sqrt(407552) = 0.0016. Residuals from the sample mean of A frames
    # correlate by -1 / (A - 1) = -0.005 even for independent frames.
    lag1 = float((residual[1:] * residual[:-1]).mean() / residual.var())
    assert abs(lag1 + 1 / (FRAMES - 1)) < 0.01
    assert not np.array_equal(frames[0], frames[1])


def test_binning_gives_signal_x4_and_dark_noise_x2() -> None:
    camera = make_camera("hr400", seed=3, rows=32)
    camera.set_scene(Scene(np.zeros((1, 1))))
    p = camera.profile
    k_dn = p.system_gain_dn_per_e()
    single_dark = model.dark_noise_dn(0.0, p.read_noise_e.value, k_dn)
    camera.binning = True
    assert camera.bits == 14
    binned = stack(camera)[:, :, :64]  # 16 x 64 binned pixels
    assert binned.shape[1:] == (16, 64)
    assert temporal_noise(binned) == pytest.approx(model.binned_noise_dn(single_dark), rel=0.02)
    assert binned.mean() == pytest.approx(model.binned_mean_dn(100.0), rel=0.002)
    camera.set_scene("flat")
    signal = camera.expected_dn(0.0) - model.binned_mean_dn(100.0)
    camera.binning = False
    single = camera.expected_dn(0.0) - 100.0
    assert signal == pytest.approx(bin2x2(single), rel=1e-5)
    assert float(signal.mean()) == pytest.approx(model.binned_mean_dn(float(single.mean())))
    with pytest.raises(ValueError, match="even number of rows and columns"):
        bin2x2(np.zeros((3, 4)))


# -- motion -----------------------------------------------------------------------------------------


def test_tracking_stage_shifts_the_scene_by_exactly_one_row_per_period() -> None:
    """Same sensor pixels, consecutive frames: frame k + 1 of scene S equals frame k of the
    scene S shifted by one row (S'(y) = S(y + 1)). This is exact whatever the rolling-shutter
    skew and the fixed pattern, because both frames use the same pixels at the same offsets
    within their frame times; only the scene position differs, by the stage's one row."""
    rng = np.random.default_rng(4)
    pattern = rng.uniform(0.0, 1.0, size=(97, 2048))
    camera = make_camera("hr400", rows=64)
    set_exposure_lines(camera.sensor, 7)
    period_s = camera.sensor.timing().tdi_line_period_s
    t0 = 0.123
    camera.set_scene(Scene.from_pattern(pattern, 1e8))
    later = camera.expected_electrons(t0 + period_s, dtype=np.float64)
    same = camera.expected_electrons(t0, dtype=np.float64)
    camera.set_scene(Scene.from_pattern(np.roll(pattern, -1, axis=0), 1e8))
    shifted = camera.expected_electrons(t0, dtype=np.float64)
    assert np.allclose(later, shifted, rtol=1e-9, atol=0)
    assert not np.allclose(later, same, rtol=1e-3)
    # Row r + 1 of frame k differs from row r of frame k + 1 by the rolling skew (1/k row):
    # close, but not equal.
    assert not np.allclose(later[:-1], same[1:], rtol=1e-6)


@pytest.mark.parametrize("error", [0.0, 0.05, -0.03])
def test_stage_speed_sets_the_displacement_per_period(error: float) -> None:
    """A linear ramp along track: the box integral of a linear function is its centre value,
    so each pixel's charge gives the mid-exposure scene row it saw, to float64 precision.
    (Fill factor 1: the aperture spans whole cells of the piecewise-constant ramp, which makes
    the staircase integrate exactly as the line.)"""
    profile = variant(
        "hr400", fill_factor=1.0, prnu_fraction=0.0, dsnu_e_per_s=0.0, dark_current_e_per_s=0.0
    )
    camera = make_camera("hr400", profile=profile, rows=64)
    set_exposure_lines(camera.sensor, 5)
    period_rows = 8192  # no wrap of the ramp inside the window
    photons = 1e9
    camera.set_scene(f"ramp:photons={photons},period={period_rows}")
    camera.stage_speed_m_s = (1.0 + error) * camera.synchronous_speed_m_s()
    timing = camera.sensor.timing()
    # The response map (QE x (1 + PRNU)) is kept in float32: QE = 0.6 is 0.6 + 2.4e-8 there.
    qe = float(np.float32(profile.quantum_efficiency.value))
    slope = photons / period_rows  # photons/s per row of scene position

    def centre_rows(t_s: float) -> np.ndarray:
        charge = camera.expected_electrons(t_s, dtype=np.float64)
        return charge / (qe * timing.exposure_s * slope)  # scene row at the pixel centre

    t0 = 0.05
    first, second = centre_rows(t0), centre_rows(t0 + timing.tdi_line_period_s)
    assert np.max(np.abs(second - first - (1.0 + error))) < 1e-6
    # And the absolute position: row r's centre r + 0.5 plus the stage's displacement at
    # mid-exposure of that row (rolling shutter: row i ends i line periods after row 0).
    rows_per_s = (1.0 + error) / timing.tdi_line_period_s
    i = np.arange(64)[:, None]
    mid_s = t0 + i * timing.line_period_s - timing.exposure_s / 2
    want = 757 + i + 0.5 + rows_per_s * mid_s
    assert np.max(np.abs(first - want)) < 1e-6


def test_an_edge_moving_during_the_exposure_gives_the_exact_blur_profile() -> None:
    """uvccd (frame transfer: every row exposes over the same interval). A sharp edge across
    track (bright for y mod 64 < 32) moving delta = 2.5 rows during the exposure, seen through
    an aperture of q = 0.8: the profile is the edge convolved with two boxes (width q, width
    delta), here recomputed by brute force (20000 instants, exact overlaps)."""
    profile = variant("uvccd", fill_factor=0.64, prnu_fraction=0.0, dsnu_e_per_s=0.0)
    profile = profile.model_copy(
        update={"dark_current_e_per_s": Sourced[float](value=0.0, assumed="test")}
    )
    camera = make_camera("uvccd", profile=profile, rows=64)
    camera.set_scene("edge:photons=1e7,angle_deg=0,period=64,oversample=4")
    timing = camera.sensor.timing()
    delta, q = 2.5, 0.8
    camera.stage_speed_m_s = (
        delta / timing.exposure_s * profile.pitch_m.value / profile.magnification.value
    )
    t_s = 0.37
    d_end = float(camera.image_rows(t_s))
    d_start = d_end - delta
    charge = camera.expected_electrons(t_s, dtype=np.float64)[:, 5]
    fraction = charge / (profile.quantum_efficiency.value * 1e7 * q * q * timing.exposure_s)

    steps = 20000
    d = d_start + delta * (np.arange(steps) + 0.5) / steps
    want = np.empty(64)
    for r in range(64):
        lo = r + (1 - q) / 2 + d
        bright = np.zeros(steps)
        for start in range(-64, 192, 64):  # the bright halves near the window
            bright += np.clip(np.minimum(lo + q, start + 32) - np.maximum(lo, start), 0, None)
        want[r] = bright.mean() / q
    assert np.max(np.abs(fraction - want)) < 1e-6
    ramp = (fraction > 1e-9) & (fraction < 1 - 1e-9)
    # Each edge spreads over delta + q = 3.3 rows: 4 partial rows per edge here.
    assert 6 <= int(ramp.sum()) <= 10
    assert np.all(fraction[(want == 1.0)] == pytest.approx(1.0))


# -- registers take effect --------------------------------------------------------------------------


def test_registers_take_effect_on_the_next_render() -> None:
    camera = make_camera("hr400", rows=16)
    assert camera.render(0.0).shape == (16, 2048)
    set_reg(camera.sensor, "WIN_ROWS", 10)
    assert camera.render(0.0).shape == (10, 2048)
    dim = camera.expected_dn(0.0).mean() - 100
    set_reg(camera.sensor, "GAIN", (2 << 8) | 64)  # x4
    assert camera.expected_dn(0.0).mean() - 100 == pytest.approx(4 * dim, rel=1e-5)
    set_reg(camera.sensor, "TEST_PATTERN", 2)  # ramp
    assert np.array_equal(camera.render(0.0), ramp_frame(10, 2048, 12))
    set_reg(camera.sensor, "TEST_PATTERN", 0)
    set_reg(camera.sensor, "WIN_START", 2040)
    with pytest.raises(ValueError, match="leave the 2048 x 2048 array"):
        camera.render(0.0)


def test_mt9m001_window_gain_code_and_test_data() -> None:
    sensor = SensorModel(load_register_map("mt9m001"))
    set_reg(sensor, "ROW_SIZE", 31)  # 32 rows
    set_reg(sensor, "COL_START", 100)
    set_reg(sensor, "COL_SIZE", 63)  # 64 columns
    camera = CameraModel(load_profile("mt9m001"), sensor)
    assert camera.window() == (0, 32, 80, 64)  # array indices (first row 12, column 20)
    assert camera.render(0.0).shape == (32, 64)
    base = camera.expected_electrons(0.0)
    set_reg(sensor, "GLOBAL_GAIN", 0x51)  # 4.25x per the datasheet coding
    assert camera.system_gain_dn_per_e() == pytest.approx(4.25 * 30e-6 * 1024)
    assert np.array_equal(camera.expected_electrons(0.0), base)  # gain is after the charge
    set_reg(sensor, "TEST_DATA", 0x2A5)
    set_reg(sensor, "OUTPUT_CONTROL", 0x0042)  # chip enable + test
    assert np.all(camera.render(0.0) == 0x2A5)


def test_ibis5_readout_register_selects_the_global_shutter() -> None:
    camera = make_camera("ibis5", rows=8)
    start, end = camera.exposure_times_s(1.0)
    assert camera.shutter == "rolling" and end[1] - end[0] == pytest.approx(35.5e-6)
    set_reg(camera.sensor, "READOUT", 0x0011)  # global shutter, 8-bit output
    start, end = camera.exposure_times_s(1.0)
    assert camera.shutter == "global" and np.all(end == 1.0)
    assert np.allclose(end - start, camera.sensor.timing().exposure_s)


def test_synchronous_speed() -> None:
    camera = make_camera("hr400")
    period_s = camera.sensor.timing().tdi_line_period_s  # 534 lines of 20.52 us
    assert period_s == pytest.approx(534 * 20.52e-6)
    # p / (m T): 11 um / (0.1 x 10.958 ms) = 10.04 mm/s on the stage.
    assert camera.synchronous_speed_m_s() == pytest.approx(11e-6 / (0.1 * period_s))
    assert float(camera.image_rows(period_s)) == pytest.approx(1.0)
    camera.stage_speed_m_s = 0.0
    assert float(camera.image_rows(period_s)) == 0.0


def test_profile_and_sensor_must_match() -> None:
    with pytest.raises(ValueError, match="profile hr400 is for sensor hr400"):
        CameraModel(load_profile("hr400"), SensorModel(load_register_map("ibis5")))
