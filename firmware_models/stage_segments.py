"""The scan stage's commanded profile: the FPGA's step pulses as constant-acceleration segments.

``P(t)`` is the commanded position in microsteps (the pulses the FPGA sent; absolute, never
re-zeroed), ``r(t) = dP/dt`` the commanded rate. The step generator
(``firmware_models.motor``) hands the stage its profile as ``Segment`` s; the stage
(``firmware_models.stage``) keeps them in a ``SegmentTable`` and evaluates them, vectorised, at
the times it integrates the carriage's motion.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

F64 = npt.NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class Segment:
    """Commanded motion from ``t0_s`` until the next segment: ``P = p0 + v0 tau + a tau^2 / 2``.

    ``p0`` microsteps, ``v0`` microsteps per second, ``a`` microsteps per second squared."""

    t0_s: float
    p0: float
    v0: float = 0.0
    a: float = 0.0

    def at(self, t_s: float) -> tuple[float, float]:
        """(position, rate) at ``t_s`` (extrapolated past the segment's end)."""
        tau = t_s - self.t0_s
        return self.p0 + self.v0 * tau + 0.5 * self.a * tau * tau, self.v0 + self.a * tau

    @property
    def moving(self) -> bool:
        return self.v0 != 0.0 or self.a != 0.0


class SegmentTable:
    """The commanded profile since the last reset, as arrays for vectorised evaluation.

    Kept in arrays that grow in place, with two derived columns (how many segments up to each
    one command motion, and when the run each one belongs to started). A segment's
    derived values depend only on the segments before it, and the profile only ever changes
    at its end (``replace_from``: a command replaces what was planned from its time on) or
    loses its oldest part (``drop_before``): so a command derives its own few rows, found by
    bisection, and never walks the history (a closed loop's 4,000 trims over the 120 s kept
    made each command walk 8,000 segments, holding the interpreter lock against the frame
    renderer).
    """

    __slots__ = ("_columns", "_n")

    # Rows of ``_columns``: t0, p0, v0, a, moving segments up to and including this one, the
    # start of the run this segment belongs to (``run_time``).
    _T0, _P0, _V0, _A, _MOVING, _CARRY = range(6)

    def __init__(self) -> None:
        self._columns = np.empty((6, 64))
        self._n = 0

    @property
    def t0(self) -> F64:
        """Start times of the kept segments (a view)."""
        return self._columns[self._T0, : self._n]

    def replace_from(self, t_s: float, segments: list[Segment]) -> None:
        """Drop the segments starting at or after ``t_s``, then append ``segments``."""
        keep = int(np.searchsorted(self.t0, t_s, side="left"))
        n = keep + len(segments)
        if n > self._columns.shape[1]:
            grown = np.empty((6, max(2 * self._columns.shape[1], n)))
            grown[:, :keep] = self._columns[:, :keep]
            self._columns = grown
        for row, seg in enumerate(segments, start=keep):
            self._columns[: self._A + 1, row] = (seg.t0_s, seg.p0, seg.v0, seg.a)
        self._n = n
        self._derive(keep)

    def drop_before(self, t_s: float) -> None:
        """Forget segments that ended before ``t_s`` (keep the one active at ``t_s``)."""
        keep_from = max(0, int(np.searchsorted(self.t0, t_s, side="right")) - 1)
        if keep_from:
            n = self._n - keep_from
            self._columns[:, :n] = self._columns[:, keep_from : self._n]
            self._n = n
            # The first kept segment now starts the profile, as after a reset (its run
            # start is its own start), and the rows after it follow from it.
            self._derive(0)

    def arrays(self) -> tuple[F64, F64, F64, F64, F64, F64]:
        """(t0, p0, v0, a, segments commanding motion up to and including each one, run start
        carried into each segment): views, valid until the profile next changes."""
        c, n = self._columns, self._n
        return (
            c[self._T0, :n],
            c[self._P0, :n],
            c[self._V0, :n],
            c[self._A, :n],
            c[self._MOVING, :n],
            c[self._CARRY, :n],
        )

    def _derive(self, lo: int) -> None:
        """The derived columns of rows ``lo ..`` from those rows and row ``lo - 1``.

        Segment j starts a new run at ``t0[j]`` if it commands no rate at its start (or is the
        first), at the zero crossing of segment j - 1 if that decelerates through zero before
        j starts, at ``t0[j]`` if j - 1 ends at rest or stood still; otherwise it continues
        j - 1's run."""
        n = self._n
        if lo >= n:
            return
        c = self._columns
        t0, v0, a = c[self._T0, :n], c[self._V0, :n], c[self._A, :n]
        moving = ((v0[lo:] != 0.0) | (a[lo:] != 0.0)).astype(np.float64)
        before = c[self._MOVING, lo - 1] if lo else 0.0
        c[self._MOVING, lo:n] = before + np.cumsum(moving)
        j = np.arange(lo, n)
        prev = np.maximum(j - 1, 0)
        tau_end = t0[j] - t0[prev]
        rate_end = v0[prev] + a[prev] * tau_end
        with np.errstate(divide="ignore", invalid="ignore"):
            crossing = np.where(
                a[prev] != 0.0, -v0[prev] / np.where(a[prev] != 0.0, a[prev], 1.0), np.inf
            )
        crosses = (a[prev] != 0.0) & (v0[prev] * a[prev] < 0.0) & (crossing <= tau_end)
        still_before = (v0[prev] == 0.0) & (a[prev] == 0.0)
        first = (v0[j] == 0.0) | (j == 0)
        start_here = first | (~crosses & ((rate_end == 0.0) | still_before))
        start = np.where(crosses & ~first, t0[prev] + crossing, t0[j])
        resets = start_here | (crosses & ~first)
        # Forward fill: each row takes the start of the latest reset at or before it, or
        # (none since ``lo``) row lo - 1's run start.
        last_reset = np.maximum.accumulate(np.where(resets, np.arange(n - lo), -1))
        seed = c[self._CARRY, lo - 1] if lo else 0.0
        c[self._CARRY, lo:n] = np.where(last_reset >= 0, start[np.maximum(last_reset, 0)], seed)

    def index(self, t: F64) -> npt.NDArray[np.intp]:
        return np.maximum(np.searchsorted(self.t0, t, side="right") - 1, 0)

    def segments_from(self, t_s: float) -> list[Segment]:
        """The segment in force at ``t_s`` (the first if ``t_s`` is earlier) and those after."""
        j0 = int(self.index(np.array([t_s]))[0])
        c, n = self._columns, self._n
        return [Segment(*c[: self._A + 1, j].tolist()) for j in range(j0, n)]

    def evaluate(self, t: F64) -> tuple[F64, F64, F64]:
        """(P, rate, acceleration) at each time."""
        t0, p0, v0, a, _, _ = self.arrays()
        j = self.index(t)
        tau = np.maximum(t - t0[j], 0.0)
        pos: F64 = p0[j] + v0[j] * tau + 0.5 * a[j] * tau * tau
        rate: F64 = v0[j] + a[j] * tau
        acc: F64 = a[j].copy()
        return pos, rate, acc

    def run_time(self, t: F64) -> F64:
        """Seconds since the commanded rate was last zero (0 while it is zero)."""
        t0, _, v0, a, _, carry = self.arrays()
        j = self.index(t)
        tau = np.maximum(t - t0[j], 0.0)
        base = carry[j].copy()
        crossing = np.where(a[j] * v0[j] < 0.0, -v0[j] / np.where(a[j] == 0.0, 1.0, a[j]), np.inf)
        base = np.where(tau >= crossing, t0[j] + crossing, base)
        base = np.where(v0[j] == 0.0, t0[j], base)
        run: F64 = np.where((v0[j] == 0.0) & (a[j] == 0.0), 0.0, np.maximum(t - base, 0.0))
        return run

    def moving_between(self, t_a: float, t_b: float) -> bool:
        """True if any segment overlapping ``[t_a, t_b]`` commands motion."""
        t0, _, _, _, through, _ = self.arrays()
        j0 = max(int(np.searchsorted(t0, t_a, side="right")) - 1, 0)
        j1 = max(int(np.searchsorted(t0, t_b, side="right")) - 1, 0)
        before = through[j0 - 1] if j0 else 0.0
        return bool(through[j1] - before > 0)
