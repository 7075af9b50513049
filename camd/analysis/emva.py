"""EMVA-style temporal noise and SNR from stacks of frames (docs/physics.md §5, §3): pure functions.

docs/physics.md §5 [YE23 eqs 9-13], A frames at one exposure, per pixel (i, j), then over a region:

    Y_dark(i,j)  = mean over the A dark frames                                        (9)
    D_noise(i,j) = sqrt( sum_m (D_dark(i,j,m) - Y_dark(i,j))^2 / A )   temporal dark noise (10)
    Y(i,j)       = mean_m ( D(i,j,m) - Y_dark(i,j) )                   dark-subtracted (11)
    S(i,j)       = sqrt( sum_m (D(i,j,m) - Y_dark(i,j) - Y(i,j))^2 / A )  temporal noise (12)
    SNR          = mean over the region of Y(i,j) / S(i,j)                             (13)

YE23 takes A = 20 frames and a 25 x 25 region at the field centre (``centred_region``,
``YE23_REGION_PX``), 2x2-binned data (``bin_2x2``, ``binned_temporal_snr``; docs/physics.md §3:
signal x4, temporal dark noise x2, SNR x2).

Differences from EMVA 1288 (release 3.x/4.0) itself, and from the ``emva1288`` package:

- EMVA 1288 takes the temporal variance from two frames, ``((y_a - y_b)^2 - (mu_a - mu_b)^2)/2``
  averaged over all pixels (``two_frame_noise``); eq 10 divides the sum over A frames by ``A``,
  not ``A - 1``, so its variance reads ``(A - 1) / A`` of the true one, and averaging the
  per-pixel roots (below) takes off another ``c4(A)``: for Gaussian noise and A = 20 the
  expectation is 0.962 sigma. ``bessel=True`` divides by ``A - 1`` instead.
- EMVA 1288 averages variances over the region and then takes the root; docs/physics.md averages the
  per-pixel noise ``D_noise(i,j)``. Both are reported (``noise_dn``, ``noise_rms_dn``).
- EMVA 1288's SNR is a ratio of region means, ``mu_y - mu_y.dark`` over ``sigma_y``
  (``TemporalSnr.snr_of_means``); eq 13 averages per-pixel ratios, which ``1 / S`` biases
  high: by a factor 1.069 for Gaussian noise and A = 20 (derived in tests/test_emva.py).
- EMVA 1288's dark noise in electrons removes quantisation first,
  ``sigma_d = sqrt(sigma_y.dark^2 - 1/12) / K`` (``DarkNoise.noise_e_less_quantisation``);
  docs/physics.md only says that the conversion needs the system gain ``K``: ``noise_e`` is
  ``noise_dn / K``, the total temporal dark noise referred to the pixel.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Final

import numpy as np
import numpy.typing as npt

from camd.analysis.sensor_noise import (
    QUANTISATION_VARIANCE_DN2,
    binned_mean_dn,
    binned_noise_dn,
    emva_dark_mean_dn,
    emva_temporal_noise_dn,
    psnr_db,
)
from camd.analysis.tdi_snr import db
from camd.tdi.binning import bin2x2

FloatArray = npt.NDArray[np.float64]

YE23_REGION_PX: Final = (25, 25)
"""YE23's measurement region: 25 x 25 pixels at the field centre (docs/physics.md §5)."""

YE23_FRAMES: Final = 20
"""YE23's number of frames A per exposure (docs/physics.md §5)."""

Region = tuple[int, int] | None
"""A centred ``(rows, cols)`` region, or ``None`` for the whole frame."""


def centred_region(
    shape: tuple[int, ...], rows: int = YE23_REGION_PX[0], cols: int = YE23_REGION_PX[1]
) -> tuple[slice, slice]:
    """Slices of a ``rows x cols`` region at the centre of a frame (docs/physics.md §5, YE23).

    ``shape`` is a frame's or a stack's shape; its last two axes are (rows, columns). When the
    free margin is odd, the extra row or column is left below or to the right.
    """
    if len(shape) < 2:
        raise ValueError(f"need a frame shape (..., rows, cols), got {shape}")
    if rows < 1 or cols < 1:
        raise ValueError(f"region must be at least 1 x 1, got {rows} x {cols}")
    height, width = shape[-2], shape[-1]
    if rows > height or cols > width:
        raise ValueError(
            f"a {rows} x {cols} region does not fit a {height} x {width} frame: "
            f"choose rows <= {height} and cols <= {width}"
        )
    top, left = (height - rows) // 2, (width - cols) // 2
    return slice(top, top + rows), slice(left, left + cols)


def _stack(name: str, frames: npt.ArrayLike) -> FloatArray:
    stack = np.asarray(frames, dtype=np.float64)
    if stack.ndim != 3 or stack.shape[0] < 2:
        raise ValueError(
            f"{name} must be a stack of at least 2 frames, shape (A, rows, cols); "
            f"got shape {stack.shape}"
        )
    return stack


def _crop(stack: FloatArray, region: Region) -> FloatArray:
    if region is None:
        return stack
    rows, cols = centred_region(stack.shape, *region)
    return stack[..., rows, cols]


def _per_pixel_noise(stack: FloatArray, bessel: bool) -> FloatArray:
    """Eq 10/12 per pixel (divisor A); ``bessel`` rescales to the divisor A - 1."""
    noise = emva_temporal_noise_dn(stack)
    if bessel:
        a = stack.shape[0]
        noise = noise * math.sqrt(a / (a - 1.0))
    return noise


def _gain(gain_dn_per_e: float | None) -> float | None:
    if gain_dn_per_e is not None and not gain_dn_per_e > 0.0:
        raise ValueError(f"gain_dn_per_e (system gain K, DN/e-) must be > 0, got {gain_dn_per_e!r}")
    return gain_dn_per_e


def region_psnr_db(
    image: npt.ArrayLike, *, region: Region = YE23_REGION_PX, black_dn: float = 0.0
) -> float:
    """``PSNR = 20 lg(mean / sigma_RMS)`` of a region of one image (docs/physics.md §5, TAO12 §5.1).

    The spatial mean and RMS deviation (divisor N) of the centred region, after subtracting
    ``black_dn`` from the mean (TAO12 uses the raw mean: ``black_dn = 0``). On a single image
    sigma includes fixed-pattern noise; ``temporal_snr`` separates the temporal part.
    """
    arr = np.asarray(image, dtype=np.float64)
    if arr.ndim != 2:
        raise ValueError(f"region_psnr_db needs one image (rows, cols), got shape {arr.shape}")
    values = _crop(arr, region)
    return psnr_db(float(values.mean()) - black_dn, float(values.std()))


@dataclass(frozen=True, slots=True)
class DarkNoise:
    """Temporal dark noise of a region from A dark frames (docs/physics.md §5, eqs 9-10).

    ``mean_dn``: region mean of ``Y_dark``; ``noise_dn``: region mean of ``D_noise(i,j)``
    (docs/physics.md); ``noise_rms_dn``: root of the region mean of ``D_noise(i,j)^2`` (EMVA 1288's
    averaging). ``bessel`` records whether eq 10 divided by ``A - 1`` rather than ``A``.
    """

    mean_dn: float
    noise_dn: float
    noise_rms_dn: float
    frames: int
    pixels: int
    gain_dn_per_e: float | None = None
    bessel: bool = False

    @property
    def noise_e(self) -> float | None:
        """``noise_dn / K`` in electrons (None without a system gain)."""
        return None if self.gain_dn_per_e is None else self.noise_dn / self.gain_dn_per_e

    @property
    def noise_e_less_quantisation(self) -> float | None:
        """EMVA 1288's ``sigma_d = sqrt(noise_rms_dn^2 - 1/12) / K`` in electrons.

        None without a system gain or when the noise does not exceed quantisation's
        ``1/sqrt(12)`` DN (EMVA 1288 then floors ``sigma_y.dark^2`` at 0.24 DN^2).
        """
        excess = self.noise_rms_dn**2 - QUANTISATION_VARIANCE_DN2
        if self.gain_dn_per_e is None or excess <= 0.0:
            return None
        return math.sqrt(excess) / self.gain_dn_per_e


def temporal_dark_noise(
    dark_frames: npt.ArrayLike,
    *,
    region: Region = YE23_REGION_PX,
    gain_dn_per_e: float | None = None,
    bessel: bool = False,
) -> DarkNoise:
    """Temporal dark noise from A >= 2 dark frames, shape (A, rows, cols) (docs/physics.md §5).

    Eq 9 (per-pixel mean) and eq 10 (per-pixel temporal noise, divided by ``A`` as written;
    ``bessel=True`` divides by ``A - 1``) over the centred ``region`` (YE23: 25 x 25; ``None``
    for the whole frame). With the system gain ``K`` (DN/e-) the result also gives electrons.
    """
    stack = _crop(_stack("dark_frames", dark_frames), region)
    return _dark_noise(stack, _gain(gain_dn_per_e), bessel)


def _dark_noise(stack: FloatArray, gain: float | None, bessel: bool) -> DarkNoise:
    """Eqs 9-10 on a cropped dark stack."""
    noise = _per_pixel_noise(stack, bessel)
    return DarkNoise(
        mean_dn=float(emva_dark_mean_dn(stack).mean()),
        noise_dn=float(noise.mean()),
        noise_rms_dn=float(np.sqrt((noise**2).mean())),
        frames=int(stack.shape[0]),
        pixels=int(noise.size),
        gain_dn_per_e=gain,
        bessel=bessel,
    )


@dataclass(frozen=True, slots=True)
class TemporalSnr:
    """Signal, temporal noise and SNR of a region (docs/physics.md §5, eqs 11-13).

    ``signal_dn``: region mean of ``Y(i,j)`` (dark subtracted); ``noise_dn``: region mean of
    ``S(i,j)``; ``noise_rms_dn``: root of the region mean of ``S(i,j)^2``; ``snr``: eq 13,
    the region mean of ``Y(i,j) / S(i,j)``; ``dark``: the dark frames' eqs 9-10.
    """

    signal_dn: float
    noise_dn: float
    noise_rms_dn: float
    snr: float
    dark: DarkNoise
    frames: int
    pixels: int
    gain_dn_per_e: float | None = None
    bessel: bool = False

    @property
    def snr_db(self) -> float:
        """Eq 13's SNR in dB, ``20 lg(SNR)`` (docs/physics.md §5)."""
        return db(self.snr)

    @property
    def snr_of_means(self) -> float:
        """EMVA 1288's SNR, ``signal_dn / noise_rms_dn`` (a ratio of region means)."""
        return self.signal_dn / self.noise_rms_dn

    @property
    def signal_e(self) -> float | None:
        """``signal_dn / K`` in electrons (None without a system gain)."""
        return None if self.gain_dn_per_e is None else self.signal_dn / self.gain_dn_per_e

    @property
    def noise_e(self) -> float | None:
        """``noise_dn / K`` in electrons (None without a system gain)."""
        return None if self.gain_dn_per_e is None else self.noise_dn / self.gain_dn_per_e


def temporal_snr(
    frames: npt.ArrayLike,
    dark_frames: npt.ArrayLike,
    *,
    region: Region = YE23_REGION_PX,
    gain_dn_per_e: float | None = None,
    bessel: bool = False,
) -> TemporalSnr:
    """SNR of a region from A >= 2 lit and A' >= 2 dark frames at one exposure (docs/physics.md §5).

    Eqs 9-13 as docs/physics.md writes them: the per-pixel dark mean ``Y_dark`` is subtracted from
    every lit frame, ``S(i,j)`` divides by ``A`` (``bessel=True``: ``A - 1``), and the SNR is
    the region mean of the per-pixel ratios. Both stacks have shape (frames, rows, cols) with
    the same rows and columns. YE23 measures at 80 % of saturation; a saturated pixel has no
    temporal noise and is refused.
    """
    gain = _gain(gain_dn_per_e)
    lit = _stack("frames", frames)
    dark = _stack("dark_frames", dark_frames)
    if lit.shape[1:] != dark.shape[1:]:
        raise ValueError(
            f"frames and dark_frames must have the same frame size, got {lit.shape[1:]} "
            f"and {dark.shape[1:]}: take the dark frames with the same window and binning"
        )
    lit, dark = _crop(lit, region), _crop(dark, region)
    y_dark = emva_dark_mean_dn(dark)  # eq 9
    y = emva_dark_mean_dn(lit) - y_dark  # eq 11
    s = _per_pixel_noise(lit, bessel)  # eq 12: Y_dark and Y cancel out of the deviations
    still = int(np.count_nonzero(s == 0.0))
    if still:
        raise ValueError(
            f"{still} pixel(s) of the region have zero temporal noise, so eq 13's Y / S is "
            "infinite: saturated or stuck pixels (lower the light level; YE23 measures at "
            "80 % of saturation, or move the region), or too few frames for the noise "
            f"(A = {lit.shape[0]}: equal values happen by chance; YE23 takes 20)"
        )
    return TemporalSnr(
        signal_dn=float(y.mean()),
        noise_dn=float(s.mean()),
        noise_rms_dn=float(np.sqrt((s**2).mean())),
        snr=float((y / s).mean()),  # eq 13
        dark=_dark_noise(dark, gain, bessel),
        frames=int(lit.shape[0]),
        pixels=int(y.size),
        gain_dn_per_e=gain,
        bessel=bessel,
    )


@dataclass(frozen=True, slots=True)
class TwoFrameNoise:
    """EMVA 1288's temporal statistics of two frames: mean and variance of the region."""

    mean_dn: float
    variance_dn2: float
    pixels: int

    @property
    def noise_dn(self) -> float:
        """The temporal noise, ``sqrt(variance_dn2)``."""
        return math.sqrt(self.variance_dn2)


def two_frame_noise(
    frame_a: npt.ArrayLike, frame_b: npt.ArrayLike, *, region: Region = None
) -> TwoFrameNoise:
    """EMVA 1288's two-frame temporal variance: ``(<(y_a - y_b)^2> - (mu_a - mu_b)^2) / 2``.

    Not in docs/physics.md (which uses eqs 9-13 on A frames); EMVA 1288 (release 3.x/4.0, the
    ``emva1288`` package) measures every point of its photon-transfer curve this way, over the
    whole frame (``region=None``). The mean is that of both frames. Subtracting the squared
    difference of the frame means removes a global level change between the frames.
    """
    a = np.asarray(frame_a, dtype=np.float64)
    b = np.asarray(frame_b, dtype=np.float64)
    if a.ndim != 2 or a.shape != b.shape:
        raise ValueError(f"need two images of one shape (rows, cols), got {a.shape} and {b.shape}")
    pair = _crop(np.stack([a, b]), region)
    diff = pair[0] - pair[1]
    variance = (float((diff**2).mean()) - float(diff.mean()) ** 2) / 2.0
    return TwoFrameNoise(float(pair.mean()), variance, int(diff.size))


def binned_snr(signal_dn: float, noise_dn: float) -> float:
    """SNR of a 2x2-binned pixel from unbinned statistics: ``4 S / (2 N) = 2 S / N``.

    docs/physics.md §3 [YE23]: the sum of 4 neighbours has signal x4 and, with independent temporal
    noise, noise x2, so the SNR doubles (+6.02 dB). ``signal_dn`` is above black.
    """
    if not noise_dn > 0.0:
        raise ValueError(f"noise_dn must be > 0, got {noise_dn!r}")
    return binned_mean_dn(signal_dn) / binned_noise_dn(noise_dn)


def bin_2x2(frames: npt.ArrayLike) -> FloatArray:
    """Sum 2 x 2 neighbours of a frame or stack (..., rows, cols) (docs/physics.md §3), in float64
    (``camd.tdi.bin2x2``, the FPGA's binning, on widened pixels)."""
    binned: FloatArray = bin2x2(np.asarray(frames, dtype=np.float64))
    return binned


def binned_temporal_snr(
    frames: npt.ArrayLike,
    dark_frames: npt.ArrayLike,
    *,
    region: Region = YE23_REGION_PX,
    gain_dn_per_e: float | None = None,
    bessel: bool = False,
) -> TemporalSnr:
    """``temporal_snr`` of 2x2-binned frames, as YE23 measures (docs/physics.md §3, §5).

    The unbinned stacks are binned with ``bin_2x2``; ``region`` counts binned pixels. The
    system gain of a binned pixel is the unbinned ``K`` (DN and electrons both add).
    """
    return temporal_snr(
        bin_2x2(_stack("frames", frames)),
        bin_2x2(_stack("dark_frames", dark_frames)),
        region=region,
        gain_dn_per_e=gain_dn_per_e,
        bessel=bessel,
    )


# -- what eqs 10 and 13 read on Gaussian noise, and the photon transfer -----------------------


def eq10_expectation_factor(frames: int) -> float:
    """``E[D_noise(i,j)] / sigma`` for A frames of Gaussian noise: ``sqrt((A-1)/A) c4(A)``.

    docs/physics.md §5 eq 10 divides by ``A`` (a factor ``sqrt((A-1)/A)`` on the root) and the
    mean of a sample standard deviation is ``c4(A) sigma`` with
    ``c4(A) = sqrt(2/(A-1)) Gamma(A/2) / Gamma((A-1)/2)``. For YE23's A = 20: 0.962. A model
    of the noise (sigma) times this factor is what eq 10 is expected to measure.
    """
    a = _frame_count(frames, 2)
    c4 = math.sqrt(2.0 / (a - 1)) * math.exp(math.lgamma(a / 2.0) - math.lgamma((a - 1) / 2.0))
    return math.sqrt((a - 1) / a) * c4


def eq13_expectation_factor(frames: int) -> float:
    """``E[eq 13's SNR] / (mu / sigma)`` for A frames of Gaussian noise (docs/physics.md §5).

    Eq 13 averages per-pixel ratios ``Y / S``; for Gaussian noise ``Y`` is independent of
    ``S`` (eq 12, divisor A), so ``E[Y / S] = mu E[1 / S]``. With ``nu = A - 1`` and
    ``S = sigma sqrt(nu / A) chi_nu / sqrt(nu)``, ``E[sigma / S] = sqrt(A / nu) sqrt(nu / 2)
    Gamma((nu - 1) / 2) / Gamma(nu / 2)``: 1.069 for YE23's A = 20, so eq 13 reads about 7 %
    above the SNR ``mu / sigma`` that a noise model gives. Needs A >= 3 (for A = 2 the
    expectation is infinite).
    """
    a = _frame_count(frames, 3)
    nu = a - 1
    e_inv_chi = math.sqrt(nu / 2.0) * math.exp(math.lgamma((nu - 1) / 2.0) - math.lgamma(nu / 2.0))
    return math.sqrt(a / nu) * e_inv_chi


def _frame_count(frames: int, least: int) -> int:
    if isinstance(frames, bool) or int(frames) != frames or frames < least:
        raise ValueError(
            f"the number of frames A must be a whole number >= {least}, got {frames!r}"
        )
    return int(frames)


@dataclass(frozen=True, slots=True)
class PhotonTransfer:
    """The photon-transfer fit ``sigma_y^2 = K mu_y + sigma_d^2`` (EMVA 1288).

    ``gain_dn_per_e`` is the slope K (DN per electron), ``gain_error_dn_per_e`` its standard
    error (NaN with 2 points), ``dark_variance_dn2`` the intercept (the temporal variance with
    no signal), ``residual_rms_dn2`` the rms misfit, ``points`` the number of points.
    """

    gain_dn_per_e: float
    gain_error_dn_per_e: float
    dark_variance_dn2: float
    residual_rms_dn2: float
    points: int


def photon_transfer(mean_dn: npt.ArrayLike, variance_dn2: npt.ArrayLike) -> PhotonTransfer:
    """System gain ``K`` from the photon transfer of dark-subtracted means and temporal variances.

    docs/physics.md §5 (dark noise in electrons needs the system gain): photon shot noise is
    Poisson, so in electrons the variance of the signal equals its mean, and in DN
    ``sigma_y^2 = K^2 (mu_e + sigma_d,e^2) = K mu_y + sigma_d^2`` with ``mu_y`` the mean above
    dark (EMVA 1288's photon transfer method). An unweighted least-squares line through
    ``(mean_dn, variance_dn2)``; the points must stay below saturation (clipping lowers the
    variance). 2x2-binned data give the unbinned K: electrons and DN both add.
    """
    mean = np.asarray(mean_dn, dtype=np.float64).reshape(-1)
    var = np.asarray(variance_dn2, dtype=np.float64).reshape(-1)
    if mean.shape != var.shape or mean.size < 2:
        raise ValueError(
            "photon transfer needs at least 2 (mean, variance) pairs of equal count, got "
            f"{mean.size} means and {var.size} variances: measure at 2 or more light levels"
        )
    if not (np.isfinite(mean).all() and np.isfinite(var).all()):
        raise ValueError("photon transfer needs finite means and variances")
    if float(np.ptp(mean)) <= 0.0:
        raise ValueError(
            "photon transfer needs different signal levels (all means are equal): vary the "
            "exposure or the light"
        )
    design = np.column_stack([mean, np.ones_like(mean)])
    (slope, intercept), *_ = np.linalg.lstsq(design, var, rcond=None)
    residuals = var - design @ np.array([slope, intercept])
    rss = float(residuals @ residuals)
    dof = mean.size - 2
    if dof > 0:
        covariance = rss / dof * np.linalg.inv(design.T @ design)
        error = math.sqrt(max(float(covariance[0, 0]), 0.0))
    else:
        error = math.nan
    return PhotonTransfer(
        gain_dn_per_e=float(slope),
        gain_error_dn_per_e=error,
        dark_variance_dn2=float(intercept),
        residual_rms_dn2=math.sqrt(rss / mean.size),
        points=int(mean.size),
    )
