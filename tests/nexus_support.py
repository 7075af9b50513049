"""Reading camd's files as NeXus tools do: the default plot as nexusformat finds it (its signal,
axes and their shapes, the detector's fields), what nexusformat's validator (``nxcheck``)
reports, and silx's view of the NXdata."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import hdf5plugin  # noqa: F401  # registers HDF5's compression filters for every reader here
import numpy as np
from nexusformat.nexus import NXfield, nxload
from nexusformat.nexus.validate import logger as nxcheck_logger
from nexusformat.nexus.validate import validate_file


def _text(value: Any) -> Any:
    """A string field's value as text (h5py hands variable-length strings back as bytes)."""
    if isinstance(value, np.ndarray) and value.shape == ():
        value = value.item()
    return value.decode() if isinstance(value, bytes) else value


def nexus_plot(path: Path) -> dict[str, Any]:
    """What a NeXus viewer finds in ``path``: the default entry's NXdata (followed through the
    ``default`` attributes, as silx and h5web do), its signal and axes, and the detector's
    fields (its groups left out)."""
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
            "signal_attrs": {name: _text(value) for name, value in signal.attrs.items()},
            "axes": [(a.nxname, tuple(a.shape)) for a in data.nxaxes],
            "signal_values": signal.nxdata,
            "axis_values": [a.nxdata for a in data.nxaxes],
            "detector": {
                name: (_text(field.nxdata), field.attrs.get("units"))
                for name, field in detector.items()
                if isinstance(field, NXfield)
            },
            # camd's TDI settings, an NXcollection under the detector (no NXdetector field)
            "tdi": {
                name: _text(field.nxdata)
                for name, field in (detector["tdi"].items() if "tdi" in detector else ())
            },
            "title": _text(entry["title"].nxdata),
        }
    finally:
        root.nxfile.close()


class _Collect(logging.Handler):
    """Keeps the validator's messages: its headers (each object's path, at CRITICAL) and what
    it says of each (WARNING, ERROR)."""

    def __init__(self) -> None:
        super().__init__(logging.DEBUG)
        self.records: list[logging.LogRecord] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.records.append(record)


def nxcheck(path: Path) -> dict[str, list[str]]:
    """What ``nxcheck -i path`` reports (nexusformat's validator against the NeXus base
    classes): ``{"warning": [...], "error": [...], "groups": [...]}``, each message prefixed
    with the path of the object it is about (``"/: \\"@format\\" is not defined as an
    attribute in NXroot"``), and every group it inspected (``"NXparameters: /entry/timing"``)."""
    collect = _Collect()
    level = nxcheck_logger.level
    nxcheck_logger.addHandler(collect)
    nxcheck_logger.setLevel(logging.INFO)  # every group inspected, not only those it warns of
    try:
        validate_file(str(path))
    finally:
        nxcheck_logger.removeHandler(collect)
        nxcheck_logger.setLevel(level)
    found: dict[str, list[str]] = {"warning": [], "error": [], "groups": []}
    where = ""
    for record in collect.records:
        text = record.getMessage().strip()
        if record.levelno == logging.CRITICAL:
            # "NXroot: /", "Field: /lines", "NXdata: /entry/data": the object the next are about
            if ": /" in text:
                kind, where = text.split(": ", 1)
                if kind.startswith("NX"):
                    found["groups"].append(text)
            continue
        if record.levelno in (logging.WARNING, logging.ERROR):
            level_name = "warning" if record.levelno == logging.WARNING else "error"
            found[level_name].append(f"{where}: {text}")
    return found


def silx_nxdata(path: Path) -> dict[str, Any]:
    """silx's view of the default plot (``silx.io.nxdata``): valid or why not, its
    interpretation, and whether silx shows it as an image (a stack of images)."""
    import h5py
    from silx.io import nxdata

    with h5py.File(path, "r") as f:
        group = nxdata.get_default(f)
        assert group is not None, "silx finds no default NXdata"
        return {
            "valid": group.is_valid,
            "issues": list(group.issues),
            "interpretation": group.interpretation,
            "is_image": group.is_image,
            "signal_is_3d": group.signal_is_3d,
            "signal": group.signal.name.rsplit("/", 1)[-1],
            "signal_long_name": group.signal_name,
            "axes_names": list(group.axes_dataset_names),
        }
