"""Snapshots of the live view (docs/live-view.md, "Snapshots"): what the operator sees, saved.

``snapshot_tiff`` makes a TIFF of the live view's frame in raw DN (uint16, one page) whose
ImageDescription is a JSON document of everything needed to know what the frame is: its
description (seq, counter, time stamp, mode, stages, geometry), the daemon's status (state,
mode, link, device, acquisition), the camera's profile, registers and timing as a recording
stores them, the ROIs and their statistics. The settings are read when the snapshot is taken,
not when the frame was: the frame's own description says which frame it is, and a change of
settings between the two is in the status's events, not here.

``frame_roi_stats`` finds the ROI statistics of the snapshot's own frame in the ROI monitor's
history (every frame is measured; the history holds the newest 4096, the live view's frame is at
most a twentieth of a second old while streaming); ``camd.analysis.roi_table`` makes them a CSV
table, one ROI a row. The TIFF's metadata holds the same statistics, so that a client makes the
same table from the TIFF alone (``camctl snapshot``). Both are built in memory and answered;
``save_snapshot`` writes them, when a client asks (``POST /api/v1/live/snapshot``), into the
data directory's ``snapshots`` folder only: a client names no path on the daemon's computer.
"""

from __future__ import annotations

import errno
import io
import json
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import tifffile

import camd
from camd.analysis.roi import STAT_FIELDS
from camd.daemon.errors import SessionError, StorageFull
from camd.pipeline.live import LiveFrame
from camd.pipeline.roi import RoiHistory
from camd.web import STATIC_DIR

SNAPSHOTS_FOLDER = "snapshots"
"""The data directory's folder where ``POST /api/v1/live/snapshot`` saves."""

SNAPSHOT_FORMAT = "camd live snapshot 1"
"""The ``format`` key of a snapshot's metadata: a reader checks it before relying on the rest."""


def snapshot_name(frame: LiveFrame, suffix: str) -> str:
    """The file name a snapshot of ``frame`` is offered under (the page and camctl use it)."""
    return f"camd-snapshot-{frame.seq}.{suffix}"


def read_or_why(read: Callable[[], Any]) -> Any:
    """``read()``, or ``{"error": why}`` when the daemon cannot read it now (no camera, a
    fault): a snapshot of the frame is still worth having without the registers."""
    try:
        return read()
    except SessionError as exc:
        return {"error": str(exc)}


def snapshot_metadata(frame: LiveFrame, settings: dict[str, Any]) -> dict[str, Any]:
    """The TIFF's ImageDescription: ``frame``'s description and the ``settings`` read now."""
    return {
        "format": SNAPSHOT_FORMAT,
        "taken_t_s": time.time(),
        "frame": frame.meta(),
        "daemon": {"version": camd.__version__},
        **settings,
    }


COLORMAPS_JSON = STATIC_DIR / "live" / "colormaps.json"
"""The page's colour maps (camd.web.colormaps writes them): the PNG uses the same tables."""

DEFAULT_PERCENTILES = (0.1, 99.9)
"""The page's default contrast: the DN at these percentiles shown black and white."""


def colormaps() -> dict[str, npt.NDArray[np.uint8]]:
    """The page's colour maps, name -> 256 x 3 RGB table, in the order the page offers them."""
    tables = json.loads(COLORMAPS_JSON.read_text())
    return {name: np.array(table, dtype=np.uint8) for name, table in tables.items()}


def display_png(
    pixels: npt.NDArray[np.uint16], lo: float, hi: float, lut: npt.NDArray[np.uint8]
) -> bytes:
    """``pixels`` as the page shows them: DN ``lo``..``hi`` onto the 256 entries of ``lut``
    (rounded, clipped at both ends), as an RGB PNG."""
    import cv2  # only here: most of the daemon never draws

    index = np.clip(np.rint((pixels - lo) * (255.0 / (hi - lo))), 0, 255).astype(np.uint8)
    rgb = lut[index]
    ok, png = cv2.imencode(".png", np.ascontiguousarray(rgb[:, :, ::-1]))  # OpenCV is BGR
    if not ok:
        raise RuntimeError("OpenCV could not encode the PNG")
    return bytes(png.tobytes())


def default_contrast(pixels: npt.NDArray[np.uint16]) -> tuple[float, float]:
    """The page's default contrast of ``pixels`` (``DEFAULT_PERCENTILES``); a flat frame
    gets one DN of range."""
    lo, hi = (float(v) for v in np.percentile(pixels, DEFAULT_PERCENTILES))
    return lo, max(hi, lo + 1.0)


def snapshot_tiff(pixels: npt.NDArray[np.uint16], metadata: dict[str, Any]) -> bytes:
    """One uint16 page of ``pixels`` with ``metadata`` as its ImageDescription (JSON)."""
    buffer = io.BytesIO()
    # metadata=None: the description is written as given (tifffile's own JSON would wrap it).
    tifffile.imwrite(
        buffer,
        pixels,
        photometric="minisblack",
        description=json.dumps(metadata),
        metadata=None,
        software=f"camd {camd.__version__}",
    )
    return buffer.getvalue()


def frame_roi_stats(history: RoiHistory, frame: LiveFrame) -> dict[str, dict[str, Any]] | None:
    """Every ROI's statistics (``STAT_FIELDS``, NaN as None) on ``frame``, found in ``history``
    by its counter and time stamp; None if the history does not hold it (the ROIs were changed
    after it, or none is defined)."""
    found = np.flatnonzero(
        (history.counter == frame.counter) & (history.timestamp_ns == frame.timestamp_ns)
    )
    if found.size == 0 or not history.rois:
        return None
    row = history.stats[found[-1]]
    return {
        roi.name: {
            f: None if v != v else v for f, v in zip(STAT_FIELDS, row[i].tolist(), strict=True)
        }
        for i, roi in enumerate(history.rois)
    }


def save_snapshot(folder: Path, frame: LiveFrame, files: dict[str, bytes]) -> list[Path]:
    """Write ``files`` (suffix -> content) as ``camd-snapshot-<UTC time>-seq<seq>.<suffix>`` in
    ``folder`` (made if needed), never over a file; all or none: StorageFull (and nothing left)
    if the disk is full."""
    folder.mkdir(exist_ok=True)
    stamp = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime())
    written: list[Path] = []
    try:
        for suffix, content in files.items():
            path = folder / f"camd-snapshot-{stamp}-seq{frame.seq}.{suffix}"
            with path.open("xb") as out:  # x: a name taken is an error, never an overwrite
                written.append(path)
                out.write(content)
    except OSError as exc:
        for path in written:
            path.unlink(missing_ok=True)
        if exc.errno in (errno.ENOSPC, errno.EDQUOT):
            raise StorageFull(f"the snapshot did not fit in {folder}: {exc.strerror}") from None
        raise
    return written
