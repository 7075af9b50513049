"""A scan's motion: the stage at speed before the first frame, corrected while it runs,
stopped after the last.

``ScanMotion`` carries out the stage part of a scan plan (``camd.daemon.scan_plan``: speed,
travel, rewind, limits, all checked before anything moved) through a ``StageDrive``
(``camd.daemon.stage_drive``) and nothing else: brake, limits, rewind, ramp to speed, the closed
loop (``camd.motion.closed_loop``, docs/motion.md) on its own thread, and the stop at the end.
Config ``[motion]`` tunes the settling and the loop.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from camd.daemon.config import MotionSection
from camd.daemon.errors import SessionError, unreachable
from camd.daemon.realtime import REALTIME
from camd.daemon.scan_plan import StagePlan
from camd.daemon.stage_drive import BRAKE_TIMEOUT_S, POSITION_TOLERANCE_M, StageDrive
from camd.motion.closed_loop import (
    EncoderSample,
    LinePeriodSetting,
    LinePeriodTrim,
    SpeedEstimator,
    SpeedTrim,
)
from camd.motion.stage import STOPPED_STATES, StageLimits

log = logging.getLogger(__name__)


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
    """The stage's part of one scan, as planned (``camd.daemon.scan_plan.StagePlan``): to
    speed before the first frame, corrected while it runs, stopped after the last (``start``,
    ``finish``; ``restore`` puts the stage back where it stood when a scan could not start).
    ``speed_m_s`` is signed (the scan direction) and includes any deliberate mismatch
    ``offset`` (dV/V): the step-rate loop holds that speed, the line-period loop keeps the line
    period ``offset`` off the measured speed's; ``mode`` is "off", "step_rate" or
    "line_period". ``settings`` is config ``[motion]``."""

    def __init__(
        self,
        drive: StageDrive,
        plan: StagePlan,
        settings: MotionSection,
        apply_line_period: Callable[[LinePeriodSetting], None] | None = None,
    ) -> None:
        self.drive = drive
        self.plan = plan
        self.settings = settings
        self.speed_m_s = plan.speed_m_s
        self.mode = plan.loop_mode
        self.offset = plan.offset
        self.record = LoopRecord()
        self._apply_line_period = apply_line_period
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.error: str | None = None
        self.limited = False
        self._released = False  # the motor was released before the scan enabled it
        self._limits_before: StageLimits | None = None  # put back by ``restore``

    def start(self) -> None:
        """Brake if still moving, program the limits, rewind if the plan says so, enable,
        ramp to speed, settle, start the loop."""
        drive = self.drive
        plan = self.plan
        self._released = drive.read().state == "disabled"
        if plan.must_brake:
            # Still braking after the last scan (or moved by hand): the FPGA takes new limits
            # only from a standing stage.
            drive.brake(BRAKE_TIMEOUT_S)
        self._limits_before = drive.limits()
        drive.program_limits(plan.limits)
        if plan.rewind_to_m is not None:
            drive.log_event(
                "info",
                f"rewinding the stage to {plan.rewind_to_m * 1e3:.1f} mm: "
                f"{plan.travel_m * 1e3:.1f} mm of travel needed",
            )
            drive.go_to(plan.rewind_to_m)
        ramp_s = drive.run(self.speed_m_s)
        time.sleep(ramp_s + self.settings.settle_s)
        if self.mode != "off":
            self._thread = threading.Thread(target=self._loop, name="camd-motion-loop", daemon=True)
            self._thread.start()

    def restore(self, position_m: float) -> None:
        """A scan that could not start: stop, put the stage back at ``position_m``, and
        release the motor again if the scan had enabled it."""
        self.finish()
        drive = self.drive
        drive.wait_stopped(BRAKE_TIMEOUT_S)
        reading = drive.read()
        if abs(reading.position_m - position_m) > POSITION_TOLERANCE_M:
            drive.go_to(position_m)
        before = self._limits_before
        if before is not None and before != drive.limits():
            # The FPGA takes limits only from a standing stage: it stands now.
            drive.set_limits(before)
        if self._released:
            drive.release()

    def _loop(self) -> None:
        """Poll the encoder, trim the step rate or the line period (module docstring)."""
        REALTIME.enter("closed_loop")
        config = self.settings
        drive = self.drive
        scale = self.plan.image_scale
        estimator = SpeedEstimator(
            config.speed_window_s,
            min_span_m=config.speed_window_counts / self.plan.encoder_counts_per_m,
        )
        # ``speed_m_s`` already carries a deliberate mismatch (``offset``): hold it.
        target = self.speed_m_s
        trim = SpeedTrim(target, gain=config.gain, max_trim=config.max_trim, predict=config.predict)
        period_trim = LinePeriodTrim(
            pixel_pitch_m=self.plan.pixel_pitch_m,
            row_time_s=self.plan.row_time_s,
            min_lines=self.plan.stages,
            max_lines=self.plan.max_lines,
            gain=config.gain,
            offset=self.offset,
        )
        command = self.speed_m_s  # in force since the last correction
        line_period = math.nan
        next_t = time.monotonic()
        try:
            while not self._stop.is_set():
                sent = time.monotonic()
                reading = drive.read()
                round_trip = time.monotonic() - sent
                if reading.at_limit != "none" and reading.state in STOPPED_STATES:
                    # The stage ran out of travel (the stream ran slower than planned): no
                    # correction can move it; the monitor flags the lines that follow.
                    self.error = (
                        f"the stage stopped at its {reading.at_limit} soft limit before the "
                        "scan ended; give it more travel (rewind, or widen the limits)"
                    )
                    self.drive.log_event("warning", self.error)
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
                            drive.trim(new)
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
        except SessionError as exc:  # the camera went away (or is going): one line, no trace
            self.error = f"closed loop stopped: {unreachable(exc)}"
            self.drive.log_event("warning", f"{self.error}; the scan continues open loop")
        except Exception as exc:  # the scan goes on open loop; say so
            self.error = f"closed loop stopped: {exc}"
            log.exception("closed loop")
            self.drive.log_event("warning", f"{self.error}; the scan continues open loop")

    def finish(self) -> None:
        """Stop the loop, then decelerate the stage to a stop."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5.0)
        try:
            self.drive.stop()
        except SessionError as exc:
            self.drive.log_event("warning", f"stage not stopped after the scan: {unreachable(exc)}")
        except Exception as exc:
            self.drive.log_event("warning", f"stopping the stage after the scan: {exc}")
