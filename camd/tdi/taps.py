"""Where each TDI stage samples its frame: row and column taps with fixed-point weights.

docs/physics.md §1: stage i of output line k takes frame k - i at row position ``i * rows_per_line``
(``(M - 1 - i) * rows_per_line`` when the scene moves the other way) and column offset
``i * cols_per_line``. Whole-number positions are exact; fractional ones are linear interpolation
with weights in steps of 1/``FIXED_POINT_ONE`` of a pixel, so that integer arithmetic (which does
not depend on the order of the additions) gives the same bits on every path. docs/tdi.md states
the arithmetic exactly.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

FIXED_POINT_ONE = 256
"""Interpolation weights are whole multiples of 1/256 pixel (docs/tdi.md)."""

MAX_STAGES = 65536  # a uint32 sum of this many 16-bit values cannot wrap
_U32_FIXED_STAGES = 256  # fractional sums of more stages than this need uint64 (65535 * 256 * M)

IntArray = npt.NDArray[np.int64]


def _split(position: float) -> tuple[int, int]:
    """``position`` as a whole pixel and a weight in 1/FIXED_POINT_ONE (rounded half up)."""
    whole = math.floor(position)
    weight = math.floor((position - whole) * FIXED_POINT_ONE + 0.5)
    if weight == FIXED_POINT_ONE:
        return whole + 1, 0
    return whole, weight


@dataclass(frozen=True, slots=True)
class StageTaps:
    """Per-stage sampling of one engine configuration (index i = stage, 0-based).

    ``row``/``row_weight``: frame row ``row[i]`` and, with weight ``row_weight[i]``/W, the next
    one. ``col``/``col_weight``: likewise for the column offset. ``one`` is the unit of the
    partial sums: 1 on the integer path (sums in DN), FIXED_POINT_ONE on the fractional path
    (sums in 1/W DN).
    """

    stages: int
    width: int
    row: IntArray
    row_weight: IntArray
    col: IntArray
    col_weight: IntArray
    one: int
    rows_needed: int
    accumulator: type[np.unsignedinteger]

    @property
    def integer(self) -> bool:
        """True on the exact integer path (no interpolation)."""
        return self.one == 1

    @property
    def shifted(self) -> bool:
        """True if any stage samples a shifted column (drift compensation)."""
        return bool(np.any(self.col) or np.any(self.col_weight))

    def valid_columns(self) -> slice:
        """Output columns to which every stage contributes (all of them without drift)."""
        lo = int(max(0, -int(self.col.min())))
        reach = self.col + (self.col_weight > 0)
        hi = int(min(self.width, self.width - int(reach.max())))
        return slice(lo, max(lo, hi))


def stage_taps(
    stages: int,
    width: int,
    *,
    rows_per_line: float = 1.0,
    cols_per_line: float = 0.0,
    reverse: bool = False,
) -> StageTaps:
    """The taps of every stage for one configuration; ValueError says what to change."""
    if not isinstance(stages, int | np.integer) or isinstance(stages, bool):
        raise ValueError(f"stages must be a whole number, got {stages!r}")
    if not 1 <= stages <= MAX_STAGES:
        raise ValueError(f"stages = {stages} is out of range; choose 1..{MAX_STAGES}")
    if not isinstance(width, int | np.integer) or width < 1:
        raise ValueError(f"width must be a positive whole number of columns, got {width!r}")
    if not math.isfinite(rows_per_line) or rows_per_line < 0:
        raise ValueError(
            f"rows_per_line = {rows_per_line} must be a finite number >= 0 "
            "(1 = synchronous, 2 = every other row, 1 + e for a velocity mismatch e)"
        )
    if not math.isfinite(cols_per_line):
        raise ValueError(f"cols_per_line = {cols_per_line} must be a finite number")
    integer = float(rows_per_line).is_integer() and float(cols_per_line).is_integer()
    order = range(stages - 1, -1, -1) if reverse else range(stages)
    rows = [_split(k * rows_per_line) for k in order]
    cols = [_split(i * cols_per_line) for i in range(stages)]
    row = np.array([r for r, _ in rows], dtype=np.int64)
    row_weight = np.array([w for _, w in rows], dtype=np.int64)
    col = np.array([c for c, _ in cols], dtype=np.int64)
    col_weight = np.array([w for _, w in cols], dtype=np.int64)
    if integer:
        assert not row_weight.any() and not col_weight.any()
    one = 1 if integer else FIXED_POINT_ONE
    wide = not integer and stages > _U32_FIXED_STAGES
    return StageTaps(
        stages=int(stages),
        width=int(width),
        row=row,
        row_weight=row_weight,
        col=col,
        col_weight=col_weight,
        one=one,
        rows_needed=int((row + (row_weight > 0)).max()) + 1,
        accumulator=np.uint64 if wide else np.uint32,
    )
