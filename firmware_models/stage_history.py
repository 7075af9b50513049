"""The stepper stage's history: the carriage's true position, integrated and kept.

The true position is integrated on a fixed grid of ``grid_s`` (50 us) in blocks of
``BLOCK_CELLS`` cells, lazily, up to the latest time asked for; between grid points it is
interpolated in proportion to the commanded microsteps (exact for a perfect stage, ramps
included). Each cell's speed factor is evaluated at its midpoint (``firmware_models.
stage_kinematics``). A new profile or new faults from time ``t`` discard what was integrated
after ``t``; blocks without commanded motion cost nothing; history older than ``history_s``
before the latest time asked for is dropped, commanded segments with it. Fault changes act from
the next grid cell: the faults in force are kept as regimes, each from its time on.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from firmware_models.stage_faults import StageFaults
from firmware_models.stage_kinematics import CarriageKinematics
from firmware_models.stage_segments import SegmentTable

F64 = npt.NDArray[np.float64]

BLOCK_CELLS = 4096


@dataclass(slots=True)
class _Block:
    """Grid points ``b * BLOCK_CELLS ... (b + 1) * BLOCK_CELLS`` (both ends): positions and
    missed microsteps, or (``x is None``) a block without motion at ``x0`` / ``missed0``."""

    x0: float
    missed0: float
    x: F64 | None = None
    missed: F64 | None = None

    @property
    def x_end(self) -> float:
        return self.x0 if self.x is None else float(self.x[-1])

    @property
    def missed_end(self) -> float:
        return self.missed0 if self.missed is None else float(self.missed[-1])


class StageHistory:
    """The true position of a stage since ``t0_s`` (see the module docstring), for the
    commanded ``segments`` (which it prunes with the history) and the ``kinematics``."""

    def __init__(
        self,
        kinematics: CarriageKinematics,
        segments: SegmentTable,
        *,
        t0_s: float,
        position_m: float,
        faults: StageFaults,
        grid_s: float,
        history_s: float,
    ) -> None:
        self.kinematics = kinematics
        self.segments = segments
        self.grid_s = grid_s
        self.history_s = history_s
        self.t0_s = t0_s
        self._fault_t: list[float] = [t0_s]
        self._fault_list: list[StageFaults] = [faults]
        self._blocks: list[_Block] = []
        self._first_block = self._block_of(t0_s)
        self._reset_x = float(position_m)
        self._start = _Block(position_m, 0.0)  # the state before the first kept block
        self.kept_from_s = t0_s  # the earliest time still known (older history was pruned)
        self.latest_s = t0_s  # "now": the latest time asked for

    @property
    def faults(self) -> StageFaults:
        """The imperfections in force now (the latest set)."""
        return self._fault_list[-1]

    def changed_from(self, t_s: float) -> float:
        """The commanded profile or the faults change from ``t_s`` on: forget what was
        integrated after it; return ``t_s``, moved to the kept history's start if earlier."""
        t_s = max(float(t_s), self.t0_s, self.kept_from_s)
        self.latest_s = max(self.latest_s, t_s)
        b = self._block_of(t_s)
        keep = max(0, b - self._first_block)
        del self._blocks[keep:]
        return t_s

    def set_faults(self, t_s: float, faults: StageFaults) -> None:
        """``faults`` from ``t_s`` on (after ``changed_from(t_s)``)."""
        while len(self._fault_t) > 1 and self._fault_t[-1] >= t_s:
            self._fault_t.pop()
            self._fault_list.pop()
        if self._fault_t[-1] >= t_s:
            self._fault_list[-1] = faults
        else:
            self._fault_t.append(t_s)
            self._fault_list.append(faults)

    def lookup(self, t: F64, *, want_velocity: bool, note: bool) -> tuple[F64, F64, F64]:
        """Positions, velocities (if wanted) and missed microsteps at times ``t``."""
        n = t.size
        x_out = np.empty(n)
        v_out = np.zeros(n)
        m_out = np.empty(n)
        if n == 0:
            return x_out, v_out, m_out
        if not np.all(np.isfinite(t)):
            raise ValueError("stage times must be finite numbers of seconds")
        before_start = t < self.t0_s
        pruned = (t < self.kept_from_s) & ~before_start
        if pruned.any():
            raise ValueError(
                f"stage position asked for t = {float(t[pruned].min()):.6f} s, older than the "
                f"kept history (from {self.kept_from_s:.6f} s, {self.history_s:g} s back); "
                "render frames closer to the present or raise history_s"
            )
        if note:
            self.latest_s = max(self.latest_s, float(t.max()))
        self._integrate_to(float(t.max()) + self.grid_s)
        x_out[before_start] = self._reset_x  # at rest there before the reset
        m_out[before_start] = 0.0
        dt = self.grid_s
        inside = ~before_start
        ti = t[inside]
        cell = np.floor(ti / dt).astype(np.int64)
        block = cell // BLOCK_CELLS
        k = cell - block * BLOCK_CELLS
        t_lo = cell.astype(np.float64) * dt
        p_t, rate_t, _ = self.segments.evaluate(ti)
        p_lo, _, _ = self.segments.evaluate(t_lo)
        p_hi, _, _ = self.segments.evaluate(t_lo + dt)
        dp = p_hi - p_lo
        moving = np.abs(dp) > 1e-12
        frac_p = np.where(moving, (p_t - p_lo) / np.where(moving, dp, 1.0), 0.0)
        frac_t = np.clip((ti - t_lo) / dt, 0.0, 1.0)
        xs = np.empty(ti.size)
        ms = np.empty(ti.size)
        vs = np.zeros(ti.size)
        for b in np.unique(block):
            sel = block == b
            blk = self._block_at(int(b))
            kk = k[sel]
            if blk.x is None:
                xs[sel] = blk.x0
            else:
                x_lo, x_hi = blk.x[kk], blk.x[kk + 1]
                dx = x_hi - x_lo
                mv = moving[sel]
                xs[sel] = x_lo + dx * np.where(mv, frac_p[sel], frac_t[sel])
                if want_velocity:
                    vs[sel] = self._velocity(t_lo[sel] + 0.5 * dt, rate_t[sel], xs[sel])
                    vs[sel] = np.where(mv | (rate_t[sel] != 0.0), vs[sel], 0.0)
            if blk.missed is None:
                ms[sel] = blk.missed0
            else:
                m_lo, m_hi = blk.missed[kk], blk.missed[kk + 1]
                ms[sel] = m_lo + (m_hi - m_lo) * frac_t[sel]
        x_out[inside] = xs
        v_out[inside] = vs
        m_out[inside] = ms
        return x_out, v_out, m_out

    # -- integration ------------------------------------------------------------------------------

    def _block_of(self, t_s: float) -> int:
        return math.floor(t_s / (self.grid_s * BLOCK_CELLS))

    def _end_state(self) -> _Block:
        return self._blocks[-1] if self._blocks else self._start

    def _integrate_to(self, t_s: float) -> None:
        """Make sure every block up to the one holding ``t_s`` (and its next point) exists."""
        target = self._block_of(t_s)
        while self._first_block + len(self._blocks) <= target:
            b = self._first_block + len(self._blocks)
            self._blocks.append(self._compute_block(b, self._end_state()))
        self._prune()

    def _prune(self) -> None:
        keep_from = self._block_of(self.latest_s - self.history_s)
        drop = min(keep_from - self._first_block, len(self._blocks) - 1)
        if drop <= 0:
            return
        last_dropped = self._blocks[drop - 1]
        self._start = _Block(last_dropped.x_end, last_dropped.missed_end)
        del self._blocks[:drop]
        self._first_block += drop
        self.kept_from_s = self._first_block * BLOCK_CELLS * self.grid_s
        self.segments.drop_before(self.kept_from_s)
        keep = max(0, int(np.searchsorted(self._fault_t, self.kept_from_s, side="right")) - 1)
        del self._fault_t[:keep]
        del self._fault_list[:keep]

    def _regimes(self, t: F64) -> npt.NDArray[np.intp]:
        """The index of the faults in force at each time."""
        return np.maximum(np.searchsorted(self._fault_t, t, side="right") - 1, 0)

    def _compute_block(self, b: int, before: _Block) -> _Block:
        dt = self.grid_s
        i0 = b * BLOCK_CELLS
        t_start, t_end = i0 * dt, (i0 + BLOCK_CELLS) * dt
        x0, missed0 = before.x_end, before.missed_end
        segments = self.segments
        if not segments.moving_between(t_start, t_end):
            return _Block(x0, missed0)
        t_pts = (i0 + np.arange(BLOCK_CELLS + 1, dtype=np.float64)) * dt
        p_pts, _, _ = segments.evaluate(t_pts)
        dp = np.diff(p_pts)
        t_mid = t_pts[:-1] + 0.5 * dt
        _, rate, acc = segments.evaluate(t_mid)
        run = segments.run_time(t_mid)
        regime = self._regimes(t_mid)
        x = np.empty(BLOCK_CELLS + 1)
        missed = np.empty(BLOCK_CELLS + 1)
        x[0], missed[0] = x0, missed0
        any_missed = False
        boundaries = np.flatnonzero(np.diff(regime)) + 1
        starts = [0, *boundaries.tolist()]
        ends = [*boundaries.tolist(), BLOCK_CELLS]
        for lo, hi in zip(starts, ends, strict=True):
            cells = slice(lo, hi)
            x[lo + 1 : hi + 1], missed[lo + 1 : hi + 1], over = self.kinematics.advance(
                self._fault_list[int(regime[lo])],
                x[lo],
                missed[lo],
                dp[cells],
                rate[cells],
                acc[cells],
                t_mid[cells],
                run[cells],
            )
            any_missed = any_missed or over
        return _Block(x0, missed0, x, missed if any_missed else None)

    def _velocity(self, t_mid: F64, rate: F64, x: F64) -> F64:
        """The true velocity at positions ``x`` and commanded rates ``rate`` in the cells
        whose midpoints are ``t_mid`` (``CarriageKinematics.velocity``)."""
        _, rate_mid, acc_mid = self.segments.evaluate(t_mid)
        run = self.segments.run_time(t_mid)
        regime = self._regimes(t_mid)
        v = np.empty_like(t_mid)
        for r in np.unique(regime):
            sel = regime == r
            v[sel] = self.kinematics.velocity(
                self._fault_list[int(r)],
                t_mid[sel],
                run[sel],
                rate_mid[sel],
                acc_mid[sel],
                rate[sel],
                x[sel],
            )
        return v

    def _block_at(self, b: int) -> _Block:
        index = b - self._first_block
        if index < 0:
            return _Block(self._start.x0, self._start.missed0)
        return self._blocks[index]
