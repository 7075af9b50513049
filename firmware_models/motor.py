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

The parts: the motion profiles (``firmware_models.motor_profiles``, pure), the motion in
progress with its predicted stops and events (``motor_plan``), the following-error check
(``motor_stall``), the step counter and encoder (``motor_counter``) and the limits
(``motor_limits``); ``MotorController`` checks and answers the commands on them.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from typing import Any, Literal, Unpack

import numpy as np

from camd.motion.stage_profile import StageProfile
from firmware_models.errors import Nak
from firmware_models.motor_counter import I32_MAX, I32_MIN, StepCounter, i32
from firmware_models.motor_limits import MotorLimits
from firmware_models.motor_plan import LOOKAHEAD_S, Event, MotionPlan, MotionPlanner, StopReason
from firmware_models.motor_profiles import move_profile, ramp_profile, rebase, trapezoid_time_s
from firmware_models.motor_stall import StallCheck
from firmware_models.stage import (
    Segment,
    StageFaults,
    StageOptions,
    StepperStage,
    power_on_position_m,
)

__all__ = [
    "ENCODER_RATE_WINDOW_S",
    "I32_MAX",
    "I32_MIN",
    "LOOKAHEAD_S",
    "Event",
    "MotorController",
    "MotorState",
    "StopReason",
    "move_profile",
    "ramp_profile",
    "rebase",
    "trapezoid_time_s",
]

MotorState = Literal["disabled", "idle", "ramping", "running", "moving", "homing", "estop"]

ENCODER_RATE_WINDOW_S = 0.01  # MOTOR_GET encoder_rate_hz: counts per second over 10 ms


class MotorController:
    """The FPGA's stepper controller for one stage (see the module docstring): the MOTOR_*
    commands' checks and answers, on the motion planner, the counters and the limits. The
    keyword arguments are the stage's (``StageOptions``); it starts at its power-on position."""

    def __init__(self, profile: StageProfile, **stage: Unpack[StageOptions]) -> None:
        self.profile = profile
        self._d = profile.metres_per_microstep
        p0 = round(power_on_position_m(profile) * profile.microsteps_per_m)
        self.stage = StepperStage(profile, position_m=p0 * self._d, **stage)
        t0_s = self.stage.t0_s
        self.limits = MotorLimits(profile)
        self.counter = StepCounter(self.stage, t0_s)
        self.stall = StallCheck(profile, self.stage)
        self.planner = MotionPlanner(self.stage, self.counter, self.stall, self.limits, t0_s)
        self._driver: Literal["disabled", "enabled", "estop"] = "disabled"
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
        return self.counter.steps(t_s)

    def encoder_count(self, t_s: float) -> int:
        """The encoder count at ``t_s`` (what the FPGA latches into a frame header)."""
        return self.counter.encoder_count(t_s)

    def encoder_counts(self, times_s: Sequence[float]) -> list[int]:
        """``encoder_count`` at each of ``times_s``, in one look-up of the stage."""
        return self.counter.encoder_counts(times_s)

    @property
    def revision(self) -> int:
        """Changes whenever a command changed what the stage does or where the encoder counts
        from: encoder counts looked up at one revision stay true until it changes."""
        return self.counter.revision

    @property
    def stall_check_s(self) -> float:
        """The following-error check's window, on the stage's grid."""
        return self.stall.stall_check_s

    def homed(self, t_s: float) -> bool:
        return self.counter.homed(t_s)

    def state(self, t_s: float) -> MotorState:
        """The MOTOR_GET state at ``t_s`` (after ``advance``)."""
        if self._driver == "disabled":
            return "disabled"
        if self._driver == "estop":
            return "estop"
        return self.planner.motion_state(t_s)

    # -- events -------------------------------------------------------------------------------------

    def advance(self, t_s: float) -> float:
        """Bring the state machine to ``t_s`` (stops that happened by then become events);
        return ``t_s``, or the latest time seen if ``t_s`` is earlier (time never runs back)."""
        return self.planner.advance(t_s)

    def poll_events(self, t_s: float) -> list[Event]:
        """The MOTOR_STOPPED events that happened by ``t_s``, each returned once, in order."""
        return self.planner.poll_events(t_s)

    def next_event_s(self) -> float | None:
        """When ``poll_events`` next has something (or must look further ahead); None: never
        without a command."""
        return self.planner.next_event_s()

    # -- commands -----------------------------------------------------------------------------------

    def motor_enable(self, t_s: float, *, enable: str | bool) -> dict[str, Any]:
        """MOTOR_ENABLE: ``enable`` ``on`` / ``off`` (or a bool)."""
        with self.stage.lock:
            t_s = self.advance(t_s)
            on = enable if isinstance(enable, bool) else str(enable) == "on"
            if on:
                self._driver = "enabled"
            elif self.planner.moving(t_s):
                raise Nak(
                    "ILLEGAL_STATE",
                    f"MOTOR_ENABLE off refused: the stage is {self.state(t_s)} at "
                    f"{self._rate(t_s):.6g} microsteps/s; send MOTOR_STOP, wait for "
                    "MOTOR_STOPPED, then release the driver",
                )
            elif self._driver != "estop":
                self._driver = "disabled"
            return {"steps": i32(self.steps(t_s)), "encoder": i32(self.encoder_count(t_s))}

    def motor_set_rate(self, t_s: float, *, rate_hz: float) -> dict[str, Any]:
        """MOTOR_SET_RATE: jog at ``rate_hz`` (signed microsteps/s), re-ramping from now."""
        with self.stage.lock:
            t_s = self.advance(t_s)
            self._require_driver("MOTOR_SET_RATE", t_s)
            self._refuse_while_homing("MOTOR_SET_RATE", t_s)
            limits = self.limits
            rate = float(rate_hz)
            limits.check_jog_rate(rate)
            p, v = self.stage.commanded_at(t_s)
            accel = float(limits.accel_hz_per_s)
            if rate == 0.0:
                if self.planner.plan is None and v == 0.0:
                    return {"ramp_s": 0.0, "steps": i32(self.steps(t_s))}
                self.planner.brake(t_s, p, v, accel)
                return {"ramp_s": abs(v) / accel, "steps": i32(self.steps(t_s))}
            offset = self.counter.epoch_at(t_s).offset
            limit, reason = limits.jog_limit(rate, p - offset, at_rest=v == 0.0)
            segments = move_profile(t_s, p, v, limit + offset, abs(rate), accel)
            self.planner.start(t_s, MotionPlan("jog", segments, segments[-1].t0_s, reason))
            return {"ramp_s": abs(rate - v) / accel, "steps": i32(self.steps(t_s))}

    def motor_move(self, t_s: float, *, target_steps: int, rate_hz: float) -> dict[str, Any]:
        """MOTOR_MOVE: trapezoidal move to ``target_steps`` cruising at ``rate_hz`` (0: max)."""
        with self.stage.lock:
            t_s = self.advance(t_s)
            self._require_driver("MOTOR_MOVE", t_s)
            self._refuse_while_homing("MOTOR_MOVE", t_s)
            limits = self.limits
            target = int(target_steps)
            rate = limits.move_rate(target, rate_hz)
            p, v = self.stage.commanded_at(t_s)
            offset = self.counter.epoch_at(t_s).offset
            accel = float(limits.accel_hz_per_s)
            segments = move_profile(t_s, p, v, target + offset, rate, accel)
            self.planner.start(t_s, MotionPlan("move", segments, segments[-1].t0_s, "done"))
            return {"duration_s": segments[-1].t0_s - t_s}

    def motor_stop(self, t_s: float) -> dict[str, Any]:
        """MOTOR_STOP: brake to rest at the programmed acceleration (harmless at rest)."""
        with self.stage.lock:
            t_s = self.advance(t_s)
            p, v = self.stage.commanded_at(t_s)
            if self.planner.plan is None:
                return {"steps": i32(self.steps(t_s)), "stop_s": 0.0}
            accel = float(self.limits.accel_hz_per_s)
            self.planner.brake(t_s, p, v, accel)
            return {"steps": i32(self.steps(t_s)), "stop_s": abs(v) / accel}

    def motor_home(self, t_s: float) -> dict[str, Any]:
        """MOTOR_HOME: find the home switch, return to it, zero steps and encoder there."""
        with self.stage.lock:
            t_s = self.advance(t_s)
            self._require_driver("MOTOR_HOME", t_s)
            if self.planner.moving(t_s):
                raise Nak(
                    "ILLEGAL_STATE",
                    f"MOTOR_HOME refused: the stage is {self.state(t_s)}; send MOTOR_STOP and "
                    "wait for MOTOR_STOPPED first",
                )
            x = float(self.stage.peek_position_m(np.array([t_s]))[0])
            circumference = self.profile.circumference_m
            level = 0.0 if circumference is None else circumference * math.floor(x / circumference)
            rate = min(self.profile.home_rate_hz, self.limits.max_rate_hz)
            end = self.planner.home(t_s, level, rate).end_s
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
                if steps <= self.limits.low_steps:
                    at_limit = "low"
                elif steps >= self.limits.high_steps:
                    at_limit = "high"
            now_counts, encoder_rate = self.counter.encoder_and_rate(t_s, ENCODER_RATE_WINDOW_S)
            return {
                "state": state,
                "homed": "yes" if self.homed(t_s) else "no",
                "steps": i32(steps),
                "encoder": i32(now_counts),
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
            if self.planner.moving(t_s):
                raise Nak(
                    "ILLEGAL_STATE",
                    f"MOTOR_SET_LIMITS refused: the stage is {self.state(t_s)}; send MOTOR_STOP "
                    "and wait for MOTOR_STOPPED first",
                )
            self.limits.program(
                int(low_steps),
                int(high_steps),
                float(max_rate_hz),
                float(accel_hz_per_s),
                lambda: self.steps(t_s),
            )
            return {}

    def motor_get_limits(self, t_s: float) -> dict[str, Any]:
        """MOTOR_GET_LIMITS: the limits in force."""
        with self.stage.lock:
            self.advance(t_s)
            return self.limits.as_dict()

    def motor_estop(self, t_s: float) -> dict[str, Any]:
        """MOTOR_ESTOP: pulses stop at once, driver off, state estop until ENABLE on."""
        with self.stage.lock:
            t_s = self.advance(t_s)
            moving = self.planner.moving(t_s)
            p, _ = self.stage.commanded_at(t_s)
            self.planner.replace(t_s)
            self.stage.set_profile(t_s, [Segment(t_s, p, 0.0, 0.0)])
            self._driver = "estop"
            if moving:
                self.planner.commit(t_s, "estop")
            return {"steps": i32(self.steps(t_s)), "encoder": i32(self.encoder_count(t_s))}

    def set_faults(self, t_s: float, faults: StageFaults | None = None, **values: float) -> None:
        """Change the stage's imperfections from ``t_s`` (a whole ``StageFaults``, or some of
        ``error``, ``ripple``, ``jitter``, ``drift``, ``load``); a motion in progress is
        re-predicted (a stall may now come, or not)."""
        with self.stage.lock:
            t_s = self.advance(t_s)
            new = faults if faults is not None else self.stage.faults.updated(**values)
            self.stage.set_faults(t_s, new)
            self.planner.predict_again(t_s)

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

    # -- checks -------------------------------------------------------------------------------------

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
        if self.planner.homing:
            raise Nak(
                "ILLEGAL_STATE",
                f"{name} refused while homing; wait for MOTOR_STOPPED (homed) or send MOTOR_STOP",
            )

    def _rate(self, t_s: float) -> float:
        return self.stage.commanded_at(t_s)[1]
