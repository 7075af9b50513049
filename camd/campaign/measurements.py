"""Measurement functions a campaign's ``measure`` steps name (docs/campaigns.md).

A measurement is a plain function registered by name::

    @measurement("stare_stats")
    def stare_stats(inputs: Inputs, *, region: list[int] | None = None) -> Results:
        frames = inputs["frames"].frames()
        ...
        return {"mean_dn": ..., "psnr_db": ...}

``inputs`` maps the step's ``inputs`` names to what acquire steps took (``Acquired``: the HDF5
file and the API's answer); the step's ``args`` arrive as keyword arguments. The function
returns named results: JSON values (numbers, strings, lists, dicts of them); the runner keeps
the names the step lists. The numbers come from camd.analysis (pure functions citing
physics.md); a measurement only reads the data and calls them. Results must depend on the data
alone (no clocks, no file paths): a resumed campaign must reproduce them exactly.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from camd.analysis.emva import Region, region_psnr_db, temporal_dark_noise
from camd.analysis.tdi_snr import along_track_snr

__all__ = ["MEASUREMENTS", "Acquired", "Inputs", "Measurement", "Results", "measurement"]

Results = dict[str, Any]


@dataclass
class Acquired:
    """What one acquire step took: ``how`` (stare, scan, wheel), its HDF5 file and the API's
    answer (``doc``: the stream, scan or wheel acquisition document)."""

    how: str
    path: Path
    doc: dict[str, Any]
    _cache: dict[str, Any] = field(default_factory=dict, repr=False, compare=False)

    def frames(self) -> npt.NDArray[np.uint16]:
        """A stare's (or wheel acquisition's) frames, shape (N, rows, cols)."""
        if "frames" not in self._cache:
            from camd.store.recording import read_recording

            self._cache["frames"] = read_recording(self.path).frames
        frames: npt.NDArray[np.uint16] = self._cache["frames"]
        return frames

    def lines(self) -> npt.NDArray[Any]:
        """A scan's complete TDI lines, shape (L, N)."""
        if "lines" not in self._cache:
            from camd.store.tdi_recording import read_tdi_scan

            scan = read_tdi_scan(self.path)
            self._cache["lines"] = scan.lines[scan.complete]
        lines: npt.NDArray[Any] = self._cache["lines"]
        return lines


Inputs = Mapping[str, Acquired]
Measurement = Callable[..., Results]
MEASUREMENTS: dict[str, Measurement] = {}


def measurement(name: str) -> Callable[[Measurement], Measurement]:
    """Register ``fn`` as the measurement ``name`` (campaign files refer to it by that name)."""

    def register(fn: Measurement) -> Measurement:
        if name in MEASUREMENTS:
            raise ValueError(f"measurement {name!r} is registered twice")
        MEASUREMENTS[name] = fn
        return fn

    return register


def _region(region: list[int] | None) -> Region:
    if region is None:
        return None
    if len(region) != 2:
        raise ValueError(f"region is [rows, cols], got {region}")
    return int(region[0]), int(region[1])


def _input(inputs: Inputs, name: str, function: str) -> Acquired:
    try:
        return inputs[name]
    except KeyError:
        raise ValueError(
            f"{function} needs the input {name!r} (inputs: {{{name}: <acquire step id>}})"
        ) from None


# -- the measurements -------------------------------------------------------------------------


@measurement("stare_stats")
def stare_stats(
    inputs: Inputs, *, region: list[int] | None = None, black_dn: float = 0.0
) -> Results:
    """Mean, spatial sigma and PSNR of a region of stared frames (physics.md §5, TAO12 §5.1):
    ``psnr_db`` is the mean over the frames of ``20 lg(mean / sigma)`` of the region
    (``camd.analysis.emva.region_psnr_db``); ``mean_dn`` and ``sigma_dn`` are the region's
    spatial mean and RMS deviation averaged over the frames. Input ``frames``."""
    frames = _input(inputs, "frames", "stare_stats").frames().astype(np.float64)
    reg = _region(region)
    if reg is not None:
        from camd.analysis.emva import centred_region

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
    """EMVA-style temporal dark noise of dark frames (physics.md §5, eqs 9-10):
    ``dark_mean_dn``, ``dark_noise_dn`` and, given the system gain, ``dark_noise_e``.
    Input ``frames`` (at least 2)."""
    frames = _input(inputs, "frames", "dark_noise").frames()
    result = temporal_dark_noise(frames, region=_region(region), gain_dn_per_e=gain_dn_per_e)
    out: Results = {"dark_mean_dn": result.mean_dn, "dark_noise_dn": result.noise_dn}
    if result.noise_e is not None:
        out["dark_noise_e"] = result.noise_e
    return out


@measurement("scan_flat_snr")
def scan_flat_snr(inputs: Inputs, *, black_dn: float = 0.0) -> Results:
    """Temporal SNR of a TDI scan of a flat field along the track (physics.md §5,
    ``camd.analysis.tdi_snr.along_track_snr``): ``signal_dn``, ``noise_dn`` and ``snr_db``.
    Input ``scan``."""
    lines = _input(inputs, "scan", "scan_flat_snr").lines()
    snr = along_track_snr(lines, black_dn=black_dn)
    return {"signal_dn": snr.signal_dn, "noise_dn": snr.noise_dn, "snr_db": snr.snr_db}
