"""The live view's tap on the frame stream: the newest frame, at most a screen's rate.

``LiveTap`` is a stream consumer that stays attached to every stream (stare, stream, scan,
wheel). It runs on the stream's dispatcher thread, so it must cost next to nothing: a frame
arriving sooner than ``1 / max_rate_hz`` after the last one kept is only counted as skipped;
a frame that is kept is copied once (the reader reuses its buffers) and published as the
``latest`` ``LiveFrame``. Viewers (the HTTP and WebSocket endpoints) read that frame or wait
for a newer one; however many there are, the acquisition does the same work.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from camd.link.frame_stream import ReceivedFrame

MAX_RATE_HZ = 20.0
"""Frames a second the live view is given at most: more than a screen needs to look live."""


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
                rows=int(pixels.shape[0]),
                cols=int(pixels.shape[1]),
                skipped=self._skipped,
                gap_before=frame.gap_before,
                pixels=pixels,
            )
            self._skipped = 0
            self._cond.notify_all()

    def latest(self) -> LiveFrame | None:
        """The newest kept frame (None before the first)."""
        with self._cond:
            return self._latest

    def wait_newer(self, seq: int, timeout_s: float) -> LiveFrame | None:
        """The newest frame once it is newer than ``seq`` (None if none came in time)."""
        with self._cond:
            self._cond.wait_for(
                lambda: self._latest is not None and self._latest.seq > seq, timeout_s
            )
            latest = self._latest
        return latest if latest is not None and latest.seq > seq else None
