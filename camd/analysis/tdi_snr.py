"""SNR of M-stage digital TDI: the models of docs/physics.md §5 and measurements on TDI scans.

Models (linear SNR gain of M stages over one, ``SNR_M = SNR_1 * gain``):

- ``snr_gain_tao12``: TAO12 eqs 27-28, quantisation noise adding linearly over the stages,
  sensor noise in quadrature: ``gain = M (s_AD + s_CMOS) / (M s_AD + sqrt(M) s_CMOS)``
  (docs/physics.md notes that eq 28 is a linear gain: convert with 20 lg);
- ``snr_gain_sqrt_m``: DONG16 eqs 1-3, every noise source independent per stage: sqrt(M). This
  is also the standard quadrature model ``sigma_M^2 = M (s_AD^2 + s_CMOS^2)`` when SNR_1 is
  measured with all its noise, as it is here.
- ``tdi_noise_tao12`` (eq 27) and ``tdi_noise_quadrature``: the noise of an M-stage sum under
  the two noise models; ``camd.analysis.snr_models`` sets the three models side by side and
  fits them to measurements.

Measurements on a TDI scan file's lines (pure functions of arrays):

- ``along_track_snr``: a flat field; each column's lines all sum the same M pixels, so the
  fixed pattern cancels along the track and the spread is temporal noise;
- ``periodic_snr``: a scene that repeats along track (the bar target, period P rows): lines
  P apart see the same scene, so the mean over periods is the scene and the rest is noise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from camd.analysis.sensor_noise import psnr_db

QUANTISATION_SIGMA_DN = 1.0 / math.sqrt(12.0)
"""Rounding to whole DN: sigma_AD = 1/sqrt(12) DN per conversion (docs/physics.md §5)."""


def db(ratio: float) -> float:
    """A linear amplitude ratio in decibels, ``20 lg(ratio)`` (docs/physics.md §5)."""
    return 20.0 * math.log10(ratio)


def snr_gain_tao12(stages: int, sigma_ad: float, sigma_cmos: float) -> float:
    """TAO12 eq 28 (linear): ``M (s_AD + s_CMOS) / (M s_AD + sqrt(M) s_CMOS)`` (docs/physics.md §5)."""
    if stages < 1:
        raise ValueError(f"stages must be >= 1, got {stages}")
    if sigma_ad < 0 or sigma_cmos < 0 or sigma_ad + sigma_cmos == 0:
        raise ValueError("sigma_ad and sigma_cmos must be >= 0 and not both 0")
    m = float(stages)
    return m * (sigma_ad + sigma_cmos) / (m * sigma_ad + math.sqrt(m) * sigma_cmos)


def snr_gain_sqrt_m(stages: int) -> float:
    """DONG16 eqs 1-3 and the quadrature model: ``sqrt(M)`` (docs/physics.md §5)."""
    if stages < 1:
        raise ValueError(f"stages must be >= 1, got {stages}")
    return math.sqrt(stages)


def _sigmas(stages: int, sigma_ad: float, sigma_cmos: float) -> float:
    if stages < 1:
        raise ValueError(f"stages must be >= 1, got {stages}")
    if sigma_ad < 0 or sigma_cmos < 0:
        raise ValueError(f"sigma_ad and sigma_cmos must be >= 0, got {sigma_ad}, {sigma_cmos}")
    return float(stages)


def tdi_noise_tao12(stages: int, sigma_ad: float, sigma_cmos: float) -> float:
    """TAO12 eq 27, noise of an M-stage sum: ``M s_AD + sqrt(M) s_CMOS`` (docs/physics.md §5).

    Quantisation adds linearly over the stages, sensor noise in quadrature; the signal is
    ``M S``, so ``M S / tdi_noise_tao12`` is ``S / (s_AD + s_CMOS)`` times eq 28's gain.
    """
    m = _sigmas(stages, sigma_ad, sigma_cmos)
    return m * sigma_ad + math.sqrt(m) * sigma_cmos


def tdi_noise_quadrature(stages: int, sigma_ad: float, sigma_cmos: float) -> float:
    """The quadrature model's noise of an M-stage sum: ``sqrt(M (s_AD^2 + s_CMOS^2))``.

    docs/physics.md §5 ("the standard model with independent quantisation noise"): every stage is
    its own ADC conversion, so quantisation, like the sensor noise, is independent per stage.
    Its SNR gain over one stage is therefore exactly ``snr_gain_sqrt_m``.
    """
    m = _sigmas(stages, sigma_ad, sigma_cmos)
    return math.sqrt(m * (sigma_ad**2 + sigma_cmos**2))


@dataclass(frozen=True, slots=True)
class SnrMeasurement:
    """Signal above black (DN), temporal noise (DN) and their ratio, with the sample size."""

    signal_dn: float
    noise_dn: float
    snr: float
    pixels: int

    @property
    def snr_db(self) -> float:
        """The SNR as PSNR in dB (docs/physics.md §5)."""
        return psnr_db(self.signal_dn, self.noise_dn)


def along_track_snr(lines: npt.ArrayLike, *, black_dn: float) -> SnrMeasurement:
    """Temporal SNR of TDI lines of a flat field: ``(mean - black) / mean_j std_k(L[k, j])``.

    ``black_dn`` is the black level of a line (M times the sensor's for a sum of M stages).
    Needs at least two lines.
    """
    arr = np.asarray(lines, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[0] < 2:
        raise ValueError(f"along_track_snr needs (lines >= 2, columns), got shape {arr.shape}")
    noise = float(arr.std(axis=0, ddof=1).mean())
    signal = float(arr.mean()) - black_dn
    return SnrMeasurement(signal, noise, signal / noise, int(arr.size))


def periodic_snr(
    lines: npt.ArrayLike,
    index: npt.ArrayLike,
    *,
    period: int,
    black_dn: float,
    bright_fraction: float = 0.25,
) -> SnrMeasurement:
    """Temporal SNR on the bright part of a scene that repeats every ``period`` lines.

    ``index`` are the lines' indices (gaps allowed): lines with equal ``index % period`` see
    the same scene. The scene is their mean; the noise is the spread about it (with the
    n/(n-1) correction of each phase's sample mean); phases seen only once are left out. Pixels whose scene is in the top
    ``bright_fraction`` make the region (the bright bars).
    """
    arr = np.asarray(lines, dtype=np.float64)
    idx = np.asarray(index, dtype=np.int64)
    if arr.ndim != 2 or idx.shape != (arr.shape[0],):
        raise ValueError(f"lines (L, N) and index (L,) do not match: {arr.shape}, {idx.shape}")
    if period < 1 or not 0 < bright_fraction <= 1:
        raise ValueError("period must be >= 1 and bright_fraction in (0, 1]")
    phase = idx % period
    scene = np.zeros((period, arr.shape[1]))
    squares = np.zeros((period, arr.shape[1]))
    counts = np.bincount(phase, minlength=period)
    usable = counts >= 2  # a phase seen once has no spread to measure
    if not usable.any():
        raise ValueError(f"no phase of the period has two lines; take at least {2 * period} lines")
    np.add.at(scene, phase, arr)
    scene /= np.maximum(counts, 1)[:, None]
    residual = arr - scene[phase]
    np.add.at(squares, phase, residual**2)
    variance = squares / np.maximum(counts - 1, 1)[:, None]
    scene, variance = scene[usable], variance[usable]
    bright = scene >= np.quantile(scene, 1.0 - bright_fraction)
    signal = float(scene[bright].mean()) - black_dn
    noise = float(np.sqrt(variance[bright].mean()))
    return SnrMeasurement(signal, noise, signal / noise, int(bright.sum()))
