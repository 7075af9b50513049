"""The scan stage under the simulated camera: where the target is at a given time.

A stage is any object with ``position_m(t_s)``: the stage position along track, in metres, at
each time of an array (seconds). The camera turns it into image rows with an image scale and
the pixel pitch (docs/physics.md §2: one row per ``p / v_image`` seconds): for a linear stage the
scale is the optics magnification (docs/physics.md §6, ``v_image = m v_stage``, the carriage carries
the target); for a turntable carrying the sensor it is 1, positions being arc length at the
sensor's distance ``l`` from the axis (docs/physics.md §2 eq 5, ``v_image = w l``).
``StageProfile.image_scale(m)`` gives the scale for a profile.

``LinearStage`` moves at a constant speed. ``StepperStage`` is the physics of a stepper-driven
axis (``camd.motion.stage_profile.StageProfile``), sans clock: the FPGA's step generator
(``firmware_models.motor.MotorController``) hands it the commanded microstep profile as
``Segment`` s, piecewise constant acceleration, and it answers where the carriage truly is.

The stepper model
-----------------
``P(t)`` is the commanded position in microsteps (the pulses the FPGA sent; absolute, never
re-zeroed), ``r(t) = dP/dt`` the commanded rate. The carriage's true velocity is

    v(t) = r(t) d (1 + error) (1 + ripple sin(2 pi x / lambda + phi)) (1 + jitter n(t))
           (1 + drift t_run) [not overloaded]

``d`` metres per microstep, ``x`` the true position, ``lambda`` ``[sim] ripple_period_m``,
``phi`` a seeded phase, ``n(t)`` unit-variance noise correlated over ``tau =
[sim] jitter_corr_s`` (``E[n(t) n(t + s)] = exp(-|s| / tau)``, a random-phase sum of 64
cosines with Lorentzian-distributed frequencies, hence a pure function of time), ``t_run`` the
seconds since the commanded rate last was zero. The factors' product is clamped at 0: the
carriage never runs against the command.

Missed steps: the motor's pull-out torque is ``T0`` up to the corner speed ``v_c =
[sim] pullout_corner_m_s`` and ``T0 v_c / |v|`` above it (the constant-power region of a
chopper driver). Ramps need ``[sim] accel_torque_fraction`` of ``T0`` at the full acceleration.
Where ``load + accel_torque_fraction |a| / a_max > min(1, v_c / |v|)`` (``load`` a fraction of
``T0``) the rotor cannot follow: the carriage stands while the commanded microsteps go on, and
every one of them is a missed step. Below that again the rotor re-locks and the carriage
follows the pulses, lagging the commanded position by the steps it missed (a real rotor
re-locks on a whole electrical cycle, 4 full steps; the model keeps the exact count).

Numerics: the true position is integrated on a fixed grid of ``grid_s`` (50 us) in blocks of
4096 cells, lazily, up to the latest time asked for; between grid points it is interpolated
in proportion to the commanded microsteps (exact for a perfect stage, ramps included). Each
cell's speed factor is evaluated at its midpoint. The ripple term is integrated exactly: with
``u`` the position the carriage would have without ripple, ``dx/du = 1 + R sin(k x + phi)``
separates and has a closed-form solution (``ripple_u`` / ``ripple_x``). A new profile or new
faults from time ``t`` discard what was integrated after ``t``; blocks without commanded motion
cost nothing; history older than ``history_s`` is dropped. Fault changes act from the next
grid cell. The result is deterministic for a seed and a sequence of calls.

The parts: the imperfections (``firmware_models.stage_faults``), the commanded profile
(``stage_segments``), the velocity model (``stage_kinematics``) and the integrated, kept
history (``stage_history``); ``StepperStage`` puts them together behind one lock.
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol, TypedDict

import numpy as np
import numpy.typing as npt

from firmware_models.stage_faults import FAULT_RANGES, StageFaults
from firmware_models.stage_history import BLOCK_CELLS, StageHistory
from firmware_models.stage_kinematics import JITTER_MODES, CarriageKinematics
from firmware_models.stage_segments import Segment, SegmentTable

if TYPE_CHECKING:
    from camd.motion.stage_profile import StageProfile

__all__ = [
    "BLOCK_CELLS",
    "FAULT_RANGES",
    "GRID_S",
    "HISTORY_S",
    "JITTER_MODES",
    "LinearStage",
    "Segment",
    "Stage",
    "StageFaults",
    "StepperStage",
    "power_on_position_m",
]

FloatArray = npt.NDArray[np.floating[Any]]
F64 = npt.NDArray[np.float64]

GRID_S = 50e-6
HISTORY_S = 120.0
# Encoder counts within this much of the next integer count as it (float rounding of x).
_ENCODER_EPS = 1e-6


class Stage(Protocol):
    """Anything that can say where the target is along track."""

    def position_m(self, t_s: FloatArray) -> FloatArray:
        """Stage position along track (m) at each time ``t_s`` (s)."""
        ...


@dataclass(frozen=True, slots=True)
class LinearStage:
    """A stage at constant speed: ``x(t) = x0 + v t``."""

    speed_m_s: float
    position0_m: float = 0.0

    def position_m(self, t_s: FloatArray) -> FloatArray:
        """``x0 + v t`` for each time."""
        result: FloatArray = self.position0_m + self.speed_m_s * np.asarray(t_s, dtype=np.float64)
        return result


def power_on_position_m(profile: StageProfile) -> float:
    """Where the stage stands at power-on: the middle of a rail's travel, half a turn from a
    turntable's index (so a scan can run before homing)."""
    if profile.travel_m is not None:
        return profile.travel_m.value / 2.0
    circumference = profile.circumference_m
    assert circumference is not None
    return circumference / 2.0


class StageOptions(TypedDict, total=False):
    """``StepperStage``'s keyword arguments but ``position_m``, for ``MotorController``, which
    passes them on: each default stays written once, in ``StepperStage``."""

    seed: int
    faults: StageFaults | None
    t0_s: float
    grid_s: float
    history_s: float


class StepperStage:
    """A stepper-driven stage (see the module docstring); a ``Stage`` for the camera.

    ``position_m(t)`` is the true position in metres from the home switch at the low end of a
    rail, or the arc at ``radius_m`` from the turntable's index. Commanded positions are in
    microsteps ``P`` with ``P = 0`` at position 0 (before any missed step or speed error).
    The stage starts at rest at ``position_m`` (default: ``power_on_position_m``) at ``t0_s``.
    """

    def __init__(
        self,
        profile: StageProfile,
        *,
        seed: int = 0,
        faults: StageFaults | None = None,
        t0_s: float = 0.0,
        position_m: float | None = None,
        grid_s: float = GRID_S,
        history_s: float = HISTORY_S,
    ) -> None:
        if not grid_s > 0.0 or not history_s > 0.0:
            raise ValueError("grid_s and history_s must be > 0")
        self.profile = profile
        self.seed = seed
        self.grid_s = grid_s
        self.history_s = history_s
        self.lock = threading.RLock()  # held by every method; a controller may hold it too
        self._d = profile.metres_per_microstep
        self.kinematics = CarriageKinematics(profile, seed)
        self.ripple_phase_rad = self.kinematics.ripple_phase_rad
        self.reset(
            t0_s,
            power_on_position_m(profile) if position_m is None else position_m,
            faults if faults is not None else StageFaults.from_profile(profile),
        )

    # -- commands ---------------------------------------------------------------------------------

    def reset(self, t0_s: float, position_m: float, faults: StageFaults | None = None) -> None:
        """Forget everything: at rest at ``position_m`` from ``t0_s``, with ``faults`` (None:
        the ones in force)."""
        with self.lock:
            if faults is None:
                faults = self.faults if hasattr(self, "_history") else StageFaults()
            # Counts changes of what was commanded (reset, profile, faults): a look-up made
            # at one revision stays true until the next.
            self.revision = getattr(self, "revision", 0) + 1
            self.t0_s = float(t0_s)
            self._segments = SegmentTable()
            self._segments.replace_from(
                self.t0_s, [Segment(self.t0_s, position_m / self._d, 0.0, 0.0)]
            )
            self._history = StageHistory(
                self.kinematics,
                self._segments,
                t0_s=self.t0_s,
                position_m=position_m,
                faults=faults,
                grid_s=self.grid_s,
                history_s=self.history_s,
            )

    @property
    def faults(self) -> StageFaults:
        """The imperfections in force now (the latest set)."""
        return self._history.faults

    def set_profile(self, t_s: float, segments: list[Segment]) -> None:
        """Command ``segments`` from ``t_s`` on (the first must start at ``t_s``), replacing
        whatever was commanded after ``t_s``; the last segment lasts for ever."""
        if not segments or segments[0].t0_s != t_s:
            raise ValueError("the new profile must start with a segment at t_s")
        if segments[-1].a != 0.0:
            raise ValueError("the last segment must have a = 0 (it lasts for ever)")
        with self.lock:
            t_s = self._history.changed_from(t_s)
            self._segments.replace_from(t_s, segments)
            self.revision += 1

    def set_faults(self, t_s: float, faults: StageFaults) -> None:
        """Change the imperfections from ``t_s`` on (from the next grid cell)."""
        with self.lock:
            t_s = self._history.changed_from(t_s)
            self.revision += 1
            self._history.set_faults(t_s, faults)

    # -- queries ----------------------------------------------------------------------------------

    def commanded(self, t_s: npt.ArrayLike) -> tuple[F64, F64, F64]:
        """(commanded position P in microsteps, rate in microsteps/s, acceleration) at times."""
        with self.lock:
            return self._segments.evaluate(np.asarray(t_s, dtype=np.float64))

    @property
    def segments(self) -> list[Segment]:
        """The commanded profile kept (since the reset or the pruned past), in order."""
        return self.segments_from(-math.inf)

    def segments_from(self, t_s: float) -> list[Segment]:
        """The kept profile from the segment in force at ``t_s`` on (found by bisection: a
        command looks at what it changes, not at the whole history)."""
        with self.lock:
            return self._segments.segments_from(t_s)

    def commanded_at(self, t_s: float) -> tuple[float, float]:
        """(P, rate) at one time."""
        pos, rate, _ = self.commanded(np.array([t_s]))
        return float(pos[0]), float(rate[0])

    def position_m(self, t_s: FloatArray) -> FloatArray:
        """True position (m) at each time (see the class docstring).

        The latest time asked for is "now" for pruning: history older than ``history_s``
        before it is dropped (``peek_position_m`` looks ahead without moving "now")."""
        with self.lock:
            times = np.asarray(t_s, dtype=np.float64)
            x, _, _ = self._history.lookup(times.ravel(), want_velocity=False, note=True)
            return x.reshape(times.shape)

    def peek_position_m(self, t_s: FloatArray) -> FloatArray:
        """``position_m`` for a look ahead (a controller predicting events): the times asked
        for do not count as "now" for pruning."""
        with self.lock:
            times = np.asarray(t_s, dtype=np.float64)
            x, _, _ = self._history.lookup(times.ravel(), want_velocity=False, note=False)
            return x.reshape(times.shape)

    def velocity_m_s(self, t_s: FloatArray) -> FloatArray:
        """True velocity (m/s) at each time."""
        with self.lock:
            times = np.asarray(t_s, dtype=np.float64)
            _, v, _ = self._history.lookup(times.ravel(), want_velocity=True, note=True)
            return v.reshape(times.shape)

    def missed_microsteps(self, t_s: FloatArray) -> FloatArray:
        """Commanded microsteps the motor has missed since the reset, at each time."""
        with self.lock:
            times = np.asarray(t_s, dtype=np.float64)
            _, _, missed = self._history.lookup(times.ravel(), want_velocity=False, note=True)
            return missed.reshape(times.shape)

    def encoder_counts(
        self,
        t_s: FloatArray,
        reference_m: float = 0.0,
        counts_at_reference: int = 0,
        *,
        peek: bool = False,
    ) -> npt.NDArray[np.int64]:
        """The encoder: ``floor((x - reference_m) * counts_per_m) + counts_at_reference``
        (``peek``: a look ahead, as ``peek_position_m``)."""
        x = self.peek_position_m(t_s) if peek else self.position_m(t_s)
        counts = np.floor((x - reference_m) * self.profile.encoder_counts_per_m + _ENCODER_EPS)
        result: npt.NDArray[np.int64] = counts.astype(np.int64) + counts_at_reference
        return result

    def first_crossing(
        self, level_m: float, t_from_s: float, t_to_s: float, direction: int
    ) -> float | None:
        """The first time in ``[t_from_s, t_to_s]`` at which the true position reaches
        ``level_m`` going down (``direction < 0``) or up; None if it does not."""
        with self.lock:
            step = self.grid_s
            chunk_s = BLOCK_CELLS * step
            start = t_from_s
            sign = -1.0 if direction < 0 else 1.0
            if sign * (float(self.peek_position_m(np.array([start]))[0]) - level_m) >= 0.0:
                return start
            while start < t_to_s:
                end = min(start + chunk_s, t_to_s)
                n = max(2, math.ceil((end - start) / step) + 1)
                times = np.linspace(start, end, n)
                x = self.peek_position_m(times)
                hits = np.nonzero(sign * (x - level_m) >= 0.0)[0]
                if hits.size:
                    hi_i = int(hits[0])
                    lo, hi = float(times[hi_i - 1]), float(times[hi_i])
                    for _ in range(60):
                        mid = 0.5 * (lo + hi)
                        mid_x = float(self.peek_position_m(np.array([mid]))[0])
                        if sign * (mid_x - level_m) >= 0.0:
                            hi = mid
                        else:
                            lo = mid
                        if hi - lo < 1e-12:
                            break
                    return hi
                start = end
            return None

    @property
    def kept_from_s(self) -> float:
        """The earliest time the stage still knows (older history was pruned)."""
        return self._history.kept_from_s

    # -- the model, for tests and plots -----------------------------------------------------------

    def jitter_noise(self, t_s: FloatArray) -> FloatArray:
        """The unit-variance noise ``n(t)`` of the jitter term (for tests and plots)."""
        return self.kinematics.jitter_noise(np.asarray(t_s, dtype=np.float64))

    def overloaded(
        self, faults: StageFaults, rate_hz: npt.ArrayLike, accel_hz_per_s: npt.ArrayLike
    ) -> npt.NDArray[np.bool_]:
        """Where the torque the motion needs exceeds the pull-out torque (see the docstring)."""
        rate = np.asarray(rate_hz, dtype=np.float64)
        acc = np.broadcast_to(np.asarray(accel_hz_per_s, dtype=np.float64), rate.shape)
        return self.kinematics.overloaded(faults, rate, np.asarray(acc))
