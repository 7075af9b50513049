"""The live ROI monitor: every ROI's statistics on every frame of every stream, with a history.

``RoiMonitor`` is a stream consumer that stays attached to every stream, like ``LiveTap``
(``camd.pipeline.live``), but it is not decimated: as areaDetector's statistics plugin, it
measures every delivered frame at the stream's full rate (``camd.analysis.roi``: one
vectorised pass per ROI; a packed transfer's frames in one pass). Without ROIs it costs one
attribute test per frame.

The ROIs are replaced whole (``set_rois``), which starts a new history: the newest
``history_max`` frames' statistics with their frame counters, in a ring. A frame the ROIs do not
fit (a stream of a smaller window) is counted in ``unfit`` and not measured. The background
(``BackgroundCapture.ready``) is looked up once per frame or batch; its ROI means are computed
once per background.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from camd.analysis.roi import STAT_FIELDS, Roi, background_means, roi_stats, rois_problem
from camd.link.frame_stream import ReceivedFrame
from camd.link.packed import FrameBatch
from camd.pipeline.background import Background

HISTORY_MAX = 4096
"""Frames of ROI statistics kept by default: a few minutes at a bench's 20 frames/s."""
LOG_VALUES_MAX = 1 << 23
"""Statistics values a recording's ROI log keeps at most (64 MB of float64): with 4 ROIs the
first 262,144 frames; the frames past it are counted (``frames_dropped``), not kept."""


class RoiLog:
    """The ROI statistics of every frame measured while a recording is written, for its
    ``/roi`` group (``write_into``). Fed by the monitor while ``active``; it stops when the ROIs
    change (``rois_changed_at``: the counter of the last frame measured with them)."""

    def __init__(self, rois: tuple[Roi, ...]) -> None:
        self.rois = rois
        self.active = True
        self.frames_max = max(1, LOG_VALUES_MAX // max(1, len(rois) * len(STAT_FIELDS)))
        self._counters: list[npt.NDArray[np.int64]] = []
        self._stats: list[npt.NDArray[np.float64]] = []
        self.frames = 0
        self.frames_dropped = 0
        self.rois_changed_at: int | None = None

    def add(self, counters: npt.NDArray[np.int64], stats: npt.NDArray[np.float64]) -> None:
        room = self.frames_max - self.frames
        k = int(counters.shape[0])
        if room < k:
            self.frames_dropped += k - max(0, room)
            k = max(0, room)
        if k:
            self._counters.append(counters[:k].copy())
            self._stats.append(stats[:k])
            self.frames += k

    def write_into(self, f: Any) -> None:
        """Add the group ``/roi`` to the open HDF5 file ``f`` (an ``h5py.File``; a recording
        passes it while it finishes the file, so the group is written before the file counts
        as closed): ``frame_counter`` (n,) and, per ROI, a group of its name with its rectangle
        as attributes and one (n,) float64 dataset per statistic (``STAT_FIELDS``); the
        group's attributes say what was left out."""
        counters = np.concatenate(self._counters) if self._counters else np.zeros(0, np.int64)
        shape = (0, len(self.rois), len(STAT_FIELDS))
        stats = np.concatenate(self._stats) if self._stats else np.zeros(shape)
        group = f.create_group("roi")
        group.attrs.update(
            {
                "fields": list(STAT_FIELDS),
                "frames": self.frames,
                "frames_dropped": self.frames_dropped,
                "rois_changed_at": -1 if self.rois_changed_at is None else self.rois_changed_at,
            }
        )
        group.create_dataset("frame_counter", data=counters)
        for i, roi in enumerate(self.rois):
            sub = group.create_group(roi.name)
            sub.attrs.update({k: v for k, v in roi.as_dict().items() if k != "name"})
            for j, field in enumerate(STAT_FIELDS):
                sub.create_dataset(field, data=stats[:, i, j])


@dataclass(frozen=True, slots=True)
class RoiHistory:
    """The newest frames' statistics of the current ROIs (copies), oldest first."""

    rois_seq: int  # ROI sets so far (1, 2, ...): a new set starts a new history
    rois: tuple[Roi, ...]
    counter: npt.NDArray[np.int64]  # (n,) each frame's device counter
    timestamp_ns: npt.NDArray[np.int64]  # (n,) each frame's device time stamp
    stats: npt.NDArray[np.float64]  # (n, ROIs, STAT_FIELDS)
    measured: int  # frames measured since the ROIs were set
    unfit: int  # frames the ROIs did not fit (not measured)

    def roi(self, name: str) -> dict[str, Any]:
        """One ROI's history as plain values: {"counter": [...], "mean_dn": [...], ...}
        (NaN as None: JSON has no NaN)."""
        i = [r.name for r in self.rois].index(name)
        out: dict[str, Any] = {"counter": self.counter.tolist()}
        for j, field in enumerate(STAT_FIELDS):
            out[field] = _plain(self.stats[:, i, j])
        return out

    def latest(self) -> dict[str, Any] | None:
        """The newest frame's statistics of every ROI, as plain values (None before one)."""
        if self.counter.shape[0] == 0:
            return None
        last = self.stats[-1]
        return {
            "counter": int(self.counter[-1]),
            "timestamp_ns": int(self.timestamp_ns[-1]),
            "rois": {
                r.name: dict(zip(STAT_FIELDS, _plain(last[i]), strict=True))
                for i, r in enumerate(self.rois)
            },
        }


def _plain(values: npt.NDArray[np.float64]) -> list[float | int | None]:
    """Floats as JSON takes them: NaN -> None, whole counts as ints."""
    return [None if v != v else v for v in values.tolist()]


class RoiMonitor:
    """Every ROI's statistics on every frame (module docstring)."""

    def __init__(
        self,
        background: Callable[[], Background | None] = lambda: None,
        history_max: int = HISTORY_MAX,
    ) -> None:
        if history_max < 1:
            raise ValueError(f"history_max must be at least 1 frame, got {history_max}")
        self.history_max = history_max
        self._background = background
        self._lock = threading.Lock()
        self.rois: tuple[Roi, ...] = ()  # replaced whole: the dispatcher reads it once a call
        self._seq = 0
        self._bg_seq = -1  # the background whose ROI means are in _bg_means
        self._bg_means: npt.NDArray[np.float64] | None = None
        self._logs: list[RoiLog] = []
        self._last_counter: int | None = None
        self._reset_history()

    def _reset_history(self) -> None:
        n = len(self.rois)
        self._counter = np.zeros(self.history_max, dtype=np.int64)
        self._timestamp = np.zeros(self.history_max, dtype=np.int64)
        self._stats = np.zeros((self.history_max, n, len(STAT_FIELDS)))
        self._total = 0
        self._unfit = 0
        self._bg_seq = -1
        self._fitted: tuple[int, int] | None = None  # the frame geometry the ROIs fit

    def set_rois(self, rois: Sequence[Roi], rows: int, cols: int) -> None:
        """Measure ``rois`` from the next frame on (a new history); ValueError with what to
        change if they do not fit ``rows`` x ``cols`` frames, before anything changes."""
        problem = rois_problem(rois, rows, cols)
        if problem is not None:
            raise ValueError(problem)
        with self._lock:
            for log in self._logs:
                log.active = False
                log.rois_changed_at = self._last_counter
            self._logs = []
            self.rois = tuple(rois)
            self._seq += 1
            self._reset_history()

    def __call__(self, frame: ReceivedFrame) -> None:
        if not self.rois:
            return
        h = frame.header
        self._measure(
            frame.pixels,
            np.array([h.counter], dtype=np.int64),
            np.array([h.timestamp_ns], dtype=np.int64),
            h.bits,
        )

    def on_batch(self, batch: FrameBatch) -> None:
        """A packed transfer's frames in one pass per ROI."""
        if not self.rois:
            return
        fields = batch.fields
        self._measure(
            batch.pixels,
            fields["counter"].astype(np.int64),
            fields["timestamp_ns"].astype(np.int64),
            int(fields["bits"][0]),
        )

    def _measure(
        self,
        pixels: npt.NDArray[np.uint16],
        counters: npt.NDArray[np.int64],
        timestamps: npt.NDArray[np.int64],
        bits: int,
    ) -> None:
        with self._lock:
            rois = self.rois
            rows, cols = pixels.shape[-2:]
            if (rows, cols) != self._fitted:  # checked once per ROI set and frame geometry
                if rois_problem(rois, rows, cols) is not None:
                    self._unfit += counters.shape[0]
                    return
                self._fitted = (rows, cols)
            background = self._background()
            bg_seq = background.seq if background is not None else 0
            if bg_seq != self._bg_seq:
                fits = background is not None and background.pixels.shape == (rows, cols)
                self._bg_means = background_means(
                    background.pixels if fits and background is not None else None, rois
                )
                self._bg_seq = bg_seq
            stats = roi_stats(pixels, rois, bits, self._bg_means)
            k = stats.shape[0]
            keep = min(k, self.history_max)
            at = (self._total + np.arange(k - keep, k)) % self.history_max
            self._stats[at] = stats[k - keep :]
            self._counter[at] = counters[k - keep :]
            self._timestamp[at] = timestamps[k - keep :]
            self._total += k
            self._last_counter = int(counters[-1])
            for log in self._logs:
                log.add(counters, stats)

    def start_log(self) -> RoiLog | None:
        """Log every frame's statistics from the next one on (a recording starts), until
        ``stop_log`` or the ROIs change; None without ROIs."""
        with self._lock:
            if not self.rois:
                return None
            log = RoiLog(self.rois)
            self._logs.append(log)
            return log

    def stop_log(self, log: RoiLog) -> None:
        """No more frames for ``log`` (its recording has ended)."""
        with self._lock:
            log.active = False
            if log in self._logs:
                self._logs.remove(log)

    def history(self, max_frames: int | None = None) -> RoiHistory:
        """The newest ``max_frames`` (default: all kept) frames' statistics, oldest first."""
        with self._lock:
            n = min(self._total, self.history_max)
            if max_frames is not None:
                n = min(n, max(0, max_frames))
            at = np.arange(self._total - n, self._total) % self.history_max
            return RoiHistory(
                rois_seq=self._seq,
                rois=self.rois,
                counter=self._counter[at],
                timestamp_ns=self._timestamp[at],
                stats=self._stats[at],
                measured=self._total,
                unfit=self._unfit,
            )
