"""EMVA-style SNR against exposure on 2x2-binned frames (docs/physics.md §3, §5; YE23 §5.1).

The measurements of config/campaigns/emva_snr_exposure.yaml, in the order it uses them:

- ``exposure_lines``, ``longest_exposure_lines``: whole exposure lines for an exposure in ms,
  with the line period read from a recording's timing (the registers count lines).
- ``saturation_level``: the binned output's saturation signal above dark, from frames taken
  with far more light than the well holds (refused if they are not saturated).
- ``light_for_fraction``: the scene level that puts the signal at a fraction of saturation,
  scaled from a probe level's measured signal (the response is linear below saturation).
- ``emva_point``: eqs 9-13 at one exposure (signal, temporal noise and variance, SNR, dark
  noise), on frames the FPGA binned.
- ``photon_transfer_gain``: the system gain K from variance against mean over the exposures.
- ``emva_model``: the measured SNR and dark noise against the model of docs/physics.md §5 with the
  profile's parameters (as the daemon recorded them in each file's ``profile`` group), and
  against the photon-transfer model of the measured K.

The formulas are camd.analysis's (``emva``, ``sensor_noise``); this module reads the data and
composes them.
"""

from __future__ import annotations

import math

import numpy as np

from camd.analysis.emva import (
    centred_region,
    eq10_expectation_factor,
    eq13_expectation_factor,
    photon_transfer,
    temporal_dark_noise,
    temporal_snr,
)
from camd.analysis.sensor_noise import binned_mean_dn, binned_noise_dn, temporal_noise_dn
from camd.analysis.sensor_noise import dark_noise_dn as model_dark_noise_dn
from camd.analysis.sensor_noise import saturation_dn as model_saturation_dn
from camd.campaign.measurements import (
    Acquired,
    Inputs,
    Results,
    measurement,
    region_arg,
    require_input,
)
from camd.sensor.profile import CameraProfile


def _lines(acquired: Acquired, exposure_ms: float) -> int:
    """``round(T_exp / T_line)`` (docs/physics.md §3: T_exp = n T_line), T_line from the file."""
    line_period_s = float(acquired.metadata()["timing"]["line_period_s"])
    exposure_s = float(exposure_ms) * 1e-3
    lines = round(exposure_s / line_period_s)
    if not (math.isfinite(exposure_s) and lines >= 1):
        raise ValueError(
            f"exposure {exposure_ms!r} ms is less than half a line ({line_period_s * 1e6:.4g} "
            "us): give at least one line"
        )
    return int(lines)


@measurement("exposure_lines")
def exposure_lines(inputs: Inputs, *, exposure_ms: float) -> Results:
    """``exposure_lines``: whole lines for ``exposure_ms`` (docs/physics.md §3), the line period
    from the input ``recording``'s timing; a configure step writes it to ``EXPOSURE``."""
    return {
        "exposure_lines": _lines(require_input(inputs, "recording", "exposure_lines"), exposure_ms)
    }


@measurement("longest_exposure_lines")
def longest_exposure_lines(inputs: Inputs, *, exposures_ms: list[float]) -> Results:
    """``longest_exposure_lines`` and ``longest_exposure_ms``: the longest of ``exposures_ms``
    in whole lines (as ``exposure_lines``; input ``recording``)."""
    if not exposures_ms:
        raise ValueError("exposures_ms is empty: give the exposures of the sweep")
    longest = max(float(e) for e in exposures_ms)
    acquired = require_input(inputs, "recording", "longest_exposure_lines")
    return {"longest_exposure_lines": _lines(acquired, longest), "longest_exposure_ms": longest}


@measurement("saturation_level")
def saturation_level(inputs: Inputs, *, region: list[int] | None = None) -> Results:
    """``saturation_dn``: the region mean of ``saturated`` frames minus that of ``dark`` frames
    at the same exposure (EMVA 1288's ``mu_y.sat - mu_y.dark``), and ``saturated_noise_dn``
    (eq 12's temporal noise of the saturated frames).

    A saturated output no longer follows the light, so its temporal noise is far below the
    dark noise; if it is not below half the dark noise the frames were not saturated and the
    measurement says to raise the light.
    """
    saturated = require_input(inputs, "saturated", "saturation_level").frames()
    dark = require_input(inputs, "dark", "saturation_level").frames()
    reg = region_arg(region)
    stack = saturated.astype(np.float64)
    if reg is not None:
        rows, cols = centred_region(stack.shape, *reg)
        stack = stack[:, rows, cols]
    noise = float(stack.std(axis=0).mean())
    dark_stats = temporal_dark_noise(dark, region=reg)
    if not noise < 0.5 * dark_stats.noise_dn:
        raise ValueError(
            f"the frames meant to be saturated still have {noise:.3g} DN of temporal noise "
            f"(dark noise {dark_stats.noise_dn:.3g} DN): they are not saturated; raise the "
            "saturating light level"
        )
    return {
        "saturation_dn": float(stack.mean()) - dark_stats.mean_dn,
        "saturated_noise_dn": noise,
    }


@measurement("emva_point")
def emva_point(inputs: Inputs, *, region: list[int] | None = None) -> Results:
    """Eqs 9-13 of docs/physics.md §5 at one exposure, on ``frames`` and ``dark`` frames (already
    2x2-binned by the FPGA for YE23's measurement; the region counts output pixels).

    ``signal_dn`` (eq 11), ``temporal_noise_dn`` (eq 12), ``snr`` (eq 13) and ``snr_db``;
    ``variance_dn2``: the region mean of the per-pixel temporal variance with divisor A - 1
    (unbiased; the photon transfer's y); ``exposure_dark_mean_dn`` and
    ``exposure_dark_noise_dn`` (eqs 9-10); ``exposure_set_ms``: the exposure the registers
    gave, from the frames' recording.
    """
    frames_in = require_input(inputs, "frames", "emva_point")
    frames = frames_in.frames()
    dark = require_input(inputs, "dark", "emva_point").frames()
    reg = region_arg(region)
    eq = temporal_snr(frames, dark, region=reg)
    unbiased = temporal_snr(frames, dark, region=reg, bessel=True)
    return {
        "exposure_set_ms": float(frames_in.metadata()["timing"]["exposure_s"]) * 1e3,
        "signal_dn": eq.signal_dn,
        "temporal_noise_dn": eq.noise_dn,
        "variance_dn2": unbiased.noise_rms_dn**2,
        "snr": eq.snr,
        "snr_db": eq.snr_db,
        "exposure_dark_mean_dn": eq.dark.mean_dn,
        "exposure_dark_noise_dn": eq.dark.noise_dn,
    }


@measurement("photon_transfer_gain")
def photon_transfer_gain(
    inputs: Inputs, *, mean_dn: list[float], variance_dn2: list[float]
) -> Results:
    """The system gain K from the photon transfer (``camd.analysis.emva.photon_transfer``):
    ``system_gain_dn_per_e``, ``system_gain_error_dn_per_e``, ``ptc_dark_variance_dn2``, and
    the fitted line at each point, ``ptc_variance_model_dn2``. Give the sweep's
    dark-subtracted means and temporal variances (``from_results``)."""
    fit = photon_transfer(mean_dn, variance_dn2)
    line = [fit.gain_dn_per_e * float(m) + fit.dark_variance_dn2 for m in mean_dn]
    return {
        "system_gain_dn_per_e": fit.gain_dn_per_e,
        "system_gain_error_dn_per_e": fit.gain_error_dn_per_e,
        "ptc_dark_variance_dn2": fit.dark_variance_dn2,
        "ptc_variance_model_dn2": line,
    }


@measurement("emva_model")
def emva_model(
    inputs: Inputs,
    *,
    frames: int,
    exposure_ms: list[float],
    signal_dn: list[float],
    snr: list[float],
    dark_noise_dn: list[float],
    gain_dn_per_e: float,
    ptc_dark_variance_dn2: float,
    saturation_dn: float,
) -> Results:
    """Measured SNR and dark noise of 2x2-binned pixels against docs/physics.md §5's model.

    The model, per exposure t with the measured binned signal Y (DN above dark): each of the
    4 summed pixels holds ``S = Y / (4 K)`` signal and ``D = I_dark t`` dark electrons, its
    noise is ``sqrt(K^2 (S + D + sigma_read^2) + 1/12)`` DN (shot, dark shot, read,
    quantisation: ``temporal_noise_dn``), and the sum has 4 x the signal and 2 x the noise
    (docs/physics.md §3). K, sigma_read and I_dark are the profile's (the input ``recording``'s
    ``profile`` group, the gain setting from its ``timing``). Eq 13 averages per-pixel
    ratios and so reads ``eq13_expectation_factor(frames)`` (1.069 at 20 frames) above
    ``Y / noise``: ``snr_model`` is that expectation, ``snr_ratio`` measured / model.
    ``snr_ptc_model`` is the same with the photon transfer's noise, ``sqrt(K Y + sigma_d^2)``
    (measured K and intercept).

    Dark noise at the shortest exposure: ``dark_noise_dn`` (eq 10), ``dark_noise_e`` (divided
    by the measured K), ``dark_noise_e_nominal`` (the profile's read noise, 37.2 e- on the
    hr400, x2 for the binned sum), ``dark_noise_e_model`` (what eq 10 should read: the
    binned dark noise with dark shot noise and quantisation, times
    ``eq10_expectation_factor(frames)``, 0.962 at 20) and ``dark_noise_ratio``.
    ``profile_gain_dn_per_e`` and ``gain_ratio`` (measured / profile), ``saturation_model_dn``
    (4 x (min(FW K + B, ADC max) - B)) and ``light_fraction`` (signal at the longest exposure
    over saturation).
    """
    n = len(exposure_ms)
    if not n or not (len(signal_dn) == len(snr) == len(dark_noise_dn) == n):
        raise ValueError(
            "exposure_ms, signal_dn, snr and dark_noise_dn must be lists over the same "
            f"exposures, got lengths {n}, {len(signal_dn)}, {len(snr)}, {len(dark_noise_dn)}"
        )
    if not gain_dn_per_e > 0.0:
        raise ValueError(f"the measured system gain must be > 0 DN/e-, got {gain_dn_per_e!r}")
    meta = require_input(inputs, "recording", "emva_model").metadata()
    profile = CameraProfile.model_validate(meta["profile"])
    timing = meta["timing"]
    k = profile.system_gain_dn_per_e(profile.analog_gain_factor(timing.get("gain")))
    black = profile.black_level_for(timing.get("offset"))
    read_e = profile.read_noise_e.value
    dark_e_per_s = profile.dark_current_e_per_s.value
    eq13 = eq13_expectation_factor(frames)

    snr_model: list[float] = []
    snr_ptc: list[float] = []
    for t_ms, y in zip(exposure_ms, signal_dn, strict=True):
        pixel_e = y / binned_mean_dn(k)  # the signal of one of the 4 summed pixels
        noise = binned_noise_dn(temporal_noise_dn(pixel_e, dark_e_per_s * t_ms * 1e-3, read_e, k))
        snr_model.append(eq13 * y / noise)
        snr_ptc.append(eq13 * y / math.sqrt(gain_dn_per_e * y + ptc_dark_variance_dn2))

    shortest = int(np.argmin(exposure_ms))
    dark_dn = float(dark_noise_dn[shortest])
    dark_model_dn = eq10_expectation_factor(frames) * binned_noise_dn(
        model_dark_noise_dn(dark_e_per_s * exposure_ms[shortest] * 1e-3, read_e, k)
    )
    dark_e = dark_dn / gain_dn_per_e
    dark_model_e = dark_model_dn / k
    longest = int(np.argmax(exposure_ms))
    sat_model = binned_mean_dn(
        model_saturation_dn(profile.full_well_e.value, k, black, profile.adc_bits.value) - black
    )
    return {
        "dark_noise_dn": dark_dn,
        "dark_noise_e": dark_e,
        "dark_noise_e_nominal": binned_noise_dn(read_e),
        "dark_noise_e_model": dark_model_e,
        "dark_noise_ratio": dark_e / dark_model_e,
        "profile_gain_dn_per_e": k,
        "gain_ratio": gain_dn_per_e / k,
        "snr_model": snr_model,
        "snr_ptc_model": snr_ptc,
        "snr_ratio": [m / e for m, e in zip(snr, snr_model, strict=True)],
        "eq13_factor": eq13,
        "saturation_model_dn": sat_model,
        "light_fraction": float(signal_dn[longest]) / saturation_dn,
    }
