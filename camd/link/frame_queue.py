"""The bounded queue between the frame reader and the dispatcher, and the slots it recycles.

The reader fills a ``FrameSlot`` (a preallocated buffer pyusb reads into), queues it with its
header (or, packed, its transfer's runs) and takes the next free slot; the dispatcher takes
queued slots in order and frees each once the consumers are done with it. When the queue is
full the reader waits at most ``overflow_wait_s`` for a place, then the overflow policy says
which entry goes (counted in ``overruns``): the reader never waits for consumers. Slots are
allocated as the queue first grows and, past the first few, given back by ``release`` at the
end of a run. ``FrameQueue`` also keeps who waits for whom (a reader waiting for a place, an
idle dispatcher, threads waiting for frames), so that each side wakes the other only when it
must. Every field is read and written under ``cond``, the stream's one lock, which the
counter bookkeeping (``camd.link.frame_ledger``) shares.
"""

from __future__ import annotations

import array
import threading
from collections import deque
from typing import Literal

import numpy as np

from camd.link.packed import Run
from camd.protocol.stream import HEADER_BYTES, FrameHeader

OVERFLOW_WAIT_S = 0.01
# Frame slots allocated when a stream starts (and kept across runs): the reader's, the
# dispatcher's and one queued. More are allocated only when the queue grows past that.
INITIAL_SLOTS = 3

Overflow = Literal["drop_newest", "drop_oldest"]
OVERFLOW_POLICIES: tuple[Overflow, ...] = ("drop_newest", "drop_oldest")


class FrameSlot:
    """A preallocated frame buffer: pyusb reads into ``buf``; numpy views alias it."""

    __slots__ = ("buf", "header", "pixels", "shaped", "view")

    def __init__(self, nbytes: int) -> None:
        self.buf = array.array("B", [0]) * nbytes
        self.view = memoryview(self.buf)
        self.header = self.view[:HEADER_BYTES]
        pixels = np.frombuffer(self.buf, dtype="<u2", offset=HEADER_BYTES)
        pixels.flags.writeable = False  # consumers get read-only views
        self.pixels = pixels
        self.shaped = pixels[:0].reshape(0, 0)  # the last frame's (rows, cols) view

    def frame_pixels(self, rows: int, cols: int) -> np.ndarray:
        """The (rows, cols) view of the slot's pixels (kept: frames rarely change shape)."""
        shaped = self.shaped
        if shaped.shape != (rows, cols):
            shaped = self.shaped = self.pixels[: rows * cols].reshape(rows, cols)
        return shaped


# What the reader queues: one frame and its header, or (packed) a transfer's runs of frames.
Queued = tuple[FrameSlot, "FrameHeader | list[Run]", int]


def frames_in(queued: FrameHeader | list[Run]) -> int:
    """Frames in a queue entry: one, or a packed transfer's runs."""
    return sum(r.count for r in queued) if isinstance(queued, list) else 1


class FrameQueue:
    """The queue of filled slots (``entries``: slot, header or runs, ``received_ns``), the
    slots, and the wake-up flags of the two threads; all under ``cond``."""

    def __init__(self, cond: threading.Condition) -> None:
        self.cond = cond
        self.entries: deque[Queued] = deque()
        self.overflow: Overflow = "drop_newest"
        self.overflow_wait_s = OVERFLOW_WAIT_S
        self.capacity = 1  # entries the queue holds this run: see prepare()
        self.burst = 1  # entries the dispatcher waits for, once woken: see prepare()
        self.slot_bytes = 0
        self.slots: list[FrameSlot] = []
        self.free: list[FrameSlot] = []
        self.overruns = 0  # frames the overflow policy dropped this run
        self.dispatching = False
        self.reader_waiting = False  # the reader waits for a queue place (the dispatcher wakes it)
        self.dispatcher_idle = False  # the dispatcher waits for frames (the reader wakes it)
        self.frame_watchers = 0  # threads in wait_frames (the dispatcher wakes them per frame)
        self.reader_done = True
        self.stopping = threading.Event()

    def prepare(
        self,
        *,
        slot_bytes: int,
        capacity: int,
        burst: int,
        overflow: Overflow,
        overflow_wait_s: float,
    ) -> None:
        """Before a run: slots of ``slot_bytes`` (the first few allocated, kept from the last
        run if they have that size), an empty queue of ``capacity`` entries."""
        self.capacity = capacity
        self.burst = burst
        self.overflow = overflow
        self.overflow_wait_s = overflow_wait_s
        if slot_bytes != self.slot_bytes:
            self.slots = []
            self.slot_bytes = slot_bytes
        # The reader's and the dispatcher's slots, and one queued: the rest come as the queue
        # grows (put), up to queued + 2.
        while len(self.slots) < min(INITIAL_SLOTS, capacity + 2):
            self.slots.append(FrameSlot(slot_bytes))
        self.free = list(self.slots)
        with self.cond:
            self.entries.clear()
            self.overruns = 0
            self.reader_done = False
        self.stopping.clear()

    def release(self) -> None:
        """After a run: a burst's slots go back to the allocator; the first few are kept for
        the next run."""
        del self.slots[INITIAL_SLOTS:]
        self.free = list(self.slots)

    def put(self, slot: FrameSlot, entry: FrameHeader | list[Run], received_ns: int) -> FrameSlot:
        """Queue the frame, or a packed transfer's runs (lock held); the overflow policy
        decides when the queue is full. The slot to fill next."""
        q = self.entries
        capacity = self.capacity
        if len(q) >= capacity and self.overflow_wait_s > 0:
            # A short, bounded wait: it also hands the dispatcher the GIL, which a reader
            # working through a backlog (reads that never block) would otherwise keep.
            self.reader_waiting = True
            self.cond.wait_for(
                lambda: len(q) < capacity or self.stopping.is_set(),
                self.overflow_wait_s,
            )
            self.reader_waiting = False
        if len(q) >= capacity:
            if self.overflow == "drop_newest":
                self.overruns += frames_in(entry)
                return slot  # this frame is dropped: the slot is reused
            old_slot, old, _ = q.popleft()
            self.overruns += frames_in(old)
            self.free.append(old_slot)
        q.append((slot, entry, received_ns))
        if self.dispatcher_idle and (len(q) == 1 or len(q) >= self.burst):
            self.cond.notify_all()
        if not self.free:
            # Never more than queued + the reader's + the dispatcher's: the queue is at most
            # capacity long here, so this slot count stays within capacity + 2.
            grown = FrameSlot(self.slot_bytes)
            self.slots.append(grown)
            return grown
        return self.free.pop()

    def idle(self) -> bool:
        """Nothing queued and nothing being delivered (lock held)."""
        return not self.entries and not self.dispatching
