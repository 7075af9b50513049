"""Serve an FpgaModel on a real pseudo-terminal, with fault injection on the line.

The host opens the pty's slave side (``/dev/pts/N``, or the stable ``link`` symlink) exactly as
it opens a USB-RS-422 adapter. One thread runs a select loop on the master side::

    read -> corrupt (rx bit errors) -> receiver Decoder -> drop? (rx) -> model.handle
         -> schedule after delay_ms -> garbage burst, drop? (tx), corrupt (tx bit errors)
         -> outgoing buffer -> write when the master is writable

plus periodic HOUSEKEEPING telemetry and the expiry of stalled candidate frames in the receiver.
While the model is silent (SIM_FAIL_NEXT with action silence: a dropped line), nothing it makes
is sent.
"""

from __future__ import annotations

import contextlib
import heapq
import itertools
import os
import select
import termios
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from camd.protocol import Frame, FrameType
from firmware_models.fpga import FpgaModel
from firmware_models.inject import FaultInjector

READ_CHUNK_BYTES = 4096
FRAME_TIMEOUT_S = 0.02  # a maximum-size frame takes ~11 ms at 921600 Bd
TX_BUFFER_LIMIT_BYTES = 64 * 1024
_IDLE_WAIT_S = 1.0  # select timeout when nothing is scheduled; a stop() wakes it anyway


@dataclass(slots=True)
class _Chunk:
    """Bytes waiting in the outgoing buffer; telemetry may be discarded when the host lags."""

    data: bytes
    telemetry: bool


@dataclass(slots=True)
class ServerCounters:
    """What the transport did besides passing frames through."""

    tx_overflow_dropped: int = 0  # frames (or garbage bursts) discarded: the host was not reading
    tx_silenced: int = 0  # frames the device made while off the line (SIM_FAIL_NEXT silence)


class PtyServer:
    """Run ``model`` behind a pty; ``open()`` creates it, ``serve()`` runs until ``stop()``.

    The server keeps its own descriptor of the slave side open, so the master never reads EIO
    while no host has the port open and a host can close and reopen the port at will. With
    ``link`` given, a symlink at that path points at the slave so that a host can reconnect to
    a newer simulator at the same path; it is replaced atomically and removed on ``close()``
    only if it still points at this server's pty.
    """

    def __init__(
        self,
        model: FpgaModel,
        *,
        link: Path | str | None = None,
        hk_period_s: float = 1.0,
        frame_timeout_s: float = FRAME_TIMEOUT_S,
        tx_buffer_limit_bytes: int = TX_BUFFER_LIMIT_BYTES,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if hk_period_s < 0:
            raise ValueError(f"hk_period_s={hk_period_s} is negative; use 0 to disable telemetry")
        self.model = model
        self.injector: FaultInjector = model.injector
        self.link = Path(link) if link is not None else None
        self.hk_period_s = hk_period_s
        self.frame_timeout_s = frame_timeout_s
        self.tx_buffer_limit_bytes = tx_buffer_limit_bytes
        self.counters = ServerCounters()
        self._clock = clock
        self._master = -1
        self._slave = -1
        self._wake_r = -1
        self._wake_w = -1
        self.tty_path = ""
        # Set once, never cleared: a stop() that lands before serve() starts must still count.
        self._stop_requested = False
        self._out: deque[_Chunk] = deque()
        self._out_bytes = 0
        self._head_sent = 0  # bytes of _out[0] already written
        self._scheduled: list[tuple[float, int, Frame]] = []  # heap of (due_s, order, frame)
        self._order = itertools.count()
        self._next_hk_s = 0.0

    # -- lifecycle ------------------------------------------------------------------------

    def open(self) -> str:
        """Create the pty (and the link) and queue the BOOT event; return the slave's path."""
        if self.link is not None and self.link.exists() and not self.link.is_symlink():
            raise FileExistsError(
                f"link path {self.link} exists and is not a symlink; "
                "remove it or choose another path"
            )
        self._master, self._slave = os.openpty()
        _make_raw(self._slave)
        os.set_blocking(self._master, False)
        self.tty_path = os.ttyname(self._slave)
        self._wake_r, self._wake_w = os.pipe()
        os.set_blocking(self._wake_w, False)
        if self.link is not None:
            self._point_link()
        now_s = self._clock()
        self._next_hk_s = now_s + self.hk_period_s
        self.model.wake = self._wake_up
        for frame in self.model.boot_frames(now_s):
            self._transmit(frame)
        return self.tty_path

    def serve(self) -> None:
        """Run the select loop until ``stop()`` is called (from a signal handler, say)."""
        if self._master < 0:
            raise RuntimeError("call open() before serve()")
        while not self._stop_requested:
            self._step()

    def stop(self) -> None:
        """Make ``serve()`` return soon; safe to call from a signal handler."""
        self._stop_requested = True
        self._wake_up()

    def _wake_up(self) -> None:
        """Make the loop run a step now (from any thread): the model has events to send."""
        if self._wake_w >= 0:
            with contextlib.suppress(BlockingIOError, OSError):
                os.write(self._wake_w, b"\0")

    def close(self) -> None:
        """Remove our link (if it is still ours) and close every descriptor."""
        self._remove_link()
        for fd in (self._master, self._slave, self._wake_r, self._wake_w):
            if fd >= 0:
                os.close(fd)
        self._master = self._slave = self._wake_r = self._wake_w = -1

    @property
    def tx_buffered_bytes(self) -> int:
        """Bytes waiting to be written to the master (bounded by ``tx_buffer_limit_bytes``)."""
        return self._out_bytes

    def __enter__(self) -> PtyServer:
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- the link -------------------------------------------------------------------------

    def _point_link(self) -> None:
        assert self.link is not None
        tmp = self.link.with_name(f".{self.link.name}.{os.getpid()}.tmp")
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
        try:
            os.symlink(self.tty_path, tmp)
            os.replace(tmp, self.link)  # atomic: a host never sees the path missing
        except OSError as exc:
            raise OSError(
                exc.errno,
                f"cannot create the link {self.link}: {exc.strerror}; "
                f"check that {self.link.parent} exists and is writable",
            ) from None

    def _remove_link(self) -> None:
        if self.link is None or not self.tty_path:
            return
        try:
            if os.readlink(self.link) == self.tty_path:
                self.link.unlink()
        except OSError:
            pass  # already gone or replaced by something that is not a symlink

    # -- the loop -------------------------------------------------------------------------

    def _step(self) -> None:
        now_s = self._clock()
        readable, _, _ = select.select(
            [self._master, self._wake_r],
            [self._master] if self._out else [],
            [],
            self._timeout_s(now_s),
        )
        if self._wake_r in readable:
            os.read(self._wake_r, READ_CHUNK_BYTES)
        if self._master in readable:
            self._receive()
        now_s = self._clock()
        self._expire_stale(now_s)
        self._release_due(now_s)
        for frame in self.model.take_unsolicited(now_s):
            self._transmit(frame)
        self._maybe_send_housekeeping(now_s)
        if self._out:
            # Non-blocking, so trying also when select did not report writable costs nothing
            # and sends this step's responses without another trip through select.
            self._write()

    def _timeout_s(self, now_s: float) -> float:
        deadlines = []
        if self._scheduled:
            deadlines.append(self._scheduled[0][0])
        head_since_s = self.model.receiver.head_since_s
        if head_since_s is not None:
            deadlines.append(head_since_s + self.frame_timeout_s)
        if self.hk_period_s > 0:
            deadlines.append(self._next_hk_s)
        event_s = self.model.next_event_s()
        if event_s is not None:
            deadlines.append(event_s)
        if not deadlines:
            return _IDLE_WAIT_S
        return min(_IDLE_WAIT_S, max(0.0, min(deadlines) - now_s))

    def _receive(self) -> None:
        # No EIO to handle: it comes only when no slave descriptor is open, and we hold one.
        try:
            data = os.read(self._master, READ_CHUNK_BYTES)
        except BlockingIOError:
            return
        now_s = self._clock()
        self._dispatch(self.model.receiver.feed(self.injector.corrupt(data), now_s), now_s)

    def _dispatch(self, frames: list[Frame], now_s: float) -> None:
        for frame in frames:
            if self.injector.drop("rx"):
                continue
            for out in self.model.handle(frame, now_s):
                due_s = now_s + self.injector.response_delay_s()
                heapq.heappush(self._scheduled, (due_s, next(self._order), out))

    def _release_due(self, now_s: float) -> None:
        while self._scheduled and self._scheduled[0][0] <= now_s:
            _, _, frame = heapq.heappop(self._scheduled)
            self._transmit(frame)

    def _expire_stale(self, now_s: float) -> None:
        # A bit error in a length field leaves the receiver waiting for bytes of later frames.
        # The host's retries keep the line busy, so an idle-line timeout would never fire: the
        # candidate's age at the head of the buffer decides (Decoder.expire).
        # (The receiver's stats.partial_flushes counts them.)
        self._dispatch(self.model.receiver.expire(now_s, self.frame_timeout_s), now_s)

    def _maybe_send_housekeeping(self, now_s: float) -> None:
        if self.hk_period_s <= 0 or now_s < self._next_hk_s:
            return
        self._transmit(self.model.housekeeping_frame(now_s))
        self._next_hk_s += self.hk_period_s
        if self._next_hk_s <= now_s:  # fell behind (suspended?): do not send a burst
            self._next_hk_s = now_s + self.hk_period_s

    def _transmit(self, frame: Frame) -> None:
        """Put one outgoing frame on the (faulty) line."""
        if self.model.silent(self._clock()):
            self.counters.tx_silenced += 1  # the line is down: the frame is lost
            return
        telemetry = frame.type == FrameType.TELEMETRY
        burst = self.injector.garbage()
        if burst:
            self._enqueue(_Chunk(self.injector.corrupt(burst), telemetry=True))
        if self.injector.drop("tx"):
            return
        self._enqueue(_Chunk(self.injector.corrupt(frame.encode()), telemetry=telemetry))

    def _enqueue(self, chunk: _Chunk) -> None:
        self._out.append(chunk)
        self._out_bytes += len(chunk.data)
        if self._out_bytes > self.tx_buffer_limit_bytes:
            self._shed()

    def _shed(self) -> None:
        """Bound the outgoing buffer when no host reads: drop the oldest telemetry first."""
        for want_telemetry in (True, False):
            # Never the head once partly written: half a frame would corrupt the next one.
            start = 1 if self._head_sent else 0
            kept: deque[_Chunk] = deque(itertools.islice(self._out, start))
            for chunk in itertools.islice(self._out, start, None):
                over = self._out_bytes > self.tx_buffer_limit_bytes
                if over and chunk.telemetry == want_telemetry:
                    self._out_bytes -= len(chunk.data)
                    self.counters.tx_overflow_dropped += 1
                else:
                    kept.append(chunk)
            self._out = kept
            if self._out_bytes <= self.tx_buffer_limit_bytes:
                return

    def _write(self) -> None:
        while self._out:
            head = self._out[0]
            try:
                n = os.write(self._master, head.data[self._head_sent :])
            except BlockingIOError:
                return
            self._head_sent += n
            if self._head_sent < len(head.data):
                return
            self._out.popleft()
            self._out_bytes -= len(head.data)
            self._head_sent = 0


def _make_raw(fd: int) -> None:
    """Put a tty in raw mode at once, as cfmakeraw(3) does.

    The default line discipline would echo the host's bytes back to it, turn CR into LF,
    swallow XON/XOFF and raise signals on ^C inside binary frames."""
    attrs = termios.tcgetattr(fd)
    attrs[0] &= ~(
        termios.IGNBRK
        | termios.BRKINT
        | termios.PARMRK
        | termios.ISTRIP
        | termios.INLCR
        | termios.IGNCR
        | termios.ICRNL
        | termios.IXON
        | termios.IXANY
        | termios.IXOFF
    )
    attrs[1] &= ~termios.OPOST
    attrs[2] &= ~(termios.CSIZE | termios.PARENB)
    attrs[2] |= termios.CS8
    attrs[3] &= ~(termios.ECHO | termios.ECHONL | termios.ICANON | termios.ISIG | termios.IEXTEN)
    attrs[6][termios.VMIN] = 1
    attrs[6][termios.VTIME] = 0
    termios.tcsetattr(fd, termios.TCSANOW, attrs)
