"""The frame stream's reader thread: bulk reads, reassembly, header checks, into the queue.

``FrameReader`` runs one stream run's reader (thread ``camd-frame-read``): bulk reads of whole
transfers straight into preallocated slots (no copy, no allocation per frame) or, with
``read_bytes``, transfers that span several reads copied into a slot; the transfer's header
checked (``camd.protocol.stream.decode_header``; a packed transfer's frames in one vectorised
pass, ``camd.link.packed``); its counter accounted (``camd.link.frame_ledger``) and the slot
queued for the dispatcher (``camd.link.frame_queue``). It never waits for consumers. The
reassembly rules are the module docstring's of ``camd.link.frame_stream`` (docs/stream.md).
"""

from __future__ import annotations

import array
import errno
import threading
import time
from collections.abc import Callable
from dataclasses import KW_ONLY, dataclass, field

import usb.core

from camd.link.frame_ledger import FrameLedger
from camd.link.frame_queue import FrameQueue, FrameSlot
from camd.link.frame_types import StreamError, log
from camd.link.packed import Run, header_fields, is_plain_run
from camd.link.stream_device import ENDPOINT_IN, StreamDevice
from camd.protocol.stream import (
    HEADER_BYTES,
    U32_WRAP,
    FrameFlags,
    StreamFormatError,
    decode_header,
)

NO_DATA_WARNING_S = 5.0
_LAST = int(FrameFlags.LAST)
_MAX_CONSECUTIVE_ERRORS = 10
# The flag values with LAST set: a set lookup, where ``flags & FrameFlags.LAST`` makes a flag.
_WITH_LAST = frozenset(
    FrameFlags(bits) for bits in range(1 << len(FrameFlags)) if bits & FrameFlags.LAST
)


@dataclass(eq=False)
class FrameReader:
    """One run's reader of ``device`` into ``queue``, counting in ``ledger``.

    ``max_frame_bytes``: the run's largest frame; ``packed``: the device packs several frames
    per transfer this run; ``read_bytes``, ``timeout_s``, ``no_data_warning_s``,
    ``end_quiet_s``: the stream's (``FrameStream``)."""

    device: StreamDevice
    _ledger: FrameLedger
    _queue: FrameQueue
    _: KW_ONLY
    max_frame_bytes: int
    packed: bool
    read_bytes: int
    timeout_s: float
    no_data_warning_s: float
    end_quiet_s: float
    ident: str = field(init=False)
    _cond: threading.Condition = field(init=False)

    def __post_init__(self) -> None:
        self.ident = self.device.ident
        self._cond = self._queue.cond

    def run(self, thread_start: Callable[[str], object] | None) -> None:
        """The thread's body: read until the queue says stop; never die silently."""
        try:
            if thread_start is not None:
                thread_start("frame_reader")
            self._read_frames()
        except Exception as exc:  # never die silently: say why the stream stopped
            log.exception("frame stream %s: the reader failed", self.ident)
            self._ledger.error = StreamError(f"the frame reader of {self.ident} failed: {exc}")
        finally:
            with self._cond:
                self._queue.reader_done = True
                self._cond.notify_all()

    def _read_frames(self) -> None:
        dev = self.device.dev
        ledger = self._ledger
        stats = ledger.stats  # this run's: only this thread writes ``reads``
        stopping = self._queue.stopping
        slot_bytes = self._queue.slot_bytes
        timeout_ms = max(1, round(self.timeout_s * 1000))
        whole = self.read_bytes == 0 or self.read_bytes >= slot_bytes
        staging = None if whole else array.array("B", [0]) * self.read_bytes
        # One check per transfer: a packed run's transfers hold runs of frames.
        complete_transfer = self._transfer if self.packed else self._frame
        slot = self._queue.free.pop()
        filled = 0  # bytes of the current transfer in the slot (several reads per frame)
        discarding = False  # skipping the rest of a broken transfer
        errors = 0
        last_data = time.monotonic()
        while not stopping.is_set():
            target = slot.buf if whole or staging is None else staging
            try:
                n = int(dev.read(ENDPOINT_IN, target, timeout_ms))
            except usb.core.USBTimeoutError:
                ledger.count("timeouts")
                if filled:
                    # The read that timed out may have swallowed part of this transfer: give
                    # up the frame and skip whatever of it still comes.
                    ledger.broken("short", filled, self._counter_in(slot, filled))
                    filled, discarding = 0, True
                now = time.monotonic()
                idle_s = now - last_data
                with self._cond:
                    # Quiet since the last data and since the device said where it ended: the
                    # frames it counted that have not come are not coming (lost).
                    quiet_s = min(idle_s, now - ledger.end_told)
                    ledger.settle_end(idle=quiet_s >= self.end_quiet_s)
                    self._cond.notify_all()
                self._warn_idle(idle_s)
                continue
            except usb.core.USBError as exc:
                if stopping.is_set():
                    return
                if exc.errno == errno.EPIPE:
                    ledger.count("stalls")
                    if filled:
                        ledger.broken("short", filled, self._counter_in(slot, filled))
                    filled, discarding = 0, False
                    self.device.clear_halt()
                    continue
                if exc.errno == errno.ENODEV:
                    ledger.error = StreamError(
                        f"the frame-stream device {self.ident} disconnected ({exc}); check the "
                        "cable and the camera's power, then open the stream again"
                    )
                    log.error("%s", ledger.error)
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
            stats.reads += 1
            short_read = n < len(target)
            if discarding:
                discarding = not short_read  # a short read (even of 0 bytes) ends the transfer
                continue
            if n == 0 and filled == 0:
                continue  # a zero-length packet after a transfer that filled the read
            if not whole:
                if filled + n > slot_bytes:
                    ledger.broken(
                        "corrupt", filled + n, None, why="the transfer overflows the slot"
                    )
                    filled, discarding = 0, not short_read
                    continue
                slot.view[filled : filled + n] = memoryview(target)[:n]
            filled += n
            if not short_read:
                if whole:
                    ledger.broken(
                        "corrupt",
                        n,
                        None,
                        why=(
                            f"a transfer longer than the {n - 1} bytes of packed frames asked for"
                            if self.packed
                            else f"a transfer longer than max_frame_bytes={self.max_frame_bytes}"
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
            slot = complete_transfer(slot, filled)
            filled = 0

    def _complete_size(self, slot: FrameSlot, filled: int) -> int | None:
        """With a frame spanning reads and no short read yet: ``filled`` if the header says the
        frame is complete, None if more is to come, -1 if the header is bad (counted)."""
        if filled < HEADER_BYTES:
            return None
        try:
            header = decode_header(slot.view[:HEADER_BYTES])
        except StreamFormatError as exc:
            self._ledger.broken("corrupt", filled, None, why=str(exc))
            return -1
        return filled if filled >= header.frame_bytes else None

    def _frame(self, slot: FrameSlot, nbytes: int) -> FrameSlot:
        """A whole transfer of ``nbytes`` is in ``slot``: check it, queue it; the slot to fill
        next (the same one if the frame was rejected)."""
        received_ns = time.monotonic_ns()
        ledger = self._ledger
        if nbytes < HEADER_BYTES:
            ledger.broken("short", nbytes, None)
            return slot
        try:
            header = decode_header(slot.header)
        except StreamFormatError as exc:
            ledger.broken("corrupt", nbytes, None, why=str(exc))
            return slot
        if nbytes != header.frame_bytes:
            kind = "short" if nbytes < header.frame_bytes else "corrupt"
            why = f"frame {header.counter}: transfer of {nbytes} bytes, header says {header.frame_bytes}"
            ledger.broken(kind, nbytes, header.counter, why=why)
            return slot
        with self._cond:
            if ledger.take_late(header.counter):
                return slot  # an earlier run's, after its end: not this run's
            if not ledger.in_sequence(header.counter):
                ledger.stats.out_of_order += 1
                return slot
            if header.flags in _WITH_LAST:
                ledger.end = (header.counter + 1) % U32_WRAP
            if ledger.end is not None:
                ledger.settle_end(idle=False)
            return self._queue.put(slot, header, received_ns)

    def _transfer(self, slot: FrameSlot, nbytes: int) -> FrameSlot:
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
                ledger = self._ledger
                with self._cond:
                    # (An earlier run's frames, late, go frame by frame: set aside there.)
                    if (
                        ledger.end is None
                        and not ledger.is_late(first)
                        and ledger.in_sequence(first)
                    ):
                        ledger.last_seen = last
                        if int(fields["flags"][-1]) & _LAST:
                            ledger.end = (last + 1) % U32_WRAP
                            ledger.settle_end(idle=False)
                        return self._queue.put(slot, [Run(0, stride, count, fields)], received_ns)
        return self._transfer_by_frame(slot, nbytes, received_ns)

    def _transfer_by_frame(self, slot: FrameSlot, nbytes: int, received_ns: int) -> FrameSlot:
        """A packed transfer walked frame by frame: a bad header or a frame cut short ends
        it (the rest cannot be framed: it stands for one frame, as a broken transfer does)."""
        ledger = self._ledger
        view = slot.view
        runs: list[Run] = []
        run: Run | None = None
        shape: tuple[int, int] = (0, 0)
        previous = 0  # the counter of the frame before, in the transfer
        offset = 0
        while offset < nbytes:
            rest = nbytes - offset
            if rest < HEADER_BYTES:
                ledger.broken("short", rest, None)
                break
            try:
                header = decode_header(view[offset : offset + HEADER_BYTES])
            except StreamFormatError as exc:
                ledger.broken("corrupt", rest, None, why=str(exc))
                break
            stride = header.frame_bytes
            if stride > rest:
                why = (
                    f"frame {header.counter}: {rest} bytes left of a transfer, header says {stride}"
                )
                ledger.broken("short", rest, header.counter, why=why)
                break
            with self._cond:
                if ledger.take_late(header.counter):
                    accepted = False  # an earlier run's, after its end: not this run's
                elif not (accepted := ledger.in_sequence(header.counter)):
                    ledger.stats.out_of_order += 1
                else:
                    if header.flags in _WITH_LAST:
                        ledger.end = (header.counter + 1) % U32_WRAP
                    if ledger.end is not None:
                        ledger.settle_end(idle=False)
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
            return self._queue.put(slot, runs, received_ns)

    @staticmethod
    def _counter_in(slot: FrameSlot, filled: int) -> int | None:
        """The counter of a partial frame whose header arrived intact, else None."""
        if filled < HEADER_BYTES:
            return None
        try:
            return decode_header(slot.view[:HEADER_BYTES]).counter
        except StreamFormatError:
            return None

    def _warn_idle(self, idle_s: float) -> None:
        if idle_s < self.no_data_warning_s:
            return
        message = (
            f"no data from {self.ident} for {idle_s:.0f} s; check that the camera is "
            "streaming (`camctl stream --status`), its trigger and line rate, and the USB link"
        )
        if self._ledger.problem != message:
            log.warning("frame stream: %s", message)
        self._ledger.problem = message
