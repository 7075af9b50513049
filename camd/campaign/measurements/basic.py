"""Basic measurements: stare statistics and PSNR, temporal dark noise, flat-field scan SNR."""

from __future__ import annotations

from typing import Any

import numpy as np

from camd.analysis.emva import centred_region, region_psnr_db, temporal_dark_noise
from camd.analysis.tdi_snr import along_track_snr
from camd.campaign.measurements import (
    Acquired,
    Inputs,
    Results,
    measurement,
    region_arg,
    require_input,
)


@measurement("stare_stats")
def stare_stats(
    inputs: Inputs, *, region: list[int] | None = None, black_dn: float = 0.0
) -> Results:
    """Mean, spatial sigma and PSNR of a region of stared frames (docs/physics.md §5, TAO12 §5.1):
    ``psnr_db`` is the mean over the frames of ``20 lg(mean / sigma)`` of the region
    (``camd.analysis.emva.region_psnr_db``); ``mean_dn`` and ``sigma_dn`` are the region's
    spatial mean and RMS deviation averaged over the frames. Input ``frames``."""
    frames = require_input(inputs, "frames", "stare_stats").frames().astype(np.float64)
    reg = region_arg(region)
    if reg is not None:
        rows, cols = centred_region(frames.shape, *reg)
        crop = frames[:, rows, cols]
    else:
        crop = frames
    psnr = [region_psnr_db(frame, region=reg, black_dn=black_dn) for frame in frames]
    return {
        "mean_dn": float(crop.mean(axis=(1, 2)).mean()) - black_dn,
        "sigma_dn": float(crop.std(axis=(1, 2)).mean()),
        "psnr_db": float(np.mean(psnr)),
        "frames": int(frames.shape[0]),
    }


@measurement("dark_noise")
def dark_noise(
    inputs: Inputs, *, region: list[int] | None = None, gain_dn_per_e: float | None = None
) -> Results:
    """EMVA-style temporal dark noise of dark frames (docs/physics.md §5, eqs 9-10):
    ``dark_mean_dn``, ``dark_noise_dn`` and, given the system gain, ``dark_noise_e``.
    Input ``frames`` (at least 2)."""
    frames = require_input(inputs, "frames", "dark_noise").frames()
    result = temporal_dark_noise(frames, region=region_arg(region), gain_dn_per_e=gain_dn_per_e)
    out: Results = {"dark_mean_dn": result.mean_dn, "dark_noise_dn": result.noise_dn}
    if result.noise_e is not None:
        out["dark_noise_e"] = result.noise_e
    return out


@measurement("scan_flat_snr")
def scan_flat_snr(inputs: Inputs, *, black_dn: float = 0.0) -> Results:
    """Temporal SNR of a TDI scan of a flat field along the track (docs/physics.md §5,
    ``camd.analysis.tdi_snr.along_track_snr``): ``signal_dn``, ``noise_dn`` and ``snr_db``.
    Input ``scan``."""
    lines = require_input(inputs, "scan", "scan_flat_snr").lines()
    snr = along_track_snr(lines, black_dn=black_dn)
    return {"signal_dn": snr.signal_dn, "noise_dn": snr.noise_dn, "snr_db": snr.snr_db}


def _mean_dn(acquired: Acquired, region: list[int] | None) -> float:
    """Mean of a stare's frames (over a centred region) or of a scan's complete lines."""
    if acquired.how == "scan":
        return float(np.mean(acquired.lines(), dtype=np.float64))
    frames = acquired.frames()
    reg = region_arg(region)
    if reg is not None:
        rows, cols = centred_region(frames.shape, *reg)
        frames = frames[:, rows, cols]
    return float(np.mean(frames, dtype=np.float64))


@measurement("light_for_level")
def light_for_level(
    inputs: Inputs,
    *,
    probe_level: float,
    target_dn: float | None = None,
    saturation_dn: float | None = None,
    fraction: float | None = None,
    region: list[int] | None = None,
) -> Results:
    """The light level that gives a wanted signal, scaled from a probe acquisition taken at
    ``probe_level`` (the dark-subtracted signal is proportional to the light between black
    and saturation: docs/physics.md §5's signal model), as a lab engineer sets a light source from
    one trial exposure: ``level = probe_level * wanted / (probe_mean - dark_mean)``.

    The wanted signal above dark is ``target_dn - dark_mean`` (``target_dn``: the mean
    wanted, black included), or ``fraction * saturation_dn`` (``saturation_dn``: saturation
    above dark, e.g. from ``saturation_level``; the probe must then sit at 5 .. 95 % of it,
    where the response is linear and the ratio precise). Inputs ``probe`` and ``dark`` (the
    same acquisition without light), each a stare's frames (``region``: a centred [rows, cols]
    region) or a scan's lines. Results ``level`` (in the probe's units), ``probe_signal_dn``,
    ``black_dn``."""
    probe = _mean_dn(require_input(inputs, "probe", "light_for_level"), region)
    black = _mean_dn(require_input(inputs, "dark", "light_for_level"), region)
    signal = probe - black
    if not signal > 0.0:
        raise ValueError(
            f"light_for_level: the probe's mean ({probe:.4g} DN) is not above the dark mean "
            f"({black:.4g} DN): no signal to scale from; raise probe_level or the exposure"
        )
    if (target_dn is None) == (saturation_dn is None or fraction is None):
        raise ValueError("light_for_level: give either target_dn, or saturation_dn and fraction")
    if target_dn is not None:
        wanted = target_dn - black
        if not wanted > 0.0:
            raise ValueError(
                f"light_for_level: target_dn {target_dn:g} is not above the black level "
                f"{black:.4g} DN; lower the offset or raise the target"
            )
    else:
        assert saturation_dn is not None and fraction is not None  # checked above
        if not (0.0 < fraction < 1.0 and saturation_dn > 0.0):
            raise ValueError(
                f"light_for_level: fraction ({fraction!r}) must be in (0, 1) and saturation_dn "
                f"({saturation_dn!r}) > 0"
            )
        share = signal / saturation_dn
        if not 0.05 <= share <= 0.95:
            raise ValueError(
                f"light_for_level: the probe light ({probe_level:g}) gave {share:.1%} of "
                "saturation; choose a probe_level that gives 5 % .. 95 % (scale it by about "
                f"{fraction / max(share, 1e-9):.3g})"
            )
        wanted = fraction * saturation_dn
    return {"level": probe_level * wanted / signal, "probe_signal_dn": signal, "black_dn": black}


@measurement("pick")
def pick(inputs: Inputs, *, values: list[Any], index: int, name: str) -> Results:
    """One element of a list result (e.g. the M = 1 point of a sweep) as the result ``name``,
    for a check on it alone. No inputs (``from_results: {values: ...}``)."""
    del inputs
    try:
        return {name: values[int(index)]}
    except (IndexError, TypeError):
        raise ValueError(f"pick: no element {index} in {values!r}") from None


@measurement("ratio")
def ratio(
    inputs: Inputs, *, numerator: list[float] | float, denominator: list[float] | float, name: str
) -> Results:
    """Element by element ``numerator / denominator`` (measured over model, say) as the result
    ``name``; a zero or missing denominator gives None. No inputs (``from_results``)."""
    del inputs
    nums = numerator if isinstance(numerator, list) else [numerator]
    dens = denominator if isinstance(denominator, list) else [denominator]
    if len(nums) != len(dens):
        raise ValueError(f"ratio: {len(nums)} numerators against {len(dens)} denominators")
    out = [None if d in (None, 0) or n is None else n / d for n, d in zip(nums, dens, strict=True)]
    return {name: out if isinstance(numerator, list) else out[0]}
