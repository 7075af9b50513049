"""The emergency stop in the daemon: engage, release, the latch's state, and holding it.

``EstopService`` is handed the device access (the latch, ``camd.daemon.estop``; the event log),
the motion and wheel services (the stage and the filter wheel it stops), and the session's ways
to stop the running acquisition and to pause the running campaign job. It serves
``/api/v1/estop`` (docs/api.md, "Emergency stop"): never refused, latched first so that nothing
racing the stop starts again, then everything stopped, each whatever the others did. While the
latch holds, a camera that answers again (a connect, a reboot) has its stage and wheel stopped
again (``hold``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import KW_ONLY, asdict, dataclass

from camd.daemon.control import ANONYMOUS
from camd.daemon.device import DeviceAccess
from camd.daemon.errors import SessionError
from camd.daemon.estop import RELEASE_HINT
from camd.daemon.models import EstopResponse, EstopState
from camd.daemon.motion_service import MotionService
from camd.daemon.wheel_service import WheelService


@dataclass(eq=False)
class EstopService:
    """The emergency stop of one device session (module docstring)."""

    device: DeviceAccess
    motion: MotionService
    wheel: WheelService
    _: KW_ONLY
    stop_acquisition: Callable[[], bool]
    pause_job: Callable[[], bool]

    def engage(self, client: str = ANONYMOUS) -> EstopResponse:
        """Emergency stop, never refused, and latched (camd.daemon.estop): first the latch, so
        that nothing racing the stop can start motion or acquisition again; then the stage (no
        ramp, motor current cut), the running acquisition (its stream stopped; a scan's file is
        closed as stopped), the filter wheel and the campaign job (paused, its worker's control
        ended). Each is tried whatever the others did; what failed is said, not raised."""
        self.device.estop.engage(client)
        stopped: list[str] = []
        failed: list[str] = []
        for what, action in (
            ("stage", self.motion.emergency_stop_now),
            ("acquisition", self.stop_acquisition),
            ("wheel", self.wheel.stop_now),
            ("campaign job", self.pause_job),
        ):
            try:
                if action():
                    stopped.append(what)
            except Exception as exc:  # keep stopping the others
                failed.append(f"{what}: {exc}")
        self.device.estop.stopped(stopped, failed)
        level = "error" if failed else "warning"
        self.device.log_event(
            level,
            "api",
            f"EMERGENCY STOP by {client}: stopped {', '.join(stopped) or 'nothing'}"
            + (f"; could not stop {'; '.join(failed)}" if failed else "")
            + f"; latched: nothing moves or acquires until it is released ({RELEASE_HINT})",
        )
        return EstopResponse(stopped=stopped, failed=failed, latch=self.state())

    def state(self) -> EstopState:
        """The emergency-stop latch (no device traffic)."""
        return EstopState.model_validate(
            {**asdict(self.device.estop.record()), "how_to_release": RELEASE_HINT}
        )

    def release(self, client: str) -> EstopState:
        """Lift the latch (the caller has control); the stage stays disabled and the wheel
        stopped until someone starts them. Harmless when not latched."""
        if self.device.estop.release(client):
            self.device.log_event(
                "warning",
                "api",
                f"emergency stop released by {client}: motion and acquisition may start again; "
                "the stage stays disabled until `camctl stage enable`, the wheel stopped until "
                "`camctl wheel speed`, a paused campaign job paused until `camctl campaign resume`",
            )
        return self.state()

    def hold(self) -> None:
        """The camera answered (a connect, a reboot) while the latch holds: it may have
        powered up turning its wheel; stop the wheel and the stage again."""
        if not self.device.estop.latched:
            return
        done = []
        for what, action in (
            ("stage", self.motion.emergency_stop_now),
            ("wheel", self.wheel.stop_now),
        ):
            try:
                action()
                done.append(what)
            except SessionError as exc:
                self.device.log_event("error", "estop", f"could not stop the {what} again: {exc}")
        if done:
            self.device.log_event(
                "warning",
                "estop",
                f"the camera answered while the emergency stop is latched: {' and '.join(done)} "
                f"stopped again; {RELEASE_HINT}",
            )
