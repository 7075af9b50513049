"""Quicklook images: an 8-bit PNG of a TDI scan for an engineer's eye, not for measurement."""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from camd.store.recording import RecordingError

MARKER_BGR = (0, 0, 255)  # red: a greyscale image never has it
MARKER_COLUMNS = 3
# The stretch's percentiles come from at most this many pixels (evenly spaced lines).
_PERCENTILE_PIXELS = 1 << 22


def _stretch_limits(
    image: npt.NDArray[Any], rows: npt.NDArray[np.bool_] | None, low_pct: float, high_pct: float
) -> tuple[float, float]:
    sample = image[rows] if rows is not None and rows.any() else image
    step = max(1, math.ceil(sample.size / _PERCENTILE_PIXELS))
    values = sample[::step].astype(np.float64).ravel()
    values = values[np.isfinite(values)]
    if values.size == 0:
        return 0.0, 0.0
    low, high = np.percentile(values, [low_pct, high_pct])
    return float(low), float(high)


def write_quicklook_png(
    path: Path | str,
    image: npt.ArrayLike,
    *,
    complete: npt.ArrayLike | None = None,
    low_pct: float = 0.5,
    high_pct: float = 99.5,
    max_lines: int = 4096,
) -> Path:
    """Write an (L, N) TDI image as an 8-bit PNG at ``path`` (a ``.png`` name); return the path.

    The grey levels are stretched linearly so that the ``low_pct`` percentile of the complete
    lines (of all lines when ``complete`` is None or no line is complete) is 0 and the
    ``high_pct`` percentile is 255, clipped outside; on a huge image the percentiles come from
    about 4 M pixels of evenly spaced lines. A flat stretch (both percentiles equal) draws pixels
    at that level mid-grey (128), below it black, above it white. NaN pixels are black.

    ``complete`` (L,) bool marks each line; lines that are not complete get a red band over their
    first 3 columns, and then the PNG is 3-channel (BGR) instead of greyscale. An image of more
    than ``max_lines`` lines is shrunk to ``max_lines`` lines by averaging neighbouring lines
    (cv2.INTER_AREA); a shrunk line is marked when any line in it is incomplete.

    The file is written next to ``path`` and renamed onto it, so a viewer never reads half a
    PNG; an existing file is replaced. ValueError for a bad shape, type, percentile or
    ``max_lines``; RecordingError if the PNG cannot be written.
    """
    path = Path(path)
    if path.suffix.lower() != ".png":
        raise ValueError(f"a quicklook is a PNG: give a path ending in .png, not {path.name!r}")
    img = np.asarray(image)
    if img.ndim != 2 or img.shape[0] < 1 or img.shape[1] < 1:
        raise ValueError(
            f"a quicklook image must be 2-D (lines, columns) with at least one of each; got "
            f"shape {img.shape}"
        )
    if img.dtype.kind not in "iuf":
        raise ValueError(f"a quicklook image must be integers or floats; got {img.dtype}")
    n_lines, width = img.shape
    rows: npt.NDArray[np.bool_] | None = None
    if complete is not None:
        rows = np.asarray(complete)
        if rows.shape != (n_lines,) or rows.dtype.kind != "b":
            raise ValueError(
                f"complete must be a bool array with one value per line, shape ({n_lines},); "
                f"got {rows.dtype} with shape {rows.shape}"
            )
    if not 0.0 <= low_pct < high_pct <= 100.0:
        raise ValueError(
            f"the stretch needs 0 <= low_pct < high_pct <= 100; got {low_pct} and {high_pct}"
        )
    if isinstance(max_lines, bool) or not isinstance(max_lines, int) or max_lines < 1:
        raise ValueError(f"max_lines must be a whole number of lines >= 1; got {max_lines!r}")

    # Here, not at the top: only a scan's quicklook needs OpenCV, and the daemon, which imports
    # this module, then starts without it (25 ms of a core at each start).
    import cv2

    low, high = _stretch_limits(img, rows, low_pct, high_pct)
    pixels: npt.NDArray[Any] = img
    incomplete = None if rows is None else ~rows
    if n_lines > max_lines:
        size = (width, max_lines)  # cv2 takes (width, height)
        pixels = cv2.resize(img.astype(np.float32), size, interpolation=cv2.INTER_AREA)
        if incomplete is not None:
            share = cv2.resize(
                incomplete.astype(np.float32).reshape(n_lines, 1),
                (1, max_lines),
                interpolation=cv2.INTER_AREA,
            )
            incomplete = share.reshape(max_lines) > 0
    values = np.nan_to_num(pixels.astype(np.float64), nan=low - 1.0, posinf=high, neginf=low)
    if high > low:
        scaled = np.clip((values - low) * (255.0 / (high - low)), 0.0, 255.0)
        grey = np.rint(scaled).astype(np.uint8)
    else:
        grey = np.where(values > low, 255, np.where(values < low, 0, 128)).astype(np.uint8)
    out: npt.NDArray[np.uint8] = grey
    if incomplete is not None and incomplete.any():
        out = np.repeat(grey[:, :, np.newaxis], 3, axis=2)
        out[incomplete, :MARKER_COLUMNS] = MARKER_BGR

    tmp = path.with_name(f".{path.stem}.{os.getpid()}.tmp.png")
    try:
        written = bool(cv2.imwrite(str(tmp), out))
    except cv2.error as exc:
        written = False
        detail = f": {exc}"
    else:
        detail = ""
    if not written:
        tmp.unlink(missing_ok=True)
        raise RecordingError(
            f"cannot write the quicklook {path}{detail}; check that {path.parent} exists and "
            "is writable"
        )
    try:
        tmp.replace(path)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise RecordingError(f"cannot write the quicklook {path}: {exc}") from None
    return path
