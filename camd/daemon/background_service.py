"""The live view's background in the daemon: capture, status and clear (docs/live-view.md).

``BackgroundService`` is handed the device access (the state machine: a capture needs a
stream; the event log), the ``BackgroundCapture`` that every stream feeds (a consumer of the
stream service, stored by each recording started while it is ready) and the stream service
(whether something streams). It serves ``GET``, ``POST`` and ``DELETE
/api/v1/live/background`` (docs/api.md).
"""

from __future__ import annotations

from camd.daemon.device import DeviceAccess
from camd.daemon.models import BackgroundStatus
from camd.daemon.state import Request
from camd.daemon.stream_service import StreamService
from camd.pipeline.background import BackgroundCapture


class BackgroundService:
    """The live view's background for one device session (module docstring)."""

    def __init__(
        self, device: DeviceAccess, capture: BackgroundCapture, stream: StreamService
    ) -> None:
        self.device = device
        self.capture = capture
        self.stream = stream

    def status(self) -> BackgroundStatus:
        """The background's state (a capture whose stream has ended fails here)."""
        capture = self.capture
        if capture.snapshot().state == "capturing" and not self.stream.streaming:
            capture.fail(
                "the stream ended",
                "capture again while something streams (`camctl stream --start`, a stare or a "
                "scan)",
            )
        snap = capture.snapshot()
        ready = snap.background
        return BackgroundStatus(
            state=snap.state,
            frames_wanted=snap.frames_wanted,
            frames_done=snap.frames_done,
            rows=snap.rows,
            cols=snap.cols,
            mode=snap.mode,
            stages=snap.stages,
            first_counter=snap.first_counter,
            last_counter=snap.last_counter,
            captured_t_s=None if ready is None else ready.captured_t_s,
            seq=None if ready is None else ready.seq,
            mean_dn=None if ready is None else ready.mean_dn,
            std_dn=None if ready is None else ready.std_dn,
            saved_to=list(snap.saved_to),
            error=snap.error,
        )

    def start(self, frames: int) -> BackgroundStatus:
        """Average the next ``frames`` frames of the running stream; returns at once. Refused
        (409, nothing changed: a ready background stays) when nothing streams."""
        self.device.require(Request.LIVE_BACKGROUND)
        self.capture.start(frames)
        self.device.log_event(
            "info", "api", f"live-view background: averaging the next {frames} frames"
        )
        return self.status()

    def clear(self) -> BackgroundStatus:
        """Drop the background (and stop a capture)."""
        self.capture.clear()
        return self.status()
