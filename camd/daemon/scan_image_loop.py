"""A scan's image loop: the line period and the drift taps follow the image's own motion.

``ScanImageLoop`` listens to the image motion monitor (``camd.pipeline.image_motion``) while its
scan runs. Each measured block goes through the pure ``camd.motion.image_loop.ImageLoop``
(docs/motion.md, "Closing the loop on the image"; docs/physics.md §10); the line period it asks
for is realised as the encoder's line-period loop realises its own (window rows and back path,
``period_setting``: never fewer rows than M, never more than the stream started with) and
written through the scan's register writer, and the drift goes to the TDI pipeline from its
next frame. A block measured before the last change reached the frames is not acted on (it
would ask again for what was just asked). It runs on the monitor's thread, off the
acquisition's path; an error (a lost link) stops the loop, not the scan, and says so.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from camd.daemon.errors import SessionError, unreachable
from camd.motion.closed_loop import LinePeriodSetting, period_setting
from camd.motion.image_loop import ImageLoop
from camd.pipeline.image_motion import COUNTER_WRAP, ImageMotionMonitor, MotionBlock
from camd.pipeline.tdi_pipeline import TdiPipeline

SETTLE_FRAMES = 4
"""Frames after a change before a block may start: the register write lands within a few."""


@dataclass
class ImageLoopRecord:
    """What the image loop saw and did, one row per block acted on (the scan's file)."""

    time_s: list[float] = field(default_factory=list)
    counter_first: list[float] = field(default_factory=list)
    shift_along_px_per_line: list[float] = field(default_factory=list)
    shift_across_px_per_line: list[float] = field(default_factory=list)
    block_line_period_s: list[float] = field(default_factory=list)
    line_period_s: list[float] = field(default_factory=list)
    cols_per_line: list[float] = field(default_factory=list)
    limited: list[float] = field(default_factory=list)

    def arrays(self) -> dict[str, np.ndarray]:
        return {k: np.asarray(v, dtype=np.float64) for k, v in self.__dict__.items()}


@dataclass(frozen=True, slots=True)
class LoopState:
    """The image loop's state: blocks acted on, the last setting, a limit reached, an error."""

    updates: int
    line_period_s: float
    cols_per_line: float
    limited: bool
    error: str | None

    def attributes(self) -> dict[str, object]:
        """As HDF5 attributes (no None)."""
        return {
            "updates": self.updates,
            "line_period_s": self.line_period_s,
            "cols_per_line": self.cols_per_line,
            "limited": self.limited,
            "error": self.error or "",
        }


class ScanImageLoop:
    """The image loop of one scan (module docstring). ``write_period`` realises a line period
    setting on the camera; ``events(level, message)`` logs for the scan."""

    def __init__(
        self,
        monitor: ImageMotionMonitor,
        pipeline: TdiPipeline,
        write_period: Callable[[LinePeriodSetting], None],
        *,
        line_period_s: float,
        row_time_s: float,
        stages: int,
        max_lines: int,
        rows_per_line: float,
        cols_per_line: float,
        gain: float,
        max_trim: float,
        max_cols_per_line: float,
        events: Callable[[str, str], None],
    ) -> None:
        self._monitor = monitor
        self._pipeline = pipeline
        self._write = write_period
        self._events = events
        self._row_time_s = row_time_s
        self._min_lines, self._max_lines = stages, max_lines
        # The rolling shutter's row time turns the frames' step into the image's speed; none
        # for a global shutter. The monitor learns which the sensor has when the scan's stream
        # starts (after this), so each block sets it (``_on_block``).
        self.loop = ImageLoop(
            line_period_s=line_period_s,
            row_time_s=row_time_s,
            rows_per_line=rows_per_line,
            cols_per_line=cols_per_line,
            gain=gain,
            max_trim=max_trim,
            max_cols_per_line=max_cols_per_line,
        )
        self.record = ImageLoopRecord()
        self.error: str | None = None
        self.limited = False
        self._settled_after: int | None = None  # counter: blocks from after it are acted on
        self._lock = threading.Lock()
        self._running = False

    def start(self) -> None:
        self._running = True
        self._monitor.add_listener(self._on_block)

    def stop(self) -> None:
        self._monitor.remove_listener(self._on_block)
        with self._lock:  # a block being acted on finishes first
            self._running = False

    def _on_block(self, block: MotionBlock) -> None:
        with self._lock:
            if not self._running or self.error is not None or not block.motion.measurable:
                return
            after = self._settled_after
            if after is not None and not 0 < (block.counter_first - after) % COUNTER_WRAP < (
                COUNTER_WRAP // 2
            ):
                return  # measured before the last change reached the frames
            motion = block.motion
            # the time between two rows of the frames as read (a binned row's is twice the
            # sensor's), as the monitor has it for the stream; 0 for a global shutter
            self.loop.row_time_s = self._monitor.row_time_s or 0.0
            setting = self.loop.update(
                motion.shift_along_px_per_line, motion.shift_across_px_per_line, block.line_period_s
            )
            window, short = period_setting(
                setting.line_period_s,
                self._row_time_s,
                min_lines=self._min_lines,
                max_lines=self._max_lines,
            )
            try:
                self._write(window)
                self._pipeline.request_drift(setting.cols_per_line)
            except SessionError as exc:  # the camera went away: one line, no trace
                self._stopped(f"image loop stopped: {unreachable(exc)}")
                return
            except Exception as exc:  # the scan goes on with what it has; say so
                self._stopped(f"image loop stopped: {exc}")
                return
            last = self._monitor.last_counter
            self._settled_after = None if last is None else (last + SETTLE_FRAMES) % COUNTER_WRAP
            limited = setting.limited or short
            if limited and not self.limited:
                self._events(
                    "warning",
                    "image loop at its limit: the line period is held within motion.max_trim "
                    "of the planned one, the drift within motion.image_max_cols_per_line, and "
                    "the window within M and the rows the stream started with",
                )
            self.limited = limited
            rec = self.record
            rec.time_s.append(time.time())
            rec.counter_first.append(float(block.counter_first))
            rec.shift_along_px_per_line.append(motion.shift_along_px_per_line)
            rec.shift_across_px_per_line.append(motion.shift_across_px_per_line)
            rec.block_line_period_s.append(block.line_period_s)
            rec.line_period_s.append(window.line_period_s)
            rec.cols_per_line.append(setting.cols_per_line)
            rec.limited.append(1.0 if limited else 0.0)

    def _stopped(self, message: str) -> None:
        self.error = message
        self._events("warning", f"{message}; the scan continues with the last setting")

    def info(self) -> LoopState:
        """The loop's state for the scan's status and file."""
        return LoopState(
            self.loop.updates,
            self.loop.line_period_s,
            self.loop.cols_per_line,
            self.limited,
            self.error,
        )
