"""The SPI socket between processes: the message framing both ends speak.

The host half (``firmware_models.mcp2210_backend.SocketSpiTarget``, behind the simulated
MCP2210 the daemon loads) sends requests; the device half
(``firmware_models.usb_spi.SpiSocketServer``, in the simulator's process) answers them::

    request    u32 big-endian length n, then n bytes: SPI mode (0..3), MOSI bytes
    response   u32 big-endian length n, then n bytes: status (0 ok, 1 error), then the MISO
               bytes (ok) or a UTF-8 message (error)

Nothing but the standard library: both processes import it.
"""

from __future__ import annotations

import socket
import struct

HEADER = struct.Struct(">I")
MAX_SPI_MESSAGE = 1 + 0xFFFF  # mode byte + the chip's longest transaction
RESPONSE_OK = 0
RESPONSE_ERROR = 1


def recv_exact(sock: socket.socket, n: int) -> bytes | None:
    """``n`` bytes, or None if the peer closed the connection before the first byte."""
    chunks = bytearray()
    while len(chunks) < n:
        chunk = sock.recv(n - len(chunks))
        if not chunk:
            if chunks:
                raise ConnectionResetError("connection closed in the middle of a message")
            return None
        chunks += chunk
    return bytes(chunks)


def send_message(sock: socket.socket, payload: bytes) -> None:
    sock.sendall(HEADER.pack(len(payload)) + payload)
