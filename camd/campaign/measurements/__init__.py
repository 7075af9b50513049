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
docs/physics.md); a measurement only reads the data and calls them. Results must depend on the data
alone (no clocks, no file paths): a resumed campaign must reproduce them exactly.

The functions live in the modules of this package, one per kind of measurement (``basic``:
stare statistics, dark noise, flat-field scan SNR; the others as their docstrings say); every
module here is imported when the package is, so registering is all a new module has to do.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from camd.analysis.emva import Region
from camd.campaign.registry import register_in

if TYPE_CHECKING:
    from camd.store.recording_reading import Recording
    from camd.store.tdi_recording import TdiScan

__all__ = [
    "MEASUREMENTS",
    "Acquired",
    "Inputs",
    "Measurement",
    "Results",
    "measurement",
    "region_arg",
    "require_input",
]

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
        frames: npt.NDArray[np.uint16] = self._recording().frames
        return frames

    def scan(self) -> TdiScan:
        """A scan's whole file: lines, their bookkeeping, metadata (camd.store.tdi_recording)."""
        if "scan" not in self._cache:
            from camd.store.tdi_recording import read_tdi_scan

            self._cache["scan"] = read_tdi_scan(self.path)
        scan: TdiScan = self._cache["scan"]
        return scan

    def lines(self) -> npt.NDArray[Any]:
        """A scan's complete TDI lines, shape (L, N)."""
        scan = self.scan()
        lines: npt.NDArray[Any] = scan.lines[scan.complete]
        return lines

    def metadata(self) -> dict[str, dict[str, Any]]:
        """The file's metadata groups (profile, registers, timing, stream or scan, ...)."""
        return self.scan().metadata if self.how == "scan" else self._recording().metadata

    def _recording(self) -> Recording:
        if "recording" not in self._cache:
            from camd.store.recording_reading import read_recording

            self._cache["recording"] = read_recording(self.path)
        recording: Recording = self._cache["recording"]
        return recording


Inputs = Mapping[str, Acquired]
Measurement = Callable[..., Results]
MEASUREMENTS: dict[str, Measurement] = {}


def measurement(name: str) -> Callable[[Measurement], Measurement]:
    """Register ``fn`` as the measurement ``name`` (campaign files refer to it by that name)."""
    return register_in(MEASUREMENTS, "measurement", name)


def region_arg(region: list[int] | None) -> Region:
    """A campaign's ``region: [rows, cols]`` argument as camd.analysis takes it."""
    if region is None:
        return None
    if len(region) != 2:
        raise ValueError(f"region is [rows, cols], got {region}")
    return int(region[0]), int(region[1])


def require_input(inputs: Inputs, name: str, function: str) -> Acquired:
    """``inputs[name]``, or a ValueError saying how to give it."""
    try:
        return inputs[name]
    except KeyError:
        raise ValueError(
            f"{function} needs the input {name!r} (inputs: {{{name}: <acquire step id>}})"
        ) from None


def _register_all() -> None:
    import importlib
    import pkgutil

    for module in pkgutil.iter_modules(__path__):
        importlib.import_module(f"{__name__}.{module.name}")


_register_all()
