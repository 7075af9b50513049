"""The FPGA's following-error check, predicted: when a commanded motion stalls the motor.

Every ``[sim] stall_check_s`` of device time, while pulses go out, the FPGA compares the
encoder's motion over the last window with the commanded one; less than ``stall_ratio`` of it
(with at least ``stall_min_counts`` commanded) is a stall, and the pulses stop at once
(docs/motion.md). The stage is deterministic, so the stepper controller
(``firmware_models.motor``) predicts these stops when it plans: ``StallCheck.first_stall``
finds the first check that fails in a span of time. Only windows near overloaded motion are
checked (found analytically from the commanded segments, ``StepperStage.overloaded``'s
condition): elsewhere the carriage follows the pulses.
"""

from __future__ import annotations

import math

import numpy as np

from camd.motion.stage_profile import StageProfile
from firmware_models.stage import StepperStage


class StallCheck:
    """The following-error check of ``stage`` (see the module docstring)."""

    def __init__(self, profile: StageProfile, stage: StepperStage) -> None:
        self.profile = profile
        self.stage = stage
        self._d = profile.metres_per_microstep
        self._cpm = profile.encoder_counts_per_m
        check = profile.sim.stall_check_s.value
        self._check_cells = max(1, round(check / stage.grid_s))
        self.stall_check_s = self._check_cells * stage.grid_s  # on the stage's grid

    def first_stall(self, t_a: float, t_b: float, *, open_ended: bool) -> float | None:
        """The first following-error check in ``(t_a, t_b]`` (``open_ended``: the last segment
        goes on) that sees a stall, or None."""
        intervals = self._overload_intervals(t_a, t_b)
        if not intervals:
            return None
        window = self.stall_check_s
        sim = self.profile.sim
        ratio, min_counts = sim.stall_ratio.value, float(sim.stall_min_counts.value)
        scale = self._d * self._cpm
        for lo, hi in intervals:
            last = hi + window + self.stage.grid_s
            if open_ended and hi >= t_b:
                last = max(last, lo + 64 * window)
            k = math.floor(lo / window) + 1
            k_last = math.floor(last / window)
            while k <= k_last:
                ks = np.arange(k, min(k + 256, k_last + 1), dtype=np.float64)
                k += ks.size
                ends = ks * self._check_cells * self.stage.grid_s
                ends = ends[ends > t_a]
                if ends.size == 0:
                    continue
                starts = ends - window
                times = np.concatenate([starts, ends])
                p, _, _ = self.stage.commanded(times)
                x = self.stage.peek_position_m(times)
                counts = np.floor(x * self._cpm + 1e-6)
                n = ends.size
                commanded = (p[n:] - p[:n]) * scale
                moved = (counts[n:] - counts[:n]) * np.sign(commanded)
                stalled = (np.abs(commanded) >= min_counts) & (moved < ratio * np.abs(commanded))
                hits = np.flatnonzero(stalled)
                if hits.size:
                    return float(ends[hits[0]])
        return None

    def _overload_intervals(self, t_a: float, t_b: float) -> list[tuple[float, float]]:
        """Time intervals in ``[t_a, t_b]`` where the commanded motion overloads the motor
        (``StepperStage.overloaded``), from the segments in force (analytically)."""
        stage = self.stage
        faults = stage.faults
        segments = stage.segments_from(t_a)  # the one in force at t_a and after it
        corner = self.profile.sim.pullout_corner_m_s.value * self.profile.microsteps_per_m
        fraction = self.profile.sim.accel_torque_fraction.value
        full = self.profile.max_accel_hz_per_s
        out: list[tuple[float, float]] = []
        starts = [seg.t0_s for seg in segments]
        for j in range(len(segments)):
            seg = segments[j]
            if seg.t0_s >= t_b:
                break
            seg_lo = max(seg.t0_s, t_a)
            seg_hi = min(starts[j + 1] if j + 1 < len(starts) else math.inf, t_b)
            if seg_lo >= seg_hi:
                continue
            vj, aj = seg.v0, seg.a
            if vj == 0.0 and aj == 0.0:
                continue
            need = faults.load + fraction * abs(aj) / full
            threshold = 0.0 if need > 1.0 else (corner / need if need > 0.0 else math.inf)
            if math.isinf(threshold):
                continue
            # |v0 + a tau| > threshold, tau measured from t0[j]
            for lo, hi in _outside(vj, aj, threshold):
                lo_t = max(seg_lo, seg.t0_s + lo)
                hi_t = min(seg_hi, seg.t0_s + hi)
                if hi_t > lo_t:
                    out.append((lo_t, hi_t))
        return out


def _outside(v0: float, a: float, threshold: float) -> list[tuple[float, float]]:
    """The tau intervals where ``|v0 + a tau| > threshold`` (tau may be any real)."""
    if a == 0.0:
        return [(-math.inf, math.inf)] if abs(v0) > threshold else []
    t1 = (-threshold - v0) / a
    t2 = (threshold - v0) / a
    lo, hi = min(t1, t2), max(t1, t2)
    return [(-math.inf, lo), (hi, math.inf)]
