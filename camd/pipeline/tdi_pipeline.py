"""One scan's acquisition pipeline: frames -> batches -> TDI engine -> HDF5 recorder.

``TdiPipeline`` owns the engine (``camd.tdi.TdiEngine``), the recorder
(``camd.store.tdi_recording.TdiRecorder``), the batcher (``consumer``: add it to the frame
stream) and the worker thread, which takes the batcher's messages in stream order:

- ``Batch``: the frames through ``TdiEngine.push_many``, each line's M dV/V from the encoder
  counts (``camd.pipeline.mismatch``), the lines appended to the file;
- ``Gap``: lost frames, skipped by the engine (the next M - 1 lines are incomplete);
- ``StageChange``: the engine's M changed and the change recorded with its line index;
- ``DriftChange``: the engine's drift trimmed (``TdiEngine.set_drift``: the image loop's),
  the open lines kept, the change listed with its line index (``drift_changes``);
- ``End``: the worker stops.

It knows nothing of the daemon: what it has to say goes through callbacks, all called on the
worker thread (so they must not block on the worker): ``on_event(level, source, message)`` for
the event log, ``on_failure()`` once the worker has failed (a full disk, an engine error: the
rest of the stream is drained unused and the file keeps what it has), ``on_red()`` once, when
the mismatch first reaches the red limit, ``on_lines(data, index, complete, stages_used)`` with
each block of lines once the file has it (the live view's waterfall: ``camd.pipeline.live``; an
error there is logged, never fails the scan). ``progress()`` is a consistent-enough snapshot for
status requests from any thread.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from camd.pipeline.batcher import Batcher
from camd.pipeline.messages import Batch, DriftChange, End, Gap, Message, StageChange
from camd.pipeline.mismatch import Level, MismatchTracker
from camd.store.tdi_recording import TdiRecorder
from camd.tdi import TdiEngine

log = logging.getLogger(__name__)

FINISH_TIMEOUT_S = 60.0  # longest ``finish`` waits for the worker to write what is queued
EVENT_LEVELS: dict[Level, str] = {"ok": "info", "yellow": "warning", "red": "error"}

EventCallback = Callable[[str, str, str], None]  # (level, source, message)
LinesCallback = Callable[
    [npt.NDArray[Any], npt.NDArray[np.int64], npt.NDArray[np.bool_], npt.NDArray[np.int32]], None
]  # (data, index, complete, stages_used) of a block of lines, as TdiBlock has them


@dataclass(frozen=True, slots=True)
class Progress:
    """What the pipeline has done so far (a snapshot)."""

    lines: int  # lines written
    complete_lines: int  # of which all M stages contributed
    frames_in: int  # frames through the engine
    frames_batched: int  # frames the batcher has taken from the stream
    gap_frames: int  # frames lost, corrupt, overrun or dropped inside the scan
    dropped_frames: int  # frames the batcher gave up (wrong geometry, worker too far behind)
    tdi_cpu_s: float  # CPU time of the worker thread
    engine_cpu_s: float  # of which in the TDI engine (push_many), on the worker thread
    record_cpu_s: float  # of which in the mismatch and the HDF5 append
    stage_changes: tuple[tuple[int, int], ...]  # (line index, M): the first M, then each change
    mismatch_max: float | None  # largest |M dV/V| of a complete line, pixels
    mismatch_rms: float | None  # RMS |M dV/V| over the complete lines, pixels
    mismatch_level: Level  # the worst level reached
    mismatch_last: float | None  # the last batch's largest |M dV/V|, pixels

    @property
    def backlog_frames(self) -> int:
        """Frames batched but not yet through the engine."""
        return max(0, self.frames_batched - self.frames_in)


class TdiPipeline:
    """The batcher, worker, engine and recorder of one scan (module docstring).

    ``rows`` is the number of window rows the engine needs from each frame (frames may have
    more). With ``counts_per_pixel`` (encoder counts per image pitch; None without a driven
    stage) each line gets its M dV/V, graded against ``yellow_px`` and ``red_px``.
    ``start`` records the first M and starts the worker; ``finish`` ends it once the stream
    has ended. The file is the caller's to close (``recorder.close``) after ``finish``.
    """

    def __init__(
        self,
        engine: TdiEngine,
        recorder: TdiRecorder,
        *,
        rows: int,
        counts_per_pixel: float | None = None,
        yellow_px: float = 1.0,
        red_px: float = 2.0,
        on_event: EventCallback | None = None,
        on_failure: Callable[[], None] | None = None,
        on_red: Callable[[], None] | None = None,
        on_lines: LinesCallback | None = None,
    ) -> None:
        self._engine = engine
        self._recorder = recorder
        self._on_event = on_event or (lambda level, source, message: None)
        self._on_failure = on_failure or (lambda: None)
        self._on_red = on_red or (lambda: None)
        self._on_lines = on_lines
        self._lines_failed = False  # on_lines raised once: logged, not called again
        self._queue: queue.Queue[Message] = queue.Queue()
        self._batcher = Batcher(rows, engine.width, self._queue)
        self._mismatch = (
            None
            if counts_per_pixel is None
            else MismatchTracker(
                counts_per_pixel, yellow_px=yellow_px, red_px=red_px, on_level=self._level_changed
            )
        )
        self._worker: threading.Thread | None = None
        self._failed = False
        self._red_reported = False
        self.error: str | None = None  # why the worker failed (None: it has not)
        # Written by the worker thread only; read by ``progress``.
        self._lines = self._complete_lines = self._frames_in = self._gap_frames = 0
        self._tdi_cpu_s = 0.0
        self._engine_cpu_s = self._record_cpu_s = 0.0
        self._stage_changes: list[tuple[int, int]] = []
        self._drift_changes: list[tuple[int, float]] = []
        # (frame counter, line index) of the first frame through the engine: a frame's line is
        # its counter's distance from it (lost frames skip their lines)
        self.first_frame: tuple[int, int] | None = None

    # -- what the caller uses -------------------------------------------------------------------

    @property
    def consumer(self) -> Batcher:
        """The frame stream consumer to add to the stream (and remove once it has ended)."""
        return self._batcher

    @property
    def recorder(self) -> TdiRecorder:
        """The scan's file (close it after ``finish``)."""
        return self._recorder

    @property
    def stages(self) -> int:
        """M, the stages the engine sums now."""
        return self._engine.stages

    @property
    def pending_stages(self) -> int | None:
        """An M asked for that no frame has reached yet (None: none)."""
        return self._batcher.pending_stages

    @property
    def width(self) -> int:
        """N, the columns of each frame and line."""
        return self._engine.width

    @property
    def rows(self) -> int:
        """The window rows the engine takes from each frame."""
        return self._batcher.rows

    @property
    def counts_per_pixel(self) -> float | None:
        """Encoder counts per image pitch (None: no mismatch monitor)."""
        return None if self._mismatch is None else self._mismatch.counts_per_pixel

    @property
    def failed(self) -> bool:
        """True once the worker failed or the pipeline was aborted: messages are drained."""
        return self._failed

    @property
    def running(self) -> bool:
        """True while the worker thread runs."""
        return self._worker is not None and self._worker.is_alive()

    def progress(self) -> Progress:
        """What has been done so far."""
        tracker = self._mismatch
        return Progress(
            lines=self._lines,
            complete_lines=self._complete_lines,
            frames_in=self._frames_in,
            frames_batched=self._batcher.frames,
            gap_frames=self._gap_frames,
            dropped_frames=self._batcher.dropped,
            tdi_cpu_s=self._tdi_cpu_s,
            engine_cpu_s=self._engine_cpu_s,
            record_cpu_s=self._record_cpu_s,
            stage_changes=tuple(self._stage_changes),
            mismatch_max=None if tracker is None else tracker.max,
            mismatch_rms=None if tracker is None else tracker.rms,
            mismatch_level="ok" if tracker is None else tracker.level,
            mismatch_last=None if tracker is None else tracker.last,
        )

    def start(self) -> None:
        """Record the first M at the engine's next line and start the worker thread."""
        if self._worker is not None:
            raise RuntimeError("the pipeline has already been started")
        self._note_stages(self._engine.next_index, self._engine.stages)
        self._worker = threading.Thread(target=self._work, name="camd-tdi-worker", daemon=True)
        self._worker.start()

    def request_stages(self, stages: int) -> None:
        """Change M from the next frame the consumer sees (checked by the caller)."""
        self._batcher.request_stages(stages)

    def request_drift(self, cols_per_line: float) -> None:
        """Follow ``cols_per_line`` columns of drift per line from the next frame the consumer
        sees (the image loop's trim)."""
        self._batcher.request_drift(cols_per_line)

    @property
    def drift_changes(self) -> tuple[tuple[int, float], ...]:
        """(line index, columns per line) of each drift trim so far."""
        return tuple(self._drift_changes)

    def finish(self, *, flush: bool = True, timeout_s: float = FINISH_TIMEOUT_S) -> bool:
        """The stream has ended: queue the partial batch (unless ``flush`` is False), then the
        end, and wait for the worker to write what is queued. True if the worker ended."""
        if flush:
            self._batcher.flush()
        return self._end(timeout_s)

    def release(self) -> None:
        """After ``finish``: free the batch buffers and what is still queued, and drop the
        callbacks (they refer back to the scan): the progress stays readable."""
        if self.running:
            return  # the worker still uses them
        self._batcher.release()
        while True:
            try:
                self._queue.get_nowait()
            except queue.Empty:
                break
        self._on_event = lambda level, source, message: None
        self._on_failure = self._on_red = lambda: None
        self._on_lines = None

    def abort(self, timeout_s: float = FINISH_TIMEOUT_S) -> bool:
        """Give up (the stream did not start): what is queued is dropped, the worker ends."""
        self._failed = True
        return self._end(timeout_s)

    # -- the worker ----------------------------------------------------------------------------

    def _end(self, timeout_s: float) -> bool:
        self._queue.put(End())
        worker = self._worker
        if worker is None:
            return True
        worker.join(timeout_s)
        return not worker.is_alive()

    def _work(self) -> None:
        """The TDI worker: messages in stream order until ``End``."""
        start_cpu = time.thread_time()
        while True:
            message = self._queue.get()
            if isinstance(message, End):
                break
            if self._failed:
                # Drain, handing the buffers back, so the batcher never waits for one.
                if isinstance(message, Batch):
                    self._batcher.recycle(message.pixels)
                continue
            try:
                self._handle(message)
            except Exception as exc:  # a full disk, a bad frame: stop the scan, keep the file
                log.exception("TDI worker failed")
                self._failed, self.error = True, f"TDI worker: {exc}"
                self._on_event("error", "scan", f"scan failed: {exc}; stopping the stream")
                self._on_failure()
            self._tdi_cpu_s = time.thread_time() - start_cpu
        self._tdi_cpu_s = time.thread_time() - start_cpu

    def _handle(self, message: Message) -> None:
        engine = self._engine
        match message:
            case Gap(frames=frames):
                engine.gap(frames)
                self._gap_frames += frames
            case StageChange(stages=stages):
                engine.stages = stages
                self._note_stages(engine.next_index, stages)
            case DriftChange(cols_per_line=cols):
                engine.set_drift(cols)
                self._drift_changes.append((engine.next_index, cols))
            case Batch():
                self._push(message)
            case End():  # handled by the loop
                pass

    def _push(self, batch: Batch) -> None:
        engine = self._engine
        t_engine = time.thread_time()
        try:
            block = engine.push_many(batch.frames)
        finally:
            self._batcher.recycle(batch.pixels)
        t_record = time.thread_time()
        self._engine_cpu_s += t_record - t_engine
        if self.first_frame is None and batch.n:
            self.first_frame = (int(batch.counters[0]), int(block.index[0]))
        mismatch = None
        if self._mismatch is not None:
            result = self._mismatch.add(
                batch.counters, batch.encoder, block.complete, stages=engine.stages
            )
            mismatch = result.values
            if result.red and not self._red_reported:
                self._red_reported = True
                self._on_red()
        self._recorder.append(
            block.data,
            index=block.index,
            stages_used=block.stages_used,
            complete=block.complete,
            frame_counter=batch.counters,
            stage_position=batch.encoder,
            m_dv_over_v=mismatch,
        )
        self._record_cpu_s += time.thread_time() - t_record
        self._frames_in += batch.n
        self._lines += batch.n
        self._complete_lines += int(block.complete.sum())
        if self._on_lines is not None and not self._lines_failed:
            try:
                self._on_lines(block.data, block.index, block.complete, block.stages_used)
            except Exception:  # the live view must never cost the scan
                log.exception("on_lines failed; no more lines for the live view in this scan")
                self._lines_failed = True

    def _note_stages(self, index: int, stages: int) -> None:
        self._recorder.note_stage_change(index, stages)
        self._stage_changes.append((index, stages))

    def _level_changed(self, level: Level, message: str) -> None:
        self._on_event(EVENT_LEVELS[level], "motion", message)
