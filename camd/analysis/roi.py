"""Region-of-interest statistics: named rectangles of a frame and their per-frame figures.

What areaDetector's statistics plugin gives per region, computed the same way for the daemon's
live monitor (``camd.pipeline.roi``, on every frame of a stream) and for tests and scripts
that check it against recorded frames:

- ``Roi``: a named rectangle, ``x`` (first column) and ``y`` (first row) from the frame's top
  left, ``width`` columns by ``height`` rows, all in pixels.
- ``roi_problem``: why a set of ROIs cannot be measured on a frame of ``rows`` x ``cols``
  (None if it can): every bad input gets a message that says what to change.
- ``roi_stats``: the statistics of every ROI in each of K frames, one vectorised pass per ROI
  over all K frames: a float64 array (K, ROIs, len(STAT_FIELDS)).

Per ROI and frame (``STAT_FIELDS``): mean, standard deviation (population, ddof=0), min, max
and sum in DN; SNR = mean / std (NaN when std is 0: a flat region has no defined SNR); the
count of saturated pixels (at or above full scale, ``2**bits - 1``); and the mean minus the
background's mean over the same rectangle (NaN without a background). The sum and the sum of
squares are exact (int64); the standard deviation comes from them in float64.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

ROIS_MAX = 16
"""ROIs measured at once at most: each costs a pass over its pixels on every frame."""
NAME_PATTERN = re.compile(r"[A-Za-z0-9_.-]{1,32}")
"""An ROI's name: 1-32 letters, digits, '_', '.', '-' (it names an HDF5 group and a CLI arg)."""
RESERVED_NAMES = frozenset({"frame"})
"""Names no ROI may take: the focus aid lists the whole frame's figure beside the ROIs' by name."""

STAT_FIELDS = (
    "mean_dn",
    "std_dn",
    "min_dn",
    "max_dn",
    "sum_dn",
    "snr",
    "saturated",
    "bg_mean_dn",
)
"""The per-frame statistics of an ROI, in the order of ``roi_stats``'s last axis."""


@dataclass(frozen=True, slots=True)
class Roi:
    """A named rectangle of a frame, in pixels: columns x .. x + width - 1, rows y .. y +
    height - 1 (x, y from the top left)."""

    name: str
    x: int
    y: int
    width: int
    height: int

    def as_dict(self) -> dict[str, int | str]:
        return {
            "name": self.name,
            "x": self.x,
            "y": self.y,
            "width": self.width,
            "height": self.height,
        }


def roi_problem(roi: Roi, rows: int, cols: int) -> str | None:
    """Why ``roi`` does not fit a frame of ``rows`` x ``cols`` (None if it does)."""
    if not NAME_PATTERN.fullmatch(roi.name):
        return f"ROI name {roi.name!r} is not valid: use 1-32 letters, digits, '_', '.' or '-'"
    if roi.name in RESERVED_NAMES:
        return (
            f"ROI name {roi.name!r} names the whole frame (the focus aid's target): choose another"
        )
    if roi.width < 1 or roi.height < 1:
        return (
            f"ROI {roi.name!r} is {roi.width} x {roi.height} pixels: width and height must be "
            "at least 1"
        )
    if roi.x < 0 or roi.y < 0:
        return f"ROI {roi.name!r} starts at x={roi.x}, y={roi.y}: x and y must be 0 or more"
    if roi.x + roi.width > cols or roi.y + roi.height > rows:
        return (
            f"ROI {roi.name!r} (x={roi.x}, y={roi.y}, {roi.width} x {roi.height}) reaches "
            f"column {roi.x + roi.width - 1}, row {roi.y + roi.height - 1}, outside the "
            f"{cols} x {rows} frame (columns 0..{cols - 1}, rows 0..{rows - 1}): make it "
            "smaller or move it"
        )
    return None


def rois_problem(rois: Sequence[Roi], rows: int, cols: int) -> str | None:
    """Why the set ``rois`` cannot be measured on ``rows`` x ``cols`` frames (None if it can):
    each must fit, names must differ, at most ROIS_MAX."""
    if len(rois) > ROIS_MAX:
        return f"{len(rois)} ROIs: at most {ROIS_MAX} are measured at once; delete some first"
    seen: set[str] = set()
    for roi in rois:
        if roi.name in seen:
            return f"ROI {roi.name!r} is defined twice: give each ROI its own name"
        seen.add(roi.name)
        problem = roi_problem(roi, rows, cols)
        if problem is not None:
            return problem
    return None


def background_means(
    background: npt.NDArray[np.floating] | None, rois: Sequence[Roi]
) -> npt.NDArray[np.float64]:
    """The background's mean over each ROI (NaN for all without one, or for an ROI it does
    not cover): computed once per background, subtracted from every frame's means."""
    out = np.full(len(rois), np.nan)
    if background is None:
        return out
    rows, cols = background.shape
    for i, r in enumerate(rois):
        if roi_problem(r, rows, cols) is None:
            out[i] = float(background[r.y : r.y + r.height, r.x : r.x + r.width].mean())
    return out


def roi_stats(
    frames: npt.NDArray[np.uint16],
    rois: Sequence[Roi],
    bits: int,
    bg_means: npt.NDArray[np.float64] | None = None,
) -> npt.NDArray[np.float64]:
    """The statistics (``STAT_FIELDS``) of each ROI in each frame: (K, ROIs, fields).

    ``frames``: (K, rows, cols) or one (rows, cols) frame (K = 1). Every ROI must fit
    (``rois_problem``). ``bits``: the stream's pixel depth (full scale ``2**bits - 1``).
    ``bg_means``: ``background_means`` for these ROIs, or None."""
    stack = frames[np.newaxis] if frames.ndim == 2 else frames
    k = stack.shape[0]
    out = np.empty((k, len(rois), len(STAT_FIELDS)))
    full_scale = (1 << bits) - 1
    for i, r in enumerate(rois):
        sub = stack[:, r.y : r.y + r.height, r.x : r.x + r.width]
        n = r.width * r.height
        total = sub.sum(axis=(1, 2), dtype=np.int64)
        # The sum of squares exact in int64 (below 2^63 for any ROI under 2^31 pixels), the variance
        # from the two exact sums: a quarter less time per frame than np.std (its float64
        # copy and second pass) in camd bench's case; a flat region gives exactly 0.
        squares = np.einsum("kij,kij->k", sub, sub, dtype=np.int64)
        mean = total / n
        std = np.sqrt(np.maximum(squares / n - mean * mean, 0.0))
        top = sub.max(axis=(1, 2))
        col = out[:, i]
        col[:, 0] = mean
        col[:, 1] = std
        col[:, 2] = sub.min(axis=(1, 2))
        col[:, 3] = top
        col[:, 4] = total
        with np.errstate(divide="ignore", invalid="ignore"):
            col[:, 5] = mean / std
        col[std == 0, 5] = np.nan
        # Counted only in the frames that reach full scale (most frames do not).
        col[:, 6] = 0
        hit = np.flatnonzero(top >= full_scale)
        if hit.size:
            col[hit, 6] = np.count_nonzero(sub[hit] >= full_scale, axis=(1, 2))
        col[:, 7] = mean - (bg_means[i] if bg_means is not None else np.nan)
    return out
