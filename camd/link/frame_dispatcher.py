"""The frame stream's dispatcher thread: payload CRCs, then every consumer, in counter order.

``FrameDispatcher`` takes the reader's queued slots (``camd.link.frame_queue``) in order
(thread ``camd-frame-dispatch``), checks each frame's payload CRC (zlib-ng's crc32, ~50 GB/s,
while the reader does the next read; ``payload_crc32``: small payloads without a hand-over of
the GIL), then calls every consumer with a zero-copy read-only view of the pixels; the slot
is freed once every callback has returned: **consumers must copy what they keep**. A packed
transfer's CRCs are checked in one loop and each stretch of good, consecutive frames goes to a
consumer with ``on_batch`` as one ``FrameBatch``, to any other frame by frame. What was
delivered is counted in the ``camd.link.frame_ledger`` in the lock section that takes the next
frame: one lock round per frame (or transfer).
"""

from __future__ import annotations

import itertools
from collections.abc import Callable

import numpy as np

from camd.link.frame_ledger import Delivered, FrameLedger
from camd.link.frame_queue import FrameQueue, FrameSlot
from camd.link.frame_types import Consumer, ReceivedFrame, log
from camd.link.packed import FrameBatch, Run, header_at, run_pixels
from camd.protocol.stream import HEADER_BYTES, U32_WRAP, FrameHeader, payload_crc32

# Small frames are dispatched in bursts: the dispatcher, woken by a first frame, waits up to
# DISPATCH_WAIT_S for a burst of frames (up to DISPATCH_BURST_BYTES, at most DISPATCH_BURST
# frames) before it delivers them. At tens of thousands of frames a second that is one
# wake-up (and one hand-over of Python's GIL between the threads) per burst instead of
# per frame; a frame waits at most DISPATCH_WAIT_S longer.
DISPATCH_BURST = 16
DISPATCH_BURST_BYTES = 256 << 10
DISPATCH_WAIT_S = 0.002
HEADER_LOG = 256  # headers kept per run for header_log() (docs/conformance.md)


class FrameDispatcher:
    """Delivers ``queue``'s frames to ``consumers`` and counts them in ``ledger``; kept across
    runs (the consumers stay), ``reset`` before each."""

    def __init__(self, ledger: FrameLedger, queue: FrameQueue) -> None:
        self._ledger = ledger
        self._queue = queue
        # Replaced whole (under the stream's lock) when a consumer is added or removed: the
        # dispatcher takes the tuple once per frame.
        self.consumers: tuple[Consumer, ...] = ()
        # The first HEADER_LOG headers of the run that passed the header checks, with the
        # payload CRC the host computed (the frames a payload CRC rejected too): the evidence
        # of docs/conformance.md's stream checks, which must not depend on the CRCs.
        self.header_log: list[tuple[FrameHeader, int]] = []
        self._last_delivered: int | None = None

    def reset(self) -> None:
        """A new run: no header logged, nothing delivered."""
        self.header_log = []
        self._last_delivered = None

    def run(self, thread_start: Callable[[str], object] | None) -> None:
        """The thread's body: deliver until the reader is done and the queue is empty."""
        if thread_start is not None:
            thread_start("frame_dispatcher")
        q = self._queue
        cond = q.cond
        entries = q.entries
        free = q.free  # this run's: replaced only between runs
        ledger = self._ledger
        account = ledger.account
        # The frame just handed to the consumers, accounted (counted, its slot freed) in the
        # same lock section that takes the next one: one lock round per frame (or transfer).
        done: tuple[FrameSlot, FrameHeader | Delivered | None] | None = None
        while True:
            with cond:
                if done is not None:
                    free.append(done[0])
                    account(done[1])
                    done = None
                if not entries:
                    q.dispatching = False
                    cond.notify_all()  # wait_drained, wait_frames
                    q.dispatcher_idle = True
                    cond.wait_for(lambda: bool(entries) or q.reader_done)
                    if len(entries) < q.burst and not q.reader_done:
                        cond.wait(DISPATCH_WAIT_S)  # for a burst: the reader wakes us at one
                    q.dispatcher_idle = False
                    if not entries:
                        return  # the reader has stopped and everything was delivered
                slot, header, received_ns = entries.popleft()
                q.dispatching = True
                consumers = self.consumers
                index = ledger.stats.frames
                if q.reader_waiting or q.frame_watchers:
                    # A reader waiting for a queue place may go on; wait_frames sees the count.
                    cond.notify_all()
            if isinstance(header, list):
                done = (slot, self._deliver_runs(slot, header, received_ns, consumers, index))
                continue
            done = (slot, None)
            if self._deliver(slot, header, received_ns, consumers, index):
                done = (slot, header)

    def _deliver_runs(
        self,
        slot: FrameSlot,
        runs: list[Run],
        received_ns: int,
        consumers: tuple[Consumer, ...],
        index: int,
    ) -> Delivered:
        """A packed transfer: the payload CRCs of its runs, then every consumer with each
        stretch of good frames (``on_batch`` with them all, else a call per frame)."""
        done = Delivered()
        view = slot.view
        for run in runs:
            stride, payload = run.stride, run.stride - HEADER_BYTES
            start = run.offset + HEADER_BYTES
            computed = np.fromiter(
                (
                    payload_crc32(view[o : o + payload])
                    for o in range(start, start + run.count * stride, stride)
                ),
                dtype=np.uint32,
                count=run.count,
            )
            for i in range(min(run.count, HEADER_LOG - len(self.header_log))):
                self.header_log.append((header_at(run.fields, i), int(computed[i])))
            good = computed == run.fields["payload_crc32"]
            if good.all():
                stretches = [(0, run.count)]
            else:
                bad = np.flatnonzero(~good)
                done.corrupt += len(bad)
                counter = int(run.fields["counter"][bad[-1]])
                self._ledger.problem = f"frame {counter}: payload CRC mismatch"
                edges = [-1, *bad.tolist(), run.count]
                stretches = [(a + 1, b) for a, b in itertools.pairwise(edges) if b > a + 1]
            for a, b in stretches:
                self._deliver_batch(slot, run, a, b, received_ns, consumers, index, done)
                index += b - a
        return done

    def _deliver_batch(
        self,
        slot: FrameSlot,
        run: Run,
        a: int,
        b: int,
        received_ns: int,
        consumers: tuple[Consumer, ...],
        index: int,
        done: Delivered,
    ) -> None:
        """Frames ``a .. b - 1`` of ``run`` (good, consecutive) to every consumer."""
        fields = run.fields[a:b]
        counters = fields["counter"]
        first = int(counters[0])
        last = self._last_delivered
        if last is None:
            seen = self._ledger.first_seen
            last = ((seen if seen is not None else first) - 1) % U32_WRAP
        pixels = run_pixels(slot.buf, run, a, b)
        batch = FrameBatch(pixels, fields, received_ns, (first - last - 1) % U32_WRAP, index)
        k = b - a
        for cb in consumers:
            on_batch = getattr(cb, "on_batch", None)
            if on_batch is not None:
                try:
                    on_batch(batch)
                except Exception:
                    self._consumer_failed(k)
                    log.exception("frame stream: consumer %r failed on frames from %d", cb, first)
                continue
            for i in range(k):
                frame = ReceivedFrame(
                    header=header_at(fields, i),
                    pixels=pixels[i],
                    received_ns=received_ns,
                    gap_before=batch.gap_before if i == 0 else 0,
                    index=index + i,
                )
                try:
                    cb(frame)
                except Exception:
                    self._consumer_failed(1)
                    log.exception(
                        "frame stream: consumer %r failed on frame %d", cb, frame.header.counter
                    )
        last_counter = int(counters[-1])
        self._last_delivered = last_counter
        done.frames += k
        done.bytes += k * run.stride
        done.pixels += k * pixels.shape[1] * pixels.shape[2]
        if done.first_counter is None:
            done.first_counter = first
        done.last_counter = last_counter

    def _deliver(
        self,
        slot: FrameSlot,
        header: FrameHeader,
        received_ns: int,
        consumers: tuple[Consumer, ...],
        index: int,
    ) -> bool:
        """Check the payload CRC, then call every consumer; False if the CRC mismatched."""
        payload = slot.view[HEADER_BYTES : HEADER_BYTES + header.payload_bytes]
        computed = payload_crc32(payload)
        if len(self.header_log) < HEADER_LOG:  # only the dispatcher appends
            self.header_log.append((header, computed))
        if computed != header.payload_crc32:
            self._ledger.problem = f"frame {header.counter}: payload CRC mismatch"
            return False
        last = self._last_delivered
        if last is None:
            # Before the first delivery, count from the first frame the reader saw (set before
            # this frame was queued): a rejected first frame is a gap too.
            seen = self._ledger.first_seen
            last = ((seen if seen is not None else header.counter) - 1) % U32_WRAP
        frame = ReceivedFrame(
            header=header,
            pixels=slot.frame_pixels(header.rows, header.cols),
            received_ns=received_ns,
            gap_before=(header.counter - last - 1) % U32_WRAP,
            index=index,
        )
        for cb in consumers:
            try:
                cb(frame)
            except Exception:
                self._consumer_failed(1)
                log.exception("frame stream: consumer %r failed on frame %d", cb, header.counter)
        self._last_delivered = header.counter
        return True

    def _consumer_failed(self, frames: int) -> None:
        """Count a consumer's failure on ``frames`` frames (the others still got them)."""
        with self._queue.cond:
            self._ledger.stats.consumer_errors += frames
