"""Push-broom scans: the stream in TDI mode, every frame through the TDI engine, lines to HDF5.

``ScanService`` belongs to a DeviceSession. A scan (docs/scan.md):

1. sets the scene (simulated camera), TDI mode, and the timing: from a stage speed or a line
   period, ``T_line,TDI = p / v_image`` and the window that fits it (physics.md §2 eqs 5-9, 13:
   window rows = n_lines, back path, exposure at most n_lines - 1 rows, eq 3), written to the
   sensor's registers, then read back;
   the scan stage (``camd.daemon.motion_service.ScanMotion``, docs/motion.md) is brought to the
   synchronous speed for that line period, with room for the scan ahead of it, and held there
   by the closed loop while the scan runs;
2. starts the stream with ``lines + M - 1`` frames and a consumer that copies each frame into
   a batch (on the stream's dispatcher thread: no per-frame thread hand-off), with the lost-frame
   count and stage changes as markers between batches;
3. a worker thread runs each batch through ``camd.tdi.TdiEngine.push_many`` and appends the lines
   to the HDF5 file (``camd.store.tdi_recording``);
4. when the stream ends, the last batch is flushed, the file gets its counters and a PNG
   quicklook is written beside it.

Each frame header carries the stage encoder count latched at the frame's start; the worker turns
them into the M dV/V each line saw (``camd.timing.line_mismatch``), records it with the line and
checks it against the yellow/red limits of config ``[motion]``.

A stage change (``set_stages``) takes effect at the next frame the consumer sees, without
stopping the stream: the engine starts a new run there, so the next M - 1 lines are incomplete.
"""

from __future__ import annotations

import datetime as dt
import logging
import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import h5py
import numpy as np
import numpy.typing as npt

from camd.daemon.models import (
    ScanMotionInfo,
    ScanRequest,
    ScanResponse,
    ScanTiming,
    StreamStartRequest,
    TimingResponse,
)
from camd.daemon.motion_service import ScanMotion
from camd.daemon.state import Request
from camd.link.frame_stream import ReceivedFrame
from camd.motion.closed_loop import LinePeriodSetting
from camd.store.quicklook import write_quicklook_png
from camd.store.recording import RecordingError
from camd.store.tdi_recording import TdiRecorder
from camd.tdi import TdiEngine, stage_taps
from camd.timing import (
    line_mismatch,
    synchronous_stage_speed_m_s,
    tdi_line_period_s,
    tdi_window,
    velocity_mismatch,
)

if TYPE_CHECKING:
    from camd.daemon.session import DeviceSession

log = logging.getLogger(__name__)

BATCH_BYTES = 16 << 20  # frames per batch: about this many bytes, so one push_many amortises
MAX_BATCH_FRAMES = 512
BATCH_BUFFERS = 4  # batches in flight between the consumer and the worker
BATCH_MAX_AGE_S = 0.1  # a partial batch older than this goes to the engine (progress, latency)
CONSUMER_WAIT_S = 5.0  # longest the consumer waits for a free batch before giving up a frame
FINISH_TIMEOUT_S = 60.0
QUICKLOOK_MAX_LINES = 8192
STREAM_END_MARGIN_S = 2.0  # stage travel planned beyond the frames' own duration
DRIVEN_MISMATCH_MAX = 0.5  # |dv_over_v| a driven stage takes (0.5 .. 1.5 x synchronous)


@dataclass
class _Progress:
    """What the worker has done (read by status requests; plain ints, written by one thread)."""

    lines: int = 0
    complete_lines: int = 0
    frames_in: int = 0
    gap_frames: int = 0  # frames the stream lost, corrupted or overran inside the scan
    tdi_cpu_s: float = 0.0
    stage_changes: list[tuple[int, int]] = field(default_factory=list)
    mismatch_max: float | None = None  # of |M dV/V| over the lines so far
    mismatch_sum_sq: float = 0.0
    mismatch_count: int = 0
    mismatch_level: str = "ok"  # the worst level reached
    mismatch_now: str = "ok"  # the level of the last batch (events on changes)
    mismatch_last: float | None = None  # the last batch's largest |M dV/V|


class _Batcher:
    """The stream consumer: copies frames into batches and queues them for the worker."""

    def __init__(self, rows: int, cols: int, work: queue.Queue[tuple[str, Any]]) -> None:
        # Frames may have more rows than ``rows`` (the line period trimmed by window rows): the
        # engine uses the first ``rows``.
        self.rows, self.cols = rows, cols
        self.batch_frames = max(1, min(MAX_BATCH_FRAMES, BATCH_BYTES // (2 * rows * cols)))
        self._free: queue.Queue[npt.NDArray[np.uint16]] = queue.Queue()
        for _ in range(BATCH_BUFFERS):
            self._free.put(np.empty((self.batch_frames, rows, cols), dtype=np.uint16))
        self._work = work
        self._lock = threading.Lock()
        self._buf: npt.NDArray[np.uint16] | None = None
        self._counters = np.zeros(self.batch_frames, dtype=np.uint32)
        self._encoder = np.zeros(self.batch_frames, dtype=np.int32)
        self._n = 0
        self._since = 0.0
        self.pending_stages: int | None = None
        self.frames = 0
        self.dropped = 0

    def recycle(self, buf: npt.NDArray[np.uint16]) -> None:
        self._free.put(buf)

    def __call__(self, frame: ReceivedFrame) -> None:
        with self._lock:
            if frame.gap_before:
                self._flush()
                self._work.put(("gap", int(frame.gap_before)))
            if self.pending_stages is not None:
                self._flush()
                self._work.put(("stages", self.pending_stages))
                self.pending_stages = None
            pixels = frame.pixels
            if pixels.shape[0] < self.rows or pixels.shape[1] != self.cols:
                # Not this scan's geometry: the engine cannot use it; the line is lost.
                self._flush()
                self._work.put(("gap", 1))
                self.dropped += 1
                return
            if self._buf is None:
                try:
                    self._buf = self._free.get(timeout=CONSUMER_WAIT_S)
                except queue.Empty:
                    self._flush()
                    self._work.put(("gap", 1))
                    self.dropped += 1
                    return
                self._since = time.monotonic()
            self._buf[self._n] = pixels[: self.rows]
            self._counters[self._n] = frame.header.counter
            self._encoder[self._n] = frame.header.stage_position
            self._n += 1
            self.frames += 1
            if self._n == self.batch_frames or time.monotonic() - self._since > BATCH_MAX_AGE_S:
                self._flush()

    def flush(self) -> None:
        with self._lock:
            self._flush()

    def _flush(self) -> None:
        if self._buf is None or self._n == 0:
            return
        n = self._n
        batch = (self._buf, n, self._counters[:n].copy(), self._encoder[:n].copy())
        self._work.put(("batch", batch))
        self._buf, self._n = None, 0


class _Scan:
    """One scan: its engine, file, batcher, worker and counters."""

    def __init__(
        self,
        request: ScanRequest,
        path: Path,
        engine: TdiEngine,
        recorder: TdiRecorder,
        timing: ScanTiming,
        frames_requested: int,
    ) -> None:
        self.request = request
        self.path = path
        self.engine = engine
        self.recorder = recorder
        self.timing = timing
        self.frames_requested = frames_requested
        self.state = "starting"
        self.error: str | None = None
        self.quicklook: Path | None = None
        self.progress = _Progress(stage_changes=[(0, request.stages)])
        self.work: queue.Queue[tuple[str, Any]] = queue.Queue()
        self.batcher: _Batcher | None = None
        self.started_mono = time.monotonic()
        self.started_cpu = time.process_time()
        self.ended_mono: float | None = None
        self.ended_cpu: float | None = None
        self.worker: threading.Thread | None = None
        self.finisher: threading.Thread | None = None
        self.done = threading.Event()
        self.stop_requested = False
        self.motion: ScanMotion | None = None
        self.counts_per_pixel: float | None = None  # encoder counts per image pitch
        self.carry = (np.zeros(0, np.int64), np.zeros(0, np.float64))  # counters, encoder
        self.red_stop = False


class ScanService:
    """Start, watch, re-stage and stop push-broom scans."""

    def __init__(self, session: DeviceSession) -> None:
        self.session = session
        self._lock = threading.Lock()
        self._scan: _Scan | None = None

    def mismatch_gauges(self) -> dict[str, float]:
        """The current (or last) scan's M |dV/V| for the metrics: last batch, max, RMS."""
        scan = self._scan
        if scan is None:
            return {}
        progress = scan.progress
        values = {
            "last": progress.mismatch_last,
            "max": progress.mismatch_max,
            "rms": self._mismatch_rms(scan),
        }
        return {k: v for k, v in values.items() if v is not None}

    # -- requests -----------------------------------------------------------------------------

    def status(self) -> ScanResponse:
        """The current or last scan (state "none" before the first)."""
        return self._response(self._scan)

    def start(self, request: ScanRequest) -> ScanResponse:
        """Set up and start a scan; returns at once (``status`` shows its progress)."""
        from camd.daemon.session import BadRequest

        session = self.session
        session.require(Request.STREAM_START)
        if request.speed_m_s is not None and request.line_period_s is not None:
            raise BadRequest(
                "give either speed_m_s or line_period_s, not both: the line period follows "
                "from the stage speed (physics.md §2)"
            )
        if request.drive_stage and abs(request.dv_over_v) > DRIVEN_MISMATCH_MAX:
            raise BadRequest(
                f"dv_over_v = {request.dv_over_v:g} with the stage driven: it takes "
                f"-{DRIVEN_MISMATCH_MAX:g} .. {DRIVEN_MISMATCH_MAX:g} (the stage at 0.5 .. 1.5 "
                "times the synchronous speed); larger mismatches run on the simulator's ideal "
                "stage (drive_stage false)"
            )
        with self._lock:
            if self._scan is not None and not self._scan.done.is_set():
                raise BadRequest("a scan is running; stop it first (`camctl scan --stop`)")
        session.sensor.require_trained("start a scan")
        if request.scene is not None:
            if session.config.link.device != "sim":
                raise BadRequest("scene is for the simulated camera only; drop --scene")
            session.stream.set_scene(request.scene)
        binned = request.binning == "2x2"
        cols = session.sensor.window_columns() // (2 if binned else 1)

        def engine_for(n_lines: int) -> TdiEngine:
            return self._engine(request, request.stages, n_lines // 2 if binned else n_lines, cols)

        path = self._scan_path(request.out)
        frames = 0 if request.lines == 0 else request.lines + request.stages - 1
        self._check_motion(request, frames)  # before any register is written
        session.set_mode("tdi")
        timing = self._set_timing(request, engine_for)
        rows = timing.n_lines // 2 if binned else timing.n_lines
        engine = engine_for(timing.n_lines)
        motion = self._scan_motion(request, timing, frames)
        if motion is not None and motion.mode == "line_period":
            rows = engine.rows_needed  # the window's rows may change under the loop
        try:
            recorder = self._recorder(path, request, cols, timing, frames)
        except Exception:
            if motion is not None:
                motion.finish()
            raise
        scan = _Scan(request, path, engine, recorder, timing, frames)
        scan.motion = motion
        if motion is not None:
            pitch, scale = session.motion.optics(binned)
            scan.counts_per_pixel = session.motion.profile.encoder_counts_per_m * pitch / scale
        recorder.note_stage_change(0, request.stages)
        with self._lock:
            self._scan = scan
        try:
            self._start_stream(scan, rows, cols)
        except Exception as exc:
            if motion is not None:
                motion.finish()
            scan.state, scan.error = "failed", str(exc)
            scan.work.put(("end", None))
            if scan.worker is not None:
                scan.worker.join(FINISH_TIMEOUT_S)
            self._close_file(scan, "failed")
            path.unlink(missing_ok=True)  # nothing was recorded: leave no file
            scan.done.set()
            raise
        return self._response(scan)

    def stop(self) -> ScanResponse:
        """Stop the running scan (the stream drains first) and wait until its file is closed."""
        scan = self._scan
        if scan is None or scan.done.is_set():
            return self._response(scan)
        scan.stop_requested = True
        self.session.stream.stop()
        scan.done.wait(FINISH_TIMEOUT_S)
        return self._response(scan)

    def set_stages(self, stages: int) -> ScanResponse:
        """Change M from the next frame on, without stopping the stream."""
        from camd.daemon.session import BadRequest

        scan = self._scan
        if scan is None or scan.done.is_set() or scan.batcher is None:
            raise BadRequest("no scan is running; start one with `camctl scan`")
        req = scan.request
        if stages == scan.engine.stages and scan.batcher.pending_stages is None:
            return self._response(scan)
        taps = stage_taps(
            stages,
            scan.engine.width,
            rows_per_line=req.rows_per_line,
            cols_per_line=req.cols_per_line,
            reverse=req.reverse,
        )
        if taps.rows_needed > scan.batcher.rows:
            raise BadRequest(
                f"stages = {stages} needs {taps.rows_needed} window rows but the scan's frames "
                f"have {scan.batcher.rows} (physics.md §2 eq 13: M <= M0); choose "
                f"1..{self._max_stages(req, scan.engine.width, scan.batcher.rows)}"
            )
        scan.batcher.pending_stages = stages
        self.session.log_event("info", "scan", f"TDI stages -> {stages} from the next frame")
        return self._response(scan)

    def close(self) -> None:
        """Daemon shutdown: end a running scan and close its file."""
        scan = self._scan
        if scan is not None and not scan.done.is_set():
            if scan.motion is not None:
                scan.motion.finish()  # a stage must not run on without its daemon
            scan.work.put(("end", None))
            if scan.worker is not None:
                scan.worker.join(FINISH_TIMEOUT_S)
            self._close_file(scan, scan.state)
            scan.done.set()

    # -- setting up -----------------------------------------------------------------------------

    def _set_timing(
        self, request: ScanRequest, engine_for: Callable[[int], TdiEngine]
    ) -> ScanTiming:
        """Program the TDI line period a speed or period asks for; return what is set.
        ``engine_for(n_lines)`` refuses stages that would not fit, before any register is
        written."""
        from camd.daemon.session import BadRequest

        sensor = self.session.sensor
        pitch_m, magnification = self._optics(request)
        now = sensor.timing()
        period_s = request.line_period_s
        if request.speed_m_s is not None:
            period_s = tdi_line_period_s(pitch_m, magnification * request.speed_m_s)
        if period_s is not None:
            try:
                window = tdi_window(period_s, now.line_period_s)
            except ValueError as exc:
                raise BadRequest(str(exc)) from None
            engine_for(window.n_lines)  # BadRequest, with the registers untouched
            writes = self._window_writes(now, window.n_lines, window.back_path_s)
            if writes:
                sensor.write(writes)
            now = sensor.timing()
        sync = synchronous_stage_speed_m_s(pitch_m, now.tdi_line_period_s, magnification)
        speed = request.speed_m_s
        if request.drive_stage:
            # The stage runs at the synchronous speed of the line period the registers could
            # realise (whole clocks), offset by any deliberate mismatch asked for.
            speed = sync * (1.0 - request.dv_over_v)
        elif self.session.config.link.device == "sim":
            # The simulator's ideal stage, offset by the deliberate mismatch too: an exact
            # dV/V for MTF against mismatch (physics.md §6), beyond a real stage's range.
            speed = (sync if speed is None else speed) * (1.0 - request.dv_over_v)
            self.session.stream.set_stage(track=False, speed_m_s=speed)
        elif speed is None:
            self.session.log_event(
                "info", "scan", f"run the scan stage at {sync * 1e3:.6g} mm/s (synchronous)"
            )
        return ScanTiming(
            tdi_line_period_s=now.tdi_line_period_s,
            row_period_s=now.line_period_s,
            n_lines=now.window_rows,
            back_path_s=now.back_path_s,
            max_stages=now.max_stages,
            exposure_s=now.exposure_s,
            sync_speed_m_s=sync,
            stage_speed_m_s=speed,
            dv_over_v=None if speed is None else velocity_mismatch(sync, speed),
        )

    def _optics(self, request: ScanRequest) -> tuple[float, float]:
        """Pixel pitch (doubled when binned) and the image scale of the stage's travel: the
        stage profile's when the scan drives it, else the camera's magnification."""
        binned = request.binning == "2x2"
        if request.drive_stage:
            return self.session.motion.optics(binned)
        return self.session.motion.camera_optics(binned)

    def _check_motion(self, request: ScanRequest, frames: int) -> None:
        """Refuse a scan whose stage speed or travel is beyond the stage's limits, from the
        line period asked for (or the registers'), before anything is written."""
        if not request.drive_stage:
            return
        pitch_m, scale = self._optics(request)
        if request.speed_m_s is not None:
            speed = request.speed_m_s
            period = tdi_line_period_s(pitch_m, scale * speed)
        else:
            period = request.line_period_s or self.session.sensor.timing().tdi_line_period_s
            speed = synchronous_stage_speed_m_s(pitch_m, period, scale)
        speed *= 1.0 - request.dv_over_v
        duration = (frames or 60.0 / period) * period + STREAM_END_MARGIN_S
        self.session.motion.check_scan(speed, duration)

    def _scan_motion(
        self, request: ScanRequest, timing: ScanTiming, frames: int
    ) -> ScanMotion | None:
        """Bring the stage to speed for the scan (None: the scan does not drive it)."""
        if not request.drive_stage:
            return None
        service = self.session.motion
        assert timing.stage_speed_m_s is not None
        mode = service.loop_mode(request.closed_loop)
        pitch, _ = service.optics(request.binning == "2x2")
        motion = ScanMotion(
            service,
            speed_m_s=-timing.stage_speed_m_s if request.reverse else timing.stage_speed_m_s,
            mode=mode,
            pixel_pitch_m=pitch,
            row_time_s=timing.row_period_s,
            stages=request.stages * (2 if request.binning == "2x2" else 1),
            max_lines=timing.n_lines,
            offset=request.dv_over_v,
            apply_line_period=self._line_period_writer(timing),
        )
        # A scan "until stopped" plans for a minute of travel; the rail rewinds if needed.
        duration = (frames or 60.0 / timing.tdi_line_period_s) * timing.tdi_line_period_s
        motion.start(duration + STREAM_END_MARGIN_S)
        return motion

    def _line_period_writer(self, timing: ScanTiming) -> Callable[[LinePeriodSetting], None]:
        """The closed loop's hand on the line period: window rows and back path registers,
        written only when they change (physics.md §2 eqs 8-9)."""
        sensor = self.session.sensor
        clock_hz = sensor.regmap.timing.clock_hz
        last = [timing.n_lines, round(timing.back_path_s * clock_hz)]

        def apply(setting: LinePeriodSetting) -> None:
            clocks = round(setting.back_path_s * clock_hz)
            if [setting.n_lines, clocks] == last:
                return
            now = sensor.timing()
            writes = self._window_writes(now, setting.n_lines, setting.back_path_s)
            writes.pop(sensor.regmap.role("exposure_lines") or "", None)
            if writes:
                sensor.trim(writes)
            last[:] = [setting.n_lines, clocks]

        return apply

    def _window_writes(
        self, now: TimingResponse, n_lines: int, back_path_s: float
    ) -> dict[str, int | str]:
        """Register values for a window of ``n_lines`` rows, that back path, and an exposure
        that fits (eq 3: at most n_lines - 1 rows; kept if it already does)."""
        regmap = self.session.sensor.regmap
        writes: dict[str, int | str] = {}

        def put(role: str, count: int) -> None:
            name = regmap.role(role)
            if name is None:
                return
            _, spec = regmap.resolve(name)
            writes[name] = count - (spec.bias if spec is not None else 0)

        if n_lines != now.window_rows:
            put("window_rows", n_lines)
        clocks = round(back_path_s * regmap.timing.clock_hz)
        if regmap.role("back_path") is not None:
            put("back_path", clocks)
        elif clocks:
            self.session.log_event(
                "warning",
                "scan",
                f"sensor {regmap.sensor} has no back-path register: the line period is "
                f"{n_lines} rows, {back_path_s * 1e6:.3f} us short of the one asked for",
            )
        if now.exposure_lines > max(1, n_lines - 1):
            put("exposure_lines", max(1, n_lines - 1))
        return writes

    def _max_stages(self, request: ScanRequest, width: int, rows: int) -> int:
        """The most stages whose taps fit ``rows`` rows."""
        best = 0
        for stages in range(1, rows + 1):
            taps = stage_taps(
                stages,
                width,
                rows_per_line=request.rows_per_line,
                cols_per_line=request.cols_per_line,
                reverse=request.reverse,
            )
            if taps.rows_needed > rows:
                break
            best = stages
        return best

    def _engine(self, request: ScanRequest, stages: int, rows: int, cols: int) -> TdiEngine:
        from camd.daemon.session import BadRequest

        try:
            engine = TdiEngine(
                stages,
                cols,
                mode=request.mode,
                out_bits=request.out_bits,
                rows_per_line=request.rows_per_line,
                cols_per_line=request.cols_per_line,
                reverse=request.reverse,
            )
        except ValueError as exc:
            raise BadRequest(str(exc)) from None
        # Load (or compile) the kernel now: doing it on the worker thread mid-stream would hold
        # the GIL for a second or more and starve the USB reader.
        TdiEngine(stages, cols, mode=request.mode, rows_per_line=request.rows_per_line,
                  cols_per_line=request.cols_per_line, reverse=request.reverse,
                  ).push_many(np.zeros((2, engine.rows_needed, cols), dtype=np.uint16))  # fmt: skip
        if engine.rows_needed > rows:
            raise BadRequest(
                f"stages = {stages} needs {engine.rows_needed} window rows but the scan's frames "
                f"have {rows} (physics.md §2 eq 13: M <= M0 = n_lines); choose "
                f"1..{self._max_stages(request, cols, rows)} stages, or slow the stage (a longer "
                "line period holds more rows)"
            )
        return engine

    def _scan_path(self, out: str | None) -> Path:
        from camd.daemon.session import BadRequest

        if out is None:
            stamp = dt.datetime.now(dt.UTC).strftime("%Y%m%dT%H%M%S.%fZ")
            folder = self.session.config.daemon.data_dir / "scans"
            folder.mkdir(parents=True, exist_ok=True)
            return folder / f"scan-{stamp}.h5"
        path = Path(out)
        if not path.is_absolute():
            raise BadRequest(f"out path {out!r} is relative; give an absolute path (camctl does)")
        if path.exists():
            raise BadRequest(f"{path} already exists; choose another file or remove it")
        return path

    def _recorder(
        self, path: Path, request: ScanRequest, cols: int, timing: ScanTiming, frames: int
    ) -> TdiRecorder:
        from camd.daemon.session import BadRequest

        sensor = self.session.sensor
        scan_meta = request.model_dump(exclude={"out"})
        scan_meta.update(frames_requested=frames, width=cols)
        try:
            return TdiRecorder(
                path,
                width=cols,
                mode=request.mode,
                metadata={
                    "profile": sensor.profile_metadata(),
                    "registers": sensor.register_values(),
                    "timing": timing.model_dump(),
                    "scan": scan_meta,
                },
            )
        except (RecordingError, ValueError) as exc:
            raise BadRequest(str(exc)) from None

    def _start_stream(self, scan: _Scan, rows: int, cols: int) -> None:
        stream = self.session.stream
        scan.batcher = _Batcher(rows, cols, scan.work)
        scan.worker = threading.Thread(
            target=self._work, args=(scan,), name="camd-tdi-worker", daemon=True
        )
        scan.worker.start()
        stream.add_consumer(scan.batcher)
        try:
            info = stream.start(
                StreamStartRequest(
                    frames=scan.frames_requested,
                    stages=scan.request.stages,
                    binning=scan.request.binning,
                )
            )
        except Exception:
            stream.remove_consumer(scan.batcher)
            raise
        # The line-period loop may already have changed the window's rows: more than the
        # engine needs is fine (it uses the first ``rows``).
        trimmed = scan.motion is not None and scan.motion.mode == "line_period"
        if info.cols != cols or (info.rows < rows if trimmed else info.rows != rows):
            stream.remove_consumer(scan.batcher)
            stream.stop()
            raise RuntimeError(
                f"the camera streams {info.rows} x {info.cols} frames, not the {rows} x {cols} "
                "the registers set; check `camctl timing` and the window registers"
            )
        scan.state = "running"
        scan.started_mono, scan.started_cpu = time.monotonic(), time.process_time()
        what = "until stopped" if scan.request.lines == 0 else f"{scan.request.lines} lines"
        self.session.log_event(
            "info", "scan", f"scan started: M = {scan.request.stages}, {what}, file {scan.path}"
        )
        scan.finisher = threading.Thread(
            target=self._finish, args=(scan,), name="camd-scan-finish", daemon=True
        )
        scan.finisher.start()

    # -- running --------------------------------------------------------------------------------

    def _work(self, scan: _Scan) -> None:
        """The TDI worker: batches through the engine, lines to the file."""
        start_cpu = time.thread_time()
        progress = scan.progress
        try:
            while True:
                kind, payload = scan.work.get()
                if kind == "end":
                    break
                if scan.state == "failed":
                    continue  # drain; the file is closed by the finisher
                if kind == "gap":
                    scan.engine.gap(int(payload))
                    progress.gap_frames += int(payload)
                elif kind == "stages":
                    scan.engine.stages = int(payload)
                    index = scan.engine.next_index
                    scan.recorder.note_stage_change(index, int(payload))
                    progress.stage_changes.append((index, int(payload)))
                else:
                    buf, n, counters, encoder = payload
                    block = scan.engine.push_many(buf[:n])
                    assert scan.batcher is not None
                    scan.batcher.recycle(buf)
                    mismatch = self._mismatch(scan, counters, encoder, block.complete)
                    scan.recorder.append(
                        block.data,
                        index=block.index,
                        stages_used=block.stages_used,
                        complete=block.complete,
                        frame_counter=counters,
                        stage_position=encoder,
                        m_dv_over_v=mismatch,
                    )
                    progress.frames_in += n
                    progress.lines += n
                    progress.complete_lines += int(block.complete.sum())
                progress.tdi_cpu_s = time.thread_time() - start_cpu
        except Exception as exc:  # a full disk, a bad frame: stop the scan, keep what is there
            log.exception("TDI worker failed")
            scan.state, scan.error = "failed", f"TDI worker: {exc}"
            self.session.log_event("error", "scan", f"scan failed: {exc}; stopping the stream")
            threading.Thread(target=self._stop_quietly, daemon=True).start()
        progress.tdi_cpu_s = time.thread_time() - start_cpu

    def _mismatch(
        self,
        scan: _Scan,
        counters: npt.NDArray[np.uint32],
        encoder: npt.NDArray[np.int32],
        complete: npt.NDArray[np.bool_],
    ) -> npt.NDArray[np.float64] | None:
        """The smear of each line of a batch (M dV/V for complete lines) from the encoder
        counts, the previous batch's last M frames carried over; the scan's statistics and
        the limit check (config ``[motion]``) take the complete lines."""
        per_pixel = scan.counts_per_pixel
        if per_pixel is None:
            return None
        m = scan.engine.stages
        # Counters wrap at 2^32: unwrap against the carried frames.
        carry_c, carry_e = scan.carry
        base = int(carry_c[-1]) if carry_c.size else int(counters[0])
        unwrapped = base + ((counters.astype(np.int64) - base) % (1 << 32))
        all_c = np.concatenate([carry_c, unwrapped])
        all_e = np.concatenate([carry_e, encoder.astype(np.float64)])
        values = line_mismatch(all_e, all_c, stages=m, counts_per_pixel=per_pixel)
        result = values[carry_c.size :]
        scan.carry = (all_c[-m:], all_e[-m:])
        finite = np.abs(result[np.isfinite(result) & complete])
        if finite.size:
            self._note_mismatch(scan, finite)
        return result

    def _note_mismatch(self, scan: _Scan, magnitude: npt.NDArray[np.float64]) -> None:
        progress = scan.progress
        worst = float(magnitude.max())
        progress.mismatch_last = worst
        progress.mismatch_max = max(worst, progress.mismatch_max or 0.0)
        progress.mismatch_sum_sq += float(np.square(magnitude).sum())
        progress.mismatch_count += int(magnitude.size)
        config = self.session.config.motion
        level = "red" if worst >= config.red else "yellow" if worst >= config.yellow else "ok"
        order = ("ok", "yellow", "red")
        if order.index(level) > order.index(progress.mismatch_level):
            progress.mismatch_level = level
        if level != progress.mismatch_now:
            progress.mismatch_now = level
            self.session.log_event(
                {"ok": "info", "yellow": "warning", "red": "error"}[level],
                "motion",
                f"scan velocity mismatch {level}: M |dV/V| up to {worst:.3g} pixels "
                f"(limits {config.yellow:g} / {config.red:g})",
            )
        if level == "red" and config.stop_on_red and not scan.red_stop:
            scan.red_stop = True
            scan.stop_requested = True
            threading.Thread(target=self._stop_quietly, daemon=True).start()

    def _stop_quietly(self) -> None:
        try:
            self.session.stream.stop()
        except Exception as exc:  # the stream may already have ended
            log.info("stopping the stream after a scan failure: %s", exc)

    def _finish(self, scan: _Scan) -> None:
        """Wait for the stream to end, then flush the engine, close the file, write the PNG."""
        stream = self.session.stream
        stream.wait_finished()
        if scan.done.is_set():
            return  # the daemon is shutting down and ``close`` has ended the scan
        assert scan.batcher is not None
        stream.remove_consumer(scan.batcher)
        scan.batcher.flush()
        scan.work.put(("end", None))
        if scan.worker is not None:
            scan.worker.join(FINISH_TIMEOUT_S)
        scan.ended_mono, scan.ended_cpu = time.monotonic(), time.process_time()
        if scan.motion is not None:
            scan.motion.finish()
        final = "stopped" if scan.stop_requested else "done"
        if scan.state == "failed":
            final = "failed"
        self._close_file(scan, final)
        stats = stream.stats()
        self.session.log_event(
            "info" if scan.state != "failed" and stats.lost == 0 else "warning",
            "scan",
            f"scan {final if scan.state != 'failed' else 'failed'}: {scan.progress.lines} lines "
            f"({scan.progress.complete_lines} complete), {stats.lost} frames lost, "
            f"{stats.overruns} overruns; {scan.path}",
        )
        # Only now, and together: a client that sees the scan ended may start the next at once.
        with self._lock:
            if scan.state != "failed":
                scan.state = final
            scan.done.set()

    def _close_file(self, scan: _Scan, state: str) -> None:
        stats = self.session.stream.stats().model_dump()
        progress = scan.progress
        motion = self._motion_info(scan)
        datasets = {}
        attributes: dict[str, Any] = {
            "counters": {
                **stats,
                "lines": progress.lines,
                "complete_lines": progress.complete_lines,
                "dropped_frames": scan.batcher.dropped if scan.batcher else 0,
                "tdi_cpu_s": progress.tdi_cpu_s,
            },
            "state": state,
            "error": scan.error or "",
        }
        if motion is not None:
            assert scan.motion is not None
            attributes["motion"] = {
                **motion.model_dump(),
                "mismatch_max": progress.mismatch_max,
                "mismatch_rms": self._mismatch_rms(scan),
                "mismatch_level": progress.mismatch_level,
                "yellow": self.session.config.motion.yellow,
                "red": self.session.config.motion.red,
                "counts_per_pixel": scan.counts_per_pixel,
            }
            if motion.loop_samples:
                datasets["motion_loop"] = scan.motion.record.arrays()
        try:
            scan.recorder.close(attributes, datasets)
        except Exception as exc:
            log.exception("closing %s", scan.path)
            scan.state, scan.error = "failed", f"closing {scan.path}: {exc}"
            return
        if scan.request.quicklook and progress.lines:
            try:
                scan.quicklook = self._quicklook(scan.path)
            except Exception as exc:  # the data are safe in the file; say so and go on
                self.session.log_event("warning", "scan", f"no quicklook for {scan.path}: {exc}")

    @staticmethod
    def _quicklook(path: Path) -> Path:
        with h5py.File(path, "r") as f:
            count = int(f["lines"].shape[0])
            step = max(1, -(-count // QUICKLOOK_MAX_LINES))
            lines = np.asarray(f["lines"][::step])
            complete = np.asarray(f["complete"][::step]).astype(bool)
        return write_quicklook_png(path.with_suffix(".png"), lines, complete=complete)

    # -- reporting ------------------------------------------------------------------------------

    @staticmethod
    def _mismatch_rms(scan: _Scan) -> float | None:
        p = scan.progress
        return (
            None if not p.mismatch_count else float(np.sqrt(p.mismatch_sum_sq / p.mismatch_count))
        )

    @staticmethod
    def _motion_info(scan: _Scan) -> ScanMotionInfo | None:
        motion = scan.motion
        if motion is None:
            return None
        return ScanMotionInfo(
            closed_loop=motion.mode,
            stage_speed_m_s=motion.speed_m_s,
            target_speed_m_s=motion.speed_m_s,
            loop_samples=len(motion.record.time_s),
            loop_error=motion.error,
            line_period_limited=motion.limited,
        )

    def _lost_frames(self, scan: _Scan) -> int:
        """Frames of the scan that never reached the engine: lost, corrupt, overrun or cut
        short on the way; once the stream has ended, by the device's own count."""
        if scan.done.is_set() or scan.ended_mono is not None:
            sent = self.session.stream.status_info().get("frames_sent")
            if sent is not None:
                return max(0, int(sent) - scan.progress.frames_in)
        return scan.progress.gap_frames

    def _response(self, scan: _Scan | None) -> ScanResponse:
        stream = self.session.stream.stats()
        if scan is None:
            return ScanResponse(
                state="none", file=None, quicklook=None, stages=0, lines_wanted=0,
                frames_requested=0, lines=0, complete_lines=0, lost_frames=0, stage_changes=[],
                mode="sum", width=0, elapsed_s=0.0, lines_per_s=0.0, cpu_load=0.0,
                tdi_cpu_s=0.0, backlog_frames=0, timing=None, error=None, stream=stream,
                mismatch_max=None, mismatch_rms=None, mismatch_level="ok", motion=None,
            )  # fmt: skip
        progress = scan.progress
        end_mono = scan.ended_mono if scan.ended_mono is not None else time.monotonic()
        end_cpu = scan.ended_cpu if scan.ended_cpu is not None else time.process_time()
        elapsed = max(end_mono - scan.started_mono, 1e-9)
        batched = scan.batcher.frames if scan.batcher is not None else 0
        return ScanResponse(
            state=scan.state,  # type: ignore[arg-type]
            file=str(scan.path),
            quicklook=None if scan.quicklook is None else str(scan.quicklook),
            stages=scan.engine.stages,
            lines_wanted=scan.request.lines,
            frames_requested=scan.frames_requested,
            lines=progress.lines,
            complete_lines=progress.complete_lines,
            lost_frames=self._lost_frames(scan),
            stage_changes=list(progress.stage_changes),
            mode=scan.request.mode,
            width=scan.engine.width,
            elapsed_s=elapsed,
            lines_per_s=progress.lines / elapsed,
            cpu_load=(end_cpu - scan.started_cpu) / elapsed,
            tdi_cpu_s=progress.tdi_cpu_s,
            backlog_frames=max(0, batched - progress.frames_in),
            timing=scan.timing,
            error=scan.error,
            stream=stream,
            mismatch_max=progress.mismatch_max,
            mismatch_rms=self._mismatch_rms(scan),
            mismatch_level=progress.mismatch_level,
            motion=self._motion_info(scan),
        )
