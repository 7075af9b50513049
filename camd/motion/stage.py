"""The scan stage as the daemon drives it: a small abstract interface and its RS-422 device.

``ScanStage`` speaks SI (metres, m/s, m/s^2; for a turntable, metres of arc at the sensor's
radius, docs/physics.md §2 eq 5); ``FpgaStage`` implements it with the MOTOR_* commands of
config/protocol.toml, which speak the driver's units (microsteps, encoder counts, microsteps
per second), converting with the stage profile (``camd.motion.stage_profile``). The simulated
camera answers the same commands, so tests run the same code as the bench.
"""

from __future__ import annotations

import abc
import math
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass
from typing import Any

from camd.motion.stage_profile import StageProfile
from camd.protocol.dictionary import FieldValue

Request = Callable[..., Mapping[str, FieldValue]]
"""Send one command with its fields and return the response's fields (raises on a NAK)."""

I32_MAX = 2**31 - 1

STOPPED_STATES = frozenset({"idle", "disabled", "estop"})
"""MOTOR_GET states in which the stage stands still."""


RATE_STEP_HZ = 0.001
"""The resolution of the step rates MOTOR_MOVE and MOTOR_SET_RATE carry (config/protocol.toml:
``rate_hz``, scale 0.001)."""
MOVE_DURATION_MAX_S = 4294.967295
"""The longest move MOTOR_MOVE can answer the duration of (``duration_s``: u32 microseconds)."""


class StageLimitError(ValueError):
    """A motion the stage's limits forbid; the message says which limit and what to change."""


@dataclass(frozen=True, slots=True)
class StageReading:
    """The stage at one device time: positions in m, speeds in m/s."""

    state: str
    homed: bool
    position_m: float  # commanded (step count)
    encoder_m: float  # measured
    speed_m_s: float  # commanded, ramps included
    encoder_speed_m_s: float  # the encoder's, over the device's last 10 ms
    at_limit: str
    time_s: float

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass(frozen=True, slots=True)
class StageLimits:
    """Soft travel limits (m), the maximum speed (m/s) and the ramp acceleration (m/s^2)."""

    low_m: float
    high_m: float
    max_speed_m_s: float
    accel_m_s2: float

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


class ScanStage(abc.ABC):
    """A driven scan axis with an encoder (python-microscope style: one small interface per
    device kind; the simulated camera's stage answers through the same transport)."""

    profile: StageProfile

    @abc.abstractmethod
    def enable(self, on: bool = True) -> None:
        """Energise (or release) the motor; enabling clears an emergency stop."""

    @abc.abstractmethod
    def run(self, speed_m_s: float) -> float:
        """Ramp to a signed constant speed and hold it; the ramp's duration (s)."""

    @abc.abstractmethod
    def move_to(self, position_m: float, speed_m_s: float | None = None) -> float:
        """Move to an absolute position and stop; the move's duration (s)."""

    @abc.abstractmethod
    def stop(self) -> float:
        """Decelerate to a stop; the time until standstill (s)."""

    @abc.abstractmethod
    def home(self) -> float:
        """Find the home switch and zero the position there; the expected duration (s)."""

    @abc.abstractmethod
    def emergency_stop(self) -> None:
        """Stop at once, no ramp, and cut the motor current."""

    @abc.abstractmethod
    def read(self) -> StageReading:
        """State, positions and speeds, latched at one device time."""

    @abc.abstractmethod
    def limits(self) -> StageLimits:
        """The limits in force."""

    @abc.abstractmethod
    def set_limits(self, limits: StageLimits) -> None:
        """Program soft limits, maximum speed and acceleration."""


class FpgaStage(ScanStage):
    """The stage behind the camera FPGA's MOTOR_* commands (``request`` sends one)."""

    def __init__(self, profile: StageProfile, request: Request) -> None:
        self.profile = profile
        self._request = request
        self._steps_per_m = profile.microsteps_per_m
        self._counts_per_m = profile.encoder_counts_per_m

    # -- conversions (the edges: SI inside camd, driver units on the wire) ----------------------

    def _steps(self, position_m: float, what: str) -> int:
        steps = round(position_m * self._steps_per_m)
        if not math.isfinite(position_m) or abs(steps) > I32_MAX:
            raise StageLimitError(f"{what} {position_m!r} m is beyond the driver's step counter")
        return steps

    def _rate_hz(self, speed_m_s: float) -> float:
        return speed_m_s * self._steps_per_m

    # -- the interface ----------------------------------------------------------------------------

    def enable(self, on: bool = True) -> None:
        self._request("MOTOR_ENABLE", enable="on" if on else "off")

    def run(self, speed_m_s: float) -> float:
        self._check_speed(speed_m_s)
        answer = self._request("MOTOR_SET_RATE", rate_hz=self._rate_hz(speed_m_s))
        return float(answer["ramp_s"])

    def move_to(self, position_m: float, speed_m_s: float | None = None) -> float:
        if speed_m_s is not None:
            self._check_speed(speed_m_s)
            if speed_m_s <= 0.0:
                raise StageLimitError(f"move speed {speed_m_s} m/s must be > 0")
        rate = 0.0 if speed_m_s is None else self._rate_hz(speed_m_s)
        answer = self._request(
            "MOTOR_MOVE", target_steps=self._steps(position_m, "target"), rate_hz=rate
        )
        return float(answer["duration_s"])

    def stop(self) -> float:
        return float(self._request("MOTOR_STOP")["stop_s"])

    def home(self) -> float:
        return float(self._request("MOTOR_HOME")["duration_s"])

    def emergency_stop(self) -> None:
        self._request("MOTOR_ESTOP")

    def read(self) -> StageReading:
        r = self._request("MOTOR_GET")
        return StageReading(
            state=str(r["state"]),
            homed=r["homed"] == "yes",
            position_m=int(r["steps"]) / self._steps_per_m,
            encoder_m=int(r["encoder"]) / self._counts_per_m,
            speed_m_s=float(r["rate_hz"]) / self._steps_per_m,
            encoder_speed_m_s=float(r["encoder_rate_hz"]) / self._counts_per_m,
            at_limit=str(r["at_limit"]),
            time_s=float(r["time_s"]),
        )

    def limits(self) -> StageLimits:
        r = self._request("MOTOR_GET_LIMITS")
        return StageLimits(
            low_m=int(r["low_steps"]) / self._steps_per_m,
            high_m=int(r["high_steps"]) / self._steps_per_m,
            max_speed_m_s=float(r["max_rate_hz"]) / self._steps_per_m,
            accel_m_s2=float(r["accel_hz_per_s"]) / self._steps_per_m,
        )

    def set_limits(self, limits: StageLimits) -> None:
        self._request(
            "MOTOR_SET_LIMITS",
            low_steps=self._steps(limits.low_m, "low limit"),
            high_steps=self._steps(limits.high_m, "high limit"),
            # Rounded down: the driver's own maxima are the profile's, rounded down the same way.
            max_rate_hz=math.floor(self._rate_hz(limits.max_speed_m_s) * 1000 + 1e-6) / 1000,
            accel_hz_per_s=max(1, math.floor(self._rate_hz(limits.accel_m_s2) + 1e-9)),
        )

    def _check_speed(self, speed_m_s: float) -> None:
        top = self.profile.max_speed_m_s.value
        if not math.isfinite(speed_m_s) or abs(speed_m_s) > top:
            raise StageLimitError(
                f"stage speed {speed_m_s * 1e3:.6g} mm/s is above the {self.profile.name} "
                f"stage's maximum {top * 1e3:.6g} mm/s; scan slower (a longer line period)"
            )
        # The step rate goes to the driver in steps of RATE_STEP_HZ: a slower, non-zero speed
        # would be sent as rate 0, which MOTOR_MOVE takes for "the programmed maximum".
        slowest = RATE_STEP_HZ / self._steps_per_m
        if speed_m_s != 0.0 and abs(self._rate_hz(speed_m_s)) < RATE_STEP_HZ:
            raise StageLimitError(
                f"stage speed {speed_m_s:.6g} m/s is below the slowest the driver takes, "
                f"{slowest:.3g} m/s ({RATE_STEP_HZ:g} steps/s); give at least that, or 0 to stop"
            )
