"""One stream on the host, from its start to its end: the bookkeeping, and its end in one place.

``StreamRun`` keeps what the current or last stream is (its geometry and the device's counts,
the acquisition that claimed the slot for it, whether it streams) and ends it in one place
(``finish``) whether a client stopped it, a counted stream ran out (STREAM_DONE), its
STREAM_DONE was lost on the line (``check_ended``), the link lost its training (LINK_LOST), the
USB reader failed (``check_reader``), the camera restarted (``on_connect``, ``on_reset``) or the
daemon stops (``shut_down``): the device's ``next_counter`` tells the reader which frames it
never got, the reader drains, a recording is closed with the counters, and the state machine
goes back to idle. What ended a stream early, and how many of its frames the camera never sent,
is kept for the stare waiting on it (``raise_if_short``), the scan finishing it and the status.

Draining waits for the reader, so a stream is never ended on the link's reader thread: the
events that end it start a finisher thread of their own.
"""

from __future__ import annotations

import threading
import time
from typing import Any, cast

from camd.daemon.acquisition import Acquisition
from camd.daemon.device import DeviceAccess
from camd.daemon.errors import (
    Disconnected,
    EndedEarly,
    SessionError,
    StorageFull,
    unreachable,
)
from camd.daemon.models import StreamResponse, StreamStats
from camd.daemon.state import Trigger
from camd.daemon.stream_reader import StreamReader
from camd.daemon.stream_recording import StreamRecording
from camd.link.frame_stream import Consumer, FrameStream
from camd.store.durability import says_disk_full
from camd.store.recording import FrameRecorder

DRAIN_TIMEOUT_S = 5.0  # after the device's last frame: how long the reader may take to catch up
LINK_LOST_GRACE_S = 1.0  # after LINK_LOST: how long STREAM_DONE may take to follow
SETTLE_TIMEOUT_S = 30.0  # longest a START_STREAM exchange can take (with all its retries)
NO_STREAM_INFO: dict[str, Any] = {
    "mode": None,
    "rows": 0,
    "cols": 0,
    "bits": 0,
    "stages": 0,
    "binning": "off",
    "frame_period_s": 0.0,
    "frames_requested": 0,
    "first_counter": 0,
    "frames_sent": None,
}


def _ended_event(
    stats: StreamStats, early: str | None, why: str, not_sent: int, late: int
) -> tuple[str, str, str]:
    """The event (level, source, message) that says how a stream ended: early (why, or None),
    else ``why``; its counts; and ``late`` frames of the stream before that came during it."""
    clean = early is None and stats.lost == stats.corrupt == stats.overruns == 0
    short = f", {not_sent} not sent" if not_sent else ""
    # Frames the camera sent after the host had ended the stream before (counted lost there),
    # which came during this one: set aside, not this stream's.
    before = f"; {late} frames of the stream before came after it had ended, set aside"
    return (
        "info" if clean else "warning",
        "stream",
        f"stream ended ({early or why}): {stats.frames} frames delivered, {stats.lost} lost, "
        f"{stats.corrupt} corrupt, {stats.overruns} overruns{short}, "
        f"{stats.mbyte_per_s:.1f} MB/s{before if late else ''}",
    )


class StreamRun:
    """The current or last stream on the host (module docstring)."""

    def __init__(
        self,
        device: DeviceAccess,
        reader: StreamReader,
        recording: StreamRecording,
        lock: threading.RLock,
    ) -> None:
        self.device = device
        self.reader = reader
        self.recording = recording
        self.lock = lock  # guards the stream's bookkeeping, not the device
        self.streaming = False
        self.finished = threading.Event()
        self.finished.set()
        # Set once an ended stream has also been announced (STREAM_STOPPED: the daemon idle
        # again): an acquisition answers only then, so that its client may write registers at
        # once.
        self.announced = threading.Event()
        self.announced.set()
        # Clear while a START_STREAM is in flight: a short stream's STREAM_DONE can overtake
        # the bookkeeping of its own start, and must wait for it.
        self.settled = threading.Event()
        self.settled.set()
        self.claimed: Acquisition | None = None  # the slot this stream took (not a scan's)
        self._started_mono = 0.0
        self._info: dict[str, Any] = dict(NO_STREAM_INFO)
        self._broken: str | None = None  # why the stream ended early (``end_broken``)
        # Why the last stream ended before its frames were all sent and delivered, or None
        # (``finish``); set while it runs when the daemon stops it itself (its recording
        # failed) or the camera's LVDS link lost its training.
        self._ended_early: str | None = None
        self.stop_cause: str | None = None  # the daemon stopped the stream itself: why
        self._link_lost = False
        self._frames_not_sent = 0  # of the last counted stream, once ended (``_shortfall``)
        # Which stream this is (one more at each ``begin``): what the daemon decided about one
        # stream, from another thread and later, must not act on the next.
        self.generation = 0

    # -- what the last stream was ---------------------------------------------------------------

    @property
    def broken(self) -> str | None:
        """Why the current or last stream ended early because it could not go on (the camera
        restarted or went away), None if it did not."""
        return self._broken

    @property
    def ended_early(self) -> str | None:
        """Why the last stream ended before all its frames were sent and delivered (the camera
        ended it, or went away; its recording failed), None if it did not or was stopped on
        request (also None while a stream runs)."""
        return self._ended_early

    @property
    def frames_not_sent(self) -> int:
        """Frames of the last counted stream that never came: the camera did not send them (by
        its own count; if it could not say, those the host never accounted for)."""
        return self._frames_not_sent

    @property
    def frame_period_s(self) -> float:
        """The current or last stream's frame period (lock-free: a stream being drained holds
        the lock for seconds)."""
        return float(self._info["frame_period_s"])

    def info(self) -> dict[str, Any]:
        """The current or last stream's geometry and device counts (no device traffic)."""
        with self.lock:
            return dict(self._info)

    def response(self) -> StreamResponse:
        """The stream document: the current or last stream and its counters."""
        with self.lock:
            recording = self.recording
            return StreamResponse(
                streaming=self.streaming,
                ended_early=None if self.streaming else self._ended_early,
                frames_not_sent=0 if self.streaming else self._frames_not_sent,
                recording=recording.path,
                frames_flushed=recording.frames_flushed,
                stats=self.reader.stats(),
                **cast(Any, dict(self._info)),
            )

    # -- a stream's start -------------------------------------------------------------------------

    def begin(
        self,
        reader: FrameStream,
        recorder: FrameRecorder | None,
        consumer: Consumer | None,
        max_frame_bytes: int,
    ) -> None:
        """A stream is about to be asked for: its recording and consumer attached and the
        reader started first, so that no frame is missed."""
        with self.lock:
            self.generation += 1
            self.finished.clear()
            self.announced.clear()
            self._broken = None
            self._ended_early = self.stop_cause = None
            self._link_lost = False
            self._frames_not_sent = 0
            self.recording.forget()
            if recorder is not None:
                self.recording.attach(recorder, reader)
            if consumer is not None:
                self.reader.attach_stream_consumer(reader, consumer)
            reader.start(max_frame_bytes=max_frame_bytes)

    def abandon(self, reader: FrameStream) -> None:
        """The stream was not started after all: stop the reader, close the recording begun
        for it (the caller removes its file) and detach its consumer."""
        with self.lock:
            reader.stop()
            self.recording.detach(reader)
            self.reader.detach_stream_consumer(reader)
            self.finished.set()
            self.announced.set()

    def started(self, info: dict[str, Any]) -> None:
        """The camera streams: ``info`` is its geometry and counts (its answer)."""
        with self.lock:
            self._info = info
            self._started_mono = time.monotonic()
            self.streaming = True

    # -- what ends it -----------------------------------------------------------------------------

    def on_connect(self, device_streaming: bool) -> None:
        """After a (re)connect or BOOT: a stream nobody reads is stopped (its frames would be
        lost); a stream the camera no longer sends (it restarted) is ended; and the USB device
        is opened afresh by the next stream."""
        with self.lock:
            self.reader.reopen_next()
            streaming = self.streaming
        if streaming and not device_streaming:
            self.end_broken("the camera stopped streaming: it restarted or reconnected")
        if not device_streaming or streaming:
            return
        self.device.log_event(
            "warning",
            "stream",
            "the camera was streaming when camd connected; stopping it (nobody was reading "
            "its frames). Start it again with `camctl stream`.",
        )
        self.device.request("STOP_STREAM")

    def check_reader(self) -> None:
        """From the service loop: end a stream whose USB reader stopped on an error (the
        device went away: unplugged, powered off, the simulated camera died); its recording is
        closed with what arrived. Lock-free until it finds one: a stream being drained holds
        the lock for seconds, and the loop pets the watchdog."""
        reader = self.reader.current
        error = reader.error if reader is not None else None
        if self.streaming and error is not None:
            self.end_broken(f"the USB frame stream failed: {error}")

    def end_broken(self, why: str) -> None:
        """End the running stream, once, because it cannot go on (``why``), on a thread of its
        own (draining waits for the reader); ``acquire`` then fails with ``why``."""
        with self.lock:
            if not self.streaming or self._broken is not None:
                return
            self._broken = why
            recording = self.recording.path
        kept = (
            f"; its recording {recording} is closed with the frames that arrived"
            if recording
            else ""
        )
        self.device.log_event("warning", "stream", f"the stream cannot go on: {why}{kept}")
        self._finish_later(None, None, why)

    def on_event(self, name: str, values: dict[str, Any]) -> bool:
        """Handle a stream event (link reader thread); True if it was one."""
        if name == "LINK_LOST":
            self.on_link_lost_training()
            return True
        if name != "STREAM_DONE":
            return False
        next_counter = int(values.get("next_counter", 0))
        frames_sent = int(values.get("frames_sent", 0))
        self.device.log_event(
            "info",
            "device",
            f"the camera ended the stream (STREAM_DONE): {frames_sent} frames sent, next "
            f"counter {next_counter}",
        )
        # Draining waits for the reader: not on the link's reader thread.
        self._finish_later(next_counter, frames_sent, "STREAM_DONE")
        return True

    def check_ended(self) -> None:
        """From the service loop: end a counted stream whose STREAM_DONE event was lost on
        the line (the device's GET_STREAM says it stopped)."""
        with self.lock:
            frames = int(self._info["frames_requested"])
            if not self.streaming or frames == 0:
                return
            due = self._started_mono + frames * float(self._info["frame_period_s"]) + 0.5
        if time.monotonic() < due:
            return
        try:
            values = self.device.request("GET_STREAM").values
        except SessionError:
            return  # the link's own handling reports it; try again next period
        if values["streaming"] == "no":
            self._finish_later(
                int(values["next_counter"]),
                int(values["frames_sent"]),
                "the stream ended (its STREAM_DONE event was lost on the line)",
            )

    def on_link_lost_training(self) -> None:
        """The LVDS link lost its training: the device stopped streaming. Its STREAM_DONE,
        which says which frames it sent, normally follows; end the stream without it only if
        it has not come within LINK_LOST_GRACE_S."""
        if not self.streaming:
            return
        self._link_lost = True

        def finish_late() -> None:
            if not self.finished.wait(LINK_LOST_GRACE_S):
                self.finish(None, None, "LVDS link lost")

        threading.Thread(target=finish_late, name="camd-stream-finish", daemon=True).start()

    def on_reset(self) -> None:
        """RESET stopped the sequencer: end the stream on our side too."""
        if self.streaming:
            self.finish(None, None, "reset")

    def shut_down(self) -> None:
        """Daemon shutdown, first step: stop the camera's stream if the link still answers,
        then end it on the host (drained, its recording closed, a scan's finisher woken). A
        camera that is gone is expected here: one line says what could not be done."""
        if not self.streaming:
            return
        next_counter = frames_sent = None
        try:
            values = self.device.request("STOP_STREAM").values
            next_counter, frames_sent = int(values["next_counter"]), int(values["frames_sent"])
        except SessionError as exc:
            self.device.log_event(
                "warning", "stream", f"stream not stopped on the camera: {unreachable(exc)}"
            )
        self.finish(
            next_counter, frames_sent, "the daemon is stopping", settle=False, on_request=True
        )

    def close(self) -> None:
        """Daemon shutdown: stop reading, close any recording, release the USB device."""
        with self.lock:
            reader = self.reader.take()
            self.streaming = False
            self.finished.set()
            self.announced.set()
            if reader is not None:
                reader.stop()
                self.recording.detach(reader, reader.stats().as_dict())
                self.reader.detach_stream_consumer(reader)
                reader.close()

    # -- its end ----------------------------------------------------------------------------------

    def _finish_later(self, next_counter: int | None, frames_sent: int | None, why: str) -> None:
        threading.Thread(
            target=self.finish,
            args=(next_counter, frames_sent, why),
            name="camd-stream-finish",
            daemon=True,
        ).start()

    def finish(
        self,
        next_counter: int | None,
        frames_sent: int | None,
        why: str,
        *,
        settle: bool = True,
        on_request: bool = False,
    ) -> None:
        """End the stream on the host side: account for, drain, stop, close; then idle.

        ``frames_sent``: the camera's own count (STREAM_DONE, STOP_STREAM), None if it could
        not say (it went away). ``on_request``: a client (or the daemon's shutdown) stopped it:
        it did not end early (its frames not sent are counted all the same). ``settle``: first
        wait for a START_STREAM in flight to be booked (not from inside it)."""
        if settle:
            self.settled.wait(SETTLE_TIMEOUT_S)
        with self.lock:
            if not self.streaming:
                return
            reader = self.reader.current
            late = 0
            if reader is not None:
                if next_counter is not None:
                    reader.expect_end(next_counter)
                    reader.wait_drained(DRAIN_TIMEOUT_S)
                reader.stop()
                late = reader.late_frames
            early, not_sent = self._shortfall(frames_sent, why, on_request, reader)
            self._ended_early, self._frames_not_sent = early, not_sent
            if reader is not None:
                counters = {**reader.stats().as_dict(), "frames_not_sent": not_sent}
                self.recording.detach(reader, counters, ended_early=early)
                self.reader.detach_stream_consumer(reader)
            self._info["frames_sent"] = frames_sent
            self.streaming = False
            claimed, self.claimed = self.claimed, None
            self.finished.set()
        if claimed is not None:
            self.device.acquisition.release(claimed)
        self.device.log_event(*_ended_event(self.reader.stats(), early, why, not_sent, late))
        self.device.fire(Trigger.STREAM_STOPPED, None)
        self.announced.set()

    def _shortfall(
        self, frames_sent: int | None, why: str, on_request: bool, reader: FrameStream | None
    ) -> tuple[str | None, int]:
        """(why the ending stream ended early, None if it did not; its frames not sent), the
        lock held. Early: the daemon stopped it itself (its recording failed); the camera
        could not say what it sent (it went away, its link failed, a reset: ``why``); or it
        ended the stream with fewer frames than asked for, or a stream until stopped at all.
        The camera sent them all but the USB reader failed: early too (broken). Not sent: of a
        counted stream, the frames asked for that the camera did not send (by
        its own count; if it could not say, those the host never accounted for), however it
        ended (also when stopped on request)."""
        requested = int(self._info["frames_requested"])
        early: str | None = None
        if self.stop_cause is not None:
            early = self.stop_cause
        elif on_request:
            pass
        elif frames_sent is None:
            early = why
        elif reader is not None and reader.error and reader.stats().frames < frames_sent:
            early = self._broken = f"the USB frame stream failed: {reader.error}"  # not all read
        elif requested == 0 or frames_sent < requested:
            of = f" of {requested}" if requested else ""
            early = f"the camera ended the stream after {frames_sent}{of} frames (STREAM_DONE)"
            if self._link_lost:
                early += ": the sensor's LVDS link lost its training (LINK_LOST)"
        if requested == 0:
            return early, 0
        if frames_sent is None and reader is not None:
            # Every frame the host saw or knows it missed was sent; the rest never came.
            st = reader.stats()
            frames_sent = st.frames + st.lost + st.corrupt + st.short + st.overruns
        return early, max(0, requested - (frames_sent or 0))

    def raise_if_short(self) -> None:
        """After an acquisition's stream ended: the error to answer with if it ended before
        all its frames came (the camera went away: Disconnected; its recording could not be
        written for want of space: StorageFull; the camera ended it, or someone stopped it:
        EndedEarly), each saying what was kept."""
        with self.lock:
            broken, early, recording = self._broken, self._ended_early, self.recording.path
            stop_cause, not_sent, flushed = (
                self.stop_cause,
                self._frames_not_sent,
                self.recording.frames_flushed,
            )
            frames = int(self._info["frames_requested"])
        if early is None and not_sent == 0:
            return
        stats = self.reader.stats()
        counts = (
            f"{stats.frames} of {frames} frames delivered, {stats.lost} lost, {not_sent} not sent"
        )
        kept = f"; the recording {recording} is closed with {flushed} of them" if recording else ""
        if broken is not None:
            raise Disconnected(
                f"the stream ended before its {frames} frames: {broken}; {counts}{kept}. Check "
                "`camctl status` and `camctl events`, then acquire again"
            )
        if early is None:
            raise EndedEarly(
                f"the stream was stopped before its {frames} frames (`camctl stream --stop`, "
                f"an emergency stop or the daemon stopping): {counts}{kept}"
            )
        if stop_cause is not None and says_disk_full(stop_cause):
            raise StorageFull(f"{early}; the stream was stopped: {counts}{kept}")
        raise EndedEarly(
            f"the stream ended before its {frames} frames: {early}; {counts}{kept}. Check "
            "`camctl events`, then acquire again"
        )
