"""The simulated EZ-USB FX3's device half: its socket server and the stream engine.

Runs in the simulator's process (``python -m firmware_models``, whose FPGA model and imaging
pipeline feed the engine, or ``python -m firmware_models.fx3`` alone):

- ``StreamSocketServer``: the simulator's end of the stream socket (one host at a time);
- ``StreamEngine``: the FX3 firmware's job: takes frames from a source (the camera model, or a
  ``BankSource`` of ready-made frames), paces them, injects faults (``InjectSpec.frame_*``)
  and sends each frame as one USB transfer;
- ``python -m firmware_models.fx3 --socket PATH``: a streamer alone, for benchmarks.

The host half, the pyusb backend the daemon loads (``Fx3Backend`` / ``get_backend``), is
``firmware_models.fx3_backend``; the socket's message framing, which both halves speak, is
``firmware_models.fx3_wire``. Each frame's transfer ends with a short packet (docs/stream.md).
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import logging
import os
import selectors
import signal
import socket
import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import FrameType

import numpy as np

from camd.protocol.stream import (
    HEADER_BYTES,
    U32_WRAP,
    FrameFlags,
    FrameHeader,
    StreamMode,
    crc32,
    pack_header,
)
from firmware_models.defects import COUNTER_SKIP_EVERY, NONE, crc32c
from firmware_models.fx3_wire import (
    MSG,
    MSG_CLEAR_HALT,
    MSG_READY,
    MSG_SET_PACKING,
    MSG_STALL,
    MSG_TRANSFER,
    SOCKET_BUFFER_BYTES,
)
from firmware_models.inject import InjectSpec
from firmware_models.pacing import Pacer
from firmware_models.usb_device import UnixSocketServer

log = logging.getLogger(__name__)

_SEND_TICK_S = 0.25  # how often a blocked send looks whether it should give up
# A paced stream makes and sends the frames due within BLOCK_S together, in one system call
# (at the hr400's fastest line rate, 41 us per frame, one call per frame would be the limit;
# the imaging pipeline renders such a block in one pass, and 2 ms rather than 1 ms took a
# quarter off a rendered frame's CPU at 164 us frames); a block goes out when its last frame
# is due, so no frame leaves early and, on schedule, none more than BLOCK_S late. An unpaced
# stream, or one catching up, sends up to MAX_BLOCK_FRAMES at a time (3 buffers each: well
# under the kernel's 1024 per sendmsg).
BLOCK_S = 2e-3
MAX_BLOCK_FRAMES = 64


# -- the simulator's end of the socket ------------------------------------------------------


class _Connection:
    """The host's connection: sent on by the engine, read (CLEAR_HALT) by the accept thread."""

    def __init__(self, sock: socket.socket) -> None:
        self.sock = sock
        self.send_lock = threading.RLock()
        self.dead = False
        self.rx = bytearray()


class _Aborted(Exception):
    """A send was given up (the engine is shutting down)."""


class StreamSocketServer(UnixSocketServer):
    """The simulator's end of the stream socket at ``path``: one host (backend) at a time.

    A new connection replaces the previous one (a host that went away without closing must
    not keep the device), which then reads ENODEV. The server holds the endpoint's halt
    state: ``stall()`` halts it (STALL message) and the host's CLEAR_HALT clears it; a new
    host finds it clear. A stale socket file (from a simulator that died) is replaced; a live
    one is an error. ``stop()`` closes the connection and removes the socket file if it is
    still this server's.
    """

    what = "the frame stream"
    backlog = 4

    def __init__(self, path: str | Path, *, send_buffer_bytes: int = SOCKET_BUFFER_BYTES) -> None:
        super().__init__(path)
        self.send_buffer_bytes = send_buffer_bytes
        self.connections_accepted = 0
        self._cond = threading.Condition()
        self._conn: _Connection | None = None
        self._halted = False
        # Bytes of whole frames one transfer may hold, as the host asked (PACK_REQUEST); 0:
        # one frame per transfer, which every new host finds.
        self.pack_bytes = 0

    # -- lifecycle --------------------------------------------------------------------------------

    def stop(self) -> None:
        """Close the listener and the connection, join the thread, remove the socket file."""
        if self._thread is None:
            return
        self._stopping.set()
        self._wake()
        self._thread.join()
        self._thread = None
        with self._cond:
            conn, self._conn = self._conn, None
            self._cond.notify_all()
        if conn is not None:
            self._close(conn)
        self._release()

    # -- state ------------------------------------------------------------------------------------

    @property
    def connected(self) -> bool:
        """A host is connected."""
        with self._cond:
            return self._conn is not None

    @property
    def halted(self) -> bool:
        """The bulk endpoint is halted (a STALL the host has not cleared)."""
        with self._cond:
            return self._halted

    @property
    def ready(self) -> bool:
        """A transfer can be sent now: a host is connected and the endpoint is not halted."""
        with self._cond:
            return self._conn is not None and not self._halted

    def wait_connected(self, timeout_s: float) -> bool:
        """Wait until a host is connected; False on timeout."""
        with self._cond:
            return self._cond.wait_for(lambda: self._conn is not None, timeout_s)

    def wait_ready(self, timeout_s: float) -> bool:
        """Wait until a transfer can be sent; False on timeout."""
        with self._cond:
            return self._cond.wait_for(
                lambda: self._conn is not None and not self._halted, timeout_s
            )

    # -- sending (the engine's thread) ------------------------------------------------------------

    def send_transfer(
        self, parts: Sequence[bytes | memoryview], *, abort: Callable[[], bool] | None = None
    ) -> bool:
        """Send ``parts`` (concatenated) as one USB transfer; False if no host took it.

        The parts go out with ``sendmsg`` (scatter-gather), so header and pixels are never
        joined into a new buffer. ``abort()`` is asked while the host does not read; True
        gives up the transfer (the connection is closed: it cannot be resynchronised)."""
        return self.send_transfers([parts], abort=abort)

    def send_transfers(
        self,
        transfers: Sequence[Sequence[bytes | memoryview]],
        *,
        abort: Callable[[], bool] | None = None,
    ) -> bool:
        """Send several transfers, in order, in as few ``sendmsg`` calls as the socket takes
        (one system call for a block of frames instead of one per frame); False if no host
        took them (then none of them counts as delivered: the connection is gone)."""
        message: list[bytes | memoryview] = []
        for parts in transfers:
            message.append(MSG.pack(MSG_TRANSFER, sum(len(p) for p in parts)))
            message.extend(parts)
        return self._send(message, abort=abort, halt=False)

    def stall(self) -> bool:
        """Halt the bulk endpoint (a STALL message); False if no host is connected."""
        return self._send([MSG.pack(MSG_STALL, 0)], abort=None, halt=True)

    def _send(
        self,
        parts: list[bytes | memoryview],
        *,
        abort: Callable[[], bool] | None,
        halt: bool,
    ) -> bool:
        with self._cond:
            conn = self._conn
            if conn is None or self._halted:
                return False
            if halt:
                self._halted = True
        with conn.send_lock:
            if conn.dead:
                return False
            try:
                _send_all(conn, parts, abort)
            except (OSError, _Aborted):
                self._kill(conn)
                return False
        return True

    # -- the accept thread --------------------------------------------------------------------

    def _wake(self) -> None:
        if self._wake_w is not None:
            with contextlib.suppress(OSError):
                self._wake_w.send(b"x")

    def _kill(self, conn: _Connection) -> None:
        """Take ``conn`` out of service (any thread); the accept thread closes it."""
        conn.dead = True
        with contextlib.suppress(OSError):
            conn.sock.shutdown(socket.SHUT_RDWR)
        with self._cond:
            if self._conn is conn:
                self._conn = None
                self._halted = False
            self._cond.notify_all()
        self._wake()

    @staticmethod
    def _close(conn: _Connection) -> None:
        conn.dead = True
        with contextlib.suppress(OSError):
            conn.sock.shutdown(socket.SHUT_RDWR)
        with conn.send_lock:  # a send in progress fails at once after the shutdown
            conn.sock.close()

    def _accept_loop(self) -> None:
        assert self._listener is not None and self._wake_r is not None
        registered: _Connection | None = None
        with selectors.DefaultSelector() as sel:
            sel.register(self._listener, selectors.EVENT_READ)
            sel.register(self._wake_r, selectors.EVENT_READ)
            while not self._stopping.is_set():
                with self._cond:
                    current = self._conn
                if registered is not current:
                    if registered is not None:
                        sel.unregister(registered.sock)
                        self._close(registered)
                    if current is not None:
                        sel.register(current.sock, selectors.EVENT_READ, current)
                    registered = current
                for key, _ in sel.select():
                    if key.fileobj is self._wake_r:
                        with contextlib.suppress(OSError):
                            self._wake_r.recv(64)
                    elif key.fileobj is self._listener:
                        if not self._stopping.is_set():
                            self._accept()
                    elif isinstance(key.data, _Connection):
                        self._control(key.data)
            if registered is not None:
                sel.unregister(registered.sock)
                with self._cond:
                    current = self._conn
                if registered is not current:
                    self._close(registered)  # stop() closes the current one

    def _accept(self) -> None:
        assert self._listener is not None
        try:
            sock, _ = self._listener.accept()
        except OSError:
            return
        with contextlib.suppress(OSError):
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, self.send_buffer_bytes)
        sock.settimeout(_SEND_TICK_S)
        conn = _Connection(sock)
        # READY goes out before any transfer can (the send lock is held from before the
        # connection is served): a host that has it knows no frame went elsewhere since.
        with conn.send_lock:
            with self._cond:
                old, self._conn = self._conn, conn
                self._halted = False  # a new host: the endpoint starts clear
                self.pack_bytes = 0
                self.connections_accepted += 1
                self._cond.notify_all()
            try:
                sock.sendall(MSG.pack(MSG_READY, 0))
            except OSError:
                self._kill(conn)
        if old is not None:
            self._kill(old)  # the accept loop closes it on its next pass

    def _control(self, conn: _Connection) -> None:
        try:
            data = conn.sock.recv(256)
        except (TimeoutError, BlockingIOError):
            return
        except OSError:
            data = b""
        if not data:
            self._kill(conn)  # the host closed the connection (unplugged)
            return
        conn.rx += data
        while len(conn.rx) >= MSG.size:
            kind, length = MSG.unpack_from(conn.rx)
            del conn.rx[: MSG.size]
            if kind == MSG_SET_PACKING:
                with self._cond:
                    if self._conn is conn:
                        self.pack_bytes = length
                continue
            if kind != MSG_CLEAR_HALT or length != 0:
                log.warning("stream socket: unknown host message %d/%d; hanging up", kind, length)
                self._kill(conn)
                return
            with self._cond:
                if self._conn is conn:
                    self._halted = False
                    self._cond.notify_all()


def _send_all(
    conn: _Connection, parts: list[bytes | memoryview], abort: Callable[[], bool] | None
) -> None:
    """sendmsg until every byte of ``parts`` is out; only memoryview slices, never joins."""
    views = [memoryview(p) for p in parts if len(p)]
    while views:
        if conn.dead:
            raise _Aborted
        try:
            n = conn.sock.sendmsg(views)
        except (TimeoutError, BlockingIOError):
            if abort is not None and abort():
                raise _Aborted from None
            continue
        while n:
            if n >= len(views[0]):
                n -= len(views[0])
                views.pop(0)
            else:
                views[0] = views[0][n:]
                n = 0


# -- the stream engine ----------------------------------------------------------------------

FrameSource = Callable[[int], tuple[FrameHeader, np.ndarray]]
DoneCallback = Callable[[int, int], None]


@dataclass(slots=True)
class StreamCounters:
    """What the engine did since it was made (SIM_GET_STREAM_STATS)."""

    produced: int = 0  # frames taken from the source (counters used)
    sent: int = 0  # frames sent whole (including corrupted ones)
    bytes_sent: int = 0  # bytes of every transfer, whole or short
    dropped: int = 0  # injected: not sent
    corrupted: int = 0  # injected: sent whole with one payload bit flipped
    shortened: int = 0  # injected: the transfer ended early
    stalls: int = 0  # injected: the endpoint halted; the frame in flight was lost
    undelivered: int = 0  # made while no host could take them (none connected, or halted)

    def as_dict(self) -> dict[str, int]:
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}


@dataclass(slots=True)
class _Stream:
    frames: int
    period_s: float
    pace: bool
    next_counter: int  # after the stream's last frame so far
    end_after: int | None = None  # the camera ends the stream early, after this many frames
    produced: int = 0
    stop: bool = False
    done: bool = False
    notify: bool = True  # call on_done when it ends


class StreamEngine:
    """The FX3 firmware's streaming job: frames from ``source`` to the host over ``server``.

    ``start(frames, period_s, pace)`` begins a stream: the engine's thread calls
    ``source(counter)`` for counter = ``first_counter``, +1, ... (mod 2**32); the source
    returns the frame's complete header (payload CRC included) and its (rows, cols) uint16
    pixels. Each frame goes out as one transfer (header + pixels by scatter-gather, no copy).
    ``pace=True`` sends frames on a clock of ``period_s`` in wall time, by deadlines
    (``firmware_models.pacing``: frames made late are followed by the next at once until the
    stream is back on schedule, within a bound; a source slower than the clock for good just
    makes the stream slower; nothing is dropped for that). Frames due within ``BLOCK_S`` of
    each other are made and sent together when the last of them is due, in one system call
    (``MAX_BLOCK_FRAMES`` at a time unpaced, or behind the schedule): a line rate of tens of
    kHz is not a system call per frame. Frames made while no host can take them (none
    connected, or the endpoint halted) are discarded and counted ``undelivered``, and the
    next frame sent carries DEVICE_OVERFLOW. ``pace=False`` sends as
    fast as the host reads, and waits (making nothing) while no host can take frames.

    A counted stream (``frames > 0``) ends by itself after that many frames, the last one
    flagged LAST (its header CRC recomputed). ``stop()`` ends a stream after the frames in
    progress (a block: the frames already made go out). Either way ``on_done(frames_produced, next_counter)`` is called once, from the
    engine's thread, after the stream's last frame went out (unless ``stop(notify=False)``).

    Faults (``inject``, read per frame so it may be replaced at any time; rates per frame,
    drawn from a numpy Generator seeded with ``seed``): frame_drop (not sent, counter used),
    frame_corrupt (one payload bit flipped after the CRC, in a copy: the source's array is
    never written), frame_short (a random prefix of 1 .. size-1 bytes is the whole transfer),
    frame_stall (the endpoint halts: the frame is lost, nothing is sent until the host clears
    the halt).

    ``start`` and ``stop`` never wait for the engine's thread, so they may be called while
    holding a lock the source takes. One thread serves all streams of the engine's life;
    ``close()`` ends it.
    """

    def __init__(
        self,
        source: FrameSource | None = None,
        *,
        server: StreamSocketServer | None = None,
        inject: InjectSpec | None = None,
        seed: int | None = 0,
        on_done: DoneCallback | None = None,
    ) -> None:
        self.source = source
        # Told before each block which frames the source will be asked for (first counter,
        # count), so that it can make them together (the imaging pipeline renders them in
        # one go); None: the source makes each frame when asked.
        self.prepare: Callable[[int, int], None] | None = None
        self.server = server
        self.inject = inject if inject is not None else InjectSpec()
        self.on_done = on_done
        self.counters = StreamCounters()
        self.next_counter = 0
        self.defects = NONE  # deliberate defects (firmware_models.defects), off
        self._counter_skew = 0  # stream_counter_skip: counter values skipped so far
        self._rng = np.random.default_rng(seed)
        self._cond = threading.Condition()
        self._pending: _Stream | None = None
        self._current: _Stream | None = None
        self._last: _Stream | None = None
        self._closing = False
        self._thread: threading.Thread | None = None

    # -- control ----------------------------------------------------------------------------------

    @property
    def running(self) -> bool:
        """A stream is on: started, not stopped, not finished."""
        with self._cond:
            s = self._pending or self._current
            return s is not None and not s.stop and not s.done

    @property
    def frames_produced(self) -> int:
        """Frames produced by the current (or last) stream, the one in progress included."""
        with self._cond:
            s = self._pending or self._current or self._last
            return s.produced if s is not None else 0

    def start(
        self,
        frames: int = 0,
        period_s: float = 0.0,
        pace: bool = True,
        *,
        first_counter: int | None = None,
        end_after: int | None = None,
    ) -> None:
        """Begin a stream of ``frames`` frames (0: until ``stop``), one per ``period_s``.

        ``first_counter`` defaults to where the previous stream ended (``next_counter``).
        ``end_after``: end the stream by itself after that many frames if it has not ended
        before, like a camera that ends a stream early (the last frame is not flagged LAST;
        ``on_done`` says how many it sent)."""
        if frames < 0:
            raise ValueError(f"frames = {frames}: give a count >= 1, or 0 to stream until stop")
        if not period_s >= 0.0:
            raise ValueError(f"period_s = {period_s} must be >= 0")
        if self.source is None:
            raise RuntimeError("the stream engine has no frame source; set engine.source")
        with self._cond:
            if self._closing:
                raise RuntimeError("the stream engine is closed")
            if self.running:
                raise RuntimeError("a stream is already running; stop() it first")
            if first_counter is not None:
                # A stopped stream finishing its frame in progress has used its last counter.
                self.next_counter = first_counter % U32_WRAP
            self._pending = _Stream(
                frames=frames,
                period_s=period_s,
                pace=pace,
                next_counter=self.next_counter,
                end_after=end_after,
            )
            if self._thread is None:
                self._thread = threading.Thread(
                    target=self._run, name="fx3-stream-engine", daemon=True
                )
                self._thread.start()
            self._cond.notify_all()

    def reseed(self, seed: int) -> None:
        """Restart the injected-fault random stream from ``seed`` (in place: a stream in
        progress draws from the restarted sequence from its next frame)."""
        with self._cond:
            self._rng.bit_generator.state = np.random.default_rng(seed).bit_generator.state

    def set_period(self, period_s: float) -> None:
        """Change the running stream's frame period from the next frame on (the sensor's line
        period was re-programmed while streaming). Harmless when not streaming or unpaced."""
        if not period_s > 0.0:
            raise ValueError(f"period_s = {period_s} must be > 0")
        with self._cond:
            s = self._pending or self._current
            if s is not None and s.period_s > 0:
                s.period_s = period_s

    def stop(self, *, notify: bool = True) -> int:
        """End the stream after the frame in progress; frames it produced (that one included).

        Does not wait for that frame to go out (see ``wait_idle``). ``notify=False``: do not
        call ``on_done`` for this stream (the caller reports the end itself)."""
        never_began = False
        with self._cond:
            s = self._pending or self._current
            if s is None:
                return self._last.produced if self._last is not None else 0
            s.stop = True
            s.notify = s.notify and notify
            if s is self._pending:
                self._pending = None
                self._last = s
                s.done = True
                never_began = True
            self._cond.notify_all()
            produced, next_counter = s.produced, s.next_counter
        if never_began and s.notify and self.on_done is not None:
            self.on_done(produced, next_counter)  # it made no frame; still, it ended
        return produced

    def wait_idle(self, timeout_s: float | None = None) -> bool:
        """Wait until no stream is in progress (the last frame is out); False on timeout."""
        with self._cond:
            return self._cond.wait_for(
                lambda: self._pending is None and self._current is None, timeout_s
            )

    def close(self, timeout_s: float = 5.0) -> None:
        """Stop any stream and end the engine's thread (an unread transfer is abandoned)."""
        with self._cond:
            self._closing = True
            for s in (self._pending, self._current):
                if s is not None:
                    s.stop = True
            self._cond.notify_all()
        if self._thread is not None:
            self._thread.join(timeout_s)

    # -- the thread -------------------------------------------------------------------------------

    def _run(self) -> None:
        while True:
            with self._cond:
                self._cond.wait_for(lambda: self._pending is not None or self._closing)
                if self._pending is None:
                    return
                stream, self._pending = self._pending, None
                self._current = stream
            try:
                self._stream(stream)
            except Exception:
                log.exception("stream engine: the stream failed")
            with self._cond:
                stream.done = True
                self._current = None
                self._last = stream
                produced, next_counter = stream.produced, stream.next_counter
                self._cond.notify_all()
            if stream.notify and self.on_done is not None:
                try:
                    self.on_done(produced, next_counter)
                except Exception:
                    log.exception("stream engine: on_done failed")

    def _abort_send(self) -> bool:
        return self._closing

    def _wait(self, stream: _Stream, timeout_s: float) -> None:
        """Sleep up to ``timeout_s``, waking early for stop/close."""
        with self._cond:
            self._cond.wait_for(lambda: stream.stop or self._closing, timeout_s)

    def _block_frames(self, stream: _Stream) -> int:
        """How many frames to make and send together: those due within BLOCK_S (at least
        one), or MAX_BLOCK_FRAMES when the host sets the pace."""
        if not stream.pace or stream.period_s <= 0:
            return MAX_BLOCK_FRAMES
        return max(1, min(MAX_BLOCK_FRAMES, int(BLOCK_S / stream.period_s)))

    def _stream(self, stream: _Stream) -> None:
        pacer = Pacer(time.monotonic())  # deadlines of a paced stream (firmware_models.pacing)
        overflow = False  # frames were undelivered since the last one sent
        while True:
            if not stream.pace:
                # As fast as the host reads: with nobody to take frames, make none.
                while not stream.stop and not self._closing:
                    server = self.server
                    if server is not None and server.wait_ready(0.05):
                        break
                    if server is None:
                        self._wait(stream, 0.05)
            count = self._block_frames(stream)
            if stream.pace and stream.period_s > 0:
                # A block goes out when its last frame is due: no frame leaves before its time;
                # behind the schedule, the frames already due go at once (the stream catches up).
                now = time.monotonic()
                count = pacer.block_frames(count, stream.period_s, MAX_BLOCK_FRAMES, now_s=now)
                wait_s = pacer.wait_s(count, stream.period_s, now_s=now)
                if wait_s > 0:
                    self._wait(stream, wait_s)
            self._announce(stream, count)
            block: list[tuple[FrameHeader, np.ndarray, bool, InjectSpec]] = []
            ended = False
            for _ in range(count):
                with self._cond:
                    if stream.stop or self._closing:
                        ended = True
                        break
                    if stream.frames and stream.produced >= stream.frames:
                        ended = True
                        break
                    if stream.end_after is not None and stream.produced >= stream.end_after:
                        ended = True  # cut short on purpose (SIM_FAIL_NEXT end_stream)
                        break
                    counter = self.next_counter
                    self.next_counter = (counter + 1) % U32_WRAP
                    stream.next_counter = self.next_counter
                    stream.produced += 1
                    self.counters.produced += 1
                    last = stream.frames > 0 and stream.produced == stream.frames
                source = self.source
                assert source is not None
                header, pixels = source(counter)
                # On a clock, like the sensor: the sleep's wake-up latency does not accumulate.
                # Read after the source, which may have changed the period (``set_period``).
                pacer.advance(stream.period_s)
                # The faults in force when the frame was made (``inject`` may change any time).
                block.append((header, pixels, last, self.inject))
            if block:
                overflow = self._send_block(stream, block, overflow)
            if ended:
                return

    def _announce(self, stream: _Stream, count: int) -> None:
        """Tell the source (``prepare``) which frames it is about to be asked for: the next
        ``count``, or fewer where the stream ends, so it may make them together."""
        if self.prepare is None:
            return
        with self._cond:
            if stream.frames:
                count = min(count, stream.frames - stream.produced)
            if stream.end_after is not None:
                count = min(count, stream.end_after - stream.produced)
            first = self.next_counter
        if count > 0:
            self.prepare(first, count)

    def _send_block(
        self,
        stream: _Stream,
        block: list[tuple[FrameHeader, np.ndarray, bool, InjectSpec]],
        overflow: bool,
    ) -> bool:
        """Send a block of frames with the faults, in one ``sendmsg`` where nothing comes
        between them; return whether frames went undelivered since the last one sent (the
        next frame sent then carries DEVICE_OVERFLOW)."""
        server = self.server
        c = self.counters
        rng = self._rng
        transfers: list[list[bytes | memoryview]] = []
        kinds: list[tuple[bool, bool, int]] = []  # (cut short, corrupted, bytes) per frame
        packed = 0  # bytes in the last transfer, while whole frames may join it (packing)

        def flush() -> bool:
            """Send the transfers gathered so far; count them sent, or all undelivered."""
            if not transfers:
                return True
            assert server is not None
            sent = server.send_transfers(transfers, abort=self._abort_send)
            for short, corrupted, nbytes in kinds:
                if not sent:
                    c.undelivered += 1
                    continue
                c.bytes_sent += nbytes
                # Each frame counts once: one both corrupted and cut short reaches the host short.
                if short:
                    c.shortened += 1
                else:
                    c.sent += 1
                    if corrupted:
                        c.corrupted += 1
            transfers.clear()
            kinds.clear()
            return sent

        for header, pixels, last, spec in block:
            if not stream.pace and server is not None:
                # As fast as the host reads: a halt in the block (an injected stall) waits
                # for the host's clear, as it would before the next frame is made.
                while not server.wait_ready(0.05) and not (stream.stop or self._closing):
                    pass
            if server is None or not server.ready:
                c.undelivered += 1
                overflow = True
                continue
            if spec.frame_drop and rng.random() < spec.frame_drop:
                c.dropped += 1
                continue
            if spec.frame_stall and rng.random() < spec.frame_stall:
                # The frames before it go out first: the halt comes after them on the wire.
                if not flush():
                    overflow = True
                if not server.stall():
                    c.undelivered += 1
                    overflow = True
                    continue
                c.stalls += 1
                continue
            flags = header.flags
            if overflow:
                flags |= FrameFlags.DEVICE_OVERFLOW
            if last:
                flags |= FrameFlags.LAST
            if flags != header.flags:
                header = header._replace(flags=flags)
            if self.defects.stream_counter_skip or self.defects.stream_crc_polynomial:
                header = self._defective(header, pixels)
            # Checked when the source made it (frame_header); the flags added are known ones.
            head = pack_header(header)
            payload = pixels.data.cast("B")
            if len(payload) != header.payload_bytes:
                raise ValueError(
                    f"the source gave {len(payload)} payload bytes for a header saying "
                    f"{header.payload_bytes} (counter {header.counter})"
                )
            corrupted = False
            if spec.frame_corrupt and rng.random() < spec.frame_corrupt:
                damaged = np.frombuffer(payload, dtype=np.uint8).copy()
                bit = int(rng.integers(0, damaged.size * 8))
                damaged[bit >> 3] ^= np.uint8(1 << (bit & 7))
                payload = damaged.data
                corrupted = True
            parts: list[bytes | memoryview] = [head, payload]
            short = False
            if spec.frame_short and rng.random() < spec.frame_short:
                total = HEADER_BYTES + len(payload)
                keep = int(rng.integers(1, total))  # 1 .. total - 1
                parts = [head[:keep], payload[: max(0, keep - HEADER_BYTES)]]
                short = True
            nbytes = sum(len(p) for p in parts)
            pack = server.pack_bytes
            if packed and not short and transfers and packed + nbytes <= pack:
                transfers[-1].extend(parts)  # packed: whole frames back to back
                packed += nbytes
            else:
                transfers.append(parts)
                packed = 0 if short or not pack else nbytes  # a cut-short frame ends its transfer
            kinds.append((short, corrupted, nbytes))
            overflow = False
        if not flush():
            overflow = True
        return overflow

    def _defective(self, header: FrameHeader, pixels: np.ndarray) -> FrameHeader:
        """The header as a defective FX3 frames it (firmware_models.defects); the header CRC
        is computed afterwards, by ``pack_header``, and so stays right."""
        if self.defects.stream_counter_skip:
            if header.counter % COUNTER_SKIP_EVERY == COUNTER_SKIP_EVERY - 1:
                self._counter_skew += 1
            header = header._replace(counter=(header.counter + self._counter_skew) % U32_WRAP)
        if self.defects.stream_crc_polynomial:
            header = header._replace(payload_crc32=crc32c(pixels.data.cast("B")))
        return header


# -- ready-made frames ----------------------------------------------------------------------


class BankSource:
    """A frame source replaying a bank of ready-made frames (benchmarks, tests).

    Frame ``counter`` is bank frame ``counter % len(frames)`` with a fresh counter and
    timestamp (``t0_ns + counter * line_period_ns``); payload CRCs and the SATURATED flag
    (some pixel at 2**bits - 1) are computed once per bank frame, so a frame costs the source
    no pass over its pixels. ``stages`` defaults to the rows in TDI mode, 0 in area mode.
    """

    def __init__(
        self,
        frames: Sequence[np.ndarray],
        *,
        line_period_ns: int,
        bits: int,
        mode: StreamMode,
        stages: int | None = None,
        t0_ns: int = 0,
    ) -> None:
        if not frames:
            raise ValueError("a bank source needs at least one frame")
        self.line_period_ns = line_period_ns
        self.bits = bits
        self.mode = StreamMode(mode)
        self.t0_ns = t0_ns
        self.frames: list[np.ndarray] = []
        self._crc: list[int] = []
        self._flags: list[FrameFlags] = []
        adc_max = (1 << bits) - 1
        for i, frame in enumerate(frames):
            if frame.ndim != 2 or frame.dtype != np.dtype("<u2"):
                raise ValueError(f"bank frame {i} is {frame.ndim}-D {frame.dtype}, not 2-D uint16")
            frame = np.ascontiguousarray(frame)
            frame.flags.writeable = False  # shared by every replay: nobody may change it
            self.frames.append(frame)
            self._crc.append(crc32(frame.data))
            saturated = bool((frame >= adc_max).any())
            self._flags.append(FrameFlags.SATURATED if saturated else FrameFlags(0))
        rows = self.frames[0].shape[0]
        self.stages = stages if stages is not None else (rows if mode == StreamMode.TDI else 0)

    @classmethod
    def random(
        cls,
        rows: int,
        cols: int,
        *,
        count: int = 4,
        bits: int = 12,
        seed: int = 0,
        line_period_ns: int = 25_000,
        mode: StreamMode = StreamMode.TDI,
    ) -> BankSource:
        """``count`` frames of uniform random ``bits``-bit pixels."""
        rng = np.random.default_rng(seed)
        bank = [
            rng.integers(0, 1 << bits, size=(rows, cols), dtype=np.uint16) for _ in range(count)
        ]
        return cls(bank, line_period_ns=line_period_ns, bits=bits, mode=mode)

    def __call__(self, counter: int) -> tuple[FrameHeader, np.ndarray]:
        i = counter % len(self.frames)
        frame = self.frames[i]
        rows, cols = frame.shape
        header = FrameHeader(
            counter=counter,
            timestamp_ns=(self.t0_ns + counter * self.line_period_ns) % (1 << 64),
            line_period_ns=self.line_period_ns,
            rows=rows,
            cols=cols,
            bits=self.bits,
            mode=self.mode,
            stages=self.stages,
            stage_position=0,
            flags=self._flags[i],
            payload_bytes=frame.nbytes,
            payload_crc32=self._crc[i],
        )
        return header, frame


# -- python -m firmware_models.fx3 ------------------------------------------------------------


def main(argv: Sequence[str] | None = None) -> int:
    """A simulated FX3 alone, streaming a random frame bank (for benchmarks and tests).

    Prints one JSON line when it listens, and one with the engine's counters when it ends
    (SIGTERM, SIGINT or end of standard input)."""
    p = argparse.ArgumentParser(
        prog="python -m firmware_models.fx3",
        description="A simulated FX3 frame streamer on a Unix socket, replaying random frames.",
    )
    p.add_argument("--socket", required=True, type=Path, help="Unix socket path to listen on")
    p.add_argument("--rows", type=int, default=534, help="window rows (default 534)")
    p.add_argument("--cols", type=int, default=2048, help="window columns (default 2048)")
    p.add_argument("--bits", type=int, default=12, help="significant bits (default 12)")
    p.add_argument("--bank", type=int, default=4, help="distinct frames replayed (default 4)")
    p.add_argument("--frames", type=int, default=0, help="frames to send, 0 = until stopped")
    p.add_argument(
        "--period-s", type=float, default=0.0, help="frame period; 0 = unpaced (default)"
    )
    p.add_argument("--inject", default="", help="faults, e.g. 'frame_drop=0.01'")
    p.add_argument("--seed", type=int, default=0, help="seed of the frames and the faults")
    args = p.parse_args(argv)
    if args.rows < 1 or args.cols < 1 or not 1 <= args.bits <= 16 or args.bank < 1:
        p.error("--rows/--cols/--bank must be >= 1 and --bits 1..16")
    source = BankSource.random(
        args.rows,
        args.cols,
        count=args.bank,
        bits=args.bits,
        seed=args.seed,
        line_period_ns=round(args.period_s * 1e9) if args.period_s > 0 else 25_000,
    )
    stop = threading.Event()

    def on_signal(signum: int, frame: FrameType | None) -> None:
        stop.set()

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    with StreamSocketServer(args.socket) as server:
        engine = StreamEngine(source, server=server, inject=InjectSpec.parse(args.inject))
        engine.start(args.frames, args.period_s, pace=args.period_s > 0)
        frame_bytes = HEADER_BYTES + 2 * args.rows * args.cols
        ready = {"socket": str(args.socket), "frame_bytes": frame_bytes, "pid": os.getpid()}
        print(json.dumps(ready), flush=True)
        threading.Thread(target=_wait_stdin_eof, args=(stop,), daemon=True).start()
        while not stop.wait(0.5):
            pass
        engine.close()
    print(json.dumps(engine.counters.as_dict()), flush=True)
    return 0


def _wait_stdin_eof(stop: threading.Event) -> None:
    with contextlib.suppress(OSError):
        while os.read(sys.stdin.fileno(), 4096):
            pass
    stop.set()


if __name__ == "__main__":
    sys.exit(main())
