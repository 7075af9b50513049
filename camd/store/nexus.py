"""The NeXus structure of camd's HDF5 files: what general viewers need to show them as images.

camd's scan and recording files keep their own layout at the root (``/lines`` or
``/frames``, the per-line or per-frame columns, the metadata groups). Beside it, each file has
a NeXus entry (NeXus: the NIAC's HDF5 conventions for scientific data, read by nexusformat,
silx and h5web), so that a viewer that knows nothing of camd finds the data, its axes and the
detector that took it::

    /                      NX_class=NXroot, default="entry"
    /entry                 NXentry, default="data": title, start_time, program_name
    /entry/instrument      NXinstrument: name (the camera profile)
    /entry/instrument/detector
                           NXdetector: description, local_name, x_pixel_size, y_pixel_size,
                           bit_depth_readout, frame_time, count_time (SI units in ``units``),
                           and camd's TDI settings (tdi_stages, tdi_mode, tdi_window_rows)
    /entry/data            NXdata: signal="lines" (or "frames"), axes, <axis>_indices;
                           the signal and the per-line (per-frame) axis are hard links to the
                           root's datasets, the column (and row) axes pixel indices

The links are HDF5 hard links: the same dataset under two names, so it grows with the file as
it is written, and the data are stored once. Everything here is made when the file is created
(before it goes to SWMR mode, whose writer may not add objects).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import h5py
import numpy as np
import numpy.typing as npt

__all__ = ["ENTRY", "Axis", "camera_name", "sensor_fields", "write_nexus"]

ENTRY = "entry"  # the NeXus entry's group: reserved, never a metadata group


@dataclass(frozen=True)
class Axis:
    """One axis of the signal: ``link`` names a root dataset to link (a per-line or per-frame
    column), or ``values`` are stored (pixel indices); ``units`` as NeXus writes them."""

    name: str
    link: str | None = None
    values: npt.ArrayLike | None = None
    units: str = ""
    long_name: str = ""


def profile_value(profile: Mapping[str, Any], key: str) -> Any:
    """A camera profile's value as recordings store it (``{"value": v, "source": ...}`` or
    ``v``); None if absent."""
    entry = profile.get(key)
    if isinstance(entry, Mapping):
        return entry.get("value")
    return entry


def camera_name(profile: Mapping[str, Any]) -> str:
    """The camera a file's profile metadata names (its profile, else its sensor)."""
    return str(profile.get("profile") or profile.get("sensor") or "camera")


def sensor_fields(profile: Mapping[str, Any]) -> dict[str, tuple[Any, str]]:
    """The NXdetector fields a camera profile gives: description, sensor, pixel pitch."""
    pitch_m = profile_value(profile, "pitch_m")
    return {
        "description": (profile.get("description"), ""),
        "local_name": (profile.get("sensor"), ""),
        "x_pixel_size": (pitch_m, "m"),
        "y_pixel_size": (pitch_m, "m"),
    }


def write_nexus(
    f: h5py.File,
    *,
    title: str,
    start_time: str,
    program: str,
    instrument: str,
    detector: Mapping[str, tuple[Any, str]],
    signal: str,
    axes: Sequence[Axis],
) -> None:
    """Add the NeXus entry (module docstring) to ``f``, whose root holds ``signal`` and the
    linked axes. ``detector`` maps NXdetector field names to (value, units); a None value is
    left out. The axes are in the signal's dimension order."""
    f.attrs["NX_class"] = "NXroot"
    f.attrs["default"] = ENTRY
    entry = f.create_group(ENTRY)
    entry.attrs["NX_class"] = "NXentry"
    entry.attrs["default"] = "data"
    entry["title"] = title
    entry["start_time"] = start_time
    entry["program_name"] = program
    inst = entry.create_group("instrument")
    inst.attrs["NX_class"] = "NXinstrument"
    inst["name"] = instrument
    det = inst.create_group("detector")
    det.attrs["NX_class"] = "NXdetector"
    for name, (value, units) in detector.items():
        if value is None:
            continue
        det[name] = value
        if units:
            det[name].attrs["units"] = units
    data = entry.create_group("data")
    data.attrs["NX_class"] = "NXdata"
    data.attrs["signal"] = signal
    data.attrs["axes"] = [axis.name for axis in axes]
    data[signal] = f[signal]  # a hard link: the same, growing, dataset
    for index, axis in enumerate(axes):
        if axis.link is not None:
            data[axis.name] = f[axis.link]
        else:
            data.create_dataset(axis.name, data=np.asarray(axis.values))
        node = data[axis.name]
        if axis.units and "units" not in node.attrs:
            node.attrs["units"] = axis.units
        if axis.long_name and "long_name" not in node.attrs:
            node.attrs["long_name"] = axis.long_name
        data.attrs[f"{axis.name}_indices"] = index
