"""The daemon's frame stream: START_STREAM / STOP_STREAM and the USB ingest behind them.

``StreamService`` is handed the device access, the sensor service and the pyusb backend the
config chose (``camd.daemon.backends``: the simulated FX3 or libusb, per ``[stream]``). It opens
the camera's USB bulk endpoint (``camd.link.frame_stream.FrameStream``), starts
the reader before it asks the camera to stream so that no frame is missed, and ends a stream
in one place (``_finish``) whether the client stopped it, a counted stream ran out (STREAM_DONE)
or the link lost its training: the device's ``next_counter`` tells the reader which frames it
never got, the reader drains, a recording is closed with the counters, and the state machine
goes back to idle.

Consumers (the HDF5 recorder here; the TDI engine next) get every frame through
``add_consumer``: called on the stream's dispatcher thread, in order, with ``gap_before`` set
when frames are missing.

A counted stream need not be started by START_STREAM: ``acquire(..., start=StreamStart(...))``
sends another command that makes the camera stream a known number of frames and end with
STREAM_DONE (WHEEL_ACQUIRE: one frame per filter-wheel channel, ``wheel_service``). Everything
else (reader first, recording, the state machine to streaming and back) is the same; a
``consumer`` given there sees the frames of that stream only.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, cast

from camd.daemon.acquisition import Acquisition
from camd.daemon.device import DeviceAccess
from camd.daemon.errors import (
    BadRequest,
    DeviceTimeout,
    Disconnected,
    EndedEarly,
    NoFrameDevice,
    SessionError,
    StorageFull,
    unreachable,
)
from camd.daemon.models import (
    StreamFrameHeader,
    StreamHeadersResponse,
    StreamResponse,
    StreamStartRequest,
    StreamStats,
)
from camd.daemon.output_paths import RECORDINGS_FOLDER, resolve_output
from camd.daemon.realtime import REALTIME
from camd.daemon.sensor_service import SensorService
from camd.daemon.state import Request, Trigger
from camd.daemon.transaction import Apply
from camd.link.frame_stream import (
    HEADER_LOG,
    PACK_BYTES,
    FrameStream,
    ReceivedFrame,
    StreamError,
)
from camd.pipeline.background import Background, BackgroundCapture
from camd.protocol.stream import HEADER_BYTES, StreamMode
from camd.store.durability import says_disk_full
from camd.store.journal import close_recording
from camd.store.recording import FrameRecorder, RecordingError, check_new_file

log = logging.getLogger(__name__)

ANNOUNCE_TIMEOUT_S = 5.0  # an ended stream's announcement (the daemon idle again) follows at once
DRAIN_TIMEOUT_S = 5.0  # after the device's last frame: how long the reader may take to catch up
LINK_LOST_GRACE_S = 1.0  # after LINK_LOST: how long STREAM_DONE may take to follow
SETTLE_TIMEOUT_S = 30.0  # longest a START_STREAM exchange can take (with all its retries)
Consumer = Callable[[ReceivedFrame], None]


@dataclass(frozen=True, slots=True)
class StreamStart:
    """A device command that starts a counted area-mode stream instead of START_STREAM.

    ``command`` is sent with ``fields``; its answer must carry ``frames`` (how many the stream
    will send), ``first_counter``, ``rows`` and ``cols``, and the device ends the stream with
    STREAM_DONE like a counted START_STREAM. ``frame_period_s`` is the longest the host should
    expect per frame (it sizes the acquisition's timeout and the lost-STREAM_DONE check: a
    wheel frame may wait up to a revolution for its channel). ``metadata`` goes into a
    recording's ``stream`` group.
    """

    command: str
    fields: Mapping[str, Any]
    frame_period_s: float
    metadata: Mapping[str, Any] = field(default_factory=dict)


class StreamService:
    """Start, stop and watch the camera's frame stream; record it on request."""

    def __init__(
        self,
        device: DeviceAccess,
        sensor: SensorService,
        usb_backend: Callable[[], Any],
        *,
        background: BackgroundCapture | None = None,
    ) -> None:
        self.device = device
        self.sensor = sensor
        # The live view's background: stored in every recording started while it is ready.
        self.background = background
        self.config = device.config.stream
        self._usb_backend = usb_backend
        self.streaming = False
        self._lock = threading.RLock()  # guards the stream's bookkeeping, not the device
        self._finished = threading.Event()
        self._finished.set()
        # Set once an ended stream has also been announced (STREAM_STOPPED: the daemon idle
        # again): an acquisition answers only then, so that its client may write registers at
        # once.
        self._announced = threading.Event()
        self._announced.set()
        # Clear while a START_STREAM is in flight: a short stream's STREAM_DONE can overtake
        # the bookkeeping of its own start, and must wait for it.
        self._settled = threading.Event()
        self._settled.set()
        self._start_lock = threading.Lock()
        self._started_mono = 0.0
        self._reader: FrameStream | None = None
        self._recording_to: tuple[FrameRecorder, Consumer] | None = None
        self._stream_consumer: Consumer | None = None  # acquire(consumer=...): this stream's
        self._recording: str | None = None
        self._frames_flushed = 0  # of the last recording, once closed
        self._consumers: list[Consumer] = []
        self._claimed: Acquisition | None = None  # the slot this stream took (not a scan's)
        self._reopen = False  # the camera (re)connected: open the USB device afresh
        self._broken: str | None = None  # why the stream ended early (``_end_broken``)
        # Why the last stream ended before its frames were all sent and delivered, or None
        # (``_finish``); set while it runs when the daemon stops it itself (its recording
        # failed) or the camera's LVDS link lost its training.
        self._ended_early: str | None = None
        self._stop_cause: str | None = None  # the daemon stopped the stream itself: why
        self._link_lost = False
        self._frames_not_sent = 0  # of the last counted stream, once ended (``_shortfall``)
        self._info: dict[str, Any] = {
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

    # -- consumers (the TDI engine plugs in here) ---------------------------------------------

    def add_consumer(self, consumer: Consumer) -> None:
        """Call ``consumer(frame)`` for every delivered frame of every stream, in order."""
        with self._lock:
            self._consumers.append(consumer)
            if self._reader is not None:
                self._reader.add_consumer(consumer)

    def remove_consumer(self, consumer: Consumer) -> None:
        with self._lock:
            if consumer in self._consumers:
                self._consumers.remove(consumer)
            if self._reader is not None:
                self._reader.remove_consumer(consumer)

    # -- lifecycle (called by the session) ---------------------------------------------------------

    def on_connect(self, device_streaming: bool) -> None:
        """After a (re)connect or BOOT: a stream nobody reads is stopped (its frames would be
        lost); a stream the camera no longer sends (it restarted) is ended; and the USB device
        is opened afresh by the next stream (a camera that restarted enumerates anew: a handle
        to the old one reads nothing)."""
        with self._lock:
            self._reopen = True
            streaming = self.streaming
        if streaming and not device_streaming:
            self._end_broken("the camera stopped streaming: it restarted or reconnected")
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
        reader = self._reader
        error = reader.error if reader is not None else None
        if self.streaming and error is not None:
            self._end_broken(f"the USB frame stream failed: {error}")

    def _end_broken(self, why: str) -> None:
        """End the running stream, once, because it cannot go on (``why``), on a thread of its
        own (draining waits for the reader); ``acquire`` then fails with ``why``."""
        with self._lock:
            if not self.streaming or self._broken is not None:
                return
            self._broken = why
            recording = self._recording
        kept = (
            f"; its recording {recording} is closed with the frames that arrived"
            if recording
            else ""
        )
        self.device.log_event("warning", "stream", f"the stream cannot go on: {why}{kept}")
        threading.Thread(
            target=self._finish, args=(None, None, why), name="camd-stream-finish", daemon=True
        ).start()

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
        threading.Thread(
            target=self._finish,
            args=(next_counter, frames_sent, "STREAM_DONE"),
            name="camd-stream-finish",
            daemon=True,
        ).start()
        return True

    def check_ended(self) -> None:
        """From the service loop: end a counted stream whose STREAM_DONE event was lost on
        the line (the device's GET_STREAM says it stopped)."""
        with self._lock:
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
            threading.Thread(
                target=self._finish,
                args=(
                    int(values["next_counter"]),
                    int(values["frames_sent"]),
                    "the stream ended (its STREAM_DONE event was lost on the line)",
                ),
                name="camd-stream-finish",
                daemon=True,
            ).start()

    def on_link_lost_training(self) -> None:
        """The LVDS link lost its training: the device stopped streaming. Its STREAM_DONE,
        which says which frames it sent, normally follows; end the stream without it only if
        it has not come within LINK_LOST_GRACE_S."""
        if not self.streaming:
            return
        self._link_lost = True

        def finish_late() -> None:
            if not self._finished.wait(LINK_LOST_GRACE_S):
                self._finish(None, None, "LVDS link lost")

        threading.Thread(target=finish_late, name="camd-stream-finish", daemon=True).start()

    def on_reset(self) -> None:
        """RESET stopped the sequencer: end the stream on our side too."""
        if self.streaming:
            self._finish(None, None, "reset")

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
        self._finish(
            next_counter, frames_sent, "the daemon is stopping", settle=False, on_request=True
        )

    def close(self) -> None:
        """Daemon shutdown: stop reading, close any recording, release the USB device."""
        with self._lock:
            reader, self._reader = self._reader, None
            self.streaming = False
            self._finished.set()
            self._announced.set()
            if reader is not None:
                reader.stop()
                self._detach_recorder(reader, reader.stats().as_dict())
                self._detach_stream_consumer(reader)
                reader.close()

    # -- requests ---------------------------------------------------------------------------------

    def status(self) -> StreamResponse:
        """The current or last stream and its counters."""
        self.device.require(Request.STREAM_READ)
        return self._response()

    def headers(self) -> StreamHeadersResponse:
        """The first headers of the current or last stream (``FrameStream.header_log``)."""
        self.device.require(Request.STREAM_READ)
        with self._lock:
            reader = self._reader
        log_ = [] if reader is None else reader.header_log()
        return StreamHeadersResponse(
            kept_max=HEADER_LOG,
            frames=[
                StreamFrameHeader(
                    counter=h.counter,
                    timestamp_ns=h.timestamp_ns,
                    line_period_ns=h.line_period_ns,
                    rows=h.rows,
                    cols=h.cols,
                    bits=h.bits,
                    mode="tdi" if h.mode == StreamMode.TDI else "area",
                    stages=h.stages,
                    stage_position=h.stage_position,
                    flags=int(h.flags),
                    payload_bytes=h.payload_bytes,
                    payload_crc32=h.payload_crc32,
                    payload_crc32_host=computed,
                )
                for h, computed in log_
            ],
        )

    def start(self, request: StreamStartRequest, *, max_rows: int | None = None) -> StreamResponse:
        """Start a stream and return at once (``frames = 0``: until ``stop``). ``max_rows``:
        the most window rows a frame of this stream may have, if the window may grow while it
        runs (a scan's line-period loop): the reader's slots are sized for it."""
        self._start(request, kind="stream", max_rows=max_rows)
        return self._response()

    def acquire(
        self,
        request: StreamStartRequest,
        *,
        start: StreamStart | None = None,
        consumer: Consumer | None = None,
    ) -> StreamResponse:
        """Take ``frames`` frames and return when the stream has ended (or on timeout).

        ``start``: send that command instead of START_STREAM (its answer says how many frames
        come; ``request.mode``, ``stages`` and ``binning`` do not apply). ``consumer`` gets
        every frame of this stream only (on the dispatcher thread, as ``add_consumer``).
        """
        if request.frames < 1:
            raise BadRequest("frames must be at least 1 for an acquisition; use start for 0")
        self._start(request, start, consumer, kind="stare")
        period_s = float(self._info["frame_period_s"])
        timeout_s = request.timeout_s or 2 * request.frames * period_s + 10.0
        if not self._finished.wait(timeout_s):
            self.stop()
            raise DeviceTimeout(
                f"the camera did not finish {request.frames} frames within {timeout_s:.1f} s "
                f"(frame period {period_s * 1e3:.3f} ms); the stream was stopped. Check "
                "`camctl stream --status` and `camctl events`"
            )
        self._announced.wait(ANNOUNCE_TIMEOUT_S)
        self._raise_if_short()
        return self._response()

    def preflight(self, what: str) -> None:
        """What every acquisition needs of the camera, checked before it changes anything (a
        mode, a register, the stage): the daemon in a state that may stream (the link up, no
        fault), the sensor's output link trained (LinkUntrained) and the frame device present
        and openable (NoFrameDevice; it stays open for the stream). Each acquisition's plan
        then checks the rest, still before it changes anything: the sensor the camera reports
        (its register reads refuse another, SENSOR_MISMATCH), the stage's state and travel, and
        the space its file needs."""
        self.device.require(Request.STREAM_START)
        self.sensor.require_trained(what)
        with self._lock:
            self._open_reader()

    def _raise_if_short(self) -> None:
        """After an acquisition's stream ended: the error to answer with if it ended before
        all its frames came (the camera went away: Disconnected; its recording could not be
        written for want of space: StorageFull; the camera ended it, or someone stopped it:
        EndedEarly), each saying what was kept."""
        with self._lock:
            broken, early, recording = self._broken, self._ended_early, self._recording
            stop_cause, not_sent, flushed = (
                self._stop_cause,
                self._frames_not_sent,
                self._frames_flushed,
            )
            frames = int(self._info["frames_requested"])
        if early is None and not_sent == 0:
            return
        stats = self._stats()
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

    def status_info(self) -> dict[str, Any]:
        """The current or last stream's geometry and device counts (no device traffic)."""
        with self._lock:
            return dict(self._info)

    def wait_finished(self, timeout_s: float | None = None) -> bool:
        """Wait until the current stream (if any) has ended on the host side."""
        return self._finished.wait(timeout_s)

    def stop(self) -> StreamResponse:
        """STOP_STREAM, then drain the reader; harmless when not streaming."""
        self.device.require(Request.STREAM_STOP)
        values = self.device.request("STOP_STREAM").values
        self._finish(
            int(values["next_counter"]), int(values["frames_sent"]), "stopped", on_request=True
        )
        return self._response()

    # -- internals --------------------------------------------------------------------------------

    def _start(
        self,
        request: StreamStartRequest,
        start: StreamStart | None = None,
        consumer: Consumer | None = None,
        *,
        kind: str,
        max_rows: int | None = None,
    ) -> None:
        # One start at a time: a second client's start waits here, then finds the slot taken
        # and is refused (Busy), never touching the running reader. A scan or a wheel run
        # that already holds the slot starts its stream inside its own claim.
        if request.record is not None:
            # Resolved and confined first: everything after names the file it will write.
            record = self.allowed_record(request.record)
            request = request.model_copy(update={"record": str(record)})
        slot = self.device.acquisition
        with self._start_lock:
            owner = slot.applying_now()
            claimed = None
            if owner is None:
                what = "until stopped" if request.frames == 0 else f"{request.frames} frames"
                if request.record:
                    what += f" to {request.record}"
                claimed = slot.claim(kind, what)
            acquisition = owner or claimed
            assert acquisition is not None
            with self._lock:
                self._claimed = claimed  # before the start: its STREAM_DONE may come at once
            try:
                with slot.applying(acquisition):
                    self._start_locked(request, start, consumer, max_rows)
            except BaseException:
                with self._lock:
                    self._claimed = None
                if claimed is not None:
                    slot.abandon(claimed)
                raise

    def _start_locked(
        self,
        request: StreamStartRequest,
        start: StreamStart | None,
        consumer: Consumer | None,
        max_rows: int | None = None,
    ) -> None:
        # Plan: everything checked before the camera is touched.
        device = self.device
        self.preflight("start a stream")
        set_mode = request.mode if start is None else None
        mode = set_mode or device.mode or "area"
        timing = self.sensor.timing()
        stages = 0
        if mode == "tdi" and start is None:
            stages = timing.window_rows if request.stages is None else request.stages
            if not 1 <= stages <= timing.window_rows:
                raise BadRequest(
                    f"stages = {stages} does not fit the window of {timing.window_rows} rows "
                    f"(docs/physics.md §2 eq 13: 1 <= M <= M0 = n_lines); choose 1..{timing.window_rows}"
                    " or make the window taller"
                )
        cols = self.sensor.window_columns()
        # Frames as large as the window may become while the stream runs: a frame larger than
        # the reader's slots would be refused as corrupt, every one of them.
        rows = max(timing.window_rows, max_rows or 0)
        max_frame_bytes = HEADER_BYTES + 2 * rows * cols
        # The file holds the frames and, if the live view has one, the background.
        background = self.background.ready() if self.background is not None else None
        extra = 0 if background is None else background.pixels.nbytes
        recorder_path = self._record_path(request.record, request.frames * max_frame_bytes + extra)
        # Apply: the mode, then the stream; a stream that does not start puts the mode back.
        with Apply("stream start", self._events, source="stream") as apply:
            if set_mode is not None and device.mode != set_mode:
                before = device.mode or "area"
                apply.step(
                    lambda: device.set_mode(set_mode),
                    lambda: device.set_mode(before),
                    f"mode {before}",
                )
            self._settled.clear()
            try:
                self._start_stream(request, stages, max_frame_bytes, recorder_path, start, consumer)
            except (DeviceTimeout, Disconnected) as exc:
                if exc.link_wait is not None:  # the command link failed, not the USB reader
                    # Only the answer may have been lost: the camera may be streaming to
                    # nobody. STOP_STREAM is harmless when it is not (sent once it answers).
                    apply.undo_later(lambda: device.request("STOP_STREAM"), "stream stopped")
                raise
            finally:
                self._settled.set()
            apply.done()

    def _events(self, level: str, source: str, message: str) -> None:
        self.device.log_event(level, source, message)

    def _start_stream(
        self,
        request: StreamStartRequest,
        stages: int,
        max_frame_bytes: int,
        recorder_path: Path | None,
        start: StreamStart | None = None,
        consumer: Consumer | None = None,
    ) -> None:
        with self._lock:
            reader = self._open_reader()
        recorder = None
        background = self.background.ready() if self.background is not None else None
        if recorder_path is not None:
            recorder = self._new_recorder(recorder_path, request, stages, start, background)
        with self._lock:
            self._finished.clear()
            self._announced.clear()
            self._broken = None
            self._ended_early = self._stop_cause = None
            self._link_lost = False
            self._frames_not_sent = 0
            self._recording = None
            self._frames_flushed = 0
            if recorder is not None:
                self._attach_recorder(recorder, reader)
            if consumer is not None:
                self._stream_consumer = consumer
                reader.add_consumer(consumer)
            reader.start(max_frame_bytes=max_frame_bytes)
        try:
            if start is None:
                values = self.device.request(
                    "START_STREAM", frames=request.frames, stages=stages, binning=request.binning
                ).values
            else:
                values = self.device.request(start.command, **start.fields).values
        except Exception:
            with self._lock:
                reader.stop()
                self._detach_recorder(reader)
                self._detach_stream_consumer(reader)
                self._finished.set()
                self._announced.set()
            if recorder_path is not None:
                recorder_path.unlink(missing_ok=True)  # nothing was recorded: leave no file
            raise
        reader.expect_first(int(values["first_counter"]))
        if recorder_path is not None and background is not None:
            assert self.background is not None
            self.background.note_saved(background, str(recorder_path))
        if start is None:
            info = {
                "mode": str(values["mode"]),
                "rows": int(values["rows"]),
                "cols": int(values["cols"]),
                "bits": int(values["bits"]),
                "stages": stages,
                "binning": request.binning,
                "frame_period_s": float(values["frame_period_s"]),
                "frames_requested": request.frames,
                "first_counter": int(values["first_counter"]),
                "frames_sent": None,
            }
        else:
            # The command's own answer says how many frames come (and their geometry); the
            # frames are plain area-mode frames of the sensor's full word.
            info = {
                "mode": "area",
                "rows": int(values["rows"]),
                "cols": int(values["cols"]),
                "bits": self.sensor.regmap.output.word_bits,
                "stages": 0,
                "binning": "off",
                "frame_period_s": start.frame_period_s,
                "frames_requested": int(values["frames"]),
                "first_counter": int(values["first_counter"]),
                "frames_sent": None,
            }
        with self._lock:
            self._info = info
            self._started_mono = time.monotonic()
            self.streaming = True
        what = "until stopped" if request.frames == 0 else f"{info['frames_requested']} frames"
        how = f"{info['mode']} stream" if start is None else start.command
        self.device.fire(Trigger.STREAM_STARTED, f"{how}, {what}")

    def allowed_record(self, record: str) -> Path:
        """The file a client's ``record`` names, resolved and confined to the data directory
        and ``daemon.record_dirs`` (a relative one in the recordings folder); BadRequest
        otherwise (``camd.daemon.output_paths``)."""
        daemon = self.device.config.daemon
        return resolve_output(
            record,
            field="record",
            relative_to=daemon.data_dir / RECORDINGS_FOLDER,
            data_dir=daemon.data_dir,
            record_dirs=daemon.record_dirs,
        )

    def _record_path(self, record: str | None, planned_bytes: int) -> Path | None:
        """The recording's path, refused (nothing changed) when it cannot be written."""
        if record is None:
            return None
        path = Path(record)  # resolved and confined by ``allowed_record`` in ``_start``
        try:
            check_new_file(path, planned_bytes)
        except RecordingError as exc:
            raise BadRequest(str(exc)) from None
        return path

    def _new_recorder(
        self,
        path: Path,
        request: StreamStartRequest,
        stages: int,
        start: StreamStart | None = None,
        background: Background | None = None,
    ) -> FrameRecorder:
        """A new recording with the camera's metadata (and the live view's ``background``, if
        one is ready), made before the stream starts so that its first frame is recorded too;
        the frames set its geometry."""
        sensor = self.sensor
        stream: dict[str, Any] = {
            "frames_requested": request.frames,
            "stages": stages,
            "binning": request.binning,
        }
        if start is not None:
            stream.update({"start_command": start.command, **start.metadata})
        # On the journal before the file exists: a daemon killed at any point after leaves an
        # entry, and the next one repairs the file (or finds it was never made).
        journal = self.device.recordings
        try:
            journal.opened(path, "recording")
        except OSError as exc:
            raise SessionError(
                f"cannot note the recording in {journal.folder}: {exc}; check the data directory"
            ) from None
        try:
            recorder = FrameRecorder(
                path,
                frames_expected=request.frames,
                metadata={
                    "profile": sensor.profile_metadata(),
                    "registers": sensor.register_values(),
                    "timing": sensor.timing().model_dump(),
                    "stream": stream,
                },
                background_dn=None if background is None else background.pixels,
                background_attrs=None if background is None else background.recording_attrs(),
            )
        except RecordingError as exc:
            journal.closed(path)  # no file was left (FrameRecorder removes what it began)
            raise BadRequest(str(exc)) from None
        return recorder

    def _attach_recorder(self, recorder: FrameRecorder, reader: FrameStream) -> None:
        def record(frame: ReceivedFrame) -> None:
            if recorder.failed is not None:
                return  # said once; the stream is being stopped
            try:
                recorder.add(
                    frame.header, frame.pixels, received_ns=frame.received_ns,
                    gap_before=frame.gap_before,
                )  # fmt: skip
            except RecordingError as exc:
                self._recording_failed(recorder, str(exc))

        self._recording_to = (recorder, record)
        self._recording = str(recorder.path)
        self._frames_flushed = 0
        reader.add_consumer(record)

    def _recording_failed(self, recorder: FrameRecorder, why: str) -> None:
        """A frame could not be written (a full disk): say so once, stop the stream (not from
        the reader's dispatch thread, which stopping joins); the daemon goes on serving."""
        self.device.log_event(
            "error", "stream", f"recording {recorder.path} stopped: {why}; stopping the stream"
        )
        # Not under the lock: this runs on the dispatcher, which _finish joins holding it.
        self._stop_cause = f"the recording {recorder.path} stopped: {why}"

        def stop() -> None:
            try:
                if self.streaming:
                    self.stop()
            except SessionError as exc:
                self.device.log_event("warning", "stream", f"could not stop the stream: {exc}")

        threading.Thread(target=stop, name="camd-recording-failed", daemon=True).start()

    def _detach_recorder(
        self,
        reader: FrameStream,
        stats: dict[str, Any] | None = None,
        *,
        ended_early: str | None = None,
    ) -> None:
        if self._recording_to is None:
            return
        recorder, record = self._recording_to
        self._recording_to = None
        reader.remove_consumer(record)
        close_recording(
            recorder,
            stats,
            self.device.recordings,
            self.device.log_event,
            ended_early=ended_early,
        )
        self._frames_flushed = recorder.flushed

    def _detach_stream_consumer(self, reader: FrameStream) -> None:
        consumer, self._stream_consumer = self._stream_consumer, None
        if consumer is not None:
            reader.remove_consumer(consumer)

    def _open_reader(self) -> FrameStream:
        """The USB reader, opened on first use; NoFrameDevice (503) if the device is absent or
        cannot be opened: its message names the device looked for and what to check."""
        try:
            return self._opened_reader()
        except (StreamError, ConnectionError, OSError) as exc:
            raise NoFrameDevice(str(exc)) from None

    def _opened_reader(self) -> FrameStream:
        stale = self._reader
        if stale is not None and (self._reopen or stale.error is not None):
            # The camera reconnected, or its USB device went away under the last stream.
            self._reader = None
            self._close_reader(stale)
        self._reopen = False
        if self._reader is None:
            reader = FrameStream(
                vendor_id=self.config.vendor_id,
                product_id=self.config.product_id,
                backend=self._usb_backend(),
                queue_frames=self.config.queue_frames,
                queue_bytes=round(self.config.queue_mb * 1e6),
                overflow=self.config.overflow,
                read_bytes=self.config.read_bytes,
                # Small frames packed into transfers, where the device can (docs/stream.md).
                pack_bytes=0 if self.config.read_bytes else PACK_BYTES,
                timeout_s=self.config.timeout_s,
                thread_start=REALTIME.enter,
            )
            reader.open()
            for consumer in self._consumers:
                reader.add_consumer(consumer)
            self._reader = reader
        return self._reader

    @staticmethod
    def _close_reader(reader: FrameStream) -> None:
        """Release a reader's USB device, gone or not, and a simulated FX3's socket."""
        try:
            reader.close()
        except Exception as exc:  # a device that went away may fail to let go
            log.info("closing the old frame stream: %s", exc)
        close_backend = getattr(reader.backend, "close", None)  # the simulated FX3's socket
        if callable(close_backend):
            close_backend()

    def _finish(
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
            self._settled.wait(SETTLE_TIMEOUT_S)
        with self._lock:
            if not self.streaming:
                return
            reader = self._reader
            if reader is not None:
                if next_counter is not None:
                    reader.expect_end(next_counter)
                    reader.wait_drained(DRAIN_TIMEOUT_S)
                reader.stop()
            early, not_sent = self._shortfall(frames_sent, why, on_request, reader)
            self._ended_early, self._frames_not_sent = early, not_sent
            if reader is not None:
                counters = {**reader.stats().as_dict(), "frames_not_sent": not_sent}
                self._detach_recorder(reader, counters, ended_early=early)
                self._detach_stream_consumer(reader)
            self._info["frames_sent"] = frames_sent
            self.streaming = False
            claimed, self._claimed = self._claimed, None
            self._finished.set()
        if claimed is not None:
            self.device.acquisition.release(claimed)
        stats = self._stats()
        short = f", {not_sent} not sent" if not_sent else ""
        self.device.log_event(
            "info"
            if early is None and stats.lost == stats.corrupt == stats.overruns == 0
            else "warning",
            "stream",
            f"stream ended ({early or why}): {stats.frames} frames delivered, {stats.lost} lost, "
            f"{stats.corrupt} corrupt, {stats.overruns} overruns{short}, "
            f"{stats.mbyte_per_s:.1f} MB/s",
        )
        self.device.fire(Trigger.STREAM_STOPPED, None)
        self._announced.set()

    def _shortfall(
        self, frames_sent: int | None, why: str, on_request: bool, reader: FrameStream | None
    ) -> tuple[str | None, int]:
        """(why the ending stream ended early, None if it did not; its frames not sent), the
        lock held. Early: the daemon stopped it itself (its recording failed); the camera
        could not say what it sent (it went away, its link failed, a reset: ``why``); or it
        ended the stream with fewer frames than asked for, or a stream until stopped at all.
        Not sent: of a counted stream, the frames asked for that the camera did not send (by
        its own count; if it could not say, those the host never accounted for), however it
        ended (also when stopped on request)."""
        requested = int(self._info["frames_requested"])
        early: str | None = None
        if self._stop_cause is not None:
            early = self._stop_cause
        elif on_request:
            pass
        elif frames_sent is None:
            early = why
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

    def stats(self) -> StreamStats:
        """The host's ingest counters of the current or last stream (no device traffic)."""
        return self._stats()

    def _stats(self) -> StreamStats:
        reader = self._reader
        if reader is None:
            return StreamStats(
                frames=0, bytes=0, lost=0, corrupt=0, short=0, overruns=0, stalls=0,
                timeouts=0, out_of_order=0, elapsed_s=0.0, mpix_per_s=0.0, mbyte_per_s=0.0,
            )  # fmt: skip
        values = reader.stats().as_dict()
        return StreamStats.model_validate({k: values[k] for k in StreamStats.model_fields})

    def _response(self) -> StreamResponse:
        with self._lock:
            info = dict(self._info)
            recording_to = self._recording_to
            return StreamResponse(
                streaming=self.streaming,
                ended_early=None if self.streaming else self._ended_early,
                frames_not_sent=0 if self.streaming else self._frames_not_sent,
                recording=self._recording,
                frames_flushed=self._frames_flushed
                if recording_to is None
                else recording_to[0].flushed,
                stats=self._stats(),
                **cast(Any, info),
            )
