"""The live view's taps: the newest frame of every stream, and the newest lines of a scan.

``LiveTap`` is a stream consumer that stays attached to every stream (stare, stream, scan,
wheel). It runs on the stream's dispatcher thread, so it must cost next to nothing: a frame
arriving sooner than ``1 / max_rate_hz`` after the last one kept is only counted as skipped;
a frame that is kept is copied once (the reader reuses its buffers) and published as the
``latest`` ``LiveFrame``. Viewers (the HTTP and WebSocket endpoints) read that frame or wait
for a newer one; however many there are, the acquisition does the same work.

``LiveLines`` keeps the newest integrated lines of the running (or last) TDI scan for the live
view's waterfall: a ring of ``capacity`` float32 rows with each line's index, completeness flag
and stages used. The TDI worker appends each block of lines it makes with one copy into the
ring; viewers ask for the lines newer than the last index they have, or wait for them.
"""

from __future__ import annotations

import bisect
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from camd.link.frame_stream import ReceivedFrame
from camd.link.packed import FrameBatch

MAX_RATE_HZ = 20.0
"""Frames a second the live view is given at most: more than a screen needs to look live."""

RECENT_FRAMES = 40
"""Kept frames the tap holds by seq, the newest included: two seconds at 20 a second, so that a
viewer asking for the frame it shows (a snapshot, a binned viewer's pixel readout) finds it,
though the tap has moved on, even when a loaded machine delays the question (5 frames, a
quarter of a second, was seen to be too few for a readout). RECENT_BYTES_MAX bounds them."""

RECENT_BYTES_MAX = 64 * 2**20
"""... but no more pixel bytes than this, the newest frame always: a 534 x 2048 window keeps 30,
a 4096 x 4096 window two."""


@dataclass(frozen=True, slots=True)
class LiveFrame:
    """One frame kept for the live view (``pixels`` is the tap's own copy)."""

    seq: int  # frames kept by the tap so far, this one included (1, 2, ...)
    index: int  # frames offered to the tap so far, this one included: a viewer that got the
    # frame of index i and then this one skipped ``index - i - 1`` frames
    counter: int  # the device's frame counter
    timestamp_ns: int  # the device's time stamp of the frame
    mode: str  # the stream's mode as the frame header gives it ("area", "tdi", ...)
    stages: int  # TDI stages the device summed (1 in area mode)
    bits: int  # significant bits per pixel: full scale is 2**bits - 1 (the clipping overlay's)
    rows: int
    cols: int
    skipped: int  # frames passed over since the previous kept one
    gap_before: int  # frames the stream lost just before this one
    pixels: npt.NDArray[np.uint16]

    def meta(self) -> dict[str, int | str]:
        """Everything but the pixels, as plain values (the endpoints send it as JSON)."""
        return {
            "seq": self.seq,
            "index": self.index,
            "counter": self.counter,
            "timestamp_ns": self.timestamp_ns,
            "mode": self.mode,
            "stages": self.stages,
            "bits": self.bits,
            "rows": self.rows,
            "cols": self.cols,
            "skipped": self.skipped,
            "gap_before": self.gap_before,
            "dtype": "<u2",
        }


class LiveTap:
    """The newest frame of the stream, decimated to ``max_rate_hz`` (module docstring)."""

    def __init__(
        self, max_rate_hz: float = MAX_RATE_HZ, clock: Callable[[], float] = time.monotonic
    ) -> None:
        if not max_rate_hz > 0:
            raise ValueError(f"max_rate_hz must be > 0, got {max_rate_hz}")
        self.min_interval_s = 1.0 / max_rate_hz
        self._clock = clock
        self._cond = threading.Condition()
        self._latest: LiveFrame | None = None
        self._recent: deque[LiveFrame] = deque(maxlen=RECENT_FRAMES)
        self._last_kept_s = -float("inf")
        self._skipped = 0
        self.kept = 0  # frames kept so far
        self.seen = 0  # frames offered so far

    def __call__(self, frame: ReceivedFrame) -> None:
        self.seen += 1
        now = self._clock()
        if now - self._last_kept_s < self.min_interval_s:
            self._skipped += 1
            return
        self._last_kept_s = now
        header = frame.header
        pixels = np.array(frame.pixels, dtype=np.uint16, copy=True)
        pixels.setflags(write=False)
        with self._cond:
            self.kept += 1
            self._latest = LiveFrame(
                seq=self.kept,
                index=self.seen,
                counter=header.counter,
                timestamp_ns=header.timestamp_ns,
                mode=header.mode.name.lower(),
                stages=header.stages,
                bits=header.bits,
                rows=int(pixels.shape[0]),
                cols=int(pixels.shape[1]),
                skipped=self._skipped,
                gap_before=frame.gap_before,
                pixels=pixels,
            )
            self._recent.append(self._latest)
            held = sum(f.pixels.nbytes for f in self._recent)
            while len(self._recent) > 1 and held > RECENT_BYTES_MAX:
                held -= self._recent.popleft().pixels.nbytes
            self._skipped = 0
            self._cond.notify_all()

    def on_batch(self, batch: FrameBatch) -> None:
        """A run of frames (a packed transfer's): what a call per frame would keep, with one
        look at the clock (the first frame, if one is due), without a header per frame."""
        k = batch.count
        if self._clock() - self._last_kept_s < self.min_interval_s:
            self.seen += k
            self._skipped += k
            return
        self(
            ReceivedFrame(
                batch.header(0),
                batch.pixels[0],
                batch.received_ns,
                batch.gap_before,
                batch.first_index,
            )
        )
        self.seen += k - 1
        self._skipped += k - 1

    def latest(self) -> LiveFrame | None:
        """The newest kept frame (None before the first)."""
        with self._cond:
            return self._latest

    def frame(self, seq: int) -> LiveFrame | None:
        """The kept frame ``seq`` if the tap still holds it (the newest ``RECENT_FRAMES``)."""
        with self._cond:
            return next((f for f in self._recent if f.seq == seq), None)

    def held(self) -> tuple[int, int] | None:
        """The oldest and newest seq the tap holds (None before the first frame)."""
        with self._cond:
            return (self._recent[0].seq, self._recent[-1].seq) if self._recent else None

    def wait_newer(self, seq: int, timeout_s: float) -> LiveFrame | None:
        """The newest frame once it is newer than ``seq`` (None if none came in time)."""
        with self._cond:
            self._cond.wait_for(
                lambda: self._latest is not None and self._latest.seq > seq, timeout_s
            )
            latest = self._latest
        return latest if latest is not None and latest.seq > seq else None


LINES_CAPACITY = 2048
"""Lines ``LiveLines`` keeps by default: a screen's height of waterfall, and then some."""


@dataclass(frozen=True, slots=True)
class LiveLinesChunk:
    """Lines of one scan newer than an index, as ``LiveLines.since`` gives them (copies)."""

    scan: str  # what the scan is called (the daemon gives its file)
    scan_seq: int  # scans seen so far, this one included (1, 2, ...): a new one restarts indices
    cols: int
    data: npt.NDArray[np.float32]  # (n, cols), oldest first
    index: npt.NDArray[np.int64]  # (n,) each line's index (= its frame's; lost frames have none)
    complete: npt.NDArray[np.bool_]  # (n,) all M stages contributed
    stages_used: npt.NDArray[np.int32]  # (n,)
    skipped: int  # lines newer than ``after`` that are not here: left the ring, or cut by max
    lines_done: int  # lines the scan has made so far
    lines_planned: int  # lines it will make (0: until stopped)
    state: str  # "running" until the scan ends, then how it ended

    @property
    def n(self) -> int:
        return int(self.index.shape[0])

    def meta(self) -> dict[str, Any]:
        """Everything but the line data, as plain values (the endpoint sends it as JSON)."""
        return {
            "scan": self.scan,
            "scan_seq": self.scan_seq,
            "first_index": int(self.index[0]) if self.n else None,
            "n": self.n,
            "cols": self.cols,
            "index": self.index.tolist(),
            "complete": self.complete.tolist(),
            "stages_used": self.stages_used.tolist(),
            "skipped": self.skipped,
            "lines_done": self.lines_done,
            "lines_planned": self.lines_planned,
            "state": self.state,
            "dtype": "<f4",
        }


class LiveLines:
    """The newest ``capacity`` lines of the running (or last) scan (module docstring).

    ``reset`` at each scan's start, ``append`` from the TDI worker (one copy into the ring, no
    per-line work), ``end`` when the scan ends; ``since`` and ``wait_newer`` from any thread.
    Line indices must increase; they may jump (frames lost on the way have no line). To count
    exactly the lines a late viewer missed, the first index and line number of every run of
    consecutive indices are kept (one pair per gap in the scan).
    """

    def __init__(self, capacity: int = LINES_CAPACITY) -> None:
        if capacity < 1:
            raise ValueError(f"capacity must be at least 1 line, got {capacity}")
        self.capacity = capacity
        self._cond = threading.Condition()
        self._scan: str | None = None
        self._scan_seq = 0
        self._version = 0  # changes at each reset and end: wakes waiting viewers
        self._lines_planned = 0
        self._state = "none"
        self._cols = 0
        self._data = np.zeros((0, 0), dtype=np.float32)
        self._index = np.zeros(capacity, dtype=np.int64)
        self._complete = np.zeros(capacity, dtype=np.bool_)
        self._stages = np.zeros(capacity, dtype=np.int32)
        self._total = 0  # lines appended to this scan
        self._run_index: list[int] = []  # first index of each run of consecutive indices
        self._run_line: list[int] = []  # its line number (0, 1, ... in appending order)

    @property
    def scan(self) -> str | None:
        """The scan whose lines these are (None before the first)."""
        with self._cond:
            return self._scan

    def reset(self, cols: int, *, scan: str, lines_planned: int = 0) -> None:
        """A new scan of ``cols``-column lines starts: forget the last one's lines."""
        if cols < 1:
            raise ValueError(f"cols must be at least 1, got {cols}")
        with self._cond:
            if self._data.shape != (self.capacity, cols):
                self._data = np.zeros((self.capacity, cols), dtype=np.float32)
            self._cols = cols
            self._scan, self._lines_planned, self._state = scan, max(0, lines_planned), "running"
            self._scan_seq += 1
            self._version += 1
            self._total = 0
            self._run_index, self._run_line = [], []
            self._cond.notify_all()

    def end(self, state: str) -> None:
        """The scan has ended (``state``: "done", "stopped", "failed")."""
        with self._cond:
            self._state = state
            self._version += 1
            self._cond.notify_all()

    def append(
        self,
        data: npt.NDArray[Any],
        index: npt.NDArray[Any],
        complete: npt.NDArray[Any],
        stages_used: npt.NDArray[Any],
    ) -> None:
        """Add F lines (a ``TdiBlock``'s arrays: data (F, cols), index, complete, stages_used),
        converted to float32 as they are copied into the ring. ValueError for a wrong shape or
        an index not above the last one, before anything is kept."""
        lines = np.asarray(data)
        idx = np.asarray(index)
        n = int(idx.shape[0]) if idx.ndim == 1 else -1
        if n == 0:
            return
        with self._cond:
            if self._scan is None:
                raise ValueError("LiveLines.append before reset: no scan has started")
            if (
                lines.shape != (n, self._cols)
                or np.shape(complete) != (n,)
                or np.shape(stages_used) != (n,)
            ):
                raise ValueError(
                    f"append takes F lines of {self._cols} columns with F indices, flags and "
                    f"stage counts; got data {lines.shape}, index {idx.shape}, complete "
                    f"{np.shape(complete)}, stages_used {np.shape(stages_used)}"
                )
            last = self._run_last_index()
            steps = np.diff(idx)
            if (last is not None and int(idx[0]) <= last) or bool((steps <= 0).any()):
                raise ValueError(
                    f"line indices must increase: got {int(idx[0])}..{int(idx[-1])} after {last}"
                )
            # Runs of consecutive indices: one per jump (the engine's blocks have none inside).
            starts = [0] if last is None or int(idx[0]) != last + 1 else []
            starts += (np.flatnonzero(steps != 1) + 1).tolist()
            for i in starts:
                self._run_index.append(int(idx[i]))
                self._run_line.append(self._total + i)
            # Into the ring, wrapping at its end: the newest ``keep`` lines (all of them unless
            # the block is longer than the ring), float32 by the assignment's cast.
            keep = min(n, self.capacity)
            first = (self._total + n - keep) % self.capacity
            head = min(keep, self.capacity - first)  # rows that fit before the ring's end
            pieces = [(slice(first, first + head), slice(n - keep, n - keep + head))]
            if head < keep:
                pieces.append((slice(0, keep - head), slice(n - keep + head, n)))
            flags, stages = np.asarray(complete), np.asarray(stages_used)
            for dst, src in pieces:
                self._data[dst] = lines[src]
                self._index[dst] = idx[src]
                self._complete[dst] = flags[src]
                self._stages[dst] = stages[src]
            self._total += n
            self._cond.notify_all()

    def since(self, after: int, max_lines: int = LINES_CAPACITY) -> LiveLinesChunk | None:
        """The newest lines with index > ``after`` (at most ``max_lines``, the newest ones),
        with how many such lines are left out; None before the first scan."""
        if max_lines < 1:
            raise ValueError(f"max_lines must be at least 1, got {max_lines}")
        with self._cond:
            if self._scan is None:
                return None
            total = self._total
            newer = total - self._lines_upto(after)
            n = min(newer, max_lines, self.capacity)
            rows = np.arange(total - n, total) % self.capacity
            return LiveLinesChunk(
                scan=self._scan,
                scan_seq=self._scan_seq,
                cols=self._cols,
                data=self._data[rows],
                index=self._index[rows],
                complete=self._complete[rows],
                stages_used=self._stages[rows],
                skipped=newer - n,
                lines_done=total,
                lines_planned=self._lines_planned,
                state=self._state,
            )

    def wait_newer(self, after: int, timeout_s: float) -> bool:
        """Wait until there is a line with index > ``after``, or a scan starts or ends, for at
        most ``timeout_s``; True if there is such a line then."""
        with self._cond:
            version = self._version
            self._cond.wait_for(
                lambda: self._newest_beyond(after) or self._version != version, timeout_s
            )
            return self._newest_beyond(after)

    # -- internals (with the lock held) ---------------------------------------------------------

    def _run_last_index(self) -> int | None:
        if not self._run_index:
            return None
        return self._run_index[-1] + (self._total - self._run_line[-1]) - 1

    def _newest_beyond(self, after: int) -> bool:
        last = self._run_last_index()
        return last is not None and last > after

    def _lines_upto(self, after: int) -> int:
        """How many of the scan's lines have an index <= ``after``."""
        run = bisect.bisect_right(self._run_index, after) - 1
        if run < 0:
            return 0
        end = self._run_line[run + 1] if run + 1 < len(self._run_line) else self._total
        return self._run_line[run] + min(
            after - self._run_index[run] + 1, end - self._run_line[run]
        )
