"""The scan stage in the daemon: requests, the open-loop solution, and a scan's motion.

``MotionService`` belongs to a DeviceSession. It drives the stage through ``FpgaStage`` (the
MOTOR_* commands), enforces the limits of config ``[stage]`` (programmed into the FPGA too),
answers ``camctl sync`` with ``camd.timing.synchronous_motion`` (physics.md §2, §6), and gives a
scan its ``ScanMotion``: travel check (and rewind), ramp to speed, the closed loop
(``camd.motion.closed_loop``) on its own thread, and the stop at the end.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from camd.daemon.models import (
    MotionMoveRequest,
    MotionStatus,
    SimStageFaultsRequest,
    SimStageTruth,
    StageLimitsModel,
    StageReadingModel,
    SyncResponse,
)
from camd.daemon.state import Request
from camd.motion.closed_loop import (
    EncoderSample,
    LinePeriodSetting,
    LinePeriodTrim,
    SpeedEstimator,
    SpeedTrim,
)
from camd.motion.stage import FpgaStage, StageLimitError, StageLimits, StageReading
from camd.motion.stage_profile import StageProfile, load_stage_profile
from camd.protocol.dictionary import FieldValue
from camd.timing import synchronous_motion, turntable_angular_velocity_rad_s

if TYPE_CHECKING:
    from camd.daemon.session import DeviceSession

log = logging.getLogger(__name__)

STOPPED_STATES = frozenset({"idle", "disabled", "estop"})
WAIT_MARGIN_S = 2.0  # beyond the device's own estimate, before a wait gives up
TRAVEL_MARGIN = 1.05  # a scan asks for 5 % more travel than it needs
BRAKE_TIMEOUT_S = 10.0  # longest wait for a moving stage to stop before a scan
SLOW_STREAM_FACTOR = 2.0  # travel planned for a stream this much slower than its frames


class MotionService:
    """Stage requests and scan motion for one device session."""

    def __init__(self, session: DeviceSession) -> None:
        self.session = session
        self._profile: StageProfile | None = None

    # -- the stage --------------------------------------------------------------------------------

    @property
    def profile(self) -> StageProfile:
        """The stage mechanics named by config ``stage.profile`` (loaded once)."""
        from camd.daemon.session import BadRequest

        if self._profile is None:
            name = self.session.config.stage.profile
            try:
                self._profile = load_stage_profile(name)
            except (OSError, ValueError) as exc:
                raise BadRequest(f"stage.profile = {name!r}: {exc}") from None
        return self._profile

    @property
    def stage(self) -> FpgaStage:
        return FpgaStage(self.profile, self._request)

    def _request(self, command: str, **fields: Any) -> Mapping[str, FieldValue]:
        return self.session.request(command, **fields).values

    def limits_wanted(self) -> StageLimits:
        """The limits config ``[stage]`` asks for, checked against the profile's maxima."""
        from camd.daemon.session import BadRequest

        cfg, profile = self.session.config.stage, self.profile
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

    def program_limits(self) -> StageLimits:
        """Program the configured limits into the FPGA (before any motion)."""
        limits = self.limits_wanted()
        with self._errors():
            self.stage.set_limits(limits)
        return limits

    def status(self) -> MotionStatus:
        self.session.require(Request.MOTION_READ)
        with self._errors():
            reading = self.stage.read()
            limits = self.stage.limits()
        return MotionStatus(
            profile=self.profile.name,
            kind=self.profile.kind,
            reading=StageReadingModel.model_validate(reading.as_dict()),
            limits=StageLimitsModel.model_validate(limits.as_dict()),
            closed_loop=self.loop_mode(None),
            yellow=self.session.config.motion.yellow,
            red=self.session.config.motion.red,
        )

    def enable(self, on: bool) -> MotionStatus:
        self.session.require(Request.MOTION_MOVE if on else Request.MOTION_STOP)
        if on:
            self.program_limits_if_idle()
        with self._errors():
            self.stage.enable(on)
        self.session.log_event("info", "motion", f"stage {'enabled' if on else 'released'}")
        return self.status()

    def program_limits_if_idle(self) -> None:
        """Program the limits unless the stage moves (the FPGA refuses then; they are set)."""
        with self._errors():
            state = self.stage.read().state
        if state in STOPPED_STATES:
            self.program_limits()

    def run(self, speed_m_s: float) -> MotionStatus:
        """Hold a constant signed speed (0 stops)."""
        self.session.require(Request.MOTION_MOVE)
        self._check_speed(speed_m_s)
        self._check_not_stopped_hard()
        with self._errors():
            self.stage.run(speed_m_s)
        return self.status()

    def _check_not_stopped_hard(self) -> None:
        """Refuse motion in emergency stop or with the motor released, in camctl's words."""
        with self._errors():
            state = self.stage.read().state
        if state == "estop":
            raise self._bad(
                "the stage is in emergency stop; check it, then `camctl stage enable` clears it"
            )
        if state == "disabled":
            raise self._bad("the stage motor is released; `camctl stage enable` first")

    def move(self, request: MotionMoveRequest) -> MotionStatus:
        self.session.require(Request.MOTION_MOVE)
        limits = self.limits_wanted()
        if not limits.low_m <= request.position_m <= limits.high_m:
            raise self._bad(
                f"position {request.position_m} m is outside the soft limits "
                f"[{limits.low_m}, {limits.high_m}] m; move within them or widen "
                "stage.low_limit_m / high_limit_m"
            )
        if request.speed_m_s is not None:
            self._check_speed(request.speed_m_s)
        self._check_not_stopped_hard()
        with self._errors():
            duration = self.stage.move_to(request.position_m, request.speed_m_s)
        if request.wait:
            self.wait_stopped(duration + WAIT_MARGIN_S)
        return self.status()

    def stop(self) -> MotionStatus:
        self.session.require(Request.MOTION_STOP)
        with self._errors():
            self.stage.stop()
        return self.status()

    def home(self, wait: bool) -> MotionStatus:
        self.session.require(Request.MOTION_MOVE)
        self._check_not_stopped_hard()
        self.program_limits_if_idle()
        with self._errors():
            duration = self.stage.home()
        if wait:
            self.wait_stopped(duration + WAIT_MARGIN_S)
        self.session.log_event("info", "motion", "stage homing")
        return self.status()

    def emergency_stop(self) -> MotionStatus:
        self.session.require(Request.MOTION_STOP)
        with self._errors():
            self.stage.emergency_stop()
        self.session.log_event("warning", "motion", "stage EMERGENCY STOP (enable to clear)")
        return self.status()

    def wait_stopped(self, timeout_s: float) -> StageReading:
        """Poll until the stage stands still; raise if it does not within ``timeout_s``."""
        deadline = time.monotonic() + timeout_s
        while True:
            with self._errors():
                reading = self.stage.read()
            if reading.state in STOPPED_STATES:
                return reading
            if time.monotonic() > deadline:
                raise self._bad(
                    f"the stage is still {reading.state} after {timeout_s:.3g} s; "
                    "`camctl stage stop` (or estop) and check it"
                )
            time.sleep(0.02)

    def check_scan(self, speed_m_s: float, duration_s: float) -> None:
        """Refuse a scan the stage cannot make (speed or travel), before anything is written."""
        self._check_speed(speed_m_s)
        limits = self.limits_wanted()
        if self.profile.kind != "linear":
            return
        needed = ScanMotion.travel_needed_m(speed_m_s, duration_s, limits)
        span = limits.high_m - limits.low_m
        if needed > span:
            raise self._bad(
                f"the scan needs {needed * 1e3:.1f} mm of travel at {abs(speed_m_s) * 1e3:.4g} "
                f"mm/s but the soft limits leave {span * 1e3:.1f} mm; scan fewer lines, or "
                "slower (a longer line period), or widen stage.low_limit_m / high_limit_m"
            )

    # -- the simulated stage ----------------------------------------------------------------------

    def set_sim_faults(self, request: SimStageFaultsRequest) -> None:
        self.session.require(Request.SIM)
        self.session.request("SIM_SET_STAGE_FAULTS", **request.model_dump())
        self.session.log_event("info", "api", f"simulated stage faults: {request.model_dump()}")

    def sim_truth(self) -> SimStageTruth:
        self.session.require(Request.SIM)
        return SimStageTruth.model_validate(self.session.request("SIM_GET_STAGE").values)

    # -- synchronisation -------------------------------------------------------------------------

    def loop_mode(self, closed_loop: bool | None) -> str:
        """What a scan's closed loop trims ("step_rate", "line_period") or "off"."""
        motion = self.session.config.motion
        wanted = motion.closed_loop != "off" if closed_loop is None else closed_loop
        if not wanted:
            return "off"  # (auto: every stage profile has an encoder, so on)
        return motion.correct

    def camera_optics(self, binned: bool = False) -> tuple[float, float]:
        """(pixel pitch on the focal plane, doubled when binned; the optics' magnification)
        from the camera's profile."""
        from camd.daemon.session import BadRequest
        from camd.sensor.profile import list_profiles, load_profile

        name = self.session.sensor.regmap.sensor
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
        registers): physics.md §2 eqs 5-9, 13 and §6 eq 9."""
        self.session.require(Request.REGISTERS_READ)
        pitch, scale = self.optics(binning)
        timing = self.session.sensor.timing()
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
            raise self._bad(str(exc)) from None
        speed = solution.sync_speed if speed_m_s is None else abs(speed_m_s)
        if speed > self.limits_wanted().max_speed_m_s:
            self.session.log_event(
                "warning",
                "motion",
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
            tolerance_ok=abs(solution.m_dv_over_v) < self.session.config.motion.yellow,
        )

    # -- helpers ----------------------------------------------------------------------------------

    def _check_speed(self, speed_m_s: float) -> None:
        limit = self.limits_wanted().max_speed_m_s
        if abs(speed_m_s) > limit:
            raise self._bad(
                f"stage speed {abs(speed_m_s) * 1e3:.6g} mm/s is above the limit "
                f"{limit * 1e3:.6g} mm/s (stage.max_speed_m_s, {self.profile.name} profile); "
                "go slower (for a scan: a longer line period or a smaller magnification)"
            )

    @staticmethod
    def _bad(message: str) -> Exception:
        from camd.daemon.session import BadRequest

        return BadRequest(message)

    def _errors(self) -> _StageErrors:
        return _StageErrors()


def travel_ends_m(profile: StageProfile) -> tuple[float, float]:
    """The stage's travel in metres from home: [0, travel] on a rail; a turntable turns
    without end (its soft limits are the step counter's range)."""
    if profile.travel_m is not None:
        return 0.0, profile.travel_m.value
    span = (2**31 - 1) * profile.metres_per_microstep
    return -span, span


class _StageErrors:
    """Context manager: a StageLimitError becomes a BadRequest (400 with the message)."""

    def __enter__(self) -> None:
        return None

    def __exit__(self, kind: object, exc: BaseException | None, tb: object) -> None:
        if isinstance(exc, StageLimitError):
            from camd.daemon.session import BadRequest

            raise BadRequest(str(exc)) from None


# -- a scan's motion ----------------------------------------------------------------------------


@dataclass
class LoopRecord:
    """What the closed loop saw and did, one row per poll (written to the scan's file)."""

    time_s: list[float] = field(default_factory=list)
    encoder_m: list[float] = field(default_factory=list)
    measured_m_s: list[float] = field(default_factory=list)
    command_m_s: list[float] = field(default_factory=list)
    line_period_s: list[float] = field(default_factory=list)

    def arrays(self) -> dict[str, np.ndarray]:
        return {k: np.asarray(v, dtype=np.float64) for k, v in self.__dict__.items()}


class ScanMotion:
    """The stage's part of one scan: to speed before the first frame, corrected while it runs,
    stopped after the last (``start``, ``finish``). ``speed_m_s`` is signed (the scan
    direction) and includes any deliberate mismatch ``offset`` (dV/V): the step-rate loop
    holds that speed, the line-period loop keeps the line period ``offset`` off the measured
    speed's; ``mode`` is "off", "step_rate" or "line_period"."""

    def __init__(
        self,
        service: MotionService,
        *,
        speed_m_s: float,
        mode: str,
        pixel_pitch_m: float,
        row_time_s: float,
        stages: int,
        max_lines: int | None = None,
        offset: float = 0.0,
        apply_line_period: Callable[[LinePeriodSetting], None] | None = None,
    ) -> None:
        self.service = service
        self.speed_m_s = speed_m_s
        self.mode = mode
        self.offset = offset
        self.record = LoopRecord()
        self._pitch_m = pixel_pitch_m
        self._row_time_s = row_time_s
        self._stages = stages
        self._max_lines = max_lines
        self._apply_line_period = apply_line_period
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.error: str | None = None
        self.limited = False

    def start(self, duration_s: float) -> None:
        """Make room for ``duration_s`` of travel, enable, ramp to speed, settle, start the
        loop. Raises BadRequest (stage untouched) when the travel or speed cannot be had."""
        service = self.service
        config = service.session.config.motion
        service._check_speed(self.speed_m_s)
        stage = service.stage
        with service._errors():
            reading = stage.read()
        if reading.state == "estop":
            raise service._bad("the stage is in emergency stop; `camctl stage enable` first")
        if reading.state not in STOPPED_STATES:
            # Still braking after the last scan (or moved by hand): the FPGA takes new limits
            # only from a standing stage.
            with service._errors():
                stage.stop()
            reading = service.wait_stopped(BRAKE_TIMEOUT_S)
        limits = service.program_limits()
        self._make_room(limits, reading, duration_s)
        with service._errors():
            stage.enable(True)
            ramp_s = stage.run(self.speed_m_s)
        time.sleep(ramp_s + config.settle_s)
        if self.mode != "off":
            self._thread = threading.Thread(target=self._loop, name="camd-motion-loop", daemon=True)
            self._thread.start()

    @staticmethod
    def travel_needed_m(speed_m_s: float, duration_s: float, limits: StageLimits) -> float:
        """Travel a scan of ``duration_s`` at ``speed_m_s`` needs, ramps and margin included."""
        speed = abs(speed_m_s)
        ramp_m = speed**2 / (2 * limits.accel_m_s2)
        return TRAVEL_MARGIN * (speed * duration_s + 2 * ramp_m)

    def _make_room(self, limits: StageLimits, reading: StageReading, duration_s: float) -> None:
        """Rewind a linear stage to the start of its travel when the scan does not fit ahead."""
        service = self.service
        if service.profile.kind != "linear":
            return
        speed = abs(self.speed_m_s)
        needed = self.travel_needed_m(speed, duration_s, limits)
        # The stage runs in wall time until the last frame is in; a stream that runs slow (a
        # busy host, or a simulator rendering slower than the line rate) takes longer than its
        # frames' duration. Rewind unless there is room for twice that.
        comfortable = self.travel_needed_m(speed, SLOW_STREAM_FACTOR * duration_s, limits)
        forward = self.speed_m_s > 0
        here = reading.position_m
        ahead = limits.high_m - here if forward else here - limits.low_m
        if comfortable <= ahead:
            return
        span = limits.high_m - limits.low_m
        if needed > span:
            raise service._bad(
                f"the scan needs {needed * 1e3:.1f} mm of travel at {speed * 1e3:.4g} mm/s "
                f"but the soft limits leave {span * 1e3:.1f} mm; scan fewer lines, or slower "
                "(a longer line period), or widen stage.low_limit_m / high_limit_m"
            )
        start = limits.low_m if forward else limits.high_m
        service.session.log_event(
            "info",
            "motion",
            f"rewinding the stage to {start * 1e3:.1f} mm: {needed * 1e3:.1f} mm of travel "
            f"needed, {ahead * 1e3:.1f} mm ahead",
        )
        with service._errors():
            service.stage.enable(True)
            duration = service.stage.move_to(start)
        service.wait_stopped(duration + WAIT_MARGIN_S)

    def _loop(self) -> None:
        """Poll the encoder, trim the step rate or the line period (module docstring)."""
        config = self.service.session.config.motion
        stage = self.service.stage
        _, scale = self.service.optics()
        estimator = SpeedEstimator(
            config.speed_window_s,
            min_span_m=config.speed_window_counts / self.service.profile.encoder_counts_per_m,
        )
        # ``speed_m_s`` already carries a deliberate mismatch (``offset``): hold it.
        target = self.speed_m_s
        trim = SpeedTrim(target, gain=config.gain, max_trim=config.max_trim, predict=config.predict)
        period_trim = LinePeriodTrim(
            pixel_pitch_m=self._pitch_m,
            row_time_s=self._row_time_s,
            min_lines=self._stages,
            max_lines=self._max_lines,
            gain=config.gain,
            offset=self.offset,
        )
        command = self.speed_m_s  # in force since the last correction
        line_period = math.nan
        next_t = time.monotonic()
        try:
            while not self._stop.is_set():
                sent = time.monotonic()
                reading = stage.read()
                round_trip = time.monotonic() - sent
                if reading.at_limit != "none" and reading.state in STOPPED_STATES:
                    # The stage ran out of travel (the stream ran slower than planned): no
                    # correction can move it; the monitor flags the lines that follow.
                    self.error = (
                        f"the stage stopped at its {reading.at_limit} soft limit before the "
                        "scan ended; give it more travel (rewind, or widen the limits)"
                    )
                    self.service.session.log_event("warning", "motion", self.error)
                    return
                got = estimator.add(
                    EncoderSample(reading.time_s, reading.encoder_m, reading.position_m)
                )
                measured = math.nan
                if got is not None:
                    measured, commanded = got
                    if self.mode == "step_rate":
                        # The correction lands about a round trip after the reading and holds
                        # for one poll period: aim at the middle of that.
                        until = reading.time_s + round_trip + config.poll_period_s / 2
                        new = trim.update(
                            measured,
                            commanded,
                            at_s=estimator.centre_s,
                            until_s=until,
                            baseline_s=estimator.span_s,
                        )
                        if abs(new - command) > 1e-6 * abs(command):
                            stage.run(new)
                            command = new
                    elif self._apply_line_period is not None:
                        setting = period_trim.update(measured * scale)
                        self._apply_line_period(setting)
                        line_period = setting.line_period_s
                        self.limited = period_trim.limited
                rec = self.record
                rec.time_s.append(reading.time_s)
                rec.encoder_m.append(reading.encoder_m)
                rec.measured_m_s.append(measured)
                rec.command_m_s.append(reading.speed_m_s)
                rec.line_period_s.append(line_period)
                # On a clock, but a late poll (a slow link) moves the clock: no catch-up burst.
                next_t = max(next_t + config.poll_period_s, time.monotonic())
                self._stop.wait(max(0.0, next_t - time.monotonic()))
        except Exception as exc:  # the scan goes on open loop; say so
            self.error = f"closed loop stopped: {exc}"
            log.exception("closed loop")
            self.service.session.log_event(
                "warning", "motion", f"{self.error}; the scan continues open loop"
            )

    def finish(self) -> None:
        """Stop the loop, then decelerate the stage to a stop."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5.0)
        try:
            self.service.stage.stop()
        except Exception as exc:
            self.service.session.log_event(
                "warning", "motion", f"stopping the stage after the scan: {exc}"
            )
