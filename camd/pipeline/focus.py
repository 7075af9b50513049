"""The live view's focus aid: a sharpness figure of the newest frames, with a history and the best.

``FocusMonitor`` measures the grey-gradient sharpness ``G`` (``camd.analysis.sharpness``,
docs/physics.md §7) of the whole frame and of each ROI defined (``camd.pipeline.roi``), so that an
operator turning the focus ring watches the figure rise to its peak and fall past it.

It is off the acquisition's critical path: it reads the live tap's kept frames (``LiveTap``, at
most 20 a second) on a thread of its own, at most ``rate_hz`` figures a second (default 4: a
2048 x 534 frame's figure costs about 30 ms of one core), and only while someone watches: a
thread starts at the first ``watch`` (every GET of the focus endpoint is one) and measures while
the last was less than ``watch_s`` ago; then it stops measuring until the next.

It keeps the newest ``history_max`` figures (a ring) and, per target (``"frame"`` and each ROI's
name), the best value so far with the frame it came from; ``reset_best`` forgets the best
(a new focusing), the history stays. ``G`` is computed on raw DN with no black level removed
(``black_dn`` 0): it compares frames of one exposure and gain, which is what focusing does.
A target with no figure (a frame or ROI of one row or column, or all pixels 0) is null.
"""

from __future__ import annotations

import collections
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from camd.analysis.roi import Roi
from camd.analysis.sharpness import grey_gradient_sharpness
from camd.pipeline.live import LiveFrame

FOCUS_RATE_HZ = 4.0
"""Figures a second at most: a focus ring turned by hand needs a few, not the stream's rate."""
FOCUS_HISTORY_MAX = 1200
"""Figures kept: five minutes at 4 a second."""
FOCUS_WATCH_S = 30.0
"""Measuring goes on this long after the last look at the figures (the page looks every second)."""
FRAME_TARGET = "frame"
"""The whole frame's target name (an ROI may not take it: ROI names are checked by the monitor)."""


@dataclass(frozen=True, slots=True)
class FocusPoint:
    """The figures of one frame: per target, ``G`` or None where it has none."""

    seq: int  # the live tap's seq of the frame
    counter: int  # the device's frame counter
    t_s: float  # wall-clock time of the measurement, s since the epoch
    values: dict[str, float | None]


@dataclass(slots=True)
class FocusBest:
    """A target's best figure so far, and the frame it came from."""

    value: float
    counter: int
    seq: int
    t_s: float


@dataclass
class FocusSnapshot:
    """What ``FocusMonitor.snapshot`` gives: the history (oldest first) and the best."""

    rate_hz: float
    watching: bool
    measured: int
    history: list[FocusPoint] = field(default_factory=list)
    best: dict[str, FocusBest] = field(default_factory=dict)


def focus_values(frame: LiveFrame, rois: Sequence[Roi]) -> dict[str, float | None]:
    """``G`` of the whole frame and of each ROI that fits it (module docstring)."""
    values: dict[str, float | None] = {FRAME_TARGET: _sharpness(frame.pixels)}
    for roi in rois:
        if roi.y + roi.height <= frame.rows and roi.x + roi.width <= frame.cols:
            part = frame.pixels[roi.y : roi.y + roi.height, roi.x : roi.x + roi.width]
            values[roi.name] = _sharpness(part)
        else:
            values[roi.name] = None  # a smaller window than the ROI's
    return values


def _sharpness(pixels: np.ndarray[Any, Any]) -> float | None:
    try:
        return grey_gradient_sharpness(pixels)
    except ValueError:  # one row or column, or a zero mean: no figure, not an error
        return None


class FocusMonitor:
    """Sharpness of the live tap's frames, measured while watched (module docstring).

    ``wait_newer(seq, timeout_s)`` is the live tap's; ``rois()`` the ROIs defined now.
    """

    def __init__(
        self,
        wait_newer: Callable[[int, float], LiveFrame | None],
        rois: Callable[[], Sequence[Roi]],
        *,
        rate_hz: float = FOCUS_RATE_HZ,
        history_max: int = FOCUS_HISTORY_MAX,
        watch_s: float = FOCUS_WATCH_S,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if not rate_hz > 0 or history_max < 1 or not watch_s > 0:
            raise ValueError(
                f"need rate_hz > 0, history_max >= 1, watch_s > 0; got {rate_hz}, "
                f"{history_max}, {watch_s}"
            )
        self.rate_hz = rate_hz
        self.watch_s = watch_s
        self._wait_newer = wait_newer
        self._rois = rois
        self._clock = clock
        self._lock = threading.Lock()
        self._wake = threading.Condition(self._lock)
        self._history: collections.deque[FocusPoint] = collections.deque(maxlen=history_max)
        self._best: dict[str, FocusBest] = {}
        self._measured = 0
        self._watched_at = -float("inf")
        self._thread: threading.Thread | None = None
        self._closed = False

    # -- from the API -----------------------------------------------------------------------------

    def watch(self) -> None:
        """Someone looks at the figures: measure (on) for ``watch_s`` from now."""
        with self._lock:
            if self._closed:
                return
            self._watched_at = self._clock()
            if self._thread is None:
                self._thread = threading.Thread(target=self._run, name="camd-focus", daemon=True)
                self._thread.start()
            self._wake.notify_all()

    def watching(self) -> bool:
        with self._lock:
            return self._is_watched()

    def reset_best(self) -> None:
        """Forget the best figures (a new focusing starts); the history stays."""
        with self._lock:
            self._best.clear()

    def snapshot(self, history: int) -> FocusSnapshot:
        """The newest ``history`` figures (0: only the newest one) and the best so far."""
        with self._lock:
            points = list(self._history)
            keep = max(history, 1)
            return FocusSnapshot(
                rate_hz=self.rate_hz,
                watching=self._is_watched(),
                measured=self._measured,
                history=points[-keep:],
                best={
                    k: FocusBest(b.value, b.counter, b.seq, b.t_s) for k, b in self._best.items()
                },
            )

    def close(self, timeout_s: float = 5.0) -> None:
        """Stop the thread (at shutdown)."""
        with self._lock:
            self._closed = True
            self._wake.notify_all()
            thread = self._thread
        if thread is not None:
            thread.join(timeout_s)

    # -- measuring ----------------------------------------------------------------------------------

    def add(self, frame: LiveFrame) -> FocusPoint:
        """Measure ``frame`` now (the thread's step; also for an in-process caller)."""
        values = focus_values(frame, self._rois())
        point = FocusPoint(frame.seq, frame.counter, time.time(), values)
        with self._lock:
            self._history.append(point)
            self._measured += 1
            for target, value in values.items():
                best = self._best.get(target)
                if value is not None and (best is None or value > best.value):
                    self._best[target] = FocusBest(value, frame.counter, frame.seq, point.t_s)
        return point

    def _is_watched(self) -> bool:
        return self._clock() - self._watched_at < self.watch_s

    def _run(self) -> None:
        seq = 0
        interval_s = 1.0 / self.rate_hz
        while True:
            with self._lock:
                # Asleep while nobody watches: no figure is computed for nobody.
                self._wake.wait_for(lambda: self._closed or self._is_watched())
                if self._closed:
                    return
            started = self._clock()
            frame = self._wait_newer(seq, 1.0)
            if frame is None:
                continue
            seq = frame.seq
            self.add(frame)
            # At most rate_hz figures a second, whatever the frame rate.
            rest = interval_s - (self._clock() - started)
            if rest > 0:
                with self._lock:
                    self._wake.wait_for(lambda: self._closed, rest)
