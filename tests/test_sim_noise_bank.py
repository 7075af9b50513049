"""The simulated camera's temporal noise comes from a pre-drawn bank; the statistics the tests
and campaigns measure must be those of fresh draws (docs/simulator.md, "Temporal noise from a
bank").

The bank itself (firmware_models.noise_bank): standard normal to the last digit of float32 in
mean and variance, the same for a seed, grown to hold several frames, offsets uniform and drawn
in frame order. Through the camera: a flat field's mean and temporal variance against the
shot + read noise equation (docs/physics.md §5) to a few tenths of a percent, no correlation
between successive frames' noise at the same pixel, and the variance of a TDI line (stage i of
M successive frames summed) M times a frame's: a frame repeating another's noise would show
in both. Precision: each estimate is given with its standard error and checked to five of them
(the seeds are fixed: the numbers do not change between runs).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from camd.analysis import sensor_noise as model
from camd.sensor.profile import load_profile
from camd.sensor.regmap import load_register_map
from firmware_models.camera import CameraModel
from firmware_models.noise_bank import (
    CHUNK_VALUES,
    FRAMES_PER_BANK,
    MAX_CHUNKS,
    MIN_CHUNKS,
    NoiseBank,
)
from firmware_models.sensor import SensorModel


def camera(name: str, rows: int, *, seed: int = 0) -> CameraModel:
    sensor = SensorModel(load_register_map(name))
    sensor.spi_write(sensor.regmap.register("WIN_ROWS").address, rows)
    return CameraModel(load_profile(name), sensor, seed=seed)


# -- the bank ---------------------------------------------------------------------------------------


def test_the_bank_is_standard_normal_exactly_and_fixed_by_the_seed() -> None:
    bank = NoiseBank(seed=3)
    values, starts = bank.take(np.random.default_rng(1), 2, 1000)
    assert bank.size == MIN_CHUNKS * CHUNK_VALUES
    assert values.dtype == np.float32 and starts.shape == (2,)
    for c in range(MIN_CHUNKS):
        chunk = values[c * CHUNK_VALUES : (c + 1) * CHUNK_VALUES].astype(np.float64)
        assert abs(chunk.mean()) < 1e-6  # shifted to mean 0 ...
        assert chunk.var() == pytest.approx(1.0, abs=1e-6)  # ... and scaled to variance 1
        # The shape of a normal: 68.3 % within one sigma (SE 0.05 %), kurtosis 3 (SE 0.01).
        assert float(np.mean(np.abs(chunk) < 1.0)) == pytest.approx(0.6827, abs=0.0025)
        assert float(np.mean(chunk**4)) == pytest.approx(3.0, abs=0.05)
    # Tails: the largest of 4 Mi draws lies near 5.2 sigma.
    assert 4.8 < float(np.abs(values).max()) < 6.0
    again, _ = NoiseBank(seed=3).take(np.random.default_rng(9), 1, 1000)
    other, _ = NoiseBank(seed=4).take(np.random.default_rng(9), 1, 1000)
    assert np.array_equal(again, values) and not np.array_equal(other[:1000], values[:1000])


def test_the_bank_grows_to_hold_several_frames_and_larger_frames_are_drawn_directly() -> None:
    bank = NoiseBank(seed=0)
    pixels = 534 * 2048  # the hr400's default window
    _, starts = bank.take(np.random.default_rng(0), 3, pixels)
    assert bank.size == math.ceil(FRAMES_PER_BANK * pixels / CHUNK_VALUES) * CHUNK_VALUES
    assert bank.size >= FRAMES_PER_BANK * pixels
    assert np.all((starts >= 0) & (starts <= bank.size - pixels))
    too_large = MAX_CHUNKS * CHUNK_VALUES // FRAMES_PER_BANK + 1
    assert not bank.holds(too_large) and bank.holds(too_large - 1)
    fresh, fresh_starts = bank.take(np.random.default_rng(0), 2, too_large)
    assert fresh.size == 2 * too_large and list(fresh_starts) == [0, too_large]
    assert bank.size < MAX_CHUNKS * CHUNK_VALUES  # the bank did not grow for it


def test_offsets_are_uniform_and_a_block_draws_what_frames_one_by_one_draw() -> None:
    bank = NoiseBank(seed=0)
    pixels = 100_000
    block = bank.offsets(np.random.default_rng(5), 4000, pixels)
    rng = np.random.default_rng(5)
    one_by_one = np.concatenate([bank.offsets(rng, 1, pixels) for _ in range(4000)])
    assert np.array_equal(block, one_by_one)
    span = bank.size - pixels + 1
    # Uniform over the starts that fit: 10 bins of 400 expected, chi-square with 9 degrees of
    # freedom below 27.9 (p = 0.001).
    counts = np.bincount((block * 10 // span).astype(np.int64), minlength=10)
    assert float(((counts - 400.0) ** 2 / 400.0).sum()) < 27.9
    # Two frames start at the same offset rarely: about 2 of the 8 million pairs here.
    assert len(set(block.tolist())) > 3990


# -- through the camera -----------------------------------------------------------------------------

FRAMES = 200


def test_flat_field_mean_and_variance_against_the_shot_and_read_noise_equation() -> None:
    """hr400, 32 x 2048 pixels, 200 frames at 20,000 e-: the mean to 0.1 % of the equation
    (the fixed pattern averages out over 65,536 pixels to 0.004 %), the temporal variance
    (per pixel, averaged) to 0.3 %: its standard error is sqrt(2 / (199 x 65,536)) = 0.039 %."""
    cam = camera("hr400", 32, seed=21)
    exp = cam.sensor.regmap.register
    cam.sensor.spi_write(exp("EXP_LO").address, 100)  # 2.052 ms
    p = cam.profile
    exposure_s = cam.sensor.timing().exposure_s
    signal_e = 20000.0
    photons = signal_e / (p.quantum_efficiency.value * p.fill_factor.value * exposure_s)
    cam.set_scene(f"flat:photons={photons}")
    frames = np.stack([cam.render(0.01 * k) for k in range(FRAMES)]).astype(np.float64)
    k_dn = p.system_gain_dn_per_e()
    dark_e = p.dark_current_e_per_s.value * exposure_s
    mean_dn = model.mean_signal_dn(signal_e, dark_e, k_dn, 100.0)
    noise_dn = model.temporal_noise_dn(signal_e, dark_e, p.read_noise_e.value, k_dn)
    assert frames.mean() == pytest.approx(mean_dn, rel=1e-3)
    variance = float(frames.var(axis=0, ddof=1).mean())
    assert variance == pytest.approx(noise_dn**2, rel=3e-3)


def test_successive_frames_noise_is_uncorrelated_at_each_pixel() -> None:
    """Residuals from each pixel's mean over 200 frames, correlated with the next frames' at
    the same pixel: -1 / 199 expected for independent frames (the shared sample mean), with a
    standard error of 1 / sqrt(199 x 65,536) = 0.0003 per lag."""
    cam = camera("hr400", 32, seed=5)  # the default flat field: a quarter of the range
    frames = np.stack([cam.render(0.01 * k) for k in range(FRAMES)]).astype(np.float64)
    residual = frames - frames.mean(axis=0)
    scale = residual.var()
    standard_error = 1.0 / math.sqrt((FRAMES - 1) * residual[0].size)
    for lag in (1, 2, 3, 10):
        correlation = float((residual[lag:] * residual[:-lag]).mean() / scale)
        assert abs(correlation + 1.0 / (FRAMES - 1)) < 5 * standard_error, (lag, correlation)


def test_a_tdi_line_of_m_frames_has_m_times_a_frames_variance() -> None:
    """Stage i of M = 16 successive frames summed, as digital TDI does (row M - 1 - i of frame
    L + i): the lines' variance about each pixel's mean is M sigma^2 (1 - 1/N) for independent
    frames. 320 frames give 305 lines x 2048 columns; standard error of the ratio
    sqrt(2 / 624,640) = 0.18 %, checked to 0.9 %."""
    m, n = 16, 320
    cam = camera("hr400", m, seed=8)
    times = 0.01 * np.arange(n)
    frames = np.concatenate([cam.render_block(times[i : i + 64])[0] for i in range(0, n, 64)])
    residual = frames.astype(np.float64) - frames.mean(axis=0)
    sigma2 = float(frames.astype(np.float64).var(axis=0, ddof=1).mean())
    lines = sum(residual[i : n - m + 1 + i, m - 1 - i, :] for i in range(m))
    ratio = float(np.var(lines) / (m * sigma2 * (1.0 - 1.0 / n)))
    assert ratio == pytest.approx(1.0, abs=0.009)
