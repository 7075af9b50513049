"""The plain numpy TDI path: the reference every faster kernel must match bit for bit.

The state is a ring of M partial sums (``acc``, M x N): the partial sum of line L lives in row
``L % M``, and the row of a line that has no contribution yet is zero (the successive-
accumulation form of docs/physics.md §1 [YUAN13 Table 2], with the ring addressing of DONG16 §2.3).
A block of F frames is done by the direct formula over stages, one vectorised add per stage, on
an extended buffer holding the block's lines and the M - 1 lines still open after it.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from camd.tdi.taps import StageTaps

Frames = npt.NDArray[np.uint16]
Sums = npt.NDArray[np.unsignedinteger]


def stage_values(frames: Frames, taps: StageTaps, stage: int) -> Sums:
    """What stage ``stage`` adds to each frame's line, in units of 1/``taps.one`` DN: (F, N).

    docs/tdi.md (the fixed-point interpolation): columns whose taps fall outside the frame add 0.
    """
    count, _, width = frames.shape
    dtype = taps.accumulator
    values = np.zeros((count, width), dtype=dtype)
    r0, wy = int(taps.row[stage]), int(taps.row_weight[stage])
    d, wx = int(taps.col[stage]), int(taps.col_weight[stage])
    lo = max(0, -d)
    hi = min(width, width - d - (1 if wx else 0))
    if hi <= lo:
        return values
    p00 = frames[:, r0, lo + d : hi + d].astype(dtype)
    if taps.integer:
        values[:, lo:hi] = p00
        return values
    one = dtype(taps.one)
    ux, vx, uy, vy = dtype(one - wx), dtype(wx), dtype(one - wy), dtype(wy)
    top = ux * p00
    bottom = np.zeros_like(top)
    if wx:
        top += vx * frames[:, r0, lo + d + 1 : hi + d + 1].astype(dtype)
    if wy:
        bottom = ux * frames[:, r0 + 1, lo + d : hi + d].astype(dtype)
        if wx:
            bottom += vx * frames[:, r0 + 1, lo + d + 1 : hi + d + 1].astype(dtype)
    weighted = uy * top + vy * bottom
    values[:, lo:hi] = (weighted + dtype(taps.one // 2)) // one
    return values


def accumulate(frames: Frames, acc: Sums, taps: StageTaps, first_index: int) -> Sums:
    """Add F frames (line indices ``first_index``..) to the ring ``acc`` (in place) and return
    the F finished lines' raw sums (F, N), in units of 1/``taps.one`` DN."""
    count, _, width = frames.shape
    stages = taps.stages
    open_before = (first_index + np.arange(stages - 1)) % stages
    lines = np.zeros((count + stages - 1, width), dtype=acc.dtype)
    lines[: stages - 1] = acc[open_before]
    for stage in range(stages):
        lines[stage : stage + count] += stage_values(frames, taps, stage)
    acc[:] = 0
    acc[(first_index + count + np.arange(stages - 1)) % stages] = lines[count:]
    return lines[:count]
