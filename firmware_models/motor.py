"""The FPGA's stepper controller: step generator, soft limits, driver state machine (sans clock).

``MotorController`` executes the MOTOR_* commands of ``config/protocol.toml`` against a
``firmware_models.stage.StepperStage``. Every method takes the device time ``t_s`` and the
decoded request fields (physical values as the dictionary decodes them: rates in microsteps per
second, positions in microsteps, times in seconds, enums by name) and returns the response
fields by their protocol names; a refusal raises ``firmware_models.errors.Nak`` with an
operator-readable detail. ``handle(name, t_s, request)`` dispatches by command name.

Step generator. The FPGA's commanded position ``P`` (microsteps) follows a profile of constant
acceleration segments (``firmware_models.stage.Segment``): trapezoidal moves (triangular when
short), jogs that re-ramp from the rate in force to the new one, and stops at the programmed
acceleration. A jog toward a soft limit is planned as a move to the limit at the jog rate, so it
starts braking in time and stops exactly at the limit. ESTOP stops the pulses at once.

State machine (MOTOR_GET ``state``)::

    disabled --ENABLE on--> idle --SET_RATE--> ramping <-> running --(rate 0, limit)--> idle
                             |  \\--MOVE--> moving --(target reached)--> idle
                             |   \\--HOME--> homing --(switch, back to it)--> idle, homed
      any state --ESTOP--> estop --ENABLE on--> idle;  idle --ENABLE off--> disabled

Stops the stage makes by itself (a move done, a limit reached, homing done, a stall, an
emergency stop while moving) are reported once each by ``poll_events`` as MOTOR_STOPPED events;
``next_event_s`` says when the next one is due. The following-error check: every
``[sim] stall_check_s`` of device time, while pulses go out, the FPGA compares the encoder's
motion over the last window with the commanded one; less than ``stall_ratio`` of it (with at
least ``stall_min_counts`` commanded) is a stall: the pulses stop at once and the event says
``stall``. Because the stage is deterministic, the controller predicts these stops when it plans
(up to ``LOOKAHEAD_S`` ahead, extended as time goes on).

Positions: the step counter (``steps``) is ``round(P - offset)``; at power-on the stage stands
in the middle of a rail's travel (half a turn from a turntable's index), the counter reads that
position in microsteps from the low end (``travel_m * microsteps_per_m / 2``) and the encoder
``floor(x * counts_per_m)``, as if homed, but ``homed`` is ``no``. HOME runs toward the low end
at the homing rate until the home switch (rail: position 0; turntable: the index mark below)
trips, brakes, returns to the switch, and makes the trip point 0 microsteps and 0 counts. Soft
limits are in step-counter microsteps; at power-on they are the mechanical travel (turntable:
the whole i32 range).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from camd.motion.stage_profile import StageProfile
from firmware_models.errors import Nak
from firmware_models.stage import Segment, StageFaults, StepperStage, power_on_position_m

MotorState = Literal["disabled", "idle", "ramping", "running", "moving", "homing", "estop"]
StopReason = Literal["done", "limit_low", "limit_high", "estop", "homed", "stall"]
Event = tuple[str, dict[str, Any]]

I32_MIN = -(2**31)
I32_MAX = 2**31 - 1
ENCODER_RATE_WINDOW_S = 0.01  # MOTOR_GET encoder_rate_hz: counts per second over 10 ms
LOOKAHEAD_S = 60.0  # stalls are predicted this far ahead, and again as time goes on
_HOME_MARGIN_S = 10.0


# -- profile planning (pure) ----------------------------------------------------------------------


def ramp_profile(t_s: float, p: float, v: float, rate: float, accel: float) -> list[Segment]:
    """From (``p``, ``v``) at ``t_s``: ramp at ``accel`` to ``rate`` and hold it."""
    if rate == v:
        return [Segment(t_s, p, v, 0.0)]
    tau = abs(rate - v) / accel
    acc = math.copysign(accel, rate - v)
    return [Segment(t_s, p, v, acc), Segment(t_s + tau, p + 0.5 * (v + rate) * tau, rate, 0.0)]


def move_profile(
    t_s: float, p: float, v: float, target: float, vmax: float, accel: float
) -> list[Segment]:
    """From (``p``, ``v``) at ``t_s``: reach ``target`` at rest, cruising at most at ``vmax``.

    Trapezoidal (accelerate, cruise, brake) when there is room, triangular when short; a stage
    moving away from the target, or too fast to stop before it, brakes to rest first. The last
    segment is the rest at ``target``, exactly."""
    segs: list[Segment] = []
    d = target - p
    if v != 0.0 and (v * d <= 0.0 or v * v / (2.0 * accel) > abs(d) * (1.0 + 1e-9) + 1e-9):
        tau = abs(v) / accel
        segs.append(Segment(t_s, p, v, -math.copysign(accel, v)))
        p += 0.5 * v * tau
        t_s += tau
        v = 0.0
        d = target - p
    distance = abs(d)
    if distance <= 1e-9 and v == 0.0:
        segs.append(Segment(t_s, target, 0.0, 0.0))
        return segs
    s = math.copysign(1.0, d)
    u = abs(v)
    phases: list[tuple[float, float]] = []  # (duration, signed acceleration)
    if u > 0.0 and u * u / (2.0 * accel) >= distance * (1.0 - 1e-12):
        brake = u * u / (2.0 * distance)  # on the braking curve already (within rounding)
        phases.append((u / brake, -s * brake))
    elif u > vmax:
        cruise = distance - u * u / (2.0 * accel)
        phases += [
            ((u - vmax) / accel, -s * accel),
            (cruise / vmax, 0.0),
            (vmax / accel, -s * accel),
        ]
    else:
        peak = math.sqrt(accel * distance + 0.5 * u * u)
        if peak <= vmax:
            phases += [((peak - u) / accel, s * accel), (peak / accel, -s * accel)]
        else:
            cruise = distance - (vmax * vmax - u * u) / (2.0 * accel) - vmax * vmax / (2.0 * accel)
            phases += [
                ((vmax - u) / accel, s * accel),
                (cruise / vmax, 0.0),
                (vmax / accel, -s * accel),
            ]
    for duration, acc in phases:
        if duration <= 0.0:
            continue
        segs.append(Segment(t_s, p, v, acc))
        p += v * duration + 0.5 * acc * duration * duration
        v += acc * duration
        t_s += duration
    segs.append(Segment(t_s, target, 0.0, 0.0))
    return segs


def trapezoid_time_s(distance: float, vmax: float, accel: float) -> float:
    """Duration of a rest-to-rest move: ``d / v + v / a``, or ``2 sqrt(d / a)`` when short."""
    distance = abs(distance)
    if distance >= vmax * vmax / accel:
        return distance / vmax + vmax / accel
    return 2.0 * math.sqrt(distance / accel)


def rebase(segments: list[Segment], t_s: float) -> list[Segment]:
    """The part of a profile from ``t_s`` on, its first segment starting at ``t_s``."""
    j = 0
    while j + 1 < len(segments) and segments[j + 1].t0_s <= t_s:
        j += 1
    p, v = segments[j].at(t_s)
    return [Segment(t_s, p, v, segments[j].a), *segments[j + 1 :]]


# -- the controller -------------------------------------------------------------------------------


@dataclass(slots=True)
class _Epoch:
    """From ``t_s`` on, steps = P - ``offset`` and the encoder counts from ``reference_m``."""

    t_s: float
    offset: float
    reference_m: float
    homed: bool


@dataclass(slots=True)
class _Plan:
    """A motion in progress: what was commanded, and when and why it comes to rest."""

    kind: Literal["jog", "move", "stop", "home"]
    segments: list[Segment]  # as commanded (no stall cut), absolute times
    end_s: float | None  # when the stage comes to rest (None: not within the look ahead)
    goal: StopReason  # why it comes to rest if nothing goes wrong
    reason: StopReason = "done"  # why it comes to rest as predicted (the goal, or a stall)
    checked_until_s: float = math.inf  # stalls were looked for up to here
    # Homing: the run toward the switch, and the switch once found.
    home_level_m: float | None = None
    home_run: list[Segment] = field(default_factory=list)
    trip_s: float | None = None


class MotorController:
    """The FPGA's stepper controller for one stage (see the module docstring)."""

    def __init__(
        self,
        profile: StageProfile,
        *,
        seed: int = 0,
        faults: StageFaults | None = None,
        t0_s: float = 0.0,
        grid_s: float | None = None,
        history_s: float | None = None,
    ) -> None:
        self.profile = profile
        self._d = profile.metres_per_microstep
        self._cpm = profile.encoder_counts_per_m
        p0 = round(power_on_position_m(profile) * profile.microsteps_per_m)
        extra: dict[str, float] = {}
        if grid_s is not None:
            extra["grid_s"] = grid_s
        if history_s is not None:
            extra["history_s"] = history_s
        self.stage = StepperStage(
            profile, seed=seed, faults=faults, t0_s=t0_s, position_m=p0 * self._d, **extra
        )
        # The driver's own maxima, which a fresh device reports as its limits.
        travel = profile.travel_microsteps
        self.hw_low_steps = 0 if travel is not None else I32_MIN
        self.hw_high_steps = travel if travel is not None else I32_MAX
        self.hw_max_rate_hz = math.floor(profile.max_rate_hz * 1000.0 + 1e-6) / 1000.0
        self.hw_accel_hz_per_s = max(1, math.floor(profile.max_accel_hz_per_s + 1e-9))
        self.low_steps = self.hw_low_steps
        self.high_steps = self.hw_high_steps
        self.max_rate_hz = self.hw_max_rate_hz
        self.accel_hz_per_s: int = self.hw_accel_hz_per_s
        check = profile.sim.stall_check_s.value
        self._check_cells = max(1, round(check / self.stage.grid_s))
        self.stall_check_s = self._check_cells * self.stage.grid_s
        self._driver: Literal["disabled", "enabled", "estop"] = "disabled"
        self._plan: _Plan | None = None
        self._epochs = [_Epoch(t0_s, 0.0, 0.0, homed=False)]
        self._epoch_changes = 0  # see ``revision``
        self._events: list[tuple[float, Event]] = []
        self._last_t = t0_s
        self._handlers: dict[str, Callable[..., dict[str, Any]]] = {
            "MOTOR_ENABLE": self.motor_enable,
            "MOTOR_SET_RATE": self.motor_set_rate,
            "MOTOR_MOVE": self.motor_move,
            "MOTOR_STOP": self.motor_stop,
            "MOTOR_HOME": self.motor_home,
            "MOTOR_GET": self.motor_get,
            "MOTOR_SET_LIMITS": self.motor_set_limits,
            "MOTOR_GET_LIMITS": self.motor_get_limits,
            "MOTOR_ESTOP": self.motor_estop,
            "SIM_SET_STAGE_FAULTS": self.sim_set_stage_faults,
            "SIM_GET_STAGE": self.sim_get_stage,
        }

    # -- dispatch ---------------------------------------------------------------------------------

    @property
    def commands(self) -> list[str]:
        """The command names ``handle`` executes."""
        return list(self._handlers)

    def handle(self, command: str, t_s: float, request: Mapping[str, Any]) -> dict[str, Any]:
        """Execute ``command`` (a protocol name) with its decoded request fields at ``t_s``."""
        return self._handlers[command](t_s, **request)

    # -- readings -----------------------------------------------------------------------------------

    @property
    def faults(self) -> StageFaults:
        return self.stage.faults

    def steps(self, t_s: float) -> int:
        """The step counter (commanded position, microsteps) at ``t_s``."""
        with self.stage.lock:
            p, _ = self.stage.commanded_at(t_s)
            return round(p - self._epoch_at(t_s).offset)

    def encoder_count(self, t_s: float) -> int:
        """The encoder count at ``t_s`` (what the FPGA latches into a frame header)."""
        return self.encoder_counts([t_s])[0]

    def encoder_counts(self, times_s: Sequence[float]) -> list[int]:
        """``encoder_count`` at each of ``times_s``, in one look-up of the stage (a block of
        frames' latches at once: one vectorised call costs about what one scalar call does)."""
        with self.stage.lock:
            times = np.asarray(times_s, dtype=np.float64)
            references = {self._epoch_at(float(t)).reference_m for t in times}
            if len(references) == 1:
                return [int(c) for c in self.stage.encoder_counts(times, references.pop())]
            # A homing's trip among them: each time with its own epoch's reference.
            return [
                int(
                    self.stage.encoder_counts(np.array([t]), self._epoch_at(float(t)).reference_m)[
                        0
                    ]
                )
                for t in times
            ]

    @property
    def revision(self) -> int:
        """Changes whenever a command changed what the stage does or where the encoder counts
        from: encoder counts looked up at one revision stay true until it changes."""
        return self.stage.revision + self._epoch_changes

    def homed(self, t_s: float) -> bool:
        return self._epoch_at(t_s).homed

    def state(self, t_s: float) -> MotorState:
        """The MOTOR_GET state at ``t_s`` (after ``advance``)."""
        if self._driver == "disabled":
            return "disabled"
        if self._driver == "estop":
            return "estop"
        plan = self._plan
        if plan is None or (plan.end_s is not None and t_s >= plan.end_s):
            return "idle"
        if plan.kind == "home":
            return "homing"
        if plan.kind == "move":
            return "moving"
        _, rate, acc = self.stage.commanded(np.array([t_s]))
        if acc[0] != 0.0:
            return "ramping"
        return "running" if rate[0] != 0.0 else "idle"

    def _epoch_at(self, t_s: float) -> _Epoch:
        for epoch in reversed(self._epochs):
            if epoch.t_s <= t_s:
                return epoch
        return self._epochs[0]

    # -- events -------------------------------------------------------------------------------------

    def advance(self, t_s: float) -> float:
        """Bring the state machine to ``t_s`` (stops that happened by then become events);
        return ``t_s``, or the latest time seen if ``t_s`` is earlier (time never runs back)."""
        with self.stage.lock:
            t_s = max(float(t_s), self._last_t)
            self._last_t = t_s
            plan = self._plan
            while plan is not None and plan.end_s is None and plan.checked_until_s <= t_s:
                self._look_ahead(plan, plan.checked_until_s)
            if plan is not None and plan.end_s is not None and plan.end_s <= t_s:
                self._commit(plan.end_s, plan.reason)
                self._plan = None
            return t_s

    def poll_events(self, t_s: float) -> list[Event]:
        """The MOTOR_STOPPED events that happened by ``t_s``, each returned once, in order."""
        with self.stage.lock:
            self.advance(t_s)
            events = [event for _, event in self._events]
            self._events.clear()
            return events

    def next_event_s(self) -> float | None:
        """When ``poll_events`` next has something (or must look further ahead); None: never
        without a command."""
        if self._events:
            return self._events[0][0]
        plan = self._plan
        if plan is None:
            return None
        if plan.end_s is not None:
            return plan.end_s
        return plan.checked_until_s if math.isfinite(plan.checked_until_s) else None

    def _commit(self, t_s: float, reason: StopReason) -> None:
        values = {
            "reason": reason,
            "steps": _i32(self.steps(t_s)),
            "encoder": _i32(self.encoder_count(t_s)),
        }
        self._events.append((t_s, ("MOTOR_STOPPED", values)))

    # -- commands -----------------------------------------------------------------------------------

    def motor_enable(self, t_s: float, *, enable: str | bool) -> dict[str, Any]:
        """MOTOR_ENABLE: ``enable`` ``on`` / ``off`` (or a bool)."""
        with self.stage.lock:
            t_s = self.advance(t_s)
            on = enable if isinstance(enable, bool) else str(enable) == "on"
            if on:
                self._driver = "enabled"
            elif self._moving(t_s):
                raise Nak(
                    "ILLEGAL_STATE",
                    f"MOTOR_ENABLE off refused: the stage is {self.state(t_s)} at "
                    f"{self._rate(t_s):.6g} microsteps/s; send MOTOR_STOP, wait for "
                    "MOTOR_STOPPED, then release the driver",
                )
            elif self._driver != "estop":
                self._driver = "disabled"
            return {"steps": _i32(self.steps(t_s)), "encoder": _i32(self.encoder_count(t_s))}

    def motor_set_rate(self, t_s: float, *, rate_hz: float) -> dict[str, Any]:
        """MOTOR_SET_RATE: jog at ``rate_hz`` (signed microsteps/s), re-ramping from now."""
        with self.stage.lock:
            t_s = self.advance(t_s)
            self._require_driver("MOTOR_SET_RATE", t_s)
            self._refuse_while_homing("MOTOR_SET_RATE", t_s)
            rate = float(rate_hz)
            if abs(rate) > self.max_rate_hz * (1.0 + 1e-12):
                raise Nak(
                    "OUT_OF_RANGE",
                    f"MOTOR_SET_RATE refused: {abs(rate):.6g} microsteps/s "
                    f"({abs(rate) * self._d:.6g} m/s) is above the programmed maximum "
                    f"{self.max_rate_hz:.6g} microsteps/s ({self.max_rate_hz * self._d:.6g} m/s); "
                    "lower the rate, or raise the maximum with MOTOR_SET_LIMITS (driver maximum "
                    f"{self.hw_max_rate_hz:.6g})",
                )
            p, v = self.stage.commanded_at(t_s)
            accel = float(self.accel_hz_per_s)
            if rate == 0.0:
                if self._plan is None and v == 0.0:
                    return {"ramp_s": 0.0, "steps": _i32(self.steps(t_s))}
                segments = ramp_profile(t_s, p, v, 0.0, accel)
                self._start(t_s, _Plan("stop", segments, segments[-1].t0_s, "done"))
                return {"ramp_s": abs(v) / accel, "steps": _i32(self.steps(t_s))}
            offset = self._epoch_at(t_s).offset
            steps_now = p - offset
            reason: StopReason
            if rate > 0.0:
                limit, reason, side = self.high_steps, "limit_high", "high"
                blocked = steps_now >= limit - 0.5
            else:
                limit, reason, side = self.low_steps, "limit_low", "low"
                blocked = steps_now <= limit + 0.5
            if blocked and v == 0.0:
                other = "negative" if rate > 0 else "positive"
                raise Nak(
                    "OUT_OF_RANGE",
                    f"MOTOR_SET_RATE refused: the stage stands at the {side} soft limit "
                    f"{limit} microsteps; jog the other way (a {other} rate) or widen the "
                    "limits with MOTOR_SET_LIMITS",
                )
            segments = move_profile(t_s, p, v, limit + offset, abs(rate), accel)
            self._start(t_s, _Plan("jog", segments, segments[-1].t0_s, reason))
            return {"ramp_s": abs(rate - v) / accel, "steps": _i32(self.steps(t_s))}

    def motor_move(self, t_s: float, *, target_steps: int, rate_hz: float) -> dict[str, Any]:
        """MOTOR_MOVE: trapezoidal move to ``target_steps`` cruising at ``rate_hz`` (0: max)."""
        with self.stage.lock:
            t_s = self.advance(t_s)
            self._require_driver("MOTOR_MOVE", t_s)
            self._refuse_while_homing("MOTOR_MOVE", t_s)
            target = int(target_steps)
            if not self.low_steps <= target <= self.high_steps:
                side = "above the high" if target > self.high_steps else "below the low"
                limit = self.high_steps if target > self.high_steps else self.low_steps
                raise Nak(
                    "OUT_OF_RANGE",
                    f"MOTOR_MOVE refused: target {target} microsteps is {side} soft limit "
                    f"{limit}; move within [{self.low_steps}, {self.high_steps}] or widen the "
                    "limits with MOTOR_SET_LIMITS",
                )
            rate = float(rate_hz) if rate_hz else self.max_rate_hz
            if rate < 0.0 or rate > self.max_rate_hz * (1.0 + 1e-12):
                raise Nak(
                    "OUT_OF_RANGE",
                    f"MOTOR_MOVE refused: rate {rate:.6g} microsteps/s "
                    f"({rate * self._d:.6g} m/s) is above the programmed maximum "
                    f"{self.max_rate_hz:.6g} microsteps/s; give at most that (0 means the "
                    "maximum) or raise it with MOTOR_SET_LIMITS",
                )
            p, v = self.stage.commanded_at(t_s)
            offset = self._epoch_at(t_s).offset
            accel = float(self.accel_hz_per_s)
            segments = move_profile(t_s, p, v, target + offset, rate, accel)
            self._start(t_s, _Plan("move", segments, segments[-1].t0_s, "done"))
            return {"duration_s": segments[-1].t0_s - t_s}

    def motor_stop(self, t_s: float) -> dict[str, Any]:
        """MOTOR_STOP: brake to rest at the programmed acceleration (harmless at rest)."""
        with self.stage.lock:
            t_s = self.advance(t_s)
            p, v = self.stage.commanded_at(t_s)
            if self._plan is None:
                return {"steps": _i32(self.steps(t_s)), "stop_s": 0.0}
            accel = float(self.accel_hz_per_s)
            segments = ramp_profile(t_s, p, v, 0.0, accel)
            self._start(t_s, _Plan("stop", segments, segments[-1].t0_s, "done"))
            return {"steps": _i32(self.steps(t_s)), "stop_s": abs(v) / accel}

    def motor_home(self, t_s: float) -> dict[str, Any]:
        """MOTOR_HOME: find the home switch, return to it, zero steps and encoder there."""
        with self.stage.lock:
            t_s = self.advance(t_s)
            self._require_driver("MOTOR_HOME", t_s)
            if self._moving(t_s):
                raise Nak(
                    "ILLEGAL_STATE",
                    f"MOTOR_HOME refused: the stage is {self.state(t_s)}; send MOTOR_STOP and "
                    "wait for MOTOR_STOPPED first",
                )
            x = float(self.stage.peek_position_m(np.array([t_s]))[0])
            circumference = self.profile.circumference_m
            level = 0.0 if circumference is None else circumference * math.floor(x / circumference)
            p, v = self.stage.commanded_at(t_s)
            rate = min(self.profile.home_rate_hz, self.max_rate_hz)
            run = ramp_profile(t_s, p, v, -rate, float(self.accel_hz_per_s))
            plan = _Plan("home", run, None, "homed", home_level_m=level, home_run=run)
            self._start(t_s, plan)
            end = plan.end_s
            return {"duration_s": 0.0 if end is None else end - t_s}

    def motor_get(self, t_s: float) -> dict[str, Any]:
        """MOTOR_GET: state, homed, steps, encoder, rate, encoder rate, at_limit, time."""
        with self.stage.lock:
            t_s = self.advance(t_s)
            state = self.state(t_s)
            steps = self.steps(t_s)
            _, rate = self.stage.commanded_at(t_s)
            at_limit = "none"
            if rate == 0.0:
                if steps <= self.low_steps:
                    at_limit = "low"
                elif steps >= self.high_steps:
                    at_limit = "high"
            since = max(t_s - ENCODER_RATE_WINDOW_S, self.stage.kept_from_s, self.stage.t0_s)
            now_counts = self.encoder_count(t_s)
            if t_s - since > 0.0:
                before = self.encoder_count(since)
                encoder_rate = (now_counts - before) / (t_s - since)
            else:
                encoder_rate = 0.0
            return {
                "state": state,
                "homed": "yes" if self.homed(t_s) else "no",
                "steps": _i32(steps),
                "encoder": _i32(now_counts),
                "rate_hz": rate,
                "encoder_rate_hz": float(encoder_rate),
                "at_limit": at_limit,
                "time_s": t_s,
            }

    def motor_set_limits(
        self,
        t_s: float,
        *,
        low_steps: int,
        high_steps: int,
        max_rate_hz: float,
        accel_hz_per_s: float,
    ) -> dict[str, Any]:
        """MOTOR_SET_LIMITS: soft limits, maximum rate and ramp acceleration."""
        with self.stage.lock:
            t_s = self.advance(t_s)
            if self._moving(t_s):
                raise Nak(
                    "ILLEGAL_STATE",
                    f"MOTOR_SET_LIMITS refused: the stage is {self.state(t_s)}; send MOTOR_STOP "
                    "and wait for MOTOR_STOPPED first",
                )
            low, high = int(low_steps), int(high_steps)
            rate, accel = float(max_rate_hz), float(accel_hz_per_s)
            hw = f"[{self.hw_low_steps}, {self.hw_high_steps}]"
            if low >= high:
                raise Nak(
                    "OUT_OF_RANGE",
                    f"MOTOR_SET_LIMITS refused: low_steps {low} must be below high_steps {high}",
                )
            if low < self.hw_low_steps or high > self.hw_high_steps:
                travel = (
                    f" ({self.profile.travel_m.value:g} m of travel)"
                    if self.profile.travel_m is not None
                    else ""
                )
                raise Nak(
                    "OUT_OF_RANGE",
                    f"MOTOR_SET_LIMITS refused: [{low}, {high}] microsteps goes beyond the "
                    f"mechanical range {hw}{travel}; keep the limits within it",
                )
            if not 0.0 < rate <= self.hw_max_rate_hz * (1.0 + 1e-12):
                raise Nak(
                    "OUT_OF_RANGE",
                    f"MOTOR_SET_LIMITS refused: max_rate_hz {rate:.6g} microsteps/s "
                    f"({rate * self._d:.6g} m/s) is above the driver's maximum "
                    f"{self.hw_max_rate_hz:.6g} ({self.profile.max_speed_m_s.value:g} m/s); "
                    "lower it",
                )
            if not 1.0 <= accel <= self.hw_accel_hz_per_s:
                raise Nak(
                    "OUT_OF_RANGE",
                    f"MOTOR_SET_LIMITS refused: accel_hz_per_s {accel:.6g} microsteps/s^2 "
                    f"({accel * self._d:.6g} m/s^2) is outside 1 .. {self.hw_accel_hz_per_s} "
                    f"({self.profile.max_accel_m_s2.value:g} m/s^2); choose a value within",
                )
            steps = self.steps(t_s)
            if not low <= steps <= high:
                raise Nak(
                    "OUT_OF_RANGE",
                    f"MOTOR_SET_LIMITS refused: the stage stands at {steps} microsteps, outside "
                    f"[{low}, {high}]; move inside first or choose limits that contain it",
                )
            self.low_steps, self.high_steps = low, high
            self.max_rate_hz = rate
            self.accel_hz_per_s = int(accel)
            return {}

    def motor_get_limits(self, t_s: float) -> dict[str, Any]:
        """MOTOR_GET_LIMITS: the limits in force."""
        with self.stage.lock:
            self.advance(t_s)
            return {
                "low_steps": self.low_steps,
                "high_steps": self.high_steps,
                "max_rate_hz": self.max_rate_hz,
                "accel_hz_per_s": self.accel_hz_per_s,
            }

    def motor_estop(self, t_s: float) -> dict[str, Any]:
        """MOTOR_ESTOP: pulses stop at once, driver off, state estop until ENABLE on."""
        with self.stage.lock:
            t_s = self.advance(t_s)
            moving = self._moving(t_s)
            p, _ = self.stage.commanded_at(t_s)
            self._replace_plan(t_s)
            self.stage.set_profile(t_s, [Segment(t_s, p, 0.0, 0.0)])
            self._driver = "estop"
            if moving:
                self._commit(t_s, "estop")
            return {"steps": _i32(self.steps(t_s)), "encoder": _i32(self.encoder_count(t_s))}

    def set_faults(self, t_s: float, faults: StageFaults | None = None, **values: float) -> None:
        """Change the stage's imperfections from ``t_s`` (a whole ``StageFaults``, or some of
        ``error``, ``ripple``, ``jitter``, ``drift``, ``load``); a motion in progress is
        re-predicted (a stall may now come, or not)."""
        with self.stage.lock:
            t_s = self.advance(t_s)
            new = faults if faults is not None else self.stage.faults.updated(**values)
            self.stage.set_faults(t_s, new)
            plan = self._plan
            if plan is not None:
                if plan.kind == "home" and (plan.trip_s is None or plan.trip_s > t_s):
                    plan.segments = plan.home_run
                    plan.trip_s = None
                    self._epochs = [e for e in self._epochs if e.t_s <= t_s]
                    self._epoch_changes += 1
                self._start(t_s, plan)

    def sim_set_stage_faults(
        self, t_s: float, *, error: float, ripple: float, jitter: float, drift: float, load: float
    ) -> dict[str, Any]:
        """SIM_SET_STAGE_FAULTS: all five imperfections at once."""
        try:
            faults = StageFaults(
                float(error), float(ripple), float(jitter), float(drift), float(load)
            )
        except ValueError as exc:
            raise Nak("OUT_OF_RANGE", f"SIM_SET_STAGE_FAULTS refused: {exc}") from None
        self.set_faults(t_s, faults)
        return {}

    def sim_get_stage(self, t_s: float) -> dict[str, Any]:
        """SIM_GET_STAGE: the true position, velocity and missed steps."""
        with self.stage.lock:
            t_s = self.advance(t_s)
            times = np.array([t_s])
            return {
                "position_m": float(self.stage.position_m(times)[0]),
                "velocity_m_s": float(self.stage.velocity_m_s(times)[0]),
                "missed_steps": round(float(self.stage.missed_microsteps(times)[0])),
                "time_s": t_s,
            }

    # -- planning -----------------------------------------------------------------------------------

    def _require_driver(self, name: str, t_s: float) -> None:
        if self._driver == "disabled":
            raise Nak(
                "ILLEGAL_STATE", f"{name} refused: the driver is disabled; send MOTOR_ENABLE on"
            )
        if self._driver == "estop":
            raise Nak(
                "ILLEGAL_STATE",
                f"{name} refused: the stage is in emergency stop; MOTOR_ENABLE on clears it",
            )

    def _refuse_while_homing(self, name: str, t_s: float) -> None:
        if self._plan is not None and self._plan.kind == "home":
            raise Nak(
                "ILLEGAL_STATE",
                f"{name} refused while homing; wait for MOTOR_STOPPED (homed) or send MOTOR_STOP",
            )

    def _moving(self, t_s: float) -> bool:
        return self._plan is not None and (self._plan.end_s is None or t_s < self._plan.end_s)

    def _rate(self, t_s: float) -> float:
        return self.stage.commanded_at(t_s)[1]

    def _replace_plan(self, t_s: float) -> None:
        """Forget the motion in progress (and a homing reference not yet reached)."""
        self._plan = None
        self._epochs = [e for e in self._epochs if e.t_s <= t_s]
        self._epoch_changes += 1

    def _start(self, t_s: float, plan: _Plan) -> None:
        """Command ``plan`` from ``t_s``: set the stage's profile, predict stops and stalls."""
        self._replace_plan(t_s)
        if plan.kind == "home" and plan.trip_s is None:
            self._plan_homing(t_s, plan)
        else:
            self.stage.set_profile(t_s, rebase(plan.segments, t_s))
            plan.checked_until_s = t_s
            self._look_ahead(plan, t_s)
        self._plan = plan
        if plan.end_s is not None and plan.end_s <= t_s:
            self._commit(plan.end_s, plan.reason)
            self._plan = None

    def _look_ahead(self, plan: _Plan, t_s: float) -> None:
        """Look for a stall from ``t_s`` up to the plan's end or ``LOOKAHEAD_S`` ahead; cut the
        profile there if one comes."""
        end = plan.segments[-1].t0_s
        horizon = min(end, t_s + LOOKAHEAD_S)
        stall = self._find_stall(t_s, horizon, open_ended=horizon < end)
        if stall is not None:
            p, _ = self.stage.commanded_at(stall)
            self.stage.set_profile(stall, [Segment(stall, p, 0.0, 0.0)])
            plan.end_s, plan.reason = stall, "stall"
            plan.checked_until_s = math.inf
        elif horizon >= end:
            plan.end_s, plan.reason = end, plan.goal
            plan.checked_until_s = math.inf
        else:
            plan.end_s, plan.reason = None, plan.goal
            plan.checked_until_s = horizon

    def _plan_homing(self, t_s: float, plan: _Plan) -> None:
        level = plan.home_level_m
        assert level is not None
        plan.reason = plan.goal
        run = rebase(plan.home_run, t_s)
        self.stage.set_profile(t_s, run)
        x = float(self.stage.peek_position_m(np.array([t_s]))[0])
        rate = abs(run[-1].v0)
        nominal = abs(x - level) / (rate * self._d) if rate else math.inf
        bound = t_s + 2.0 * nominal + _HOME_MARGIN_S
        stall = self._find_stall(t_s, bound, open_ended=True)
        trip = self.stage.first_crossing(level, t_s, bound if stall is None else stall, -1)
        if trip is None:
            if stall is not None:
                p, _ = self.stage.commanded_at(stall)
                self.stage.set_profile(stall, [Segment(stall, p, 0.0, 0.0)])
                plan.segments, plan.end_s, plan.reason = run, stall, "stall"
            else:  # the carriage cannot reach the switch (it crawls): run on, no event
                plan.segments, plan.end_s = run, None
            plan.checked_until_s = math.inf
            return
        p_trip, v_trip = self.stage.commanded_at(trip)
        accel = float(self.accel_hz_per_s)
        back = move_profile(trip, p_trip, v_trip, p_trip, rate, accel)
        plan.trip_s = trip
        plan.segments = [*[s for s in run if s.t0_s < trip], *back]
        self._epochs.append(_Epoch(trip, p_trip, level, homed=True))
        self._epoch_changes += 1
        self.stage.set_profile(trip, back)
        plan.checked_until_s = trip
        self._look_ahead(plan, trip)

    def _find_stall(self, t_a: float, t_b: float, *, open_ended: bool) -> float | None:
        """The first following-error check in ``(t_a, t_b]`` (``open_ended``: the last segment
        goes on) that sees a stall, or None. Only windows near overloaded motion are checked:
        elsewhere the carriage follows the pulses."""
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


def _i32(value: int) -> int:
    """A counter as the FPGA's 32-bit register holds it (wrapping, signed)."""
    return (int(value) - I32_MIN) % 2**32 + I32_MIN
