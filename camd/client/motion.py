"""The scan stage: enable, run, move, home and stop it, wait until it stands, and the open-loop
synchronisation for a line period or a speed (docs/motion.md)."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any, Unpack, cast

from camd.client.connection import API, UNSET, CamdError, HttpClient, Unset, given
from camd.client_requests import MotionMoveRequestOptions
from camd.client_types import MotionStatus, SyncResponse

# Waiting for a stage move or homing (``MotionClient.wait_stage``): the request that starts it
# answers at once and the client polls GET /motion. The wait lasts the daemon's estimate of the
# operation plus a margin; past that it goes on while the stage still makes progress, for at most
# as long again (and at least STAGE_EXTRA_MIN_S), then fails naming what to do.
STAGE_POLL_S = 0.2
STAGE_MARGIN_MIN_S = 5.0  # at least this beyond the estimate
STAGE_MARGIN_FRACTION = 0.1  # or this fraction of it, whichever is more
STAGE_EXTRA_MIN_S = 30.0
STAGE_STALL_S = 3.0  # past the estimate, no progress for this long is a stall
STAGE_PROGRESS_M = 1e-6  # a change of position that counts as progress
STAGE_WAIT_MAX_S = 600.0  # a daemon that gives no estimate (older camd): wait at most this
STOPPED_STATES = frozenset({"idle", "disabled", "estop"})  # camd.motion.stage.STOPPED_STATES

StageProgress = Callable[[MotionStatus], None]
"""Called with each motion document polled while ``wait_stage`` waits."""


class MotionClient(HttpClient):
    """The client of the motion routes."""

    def motion(self) -> MotionStatus:
        """The scan stage: state, positions, speeds, limits."""
        return cast(MotionStatus, self._json("GET", f"{API}/motion"))

    def enable_stage(self, on: bool | Unset = UNSET) -> MotionStatus:
        """Energise (or release) the stage motor (not given: energise); enabling clears an
        emergency stop."""
        return cast(MotionStatus, self._json("POST", f"{API}/motion/enable", json=given(on=on)))

    def run_stage(self, speed_m_s: float) -> MotionStatus:
        """Ramp to a constant signed speed (m/s) and hold it; 0 stops."""
        body = {"speed_m_s": speed_m_s}
        return cast(MotionStatus, self._json("POST", f"{API}/motion/run", json=body))

    def move_stage(
        self,
        position_m: float,
        *,
        wait: bool = True,
        progress: StageProgress | None = None,
        **options: Unpack[MotionMoveRequestOptions],
    ) -> MotionStatus:
        """Move to ``position_m`` (metres from home) and stop, at ``speed_m_s`` (not given: the
        speed limit). The request answers at once; with ``wait`` this then polls until the
        stage stands (``wait_stage``, which calls ``progress`` with each motion document) and
        returns the last document."""
        body = {"position_m": position_m, **options, "wait": False}
        doc = cast(MotionStatus, self._json("POST", f"{API}/motion/move", json=body))
        return self.wait_stage(doc, progress=progress) if wait else doc

    def stop_stage(self) -> MotionStatus:
        """Decelerate the stage to a stop."""
        return cast(MotionStatus, self._json("POST", f"{API}/motion/stop"))

    def home_stage(
        self, *, wait: bool = True, progress: StageProgress | None = None
    ) -> MotionStatus:
        """Find the home switch and zero the position there. The request answers at once;
        with ``wait`` this then polls until homing has finished (``wait_stage``)."""
        doc = cast(MotionStatus, self._json("POST", f"{API}/motion/home", json={"wait": False}))
        return self.wait_stage(doc, progress=progress) if wait else doc

    def wait_stage(
        self,
        started: MotionStatus | None = None,
        *,
        progress: StageProgress | None = None,
        poll_s: float = STAGE_POLL_S,
    ) -> MotionStatus:
        """Poll GET /motion until the move or homing of ``started`` (the answer that started it;
        default: the last one the daemon started) has finished and the stage stands; return
        that motion document. ``progress`` is called with every document polled.

        The wait follows the daemon's estimate (``operation.expected_duration_s``) plus a
        margin (10 %, at least 5 s); a stage still making progress past that is waited for
        longer, at most as long again (at least 30 s more). Raises CamdError ``timeout`` when
        the stage has not finished by then, or stopped making progress, and ``stage_taken``
        when another move, homing, jog or scan took the stage over; the stage is not stopped
        (``camctl stage stop`` does that).
        """
        doc = self.motion() if started is None else started
        op = doc.get("operation")
        seq = None if op is None else op["seq"]
        expected = None if op is None else op["expected_duration_s"]
        begun = time.monotonic()
        if expected is None:  # an older daemon gives no estimate: progress alone
            soft = hard = begun + STAGE_WAIT_MAX_S
        else:
            soft = begun + expected + max(STAGE_MARGIN_MIN_S, STAGE_MARGIN_FRACTION * expected)
            hard = soft + max(STAGE_EXTRA_MIN_S, expected)
        last_position = doc["reading"]["position_m"]
        moved_at = begun
        while True:
            if progress is not None:
                progress(doc)
            reading, now_op = doc["reading"], doc.get("operation")
            if seq is not None and (now_op is None or now_op["seq"] != seq):
                raise CamdError(
                    f"the stage's {op['kind'] if op else 'move'} was taken over by another "
                    f"command (the stage is {reading['state']} at "
                    f"{reading['position_m'] * 1e3:.3f} mm); see `camctl stage` and "
                    "`camctl events`; `camctl stage stop` stops it",
                    "stage_taken",
                )
            finished = now_op is None or not now_op["active"]
            if finished and reading["state"] in STOPPED_STATES:
                return doc
            now = time.monotonic()
            if abs(reading["position_m"] - last_position) > STAGE_PROGRESS_M:
                last_position, moved_at = reading["position_m"], now
            stalled = now - moved_at > STAGE_STALL_S
            if now > hard or (now > soft and stalled):
                what = "homing" if op is not None and op["kind"] == "home" else "moving"
                estimate = "" if expected is None else f" (expected {expected:.3g} s)"
                why = "" if not stalled else f", without progress for {now - moved_at:.3g} s"
                raise CamdError(
                    f"the stage is still {reading['state']} at "
                    f"{reading['position_m'] * 1e3:.3f} mm after {now - begun:.3g} s of "
                    f"{what}{estimate}{why}; it was not stopped: `camctl stage` shows it, "
                    "`camctl stage stop` stops it",
                    "timeout",
                )
            time.sleep(poll_s)
            doc = self.motion()

    def estop_stage(self) -> MotionStatus:
        """Emergency stop (no ramp, current cut) until ``enable_stage``."""
        return cast(MotionStatus, self._json("POST", f"{API}/motion/estop"))

    def sync(
        self,
        *,
        line_period_s: float | None = None,
        speed_m_s: float | None = None,
        stages: int | None = None,
        binning: bool = False,
    ) -> SyncResponse:
        """Open-loop synchronisation for a line period, a stage speed, both, or neither."""
        params: dict[str, Any] = {"binning": binning}
        for key, value in (
            ("line_period_s", line_period_s), ("speed_m_s", speed_m_s), ("stages", stages)
        ):  # fmt: skip
            if value is not None:
                params[key] = value
        return cast(SyncResponse, self._json("GET", f"{API}/motion/sync", params=params))
