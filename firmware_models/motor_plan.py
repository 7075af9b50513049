"""The stepper controller's motion in progress: when and why it comes to rest, and the events.

A MOTOR_* command (``firmware_models.motor``) plans a motion as a ``MotionPlan`` (its segments,
``firmware_models.motor_profiles``) and hands it to ``MotionPlanner.start``, which commands it
to the stage and predicts where it ends: at its goal (a move done, a limit reached, homing
done), or earlier at a stall the following-error check will see (``firmware_models.
motor_stall``, up to ``LOOKAHEAD_S`` ahead, looked for again as time goes on). A homing runs
toward the low end until the home switch trips, brakes, returns to the switch and re-zeroes
the counters there (``firmware_models.motor_counter``).

Stops the stage makes by itself are reported once each by ``poll_events`` as MOTOR_STOPPED
events; ``next_event_s`` says when the next one is due. Time never runs back: ``advance``
brings the state to a time, and an earlier time counts as the latest seen.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from firmware_models.motor_counter import StepCounter, i32
from firmware_models.motor_limits import MotorLimits
from firmware_models.motor_profiles import move_profile, ramp_profile, rebase
from firmware_models.motor_stall import StallCheck
from firmware_models.stage import Segment, StepperStage

StopReason = Literal["done", "limit_low", "limit_high", "estop", "homed", "stall"]
Event = tuple[str, dict[str, Any]]

LOOKAHEAD_S = 60.0  # stalls are predicted this far ahead, and again as time goes on
_HOME_MARGIN_S = 10.0


@dataclass(slots=True)
class MotionPlan:
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


class MotionPlanner:
    """The motion in progress on ``stage`` and the stops it makes (see the module docstring)."""

    def __init__(
        self,
        stage: StepperStage,
        counter: StepCounter,
        stall: StallCheck,
        limits: MotorLimits,
        t0_s: float,
    ) -> None:
        self.stage = stage
        self.counter = counter
        self.stall = stall
        self.limits = limits
        self._d = stage.profile.metres_per_microstep
        self.plan: MotionPlan | None = None
        self._events: list[tuple[float, Event]] = []
        self._last_t = t0_s

    # -- time and events ----------------------------------------------------------------------------

    def advance(self, t_s: float) -> float:
        """Bring the state to ``t_s`` (stops that happened by then become events); return
        ``t_s``, or the latest time seen if ``t_s`` is earlier (time never runs back)."""
        with self.stage.lock:
            t_s = max(float(t_s), self._last_t)
            self._last_t = t_s
            plan = self.plan
            while plan is not None and plan.end_s is None and plan.checked_until_s <= t_s:
                self._look_ahead(plan, plan.checked_until_s)
            if plan is not None and plan.end_s is not None and plan.end_s <= t_s:
                self.commit(plan.end_s, plan.reason)
                self.plan = None
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
        plan = self.plan
        if plan is None:
            return None
        if plan.end_s is not None:
            return plan.end_s
        return plan.checked_until_s if math.isfinite(plan.checked_until_s) else None

    def commit(self, t_s: float, reason: StopReason) -> None:
        """The stage came to rest at ``t_s`` for ``reason``: a MOTOR_STOPPED event."""
        values = {
            "reason": reason,
            "steps": i32(self.counter.steps(t_s)),
            "encoder": i32(self.counter.encoder_count(t_s)),
        }
        self._events.append((t_s, ("MOTOR_STOPPED", values)))

    # -- the plan -----------------------------------------------------------------------------------

    def moving(self, t_s: float) -> bool:
        """A motion is in progress at ``t_s``."""
        return self.plan is not None and (self.plan.end_s is None or t_s < self.plan.end_s)

    def motion_state(self, t_s: float) -> Literal["idle", "ramping", "running", "moving", "homing"]:
        """MOTOR_GET's state at ``t_s`` with the driver enabled (after ``advance``)."""
        plan = self.plan
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

    @property
    def homing(self) -> bool:
        """The motion in progress is a homing."""
        return self.plan is not None and self.plan.kind == "home"

    def replace(self, t_s: float) -> None:
        """Forget the motion in progress (and a homing reference not yet reached)."""
        self.plan = None
        self.counter.forget_after(t_s)

    def start(self, t_s: float, plan: MotionPlan) -> None:
        """Command ``plan`` from ``t_s``: set the stage's profile, predict stops and stalls."""
        self.replace(t_s)
        if plan.kind == "home" and plan.trip_s is None:
            self._plan_homing(t_s, plan)
        else:
            self.stage.set_profile(t_s, rebase(plan.segments, t_s))
            plan.checked_until_s = t_s
            self._look_ahead(plan, t_s)
        self.plan = plan
        if plan.end_s is not None and plan.end_s <= t_s:
            self.commit(plan.end_s, plan.reason)
            self.plan = None

    def brake(self, t_s: float, p: float, v: float, accel: float) -> None:
        """Brake from position ``p`` at rate ``v`` to rest at ``accel`` (MOTOR_STOP)."""
        segments = ramp_profile(t_s, p, v, 0.0, accel)
        self.start(t_s, MotionPlan("stop", segments, segments[-1].t0_s, "done"))

    def home(self, t_s: float, level_m: float, rate: float) -> MotionPlan:
        """Run toward the low end at ``rate`` until the home switch at ``level_m`` trips, then
        back to it (module docstring); the plan started."""
        p, v = self.stage.commanded_at(t_s)
        run = ramp_profile(t_s, p, v, -rate, float(self.limits.accel_hz_per_s))
        plan = MotionPlan("home", run, None, "homed", home_level_m=level_m, home_run=run)
        self.start(t_s, plan)
        return plan

    def predict_again(self, t_s: float) -> None:
        """The stage's faults changed at ``t_s``: predict the motion in progress again (a
        stall may now come, or not; a homing whose switch is not reached looks for it again)."""
        plan = self.plan
        if plan is not None:
            if plan.kind == "home" and (plan.trip_s is None or plan.trip_s > t_s):
                plan.segments = plan.home_run
                plan.trip_s = None
                self.counter.forget_after(t_s)
            self.start(t_s, plan)

    def _look_ahead(self, plan: MotionPlan, t_s: float) -> None:
        """Look for a stall from ``t_s`` up to the plan's end or ``LOOKAHEAD_S`` ahead; cut the
        profile there if one comes."""
        end = plan.segments[-1].t0_s
        horizon = min(end, t_s + LOOKAHEAD_S)
        stall = self.stall.first_stall(t_s, horizon, open_ended=horizon < end)
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

    def _plan_homing(self, t_s: float, plan: MotionPlan) -> None:
        level = plan.home_level_m
        assert level is not None
        plan.reason = plan.goal
        run = rebase(plan.home_run, t_s)
        self.stage.set_profile(t_s, run)
        x = float(self.stage.peek_position_m(np.array([t_s]))[0])
        rate = abs(run[-1].v0)
        nominal = abs(x - level) / (rate * self._d) if rate else math.inf
        bound = t_s + 2.0 * nominal + _HOME_MARGIN_S
        stall = self.stall.first_stall(t_s, bound, open_ended=True)
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
        accel = float(self.limits.accel_hz_per_s)
        back = move_profile(trip, p_trip, v_trip, p_trip, rate, accel)
        plan.trip_s = trip
        plan.segments = [*[s for s in run if s.t0_s < trip], *back]
        self.counter.rezero(trip, p_trip, level)
        self.stage.set_profile(trip, back)
        plan.checked_until_s = trip
        self._look_ahead(plan, trip)
