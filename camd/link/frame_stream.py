"""The frame stream's host side: USB bulk reads in, checked window frames out to consumers.

``FrameStream`` finds the camera's FX3-class streamer with pyusb (``backend=None``: libusb,
the hardware; or the simulated FX3's ``firmware_models.fx3_backend.get_backend(path)``), claims
its interface and runs two threads:

- the reader: bulk reads of whole frames straight into preallocated slots (no copy, no
  allocation per frame), reassembly of frames that span several reads, header checks
  (``camd.protocol.stream.decode_header``), counter bookkeeping (lost, out of order), then a
  bounded queue with an explicit overflow policy: the reader never waits for consumers;
- the dispatcher: the payload CRC (zlib-ng's crc32, ~50 GB/s, while the reader does the next read;
  ``payload_crc32``: small payloads without a hand-over of the GIL),
  then every consumer callback, in counter order, with a zero-copy read-only view of the
  pixels; the slot is reused once every callback has returned: **consumers must copy what
  they keep**.

Reassembly rules (docs/stream.md): the device ends each frame's transfer with a short packet,
so a read that returns fewer bytes than asked ends a transfer; a transfer is one frame. A
transfer shorter than its header says is ``short``; one whose header fails its checks, or
longer than its header says, or that overflows the slot, is ``corrupt``; after a broken
transfer the reader discards data up to the next transfer boundary. Each broken transfer
stands for one frame, so a gap in the counters after it counts one less as ``lost``.

``FrameStream`` is the facade; each job is a part of its own, each depending on those below it
only (the import-linter contract ``frame-stream-parts``):

- ``camd.link.frame_reader``: the reader thread (reads, reassembly, header checks);
- ``camd.link.frame_dispatcher``: the dispatcher thread (payload CRCs, consumers, batches);
- ``camd.link.frame_queue``: the bounded queue between them, its slots and its overflow policy;
- ``camd.link.frame_ledger``: the counters and their bookkeeping (lost, out of order, the end);
- ``camd.link.stream_device``: the USB device (find, claim, release; packing, halts);
- ``camd.link.frame_types``: what they share with the stream's users (``ReceivedFrame``,
  ``StreamStats``, ``StreamError``, ``Consumer``).

The hot path crosses no more calls than it did as one class: the reader's loop calls the
check of a transfer, which calls the ledger and the queue under one lock; the dispatcher's
loop accounts a frame and takes the next in one lock section.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any

from camd.link.frame_dispatcher import (
    DISPATCH_BURST,
    DISPATCH_BURST_BYTES,
    DISPATCH_WAIT_S,
    HEADER_LOG,
    FrameDispatcher,
)
from camd.link.frame_ledger import FrameLedger
from camd.link.frame_queue import (
    INITIAL_SLOTS,
    OVERFLOW_POLICIES,
    OVERFLOW_WAIT_S,
    FrameQueue,
    Overflow,
)
from camd.link.frame_reader import NO_DATA_WARNING_S, FrameReader
from camd.link.frame_types import Consumer, ReceivedFrame, StreamError, StreamStats
from camd.link.stream_device import (
    ENDPOINT_IN,
    INTERFACE,
    PACK_BYTES,
    PACK_BYTES_MAX,
    PACK_REQUEST,
    PRODUCT_ID,
    VENDOR_ID,
    StreamDevice,
)
from camd.protocol.stream import HEADER_BYTES, FrameHeader

__all__ = [
    "DISPATCH_BURST",
    "DISPATCH_BURST_BYTES",
    "DISPATCH_WAIT_S",
    "ENDPOINT_IN",
    "HEADER_LOG",
    "INITIAL_SLOTS",
    "INTERFACE",
    "NO_DATA_WARNING_S",
    "OVERFLOW_POLICIES",
    "OVERFLOW_WAIT_S",
    "PACK_BYTES",
    "PACK_BYTES_MAX",
    "PACK_REQUEST",
    "PRODUCT_ID",
    "VENDOR_ID",
    "Consumer",
    "FrameStream",
    "Overflow",
    "ReceivedFrame",
    "StreamError",
    "StreamStats",
]


class FrameStream:
    """Reads window frames from the camera's bulk IN endpoint and hands them to consumers.

    ``queue_frames``: frames buffered between reader and dispatcher; ``queue_bytes``, if given,
    caps that further to the frames whose slots fit in that many bytes (at least 2), so the
    queue holds the same time of stream for small and large windows. Slots are allocated as
    the queue first grows and, past the first few, released by ``stop()``: memory is only
    taken while a consumer is really behind. When the queue is full, the reader waits up to
    ``overflow_wait_s`` for a place, then ``overflow`` says which frame goes: "drop_newest"
    (the arriving one) or "drop_oldest" (counted as ``overruns``).
    ``read_bytes``: bytes per bulk read; 0 (default) reads a whole frame per read (zero copy);
    a positive value, a multiple of the endpoint's packet size, makes frames span several
    reads (each read is then copied into the slot). ``timeout_s``: each bulk read's timeout;
    ``stop()`` may take that long. ``end_quiet_s``: frames the device said it sent
    (``expect_end``) that have not come count as lost once a read times out with the line quiet
    that long since the last data and since ``expect_end`` (0: at the first read timeout); a
    device slow to send its last frames (a loaded simulator) then still has them delivered.
    Use: ``open()``, ``add_consumer``, ``start(max_frame_bytes=)``, ... ``expect_end(n)``,
    ``wait_drained()``, ``stop()``, ``close()``; ``start`` and ``stop`` may repeat on one open
    stream: frames of an earlier run that come during a later one are set aside
    (``late_frames``).
    """

    def __init__(
        self,
        *,
        vendor_id: int = VENDOR_ID,
        product_id: int = PRODUCT_ID,
        backend: Any = None,
        queue_frames: int = 32,
        queue_bytes: int | None = None,
        overflow: Overflow = "drop_newest",
        read_bytes: int = 0,
        pack_bytes: int = 0,
        timeout_s: float = 1.0,
        overflow_wait_s: float = OVERFLOW_WAIT_S,
        no_data_warning_s: float = NO_DATA_WARNING_S,
        end_quiet_s: float = 0.0,
        thread_start: Callable[[str], object] | None = None,
    ) -> None:
        if queue_frames < 1:
            raise ValueError(f"queue_frames = {queue_frames} must be at least 1")
        if queue_bytes is not None and queue_bytes < 1:
            raise ValueError(f"queue_bytes = {queue_bytes} must be at least 1 (None: no cap)")
        if overflow not in OVERFLOW_POLICIES:
            raise ValueError(f"overflow = {overflow!r}: use one of {', '.join(OVERFLOW_POLICIES)}")
        if read_bytes < 0:
            raise ValueError(f"read_bytes = {read_bytes} must be >= 0 (0: whole frames)")
        if not 0 <= pack_bytes <= PACK_BYTES_MAX or pack_bytes % 1024:
            raise ValueError(
                f"pack_bytes = {pack_bytes} must be a whole number of KiB from 0 (one frame per "
                f"transfer) to {PACK_BYTES_MAX}"
            )
        if pack_bytes and read_bytes:
            raise ValueError(
                "pack_bytes needs whole-transfer reads: use read_bytes = 0 with pack_bytes"
            )
        if not timeout_s > 0:
            raise ValueError(f"timeout_s = {timeout_s} must be positive")
        if not end_quiet_s >= 0:
            raise ValueError(f"end_quiet_s = {end_quiet_s} must be >= 0 (0: one read timeout)")
        self.vendor_id = vendor_id
        self.product_id = product_id
        self.backend = backend
        self.queue_frames = queue_frames
        self.queue_bytes = queue_bytes
        self.overflow = overflow
        self.read_bytes = read_bytes
        self.pack_bytes = pack_bytes
        self._packed = False  # this run's transfers may hold several frames (start())
        self.timeout_s = timeout_s
        self.overflow_wait_s = overflow_wait_s
        self.no_data_warning_s = no_data_warning_s
        self.end_quiet_s = end_quiet_s
        # Called as ``thread_start("frame_reader")`` and ``thread_start("frame_dispatcher")``
        # from inside each thread when it starts: how the daemon gives the reader real-time
        # scheduling (camd/daemon/realtime.py).
        self.thread_start = thread_start
        self.ident = f"{vendor_id:04x}:{product_id:04x}"
        self._device = StreamDevice(vendor_id=vendor_id, product_id=product_id, backend=backend)
        # One lock for the counters, the queue and the counter bookkeeping; held briefly.
        self._lock = threading.Lock()
        self._cond = threading.Condition(self._lock)
        self._queue = FrameQueue(self._cond)
        self._ledger = FrameLedger(self._cond, self.ident)
        self._dispatcher = FrameDispatcher(self._ledger, self._queue)
        self._reader_thread: threading.Thread | None = None
        self._dispatcher_thread: threading.Thread | None = None

    @property
    def error(self) -> StreamError | None:
        """Why the reader stopped on its own (a device gone, reads failing), else None."""
        return self._ledger.error

    @error.setter
    def error(self, value: StreamError | None) -> None:
        self._ledger.error = value

    @property
    def problem(self) -> str | None:
        """The last problem the stream saw (a broken transfer, a CRC mismatch, no data)."""
        return self._ledger.problem

    @problem.setter
    def problem(self, value: str | None) -> None:
        self._ledger.problem = value

    # -- context manager --------------------------------------------------------------------------

    def __enter__(self) -> FrameStream:
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- opening ----------------------------------------------------------------------------------

    def open(self) -> None:
        """Find the device, set its configuration, claim its interface."""
        self._device.open(self.read_bytes)

    def close(self) -> None:
        """Stop, release the interface and the device (a closed stream may be opened again)."""
        self.stop()
        self._device.close()

    # -- consumers --------------------------------------------------------------------------------

    def add_consumer(self, cb: Consumer) -> None:
        """Call ``cb(frame)`` on the dispatcher thread for every delivered frame, in order."""
        with self._lock:
            self._dispatcher.consumers = (*self._dispatcher.consumers, cb)

    def remove_consumer(self, cb: Consumer) -> None:
        """Stop calling ``cb`` (from the next frame on); unknown callbacks are ignored."""
        with self._lock:
            consumers = list(self._dispatcher.consumers)
            if cb in consumers:
                consumers.remove(cb)
            self._dispatcher.consumers = tuple(consumers)

    # -- running ----------------------------------------------------------------------------------

    @property
    def running(self) -> bool:
        return self._reader_thread is not None

    def queue_capacity(self, slot_bytes: int) -> int:
        """Frames the queue holds for slots of ``slot_bytes``: ``queue_frames``, capped to
        what ``queue_bytes`` holds (never under 2)."""
        if self.queue_bytes is None:
            return self.queue_frames
        return max(2, min(self.queue_frames, self.queue_bytes // slot_bytes))

    @property
    def allocated_slots(self) -> int:
        """Frame slots allocated now (the queue's high-water mark plus two, this run)."""
        return len(self._queue.slots)

    def start(self, *, max_frame_bytes: int) -> None:
        """Reset the counters and start reading frames of up to ``max_frame_bytes`` (header
        included)."""
        device = self._device
        if device.dev is None:
            raise StreamError("the frame stream is not open; call open() first")
        if self._reader_thread is not None:
            raise StreamError("the frame stream is already running; stop() it first")
        if max_frame_bytes <= HEADER_BYTES:
            raise ValueError(f"max_frame_bytes = {max_frame_bytes} must exceed the header")
        # One byte over the largest frame, rounded up to whole packets: every frame then
        # ends in a short read, and a longer transfer shows as a full one.
        p = device.packet_bytes
        slot_bytes = (max_frame_bytes + 1 + p - 1) // p * p
        self._packed = self.pack_bytes > 0 and device.ask_packing(self.pack_bytes)
        if self._packed:
            # A slot holds a whole transfer: up to pack_bytes of frames, and one frame more
            # than asked (a transfer that overfills the read is too long, as with one frame).
            slot_bytes = max(slot_bytes, (self.pack_bytes + 1 + p - 1) // p * p)
        capacity = self.queue_capacity(slot_bytes)
        self._queue.prepare(
            slot_bytes=slot_bytes,
            capacity=capacity,
            burst=(
                1  # a transfer is a burst already
                if self._packed
                else max(1, min(DISPATCH_BURST, capacity, DISPATCH_BURST_BYTES // slot_bytes))
            ),
            overflow=self.overflow,
            overflow_wait_s=self.overflow_wait_s,
        )
        with self._lock:
            self._ledger.reset()
            self._dispatcher.reset()
        reader = FrameReader(
            device,
            self._ledger,
            self._queue,
            max_frame_bytes=max_frame_bytes,
            packed=self._packed,
            read_bytes=self.read_bytes,
            timeout_s=self.timeout_s,
            no_data_warning_s=self.no_data_warning_s,
            end_quiet_s=self.end_quiet_s,
        )
        self._dispatcher_thread = threading.Thread(
            target=self._dispatcher.run,
            args=(self.thread_start,),
            name="camd-frame-dispatch",
            daemon=True,
        )
        self._reader_thread = threading.Thread(
            target=reader.run, args=(self.thread_start,), name="camd-frame-read", daemon=True
        )
        self._dispatcher_thread.start()
        self._reader_thread.start()

    def stop(self) -> None:
        """Stop reading (within ``timeout_s``), deliver what is queued, join the threads."""
        reader, dispatcher = self._reader_thread, self._dispatcher_thread
        if reader is None or dispatcher is None:
            return
        self._queue.stopping.set()
        reader.join()
        dispatcher.join()
        self._reader_thread = self._dispatcher_thread = None
        with self._lock:
            self._ledger.t_stop = time.monotonic()
            # Frames the device said it sent (expect_end) that have not come cannot come now:
            # lost. A reader that gave up on an error (its device gone) never saw the line go
            # quiet, which is what counts them otherwise.
            self._ledger.settle_end(idle=True)
        if self._packed:
            # Back to one frame per transfer: another reader of this device may expect it.
            self._device.ask_packing(0)
            self._packed = False
        self._queue.release()

    @property
    def packed(self) -> bool:
        """True while the device packs several frames per transfer for this run."""
        return self._packed

    def expect_end(self, next_counter: int) -> None:
        """The device says the stream ended before ``next_counter``: frames after the last one
        received, up to ``next_counter - 1``, count as lost once they cannot arrive any more
        (at once if the last frame is in; else after a read times out). If no frame arrives
        at all, nothing is known to be missing."""
        self._ledger.expect_end(next_counter)

    def expect_first(self, first_counter: int) -> None:
        """The device says the stream's first frame has counter ``first_counter`` (START_STREAM's
        answer): frames missing before the first one received count as lost too, and frames
        before it are an earlier run's (``late_frames``)."""
        self._ledger.expect_first(first_counter)

    @property
    def late_frames(self) -> int:
        """Frames of an earlier run that arrived during this one, set aside: never delivered
        nor counted in this run's ``stats``. The device had counted them (its answer to the
        stop), but they came after the host had accounted that run's end (they count as
        ``lost`` there) and stopped reading it: a device slow to send its last frames. The
        rest of a frame that the stop cut in two counts here too (a broken transfer before
        this run's first frame with no counter missing for it to stand for)."""
        with self._lock:
            return self._ledger.late

    def header_log(self) -> list[tuple[FrameHeader, int]]:
        """The first ``HEADER_LOG`` frames of the run whose header passed its checks, in
        order, each with the payload CRC-32 the host computed (it differs from the header's for
        a frame the payload CRC rejected)."""
        return list(self._dispatcher.header_log)

    def wait_drained(self, timeout_s: float) -> bool:
        """Wait until the stream's end (``expect_end``) is accounted and every queued frame is
        delivered; False on timeout."""
        ledger, queue = self._ledger, self._queue
        with self._cond:
            return self._cond.wait_for(lambda: ledger.end is None and queue.idle(), timeout_s)

    def wait_frames(self, n: int, timeout_s: float) -> bool:
        """Wait until ``n`` frames were delivered since ``start``; False on timeout or if the
        reader failed (see ``error``)."""
        ledger, queue = self._ledger, self._queue
        with self._cond:
            queue.frame_watchers += 1  # the dispatcher then says when each frame is counted
            try:
                return self._cond.wait_for(
                    lambda: ledger.stats.frames >= n or (queue.reader_done and queue.idle()),
                    timeout_s,
                ) and (ledger.stats.frames >= n)
            finally:
                queue.frame_watchers -= 1

    def stats(self) -> StreamStats:
        """A snapshot of the counters, with rates over the time since ``start``."""
        with self._lock:
            return self._ledger.snapshot(self._queue.overruns)
