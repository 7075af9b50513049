"""One push-broom scan from its stream's start to its file closed: the line consumer, the finisher.

``ScanRun`` is made by ``camd.daemon.scan_apply`` once the scan's plan has been applied (the
camera, the stage and the file are ready), handed the device access, the stream service, the
live view's waterfall and the scan service's lock. It keeps what the current or last scan is
(its request, file, timing, stage, state, error and times) and runs it:

- its acquisition pipeline (``camd.pipeline.TdiPipeline``), the stream's consumer: frames are
  batched on the stream's dispatcher thread and integrated on the pipeline's worker thread,
  each line's M dV/V worked out from the encoder counts, the lines appended to the HDF5 file
  (and to the live view's waterfall);
- the stream's start with ``lines + M - 1`` frames (``start_stream``), and a finisher thread
  that waits for the stream to end, then finishes the pipeline, stops the stage, closes the
  file with its counters and writes a PNG quicklook beside it;
- the pipeline's callbacks (a failed worker, a red mismatch), which stop the stream without
  waiting, as they run on the worker thread;
- at the daemon's shutdown (``close``), the end of a scan its finisher did not end in time;
- the image's motion measured from blocks of its frames (``camd.pipeline.image_motion``: a log
  for the file's ``/image_motion`` group and the status) and, with ``image_loop``, the loop
  that trims its line period and drift from them (``camd.daemon.scan_image_loop``: the file's
  ``/image_loop`` group).

The scan's log lines keep the logger name they had before the scan service was split by job.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from camd.daemon.acquisition import Acquisition
from camd.daemon.device import DeviceAccess
from camd.daemon.errors import DeviceRejected
from camd.daemon.models import ScanMotionInfo, StreamStartRequest
from camd.daemon.scan_image_loop import ScanImageLoop
from camd.daemon.scan_motion import ScanMotion
from camd.daemon.scan_plan import ScanPlan, engine_for
from camd.daemon.stream_service import StreamService
from camd.motion.closed_loop import LinePeriodSetting
from camd.pipeline import TdiPipeline
from camd.pipeline.image_motion import (
    COUNTER_WRAP,
    ImageMotionMonitor,
    MotionLog,
    MotionSummary,
)
from camd.pipeline.live import LiveLines
from camd.store.journal import settle_failed_close
from camd.store.quicklook import write_quicklook_png
from camd.store.tdi_recording import TdiRecorder

log = logging.getLogger("camd.daemon.scan_service")

FINISH_TIMEOUT_S = 60.0
QUICKLOOK_MAX_LINES = 8192
IMAGE_MOTION_WAIT_S = 2.0  # a closing scan waits this long at most for its last block


def _or_nan(value: float | None) -> float:
    return float("nan") if value is None else value


class ScanRun:
    """One scan: its request, pipeline, stage and state (module docstring)."""

    def __init__(
        self,
        plan: ScanPlan,
        motion: ScanMotion | None,
        recorder: TdiRecorder,
        acquisition: Acquisition,
        *,
        device: DeviceAccess,
        stream: StreamService,
        live_lines: LiveLines | None,
        lock: threading.Lock,
        image_motion: ImageMotionMonitor | None = None,
        line_period_writer: Callable[[LinePeriodSetting], None] | None = None,
    ) -> None:
        self.device = device
        # The image's motion from blocks of the scan's frames (None: not measured).
        self._image_motion = image_motion if image_motion and image_motion.enabled else None
        self.image_motion_log: MotionLog | None = None
        self._stream = stream
        self._live_lines = live_lines  # the live view's waterfall (None: no live lines)
        # The scan service's: the scan's end (state and ``done``) is set under it.
        self._lock = lock
        self.request = request = plan.request
        self.path = plan.path
        self.timing = plan.timing
        self.frames_requested = plan.frames
        # The most window rows a loop that trims the line period may set (None: no such loop):
        # the encoder's line-period loop or the image loop.
        trims = plan.image_loop or (motion is not None and motion.mode == "line_period")
        self.max_rows = plan.max_lines if trims else None
        self.motion = motion
        self.acquisition = acquisition  # released once the file is closed
        self.state = "starting"
        self.error: str | None = None
        # A failure met while the scan runs (a write failed): the scan shows "failed" once its
        # file is closed (``_finish``), so that a client that sees it ended may read the file.
        self.failing = False
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
        limits = device.config.motion
        self.pipeline = TdiPipeline(
            engine_for(request, request.stages, plan.columns),
            recorder,
            rows=plan.rows,
            counts_per_pixel=None if plan.stage is None else plan.stage.counts_per_pixel,
            yellow_px=limits.yellow,
            red_px=limits.red,
            on_event=self._events,
            on_failure=self._worker_failed,
            on_red=self._mismatch_red,
            on_lines=None if live_lines is None else live_lines.append,
        )
        self.image_loop: ScanImageLoop | None = None
        if plan.image_loop and self._image_motion is not None and line_period_writer is not None:
            request, timing = plan.request, plan.timing
            self.image_loop = ScanImageLoop(
                self._image_motion,
                self.pipeline,
                line_period_writer,
                line_period_s=timing.tdi_line_period_s,
                row_time_s=timing.row_period_s,
                stages=request.stages * (2 if plan.binned else 1),
                max_lines=plan.max_lines,
                rows_per_line=request.rows_per_line,
                cols_per_line=request.cols_per_line,
                gain=limits.image_loop_gain,
                max_trim=limits.max_trim,
                max_cols_per_line=limits.image_max_cols_per_line,
                events=lambda level, message: self.device.log_event(level, "motion", message),
            )

    def _events(self, level: str, source: str, message: str) -> None:
        self.device.log_event(level, source, message)

    # -- starting -------------------------------------------------------------------------------

    def start_stream(self, rows: int, cols: int) -> None:
        """Start the pipeline and the stream of the scan's frames, then the finisher; on a
        failure the scan is "failed", the pipeline aborted, and the error raised."""
        stream, pipeline = self._stream, self.pipeline
        pipeline.start()
        if self._image_motion is not None:
            self._image_motion.set_reverse(self.request.reverse)
            self.image_motion_log = self._image_motion.start_log()
        stream.add_consumer(pipeline.consumer)
        try:
            # A loop that trims the line period changes the window's rows, up to the plan's:
            # the stream's frames may be as large as that from any frame on.
            trimmed = self.max_rows is not None
            info = stream.start(
                StreamStartRequest(
                    frames=self.frames_requested,
                    stages=self.request.stages,
                    binning=self.request.binning,
                ),
                max_rows=self.max_rows if trimmed else None,
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
            self._stop_image_motion(0.0)
            self.state = "failed"
            pipeline.abort(FINISH_TIMEOUT_S)
            self.live_end("failed")
            raise
        self.state = "running"
        if self.image_loop is not None:
            self.image_loop.start()
        self.started_mono, self.started_cpu = time.monotonic(), time.process_time()
        what = "until stopped" if self.request.lines == 0 else f"{self.request.lines} lines"
        self.device.log_event(
            "info", "scan", f"scan started: M = {self.request.stages}, {what}, file {self.path}"
        )
        self.finisher = threading.Thread(target=self._finish, name="camd-scan-finish", daemon=True)
        self.finisher.start()

    # -- running (the pipeline's callbacks, on its worker thread: they must not wait) -----------

    def _worker_failed(self) -> None:
        self.failing, self.error = True, self.pipeline.error
        threading.Thread(target=self._stop_quietly, name="camd-scan-stop", daemon=True).start()

    def _mismatch_red(self) -> None:
        if self.device.config.motion.stop_on_red:
            self.stop_requested = True
            threading.Thread(target=self._stop_quietly, name="camd-scan-stop", daemon=True).start()

    def _stop_quietly(self) -> None:
        try:
            self._stream.stop()
        except Exception as exc:  # the stream may already have ended
            log.info("stopping the stream after a scan failure: %s", exc)

    # -- finishing ------------------------------------------------------------------------------

    def _finish(self) -> None:
        """Wait for the stream to end, then finish the pipeline, close the file, write the PNG."""
        stream = self._stream
        stream.wait_finished()
        if self.done.is_set():
            return  # the daemon is shutting down and ``close`` has ended the scan
        stream.remove_consumer(self.pipeline.consumer)
        if self.image_loop is not None:
            self.image_loop.stop()
        self.pipeline.finish(timeout_s=FINISH_TIMEOUT_S)
        self.ended_mono, self.ended_cpu = time.monotonic(), time.process_time()
        self.not_sent_frames = stream.frames_not_sent  # this scan's stream has ended
        if self.motion is not None:
            self.motion.finish()
        final = "stopped" if self.stop_requested else "done"
        broken, early = stream.broken, stream.ended_early
        if broken is not None and not self.failing and not self.stop_requested:
            self.failing, self.error = True, f"the stream ended early: {broken}"
        elif early is not None and not self.failing and not self.stop_requested:
            # The camera ended the stream before the scan's frames were all sent: the file
            # holds the lines that came, and the scan is not done.
            final, self.error = "ended_early", f"the stream ended early: {early}"
        if self.failing:
            final = "failed"
        self._close_file(final)
        stats = stream.stats()
        progress = self.pipeline.progress()
        not_sent = self.not_sent_frames
        self.device.log_event(
            "info" if final == "done" and stats.lost == 0 else "warning",
            "scan",
            f"scan {final}: {progress.lines} lines ({progress.complete_lines} complete), "
            f"{stats.lost} frames lost, {not_sent} not sent, {stats.overruns} overruns; "
            f"{self.path}" + (f"; {self.error}" if final == "ended_early" else ""),
        )
        # Only now, and together: a client that sees the scan ended may start the next at once.
        with self._lock:
            if self.state != "failed":
                self.state = final
            self.done.set()
        self.live_end(self.state)
        self.pipeline.release()  # tens of MB of batch buffers: not left to the collector
        self.device.acquisition.release(self.acquisition)

    def close(self, timeout_s: float) -> None:
        """Daemon shutdown, after the stream was ended: the finisher ends the scan as stopped
        within ``timeout_s``; a scan it has not ended by then is ended here."""
        self.stop_requested = True
        finisher = self.finisher
        if finisher is not None and finisher is not threading.current_thread():
            finisher.join(timeout_s)
        if not self.done.is_set():
            self.device.log_event(
                "warning", "scan", f"the scan did not end within {timeout_s:g} s; closing it"
            )
            if self.motion is not None:
                self.motion.finish()  # a stage must not run on without its daemon
            if self.image_loop is not None:
                self.image_loop.stop()
            self.pipeline.finish(flush=False)
            self.not_sent_frames = self._stream.frames_not_sent
            if self.failing:
                self.state = "failed"
            self._close_file(self.state)
            self.done.set()
            self.live_end(self.state)
            self.pipeline.release()  # tens of MB of batch buffers: not left to the collector
        self.device.acquisition.release(self.acquisition)

    def live_end(self, state: str) -> None:
        """The live view's waterfall ends with the scan's ``state``."""
        if self._live_lines is not None:
            self._live_lines.end(state)

    def _stop_image_motion(self, wait_s: float) -> None:
        """No more blocks for the scan's log; wait ``wait_s`` at most for one being measured."""
        if self._image_motion is not None and self.image_motion_log is not None:
            self._image_motion.stop_log(self.image_motion_log, wait_s=wait_s)
            self._image_motion.set_reverse(False)

    def image_motion_summary(self) -> MotionSummary | None:
        """The image's motion over the scan's blocks so far (None: not measured)."""
        log = self.image_motion_log
        return None if log is None else log.summary()

    def _image_motion_record(self) -> tuple[dict[str, Any], dict[str, Any]] | None:
        """The file's ``/image_motion`` group: its attributes and per-block datasets, with each
        block's first and last line (-1 for a block before the first line's frame)."""
        log, monitor = self.image_motion_log, self._image_motion
        if log is None or monitor is None:
            return None
        summary = log.summary()
        arrays: dict[str, Any] = log.arrays()
        first = self.pipeline.first_frame
        for end in ("first", "last"):
            counters = arrays[f"counter_{end}"]
            if first is None:
                arrays[f"line_{end}"] = np.full(counters.shape, -1, np.int64)
            else:
                counter0, index0 = first
                arrays[f"line_{end}"] = index0 + (counters - counter0) % COUNTER_WRAP
        attributes = {
            "frames_per_block": monitor.frames_per_block,
            "columns_max": monitor.columns_max,
            "cpu_fraction": monitor.cpu_fraction,
            "blocks": summary.blocks,
            "blocks_dropped": log.blocks_dropped,
            "measurable_blocks": summary.measurable_blocks,
            "dv_over_v_mean": _or_nan(summary.dv_over_v_mean),
            "m_dv_over_v_mean": _or_nan(summary.m_dv_over_v_mean),
            "theta_deg_mean": _or_nan(summary.theta_deg_mean),
            "dv_over_v_sem": _or_nan(summary.dv_over_v_sem),
        }
        return attributes, arrays

    def _close_file(self, state: str) -> None:
        stats = self._stream.stats().model_dump()
        progress = self.pipeline.progress()
        motion = self.motion_info()
        datasets = {}
        self._stop_image_motion(IMAGE_MOTION_WAIT_S)
        image_motion = self._image_motion_record()
        attributes: dict[str, Any] = {
            "counters": {
                **stats,
                "not_sent_frames": self.not_sent_frames,
                "lines": progress.lines,
                "complete_lines": progress.complete_lines,
                "dropped_frames": progress.dropped_frames,
                "tdi_cpu_s": progress.tdi_cpu_s,
            },
            "state": state,
            "error": self.error or "",
        }
        if motion is not None:
            assert self.motion is not None
            limits = self.device.config.motion
            attributes["motion"] = {
                **motion.model_dump(),
                "mismatch_max": progress.mismatch_max,
                "mismatch_rms": progress.mismatch_rms,
                "mismatch_level": progress.mismatch_level,
                "yellow": limits.yellow,
                "red": limits.red,
                "counts_per_pixel": self.pipeline.counts_per_pixel,
                # the stage's position in m from /stage_position (the file's NXpositioner)
                "encoder_counts_per_m": self.motion.plan.encoder_counts_per_m,
            }
            if motion.loop_samples:
                datasets["motion_loop"] = self.motion.record.arrays()
        if image_motion is not None:
            attributes["image_motion"], datasets["image_motion"] = image_motion
        if self.image_loop is not None:
            attributes["image_loop"] = self.image_loop.info().attributes()
            if self.image_loop.record.time_s:
                datasets["image_loop"] = self.image_loop.record.arrays()
        try:
            self.pipeline.recorder.close(attributes, datasets)
        except Exception as exc:
            log.exception("closing %s", self.path)
            self.state, self.error = "failed", f"closing {self.path}: {exc}"
            # Repaired now if it can be, else the journal keeps it for the next start.
            settle_failed_close(
                self.path, exc, "scan", self.device.recordings, self.device.log_event, "scan"
            )
            return
        self.device.recordings.closed(self.path)
        if self.request.quicklook and progress.lines:
            try:
                self.quicklook = _quicklook(self.path)
            except Exception as exc:  # the data are safe in the file; say so and go on
                self.device.log_event("warning", "scan", f"no quicklook for {self.path}: {exc}")

    # -- reporting ------------------------------------------------------------------------------

    def motion_info(self) -> ScanMotionInfo | None:
        """The scan's stage as the status and the file report it (None: no driven stage)."""
        motion = self.motion
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


def _quicklook(path: Path) -> Path:
    """A PNG of the scan's lines (at most QUICKLOOK_MAX_LINES of them, evenly taken) beside
    its file."""
    with h5py.File(path, "r") as f:
        count = int(f["lines"].shape[0])
        step = max(1, -(-count // QUICKLOOK_MAX_LINES))
        lines = np.asarray(f["lines"][::step])
        complete = np.asarray(f["complete"][::step]).astype(bool)
    return write_quicklook_png(path.with_suffix(".png"), lines, complete=complete)
