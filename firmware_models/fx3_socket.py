"""The simulated FX3's end of the stream socket (the simulator's side, one host at a time).

The host half, the pyusb backend the daemon loads, is ``firmware_models.fx3_backend``; the
socket's message framing, which both halves speak, is ``firmware_models.fx3_wire``. The stream
engine (``firmware_models.fx3``) sends the frames through ``StreamSocketServer``, each
transfer by scatter-gather (header and pixels never joined), several in one system call.
"""

from __future__ import annotations

import contextlib
import logging
import selectors
import socket
import threading
from collections.abc import Callable, Sequence
from pathlib import Path

from firmware_models.fx3_wire import (
    MSG,
    MSG_CLEAR_HALT,
    MSG_READY,
    MSG_SET_PACKING,
    MSG_STALL,
    MSG_TRANSFER,
    SOCKET_BUFFER_BYTES,
)
from firmware_models.usb_device import UnixSocketServer

log = logging.getLogger(__name__)

_SEND_TICK_S = 0.25  # how often a blocked send looks whether it should give up


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
