"""The velocity mismatch each TDI line saw, from the stage encoder counts in the frame headers.

Each frame header carries the stage encoder count latched at the frame's start. Over the M
frames of a line the image should move M pitches; ``camd.timing.line_mismatch`` (docs/physics.md §6)
turns the counts into the smear M dV/V of each line. ``MismatchTracker`` does it batch by batch:
it carries the previous batch's last M frames over (a line's first stages are in the batch
before), unwraps the device's 32-bit frame counter across batches, keeps the scan's largest and
RMS |M dV/V| over the complete lines and grades each batch against the yellow and red limits.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

import numpy as np
import numpy.typing as npt

from camd.timing import line_mismatch

Level = Literal["ok", "yellow", "red"]
LEVELS: tuple[Level, ...] = ("ok", "yellow", "red")  # in order of gravity
COUNTER_WRAP = 1 << 32  # the frame header's counter is 32 bits


@dataclass(frozen=True, slots=True)
class BatchMismatch:
    """One batch's result: M dV/V of each of its lines (NaN where unknown) and whether its
    complete lines reached the red limit."""

    values: npt.NDArray[np.float64]
    red: bool


class MismatchTracker:
    """Per-line M dV/V of a scan and its statistics (module docstring).

    ``counts_per_pixel`` is encoder counts per image pitch of stage travel; ``yellow_px`` and
    ``red_px`` are the limits on |M dV/V| in pixels of smear (docs/physics.md §6: 2 is the
    tolerance). ``on_level(level, message)`` is called, on the caller's thread, whenever a
    batch's level differs from the previous batch's, with a sentence saying so.
    """

    def __init__(
        self,
        counts_per_pixel: float,
        *,
        yellow_px: float,
        red_px: float,
        on_level: Callable[[Level, str], None] | None = None,
    ) -> None:
        if not (math.isfinite(counts_per_pixel) and counts_per_pixel > 0):
            raise ValueError(
                f"counts_per_pixel = {counts_per_pixel} must be a positive number of encoder "
                "counts per image pitch"
            )
        if not 0 < yellow_px < red_px:
            raise ValueError(
                f"the limits yellow = {yellow_px} and red = {red_px} must satisfy 0 < yellow < red"
            )
        self.counts_per_pixel = float(counts_per_pixel)
        self.yellow_px = float(yellow_px)
        self.red_px = float(red_px)
        self._on_level = on_level
        self._carry_counters = np.zeros(0, np.int64)  # unwrapped
        self._carry_encoder = np.zeros(0, np.float64)
        self.max: float | None = None  # of |M dV/V| over the complete lines so far
        self.last: float | None = None  # the last graded batch's largest |M dV/V|
        self.level: Level = "ok"  # the worst level reached
        self.now: Level = "ok"  # the last graded batch's level
        self._sum_sq = 0.0
        self._count = 0

    @property
    def rms(self) -> float | None:
        """RMS of |M dV/V| over the complete lines so far (None before the first)."""
        return None if not self._count else math.sqrt(self._sum_sq / self._count)

    def grade(self, magnitude_px: float) -> Level:
        """The level of a smear of ``magnitude_px`` pixels."""
        if magnitude_px >= self.red_px:
            return "red"
        return "yellow" if magnitude_px >= self.yellow_px else "ok"

    def add(
        self,
        counters: npt.NDArray[np.integer],
        encoder: npt.NDArray[np.integer],
        complete: npt.NDArray[np.bool_],
        *,
        stages: int,
    ) -> BatchMismatch:
        """One batch of consecutive frames (gaps show in the counters): each line's M dV/V,
        the statistics and the level updated from the complete lines."""
        m = stages
        carry_c, carry_e = self._carry_counters, self._carry_encoder
        # Counters wrap at 2^32: unwrap against the carried frames.
        base = int(carry_c[-1]) if carry_c.size else int(counters[0])
        unwrapped = base + ((counters.astype(np.int64) - base) % COUNTER_WRAP)
        all_c = np.concatenate([carry_c, unwrapped])
        all_e = np.concatenate([carry_e, encoder.astype(np.float64)])
        values = line_mismatch(all_e, all_c, stages=m, counts_per_pixel=self.counts_per_pixel)
        result = values[carry_c.size :]
        self._carry_counters, self._carry_encoder = all_c[-m:], all_e[-m:]
        magnitude = np.abs(result[np.isfinite(result) & complete])
        red = bool(magnitude.size) and self._note(magnitude) == "red"
        return BatchMismatch(result, red)

    def _note(self, magnitude: npt.NDArray[np.float64]) -> Level:
        worst = float(magnitude.max())
        self.last = worst
        self.max = max(worst, self.max or 0.0)
        self._sum_sq += float(np.square(magnitude).sum())
        self._count += int(magnitude.size)
        level = self.grade(worst)
        if LEVELS.index(level) > LEVELS.index(self.level):
            self.level = level
        if level != self.now:
            self.now = level
            if self._on_level is not None:
                self._on_level(
                    level,
                    f"scan velocity mismatch {level}: M |dV/V| up to {worst:.3g} pixels "
                    f"(limits {self.yellow_px:g} / {self.red_px:g})",
                )
        return level
