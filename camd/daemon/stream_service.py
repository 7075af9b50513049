"""The daemon's frame stream: START_STREAM / STOP_STREAM and the requests that take frames.

``StreamService`` is handed the device access, the sensor service and the pyusb backend the
config chose (``camd.daemon.backends``: the simulated FX3 or libusb, per ``[stream]``). It
serves a stream's start (returns at once; ``frames = 0`` streams until stopped), a stare
(``acquire``: returns when its frames are in), a stop, the status and the first headers.

A start is planned whole before the camera is touched: its frame count and file path are
checked, the acquisition slot claimed and the preflight passed, then ``camd.daemon.stream_plan``
checks the mode, the TDI stages, the largest frame and the recording's file and size. It is
then applied step by step through an ``Apply`` (``camd.daemon.transaction``): the mode, then
the stream, its reader started before the camera is asked to stream so that no frame is
missed. A start that fails puts the mode back, stops a
stream whose answer was lost (the camera may be streaming to nobody) and removes the recording
it had begun.

A counted stream need not be started by START_STREAM: ``acquire(..., start=StreamStart(...))``
sends another command that makes the camera stream a known number of frames and end with
STREAM_DONE (WHEEL_ACQUIRE: one frame per filter-wheel channel, ``wheel_service``). Everything
else (reader first, recording, the state machine to streaming and back) is the same; a
``consumer`` given there sees the frames of that stream only.

Its parts, one job each: the USB reader and the frame consumers (``stream_reader``; consumers,
such as the TDI engine, get every frame on the stream's dispatcher thread, in order, with
``gap_before`` set when frames are missing), the recording (``stream_recording``), and the
stream's bookkeeping and its end in one place (``stream_run``).
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

from camd.daemon.device import DeviceAccess
from camd.daemon.errors import DeviceTimeout, Disconnected, SessionError
from camd.daemon.models import (
    StreamHeadersResponse,
    StreamResponse,
    StreamStartRequest,
    StreamStats,
    TimingResponse,
)
from camd.daemon.sensor_service import SensorService
from camd.daemon.state import Request, Trigger
from camd.daemon.stream_plan import (
    StreamContext,
    StreamPlan,
    check_request,
    claim_description,
    plan_stream,
    resolve_record,
)
from camd.daemon.stream_plan import StreamStart as StreamStart  # re-exported: wheel_service
from camd.daemon.stream_reader import StreamReader
from camd.daemon.stream_recording import StreamRecording
from camd.daemon.stream_run import StreamRun
from camd.daemon.transaction import Apply
from camd.link.frame_stream import Consumer
from camd.pipeline.background import Background, BackgroundCapture
from camd.pipeline.roi import RoiMonitor

ANNOUNCE_TIMEOUT_S = 5.0  # an ended stream's announcement (the daemon idle again) follows at once


class StreamService:
    """Start, stop and watch the camera's frame stream; record it on request."""

    def __init__(
        self,
        device: DeviceAccess,
        sensor: SensorService,
        usb_backend: Callable[[], Any],
        *,
        background: BackgroundCapture | None = None,
        roi: RoiMonitor | None = None,
        on_timing: Callable[[TimingResponse, bool], None] | None = None,
    ) -> None:
        self.device = device
        # Told the sensor's timing and whether the frames are 2x2-binned at every stream's start
        # (the image motion monitor's row time: a binned row spans two of the sensor's)
        self._on_timing = on_timing
        self.sensor = sensor
        # The live view's background: stored in every recording started while it is ready.
        self.background = background
        self.config = device.config.stream
        self._lock = threading.RLock()  # guards the stream's bookkeeping, not the device
        self._reader = StreamReader(self.config, usb_backend, self._lock)
        self._recording = StreamRecording(device, self._recording_failed, roi)
        self._run = StreamRun(device, self._reader, self._recording, self._lock)
        self._start_lock = threading.Lock()

    @property
    def streaming(self) -> bool:
        """Whether a stream runs now (on the host's side)."""
        return self._run.streaming

    # -- consumers (the TDI engine plugs in here) ---------------------------------------------

    def add_consumer(self, consumer: Consumer) -> None:
        """Call ``consumer(frame)`` for every delivered frame of every stream, in order."""
        self._reader.add_consumer(consumer)

    def remove_consumer(self, consumer: Consumer) -> None:
        self._reader.remove_consumer(consumer)

    # -- lifecycle (called by the session; ``camd.daemon.stream_run``) ------------------------

    def on_connect(self, device_streaming: bool) -> None:
        """After a (re)connect or BOOT: stop a stream nobody reads, end one the camera no
        longer sends, and open the USB device afresh for the next."""
        self._run.on_connect(device_streaming)

    def check_reader(self) -> None:
        """From the service loop: end a stream whose USB reader stopped on an error."""
        self._run.check_reader()

    def on_event(self, name: str, values: dict[str, Any]) -> bool:
        """Handle a stream event (link reader thread); True if it was one."""
        return self._run.on_event(name, values)

    def check_ended(self) -> None:
        """From the service loop: end a counted stream whose STREAM_DONE was lost."""
        self._run.check_ended()

    def on_reset(self) -> None:
        """RESET stopped the sequencer: end the stream on our side too."""
        self._run.on_reset()

    @property
    def broken(self) -> str | None:
        """Why the current or last stream could not go on, None if it could."""
        return self._run.broken

    @property
    def ended_early(self) -> str | None:
        """Why the last stream ended before all its frames were sent and delivered, or None."""
        return self._run.ended_early

    @property
    def frames_not_sent(self) -> int:
        """Frames of the last counted stream that never came."""
        return self._run.frames_not_sent

    def shut_down(self) -> None:
        """Daemon shutdown, first step: stop the camera's stream and end it on the host."""
        self._run.shut_down()

    def close(self) -> None:
        """Daemon shutdown: stop reading, close any recording, release the USB device."""
        self._run.close()

    # -- requests ---------------------------------------------------------------------------------

    def status(self) -> StreamResponse:
        """The current or last stream and its counters."""
        self.device.require(Request.STREAM_READ)
        return self._run.response()

    def headers(self) -> StreamHeadersResponse:
        """The first headers of the current or last stream (``FrameStream.header_log``)."""
        self.device.require(Request.STREAM_READ)
        return self._reader.headers()

    def stats(self) -> StreamStats:
        """The host's ingest counters of the current or last stream (no device traffic)."""
        return self._reader.stats()

    def status_info(self) -> dict[str, Any]:
        """The current or last stream's geometry and device counts (no device traffic)."""
        return self._run.info()

    def wait_finished(self, timeout_s: float | None = None) -> bool:
        """Wait until the current stream (if any) has ended on the host side."""
        return self._run.finished.wait(timeout_s)

    def start(self, request: StreamStartRequest, *, max_rows: int | None = None) -> StreamResponse:
        """Start a stream and return at once (``frames = 0``: until ``stop``). ``max_rows``:
        the most window rows a frame of this stream may have, if the window may grow while it
        runs (a scan's line-period loop): the reader's slots are sized for it."""
        request = check_request(request, self.device.config.daemon, stare=False)
        self._start(request, kind="stream", max_rows=max_rows)
        return self._run.response()

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
        request = check_request(request, self.device.config.daemon, stare=True)
        self._start(request, start, consumer, kind="stare")
        run = self._run
        period_s = run.frame_period_s
        timeout_s = request.timeout_s or 2 * request.frames * period_s + 10.0
        if not run.finished.wait(timeout_s):
            self.stop()
            raise DeviceTimeout(
                f"the camera did not finish {request.frames} frames within {timeout_s:.1f} s "
                f"(frame period {period_s * 1e3:.3f} ms); the stream was stopped. Check "
                "`camctl stream --status` and `camctl events`"
            )
        run.announced.wait(ANNOUNCE_TIMEOUT_S)
        run.raise_if_short()
        return run.response()

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
            self._reader.open()

    def allowed_record(self, record: str) -> Path:
        """The file a client's ``record`` names, resolved and confined to the data directory
        and ``daemon.record_dirs`` (a relative one in the recordings folder); BadRequest
        otherwise (``camd.daemon.output_paths``)."""
        return resolve_record(record, self.device.config.daemon)

    def stop(self) -> StreamResponse:
        """STOP_STREAM, then drain the reader; harmless when not streaming."""
        self.device.require(Request.STREAM_STOP)
        values = self.device.request("STOP_STREAM").values
        self._run.finish(
            int(values["next_counter"]), int(values["frames_sent"]), "stopped", on_request=True
        )
        return self._run.response()

    # -- plan, then apply -------------------------------------------------------------------------

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
        slot = self.device.acquisition
        with self._start_lock:
            owner = slot.applying_now()
            claimed = None
            if owner is None:
                claimed = slot.claim(kind, claim_description(request))
            acquisition = owner or claimed
            assert acquisition is not None
            with self._lock:
                self._run.claimed = claimed  # before the start: its STREAM_DONE may come at once
            try:
                with slot.applying(acquisition):
                    self.preflight("start a stream")
                    background = self.background.ready() if self.background is not None else None
                    plan = plan_stream(
                        request,
                        self._context(background, binned=request.binning == "2x2"),
                        start=start,
                        max_rows=max_rows,
                    )
                    self._apply(plan, consumer, background)
            except BaseException:
                with self._lock:
                    self._run.claimed = None
                if claimed is not None:
                    slot.abandon(claimed)
                raise

    def _context(self, background: Background | None, *, binned: bool = False) -> StreamContext:
        """What the plan is made against: the camera's mode and window now."""
        timing = self.sensor.timing()
        if self._on_timing is not None:
            self._on_timing(timing, binned)
        return StreamContext(
            mode=self.device.mode,
            window_rows=timing.window_rows,
            columns=self.sensor.window_columns(),
            background_bytes=0 if background is None else background.pixels.nbytes,
        )

    def _apply(
        self, plan: StreamPlan, consumer: Consumer | None, background: Background | None
    ) -> None:
        """The mode, then the stream; a stream that does not start puts the mode back."""
        device = self.device
        with Apply("stream start", self._events, source="stream") as apply:
            if plan.mode_change is not None:
                before, mode = plan.mode_change
                apply.step(
                    lambda: device.set_mode(mode),
                    lambda: device.set_mode(before),
                    f"mode {before}",
                )
            self._run.settled.clear()
            try:
                self._start_stream(plan, consumer, background)
            except (DeviceTimeout, Disconnected) as exc:
                if exc.link_wait is not None:  # the command link failed, not the USB reader
                    # Only the answer may have been lost: the camera may be streaming to
                    # nobody. STOP_STREAM is harmless when it is not (sent once it answers).
                    apply.undo_later(lambda: device.request("STOP_STREAM"), "stream stopped")
                raise
            finally:
                self._run.settled.set()
            apply.done()

    def _start_stream(
        self, plan: StreamPlan, consumer: Consumer | None, background: Background | None
    ) -> None:
        """The recording made, the reader started, then the camera asked to stream; what was
        begun for a stream the camera does not start is undone (its file removed)."""
        request, start, run = plan.request, plan.start, self._run
        with self._lock:
            reader = self._reader.open()
        recorder = None
        if plan.record is not None:
            metadata = self._metadata(plan)
            compression = self.device.config.store.compression_for(
                request.compression, request.compression_level
            )
            recorder = self._recording.create(
                plan.record, request.frames, metadata, compression, background
            )
        try:
            run.begin(reader, recorder, consumer, plan.max_frame_bytes)
            if start is None:
                values = self.device.request(
                    "START_STREAM", frames=request.frames, stages=plan.stages,
                    binning=request.binning,
                ).values  # fmt: skip
            else:
                values = self.device.request(start.command, **start.fields).values
        except Exception:
            run.abandon(reader)
            if plan.record is not None:
                plan.record.unlink(missing_ok=True)  # nothing was recorded: leave no file
            raise
        reader.expect_first(int(values["first_counter"]))
        if plan.record is not None and background is not None:
            assert self.background is not None
            self.background.note_saved(background, str(plan.record))
        info = self._stream_info(plan, values)
        run.started(info)
        what = "until stopped" if request.frames == 0 else f"{info['frames_requested']} frames"
        how = f"{info['mode']} stream" if start is None else start.command
        self.device.fire(Trigger.STREAM_STARTED, f"{how}, {what}")

    def _stream_info(self, plan: StreamPlan, values: dict[str, Any]) -> dict[str, Any]:
        """The stream's geometry and counts, from the camera's answer to its start."""
        if plan.start is None:
            return {
                "mode": str(values["mode"]),
                "rows": int(values["rows"]),
                "cols": int(values["cols"]),
                "bits": int(values["bits"]),
                "stages": plan.stages,
                "binning": plan.request.binning,
                "frame_period_s": float(values["frame_period_s"]),
                "frames_requested": plan.request.frames,
                "first_counter": int(values["first_counter"]),
                "frames_sent": None,
            }
        # The command's own answer says how many frames come (and their geometry); the frames
        # are plain area-mode frames of the sensor's full word.
        return {
            "mode": "area",
            "rows": int(values["rows"]),
            "cols": int(values["cols"]),
            "bits": self.sensor.regmap.output.word_bits,
            "stages": 0,
            "binning": "off",
            "frame_period_s": plan.start.frame_period_s,
            "frames_requested": int(values["frames"]),
            "first_counter": int(values["first_counter"]),
            "frames_sent": None,
        }

    def _metadata(self, plan: StreamPlan) -> dict[str, dict[str, Any]]:
        """A recording's metadata: the camera's profile, registers and timing, the stream."""
        sensor, request = self.sensor, plan.request
        stream: dict[str, Any] = {
            "frames_requested": request.frames,
            "stages": plan.stages,
            "binning": request.binning,
        }
        if plan.start is not None:
            stream.update({"start_command": plan.start.command, **plan.start.metadata})
        return {
            "profile": sensor.profile_metadata(),
            "registers": sensor.register_values(),
            "timing": sensor.timing().model_dump(),
            "stream": stream,
            **self.device.file_context(),  # the scene, the campaign step (camd.store.nexus)
        }

    def _recording_failed(self, cause: str) -> None:
        """A frame could not be written (``StreamRecording``): stop the stream, not from the
        reader's dispatch thread (which stopping joins); the daemon goes on serving."""
        # Not under the lock: this runs on the dispatcher, which finishing joins holding it.
        self._run.stop_cause = cause
        generation = self._run.generation  # the stream whose frame could not be written
        threading.Thread(
            target=self.stop_stream_of,
            args=(generation,),
            name="camd-recording-failed",
            daemon=True,
        ).start()

    def stop_stream_of(self, generation: int) -> bool:
        """Stop the stream ``generation`` (``StreamRun.generation``) if it still runs; True if
        this stopped it. A stop decided for one stream, run late on a busy host, must not stop
        the next one: under the start lock no stream starts between the check and the stop."""
        with self._start_lock:
            if not (self.streaming and self._run.generation == generation):
                return False
            try:
                self.stop()
            except SessionError as exc:
                self.device.log_event("warning", "stream", f"could not stop the stream: {exc}")
                return False
            return True

    def _events(self, level: str, source: str, message: str) -> None:
        self.device.log_event(level, source, message)
