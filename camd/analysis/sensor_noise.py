"""The lumped sensor noise model of docs/physics.md §5 (and §3 for 2x2 binning): pure functions.

These equations are what measurements on the simulated (or real) camera are compared with. They
are written from docs/physics.md alone, independently of the simulator (``firmware_models.camera``),
so that a test comparing the two checks both.

Units: electrons (e-) at the pixel, DN (digital numbers, ADC counts) at the output, the system
gain ``K`` in DN per electron. Noise terms are standard deviations; independent terms add in
quadrature (docs/physics.md §5: photon shot noise, dark-current shot noise, read noise, quantisation).

- ``dark_current_e_per_s``: dark current at a temperature (doubling rule)
- ``system_gain_dn_per_e``: ``K`` from conversion gain, analogue gain and ADC full scale
- ``mean_signal_dn``, ``temporal_noise_dn``, ``dark_noise_dn``, ``saturation_dn``
- ``binned_mean_dn``, ``binned_noise_dn`` (docs/physics.md §3)
- ``psnr_db`` (docs/physics.md §5, TAO12 §5.1)
- ``emva_dark_mean_dn``, ``emva_temporal_noise_dn`` (docs/physics.md §5, YE23 eqs 9-13)
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

QUANTISATION_VARIANCE_DN2 = 1.0 / 12.0
"""Variance of rounding to whole DN, ``1/12 DN^2`` (uniform error over one step; docs/physics.md §5)."""


def dark_current_e_per_s(
    reference_e_per_s: float, reference_temp_degc: float, doubling_degc: float, temp_degc: float
) -> float:
    """Dark current at ``temp_degc``: ``I(T) = I_ref * 2^((T - T_ref) / T_double)``.

    docs/physics.md §5 keeps dark-current shot noise as one of the lumped terms; the temperature law
    is the usual doubling rule (the doubling temperature is a per-profile assumption, see
    docs/profiles.md). ``doubling_degc`` must be > 0.
    """
    if not doubling_degc > 0.0:
        raise ValueError(f"doubling_degc must be > 0, got {doubling_degc!r}")
    return reference_e_per_s * math.pow(2.0, (temp_degc - reference_temp_degc) / doubling_degc)


def system_gain_dn_per_e(
    conversion_gain_uv_per_e: float,
    analog_gain: float,
    adc_full_scale_v: float,
    adc_bits: int,
) -> float:
    """System gain ``K = g_conv * G / (V_FS / 2^bits)`` in DN per electron.

    docs/physics.md §5 ("dark noise in electrons needs the system gain"): the charge-to-voltage
    conversion gain ``g_conv`` (uV/e-) times the analogue gain ``G`` gives volts per electron
    at the ADC, and one DN is ``V_FS / 2^bits`` volts.
    """
    lsb_v = adc_full_scale_v / 2.0**adc_bits
    return conversion_gain_uv_per_e * 1e-6 * analog_gain / lsb_v


def mean_signal_dn(
    signal_e: float, dark_e: float, gain_dn_per_e: float, black_level_dn: float
) -> float:
    """Mean output ``K (S + D) + B`` in DN, below saturation.

    docs/physics.md §5: the mean of an unsaturated pixel is the collected charge (signal ``S`` and
    dark charge ``D``, electrons) times the system gain, on top of the black level ``B``.
    Rounding to whole DN leaves the mean unchanged when the noise exceeds about 0.5 DN.
    """
    return gain_dn_per_e * (signal_e + dark_e) + black_level_dn


def temporal_noise_dn(
    signal_e: float, dark_e: float, read_noise_e: float, gain_dn_per_e: float
) -> float:
    """Temporal noise ``sqrt(K^2 (S + D + sigma_read^2) + 1/12)`` in DN.

    docs/physics.md §5, lumped terms: photon shot noise (variance ``S``) and dark-current shot
    noise (variance ``D``) are Poisson, read noise ``sigma_read`` (electrons) is independent
    of both, and quantisation adds ``1/12 DN^2``.
    """
    variance_e2 = signal_e + dark_e + read_noise_e**2
    return math.sqrt(gain_dn_per_e**2 * variance_e2 + QUANTISATION_VARIANCE_DN2)


def dark_noise_dn(dark_e: float, read_noise_e: float, gain_dn_per_e: float) -> float:
    """Temporal dark noise (no light): ``temporal_noise_dn`` with ``S = 0`` (docs/physics.md §5)."""
    return temporal_noise_dn(0.0, dark_e, read_noise_e, gain_dn_per_e)


def saturation_dn(
    full_well_e: float, gain_dn_per_e: float, black_level_dn: float, adc_bits: int
) -> float:
    """The code a saturated pixel gives: ``min(FW K + B, 2^bits - 1)``.

    docs/physics.md §5 (full-well clipping, ADC clipping): the well stops filling at ``FW``
    electrons, the ADC at its largest code; whichever comes first sets the output.
    """
    return min(full_well_e * gain_dn_per_e + black_level_dn, 2.0**adc_bits - 1.0)


def binned_mean_dn(mean_dn: float) -> float:
    """Mean of a 2x2-binned pixel: the sum of 4 neighbours, ``4 x`` (docs/physics.md §3 [YE23])."""
    return 4.0 * mean_dn


def binned_noise_dn(noise_dn: float) -> float:
    """Temporal noise of a 2x2-binned pixel: 4 independent pixels add in quadrature, ``2 x``.

    docs/physics.md §3 [YE23]: binning gives signal x4, temporal dark noise x2, SNR x2.
    """
    return 2.0 * noise_dn


def psnr_db(mean: float, sigma: float) -> float:
    """``PSNR = 20 lg(mean / sigma_RMS)`` in dB (docs/physics.md §5 [TAO12 §5.1])."""
    if not sigma > 0.0:
        raise ValueError(f"sigma must be > 0, got {sigma!r}")
    return 20.0 * math.log10(mean / sigma)


def emva_dark_mean_dn(frames: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """Per-pixel mean over A frames, ``Y(i,j) = mean_m D(i,j,m)`` (docs/physics.md §5, YE23 eq 9).

    ``frames`` has shape (A, rows, cols).
    """
    stack = np.asarray(frames, dtype=np.float64)
    if stack.ndim != 3 or stack.shape[0] < 2:
        raise ValueError(f"need a stack of at least 2 frames (A, rows, cols), got {stack.shape}")
    mean: npt.NDArray[np.float64] = stack.mean(axis=0)
    return mean


def emva_temporal_noise_dn(frames: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """Per-pixel temporal noise ``sqrt(sum_m (D - Y)^2 / A)`` (docs/physics.md §5, YE23 eqs 10, 12).

    As in YE23 the sum is divided by ``A``, not ``A - 1``, so its expectation is
    ``sigma * sqrt((A - 1) / A)`` (0.25 % low for A = 200; 2.5 % low for YE23's A = 20).
    """
    stack = np.asarray(frames, dtype=np.float64)
    mean = emva_dark_mean_dn(stack)
    variance: npt.NDArray[np.float64] = ((stack - mean) ** 2).mean(axis=0)
    noise: npt.NDArray[np.float64] = np.sqrt(variance)
    return noise
