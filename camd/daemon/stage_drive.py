"""The scan stage as a scan drives it: brake, program limits, go to, run at a speed, stop.

``StageDrive`` is all a scan's motion (``camd.daemon.scan_motion.ScanMotion``) knows of the
stage. It wraps the stage's device interface (``camd.motion.stage.ScanStage``; on the camera
``FpgaStage`` and its MOTOR_* commands) with what a scan needs: stop and wait until it stands
(``brake``), program limits, go to a position and wait, enable and run at a speed and say how
long the ramp takes (``run``), correct the speed while running (``trim``), stop, release. The
motion service hands one out (``MotionService.scan_drive``), so that a scan's speed goes from
its plan through ``ScanMotion`` and ``StageDrive`` to the stage's MOTOR_SET_RATE, one way down.

A motion the stage's limits forbid (``StageLimitError``) is a ``BadRequest`` here, as in every
motion request (``stage_errors``), except for the closed loop's trims, which the loop reports
itself. The waits and tolerances the motion service uses for its own moves live here too.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable, Iterator

from camd.daemon.errors import BadRequest
from camd.motion.stage import (
    STOPPED_STATES,
    ScanStage,
    StageLimitError,
    StageLimits,
    StageReading,
)

WAIT_MARGIN_S = 2.0  # beyond the device's own estimate, before a wait gives up
BRAKE_TIMEOUT_S = 10.0  # longest a stage takes to decelerate to a stop
POSITION_TOLERANCE_M = 1e-6  # a stage this close to where it stood is back
POLL_S = 0.02  # between readings while waiting for the stage to stand

Events = Callable[[str, str], None]
"""``(level, message)``: an event from the motion side."""


@contextlib.contextmanager
def stage_errors() -> Iterator[None]:
    """A StageLimitError (a motion the stage's limits forbid) becomes a BadRequest."""
    try:
        yield
    except StageLimitError as exc:
        raise BadRequest(str(exc)) from None


def wait_stopped(stage: ScanStage, timeout_s: float) -> StageReading:
    """Poll until the stage stands still; raise if it does not within ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while True:
        with stage_errors():
            reading = stage.read()
        if reading.state in STOPPED_STATES:
            return reading
        if time.monotonic() > deadline:
            raise BadRequest(
                f"the stage is still {reading.state} after {timeout_s:.3g} s; "
                "`camctl stage stop` (or estop) and check it"
            )
        time.sleep(POLL_S)


class StageDrive:
    """The stage's commands a scan uses (module docstring). ``on_take`` is called when a scan
    takes the stage (it programs its limits): the motion service then stops reporting the move
    or homing it started; ``events`` logs what the drive does on its own (a rewind)."""

    def __init__(
        self,
        stage: ScanStage,
        *,
        events: Events,
        on_take: Callable[[], None] = lambda: None,
    ) -> None:
        self._stage = stage
        self._events = events
        self._on_take = on_take

    def log_event(self, level: str, message: str) -> None:
        """An event from the motion side."""
        self._events(level, message)

    def read(self) -> StageReading:
        """The stage now (MOTOR_GET)."""
        with stage_errors():
            return self._stage.read()

    def limits(self) -> StageLimits:
        """The limits in force (MOTOR_GET_LIMITS)."""
        with stage_errors():
            return self._stage.limits()

    def brake(self, timeout_s: float = BRAKE_TIMEOUT_S) -> StageReading:
        """Decelerate to a stop and wait until the stage stands (the FPGA takes limits only
        from a standing stage)."""
        with stage_errors():
            self._stage.stop()
        return self.wait_stopped(timeout_s)

    def wait_stopped(self, timeout_s: float = BRAKE_TIMEOUT_S) -> StageReading:
        """Wait until the stage stands (``wait_stopped``)."""
        return wait_stopped(self._stage, timeout_s)

    def program_limits(self, limits: StageLimits) -> None:
        """Take the stage for a scan and program ``limits`` (before it moves)."""
        self._on_take()
        self.set_limits(limits)

    def set_limits(self, limits: StageLimits) -> None:
        """Program ``limits`` (a standing stage's: the FPGA refuses them otherwise)."""
        with stage_errors():
            self._stage.set_limits(limits)

    def go_to(self, position_m: float) -> None:
        """Enable the motor, move to ``position_m`` and wait until the stage stands there."""
        with stage_errors():
            self._stage.enable(True)
            duration_s = self._stage.move_to(position_m)
        self.wait_stopped(duration_s + WAIT_MARGIN_S)

    def run(self, speed_m_s: float) -> float:
        """Enable the motor and run at ``speed_m_s`` (signed); returns how long the ramp to
        that speed takes, in s."""
        with stage_errors():
            self._stage.enable(True)
            return self._stage.run(speed_m_s)

    def trim(self, speed_m_s: float) -> None:
        """A new speed while running (the closed loop's correction). A speed the stage refuses
        raises its own error (``StageLimitError``): the loop reports it as it is."""
        self._stage.run(speed_m_s)

    def stop(self) -> None:
        """Decelerate to a stop (MOTOR_STOP), without waiting."""
        self._stage.stop()

    def release(self) -> None:
        """Cut the motor current (the motor as the operator left it)."""
        with stage_errors():
            self._stage.enable(False)
