"""The image's motion measured live from the stream's TDI windows, off the critical path.

``ImageMotionMonitor`` is a stream consumer that stays on every stream (like ``RoiMonitor``),
but it measures a subset of the frames, on its own thread, so the stream's dispatcher and the
TDI worker never wait for it:

- **Which frames.** TDI-mode frames only (in area mode nothing says how far the image moved
  between two frames). A *block* is ``frames_per_block`` window frames of one geometry and one
  M (``_offsets``: four consecutive ones, then the rest spread over 45 % of the window's rows,
  each taken at its offset from the block's first, or the next that came after a loss;
  consecutive ones in a window too short for that; far past the block's span, a new block
  starts), cut to their central ``columns_max`` columns. A block is started only while the
  worker is idle and the CPU budget allows: after a block that took ``c`` CPU-seconds to
  measure, the next starts no sooner than ``c (1 / cpu_fraction - 1)`` seconds later, so the
  measurement uses at most ``cpu_fraction`` of one core (one OpenCV thread, one BLAS thread),
  whatever the line rate. Frames that arrive meanwhile are not measured. On the dispatcher
  thread the monitor copies a block's frames and otherwise costs a comparison per frame (or
  per packed transfer).
- **What it gives.** Per block, ``camd.analysis.image_motion.measure_tdi_motion``'s result
  (dV/V, M dV/V with the frames' M, theta, or "not measurable" with the reason) with the block's
  first and last frame counters, in a ring of the newest ``history_max`` blocks, and in every
  active ``MotionLog`` (a scan keeps one for its file's ``/image_motion`` group).
- **A rolling shutter.** Each row of a window is exposed ``T_row`` after the one before, so
  the shift between frames is not the image's speed; ``row_time_s`` (set from the sensor's
  timing at every stream's start, None for a global shutter) and each frame header's line
  period give the lag ``T_row / T_line`` the measurement converts with, and ``reverse`` (a
  reverse scan's) turns the frames upside down first (docs/physics.md §10).
- **Fixed pattern.** The live view's background (``BackgroundCapture.ready``) is subtracted
  when it has the frames' geometry; otherwise the measurement removes each column's mean over
  the block (docs/physics.md §10). The pixels' gain pattern is learnt from the (offset-free)
  frames of the blocks measured so far in the stream whose image moved, and divided out once
  ``FLAT_FRAMES_MIN`` of them are in (``flat_from_mean``).
- **Listeners** (a scan's image loop, ``camd.daemon.scan_image_loop``) get every block on the
  monitor's thread once it is recorded.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from camd.link.frame_stream import ReceivedFrame
from camd.link.packed import FrameBatch
from camd.pipeline.background import Background
from camd.protocol.stream import StreamMode

if TYPE_CHECKING:
    # OpenCV (the measurement's) is loaded when the first block is measured, not with the
    # daemon: a daemon that never streams TDI frames never loads it.
    from camd.analysis.image_motion import ImageMotion

logger = logging.getLogger(__name__)

FRAMES_PER_BLOCK = 16
COLUMNS_MAX = 512
CPU_FRACTION = 0.25
HISTORY_MAX = 1024
LOG_BLOCKS_MAX = 1 << 20
"""Blocks a recording's log keeps at most (a scan of hours at a block a second): the blocks past
it are counted, not kept."""
FLAT_FRAMES_MIN = 64
"""Frames of moving scene averaged before their gain pattern is divided out (four blocks)."""
COUNTER_WRAP = 1 << 32
MIN_OVERLAP_ROWS = 3  # as camd.analysis.image_motion: a pair needs 3 rows of overlap


@dataclass(frozen=True, slots=True)
class MotionBlock:
    """One measured block: its frames' counters, M, when it was measured and the result."""

    counter_first: int
    counter_last: int
    frames: int
    stages: int
    line_period_s: float  # the frames' line period, as their headers give it
    columns: tuple[int, int]  # the columns [first, last) measured
    measured_t_s: float  # Unix time the measurement ended
    cpu_s: float  # the measurement's CPU time
    motion: ImageMotion

    def as_dict(self) -> dict[str, Any]:
        """Plain values for JSON (NaN as None)."""
        m = self.motion
        measurable = m.measurable
        values: dict[str, Any] = {
            "counter_first": self.counter_first,
            "counter_last": self.counter_last,
            "frames": self.frames,
            "pairs": m.pairs_used,
            "stages": self.stages,
            "columns": list(self.columns),
            "measured_t_s": self.measured_t_s,
            "cpu_s": self.cpu_s,
            "measurable": measurable,
            "why": m.why,
            "shift_along_px_per_line": m.shift_along_px_per_line,
            "shift_across_px_per_line": m.shift_across_px_per_line,
            "shift_along_stderr_px": m.shift_along_stderr_px,
            "shift_across_stderr_px": m.shift_across_stderr_px,
            "dv_over_v": m.dv_over_v,
            "dv_over_v_stderr": m.dv_over_v_stderr,
            "m_dv_over_v": m.m_dv_over_v(self.stages),
            "theta_deg": m.theta_deg,
            "row_lag_lines": m.row_lag_lines,
        }
        return {k: _plain(v) for k, v in values.items()}


def _plain(value: Any) -> Any:
    return None if isinstance(value, float) and not math.isfinite(value) else value


BLOCK_FIELDS = (
    "counter_first",
    "counter_last",
    "frames",
    "pairs",
    "stages",
    "measured_t_s",
    "measurable",
    "shift_along_px_per_line",
    "shift_across_px_per_line",
    "shift_along_stderr_px",
    "shift_across_stderr_px",
    "dv_over_v",
    "m_dv_over_v",
    "theta_deg",
)
"""The per-block values a recording's ``/image_motion`` group holds, one dataset each."""


class MotionLog:
    """The blocks measured while a recording is written: each block's ``BLOCK_FIELDS`` values
    in a float64 table (14 numbers a block, grown by doubling: a long scan's blocks cost 112
    bytes each, not a Python object each), and the newest block whole."""

    def __init__(self, blocks_max: int = LOG_BLOCKS_MAX) -> None:
        self.blocks_max = blocks_max
        self.blocks_dropped = 0
        self.count = 0
        self.latest: MotionBlock | None = None
        self._values = np.empty((64, len(BLOCK_FIELDS)), dtype=np.float64)

    def add(self, block: MotionBlock) -> None:
        self.latest = block
        if self.count >= self.blocks_max:
            self.blocks_dropped += 1
            return
        if self.count == self._values.shape[0]:
            grown = np.empty((2 * self.count, len(BLOCK_FIELDS)), dtype=np.float64)
            grown[: self.count] = self._values
            self._values = grown
        values = block.as_dict()
        self._values[self.count] = [
            math.nan if values[name] is None else float(values[name]) for name in BLOCK_FIELDS
        ]
        self.count += 1

    def arrays(self) -> dict[str, npt.NDArray[Any]]:
        """One array per ``BLOCK_FIELDS`` name, a value per block (NaN where not measurable)."""
        table = self._values[: self.count]
        out: dict[str, npt.NDArray[Any]] = {}
        for k, name in enumerate(BLOCK_FIELDS):
            column = table[:, k]
            if name in ("counter_first", "counter_last", "frames", "pairs", "stages"):
                out[name] = column.astype(np.int64)
            elif name == "measurable":
                out[name] = column.astype(bool)
            else:
                out[name] = column.copy()
        return out

    def summary(self) -> MotionSummary:
        """The kept blocks summed up (``summarize``'s figures) and the newest block."""
        table = self._values[: self.count]
        column = {name: table[:, k] for k, name in enumerate(BLOCK_FIELDS)}
        good = column["measurable"] > 0
        n = int(good.sum())
        if not n:
            return MotionSummary(self.count, 0, None, None, None, None, self.latest)
        dv = column["dv_over_v"][good]
        sem = float(dv.std(ddof=1) / math.sqrt(n)) if n >= 2 else None
        return MotionSummary(
            blocks=self.count,
            measurable_blocks=n,
            dv_over_v_mean=float(dv.mean()),
            m_dv_over_v_mean=float(column["m_dv_over_v"][good].mean()),
            theta_deg_mean=float(column["theta_deg"][good].mean()),
            dv_over_v_sem=sem,
            latest=self.latest,
        )


@dataclass(slots=True)
class _Block:
    """A block being collected on the dispatcher thread."""

    pixels: npt.NDArray[np.uint16]  # (frames_per_block, rows, columns)
    counters: list[int]
    rows: int
    cols: int
    stages: int
    col0: int
    row_lag_lines: float  # signed for the frames as measured (flipped when reverse)
    reverse: bool
    line_period_ns: int
    offsets: tuple[int, ...]  # the frames wanted, in line periods after the first
    next: int = 0  # the offset wanted next
    first: int = 0  # the first frame's counter


def _offsets(rows: int, frames: int) -> tuple[int, ...]:
    """The frames a block takes, in line periods after its first (module docstring, "Which
    frames"): four consecutive ones, then the rest spread up to 45 % of the window's rows, so
    that all are registered on the first (``MAX_BASELINE_FRACTION``, half the window, with room
    for an image 10 % fast); consecutive frames when the window is too short for that."""
    longest = int(0.45 * rows)
    if longest < frames:
        return tuple(range(frames))
    spread = np.rint(np.linspace(4, longest, frames - 4)).astype(int).tolist()
    return tuple(sorted({0, 1, 2, 3, *spread}))


@dataclass(frozen=True, slots=True)
class MonitorStatus:
    """The monitor's counters and its newest blocks (oldest first)."""

    enabled: bool
    frames_per_block: int
    columns_max: int
    cpu_fraction: float
    blocks_measured: int
    tdi_frames_seen: int
    frames_measured: int
    cpu_s: float
    blocks: tuple[MotionBlock, ...]


class ImageMotionMonitor:
    """The image's motion from blocks of the stream's TDI windows (module docstring)."""

    def __init__(
        self,
        background: Callable[[], Background | None] = lambda: None,
        *,
        enabled: bool = True,
        frames_per_block: int = FRAMES_PER_BLOCK,
        columns_max: int = COLUMNS_MAX,
        cpu_fraction: float = CPU_FRACTION,
        history_max: int = HISTORY_MAX,
    ) -> None:
        if frames_per_block < 3:
            raise ValueError(f"frames_per_block = {frames_per_block}: use 3 or more")
        if columns_max < 16:
            raise ValueError(f"columns_max = {columns_max}: use 16 or more")
        if not 0.0 < cpu_fraction <= 1.0:
            raise ValueError(f"cpu_fraction = {cpu_fraction}: use 0 < cpu_fraction <= 1")
        self.enabled = enabled
        self.frames_per_block = frames_per_block
        self.columns_max = columns_max
        self.cpu_fraction = cpu_fraction
        self._background = background
        # The sensor's row time when its shutter rolls (None: every row exposed at once), and
        # whether the image moves towards the window's last row (a reverse scan): both turn the
        # shift between frames into the image's speed (docs/physics.md §10).
        self.row_time_s: float | None = None
        self.reverse = False
        self._lock = threading.Condition()
        self._collecting: _Block | None = None  # the dispatcher's
        self._pending: _Block | None = None  # handed to the worker, until it is measured
        self._not_before = 0.0  # monotonic: no block starts before this (the CPU budget)
        self._blocks: deque[MotionBlock] = deque(maxlen=history_max)
        self._logs: list[MotionLog] = []
        self._listeners: list[Callable[[MotionBlock], None]] = []
        self.last_counter: int | None = None  # the newest TDI frame's counter seen
        self._worker: threading.Thread | None = None
        # The sum of the (offset-free) frames measured in this stream, for the gain pattern
        # (worker thread only, but for the reset at a stream's start).
        self._flat_sum: npt.NDArray[np.float64] | None = None
        self._flat_key: tuple[int, int, int, bool] | None = None
        self._flat_frames = 0
        self._closed = False
        self._measured = 0
        self._seen = 0
        self._frames_measured = 0
        self._cpu_s = 0.0

    # -- the stream's dispatcher thread --------------------------------------------------------

    def __call__(self, frame: ReceivedFrame) -> None:
        h = frame.header
        if not self.enabled or h.mode != StreamMode.TDI:
            return
        self._take(frame.pixels[np.newaxis], [h.counter], h.stages, h.line_period_ns)

    def on_batch(self, batch: FrameBatch) -> None:
        """A packed transfer's frames (one geometry, counters one apart)."""
        fields = batch.fields
        if not self.enabled or int(fields["mode"][0]) != StreamMode.TDI:
            return
        self._take(
            batch.pixels,
            fields["counter"].tolist(),
            int(fields["stages"][0]),
            int(fields["line_period_ns"][0]),
        )

    def _take(
        self,
        pixels: npt.NDArray[np.uint16],
        counters: list[int],
        stages: int,
        line_period_ns: int,
    ) -> None:
        self._seen += len(counters)
        self.last_counter = counters[-1]
        block = self._collecting
        if block is None:
            if self._pending is not None or time.monotonic() < self._not_before:
                return
            block = self._collecting = self._new_block(pixels.shape, stages, line_period_ns)
        if pixels.shape[1:] != (block.rows, block.cols) or stages != block.stages:
            block = self._collecting = self._new_block(pixels.shape, stages, line_period_ns)
        if not block.counters:
            block.first = counters[0]
        rel = (np.asarray(counters, dtype=np.int64) - block.first) % COUNTER_WRAP
        if rel[0] > block.offsets[-1] + block.rows:
            # Far past the block's span (a new stream, a long loss): keep what the block has
            # if it can be measured, else start again from these frames.
            if len(block.counters) >= 3:
                self._hand_over(block)
                return
            block = self._collecting = self._new_block(pixels.shape, stages, line_period_ns)
            block.first = counters[0]
            rel = (np.asarray(counters, dtype=np.int64) - block.first) % COUNTER_WRAP
        width = block.pixels.shape[2]
        offsets = block.offsets
        while block.next < len(offsets):
            # the first frame at or after the offset wanted next (after a loss, the one after)
            i = int(np.searchsorted(rel, offsets[block.next]))
            if i == rel.shape[0]:
                return  # in a later transfer
            at = len(block.counters)
            block.pixels[at] = pixels[i, :, block.col0 : block.col0 + width]
            block.counters.append(counters[i])
            while block.next < len(offsets) and offsets[block.next] <= rel[i]:
                block.next += 1
        self._hand_over(block)

    def _hand_over(self, block: _Block) -> None:
        """The block is collected: the worker measures it."""
        self._collecting = None
        block.pixels = block.pixels[: len(block.counters)]
        with self._lock:
            self._pending = block
            self._start_worker()
            self._lock.notify_all()

    def _new_block(self, shape: tuple[int, ...], stages: int, line_period_ns: int) -> _Block:
        _, rows, cols = shape
        width = min(cols, self.columns_max)
        col0 = (cols - width) // 2
        pixels = np.empty((self.frames_per_block, rows, width), np.uint16)
        row_time_s, reverse = self.row_time_s, self.reverse
        lag = 0.0
        if row_time_s is not None and line_period_ns > 0:
            lag = row_time_s / (line_period_ns * 1e-9)
            lag = min(lag, 0.49)  # a header's line period below two rows is not a TDI window's
        # A reverse scan is measured on frames turned upside down: the image then moves towards
        # the rows read last, and the lag changes sign.
        lag = -lag if reverse else lag
        return _Block(
            pixels,
            [],
            rows,
            cols,
            stages,
            col0,
            lag,
            reverse,
            line_period_ns,
            _offsets(rows, self.frames_per_block),
        )

    # -- the worker ------------------------------------------------------------------------------

    def _start_worker(self) -> None:
        if self._worker is None and not self._closed:
            self._worker = threading.Thread(
                target=self._work, name="camd-image-motion", daemon=True
            )
            self._worker.start()

    def _work(self) -> None:
        # One core: OpenCV's remap and BLAS's dot products would otherwise take every core
        # from the stream and the TDI worker, and the CPU budget, which counts this thread's
        # time, would not see their helpers' (camd bench motion: 0.3-0.5 of a core measured
        # against a 0.25 budget with two BLAS threads). Both settings are the process's;
        # camd's other OpenCV use is the quicklook, and the TDI engine uses no BLAS.
        import cv2
        from threadpoolctl import threadpool_limits

        cv2.setNumThreads(1)
        threadpool_limits(limits=1)
        while True:
            with self._lock:
                while self._pending is None and not self._closed:
                    self._lock.wait()
                if self._closed:
                    return
                block = self._pending
            assert block is not None
            cpu0 = time.thread_time()
            motion = self._measure(block)
            cpu_s = time.thread_time() - cpu0
            result = MotionBlock(
                counter_first=block.counters[0],
                counter_last=block.counters[-1],
                frames=len(block.counters),
                stages=block.stages,
                line_period_s=block.line_period_ns * 1e-9,
                columns=(block.col0, block.col0 + block.pixels.shape[2]),
                measured_t_s=time.time(),
                cpu_s=cpu_s,
                motion=motion,
            )
            with self._lock:
                self._blocks.append(result)
                for log in self._logs:
                    log.add(result)
                listeners = list(self._listeners)
                self._measured += 1
                self._frames_measured += result.frames
                self._cpu_s += cpu_s
                self._not_before = time.monotonic() + cpu_s * (1.0 / self.cpu_fraction - 1.0)
                self._pending = None
                self._lock.notify_all()  # a recording that waits for its last block
            for listener in listeners:  # outside the lock: a listener may take its time
                try:
                    listener(result)
                except Exception:  # a listener's failure is its own; the monitor goes on
                    logger.exception("an image motion listener failed")

    def _measure(self, block: _Block) -> ImageMotion:
        from camd.analysis.image_motion import ImageMotion, measure_tdi_motion

        background = self._background()
        width = block.pixels.shape[2]
        back = None
        if background is not None and background.pixels.shape == (block.rows, block.cols):
            back = background.pixels[:, block.col0 : block.col0 + width]
        frames = block.pixels[:, ::-1] if block.reverse else block.pixels
        if back is not None and block.reverse:
            back = back[::-1]
        key = (block.rows, block.col0, width, block.reverse)
        flat = self._flat(key)
        try:
            motion = measure_tdi_motion(
                list(frames),
                block.counters,
                background=back,
                flat=flat,
                row_lag_lines=block.row_lag_lines,
            )
        except ValueError as exc:  # counters out of order after a wrap: say so, go on
            nan = math.nan
            return ImageMotion(nan, nan, nan, nan, len(block.counters), 0, False, str(exc))
        if motion.measurable and abs(motion.shift_along_px_per_line) > 0.5:
            # The image moved: its frames add to the mean the gain pattern comes from.
            total: npt.NDArray[np.float64] = frames.sum(axis=0, dtype=np.float64)
            if back is not None:
                total -= len(frames) * back
            if self._flat_key != key or self._flat_sum is None:
                self._flat_key, self._flat_sum, self._flat_frames = key, total, 0
            else:
                self._flat_sum += total
            self._flat_frames += len(frames)
        return motion

    def _flat(self, key: tuple[int, int, int, bool]) -> npt.NDArray[np.float32] | None:
        """The gain pattern from the frames of the blocks measured so far in this stream
        (None before ``FLAT_FRAMES_MIN`` of them, or for another geometry)."""
        if self._flat_key != key or self._flat_sum is None:
            return None
        if self._flat_frames < FLAT_FRAMES_MIN:
            return None
        from camd.analysis.image_motion import flat_from_mean

        return flat_from_mean(self._flat_sum / self._flat_frames)

    # -- what the daemon sets and asks ------------------------------------------------------

    def stream_started(self, row_time_s: float | None) -> None:
        """A stream starts: the time between two rows of its frames as read (the sensor's row
        time, twice it for 2x2-binned frames; None: a global shutter) for its blocks; the gain
        pattern is learnt afresh from its frames (the scene, the window may differ)."""
        self.row_time_s = row_time_s
        with self._lock:
            self._flat_sum, self._flat_key, self._flat_frames = None, None, 0

    def set_reverse(self, reverse: bool) -> None:
        """Whether the image moves towards the window's last row (a reverse scan), from the
        next block on."""
        self.reverse = reverse

    def status(self, max_blocks: int | None = None) -> MonitorStatus:
        """The counters and the newest ``max_blocks`` (default: all kept) blocks."""
        with self._lock:
            blocks = tuple(self._blocks)
            if max_blocks is not None:
                blocks = blocks[len(blocks) - min(len(blocks), max(0, max_blocks)) :]
            return MonitorStatus(
                enabled=self.enabled,
                frames_per_block=self.frames_per_block,
                columns_max=self.columns_max,
                cpu_fraction=self.cpu_fraction,
                blocks_measured=self._measured,
                tdi_frames_seen=self._seen,
                frames_measured=self._frames_measured,
                cpu_s=self._cpu_s,
                blocks=blocks,
            )

    def start_log(self) -> MotionLog:
        """Keep every block measured from now on until ``stop_log`` (a recording starts,
        before its stream: a block being collected from an earlier stream is dropped)."""
        log = MotionLog()
        with self._lock:
            self._collecting = None
            self._logs.append(log)
        return log

    def add_listener(self, listener: Callable[[MotionBlock], None]) -> None:
        """Call ``listener(block)`` with every block measured from now on, on the monitor's
        thread (the image loop; it must not wait on the stream)."""
        with self._lock:
            self._listeners.append(listener)

    def remove_listener(self, listener: Callable[[MotionBlock], None]) -> None:
        with self._lock:
            if listener in self._listeners:
                self._listeners.remove(listener)

    def stop_log(self, log: MotionLog, *, wait_s: float = 0.0) -> None:
        """No more blocks for ``log``; with ``wait_s``, first wait that long at most for a block
        being measured (a recording that ends keeps its last block)."""
        deadline = time.monotonic() + wait_s
        with self._lock:
            while self._pending is not None and not self._closed:
                left = deadline - time.monotonic()
                if left <= 0:
                    break
                self._lock.wait(left)
            if log in self._logs:
                self._logs.remove(log)

    def close(self, timeout_s: float = 5.0) -> None:
        """Stop the worker (daemon shutdown)."""
        with self._lock:
            self._closed = True
            self._lock.notify_all()
        worker = self._worker
        if worker is not None:
            worker.join(timeout_s)


@dataclass(frozen=True, slots=True)
class MotionSummary:
    """The blocks of a recording summed up: their count, the measurable ones' means (None
    before the first) and the standard error of the mean dV/V from their scatter."""

    blocks: int
    measurable_blocks: int
    dv_over_v_mean: float | None
    m_dv_over_v_mean: float | None
    theta_deg_mean: float | None
    dv_over_v_sem: float | None
    latest: MotionBlock | None


def summarize(blocks: list[MotionBlock]) -> MotionSummary:
    """``MotionSummary`` of ``blocks`` (oldest first), as a recording's log sums them up."""
    log = MotionLog(max(1, len(blocks)))
    for block in blocks:
        log.add(block)
    return log.summary()


def warm_up() -> float:
    """Load the measurement (OpenCV, threadpoolctl) and run it once on a small made-up block,
    ahead of the first stream (``daemon.tdi_warm_up``): an import holds Python's lock for a
    tenth of a second or more, which on the monitor's thread during a scan would hold up the
    closed loop's thread too. Seconds it took."""
    start = time.perf_counter()
    import cv2  # noqa: F401  (loaded here, once)
    import threadpoolctl  # noqa: F401

    from camd.analysis.image_motion import measure_tdi_motion

    rng = np.random.default_rng(0)
    scene = rng.normal(1000.0, 100.0, (40, 64))
    frames = [scene[k : k + 16] for k in range(4)]
    measure_tdi_motion(frames, list(range(4)))
    return time.perf_counter() - start
