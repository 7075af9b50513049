"""The frame stream's bookkeeping: which counters came, which are missing, what was delivered.

``FrameLedger`` holds a run's ``StreamStats`` and the counter bookkeeping behind them: the last
counter seen in order (``in_sequence``: a gap counts as ``lost``, a step back is out of order),
broken transfers that each stand for one frame of a later gap (``broken``), the stream's end
as the device announces it (``expect_end``, a frame flagged LAST) or its first counter
(``expect_first``), and what the dispatcher delivered (``account``). Frames of an earlier run
that arrive after it ended (a device that sent the frames it had counted late, after the host
had stopped reading that run) are set aside as ``late``: they are not this run's. It also keeps
the last problem seen and the error that ended the reader. Every field is under ``cond``, the
stream's one lock (shared with ``camd.link.frame_queue``); the reader and the dispatcher call
in with it held where they already hold it for the queue.
"""

from __future__ import annotations

import dataclasses
import threading
import time
from dataclasses import dataclass

from camd.link.frame_types import StreamError, StreamStats, log
from camd.protocol.stream import U32_WRAP, FrameHeader


@dataclass(slots=True)
class Delivered:
    """What a packed transfer's dispatch delivered, for ``FrameLedger.account``."""

    frames: int = 0
    bytes: int = 0
    pixels: int = 0
    corrupt: int = 0
    first_counter: int | None = None
    last_counter: int | None = None


class FrameLedger:
    """A run's counters and their bookkeeping (module docstring), for the stream ``ident``."""

    def __init__(self, cond: threading.Condition, ident: str) -> None:
        self.cond = cond
        self.ident = ident
        self.stats = StreamStats()
        self.pixels = 0
        self.t_start = 0.0
        self.t_stop: float | None = None
        self.t_last_frame: float | None = None  # when the last frame was delivered
        self.last_seen: int | None = None  # counter of the last good header, in order
        self.first_seen: int | None = None  # the stream's first good header
        self.unattributed = 0  # broken transfers since then, each one frame of a gap
        self.broken_before_first = 0  # broken transfers before the first good header
        self.end: int | None = None  # expect_end's counter, until accounted
        self.ended_at: int | None = None  # the last end accounted (``settle_end``)
        self.end_told = 0.0  # when expect_end last said where the run ended (monotonic)
        # Frames before this counter belong to an earlier run (``is_late``): where the last run
        # ended, until the device says where this one starts (``expect_first``); None: unknown.
        self.run_start: int | None = None
        self.late = 0  # frames of an earlier run set aside in this one
        self.frame_in = False  # a frame of this run came (its counter known)
        # Kinds of the broken transfers without a counter before it: those beyond the counters
        # missing before this run's first are an earlier run's (``_set_aside_early``).
        self.early_broken: list[str] = []
        self.error: StreamError | None = None
        self.problem: str | None = None

    def reset(self) -> None:
        """A new run: counters from zero, nothing seen (lock held). Frames of the run before
        may still be on their way (the device counted them, the host stopped reading before
        they came): those before where it ended are late, not this run's."""
        if self.last_seen is not None:
            self.run_start = (self.last_seen + 1) % U32_WRAP  # its end is accounted by now
        elif self.ended_at is not None:
            self.run_start = self.ended_at  # it ended with none of its frames received
        self.late = 0
        self.ended_at = None
        self.frame_in = False
        self.early_broken = []
        self.stats = StreamStats()
        self.pixels = 0
        self.last_seen = None
        self.first_seen = None
        self.unattributed = 0
        self.broken_before_first = 0
        self.end = None
        self.end_told = 0.0
        self.t_start = time.monotonic()
        self.t_stop = None
        self.t_last_frame = None
        self.error = None
        self.problem = None

    def is_late(self, counter: int) -> bool:
        """Whether ``counter`` comes before this run's start: a frame of an earlier run that
        arrived after it ended (lock held)."""
        start = self.run_start
        return start is not None and 0 < (start - counter) % U32_WRAP < U32_WRAP // 2

    def take_late(self, counter: int) -> bool:
        """``is_late``, counting the frame as set aside if it is (lock held)."""
        if not self.is_late(counter):
            return False
        self.late += 1
        return True

    def in_sequence(self, counter: int) -> bool:
        """Account for ``counter`` (lock held): lost frames before it; False if it goes back."""
        if self.last_seen is None:
            self.last_seen = self.first_seen = counter
            self.broken_before_first = self.unattributed
            self.unattributed = 0
            self.frame_in = True
            return True
        step = (counter - self.last_seen) % U32_WRAP
        if step == 0 or step >= U32_WRAP // 2:
            return False
        if not self.frame_in:
            # The run's first frame, after ``expect_first``: a broken transfer before it with
            # no counter missing to stand for is an earlier run's.
            self.frame_in = True
            self.unattributed -= self._set_aside_early(self.unattributed - (step - 1))
        self.stats.lost += max(0, step - 1 - self.unattributed)
        self.unattributed = 0
        self.last_seen = counter
        return True

    def _set_aside_early(self, count: int) -> int:
        """The first ``count`` broken transfers before this run's first frame stand for none of
        its frames (the rest of a frame of the run before, cut in two by its stop): set aside
        as late, not counted broken in this run; how many (lock held)."""
        kinds, self.early_broken = self.early_broken[: max(0, count)], []
        for kind in kinds:
            if kind == "short":
                self.stats.short -= 1
            else:
                self.stats.corrupt -= 1
        self.late += len(kinds)
        return len(kinds)

    def settle_end(self, *, idle: bool) -> None:
        """Account the end of the stream if it is due (lock held)."""
        end = self.end
        if end is None:
            return
        last = self.last_seen
        missing = 0 if last is None else (end - 1 - last) % U32_WRAP
        if missing >= U32_WRAP // 2:
            missing = 0  # frames past the end arrived: nothing more is missing
        if (missing or last is None) and not idle:
            return  # frames may still be on their way: wait for the line to go quiet
        self.stats.lost += max(0, missing - self.unattributed)
        self.unattributed = 0
        if last is not None:
            self.last_seen = (end - 1) % U32_WRAP  # late frames count as out of order
        self.end = None
        self.ended_at = end

    def expect_end(self, next_counter: int) -> None:
        """The device says the stream ended before ``next_counter`` (``FrameStream.expect_end``)."""
        with self.cond:
            self.end = next_counter % U32_WRAP
            self.end_told = time.monotonic()
            self.settle_end(idle=False)
            self.cond.notify_all()

    def expect_first(self, first_counter: int) -> None:
        """The device says the stream's first frame has counter ``first_counter``
        (``FrameStream.expect_first``)."""
        with self.cond:
            first = first_counter % U32_WRAP
            self.run_start = first  # what came before it is an earlier run's
            if self.last_seen is None:
                # Nothing received yet: the first frame's gap is measured from here.
                self.last_seen = (first - 1) % U32_WRAP
                self.first_seen = first
            elif self.first_seen is not None:
                missing = (self.first_seen - first) % U32_WRAP
                if missing < U32_WRAP // 2:
                    excess = self.broken_before_first - missing  # standing for no frame of it
                    self.broken_before_first -= self._set_aside_early(excess)
                    self.stats.lost += max(0, missing - self.broken_before_first)
                    self.broken_before_first = 0
            self.cond.notify_all()

    def broken(self, kind: str, nbytes: int, counter: int | None, *, why: str = "") -> None:
        """Count a broken transfer; it stands for one frame in the counter bookkeeping (one
        whose counter says it is an earlier run's is set aside as late)."""
        with self.cond:
            if counter is not None and self.take_late(counter):
                return
            if kind == "short":
                self.stats.short += 1
            else:
                self.stats.corrupt += 1
            if counter is None:
                self.unattributed += 1  # the next counter gap has one frame less lost
                if not self.frame_in:
                    self.early_broken.append(kind)
            else:
                self.in_sequence(counter)  # known: this frame is accounted, not lost
        detail = why or f"a {kind} transfer of {nbytes} bytes"
        self.problem = detail
        log.debug("frame stream %s: %s", self.ident, detail)

    def count(self, name: str) -> None:
        """One more of the counter ``name`` (a timeout, a stall)."""
        with self.cond:
            setattr(self.stats, name, getattr(self.stats, name) + 1)

    def account(self, header: FrameHeader | Delivered | None) -> None:
        """A frame went through the consumers (``header``; None: it was dropped, its payload
        CRC mismatched), or a packed transfer's frames did (``Delivered``): count it (lock
        held)."""
        s = self.stats
        if header is None:
            s.corrupt += 1
            return
        if isinstance(header, Delivered):
            s.corrupt += header.corrupt
            if header.frames:
                self.t_last_frame = time.monotonic()
                s.frames += header.frames
                s.bytes += header.bytes
                self.pixels += header.pixels
                if s.first_counter is None:
                    s.first_counter = header.first_counter
                s.last_counter = header.last_counter
            return
        self.t_last_frame = time.monotonic()
        s.frames += 1
        s.bytes += header.frame_bytes
        self.pixels += header.rows * header.cols
        if s.first_counter is None:
            s.first_counter = header.counter
        s.last_counter = header.counter

    def snapshot(self, overruns: int) -> StreamStats:
        """A copy of the counters, with the queue's ``overruns`` and rates over the time
        since the run started (lock held)."""
        s = dataclasses.replace(self.stats, overruns=overruns)
        # Rates over the time frames were flowing: from start() to the last delivery (not
        # to stop(), which may come much later, e.g. after an idle read timeout).
        if self.t_last_frame is not None:
            end = self.t_last_frame
        else:
            end = self.t_stop if self.t_stop is not None else time.monotonic()
        s.elapsed_s = max(0.0, end - self.t_start) if self.t_start else 0.0
        if s.elapsed_s > 0:
            s.mpix_per_s = self.pixels / s.elapsed_s / 1e6
            s.mbyte_per_s = s.bytes / s.elapsed_s / 1e6
        return s
