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
"""

from __future__ import annotations

import array
import contextlib
import dataclasses
import errno
import itertools
import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from types import TracebackType
from typing import Any, Literal

import numpy as np
import usb.core
import usb.util

from camd.link.packed import FrameBatch, Run, header_at, header_fields, is_plain_run, run_pixels
from camd.protocol.stream import (
    HEADER_BYTES,
    U32_WRAP,
    FrameFlags,
    FrameHeader,
    StreamFormatError,
    decode_header,
    payload_crc32,
)

log = logging.getLogger(__name__)

VENDOR_ID = 0x04B4  # Cypress FX3
PRODUCT_ID = 0x00F1  # the FX3 SDK's streamer example
ENDPOINT_IN = 0x81
INTERFACE = 0
NO_DATA_WARNING_S = 5.0
OVERFLOW_WAIT_S = 0.01
# Frame slots allocated when a stream starts (and kept across runs): the reader's, the
# dispatcher's and one queued. More are allocated only when the queue grows past that.
INITIAL_SLOTS = 3
# Small frames are dispatched in bursts: the dispatcher, woken by a first frame, waits up to
# DISPATCH_WAIT_S for a burst of frames (up to DISPATCH_BURST_BYTES, at most DISPATCH_BURST
# frames) before it delivers them. At tens of thousands of frames a second that is one
# wake-up (and one hand-over of Python's GIL between the threads) per burst instead of
# per frame; a frame waits at most DISPATCH_WAIT_S longer.
DISPATCH_BURST = 16
DISPATCH_BURST_BYTES = 256 << 10
DISPATCH_WAIT_S = 0.002
HEADER_LOG = 256  # headers kept per run for header_log() (docs/conformance.md)
# The streamer's vendor request for packed transfers (docs/stream.md "Packed transfers"):
# bmRequestType 0x40 (vendor, to the device), wValue = KiB of whole frames per transfer.
PACK_REQUEST = 0xB5
PACK_BYTES_MAX = 0xFFFF << 10  # wValue is 16 bits of KiB
# What a reader of small frames asks for: tens of small frames per read, a quarter of a
# millisecond of the fastest streams, a few hundred KiB of memory per slot.
PACK_BYTES = 256 << 10
_LAST = int(FrameFlags.LAST)
_MAX_CONSECUTIVE_ERRORS = 10
# The flag values with LAST set: a set lookup, where ``flags & FrameFlags.LAST`` makes a flag.
_WITH_LAST = frozenset(
    FrameFlags(bits) for bits in range(1 << len(FrameFlags)) if bits & FrameFlags.LAST
)

Overflow = Literal["drop_newest", "drop_oldest"]
# What the reader queues: one frame and its header, or (packed) a transfer's runs of frames.
Queued = tuple["_Slot", "FrameHeader | list[Run]", int]
OVERFLOW_POLICIES: tuple[Overflow, ...] = ("drop_newest", "drop_oldest")


class StreamError(RuntimeError):
    """The frame stream cannot be opened or read; the message says what to check."""


@dataclass(frozen=True, slots=True)
class ReceivedFrame:
    """One delivered frame.

    ``pixels`` is a read-only (rows, cols) uint16 view into the reader's slot, valid only
    during the callback: copy what you keep. ``gap_before`` is the number of frames missing
    between the previously delivered frame and this one, whatever the cause (lost on the
    link, corrupt, dropped by the queue); ``index`` counts delivered frames from 0.
    """

    header: FrameHeader
    pixels: np.ndarray
    received_ns: int  # time.monotonic_ns() when the reader had the whole frame
    gap_before: int
    index: int


@dataclass(slots=True)
class StreamStats:
    """The stream's counters since ``start()``.

    ``lost``: counters never received; ``corrupt``: bad header or payload CRC (or a
    malformed transfer); ``short``: truncated transfers; ``overruns``: dropped by the queue's
    overflow policy; ``stalls``: endpoint halts cleared; ``timeouts``: bulk reads that
    timed out (each ``timeout_s`` without data); ``out_of_order``: counters going backwards or
    repeated (dropped). ``frames``/``bytes``: delivered (header + payload bytes).
    """

    frames: int = 0
    bytes: int = 0
    lost: int = 0
    corrupt: int = 0
    short: int = 0
    overruns: int = 0
    stalls: int = 0
    timeouts: int = 0
    out_of_order: int = 0
    reads: int = 0
    consumer_errors: int = 0
    first_counter: int | None = None
    last_counter: int | None = None
    elapsed_s: float = 0.0
    mpix_per_s: float = 0.0
    mbyte_per_s: float = 0.0

    def as_dict(self) -> dict[str, int | float | None]:
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}


class _Slot:
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


Consumer = Callable[[ReceivedFrame], None]


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
    ``stop()`` may take that long. Use: ``open()``, ``add_consumer``, ``start(max_frame_bytes=)``,
    ... ``expect_end(n)``, ``wait_drained()``, ``stop()``, ``close()``; ``start`` and ``stop``
    may repeat on one open stream.
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
        self.vendor_id = vendor_id
        self.product_id = product_id
        self.backend = backend
        self.queue_frames = queue_frames
        self.queue_bytes = queue_bytes
        self._capacity = queue_frames  # frames the queue holds this run: see start()
        self.overflow = overflow
        self.read_bytes = read_bytes
        self.pack_bytes = pack_bytes
        self._packed = False  # this run's transfers may hold several frames (start())
        self.timeout_s = timeout_s
        self.overflow_wait_s = overflow_wait_s
        self.no_data_warning_s = no_data_warning_s
        # Called as ``thread_start("frame_reader")`` and ``thread_start("frame_dispatcher")``
        # from inside each thread when it starts: how the daemon gives the reader real-time
        # scheduling (camd/daemon/realtime.py).
        self.thread_start = thread_start
        self.ident = f"{vendor_id:04x}:{product_id:04x}"
        self._dev: Any = None
        self._detached = False
        self._packet_bytes = 0
        self._slot_bytes = 0
        self._max_frame_bytes = 0
        self._slots: list[_Slot] = []
        self._free: list[_Slot] = []
        self._consumers: tuple[Consumer, ...] = ()
        # One lock for the counters, the queue and the counter bookkeeping; held briefly.
        self._lock = threading.Lock()
        self._cond = threading.Condition(self._lock)
        self._queue: deque[Queued] = deque()
        self._dispatching = False
        self._reader_waiting = False  # the reader waits for a queue place (the dispatcher wakes it)
        self._dispatcher_idle = False  # the dispatcher waits for frames (the reader wakes it)
        self._frame_watchers = 0  # threads in wait_frames (the dispatcher wakes them per frame)
        self._burst = 1  # frames the dispatcher waits for, once woken: see start()
        self._stats = StreamStats()
        self._pixels = 0
        self._t_start = 0.0
        self._t_stop: float | None = None
        self._t_last_frame: float | None = None  # when the last frame was delivered
        self._last_seen: int | None = None  # counter of the last good header, in order
        self._first_seen: int | None = None  # the stream's first good header
        self._unattributed = 0  # broken transfers since then, each one frame of a gap
        self._broken_before_first = 0  # broken transfers before the first good header
        self._last_delivered: int | None = None
        self._end: int | None = None  # expect_end's counter, until accounted
        # The first HEADER_LOG headers of the run that passed the header checks, with the
        # payload CRC the host computed (the frames a payload CRC rejected too): the evidence
        # of docs/conformance.md's stream checks, which must not depend on the CRCs.
        self._header_log: list[tuple[FrameHeader, int]] = []
        self._stopping = threading.Event()
        self._reader: threading.Thread | None = None
        self._dispatcher: threading.Thread | None = None
        self._reader_done = True
        self.error: StreamError | None = None
        self.problem: str | None = None

    # -- context manager --------------------------------------------------------------------------

    def __enter__(self) -> FrameStream:
        self.open()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    # -- opening ----------------------------------------------------------------------------------

    def open(self) -> None:
        """Find the device, set its configuration, claim its interface."""
        if self._dev is not None:
            return
        try:
            dev = usb.core.find(
                idVendor=self.vendor_id, idProduct=self.product_id, backend=self.backend
            )
        except usb.core.NoBackendError:
            raise StreamError(
                "pyusb found no USB library: install libusb-1.0 (Debian/Ubuntu: "
                "`apt install libusb-1.0-0`)"
            ) from None
        except usb.core.USBError as exc:
            raise StreamError(f"cannot list USB devices ({exc}); {self._hint()}") from exc
        if dev is None:
            raise StreamError(f"no USB frame-stream device {self.ident} found; {self._hint()}")
        try:
            self._claim(dev)
            ep = self._endpoint(dev)
        except BaseException:
            with contextlib.suppress(Exception):
                usb.util.dispose_resources(dev)
            raise
        self._packet_bytes = int(ep.wMaxPacketSize)
        if self.read_bytes % self._packet_bytes:
            usb.util.dispose_resources(dev)
            raise ValueError(
                f"read_bytes = {self.read_bytes} is not a multiple of the endpoint's "
                f"{self._packet_bytes}-byte packets (a read must end on a packet boundary); "
                "use 0 for whole frames"
            )
        self._dev = dev

    def _hint(self) -> str:
        vid_pid = f"{self.vendor_id:04x}:{self.product_id:04x}"
        return (
            f"check the camera's power and USB 3 cable, that `lsusb -d {vid_pid}` lists it "
            "(an FX3 without its firmware shows as 04b4:00f3), and that this user may open it "
            "(udev rule systemd/99-camd.rules, group plugdev; docs/hardware.md)"
            # A backend given is a simulated device's (real hardware is libusb's default).
            + ("; with the simulator, that it runs with --usb-socket" if self.backend else "")
        )

    def _claim(self, dev: Any) -> None:
        try:
            active = bool(dev.is_kernel_driver_active(INTERFACE))
        except NotImplementedError:
            active = False
        except usb.core.USBError as exc:
            raise StreamError(
                f"cannot open the USB frame-stream device {self.ident}: {exc}; {self._hint()}"
            ) from exc
        if active:
            try:
                dev.detach_kernel_driver(INTERFACE)
            except usb.core.USBError as exc:
                raise StreamError(
                    f"cannot detach the kernel driver of {self.ident}: {exc}"
                ) from exc
            self._detached = True
        try:
            dev.get_active_configuration()
        except usb.core.USBError:
            try:
                dev.set_configuration()
            except usb.core.USBError as exc:
                raise StreamError(f"cannot configure {self.ident}: {exc}") from exc
        try:
            usb.util.claim_interface(dev, INTERFACE)
        except usb.core.USBError as exc:
            raise StreamError(
                f"cannot claim interface {INTERFACE} of {self.ident}: {exc}; is another "
                "program (another camd) reading the camera?"
            ) from exc

    def _endpoint(self, dev: Any) -> Any:
        intf = dev.get_active_configuration()[(INTERFACE, 0)]
        for ep in intf:
            if ep.bEndpointAddress == ENDPOINT_IN:
                if usb.util.endpoint_type(ep.bmAttributes) != usb.util.ENDPOINT_TYPE_BULK:
                    raise StreamError(f"endpoint 0x{ENDPOINT_IN:02X} of {self.ident} is not bulk")
                return ep
        raise StreamError(
            f"{self.ident} has no bulk IN endpoint 0x{ENDPOINT_IN:02X}; is its streamer "
            "firmware loaded?"
        )

    def close(self) -> None:
        """Stop, release the interface and the device (a closed stream may be opened again)."""
        self.stop()
        dev, self._dev = self._dev, None
        if dev is None:
            return
        with contextlib.suppress(usb.core.USBError):
            usb.util.release_interface(dev, INTERFACE)
        if self._detached:
            with contextlib.suppress(usb.core.USBError, NotImplementedError):
                dev.attach_kernel_driver(INTERFACE)
            self._detached = False
        usb.util.dispose_resources(dev)

    # -- consumers --------------------------------------------------------------------------------

    def add_consumer(self, cb: Consumer) -> None:
        """Call ``cb(frame)`` on the dispatcher thread for every delivered frame, in order."""
        with self._lock:
            self._consumers = (*self._consumers, cb)

    def remove_consumer(self, cb: Consumer) -> None:
        """Stop calling ``cb`` (from the next frame on); unknown callbacks are ignored."""
        with self._lock:
            consumers = list(self._consumers)
            if cb in consumers:
                consumers.remove(cb)
            self._consumers = tuple(consumers)

    # -- running ----------------------------------------------------------------------------------

    @property
    def running(self) -> bool:
        return self._reader is not None

    def queue_capacity(self, slot_bytes: int) -> int:
        """Frames the queue holds for slots of ``slot_bytes``: ``queue_frames``, capped to
        what ``queue_bytes`` holds (never under 2)."""
        if self.queue_bytes is None:
            return self.queue_frames
        return max(2, min(self.queue_frames, self.queue_bytes // slot_bytes))

    @property
    def allocated_slots(self) -> int:
        """Frame slots allocated now (the queue's high-water mark plus two, this run)."""
        return len(self._slots)

    def start(self, *, max_frame_bytes: int) -> None:
        """Reset the counters and start reading frames of up to ``max_frame_bytes`` (header
        included)."""
        if self._dev is None:
            raise StreamError("the frame stream is not open; call open() first")
        if self._reader is not None:
            raise StreamError("the frame stream is already running; stop() it first")
        if max_frame_bytes <= HEADER_BYTES:
            raise ValueError(f"max_frame_bytes = {max_frame_bytes} must exceed the header")
        # One byte over the largest frame, rounded up to whole packets: every frame then
        # ends in a short read, and a longer transfer shows as a full one.
        self._max_frame_bytes = max_frame_bytes
        p = self._packet_bytes
        slot_bytes = (max_frame_bytes + 1 + p - 1) // p * p
        self._packed = self.pack_bytes > 0 and self._ask_packing(self.pack_bytes)
        if self._packed:
            # A slot holds a whole transfer: up to pack_bytes of frames, and one frame more
            # than asked (a transfer that overfills the read is too long, as with one frame).
            slot_bytes = max(slot_bytes, (self.pack_bytes + 1 + p - 1) // p * p)
        self._capacity = self.queue_capacity(slot_bytes)
        self._burst = (
            1  # a transfer is a burst already
            if self._packed
            else max(1, min(DISPATCH_BURST, self._capacity, DISPATCH_BURST_BYTES // slot_bytes))
        )
        if slot_bytes != self._slot_bytes:
            self._slots = []
            self._slot_bytes = slot_bytes
        # The reader's and the dispatcher's slots, and one queued: the rest come as the queue
        # grows (_enqueue), up to queued + 2.
        while len(self._slots) < min(INITIAL_SLOTS, self._capacity + 2):
            self._slots.append(_Slot(slot_bytes))
        self._free = list(self._slots)
        with self._lock:
            self._queue.clear()
            self._stats = StreamStats()
            self._pixels = 0
            self._last_seen = None
            self._first_seen = None
            self._unattributed = 0
            self._broken_before_first = 0
            self._last_delivered = None
            self._end = None
            self._header_log = []
            self._t_start = time.monotonic()
            self._t_stop = None
            self._t_last_frame = None
            self._reader_done = False
        self.error = None
        self.problem = None
        self._stopping.clear()
        self._dispatcher = threading.Thread(
            target=self._dispatch_loop, name="camd-frame-dispatch", daemon=True
        )
        self._reader = threading.Thread(target=self._read_loop, name="camd-frame-read", daemon=True)
        self._dispatcher.start()
        self._reader.start()

    def stop(self) -> None:
        """Stop reading (within ``timeout_s``), deliver what is queued, join the threads."""
        reader, dispatcher = self._reader, self._dispatcher
        if reader is None or dispatcher is None:
            return
        self._stopping.set()
        reader.join()
        dispatcher.join()
        self._reader = self._dispatcher = None
        with self._lock:
            self._t_stop = time.monotonic()
        if self._packed:
            # Back to one frame per transfer: another reader of this device may expect it.
            self._ask_packing(0)
            self._packed = False
        # A burst's slots go back to the allocator; the first few are kept for the next run.
        del self._slots[INITIAL_SLOTS:]
        self._free = list(self._slots)

    @property
    def packed(self) -> bool:
        """True while the device packs several frames per transfer for this run."""
        return self._packed

    def _ask_packing(self, pack_bytes: int) -> bool:
        """Ask the streamer to pack frames into transfers of up to ``pack_bytes`` (0: one
        frame per transfer); False if it does not know the request (it stalls it)."""
        try:
            self._dev.ctrl_transfer(0x40, PACK_REQUEST, pack_bytes >> 10, INTERFACE, None)
        except usb.core.USBError as exc:
            if exc.errno == errno.EPIPE:
                log.info("frame stream %s: the device sends one frame per transfer", self.ident)
                return False
            if exc.errno == errno.ENODEV:
                return False  # gone: the reader says so
            raise StreamError(f"cannot set the transfer packing of {self.ident}: {exc}") from exc
        return True

    def expect_end(self, next_counter: int) -> None:
        """The device says the stream ended before ``next_counter``: frames after the last one
        received, up to ``next_counter - 1``, count as lost once they cannot arrive any more
        (at once if the last frame is in; else after a read times out). If no frame arrives
        at all, nothing is known to be missing."""
        with self._cond:
            self._end = next_counter % U32_WRAP
            self._settle_end(idle=False)
            self._cond.notify_all()

    def expect_first(self, first_counter: int) -> None:
        """The device says the stream's first frame has counter ``first_counter`` (START_STREAM's
        answer): frames missing before the first one received count as lost too."""
        with self._cond:
            first = first_counter % U32_WRAP
            if self._last_seen is None:
                # Nothing received yet: the first frame's gap is measured from here.
                self._last_seen = (first - 1) % U32_WRAP
                self._first_seen = first
            elif self._first_seen is not None:
                missing = (self._first_seen - first) % U32_WRAP
                if missing < U32_WRAP // 2:
                    self._stats.lost += max(0, missing - self._broken_before_first)
                    self._broken_before_first = 0
            self._cond.notify_all()

    def header_log(self) -> list[tuple[FrameHeader, int]]:
        """The first ``HEADER_LOG`` frames of the run whose header passed its checks, in
        order, each with the payload CRC-32 the host computed (it differs from the header's for
        a frame the payload CRC rejected)."""
        return list(self._header_log)

    def wait_drained(self, timeout_s: float) -> bool:
        """Wait until the stream's end (``expect_end``) is accounted and every queued frame is
        delivered; False on timeout."""
        with self._cond:
            return self._cond.wait_for(
                lambda: self._end is None and not self._queue and not self._dispatching,
                timeout_s,
            )

    def wait_frames(self, n: int, timeout_s: float) -> bool:
        """Wait until ``n`` frames were delivered since ``start``; False on timeout or if the
        reader failed (see ``error``)."""
        with self._cond:
            self._frame_watchers += 1  # the dispatcher then says when each frame is counted
            try:
                return self._cond.wait_for(
                    lambda: (
                        self._stats.frames >= n
                        or (self._reader_done and not self._queue and not self._dispatching)
                    ),
                    timeout_s,
                ) and (self._stats.frames >= n)
            finally:
                self._frame_watchers -= 1

    def stats(self) -> StreamStats:
        """A snapshot of the counters, with rates over the time since ``start``."""
        with self._lock:
            s = dataclasses.replace(self._stats)
            # Rates over the time frames were flowing: from start() to the last delivery (not
            # to stop(), which may come much later, e.g. after an idle read timeout).
            if self._t_last_frame is not None:
                end = self._t_last_frame
            else:
                end = self._t_stop if self._t_stop is not None else time.monotonic()
            pixels = self._pixels
        s.elapsed_s = max(0.0, end - self._t_start) if self._t_start else 0.0
        if s.elapsed_s > 0:
            s.mpix_per_s = pixels / s.elapsed_s / 1e6
            s.mbyte_per_s = s.bytes / s.elapsed_s / 1e6
        return s

    # -- the reader thread --------------------------------------------------------------------

    def _read_loop(self) -> None:
        try:
            if self.thread_start is not None:
                self.thread_start("frame_reader")
            self._read_frames()
        except Exception as exc:  # never die silently: say why the stream stopped
            log.exception("frame stream %s: the reader failed", self.ident)
            self.error = StreamError(f"the frame reader of {self.ident} failed: {exc}")
        finally:
            with self._cond:
                self._reader_done = True
                self._cond.notify_all()

    def _read_frames(self) -> None:
        dev = self._dev
        timeout_ms = max(1, round(self.timeout_s * 1000))
        whole = self.read_bytes == 0 or self.read_bytes >= self._slot_bytes
        staging = None if whole else array.array("B", [0]) * self.read_bytes
        slot = self._free.pop()
        filled = 0  # bytes of the current transfer in the slot (several reads per frame)
        discarding = False  # skipping the rest of a broken transfer
        errors = 0
        last_data = time.monotonic()
        while not self._stopping.is_set():
            target = slot.buf if whole or staging is None else staging
            try:
                n = int(dev.read(ENDPOINT_IN, target, timeout_ms))
            except usb.core.USBTimeoutError:
                self._count("timeouts")
                if filled:
                    # The read that timed out may have swallowed part of this transfer: give
                    # up the frame and skip whatever of it still comes.
                    self._broken("short", filled, self._counter_in(slot, filled))
                    filled, discarding = 0, True
                idle_s = time.monotonic() - last_data
                with self._cond:
                    self._settle_end(idle=True)
                    self._cond.notify_all()
                self._warn_idle(idle_s)
                continue
            except usb.core.USBError as exc:
                if self._stopping.is_set():
                    return
                if exc.errno == errno.EPIPE:
                    self._count("stalls")
                    if filled:
                        self._broken("short", filled, self._counter_in(slot, filled))
                    filled, discarding = 0, False
                    self._clear_halt(dev)
                    continue
                if exc.errno == errno.ENODEV:
                    self.error = StreamError(
                        f"the frame-stream device {self.ident} disconnected ({exc}); check the "
                        "cable and the camera's power, then open the stream again"
                    )
                    log.error("%s", self.error)
                    return
                errors += 1
                log.warning("frame stream %s: bulk read failed: %s", self.ident, exc)
                if errors >= _MAX_CONSECUTIVE_ERRORS:
                    raise StreamError(
                        f"{errors} bulk reads in a row failed, the last: {exc}"
                    ) from exc
                time.sleep(0.01)
                continue
            errors = 0
            last_data = time.monotonic()
            # Only this thread writes ``reads``: no lock (a snapshot may be one read behind).
            self._stats.reads += 1
            short_read = n < len(target)
            if discarding:
                discarding = not short_read  # a short read (even of 0 bytes) ends the transfer
                continue
            if n == 0 and filled == 0:
                continue  # a zero-length packet after a transfer that filled the read
            if not whole:
                if filled + n > self._slot_bytes:
                    self._broken("corrupt", filled + n, None, why="the transfer overflows the slot")
                    filled, discarding = 0, not short_read
                    continue
                slot.view[filled : filled + n] = memoryview(target)[:n]
            filled += n
            if not short_read:
                if whole:
                    self._broken(
                        "corrupt",
                        n,
                        None,
                        why=(
                            f"a transfer longer than the {n - 1} bytes of packed frames asked for"
                            if self._packed
                            else f"a transfer longer than max_frame_bytes={self._max_frame_bytes}"
                        ),
                    )
                    filled, discarding = 0, True
                    continue
                complete = self._complete_size(slot, filled)
                if complete is None:
                    continue  # more of this transfer to read
                if complete < 0:
                    filled, discarding = 0, True  # a bad header: skip to the transfer's end
                    continue
            slot = self._transfer(slot, filled) if self._packed else self._frame(slot, filled)
            filled = 0

    def _complete_size(self, slot: _Slot, filled: int) -> int | None:
        """With a frame spanning reads and no short read yet: ``filled`` if the header says the
        frame is complete, None if more is to come, -1 if the header is bad (counted)."""
        if filled < HEADER_BYTES:
            return None
        try:
            header = decode_header(slot.view[:HEADER_BYTES])
        except StreamFormatError as exc:
            self._broken("corrupt", filled, None, why=str(exc))
            return -1
        return filled if filled >= header.frame_bytes else None

    def _frame(self, slot: _Slot, nbytes: int) -> _Slot:
        """A whole transfer of ``nbytes`` is in ``slot``: check it, queue it; the slot to fill
        next (the same one if the frame was rejected)."""
        received_ns = time.monotonic_ns()
        if nbytes < HEADER_BYTES:
            self._broken("short", nbytes, None)
            return slot
        try:
            header = decode_header(slot.header)
        except StreamFormatError as exc:
            self._broken("corrupt", nbytes, None, why=str(exc))
            return slot
        if nbytes != header.frame_bytes:
            kind = "short" if nbytes < header.frame_bytes else "corrupt"
            why = f"frame {header.counter}: transfer of {nbytes} bytes, header says {header.frame_bytes}"
            self._broken(kind, nbytes, header.counter, why=why)
            return slot
        with self._cond:
            if not self._in_sequence(header.counter):
                self._stats.out_of_order += 1
                return slot
            if header.flags in _WITH_LAST:
                self._end = (header.counter + 1) % U32_WRAP
            if self._end is not None:
                self._settle_end(idle=False)
            return self._enqueue(slot, header, received_ns)

    def _transfer(self, slot: _Slot, nbytes: int) -> _Slot:
        """A whole packed transfer of ``nbytes`` is in ``slot``: check its frames, queue those
        accepted; the slot to fill next. The usual transfer (frames of one size, every header
        good, counters consecutive) is checked in one vectorised pass; any other goes frame
        by frame, with exactly the rules and counts of one frame per transfer."""
        received_ns = time.monotonic_ns()
        view = slot.view
        stride = HEADER_BYTES + int.from_bytes(view[40:44], "little") if nbytes >= 44 else 0
        # (One frame alone: decode_header costs less than the numpy pass.)
        if stride > HEADER_BYTES and nbytes % stride == 0 and nbytes > stride:
            count = nbytes // stride
            fields = header_fields(slot.buf, 0, stride, count)
            if is_plain_run(view, fields, stride):
                first, last = int(fields["counter"][0]), int(fields["counter"][-1])
                with self._cond:
                    if self._end is None and self._in_sequence(first):
                        self._last_seen = last
                        if int(fields["flags"][-1]) & _LAST:
                            self._end = (last + 1) % U32_WRAP
                            self._settle_end(idle=False)
                        return self._enqueue(slot, [Run(0, stride, count, fields)], received_ns)
        return self._transfer_by_frame(slot, nbytes, received_ns)

    def _transfer_by_frame(self, slot: _Slot, nbytes: int, received_ns: int) -> _Slot:
        """A packed transfer walked frame by frame: a bad header or a frame cut short ends
        it (the rest cannot be framed: it stands for one frame, as a broken transfer does)."""
        view = slot.view
        runs: list[Run] = []
        run: Run | None = None
        shape: tuple[int, int] = (0, 0)
        previous = 0  # the counter of the frame before, in the transfer
        offset = 0
        while offset < nbytes:
            rest = nbytes - offset
            if rest < HEADER_BYTES:
                self._broken("short", rest, None)
                break
            try:
                header = decode_header(view[offset : offset + HEADER_BYTES])
            except StreamFormatError as exc:
                self._broken("corrupt", rest, None, why=str(exc))
                break
            stride = header.frame_bytes
            if stride > rest:
                why = (
                    f"frame {header.counter}: {rest} bytes left of a transfer, header says {stride}"
                )
                self._broken("short", rest, header.counter, why=why)
                break
            with self._cond:
                accepted = self._in_sequence(header.counter)
                if not accepted:
                    self._stats.out_of_order += 1
                else:
                    if header.flags in _WITH_LAST:
                        self._end = (header.counter + 1) % U32_WRAP
                    if self._end is not None:
                        self._settle_end(idle=False)
            if not accepted:
                run = None
            elif (
                run is not None
                and run.stride == stride
                and shape == (header.rows, header.cols)
                and run.offset + run.count * stride == offset
                and header.counter == (previous + 1) % U32_WRAP
            ):
                run.count += 1  # a run: the same size and shape, counters one apart
            else:
                run = Run(offset, stride, 1, header_fields(slot.buf, offset, stride, 1))
                shape = (header.rows, header.cols)
                runs.append(run)
            previous = header.counter
            offset += stride
        if not runs:
            return slot
        for r in runs:
            r.fields = header_fields(slot.buf, r.offset, r.stride, r.count)
        with self._cond:
            return self._enqueue(slot, runs, received_ns)

    def _enqueue(self, slot: _Slot, header: FrameHeader | list[Run], received_ns: int) -> _Slot:
        """Queue the frame, or a packed transfer's runs (lock held); the overflow policy
        decides when the queue is full."""
        q = self._queue
        capacity = self._capacity
        if len(q) >= capacity and self.overflow_wait_s > 0:
            # A short, bounded wait: it also hands the dispatcher the GIL, which a reader
            # working through a backlog (reads that never block) would otherwise keep.
            self._reader_waiting = True
            self._cond.wait_for(
                lambda: len(q) < capacity or self._stopping.is_set(),
                self.overflow_wait_s,
            )
            self._reader_waiting = False
        if len(q) >= capacity:
            if self.overflow == "drop_newest":
                self._stats.overruns += _frames_in(header)
                return slot  # this frame is dropped: the slot is reused
            old_slot, old, _ = q.popleft()
            self._stats.overruns += _frames_in(old)
            self._free.append(old_slot)
        q.append((slot, header, received_ns))
        if self._dispatcher_idle and (len(q) == 1 or len(q) >= self._burst):
            self._cond.notify_all()
        if not self._free:
            # Never more than queued + the reader's + the dispatcher's: the queue is at most
            # capacity long here, so this slot count stays within capacity + 2.
            grown = _Slot(self._slot_bytes)
            self._slots.append(grown)
            return grown
        return self._free.pop()

    def _in_sequence(self, counter: int) -> bool:
        """Account for ``counter`` (lock held): lost frames before it; False if it goes back."""
        if self._last_seen is None:
            self._last_seen = self._first_seen = counter
            self._broken_before_first = self._unattributed
            self._unattributed = 0
            return True
        step = (counter - self._last_seen) % U32_WRAP
        if step == 0 or step >= U32_WRAP // 2:
            return False
        self._stats.lost += max(0, step - 1 - self._unattributed)
        self._unattributed = 0
        self._last_seen = counter
        return True

    def _settle_end(self, *, idle: bool) -> None:
        """Account the end of the stream if it is due (lock held)."""
        end = self._end
        if end is None:
            return
        last = self._last_seen
        missing = 0 if last is None else (end - 1 - last) % U32_WRAP
        if missing >= U32_WRAP // 2:
            missing = 0  # frames past the end arrived: nothing more is missing
        if (missing or last is None) and not idle:
            return  # frames may still be on their way: wait for the line to go quiet
        self._stats.lost += max(0, missing - self._unattributed)
        self._unattributed = 0
        if last is not None:
            self._last_seen = (end - 1) % U32_WRAP  # late frames count as out of order
        self._end = None

    def _broken(self, kind: str, nbytes: int, counter: int | None, *, why: str = "") -> None:
        """Count a broken transfer; it stands for one frame in the counter bookkeeping."""
        with self._cond:
            if kind == "short":
                self._stats.short += 1
            else:
                self._stats.corrupt += 1
            if counter is None:
                self._unattributed += 1  # the next counter gap has one frame less lost
            else:
                self._in_sequence(counter)  # known: this frame is accounted, not lost
        detail = why or f"a {kind} transfer of {nbytes} bytes"
        self.problem = detail
        log.debug("frame stream %s: %s", self.ident, detail)

    @staticmethod
    def _counter_in(slot: _Slot, filled: int) -> int | None:
        """The counter of a partial frame whose header arrived intact, else None."""
        if filled < HEADER_BYTES:
            return None
        try:
            return decode_header(slot.view[:HEADER_BYTES]).counter
        except StreamFormatError:
            return None

    def _clear_halt(self, dev: Any) -> None:
        try:
            dev.clear_halt(ENDPOINT_IN)
        except usb.core.USBError as exc:
            raise StreamError(
                f"cannot clear the halt of endpoint 0x{ENDPOINT_IN:02X} on {self.ident}: {exc}; "
                "reset the camera"
            ) from exc

    def _warn_idle(self, idle_s: float) -> None:
        if idle_s < self.no_data_warning_s:
            return
        message = (
            f"no data from {self.ident} for {idle_s:.0f} s; check that the camera is "
            "streaming (`camctl stream --status`), its trigger and line rate, and the USB link"
        )
        if self.problem != message:
            log.warning("frame stream: %s", message)
        self.problem = message

    def _count(self, name: str) -> None:
        with self._lock:
            setattr(self._stats, name, getattr(self._stats, name) + 1)

    # -- the dispatcher thread --------------------------------------------------------------------

    def _dispatch_loop(self) -> None:
        if self.thread_start is not None:
            self.thread_start("frame_dispatcher")
        cond = self._cond
        queue = self._queue
        # The frame just handed to the consumers, accounted (counted, its slot freed) in the
        # same lock section that takes the next one: one lock round per frame (or transfer).
        done: tuple[_Slot, FrameHeader | _Delivered | None] | None = None
        while True:
            with cond:
                if done is not None:
                    self._account(*done)
                    done = None
                if not queue:
                    self._dispatching = False
                    cond.notify_all()  # wait_drained, wait_frames
                    self._dispatcher_idle = True
                    cond.wait_for(lambda: bool(queue) or self._reader_done)
                    if len(queue) < self._burst and not self._reader_done:
                        cond.wait(DISPATCH_WAIT_S)  # for a burst: the reader wakes us at one
                    self._dispatcher_idle = False
                    if not queue:
                        return  # the reader has stopped and everything was delivered
                slot, header, received_ns = queue.popleft()
                self._dispatching = True
                consumers = self._consumers
                index = self._stats.frames
                if self._reader_waiting or self._frame_watchers:
                    # A reader waiting for a queue place may go on; wait_frames sees the count.
                    cond.notify_all()
            if isinstance(header, list):
                done = (slot, self._deliver_runs(slot, header, received_ns, consumers, index))
                continue
            done = (slot, None)
            if self._deliver(slot, header, received_ns, consumers, index):
                done = (slot, header)

    def _account(self, slot: _Slot, header: FrameHeader | _Delivered | None) -> None:
        """A frame went through the consumers (``header``; None: it was dropped, its payload
        CRC mismatched), or a packed transfer's frames did (``_Delivered``): count it and
        free its slot (lock held)."""
        self._free.append(slot)
        s = self._stats
        if header is None:
            s.corrupt += 1
            return
        if isinstance(header, _Delivered):
            s.corrupt += header.corrupt
            if header.frames:
                self._t_last_frame = time.monotonic()
                s.frames += header.frames
                s.bytes += header.bytes
                self._pixels += header.pixels
                if s.first_counter is None:
                    s.first_counter = header.first_counter
                s.last_counter = header.last_counter
            return
        self._t_last_frame = time.monotonic()
        s.frames += 1
        s.bytes += header.frame_bytes
        self._pixels += header.rows * header.cols
        if s.first_counter is None:
            s.first_counter = header.counter
        s.last_counter = header.counter

    def _deliver_runs(
        self,
        slot: _Slot,
        runs: list[Run],
        received_ns: int,
        consumers: tuple[Consumer, ...],
        index: int,
    ) -> _Delivered:
        """A packed transfer: the payload CRCs of its runs, then every consumer with each
        stretch of good frames (``on_batch`` with them all, else a call per frame)."""
        done = _Delivered()
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
            for i in range(min(run.count, HEADER_LOG - len(self._header_log))):
                self._header_log.append((header_at(run.fields, i), int(computed[i])))
            good = computed == run.fields["payload_crc32"]
            if good.all():
                stretches = [(0, run.count)]
            else:
                bad = np.flatnonzero(~good)
                done.corrupt += len(bad)
                counter = int(run.fields["counter"][bad[-1]])
                self.problem = f"frame {counter}: payload CRC mismatch"
                edges = [-1, *bad.tolist(), run.count]
                stretches = [(a + 1, b) for a, b in itertools.pairwise(edges) if b > a + 1]
            for a, b in stretches:
                self._deliver_batch(slot, run, a, b, received_ns, consumers, index, done)
                index += b - a
        return done

    def _deliver_batch(
        self,
        slot: _Slot,
        run: Run,
        a: int,
        b: int,
        received_ns: int,
        consumers: tuple[Consumer, ...],
        index: int,
        done: _Delivered,
    ) -> None:
        """Frames ``a .. b - 1`` of ``run`` (good, consecutive) to every consumer."""
        fields = run.fields[a:b]
        counters = fields["counter"]
        first = int(counters[0])
        last = self._last_delivered
        if last is None:
            seen = self._first_seen if self._first_seen is not None else first
            last = (seen - 1) % U32_WRAP
        pixels = run_pixels(slot.buf, run, a, b)
        batch = FrameBatch(pixels, fields, received_ns, (first - last - 1) % U32_WRAP, index)
        k = b - a
        for cb in consumers:
            on_batch = getattr(cb, "on_batch", None)
            if on_batch is not None:
                try:
                    on_batch(batch)
                except Exception:
                    with self._lock:
                        self._stats.consumer_errors += k
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
                    with self._lock:
                        self._stats.consumer_errors += 1
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
        slot: _Slot,
        header: FrameHeader,
        received_ns: int,
        consumers: tuple[Consumer, ...],
        index: int,
    ) -> bool:
        """Check the payload CRC, then call every consumer; False if the CRC mismatched."""
        payload = slot.view[HEADER_BYTES : HEADER_BYTES + header.payload_bytes]
        computed = payload_crc32(payload)
        if len(self._header_log) < HEADER_LOG:  # only the dispatcher appends
            self._header_log.append((header, computed))
        if computed != header.payload_crc32:
            self.problem = f"frame {header.counter}: payload CRC mismatch"
            return False
        last = self._last_delivered
        if last is None:
            # Before the first delivery, count from the first frame the reader saw (set before
            # this frame was queued): a rejected first frame is a gap too.
            first = self._first_seen if self._first_seen is not None else header.counter
            last = (first - 1) % U32_WRAP
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
                with self._lock:
                    self._stats.consumer_errors += 1
                log.exception("frame stream: consumer %r failed on frame %d", cb, header.counter)
        self._last_delivered = header.counter
        return True


@dataclass(slots=True)
class _Delivered:
    """What a packed transfer's dispatch delivered, for ``_account``."""

    frames: int = 0
    bytes: int = 0
    pixels: int = 0
    corrupt: int = 0
    first_counter: int | None = None
    last_counter: int | None = None


def _frames_in(queued: FrameHeader | list[Run]) -> int:
    """Frames in a queue entry: one, or a packed transfer's runs."""
    return sum(r.count for r in queued) if isinstance(queued, list) else 1
