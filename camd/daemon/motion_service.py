"""The scan stage in the daemon: requests, the open-loop solution, and a scan's motion.

``MotionService`` is handed the device access and the sensor service. It drives the stage
through ``FpgaStage`` (the MOTOR_* commands), enforces the limits of config ``[stage]``
(programmed into the FPGA too), and answers ``camctl sync`` with
``camd.timing.synchronous_motion`` (docs/physics.md §2, §6). For a scan it gives the planner
the stage as it stands (``stage_context``) and a scan's motion
(``camd.daemon.scan_motion.ScanMotion``) a ``StageDrive`` (``scan_drive``,
``camd.daemon.stage_drive``): the stage's commands and nothing else of this service.
Enabling and homing program the configured limits first: if the command after them fails, the
limits in force before are put back (``camd.daemon.transaction.Apply``). A move or run whose
answer is lost (a lost link, a silent camera) may have started: the stage is then stopped and
put back where it stood, or at the speed it had.

A move or a homing answers at once unless asked to wait (``wait``, kept for old clients): the
service remembers the last one it started (``StageOperationModel`` in the motion document: its
target, the device's estimate of its duration, how far it got), so that a client follows it by
polling GET /api/v1/motion instead of holding a request open for as long as the stage runs.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Literal

from camd.daemon.config import MotionSection
from camd.daemon.device import DeviceAccess
from camd.daemon.errors import BadRequest
from camd.daemon.models import (
    MotionMoveRequest,
    MotionStatus,
    StageLimitsModel,
    StageOperationModel,
    StageReadingModel,
    SyncResponse,
)
from camd.daemon.scan_plan import StageContext
from camd.daemon.sensor_service import SensorService
from camd.daemon.stage_drive import (
    BRAKE_TIMEOUT_S,
    POSITION_TOLERANCE_M,
    WAIT_MARGIN_S,
    StageDrive,
    stage_errors,
    wait_stopped,
)
from camd.daemon.state import Request
from camd.daemon.transaction import Apply, apply_one
from camd.motion.stage import (
    MOVE_DURATION_MAX_S,
    STOPPED_STATES,
    FpgaStage,
    StageLimits,
    StageReading,
)
from camd.motion.stage_profile import StageProfile, load_stage_profile
from camd.protocol.dictionary import FieldValue
from camd.sensor.profile import list_profiles, load_profile
from camd.timing import synchronous_motion, turntable_angular_velocity_rad_s

log = logging.getLogger(__name__)

DEVICE_CLOCK_BACK_S = 1.0  # a reading this much older than a move's start is another device's

OperationKind = Literal["move", "home"]
_RUNNING_STATE: dict[OperationKind, str] = {"move": "moving", "home": "homing"}


@dataclass(slots=True)
class _Operation:
    """A move or homing started through the API (positions in m, device times in s)."""

    seq: int
    kind: OperationKind
    start_m: float
    target_m: float | None
    speed_m_s: float
    expected_duration_s: float
    started_time_s: float
    running_from_s: float  # device time of a reading taken after the command was answered
    finished: bool = False

    def report(self, reading: StageReading) -> StageOperationModel:
        """The operation as of ``reading``; latches ``finished`` once the stage has left the
        state the operation runs in (so that a later motion of the same kind cannot revive
        it). A reading taken before the command went through (a status request racing it)
        says nothing of it."""
        if reading.time_s < self.started_time_s - DEVICE_CLOCK_BACK_S:
            self.finished = True  # a new device: its clock started again
        elif reading.time_s >= self.running_from_s and reading.state != _RUNNING_STATE[self.kind]:
            self.finished = True  # stood, stopped or emergency-stopped
        elapsed = max(0.0, reading.time_s - self.started_time_s)
        expected = self.expected_duration_s
        by_time = min(1.0, elapsed / expected) if expected > 0 else 1.0
        if self.target_m is not None:  # a move: the distance covered
            whole = abs(self.target_m - self.start_m)
            covered = abs(reading.position_m - self.start_m)
            fraction = min(1.0, covered / whole) if whole > POSITION_TOLERANCE_M else 1.0
        elif self.finished:
            fraction = 1.0 if reading.homed else by_time
        else:
            fraction = min(by_time, 0.99)  # homing: the switch, not the clock, ends it
        return StageOperationModel(
            seq=self.seq,
            kind=self.kind,
            active=not self.finished,
            start_m=self.start_m,
            target_m=self.target_m,
            speed_m_s=self.speed_m_s,
            expected_duration_s=expected,
            started_time_s=self.started_time_s,
            elapsed_s=elapsed,
            remaining_s=0.0 if self.finished else max(0.0, expected - elapsed),
            fraction_done=fraction,
        )


class MotionService:
    """Stage requests and scan motion for one device session."""

    def __init__(self, device: DeviceAccess, sensor: SensorService) -> None:
        self.device = device
        self.sensor = sensor
        self._profile: StageProfile | None = None
        self._operation_lock = threading.Lock()
        self._operation: _Operation | None = None  # the last move or homing, for status
        self._operations = 0  # moves and homings started

    @property
    def config(self) -> MotionSection:
        """Config ``[motion]``: the closed loop and the M dV/V limits."""
        return self.device.config.motion

    def log_event(self, level: str, message: str) -> None:
        """An event from the motion side."""
        self.device.log_event(level, "motion", message)

    # -- the stage --------------------------------------------------------------------------------

    @property
    def profile(self) -> StageProfile:
        """The stage mechanics named by config ``stage.profile`` (loaded once)."""
        if self._profile is None:
            name = self.device.config.stage.profile
            try:
                self._profile = load_stage_profile(name)
            except (OSError, ValueError) as exc:
                raise BadRequest(f"stage.profile = {name!r}: {exc}") from None
        return self._profile

    @property
    def stage(self) -> FpgaStage:
        """The stage's device interface (MOTOR_* commands through the device access)."""
        return FpgaStage(self.profile, self._request)

    def _request(self, command: str, **fields: Any) -> Mapping[str, FieldValue]:
        return self.device.request(command, **fields).values

    def limits_wanted(self) -> StageLimits:
        """The limits config ``[stage]`` asks for, checked against the profile's maxima."""
        cfg, profile = self.device.config.stage, self.profile
        top_speed, top_accel = profile.max_speed_m_s.value, profile.max_accel_m_s2.value
        speed = cfg.max_speed_m_s or top_speed
        accel = cfg.max_accel_m_s2 or top_accel
        if speed > top_speed or accel > top_accel:
            raise BadRequest(
                f"stage.max_speed_m_s = {cfg.max_speed_m_s} / max_accel_m_s2 = "
                f"{cfg.max_accel_m_s2} exceed the {profile.name} stage's maxima "
                f"{top_speed} m/s and {top_accel} m/s^2; lower them"
            )
        low_end, high_end = travel_ends_m(profile)
        low = low_end if cfg.low_limit_m is None else cfg.low_limit_m
        high = high_end if cfg.high_limit_m is None else cfg.high_limit_m
        if low < low_end or high > high_end:
            raise BadRequest(
                f"stage soft limits [{low}, {high}] m leave the {profile.name} stage's travel "
                f"[{low_end}, {high_end}] m; set stage.low_limit_m / high_limit_m inside it"
            )
        return StageLimits(low_m=low, high_m=high, max_speed_m_s=speed, accel_m_s2=accel)

    # -- a scan's stage ----------------------------------------------------------------------------

    def stage_context(self, closed_loop: bool | None) -> StageContext:
        """The stage as it stands and what config allows it, for a scan's plan
        (``closed_loop``: the scan request's, None for config's)."""
        reading = self.read()
        _, scale = self.optics()
        return StageContext(
            kind=self.profile.kind,
            limits=self.limits_wanted(),
            position_m=reading.position_m,
            state=reading.state,
            loop_mode=self.loop_mode(closed_loop),
            image_scale=scale,
            encoder_counts_per_m=self.profile.encoder_counts_per_m,
        )

    def scan_drive(self) -> StageDrive:
        """The stage for a scan's motion: its commands, the motion events, and taking the stage
        from a move or homing started here (no longer followed once the scan programs its
        limits)."""
        return StageDrive(self.stage, events=self.log_event, on_take=self._forget_operation)

    def status(self) -> MotionStatus:
        self.device.require(Request.MOTION_READ)
        with stage_errors():
            reading = self.stage.read()
            limits = self.stage.limits()
        with self._operation_lock:
            operation = None if self._operation is None else self._operation.report(reading)
        return MotionStatus(
            profile=self.profile.name,
            kind=self.profile.kind,
            reading=StageReadingModel.model_validate(reading.as_dict()),
            limits=StageLimitsModel.model_validate(limits.as_dict()),
            closed_loop=self.loop_mode(None),
            yellow=self.config.yellow,
            red=self.config.red,
            operation=operation,
        )

    def _start_operation(
        self,
        kind: OperationKind,
        before: StageReading,
        target_m: float | None,
        speed_m_s: float,
        duration_s: float,
    ) -> None:
        """Remember the move or homing just started (``before``: the stage as it stood)."""
        after = self.read()
        with self._operation_lock:
            self._operations += 1
            self._operation = _Operation(
                seq=self._operations,
                kind=kind,
                start_m=before.position_m,
                target_m=target_m,
                speed_m_s=speed_m_s,
                expected_duration_s=max(0.0, duration_s),
                started_time_s=before.time_s,
                running_from_s=after.time_s,
            )

    def _forget_operation(self) -> None:
        """Another motion (a jog, a scan) takes the stage: no move or homing to follow."""
        with self._operation_lock:
            self._operation = None

    def enable(self, on: bool) -> MotionStatus:
        self.device.require(Request.MOTION_MOVE if on else Request.MOTION_STOP)
        with Apply("stage enable", self._events, source="motion") as apply:
            if on:
                self._program_limits_if_idle(apply)
            with stage_errors():
                self.stage.enable(on)
            apply.done()
        self.log_event("info", f"stage {'enabled' if on else 'released'}")
        return self.status()

    def _program_limits_if_idle(self, apply: Apply) -> None:
        """Program the limits unless the stage moves (the FPGA refuses then; they are set), as
        a step of ``apply`` whose undo programs the limits in force before."""
        stage = self.stage
        with stage_errors():
            state = stage.read().state
        if state not in STOPPED_STATES:
            return
        wanted = self.limits_wanted()
        with stage_errors():
            before = stage.limits()

        def program(limits: StageLimits) -> None:
            with stage_errors():
                stage.set_limits(limits)

        apply.step(lambda: program(wanted), lambda: program(before), "stage limits")

    def _events(self, level: str, source: str, message: str) -> None:
        self.device.log_event(level, source, message)

    def run(self, speed_m_s: float) -> MotionStatus:
        """Hold a constant signed speed (0 stops)."""
        self.device.require(Request.MOTION_MOVE)
        self.check_speed(speed_m_s)
        was = self._check_not_stopped_hard().speed_m_s
        self._forget_operation()
        stage = self.stage

        def run_at(speed: float) -> None:
            with stage_errors():
                stage.run(speed)

        apply_one(
            "stage run",
            self._events,
            lambda: run_at(speed_m_s),
            lambda: run_at(was),
            f"stage speed back at {was * 1e3:.6g} mm/s",
            source="motion",
        )
        return self.status()

    def _check_not_stopped_hard(self) -> StageReading:
        """Refuse motion in emergency stop or with the motor released, in camctl's words;
        returns the stage as it is."""
        with stage_errors():
            reading = self.stage.read()
        if reading.state == "estop":
            raise BadRequest(
                "the stage is in emergency stop; check it, then `camctl stage enable` clears it"
            )
        if reading.state == "disabled":
            raise BadRequest("the stage motor is released; `camctl stage enable` first")
        if reading.state == "homing":  # the device refuses (ILLEGAL_STATE): a 502 otherwise
            raise BadRequest(
                "the stage is homing; wait until it stands (`camctl stage` shows its state) "
                "or stop it with `camctl stage stop`"
            )
        return reading

    def _back_to(self, position_m: float) -> None:
        """Stop, and move back to ``position_m`` unless the stage stands there."""
        with stage_errors():
            self.stage.stop()
        reading = self.wait_stopped(BRAKE_TIMEOUT_S)
        if abs(reading.position_m - position_m) > POSITION_TOLERANCE_M:
            with stage_errors():
                duration = self.stage.move_to(position_m)
            self.wait_stopped(duration + WAIT_MARGIN_S)

    def move(self, request: MotionMoveRequest) -> MotionStatus:
        self.device.require(Request.MOTION_MOVE)
        limits = self.limits_wanted()
        if not limits.low_m <= request.position_m <= limits.high_m:
            raise BadRequest(
                f"position {request.position_m} m is outside the soft limits "
                f"[{limits.low_m}, {limits.high_m}] m; move within them or widen "
                "stage.low_limit_m / high_limit_m"
            )
        if request.speed_m_s is not None:
            self.check_speed(request.speed_m_s)
        before = self._check_not_stopped_hard()
        stood = before.position_m
        distance = abs(request.position_m - stood)
        if request.speed_m_s is not None and distance > request.speed_m_s * MOVE_DURATION_MAX_S:
            raise BadRequest(
                f"a move of {distance * 1e3:.4g} mm at {request.speed_m_s:.6g} m/s would take "
                f"{distance / request.speed_m_s:.6g} s, longer than the {MOVE_DURATION_MAX_S:g} "
                f"s a move may take; give at least {distance / MOVE_DURATION_MAX_S:.3g} m/s"
            )
        stage = self.stage

        def move() -> float:
            with stage_errors():
                return stage.move_to(request.position_m, request.speed_m_s)

        duration = apply_one(
            "stage move",
            self._events,
            move,
            lambda: self._back_to(stood),
            f"stage stopped and back at {stood * 1e3:.3f} mm",
            source="motion",
        )
        speed = limits.max_speed_m_s if request.speed_m_s is None else request.speed_m_s
        self._start_operation("move", before, request.position_m, speed, duration)
        if request.wait:
            self.wait_stopped(duration + WAIT_MARGIN_S)
        return self.status()

    def stop(self) -> MotionStatus:
        self.device.require(Request.MOTION_STOP)
        with stage_errors():
            self.stage.stop()
        return self.status()

    def home(self, wait: bool) -> MotionStatus:
        self.device.require(Request.MOTION_MOVE)
        before = self._check_not_stopped_hard()
        with Apply("stage homing", self._events, source="motion") as apply:
            self._program_limits_if_idle(apply)
            with stage_errors():
                duration = self.stage.home()
            apply.done()
        speed = min(self.profile.home_speed_m_s.value, self.limits_wanted().max_speed_m_s)
        self._start_operation("home", before, None, speed, duration)
        if wait:
            self.wait_stopped(duration + WAIT_MARGIN_S)
        self.log_event("info", "stage homing")
        return self.status()

    def emergency_stop(self) -> MotionStatus:
        """Stop without a ramp and cut the motor current, until enabled again. Never refused
        for control or a running acquisition (only a silent camera cannot be stopped)."""
        self.device.require(Request.MOTION_STOP)
        self.emergency_stop_now()
        return self.status()

    def emergency_stop_now(self) -> bool:
        """MOTOR_ESTOP at once, whatever the daemon's state (``POST /api/v1/estop``)."""
        with stage_errors():
            self.stage.emergency_stop()
        self.log_event("warning", "stage EMERGENCY STOP (enable to clear)")
        return True

    def read(self) -> StageReading:
        """The stage now (MOTOR_GET), without the state check of ``status``."""
        with stage_errors():
            return self.stage.read()

    def wait_stopped(self, timeout_s: float) -> StageReading:
        """Poll until the stage stands still; raise if it does not within ``timeout_s``."""
        return wait_stopped(self.stage, timeout_s)

    # -- synchronisation -------------------------------------------------------------------------

    def loop_mode(self, closed_loop: bool | None) -> str:
        """What a scan's closed loop trims ("step_rate", "line_period") or "off"."""
        motion = self.config
        wanted = motion.closed_loop != "off" if closed_loop is None else closed_loop
        if not wanted:
            return "off"  # (auto: every stage profile has an encoder, so on)
        return motion.correct

    def camera_optics(self, binned: bool = False) -> tuple[float, float]:
        """(pixel pitch on the focal plane, doubled when binned; the optics' magnification)
        from the camera's profile."""
        name = self.sensor.regmap.sensor
        if name not in list_profiles():
            raise BadRequest(
                f"sensor {name} has no camera profile in config/profiles/, so the pixel pitch "
                "and magnification that scan timing and synchronisation need are unknown; "
                "add one"
            )
        camera = load_profile(name)
        return camera.pitch_m.value * (2 if binned else 1), camera.magnification.value

    def optics(self, binned: bool = False) -> tuple[float, float]:
        """(pixel pitch on the focal plane, image scale of stage travel) for this camera."""
        pitch, magnification = self.camera_optics(binned)
        return pitch, self.profile.image_scale(magnification)

    def sync(
        self,
        *,
        line_period_s: float | None = None,
        speed_m_s: float | None = None,
        stages: int | None = None,
        binning: bool = False,
    ) -> SyncResponse:
        """The open-loop solution for a line period or a stage speed (or the line period in the
        registers): docs/physics.md §2 eqs 5-9, 13 and §6 eq 9."""
        self.device.require(Request.REGISTERS_READ)
        pitch, scale = self.optics(binning)
        timing = self.sensor.timing()
        period = line_period_s
        if period is None and speed_m_s is None:
            period = timing.tdi_line_period_s
        try:
            solution = synchronous_motion(
                row_time_s=timing.line_period_s,
                pixel_pitch_m=pitch,
                image_scale=scale,
                metres_per_microstep=self.profile.metres_per_microstep,
                line_period_s=period,
                stage_speed_m_s=speed_m_s,
                stages=stages,
            )
        except ValueError as exc:
            raise BadRequest(str(exc)) from None
        speed = solution.sync_speed if speed_m_s is None else abs(speed_m_s)
        if speed > self.limits_wanted().max_speed_m_s:
            self.log_event(
                "warning",
                f"synchronous speed {speed * 1e3:.6g} mm/s is above the stage's limit",
            )
        angular = None
        if self.profile.kind == "turntable":
            assert self.profile.radius_m is not None  # validated for a turntable
            angular = turntable_angular_velocity_rad_s(
                pitch, solution.line_period_s, self.profile.radius_m.value
            )
        return SyncResponse(
            **solution.as_dict(),
            image_speed_m_s=solution.sync_speed * scale,
            stage_speed_m_s=speed,
            stage_profile=self.profile.name,
            image_scale=scale,
            pixel_pitch_m=pitch,
            angular_velocity_rad_s=angular,
            tolerance_ok=abs(solution.m_dv_over_v) < self.config.yellow,
        )

    # -- helpers ----------------------------------------------------------------------------------

    def check_speed(self, speed_m_s: float) -> None:
        """Refuse a speed above config ``[stage]``'s limit (400, with the numbers)."""
        limit = self.limits_wanted().max_speed_m_s
        if abs(speed_m_s) > limit:
            raise BadRequest(
                f"stage speed {abs(speed_m_s) * 1e3:.6g} mm/s is above the limit "
                f"{limit * 1e3:.6g} mm/s (stage.max_speed_m_s, {self.profile.name} profile); "
                "go slower (for a scan: a longer line period or a smaller magnification)"
            )


def travel_ends_m(profile: StageProfile) -> tuple[float, float]:
    """The stage's travel in metres from home: [0, travel] on a rail; a turntable turns
    without end (its soft limits are the step counter's range)."""
    if profile.travel_m is not None:
        return 0.0, profile.travel_m.value
    span = (2**31 - 1) * profile.metres_per_microstep
    return -span, span
