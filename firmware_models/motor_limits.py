"""The stepper controller's limits: soft limits, maximum rate, ramp acceleration (MOTOR_SET_LIMITS).

The driver's own maxima (``hw_*``: the mechanical travel, the profile's top speed and
acceleration) are what a fresh device reports as its limits; MOTOR_SET_LIMITS programs limits
within them. Soft limits are in step-counter microsteps (a turntable's mechanical range is the
whole i32 range).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any, Literal

from camd.motion.stage_profile import StageProfile
from firmware_models.errors import Nak
from firmware_models.motor_counter import I32_MAX, I32_MIN


class MotorLimits:
    """The limits in force and the driver's maxima they must stay within."""

    def __init__(self, profile: StageProfile) -> None:
        self.profile = profile
        travel = profile.travel_microsteps
        self.hw_low_steps = 0 if travel is not None else I32_MIN
        self.hw_high_steps = travel if travel is not None else I32_MAX
        self.hw_max_rate_hz = math.floor(profile.max_rate_hz * 1000.0 + 1e-6) / 1000.0
        self.hw_accel_hz_per_s = max(1, math.floor(profile.max_accel_hz_per_s + 1e-9))
        self.low_steps = self.hw_low_steps
        self.high_steps = self.hw_high_steps
        self.max_rate_hz = self.hw_max_rate_hz
        self.accel_hz_per_s: int = self.hw_accel_hz_per_s

    def as_dict(self) -> dict[str, Any]:
        """MOTOR_GET_LIMITS's fields."""
        return {
            "low_steps": self.low_steps,
            "high_steps": self.high_steps,
            "max_rate_hz": self.max_rate_hz,
            "accel_hz_per_s": self.accel_hz_per_s,
        }

    def program(
        self, low: int, high: int, rate: float, accel: float, steps_now: Callable[[], int]
    ) -> None:
        """Program the limits (MOTOR_SET_LIMITS) with the stage at rest at ``steps_now()``
        microsteps; NAK OUT_OF_RANGE (nothing changed) for limits it cannot take."""
        d = self.profile.metres_per_microstep
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
                f"({rate * d:.6g} m/s) is above the driver's maximum "
                f"{self.hw_max_rate_hz:.6g} ({self.profile.max_speed_m_s.value:g} m/s); "
                "lower it",
            )
        if not 1.0 <= accel <= self.hw_accel_hz_per_s:
            raise Nak(
                "OUT_OF_RANGE",
                f"MOTOR_SET_LIMITS refused: accel_hz_per_s {accel:.6g} microsteps/s^2 "
                f"({accel * d:.6g} m/s^2) is outside 1 .. {self.hw_accel_hz_per_s} "
                f"({self.profile.max_accel_m_s2.value:g} m/s^2); choose a value within",
            )
        steps = steps_now()
        if not low <= steps <= high:
            raise Nak(
                "OUT_OF_RANGE",
                f"MOTOR_SET_LIMITS refused: the stage stands at {steps} microsteps, outside "
                f"[{low}, {high}]; move inside first or choose limits that contain it",
            )
        self.low_steps, self.high_steps = low, high
        self.max_rate_hz = rate
        self.accel_hz_per_s = int(accel)

    # -- a motion command against the limits ------------------------------------------------------

    def check_jog_rate(self, rate: float) -> None:
        """NAK OUT_OF_RANGE for a MOTOR_SET_RATE rate above the programmed maximum."""
        d = self.profile.metres_per_microstep
        if abs(rate) > self.max_rate_hz * (1.0 + 1e-12):
            raise Nak(
                "OUT_OF_RANGE",
                f"MOTOR_SET_RATE refused: {abs(rate):.6g} microsteps/s "
                f"({abs(rate) * d:.6g} m/s) is above the programmed maximum "
                f"{self.max_rate_hz:.6g} microsteps/s ({self.max_rate_hz * d:.6g} m/s); "
                "lower the rate, or raise the maximum with MOTOR_SET_LIMITS (driver maximum "
                f"{self.hw_max_rate_hz:.6g})",
            )

    def jog_limit(
        self, rate: float, steps_now: float, at_rest: bool
    ) -> tuple[int, Literal["limit_low", "limit_high"]]:
        """The soft limit a jog at ``rate`` runs to, and why it stops there; NAK OUT_OF_RANGE
        for a jog from rest at ``steps_now`` (microsteps, unrounded) into the limit it
        stands at."""
        reason: Literal["limit_low", "limit_high"]
        if rate > 0.0:
            limit, reason, side = self.high_steps, "limit_high", "high"
            blocked = steps_now >= limit - 0.5
        else:
            limit, reason, side = self.low_steps, "limit_low", "low"
            blocked = steps_now <= limit + 0.5
        if blocked and at_rest:
            other = "negative" if rate > 0 else "positive"
            raise Nak(
                "OUT_OF_RANGE",
                f"MOTOR_SET_RATE refused: the stage stands at the {side} soft limit "
                f"{limit} microsteps; jog the other way (a {other} rate) or widen the "
                "limits with MOTOR_SET_LIMITS",
            )
        return limit, reason

    def move_rate(self, target: int, rate_hz: float) -> float:
        """The cruising rate of a MOTOR_MOVE to ``target`` (``rate_hz`` 0: the maximum); NAK
        OUT_OF_RANGE for a target beyond the soft limits or a rate above the maximum."""
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
                f"({rate * self.profile.metres_per_microstep:.6g} m/s) is above the programmed "
                f"maximum {self.max_rate_hz:.6g} microsteps/s; give at most that (0 means the "
                "maximum) or raise it with MOTOR_SET_LIMITS",
            )
        return rate
