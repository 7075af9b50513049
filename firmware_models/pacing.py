"""When the simulated FX3 sends a paced stream's frames: deadlines on the sensor's clock.

Frame k of a stream is due at ``start + T_0 + ... + T_(k-1)`` (the frame periods in force),
in wall time: the sensor reads a frame out every period whatever the simulator does. The
stream engine (``firmware_models.fx3.StreamEngine``) makes the frames due within a millisecond
together and sends them when the last of them is due, so none leaves early.

A frame made late (the process was not scheduled in time, a render took longer than a period)
is followed by the next ones at once, until the stream is back on its schedule: late frames do
not move the clock, so short delays cost none of the line rate. Moving the clock instead (the
simulator's earlier rule: a frame more than a period late restarted the schedule from it)
lost the time of every late wake-up; at 6,092 lines/s a wake-up is often later than the
164 us period, and a stream delivered 0.82 of the line rate with CPU to spare.

Only a delay beyond a bound restarts the schedule from now: ``MAX_LAG_S``, or at high line
rates ``MAX_LAG_FRAMES`` periods, whichever is shorter. A simulator stalled for longer (a
stopped process, a source slower than the line rate for good) so never floods the host with
more than that: the host's frame queue (``[stream] queue_mb``, ``queue_frames``, 4096 frames by
default) holds a bound's worth of frames at any line rate. A source that is slower than the
line rate on average makes the stream slower, as before: it cannot catch up.

The pacer does not read a clock: the engine passes ``now_s`` (``time.monotonic()``), and the
tests pass plain numbers.
"""

from __future__ import annotations

MAX_LAG_S = 0.25
"""The most a paced stream may fall behind its schedule and still catch up, in seconds."""

MAX_LAG_FRAMES = 1024
"""... and in frame periods (at 24,366 frames/s, 42 ms: a quarter of the host's queue)."""


class Pacer:
    """The deadlines of one paced stream. ``due_s``: when the next frame is due (wall time,
    the engine's clock); ``restarts``: how often a delay beyond the bound restarted the
    schedule."""

    def __init__(self, start_s: float) -> None:
        self.due_s = start_s
        self.restarts = 0

    @staticmethod
    def max_lag_s(period_s: float) -> float:
        """The catch-up bound at this frame period: ``MAX_LAG_S`` or ``MAX_LAG_FRAMES``
        periods, whichever is shorter, but at least one period."""
        return max(period_s, min(MAX_LAG_S, MAX_LAG_FRAMES * period_s))

    def block_frames(self, usual: int, period_s: float, most: int, *, now_s: float) -> int:
        """How many frames to make next: the ``usual`` block, or every frame already due if
        the stream is behind (one system call for a backlog), at most ``most``."""
        due_already = int((now_s - self.due_s) / period_s) + 1 if period_s > 0 else usual
        return max(1, min(most, max(usual, due_already)))

    def wait_s(self, count: int, period_s: float, *, now_s: float) -> float:
        """How long to wait before making a block of ``count`` frames: until the last of them
        is due (0 if it is due already). A block later than the catch-up bound restarts the
        schedule so that it is due now."""
        last_due_s = self.due_s + (count - 1) * period_s
        if last_due_s > now_s:
            return last_due_s - now_s
        if now_s - last_due_s > self.max_lag_s(period_s):
            self.due_s = now_s - (count - 1) * period_s
            self.restarts += 1
        return 0.0

    def advance(self, period_s: float, frames: int = 1) -> None:
        """``frames`` frames of ``period_s`` were made: the next one is due that much later."""
        self.due_s += frames * period_s
