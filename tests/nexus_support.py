"""Reading camd's files as a NeXus viewer does (nexusformat): the default plot's signal, its
axes and their shapes, and the detector's fields."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from nexusformat.nexus import nxload


def _text(value: Any) -> Any:
    """A string field's value as text (h5py hands variable-length strings back as bytes)."""
    if isinstance(value, np.ndarray) and value.shape == ():
        value = value.item()
    return value.decode() if isinstance(value, bytes) else value


def nexus_plot(path: Path) -> dict[str, Any]:
    """What a NeXus viewer finds in ``path``: the default entry's NXdata (followed through the
    ``default`` attributes, as silx and h5web do), its signal and axes, and the detector."""
    root = nxload(str(path), "r")
    try:
        entry = root[root.attrs["default"]]
        data = entry[entry.attrs["default"]]
        assert root.nxclass == "NXroot" and entry.nxclass == "NXentry"
        assert data.nxclass == "NXdata"
        signal = data.nxsignal
        detector = entry["instrument/detector"]
        assert detector.nxclass == "NXdetector"
        return {
            "signal": signal.nxname,
            "shape": tuple(signal.shape),
            "axes": [(a.nxname, tuple(a.shape)) for a in data.nxaxes],
            "signal_values": signal.nxdata,
            "axis_values": [a.nxdata for a in data.nxaxes],
            "detector": {
                name: (_text(field.nxdata), field.attrs.get("units"))
                for name, field in detector.items()
            },
            "title": _text(entry["title"].nxdata),
        }
    finally:
        root.nxfile.close()
