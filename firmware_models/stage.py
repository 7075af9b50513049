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
separates and has a closed-form solution (``_ripple_u`` / ``_ripple_x``). A new profile or new
faults from time ``t`` discard what was integrated after ``t``; blocks without commanded motion
cost nothing; history older than ``history_s`` is dropped. Fault changes act from the next
grid cell. The result is deterministic for a seed and a sequence of calls.
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass, fields, replace
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np
import numpy.typing as npt

if TYPE_CHECKING:
    from camd.motion.stage_profile import StageProfile

FloatArray = npt.NDArray[np.floating[Any]]
F64 = npt.NDArray[np.float64]

GRID_S = 50e-6
BLOCK_CELLS = 4096
HISTORY_S = 120.0
JITTER_MODES = 64
# Encoder counts within this much of the next integer count as it (float rounding of x).
_ENCODER_EPS = 1e-6
_STREAM_RIPPLE = 0x5250  # "RP"
_STREAM_JITTER = 0x4A54  # "JT"


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


# -- the imperfections ----------------------------------------------------------------------------

# key: (lowest, highest, meaning); the ranges of --inject stage_* and SIM_SET_STAGE_FAULTS.
FAULT_RANGES: dict[str, tuple[float, float, str]] = {
    "error": (-0.1, 0.1, "relative step-rate error"),
    "ripple": (0.0, 0.2, "relative amplitude of the periodic speed ripple"),
    "jitter": (0.0, 0.2, "relative rms random speed jitter"),
    "drift": (-0.1, 0.1, "relative speed drift per second of running"),
    "load": (0.0, 3.0, "load torque as a fraction of the low-speed pull-out torque"),
}


@dataclass(frozen=True, slots=True)
class StageFaults:
    """The stage's imperfections (see the module docstring); all zero is a perfect stage."""

    error: float = 0.0
    ripple: float = 0.0
    jitter: float = 0.0
    drift: float = 0.0
    load: float = 0.0

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            lo, hi, meaning = FAULT_RANGES[f.name]
            if not lo <= value <= hi:  # NaN too
                raise ValueError(
                    f"stage fault {f.name} = {value:g} is out of range: {f.name} ({meaning}) "
                    f"must be from {lo:g} to {hi:g}"
                )

    @classmethod
    def from_profile(cls, profile: StageProfile) -> StageFaults:
        """The profile's ``[sim]`` defaults."""
        sim = profile.sim
        return cls(sim.error, sim.ripple, sim.jitter, sim.drift, sim.load)

    def updated(self, **changes: float | None) -> StageFaults:
        """A copy with the given (non-None) values changed."""
        return replace(self, **{k: float(v) for k, v in changes.items() if v is not None})

    def as_dict(self) -> dict[str, float]:
        return {f.name: float(getattr(self, f.name)) for f in fields(self)}


# -- the commanded profile ------------------------------------------------------------------------


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


class _Segments:
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


def _ripple_u(x: F64, r: float, k: float, phase: float) -> F64:
    """Ripple-free coordinate of position ``x``: ``u = (G(k x + phi) - G(phi)) / k``."""
    if r == 0.0:
        return x
    g0 = float(_ripple_g(np.array([phase]), r)[0])
    u: F64 = (_ripple_g(k * x + phase, r) - g0) / k
    return u


def _ripple_x(u: F64, r: float, k: float, phase: float) -> F64:
    """Inverse of ``_ripple_u``: the position for ripple-free coordinate ``u``."""
    if r == 0.0:
        return u
    g0 = float(_ripple_g(np.array([phase]), r)[0])
    x: F64 = (_ripple_g_inverse(k * u + g0, r) - phase) / k
    return x


# -- the stage ------------------------------------------------------------------------------------


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


def power_on_position_m(profile: StageProfile) -> float:
    """Where the stage stands at power-on: the middle of a rail's travel, half a turn from a
    turntable's index (so a scan can run before homing)."""
    if profile.travel_m is not None:
        return profile.travel_m.value / 2.0
    circumference = profile.circumference_m
    assert circumference is not None
    return circumference / 2.0


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
        self._k = 2.0 * math.pi / profile.sim.ripple_period_m.value
        ripple_rng = np.random.default_rng([seed, _STREAM_RIPPLE])
        self.ripple_phase_rad = float(ripple_rng.uniform(0.0, 2.0 * math.pi))
        jitter_rng = np.random.default_rng([seed, _STREAM_JITTER])
        tau = profile.sim.jitter_corr_s.value
        self._omega = np.abs(jitter_rng.standard_cauchy(JITTER_MODES)) / tau
        self._omega_phase = jitter_rng.uniform(0.0, 2.0 * math.pi, JITTER_MODES)
        self._rate_corner = profile.sim.pullout_corner_m_s.value * profile.microsteps_per_m
        self._accel_full = profile.max_accel_hz_per_s
        self._accel_fraction = profile.sim.accel_torque_fraction.value
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
                faults = self.faults if hasattr(self, "_fault_list") else StageFaults()
            # Counts changes of what was commanded (reset, profile, faults): a look-up made
            # at one revision stays true until the next.
            self.revision = getattr(self, "revision", 0) + 1
            self.t0_s = float(t0_s)
            self._segments = _Segments()
            self._segments.replace_from(
                self.t0_s, [Segment(self.t0_s, position_m / self._d, 0.0, 0.0)]
            )
            self._fault_t: list[float] = [self.t0_s]
            self._fault_list: list[StageFaults] = [faults]
            self._blocks: list[_Block] = []
            self._first_block = self._block_of(self.t0_s)
            self._reset_x = float(position_m)
            self._start = _Block(position_m, 0.0)  # the state before the first kept block
            self._kept_from_s = self.t0_s
            self._latest_s = self.t0_s

    @property
    def faults(self) -> StageFaults:
        """The imperfections in force now (the latest set)."""
        return self._fault_list[-1]

    def set_profile(self, t_s: float, segments: list[Segment]) -> None:
        """Command ``segments`` from ``t_s`` on (the first must start at ``t_s``), replacing
        whatever was commanded after ``t_s``; the last segment lasts for ever."""
        if not segments or segments[0].t0_s != t_s:
            raise ValueError("the new profile must start with a segment at t_s")
        if segments[-1].a != 0.0:
            raise ValueError("the last segment must have a = 0 (it lasts for ever)")
        with self.lock:
            t_s = self._at_least_start(t_s)
            self._truncate(t_s)
            self._segments.replace_from(t_s, segments)
            self.revision += 1

    def set_faults(self, t_s: float, faults: StageFaults) -> None:
        """Change the imperfections from ``t_s`` on (from the next grid cell)."""
        with self.lock:
            t_s = self._at_least_start(t_s)
            self._truncate(t_s)
            self.revision += 1
            while len(self._fault_t) > 1 and self._fault_t[-1] >= t_s:
                self._fault_t.pop()
                self._fault_list.pop()
            if self._fault_t[-1] >= t_s:
                self._fault_list[-1] = faults
            else:
                self._fault_t.append(t_s)
                self._fault_list.append(faults)

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
            x, _, _ = self._lookup(times.ravel(), want_velocity=False, note=True)
            return x.reshape(times.shape)

    def peek_position_m(self, t_s: FloatArray) -> FloatArray:
        """``position_m`` for a look ahead (a controller predicting events): the times asked
        for do not count as "now" for pruning."""
        with self.lock:
            times = np.asarray(t_s, dtype=np.float64)
            x, _, _ = self._lookup(times.ravel(), want_velocity=False, note=False)
            return x.reshape(times.shape)

    def velocity_m_s(self, t_s: FloatArray) -> FloatArray:
        """True velocity (m/s) at each time."""
        with self.lock:
            times = np.asarray(t_s, dtype=np.float64)
            _, v, _ = self._lookup(times.ravel(), want_velocity=True, note=True)
            return v.reshape(times.shape)

    def missed_microsteps(self, t_s: FloatArray) -> FloatArray:
        """Commanded microsteps the motor has missed since the reset, at each time."""
        with self.lock:
            times = np.asarray(t_s, dtype=np.float64)
            _, _, missed = self._lookup(times.ravel(), want_velocity=False, note=True)
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
        return self._kept_from_s

    # -- integration ------------------------------------------------------------------------------

    def _at_least_start(self, t_s: float) -> float:
        t_s = max(float(t_s), self.t0_s, self._kept_from_s)
        self._latest_s = max(self._latest_s, t_s)
        return t_s

    def _block_of(self, t_s: float) -> int:
        return math.floor(t_s / (self.grid_s * BLOCK_CELLS))

    def _truncate(self, t_s: float) -> None:
        b = self._block_of(t_s)
        keep = max(0, b - self._first_block)
        del self._blocks[keep:]

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
        keep_from = self._block_of(self._latest_s - self.history_s)
        drop = min(keep_from - self._first_block, len(self._blocks) - 1)
        if drop <= 0:
            return
        last_dropped = self._blocks[drop - 1]
        self._start = _Block(last_dropped.x_end, last_dropped.missed_end)
        del self._blocks[:drop]
        self._first_block += drop
        self._kept_from_s = self._first_block * BLOCK_CELLS * self.grid_s
        self._segments.drop_before(self._kept_from_s)
        keep = max(0, int(np.searchsorted(self._fault_t, self._kept_from_s, side="right")) - 1)
        del self._fault_t[:keep]
        del self._fault_list[:keep]

    def _compute_block(self, b: int, before: _Block) -> _Block:
        dt = self.grid_s
        i0 = b * BLOCK_CELLS
        t_start, t_end = i0 * dt, (i0 + BLOCK_CELLS) * dt
        x0, missed0 = before.x_end, before.missed_end
        if not self._segments.moving_between(t_start, t_end):
            return _Block(x0, missed0)
        t_pts = (i0 + np.arange(BLOCK_CELLS + 1, dtype=np.float64)) * dt
        p_pts, _, _ = self._segments.evaluate(t_pts)
        dp = np.diff(p_pts)
        t_mid = t_pts[:-1] + 0.5 * dt
        _, rate, acc = self._segments.evaluate(t_mid)
        run = self._segments.run_time(t_mid)
        regime = np.maximum(np.searchsorted(self._fault_t, t_mid, side="right") - 1, 0)
        x = np.empty(BLOCK_CELLS + 1)
        missed = np.empty(BLOCK_CELLS + 1)
        x[0], missed[0] = x0, missed0
        any_missed = False
        boundaries = np.flatnonzero(np.diff(regime)) + 1
        starts = [0, *boundaries.tolist()]
        ends = [*boundaries.tolist(), BLOCK_CELLS]
        for lo, hi in zip(starts, ends, strict=True):
            faults = self._fault_list[int(regime[lo])]
            cells = slice(lo, hi)
            speed = self._speed_factor(faults, t_mid[cells], run[cells])
            over = self._overloaded(faults, rate[cells], acc[cells]) & (dp[cells] != 0.0)
            speed = np.where(over, 0.0, speed)
            du = speed * self._d * dp[cells]
            missed[lo + 1 : hi + 1] = missed[lo] + np.cumsum(np.abs(dp[cells]) * over)
            any_missed = any_missed or bool(over.any())
            u_start = _ripple_u(np.array([x[lo]]), faults.ripple, self._k, self.ripple_phase_rad)
            u = u_start[0] + np.cumsum(du)
            x[lo + 1 : hi + 1] = _ripple_x(u, faults.ripple, self._k, self.ripple_phase_rad)
        return _Block(x0, missed0, x, missed if any_missed else None)

    def _speed_factor(self, faults: StageFaults, t_mid: F64, run: F64) -> F64:
        factor = np.full(t_mid.shape, 1.0 + faults.error)
        if faults.jitter:
            factor *= 1.0 + faults.jitter * self._jitter_noise(t_mid)
        if faults.drift:
            factor *= 1.0 + faults.drift * run
        clamped: F64 = np.maximum(factor, 0.0)
        return clamped

    def jitter_noise(self, t_s: FloatArray) -> FloatArray:
        """The unit-variance noise ``n(t)`` of the jitter term (for tests and plots)."""
        return self._jitter_noise(np.asarray(t_s, dtype=np.float64))

    def _jitter_noise(self, t: F64) -> F64:
        out = np.empty_like(t)
        amplitude = math.sqrt(2.0 / JITTER_MODES)
        for lo in range(0, t.size, 8192):
            part = t[lo : lo + 8192]
            phases = np.outer(part, self._omega) + self._omega_phase
            out[lo : lo + 8192] = amplitude * np.cos(phases).sum(axis=1)
        return out

    def overloaded(
        self, faults: StageFaults, rate_hz: npt.ArrayLike, accel_hz_per_s: npt.ArrayLike
    ) -> npt.NDArray[np.bool_]:
        """Where the torque the motion needs exceeds the pull-out torque (see the docstring)."""
        rate = np.asarray(rate_hz, dtype=np.float64)
        acc = np.broadcast_to(np.asarray(accel_hz_per_s, dtype=np.float64), rate.shape)
        return self._overloaded(faults, rate, np.asarray(acc))

    def _overloaded(self, faults: StageFaults, rate: F64, acc: F64) -> npt.NDArray[np.bool_]:
        need = faults.load + self._accel_fraction * np.abs(acc) / self._accel_full
        speed = np.abs(rate)
        available = np.where(
            speed > self._rate_corner, self._rate_corner / np.maximum(speed, 1e-300), 1.0
        )
        moving = (rate != 0.0) | (acc != 0.0)
        result: npt.NDArray[np.bool_] = moving & (need > available)
        return result

    def _lookup(self, t: F64, *, want_velocity: bool, note: bool) -> tuple[F64, F64, F64]:
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
        pruned = (t < self._kept_from_s) & ~before_start
        if pruned.any():
            raise ValueError(
                f"stage position asked for t = {float(t[pruned].min()):.6f} s, older than the "
                f"kept history (from {self._kept_from_s:.6f} s, {self.history_s:g} s back); "
                "render frames closer to the present or raise history_s"
            )
        if note:
            self._latest_s = max(self._latest_s, float(t.max()))
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
        p_t, rate_t, _ = self._segments.evaluate(ti)
        p_lo, _, _ = self._segments.evaluate(t_lo)
        p_hi, _, _ = self._segments.evaluate(t_lo + dt)
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

    def _velocity(self, t_mid: F64, rate: F64, x: F64) -> F64:
        """``v = r d (speed factor of the cell) (1 + R sin(k x + phi))``, the model's formula
        evaluated directly (a difference of positions would lose digits)."""
        _, rate_mid, acc_mid = self._segments.evaluate(t_mid)
        run = self._segments.run_time(t_mid)
        regime = np.maximum(np.searchsorted(self._fault_t, t_mid, side="right") - 1, 0)
        v = np.empty_like(t_mid)
        for r in np.unique(regime):
            sel = regime == r
            faults = self._fault_list[int(r)]
            speed = self._speed_factor(faults, t_mid[sel], run[sel])
            over = self._overloaded(faults, rate_mid[sel], acc_mid[sel])
            ripple = 1.0 + faults.ripple * np.sin(self._k * x[sel] + self.ripple_phase_rad)
            v[sel] = np.where(over, 0.0, rate[sel] * self._d * speed * ripple)
        return v

    def _block_at(self, b: int) -> _Block:
        index = b - self._first_block
        if index < 0:
            return _Block(self._start.x0, self._start.missed0)
        return self._blocks[index]
