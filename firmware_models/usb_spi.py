"""The simulated MCP2210 USB-SPI bridge's device half: the simulator's end of the SPI socket.

Runs in the simulator's process (``python -m firmware_models --spi-socket PATH``):

- ``SpiSocketServer``: serves the camera's SPI slave (the sensor's register file behind
  ``firmware_models.spi.SpiSlave``) on a Unix socket, one thread per connection.

The host half, the pyusb backend the daemon loads (``Mcp2210Chip``, ``Mcp2210Backend``,
``get_backend``) and the socket's client end (``SocketSpiTarget``), is
``firmware_models.mcp2210_backend``; the socket's message framing, which both ends speak, is
``firmware_models.spi_wire`` (docs/usb-spi.md).
"""

from __future__ import annotations

import contextlib
import selectors
import socket
import threading
from pathlib import Path
from typing import TYPE_CHECKING

from firmware_models.spi_wire import (
    HEADER,
    MAX_SPI_MESSAGE,
    RESPONSE_ERROR,
    RESPONSE_OK,
    recv_exact,
    send_message,
)
from firmware_models.usb_device import UnixSocketServer

if TYPE_CHECKING:
    from firmware_models.mcp2210_backend import SpiTarget


class SpiSocketServer(UnixSocketServer):
    """Serve ``target`` on a Unix socket at ``path``, one thread per connection.

    ``lock`` is held around every transaction, so the SPI socket and the command link never
    touch the model at the same time. A stale socket file (from a simulator that died) is
    replaced; a live one (another simulator listening) is an error. ``stop()`` closes every
    connection and removes the socket file if it is still this server's.
    """

    what = "SPI"
    backlog = 8

    def __init__(
        self,
        path: str | Path,
        target: SpiTarget,
        lock: threading.Lock | threading.RLock,
    ) -> None:
        super().__init__(path)
        self.target = target
        self.lock = lock
        self._conns: dict[socket.socket, threading.Thread] = {}
        self._conns_lock = threading.Lock()

    def stop(self) -> None:
        """Close the listener and every connection, join the threads, remove the socket file."""
        if self._thread is None:
            return
        self._stopping.set()
        assert self._wake_w is not None
        self._wake_w.send(b"x")
        self._thread.join()
        self._thread = None
        with self._conns_lock:
            conns = dict(self._conns)
        for conn in conns:
            with contextlib.suppress(OSError):
                conn.shutdown(socket.SHUT_RDWR)
        for thread in conns.values():
            thread.join(timeout=5.0)
        self._release()

    @property
    def connections(self) -> int:
        """Connections currently open."""
        with self._conns_lock:
            return len(self._conns)

    def _accept_loop(self) -> None:
        assert self._listener is not None and self._wake_r is not None
        with selectors.DefaultSelector() as sel:
            sel.register(self._listener, selectors.EVENT_READ)
            sel.register(self._wake_r, selectors.EVENT_READ)
            while not self._stopping.is_set():
                for key, _ in sel.select():
                    if key.fileobj is self._listener and not self._stopping.is_set():
                        self._accept()

    def _accept(self) -> None:
        assert self._listener is not None
        try:
            conn, _ = self._listener.accept()
        except OSError:
            return
        thread = threading.Thread(target=self._serve, args=(conn,), daemon=True)
        with self._conns_lock:
            self._conns[conn] = thread
        thread.start()

    def _serve(self, conn: socket.socket) -> None:
        try:
            while not self._stopping.is_set():
                header = recv_exact(conn, HEADER.size)
                if header is None:
                    return
                (length,) = HEADER.unpack(header)
                if not 1 <= length <= MAX_SPI_MESSAGE:
                    # The stream cannot be resynchronised: say why and hang up.
                    message = f"message length {length} outside 1 .. {MAX_SPI_MESSAGE}"
                    send_message(conn, bytes([RESPONSE_ERROR]) + message.encode())
                    return
                body = recv_exact(conn, length)
                if body is None:
                    return
                send_message(conn, self._execute(body[0], body[1:]))
        except OSError:
            return  # the client went away, or stop() shut the connection down
        finally:
            with self._conns_lock:
                self._conns.pop(conn, None)
            conn.close()

    def _execute(self, mode: int, mosi: bytes) -> bytes:
        if mode > 3:
            return bytes([RESPONSE_ERROR]) + f"SPI mode {mode} is not 0 .. 3".encode()
        try:
            with self.lock:
                miso = self.target.transfer(mosi, mode=mode)
        except Exception as exc:  # the client reports it; the server keeps serving
            return bytes([RESPONSE_ERROR]) + f"{type(exc).__name__}: {exc}".encode()
        return bytes([RESPONSE_OK]) + bytes(miso)
