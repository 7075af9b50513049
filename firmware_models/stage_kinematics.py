"""The stepper stage's kinematics: how the carriage moves for the pulses it is sent.

The carriage's true velocity for a commanded rate ``r`` (microsteps per second) is

    v(t) = r(t) d (1 + error) (1 + ripple sin(2 pi x / lambda + phi)) (1 + jitter n(t))
           (1 + drift t_run) [not overloaded]

with the symbols of ``firmware_models.stage``'s docstring (which gives the model in full): the
factors' product clamped at 0, and nothing while the motor is overloaded (the commanded
microsteps are then missed). ``CarriageKinematics`` evaluates it for one seed: the speed factor
of a grid cell, the jitter noise ``n(t)`` (a random-phase sum of ``JITTER_MODES`` cosines with
Lorentzian-distributed frequencies, a pure function of time), the overload condition, and the
position after a run of cells, the ripple term integrated exactly: with ``u`` the position the
carriage would have without ripple, ``dx/du = 1 + R sin(k x + phi)`` separates and has a
closed-form solution (``ripple_u`` / ``ripple_x``).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from firmware_models.stage_faults import StageFaults

if TYPE_CHECKING:
    from camd.motion.stage_profile import StageProfile

F64 = npt.NDArray[np.float64]

JITTER_MODES = 64
_STREAM_RIPPLE = 0x5250  # "RP"
_STREAM_JITTER = 0x4A54  # "JT"


class CarriageKinematics:
    """The velocity model of one stage (``profile``) with the random phases of ``seed``."""

    def __init__(self, profile: StageProfile, seed: int) -> None:
        self._d = profile.metres_per_microstep
        self.k = 2.0 * math.pi / profile.sim.ripple_period_m.value
        ripple_rng = np.random.default_rng([seed, _STREAM_RIPPLE])
        self.ripple_phase_rad = float(ripple_rng.uniform(0.0, 2.0 * math.pi))
        jitter_rng = np.random.default_rng([seed, _STREAM_JITTER])
        tau = profile.sim.jitter_corr_s.value
        self._omega = np.abs(jitter_rng.standard_cauchy(JITTER_MODES)) / tau
        self._omega_phase = jitter_rng.uniform(0.0, 2.0 * math.pi, JITTER_MODES)
        self._rate_corner = profile.sim.pullout_corner_m_s.value * profile.microsteps_per_m
        self._accel_full = profile.max_accel_hz_per_s
        self._accel_fraction = profile.sim.accel_torque_fraction.value

    def speed_factor(self, faults: StageFaults, t_mid: F64, run: F64) -> F64:
        """The speed factor but the ripple's at cell midpoints ``t_mid``, ``run`` seconds into
        the run (clamped at 0)."""
        factor = np.full(t_mid.shape, 1.0 + faults.error)
        if faults.jitter:
            factor *= 1.0 + faults.jitter * self.jitter_noise(t_mid)
        if faults.drift:
            factor *= 1.0 + faults.drift * run
        clamped: F64 = np.maximum(factor, 0.0)
        return clamped

    def jitter_noise(self, t: F64) -> F64:
        """The unit-variance noise ``n(t)`` of the jitter term."""
        out = np.empty_like(t)
        amplitude = math.sqrt(2.0 / JITTER_MODES)
        for lo in range(0, t.size, 8192):
            part = t[lo : lo + 8192]
            phases = np.outer(part, self._omega) + self._omega_phase
            out[lo : lo + 8192] = amplitude * np.cos(phases).sum(axis=1)
        return out

    def overloaded(self, faults: StageFaults, rate: F64, acc: F64) -> npt.NDArray[np.bool_]:
        """Where the torque the motion needs exceeds the pull-out torque."""
        need = faults.load + self._accel_fraction * np.abs(acc) / self._accel_full
        speed = np.abs(rate)
        available = np.where(
            speed > self._rate_corner, self._rate_corner / np.maximum(speed, 1e-300), 1.0
        )
        moving = (rate != 0.0) | (acc != 0.0)
        result: npt.NDArray[np.bool_] = moving & (need > available)
        return result

    def advance(
        self,
        faults: StageFaults,
        x0: float,
        missed0: float,
        dp: F64,
        rate: F64,
        acc: F64,
        t_mid: F64,
        run: F64,
    ) -> tuple[F64, F64, bool]:
        """The carriage over a run of grid cells under one set of faults, from position
        ``x0`` with ``missed0`` microsteps missed: the position and the missed microsteps at
        each cell's end, and whether any cell missed steps. ``dp`` the commanded microsteps of
        each cell; ``rate``, ``acc``, ``t_mid`` and ``run`` at each cell's midpoint."""
        speed = self.speed_factor(faults, t_mid, run)
        over = self.overloaded(faults, rate, acc) & (dp != 0.0)
        speed = np.where(over, 0.0, speed)
        du = speed * self._d * dp
        missed: F64 = missed0 + np.cumsum(np.abs(dp) * over)
        u_start = ripple_u(np.array([x0]), faults.ripple, self.k, self.ripple_phase_rad)
        u = u_start[0] + np.cumsum(du)
        x = ripple_x(u, faults.ripple, self.k, self.ripple_phase_rad)
        return x, missed, bool(over.any())

    def velocity(
        self,
        faults: StageFaults,
        t_mid: F64,
        run: F64,
        rate_mid: F64,
        acc_mid: F64,
        rate: F64,
        x: F64,
    ) -> F64:
        """``v = r d (speed factor of the cell) (1 + R sin(k x + phi))``, the model's formula
        evaluated directly (a difference of positions would lose digits): ``rate`` the
        commanded rate now, ``x`` the position now, the rest at the cell's midpoint."""
        speed = self.speed_factor(faults, t_mid, run)
        over = self.overloaded(faults, rate_mid, acc_mid)
        ripple = 1.0 + faults.ripple * np.sin(self.k * x + self.ripple_phase_rad)
        v: F64 = np.where(over, 0.0, rate * self._d * speed * ripple)
        return v


# -- the ripple map ---------------------------------------------------------------------------


def _ripple_g(theta: F64, r: float) -> F64:
    """``G(theta) = integral_0^theta dt / (1 + r sin t)``, continuous and increasing."""
    s = math.sqrt(1.0 - r * r)
    m = np.floor((theta + math.pi) / (2.0 * math.pi))
    reduced = theta - 2.0 * math.pi * m  # in [-pi, pi)
    c = math.atan(r / s)
    g: F64 = (2.0 / s) * (np.arctan((np.tan(reduced / 2.0) + r) / s) - c) + m * (2.0 * math.pi / s)
    return g


def _ripple_g_inverse(g: F64, r: float) -> F64:
    s = math.sqrt(1.0 - r * r)
    period = 2.0 * math.pi / s
    c = math.atan(r / s)
    low = -(2.0 / s) * (math.pi / 2.0 + c)  # G(-pi)
    m = np.floor((g - low) / period)
    reduced = g - m * period  # in [G(-pi), G(pi))
    w = np.clip(s * reduced / 2.0 + c, -math.pi / 2.0, math.pi / 2.0)
    theta: F64 = 2.0 * np.arctan(s * np.tan(w) - r) + 2.0 * math.pi * m
    return theta


def ripple_u(x: F64, r: float, k: float, phase: float) -> F64:
    """Ripple-free coordinate of position ``x``: ``u = (G(k x + phi) - G(phi)) / k``."""
    if r == 0.0:
        return x
    g0 = float(_ripple_g(np.array([phase]), r)[0])
    u: F64 = (_ripple_g(k * x + phase, r) - g0) / k
    return u


def ripple_x(u: F64, r: float, k: float, phase: float) -> F64:
    """Inverse of ``ripple_u``: the position for ripple-free coordinate ``u``."""
    if r == 0.0:
        return u
    g0 = float(_ripple_g(np.array([phase]), r)[0])
    x: F64 = (_ripple_g_inverse(k * u + g0, r) - phase) / k
    return x
