"""Closing a scan's loop on the image: the line period and the drift taps from the frames.

Pure logic, no I/O (``camd.daemon.scan_image_loop`` feeds it the image motion monitor's blocks
and applies what it returns). docs/motion.md, "Closing the loop on the image"; the relations
are docs/physics.md §10's.

A block measured at line period ``T_b`` says the frames stepped ``s`` rows and ``t`` columns a
line. With a rolling shutter of row time ``T_row`` the image moves ``u = s / (T_b - s T_row)``
rows a second (§10, "A rolling shutter": ``s = v / (1 + v lambda)`` with ``v = u T_b``); the
frames step ``r0`` rows a line (the engine's ``rows_per_line``, 1 normally: every stage on the
same ground line) at

    T* = r0 / u + r0 T_row

and the drift taps follow the image when they add ``r0 t / s`` columns a line (the image's
columns per row of its motion, times the rows a line). Each block moves the period and the
drift a fraction ``gain`` of the way (1 = dead-beat), within the same limits as the encoder's
loop: the period within ``max_trim`` (relative) of the scan's planned one, the drift within
``max_cols_per_line``. A block that could not be measured changes nothing.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from camd.timing._checks import positive


@dataclass(frozen=True, slots=True)
class ImageLoopSetting:
    """What the loop asks for next: a line period, the drift taps' columns per line, and
    whether a limit held either back."""

    line_period_s: float
    cols_per_line: float
    limited: bool


class ImageLoop:
    """The line period and the drift from the image (module docstring)."""

    def __init__(
        self,
        *,
        line_period_s: float,
        row_time_s: float,
        rows_per_line: float = 1.0,
        cols_per_line: float = 0.0,
        gain: float = 0.6,
        max_trim: float = 0.1,
        max_cols_per_line: float = 0.2,
    ) -> None:
        self.planned_s = positive("line_period_s", line_period_s)
        if not (math.isfinite(row_time_s) and 0.0 <= row_time_s < line_period_s):
            raise ValueError(
                f"row_time_s = {row_time_s}: give the rolling shutter's row time, 0 <= it < the "
                "line period (0 for a global shutter)"
            )
        if not 0.0 < gain <= 1.0:
            raise ValueError(f"gain = {gain}: use 0 < gain <= 1 (1 = dead-beat)")
        if not 0.0 < max_trim < 1.0:
            raise ValueError(f"max_trim = {max_trim}: use a fraction between 0 and 1")
        self.row_time_s = row_time_s
        self.rows_per_line = positive("rows_per_line", rows_per_line)
        self.gain = gain
        self.max_trim = max_trim
        self.max_cols_per_line = positive("max_cols_per_line", max_cols_per_line)
        self.line_period_s = line_period_s
        self.cols_per_line = cols_per_line
        self.limited = False
        self.updates = 0

    def target(
        self, shift_along: float, shift_across: float, line_period_s: float
    ) -> tuple[float, float]:
        """The line period and the drift that would make the frames step ``rows_per_line``
        rows and follow the image, from one block's shifts at its line period (module
        docstring); ValueError for a block that says nothing (not finite, not moving)."""
        s, t, period = shift_along, shift_across, line_period_s
        if not (math.isfinite(s) and math.isfinite(t) and s > 0.0 and period > 0.0):
            raise ValueError(
                f"a block with shifts ({s}, {t}) at {period} s says nothing of the image's speed"
            )
        lag_s = period - s * self.row_time_s
        if lag_s <= 0.0:
            raise ValueError(f"a shift of {s} rows a line is beyond the rolling shutter's reach")
        speed_rows_s = s / lag_s
        r0 = self.rows_per_line
        return r0 / speed_rows_s + r0 * self.row_time_s, r0 * t / s

    def update(
        self, shift_along: float, shift_across: float, line_period_s: float
    ) -> ImageLoopSetting:
        """The next setting after one measured block (the period the block was taken at)."""
        try:
            period, drift = self.target(shift_along, shift_across, line_period_s)
        except ValueError:
            return ImageLoopSetting(self.line_period_s, self.cols_per_line, self.limited)
        self.updates += 1
        period = self.line_period_s + self.gain * (period - self.line_period_s)
        drift = self.cols_per_line + self.gain * (drift - self.cols_per_line)
        low, high = self.planned_s * (1 - self.max_trim), self.planned_s * (1 + self.max_trim)
        limit = self.max_cols_per_line
        self.limited = not (low <= period <= high and abs(drift) <= limit)
        self.line_period_s = min(max(period, low), high)
        self.cols_per_line = min(max(drift, -limit), limit)
        return ImageLoopSetting(self.line_period_s, self.cols_per_line, self.limited)
