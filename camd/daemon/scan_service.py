"""Push-broom scans: the stream in TDI mode, every frame through the TDI engine, lines to HDF5.

``ScanService`` is handed the device access and the sensor, stream, motion and simulator
services. A scan (docs/scan.md):

1. claims the acquisition slot (one scan, stare or stream at a time), reads the registers and
   the stage once and plans the whole scan from them (``camd.daemon.scan_plan.plan_scan``: line
   period, window, register writes, synchronous speed, travel, file), refusing it before
   anything is changed; then applies the plan step by step (scene, TDI mode, registers, the
   simulator's ideal stage, the scan stage through ``camd.daemon.scan_motion.ScanMotion`` on
   the motion service's ``StageDrive``, the file), each step with its undo (``camd.daemon.transaction.Apply``): a failure puts back what
   was changed and says so;
2. starts the stream with ``lines + M - 1`` frames and the scan's acquisition pipeline
   (``camd.pipeline.TdiPipeline``): its consumer copies each frame into a batch on the stream's
   dispatcher thread, and its worker thread runs the batches through the TDI engine, works out
   each line's M dV/V from the encoder counts in the frame headers (checked against the
   yellow/red limits of config ``[motion]``) and appends the lines to the HDF5 file;
3. when the stream ends, the pipeline is finished, the file gets its counters and a PNG
   quicklook is written beside it.

A stage change (``set_stages``) takes effect at the next frame the consumer sees, without
stopping the stream: the engine starts a new run there, so the next M - 1 lines are incomplete.

With ``live_lines`` (the session's ``camd.pipeline.live.LiveLines``), each scan's lines also go
to the live view's waterfall: reset as the scan's stream starts, fed by the pipeline's worker,
ended with the scan's final state.
"""

from __future__ import annotations

import datetime as dt
import logging
import math
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from camd.daemon.acquisition import Acquisition
from camd.daemon.device import DeviceAccess
from camd.daemon.errors import BadRequest, DeviceRejected, SessionError
from camd.daemon.models import (
    ScanMotionInfo,
    ScanRequest,
    ScanResponse,
    ScanTiming,
    StreamStartRequest,
)
from camd.daemon.motion_service import MotionService
from camd.daemon.scan_motion import ScanMotion
from camd.daemon.scan_plan import (
    ScanContext,
    ScanPlan,
    StageContext,
    engine_for,
    max_stages,
    plan_scan,
    scan_path,
    window_writes,
)
from camd.daemon.sensor_service import RegisterSnapshot, SensorService
from camd.daemon.sim_control import SimulatorControl
from camd.daemon.stream_service import StreamService
from camd.daemon.transaction import Apply
from camd.motion.closed_loop import LinePeriodSetting
from camd.pipeline import TdiPipeline
from camd.pipeline.background import Background, BackgroundCapture
from camd.pipeline.live import LiveLines
from camd.store.journal import RecordingJournal, settle_failed_close
from camd.store.quicklook import write_quicklook_png
from camd.store.recording import RecordingError, check_new_file
from camd.store.tdi_recording import TdiRecorder
from camd.tdi import stage_taps

log = logging.getLogger(__name__)

FINISH_TIMEOUT_S = 60.0
SHUTDOWN_WAIT_S = 8.0  # at shutdown, how long the scan's finisher may take to end it
QUICKLOOK_MAX_LINES = 8192


class _Scan:
    """One scan: its request, pipeline, stage and state."""

    pipeline: TdiPipeline  # made by ``ScanService._apply`` once the scan exists

    def __init__(
        self,
        plan: ScanPlan,
        motion: ScanMotion | None,
        acquisition: Acquisition,
    ) -> None:
        self.request = plan.request
        self.path = plan.path
        self.timing = plan.timing
        self.frames_requested = plan.frames
        # The most window rows the line-period loop may set (None: no loop).
        self.max_rows = None if plan.stage is None else plan.stage.max_lines
        self.motion = motion
        self.acquisition = acquisition  # released once the file is closed
        self.state = "starting"
        self.error: str | None = None
        self.quicklook: Path | None = None
        self.started_mono = time.monotonic()
        self.started_cpu = time.process_time()
        self.ended_mono: float | None = None
        self.ended_cpu: float | None = None
        self.finisher: threading.Thread | None = None
        self.done = threading.Event()
        self.stop_requested = False
        # Frames asked for that the camera never sent (stopped, failed, ended early): set when
        # the scan's stream has ended (StreamService.frames_not_sent).
        self.not_sent_frames = 0


class ScanService:
    """Start, watch, re-stage and stop push-broom scans."""

    def __init__(
        self,
        device: DeviceAccess,
        sensor: SensorService,
        stream: StreamService,
        motion: MotionService,
        sim: SimulatorControl,
        *,
        background: BackgroundCapture | None = None,
        live_lines: LiveLines | None = None,
    ) -> None:
        self.device = device
        self.sensor = sensor
        self.stream = stream
        self.motion = motion
        self.sim = sim
        self.live_lines = live_lines  # the live view's waterfall (None: no live lines)
        # The live view's background: stored in every scan started while it is ready.
        self.background = background
        self._lock = threading.Lock()
        self._scan: _Scan | None = None

    def mismatch_gauges(self) -> dict[str, float]:
        """The current (or last) scan's M |dV/V| for the metrics: last batch, max, RMS."""
        scan = self._scan
        if scan is None:
            return {}
        progress = scan.pipeline.progress()
        values = {
            "last": progress.mismatch_last,
            "max": progress.mismatch_max,
            "rms": progress.mismatch_rms,
        }
        return {k: v for k, v in values.items() if v is not None}

    # -- requests -----------------------------------------------------------------------------

    def status(self) -> ScanResponse:
        """The current or last scan (state "none" before the first)."""
        return self._response(self._scan)

    def start(self, request: ScanRequest) -> ScanResponse:
        """Plan the scan whole, then apply it, and return at once (``status`` shows its
        progress). A refused scan changes nothing; a scan that fails while being applied puts
        back what it had changed and says so (``camd.daemon.transaction``)."""
        device = self.device
        what = "until stopped" if request.lines == 0 else f"{request.lines} lines"
        daemon = device.config.daemon
        path = scan_path(request.out, daemon.data_dir, dt.datetime.now(dt.UTC), daemon.record_dirs)
        slot = device.acquisition
        acquisition = slot.claim("scan", f"M = {request.stages}, {what} to {path}")
        try:
            with slot.applying(acquisition):
                # The camera first: a scan that will be refused must not have set the mode
                # or run the stage to find out.
                self.stream.preflight("start a scan")
                plan, snapshot, stage_position = self._plan(request, path)
                self._warm_engine(plan)
                # The file holds the lines and, if the live view has one, the background;
                # its recorder keeps a headroom besides.
                reserve = TdiRecorder.reserve_bytes(plan.columns, request.mode)
                background = self.background.ready() if self.background is not None else None
                extra = 0 if background is None else background.pixels.nbytes
                try:
                    check_new_file(plan.path, plan.planned_bytes + extra, reserve)
                except RecordingError as exc:
                    raise BadRequest(str(exc)) from None
                scan = self._apply(plan, snapshot, stage_position, acquisition)
        except BaseException:
            slot.abandon(acquisition)
            raise
        return self._response(scan)

    def stop(self) -> ScanResponse:
        """Stop the running scan (the stream drains first) and wait until its file is closed."""
        scan = self._scan
        if self.request_stop():
            assert scan is not None
            scan.done.wait(FINISH_TIMEOUT_S)
        return self._response(scan)

    def request_stop(self) -> bool:
        """Stop the running scan without waiting for its file (the emergency stop): it ends
        as "stopped". False if no scan is running."""
        scan = self._scan
        if scan is None or scan.done.is_set():
            return False
        scan.stop_requested = True
        self.stream.stop()
        return True

    def set_stages(self, stages: int) -> ScanResponse:
        """Change M from the next frame on, without stopping the stream."""
        scan = self._scan
        if scan is None or scan.done.is_set():
            raise BadRequest("no scan is running; start one with `camctl scan`")
        pipeline, req = scan.pipeline, scan.request
        if stages == pipeline.stages and pipeline.pending_stages is None:
            return self._response(scan)
        taps = stage_taps(
            stages,
            pipeline.width,
            rows_per_line=req.rows_per_line,
            cols_per_line=req.cols_per_line,
            reverse=req.reverse,
        )
        if taps.rows_needed > pipeline.rows:
            raise BadRequest(
                f"stages = {stages} needs {taps.rows_needed} window rows but the scan's frames "
                f"have {pipeline.rows} (docs/physics.md §2 eq 13: M <= M0); choose "
                f"1..{max_stages(req, pipeline.width, pipeline.rows)}"
            )
        pipeline.request_stages(stages)
        self.device.log_event("info", "scan", f"TDI stages -> {stages} from the next frame")
        return self._response(scan)

    def stopping(self) -> None:
        """Daemon shutdown, before the stream is ended: the running scan ends as stopped (not
        done), whichever of its finisher and ``close`` gets there first."""
        scan = self._scan
        if scan is not None and not scan.done.is_set():
            scan.stop_requested = True

    def close(self, timeout_s: float = SHUTDOWN_WAIT_S) -> None:
        """Daemon shutdown, after the stream was ended (``StreamService.shut_down``): the scan's
        finisher ends it as a stopped scan (the pipeline drained, the closed loop and the stage
        stopped, the file closed, the event with its line count), within ``timeout_s``; a scan
        it has not ended by then is ended here."""
        scan = self._scan
        if scan is None or scan.done.is_set():
            return
        scan.stop_requested = True
        finisher = scan.finisher
        if finisher is not None and finisher is not threading.current_thread():
            finisher.join(timeout_s)
        if not scan.done.is_set():
            self.device.log_event(
                "warning", "scan", f"the scan did not end within {timeout_s:g} s; closing it"
            )
            if scan.motion is not None:
                scan.motion.finish()  # a stage must not run on without its daemon
            scan.pipeline.finish(flush=False)
            scan.not_sent_frames = self.stream.frames_not_sent
            self._close_file(scan, scan.state)
            scan.done.set()
            self._live_end(scan.state)
            scan.pipeline.release()  # tens of MB of batch buffers: not left to the collector
        self.device.acquisition.release(scan.acquisition)

    # -- setting up -----------------------------------------------------------------------------

    def _plan(self, request: ScanRequest, path: Path) -> tuple[ScanPlan, RegisterSnapshot, float]:
        """Read what the plan needs (registers, stage), then plan: nothing is changed."""
        if request.scene is not None and not self.sim.available:
            raise BadRequest("scene is for the simulated camera only; drop --scene")
        snapshot = self.sensor.snapshot()
        stage: StageContext | None = None
        position = 0.0
        if request.drive_stage:
            stage = self.motion.stage_context(request.closed_loop)
            position = stage.position_m
        pitch, magnification = self.motion.camera_optics()
        context = ScanContext(
            timing=snapshot.timing(),
            preview=snapshot.preview,
            regmap=self.sensor.regmap,
            columns=snapshot.columns(),
            pixel_pitch_m=pitch,
            magnification=magnification,
            stage=stage,
            ideal_stage=self.sim.available and not request.drive_stage,
            path=path,
        )
        plan = plan_scan(request, context)
        if request.out is None:
            plan.path.parent.mkdir(parents=True, exist_ok=True)  # the daemon's own folder
        return plan, snapshot, position

    @staticmethod
    def _warm_engine(plan: ScanPlan) -> None:
        """Load (or compile) the TDI kernel now: doing it on the worker thread mid-stream would
        hold the GIL for a second or more and starve the USB reader."""
        engine = engine_for(plan.request, plan.request.stages, plan.columns)
        engine.push_many(np.zeros((2, engine.rows_needed, plan.columns), dtype=np.uint16))

    def _apply(
        self,
        plan: ScanPlan,
        snapshot: RegisterSnapshot,
        stage_position: float,
        acquisition: Acquisition,
    ) -> _Scan:
        """Change the camera as planned, step by step, and start the stream; on a failure the
        steps done so far are undone (newest first) and the error says what was restored."""
        request = plan.request
        device, sim, sensor = self.device, self.sim, self.sensor
        with Apply("scan start", self._events, source="scan") as apply:
            if request.scene is not None:
                scene, before = request.scene, sim.scene
                apply.step(
                    lambda: sim.set_scene(scene), lambda: sim.set_scene(before), f"scene {before}"
                )
            if device.mode != "tdi":
                mode = device.mode or "area"
                apply.step(
                    lambda: device.set_mode("tdi"), lambda: device.set_mode(mode), f"mode {mode}"
                )
            if plan.register_writes:
                changed = snapshot.changed(plan.register_writes)
                apply.step(
                    lambda: sensor.write(plan.register_writes),
                    lambda: sensor.restore(snapshot, changed),
                    "registers " + ", ".join(changed or list(plan.register_writes)),
                )
                self._check_timing(plan)
            if plan.ideal_stage_speed_m_s is not None:
                track, speed = sim.ideal_stage
                apply.step(
                    lambda: sim.set_ideal_stage(
                        track=False, speed_m_s=plan.ideal_stage_speed_m_s or 0
                    ),
                    lambda: sim.set_ideal_stage(track=track, speed_m_s=speed),
                    "the simulator's ideal stage",
                )
            motion = None
            if plan.stage is not None:
                motion = ScanMotion(
                    self.motion.scan_drive(),
                    plan.stage,
                    device.config.motion,
                    self._line_period_writer(plan.timing),
                )
                apply.undo_later(
                    lambda: motion.restore(stage_position),
                    f"stage stopped and back at {stage_position * 1e3:.3f} mm",
                )
                motion.start()
            background = self.background.ready() if self.background is not None else None
            recorder = self._recorder(plan, background)
            apply.undo_later(
                lambda: _discard(recorder, self.device.recordings), f"file {plan.path} removed"
            )
            scan = _Scan(plan, motion, acquisition)
            limits = device.config.motion
            scan.pipeline = TdiPipeline(
                engine_for(request, request.stages, plan.columns),
                recorder,
                rows=plan.rows,
                counts_per_pixel=None if plan.stage is None else plan.stage.counts_per_pixel,
                yellow_px=limits.yellow,
                red_px=limits.red,
                on_event=self._events,
                on_failure=lambda: self._worker_failed(scan),
                on_red=lambda: self._mismatch_red(scan),
                on_lines=None if self.live_lines is None else self.live_lines.append,
            )
            if self.live_lines is not None:
                self.live_lines.reset(plan.columns, scan=str(plan.path), lines_planned=plan.frames)
            self._start_stream(scan, plan.rows, plan.columns)
            if background is not None:
                assert self.background is not None
                self.background.note_saved(background, str(plan.path))
            with self._lock:
                self._scan = scan
            for note in plan.notes:
                device.log_event("info", "scan", note)
            apply.done()
        return scan

    def _events(self, level: str, source: str, message: str) -> None:
        self.device.log_event(level, source, message)

    def _check_timing(self, plan: ScanPlan) -> None:
        """The registers read back set the planned timing (else the plan is not what runs)."""
        now = self.sensor.timing()
        want = plan.timing
        if now.window_rows != want.n_lines or not math.isclose(
            now.tdi_line_period_s, want.tdi_line_period_s, rel_tol=1e-9
        ):
            raise DeviceRejected(
                f"the registers read back set a {now.window_rows}-row window and a "
                f"{now.tdi_line_period_s * 1e6:.3f} us line period, not the planned "
                f"{want.n_lines} rows and {want.tdi_line_period_s * 1e6:.3f} us; check "
                "`camctl timing` and the register map",
                "TIMING_MISMATCH",
            )

    def _line_period_writer(self, timing: ScanTiming) -> Callable[[LinePeriodSetting], None]:
        """The closed loop's hand on the line period: window rows and back path registers,
        written only when they change (docs/physics.md §2 eqs 8-9)."""
        sensor = self.sensor
        clock_hz = sensor.regmap.timing.clock_hz
        last = [timing.n_lines, round(timing.back_path_s * clock_hz)]

        def apply(setting: LinePeriodSetting) -> None:
            clocks = round(setting.back_path_s * clock_hz)
            if [setting.n_lines, clocks] == last:
                return
            now = sensor.timing()
            writes, _ = window_writes(sensor.regmap, now, setting.n_lines, setting.back_path_s)
            writes.pop(sensor.regmap.role("exposure_lines") or "", None)
            if writes:
                sensor.trim(writes)
            last[:] = [setting.n_lines, clocks]

        return apply

    def _recorder(self, plan: ScanPlan, background: Background | None = None) -> TdiRecorder:
        sensor = self.sensor
        request = plan.request
        scan_meta = request.model_dump(exclude={"out"})
        scan_meta.update(frames_requested=plan.frames, width=plan.columns)
        # On the journal before the file exists: a daemon killed at any point after leaves an
        # entry, and the next one repairs the file (or finds it was never made).
        journal = self.device.recordings
        try:
            journal.opened(plan.path, "scan")
        except OSError as exc:
            raise SessionError(
                f"cannot note the scan in {journal.folder}: {exc}; check the data directory"
            ) from None
        try:
            recorder = TdiRecorder(
                plan.path,
                width=plan.columns,
                mode=request.mode,
                metadata={
                    "profile": sensor.profile_metadata(),
                    "registers": sensor.register_values(),
                    "timing": plan.timing.model_dump(),
                    "scan": scan_meta,
                },
                background_dn=None if background is None else background.pixels,
                background_attrs=None if background is None else background.recording_attrs(),
            )
        except (RecordingError, ValueError) as exc:
            journal.closed(plan.path)  # no file was left (TdiRecorder removes what it began)
            raise BadRequest(str(exc)) from None
        return recorder

    def _start_stream(self, scan: _Scan, rows: int, cols: int) -> None:
        stream, pipeline = self.stream, scan.pipeline
        pipeline.start()
        stream.add_consumer(pipeline.consumer)
        try:
            # The line-period loop (started before the stream) changes the window's rows, up
            # to the plan's: the stream's frames may be as large as that from any frame on.
            trimmed = scan.motion is not None and scan.motion.mode == "line_period"
            info = stream.start(
                StreamStartRequest(
                    frames=scan.frames_requested,
                    stages=scan.request.stages,
                    binning=scan.request.binning,
                ),
                max_rows=scan.max_rows if trimmed else None,
            )
            # The loop may already have changed the window's rows: more than the engine needs
            # is fine (it uses the first ``rows``).
            if info.cols != cols or (info.rows < rows if trimmed else info.rows != rows):
                stream.stop()
                raise DeviceRejected(
                    f"the camera streams {info.rows} x {info.cols} frames, not the {rows} x "
                    f"{cols} the registers set; check `camctl timing` and the window registers",
                    "GEOMETRY_MISMATCH",
                )
        except BaseException:
            stream.remove_consumer(pipeline.consumer)
            scan.state = "failed"
            pipeline.abort(FINISH_TIMEOUT_S)
            self._live_end("failed")
            raise
        scan.state = "running"
        scan.started_mono, scan.started_cpu = time.monotonic(), time.process_time()
        what = "until stopped" if scan.request.lines == 0 else f"{scan.request.lines} lines"
        self.device.log_event(
            "info", "scan", f"scan started: M = {scan.request.stages}, {what}, file {scan.path}"
        )
        scan.finisher = threading.Thread(
            target=self._finish, args=(scan,), name="camd-scan-finish", daemon=True
        )
        scan.finisher.start()

    # -- running (the pipeline's callbacks, on its worker thread: they must not wait) -----------

    def _worker_failed(self, scan: _Scan) -> None:
        scan.state, scan.error = "failed", scan.pipeline.error
        threading.Thread(target=self._stop_quietly, name="camd-scan-stop", daemon=True).start()

    def _mismatch_red(self, scan: _Scan) -> None:
        if self.device.config.motion.stop_on_red:
            scan.stop_requested = True
            threading.Thread(target=self._stop_quietly, name="camd-scan-stop", daemon=True).start()

    def _stop_quietly(self) -> None:
        try:
            self.stream.stop()
        except Exception as exc:  # the stream may already have ended
            log.info("stopping the stream after a scan failure: %s", exc)

    # -- finishing ------------------------------------------------------------------------------

    def _finish(self, scan: _Scan) -> None:
        """Wait for the stream to end, then finish the pipeline, close the file, write the PNG."""
        stream = self.stream
        stream.wait_finished()
        if scan.done.is_set():
            return  # the daemon is shutting down and ``close`` has ended the scan
        stream.remove_consumer(scan.pipeline.consumer)
        scan.pipeline.finish(timeout_s=FINISH_TIMEOUT_S)
        scan.ended_mono, scan.ended_cpu = time.monotonic(), time.process_time()
        scan.not_sent_frames = stream.frames_not_sent  # this scan's stream has ended
        if scan.motion is not None:
            scan.motion.finish()
        final = "stopped" if scan.stop_requested else "done"
        broken, early = stream.broken, stream.ended_early
        if broken is not None and scan.state != "failed" and not scan.stop_requested:
            scan.state, scan.error = "failed", f"the stream ended early: {broken}"
        elif early is not None and scan.state != "failed" and not scan.stop_requested:
            # The camera ended the stream before the scan's frames were all sent: the file
            # holds the lines that came, and the scan is not done.
            final, scan.error = "ended_early", f"the stream ended early: {early}"
        if scan.state == "failed":
            final = "failed"
        self._close_file(scan, final)
        stats = stream.stats()
        progress = scan.pipeline.progress()
        not_sent = scan.not_sent_frames
        self.device.log_event(
            "info" if final == "done" and stats.lost == 0 else "warning",
            "scan",
            f"scan {final}: {progress.lines} lines ({progress.complete_lines} complete), "
            f"{stats.lost} frames lost, {not_sent} not sent, {stats.overruns} overruns; "
            f"{scan.path}" + (f"; {scan.error}" if final == "ended_early" else ""),
        )
        # Only now, and together: a client that sees the scan ended may start the next at once.
        with self._lock:
            if scan.state != "failed":
                scan.state = final
            scan.done.set()
        self._live_end(scan.state)
        scan.pipeline.release()  # tens of MB of batch buffers: not left to the collector
        self.device.acquisition.release(scan.acquisition)

    def _live_end(self, state: str) -> None:
        if self.live_lines is not None:
            self.live_lines.end(state)

    def _close_file(self, scan: _Scan, state: str) -> None:
        stats = self.stream.stats().model_dump()
        progress = scan.pipeline.progress()
        motion = self._motion_info(scan)
        datasets = {}
        attributes: dict[str, Any] = {
            "counters": {
                **stats,
                "not_sent_frames": scan.not_sent_frames,
                "lines": progress.lines,
                "complete_lines": progress.complete_lines,
                "dropped_frames": progress.dropped_frames,
                "tdi_cpu_s": progress.tdi_cpu_s,
            },
            "state": state,
            "error": scan.error or "",
        }
        if motion is not None:
            assert scan.motion is not None
            limits = self.device.config.motion
            attributes["motion"] = {
                **motion.model_dump(),
                "mismatch_max": progress.mismatch_max,
                "mismatch_rms": progress.mismatch_rms,
                "mismatch_level": progress.mismatch_level,
                "yellow": limits.yellow,
                "red": limits.red,
                "counts_per_pixel": scan.pipeline.counts_per_pixel,
            }
            if motion.loop_samples:
                datasets["motion_loop"] = scan.motion.record.arrays()
        try:
            scan.pipeline.recorder.close(attributes, datasets)
        except Exception as exc:
            log.exception("closing %s", scan.path)
            scan.state, scan.error = "failed", f"closing {scan.path}: {exc}"
            # Repaired now if it can be, else the journal keeps it for the next start.
            settle_failed_close(
                scan.path, exc, "scan", self.device.recordings, self.device.log_event, "scan"
            )
            return
        self.device.recordings.closed(scan.path)
        if scan.request.quicklook and progress.lines:
            try:
                scan.quicklook = self._quicklook(scan.path)
            except Exception as exc:  # the data are safe in the file; say so and go on
                self.device.log_event("warning", "scan", f"no quicklook for {scan.path}: {exc}")

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

    def _lost_frames(self, scan: _Scan, frames_in: int, gap_frames: int) -> int:
        """Frames of the scan that never reached the engine: lost, corrupt, overrun or cut
        short on the way; once the stream has ended, by the device's own count."""
        if scan.done.is_set() or scan.ended_mono is not None:
            sent = self.stream.status_info().get("frames_sent")
            if sent is not None:
                return max(0, int(sent) - frames_in)
        return gap_frames

    def _response(self, scan: _Scan | None) -> ScanResponse:
        stream = self.stream.stats()
        if scan is None:
            return ScanResponse(
                state="none", file=None, quicklook=None, stages=0, lines_wanted=0,
                frames_requested=0, lines=0, complete_lines=0, lost_frames=0, not_sent_frames=0,
                stage_changes=[],
                mode="sum", width=0, elapsed_s=0.0, lines_per_s=0.0, cpu_load=0.0,
                tdi_cpu_s=0.0, backlog_frames=0, timing=None, error=None, stream=stream,
                mismatch_max=None, mismatch_rms=None, mismatch_level="ok", motion=None,
            )  # fmt: skip
        progress = scan.pipeline.progress()
        end_mono = scan.ended_mono if scan.ended_mono is not None else time.monotonic()
        end_cpu = scan.ended_cpu if scan.ended_cpu is not None else time.process_time()
        elapsed = max(end_mono - scan.started_mono, 1e-9)
        return ScanResponse(
            state=scan.state,  # type: ignore[arg-type]
            file=str(scan.path),
            quicklook=None if scan.quicklook is None else str(scan.quicklook),
            stages=scan.pipeline.stages,
            lines_wanted=scan.request.lines,
            frames_requested=scan.frames_requested,
            lines=progress.lines,
            complete_lines=progress.complete_lines,
            lines_flushed=scan.pipeline.recorder.flushed_lines,
            lost_frames=self._lost_frames(scan, progress.frames_in, progress.gap_frames),
            not_sent_frames=scan.not_sent_frames,
            stage_changes=list(progress.stage_changes),
            mode=scan.request.mode,
            width=scan.pipeline.width,
            elapsed_s=elapsed,
            lines_per_s=progress.lines / elapsed,
            cpu_load=(end_cpu - scan.started_cpu) / elapsed,
            tdi_cpu_s=progress.tdi_cpu_s,
            backlog_frames=progress.backlog_frames,
            timing=scan.timing,
            error=scan.error,
            stream=stream,
            mismatch_max=progress.mismatch_max,
            mismatch_rms=progress.mismatch_rms,
            mismatch_level=progress.mismatch_level,
            motion=self._motion_info(scan),
        )


def _discard(recorder: TdiRecorder, journal: RecordingJournal) -> None:
    """Close and delete a scan file that never got a line (a scan that did not start)."""
    try:
        recorder.close({"state": "failed"}, {})
    finally:
        recorder.path.unlink(missing_ok=True)
        journal.closed(recorder.path)
