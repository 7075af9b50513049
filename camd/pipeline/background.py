"""The live view's background: the mean of N frames of the stream, captured on demand.

``BackgroundCapture`` is a stream consumer that stays attached to every stream, like
``LiveTap`` (``camd.pipeline.live``). It runs on the stream's dispatcher thread and costs one
attribute test per frame until ``start(frames)`` arms it; it then sums the next ``frames``
frames in a float64 accumulator and publishes their mean as a read-only float32 image, a
``Background``, with where it came from (counters, geometry) and its spatial mean and standard
deviation. Viewers subtract it from live frames; the daemon stores it in every recording
started while it is ready (``Background.recording_attrs``) and notes where (``note_saved``).

All frames of one background have the geometry of the first: a frame of other rows, columns,
mode or TDI stages, or the first frame of a new stream, fails the capture (the message says
what changed, and to capture again). Starting a capture drops the background there was;
``clear()`` drops both. ``snapshot()`` reads the state at any time from any thread.
"""

from __future__ import annotations

import datetime as dt
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
import numpy.typing as npt

from camd.link.frame_stream import ReceivedFrame
from camd.link.packed import FrameBatch

FRAMES_MIN = 1
FRAMES_MAX = 1000
"""Frames one background may average: 1..1000 (a few seconds of a fast stream)."""
FRAMES_DEFAULT = 16
SAVED_MAX = 20
"""Recording paths a background remembers (``saved_to``: the newest ones)."""

BackgroundState = Literal["none", "capturing", "ready", "failed"]


@dataclass(frozen=True, slots=True)
class Background:
    """A captured background: the mean of ``frames`` frames (``pixels``, float32, read-only)."""

    seq: int  # completed captures so far, this one included (1, 2, ...)
    frames: int
    rows: int
    cols: int
    mode: str  # the frames' mode as their headers give it ("area", "tdi")
    stages: int  # TDI stages as the frame headers give them (0 in area mode)
    first_counter: int  # the device's counter of the first frame averaged
    last_counter: int  # ... and of the last
    captured_t_s: float  # Unix time the last frame came in
    mean_dn: float  # spatial mean of the mean image, DN
    std_dn: float  # spatial standard deviation of the mean image, DN
    pixels: npt.NDArray[np.float32]

    def _what(self) -> dict[str, int | str]:
        """What was averaged: frames, geometry, mode and the frames' counters."""
        return {
            "frames": self.frames,
            "rows": self.rows,
            "cols": self.cols,
            "mode": self.mode,
            "stages": self.stages,
            "first_counter": self.first_counter,
            "last_counter": self.last_counter,
        }

    def meta(self) -> dict[str, int | float | str]:
        """Everything but the pixels, as plain values (the endpoints send it as JSON)."""
        return {
            "seq": self.seq,
            **self._what(),
            "captured_t_s": self.captured_t_s,
            "mean_dn": self.mean_dn,
            "std_dn": self.std_dn,
            "dtype": "<f4",
        }

    def recording_attrs(self) -> dict[str, int | str]:
        """The attributes of a recording's ``/background`` group (its ``mean_dn`` dataset is
        ``pixels``)."""
        captured = dt.datetime.fromtimestamp(self.captured_t_s, dt.UTC)
        return {**self._what(), "captured_utc": captured.isoformat(timespec="milliseconds")}


@dataclass(frozen=True, slots=True)
class BackgroundSnapshot:
    """The capture's state at one moment. While capturing (and after a failure) the geometry
    and counters are those of the frames taken so far; ``background`` is set when ready."""

    state: BackgroundState
    frames_wanted: int | None = None
    frames_done: int | None = None
    rows: int | None = None
    cols: int | None = None
    mode: str | None = None
    stages: int | None = None
    first_counter: int | None = None
    last_counter: int | None = None
    background: Background | None = None
    saved_to: tuple[str, ...] = ()
    error: str | None = None


class _Job:
    """One capture in progress. Only the dispatcher thread touches ``total``."""

    def __init__(self, frames: int) -> None:
        self.wanted = frames
        self.done = 0
        self.total: npt.NDArray[np.float64] | None = None
        self.rows = self.cols = self.stages = 0
        self.mode = ""
        self.first_counter = self.last_counter = 0


def _geometry(frame: ReceivedFrame) -> tuple[int, int, str, int]:
    header = frame.header
    rows, cols = frame.pixels.shape
    return int(rows), int(cols), header.mode.name.lower(), int(header.stages)


class BackgroundCapture:
    """The mean of the next N frames of the stream, on demand (module docstring)."""

    def __init__(self, saved_max: int = SAVED_MAX, clock: Callable[[], float] = time.time) -> None:
        self._saved_max = saved_max
        self._clock = clock
        self._lock = threading.Lock()
        self._job: _Job | None = None  # the capture running, read without the lock per frame
        self._state: BackgroundState = "none"
        self._last_job: _Job | None = None  # the running, failed or finished capture
        self._background: Background | None = None
        self._saved_to: list[str] = []
        self._error: str | None = None
        self._seq = 0

    # -- the stream consumer (dispatcher thread) -----------------------------------------------

    def __call__(self, frame: ReceivedFrame) -> None:
        job = self._job
        if job is None:
            return
        geometry = _geometry(frame)
        counter = frame.header.counter
        total = job.total  # another thread may drop the job's sum (``fail``): keep this one
        if job.done:
            if total is None:
                return  # failed meanwhile
            problem = self._problem(job, frame, geometry)
            if problem is not None:
                self._fail(job, problem)
                return
            np.add(total, frame.pixels, out=total)
        else:
            job.rows, job.cols, job.mode, job.stages = geometry
            job.first_counter = counter
            total = job.total = frame.pixels.astype(np.float64)
        with self._lock:
            if self._job is not job:
                return  # cleared, failed or restarted meanwhile
            job.last_counter = counter
            job.done += 1
            if job.done < job.wanted:
                return
        self._complete(job, total)

    def on_batch(self, batch: FrameBatch) -> None:
        """A run of frames (a packed transfer's): nothing to do unless a background is being
        captured; then frame by frame, as ever."""
        if self._job is None:
            return
        for i in range(batch.count):
            self(
                ReceivedFrame(
                    batch.header(i),
                    batch.pixels[i],
                    batch.received_ns,
                    batch.gap_before if i == 0 else 0,
                    batch.first_index + i,
                )
            )

    @staticmethod
    def _problem(
        job: _Job, frame: ReceivedFrame, geometry: tuple[int, int, str, int]
    ) -> str | None:
        """Why ``frame`` cannot join the frames so far (None if it can)."""
        so_far = f"after {job.done} of {job.wanted} frames"
        if frame.index == 0:
            return (
                f"the stream ended {so_far} and another one started; the background needs "
                f"{job.wanted} frames of one stream: capture again while streaming"
            )
        rows, cols, mode, stages = geometry
        changes = []
        if (rows, cols) != (job.rows, job.cols):
            changes.append(f"{job.rows} x {job.cols} -> {rows} x {cols} pixels")
        if mode != job.mode:
            changes.append(f"mode {job.mode} -> {mode}")
        if stages != job.stages:
            changes.append(f"stages {job.stages} -> {stages}")
        if not changes:
            return None
        return (
            f"the frames changed {so_far}: {', '.join(changes)} at frame counter "
            f"{frame.header.counter}; all frames of a background must be alike: capture again "
            "once the window, mode and stages are settled"
        )

    def _complete(self, job: _Job, total: npt.NDArray[np.float64]) -> None:
        mean = (total / job.done).astype(np.float32)
        mean.setflags(write=False)
        mean_dn = float(mean.mean(dtype=np.float64))
        std_dn = float(mean.std(dtype=np.float64))
        with self._lock:
            if self._job is not job:
                return
            self._seq += 1
            self._background = Background(
                seq=self._seq,
                frames=job.done,
                rows=job.rows,
                cols=job.cols,
                mode=job.mode,
                stages=job.stages,
                first_counter=job.first_counter,
                last_counter=job.last_counter,
                captured_t_s=self._clock(),
                mean_dn=mean_dn,
                std_dn=std_dn,
                pixels=mean,
            )
            self._job = None
            self._state = "ready"
        job.total = None  # the sum is no longer needed

    def _fail(self, job: _Job, why: str) -> None:
        with self._lock:
            if self._job is not job:
                return
            self._job = None
            self._state = "failed"
            self._error = why
        job.total = None

    def _begin(self, job: _Job | None) -> None:
        """From nothing: a capture of ``job`` ("capturing"), or none at all ("none")."""
        with self._lock:
            self._job = self._last_job = job
            self._state = "none" if job is None else "capturing"
            self._background = None
            self._saved_to = []
            self._error = None

    # -- requests (any thread) --------------------------------------------------------------------

    def start(self, frames: int = FRAMES_DEFAULT) -> None:
        """Average the next ``frames`` frames (1..1000); drops the background there was."""
        if not FRAMES_MIN <= frames <= FRAMES_MAX:
            raise ValueError(
                f"frames must be {FRAMES_MIN}..{FRAMES_MAX} for a background, got {frames}"
            )
        self._begin(_Job(frames))

    def fail(self, why: str, then: str) -> bool:
        """Fail the running capture (the daemon: its stream ended) with the message "``why``
        after k of N frames; ``then``"; False if none runs."""
        with self._lock:
            job = self._job
        if job is None:
            return False
        self._fail(job, f"{why} after {job.done} of {job.wanted} frames; {then}")
        return True

    def clear(self) -> None:
        """Drop the background and stop a capture: the state is "none" again."""
        self._begin(None)

    def ready(self) -> Background | None:
        """The background, when one is ready."""
        with self._lock:
            return self._background

    def note_saved(self, background: Background, path: str) -> None:
        """``background`` went into the recording ``path`` (ignored if it is no longer the
        current one)."""
        with self._lock:
            if self._background is not background:
                return
            self._saved_to.append(path)
            del self._saved_to[: -self._saved_max]

    def snapshot(self) -> BackgroundSnapshot:
        """The state, the progress or the background, and where it was saved."""
        with self._lock:
            job, state = self._last_job, self._state
            if job is None:
                return BackgroundSnapshot(state=state)
            seen: dict[str, Any] = {}
            if job.done:
                seen = {
                    "rows": job.rows,
                    "cols": job.cols,
                    "mode": job.mode,
                    "stages": job.stages,
                    "first_counter": job.first_counter,
                    "last_counter": job.last_counter,
                }
            return BackgroundSnapshot(
                state=state,
                frames_wanted=job.wanted,
                frames_done=job.done,
                background=self._background,
                saved_to=tuple(self._saved_to),
                error=self._error,
                **seen,
            )
