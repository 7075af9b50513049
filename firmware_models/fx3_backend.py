"""The simulated EZ-USB FX3's host half: the pyusb backend the daemon loads.

The camera's frames reach the host over USB bulk IN from an FX3-class bridge (Cypress
04B4:00F1, the FX3 streamer example's ids; USB 3.0, one vendor-class interface, bulk IN
endpoint 0x81 with 1024-byte packets). The host (``camd.link.frame_stream.FrameStream``)
finds and reads it through ``usb.core.find(..., backend=...)`` and ``dev.read`` exactly as it
reads the hardware:

- ``Fx3Backend`` / ``get_backend(path)``: the device as a ``usb.backend.IBackend`` in the host
  process (the daemon, benchmarks, tests), its bulk endpoint fed from the simulator's stream
  socket.

The device half, the simulator's end of that socket and the stream engine, is
``firmware_models.fx3``; the two share only the socket's framing (``firmware_models.fx3_wire``).
This module imports neither the device half nor numpy, so the daemon stays light.

Transfers (docs/stream.md): the device ends every frame's transfer with a short packet, so a
bulk read of L bytes returns min(L, bytes left in the current transfer) and a read that asks
for less gets the rest on the next read; a timed-out read loses what it had received (pyusb
discards it), as on the hardware.
"""

from __future__ import annotations

import array
import contextlib
import socket
import struct
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from firmware_models.fx3_wire import (
    MAX_TRANSFER_BYTES,
    MSG,
    MSG_CLEAR_HALT,
    MSG_READY,
    MSG_SET_PACKING,
    MSG_STALL,
    MSG_TRANSFER,
    PACK_REQUEST,
    SOCKET_BUFFER_BYTES,
)
from firmware_models.usb_device import (
    SPEED_SUPER,
    ConfigurationDescriptor,
    DeviceDescriptor,
    EndpointDescriptor,
    Handle,
    InterfaceDescriptor,
    SimulatedUsbDevice,
    UsbDescriptors,
    usb_error,
)

# -- the device -------------------------------------------------------------------------------

VENDOR_ID = 0x04B4  # Cypress (Infineon)
PRODUCT_ID = 0x00F1  # the FX3 SDK's streamer example
EP_IN = 0x81
INTERFACE = 0
CONFIGURATION = 1
MAX_PACKET_BYTES = 1024  # USB 3.0 SuperSpeed bulk
MAX_BURST = 15  # packets per burst - 1 (the companion descriptor's bMaxBurst)
MANUFACTURER = "Cypress"
PRODUCT = "FX3 frame streamer (simulated)"
DEFAULT_SERIAL = "0000000001"


class StreamLinkError(ConnectionError):
    """The stream socket to the simulated camera is unreachable; the message says what to do."""


def _descriptors(
    serial: str,
) -> UsbDescriptors:
    device = DeviceDescriptor(
        VENDOR_ID,
        PRODUCT_ID,
        bus=2,  # a SuperSpeed root hub
        address=4,
        port_number=1,
        bcdUSB=0x0300,
        bMaxPacketSize0=9,  # USB 3: 2**9 = 512 bytes
        bcdDevice=0x0100,
        speed=SPEED_SUPER,
    )
    configuration = ConfigurationDescriptor(
        bConfigurationValue=CONFIGURATION,
        bmAttributes=0x80,  # bus powered
        bMaxPower=25,  # 200 mA in the 8 mA units of SuperSpeed
    )
    interface = InterfaceDescriptor(bInterfaceNumber=INTERFACE, bInterfaceClass=0xFF)
    # SuperSpeed endpoint companion: bursts of 16 packets, no streams.
    companion = struct.pack("<BBBBH", 6, 0x30, MAX_BURST, 0, 0)
    endpoint = EndpointDescriptor(
        EP_IN,
        bmAttributes=0x02,  # bulk
        wMaxPacketSize=MAX_PACKET_BYTES,
        bInterval=0,
        extra_descriptors=list(companion),
    )
    return UsbDescriptors(device, configuration, interface, [endpoint])


class _Gone(Exception):
    """The simulator's end of the stream socket went away (or broke the protocol)."""


class Fx3Backend(SimulatedUsbDevice):
    """A pyusb backend with one simulated FX3 streamer, fed from the stream socket at ``path``.

    The device is plugged while the socket is connected: construction connects (or raises
    StreamLinkError), a lost connection unplugs it (every call then fails with ENODEV), and
    enumeration connects again if a simulator listens once more. Only ``bulk_read`` on 0x81
    moves data; it receives straight into the caller's buffer. No kernel driver binds to the
    vendor-class interface unless ``kernel_driver`` names one (tests of the detach path).
    """

    def __init__(
        self,
        path: str | Path,
        *,
        serial: str = DEFAULT_SERIAL,
        kernel_driver: str | None = None,
        connect_timeout_s: float = 2.0,
    ) -> None:
        super().__init__(
            name="FX3",
            descriptors=_descriptors(serial),
            strings={1: MANUFACTURER, 2: PRODUCT, 3: serial},
            kernel_driver=kernel_driver,
        )
        self.path = Path(path)
        self.serial = serial
        self.connect_timeout_s = connect_timeout_s
        self._sock: socket.socket | None = None
        self._io_lock = threading.Lock()  # one bulk read at a time; not held for control calls
        self._send_lock = threading.Lock()
        self._msg = bytearray(MSG.size)
        self._msg_view = memoryview(self._msg)
        self._msg_got = 0  # bytes of the next message header received so far
        self._remaining = 0  # bytes left in the current transfer
        self._receive_timeout: tuple[socket.socket, int] | None = None  # SO_RCVTIMEO's (sock, ms)
        self._halted = False
        self._closed = False
        self.plugged = False
        self._connect()

    # -- connection (the cable) -----------------------------------------------------------------

    def _connect(self) -> None:
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        with contextlib.suppress(OSError):
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, SOCKET_BUFFER_BYTES)
        sock.settimeout(self.connect_timeout_s)
        try:
            sock.connect(str(self.path))
        except OSError as exc:
            sock.close()
            raise StreamLinkError(
                f"no simulated camera streams frames on {self.path} ({exc.strerror or exc}); "
                "start it with `python -m firmware_models --usb-socket PATH` (or "
                "`python -m firmware_models.fx3 --socket PATH`) or check the path"
            ) from exc
        # Plugged in once the device says it serves this host (before that, frames it makes
        # would be counted undelivered, and the host could not know).
        try:
            ready = b""
            while len(ready) < MSG.size:
                chunk = sock.recv(MSG.size - len(ready))
                if not chunk:
                    raise OSError("the simulator closed the connection")
                ready += chunk
        except OSError as exc:
            sock.close()
            raise StreamLinkError(
                f"the simulated camera on {self.path} did not accept the connection within "
                f"{self.connect_timeout_s:g} s ({exc}); is another host attached, or is it hung?"
            ) from exc
        kind, _ = MSG.unpack(ready)
        if kind != MSG_READY:
            sock.close()
            raise StreamLinkError(f"stream socket protocol error: first message kind {kind}")
        sock.settimeout(None)  # blocking: bulk reads time out by SO_RCVTIMEO
        with self._lock:
            self._sock = sock
            self._msg_got = 0
            self._remaining = 0
            self._halted = False
            self.plug()

    def close(self) -> None:
        """Disconnect for good (the device is unplugged and enumeration no longer reconnects)."""
        with self._lock:
            self._closed = True
            self.unplug()

    def _on_unplug(self) -> None:
        sock, self._sock = self._sock, None
        if sock is not None:
            # shutdown wakes a read blocked on the socket; the socket is closed when the last
            # reference (the reader's) goes away.
            with contextlib.suppress(OSError):
                sock.shutdown(socket.SHUT_RDWR)

    def _on_reset(self) -> None:
        self._halted = False

    def enumerate_devices(self) -> Iterator[Any]:
        if not self.plugged and not self._closed:
            with contextlib.suppress(StreamLinkError):
                self._connect()  # the simulator is back: the device enumerates again
        yield from super().enumerate_devices()

    def _lost(self, sock: socket.socket, why: str) -> Exception:
        with self._lock:
            if self._sock is sock:
                self.unplug()
        sock.close()
        return usb_error("no_device", f"simulated FX3: {why}")

    # -- transfers ------------------------------------------------------------------------------

    def _set_receive_timeout(self, sock: socket.socket, timeout_ms: int) -> None:
        """Reads block in the kernel for at most ``timeout_ms`` (0: no limit), then fail with
        EAGAIN: a timeout. One setsockopt when the read's timeout changes, instead of
        Python's socket timeout, which costs an ioctl and a poll on every call."""
        seconds, ms = divmod(max(0, timeout_ms), 1000)
        try:
            sock.setsockopt(
                socket.SOL_SOCKET, socket.SO_RCVTIMEO, struct.pack("@ll", seconds, ms * 1000)
            )
        except OSError as exc:
            raise self._lost(sock, f"cannot set the read timeout ({exc})") from None
        self._receive_timeout = (sock, timeout_ms)

    def bulk_read(
        self, dev_handle: Handle, ep: int, intf: int, buff: array.array[int], timeout: int
    ) -> int:
        with self._lock:
            self._check_claimed(dev_handle, intf)
            if ep != EP_IN:
                raise usb_error("pipe", f"endpoint 0x{ep:02X} is not the bulk IN endpoint")
            if self._halted:
                raise usb_error("pipe", f"endpoint 0x{EP_IN:02X} is halted; clear_halt it")
            sock = self._sock
        assert sock is not None  # plugged
        deadline = None if timeout <= 0 else time.monotonic() + timeout / 1000.0
        view = memoryview(buff)
        if view.format != "B":
            view = view.cast("B")
        with self._io_lock:
            if self._receive_timeout != (sock, timeout):
                self._set_receive_timeout(sock, timeout)
            try:
                return self._read(sock, view, deadline)
            except _Gone as exc:
                raise self._lost(sock, str(exc)) from None

    def _read(self, sock: socket.socket, view: memoryview, deadline: float | None) -> int:
        if self._remaining == 0:
            while self._msg_got < MSG.size:
                self._msg_got += self._recv(sock, [self._msg_view[self._msg_got :]], deadline)
            self._msg_got = 0
            kind, length = MSG.unpack(self._msg)
            if kind == MSG_STALL:
                with self._lock:
                    self._halted = True
                raise usb_error("pipe", f"endpoint 0x{EP_IN:02X} stalled")
            if kind != MSG_TRANSFER or length > MAX_TRANSFER_BYTES:
                raise _Gone(f"stream socket protocol error: message kind {kind}, length {length}")
            if length == 0:
                return 0  # a zero-length packet: an empty transfer
            self._remaining = length
        want = min(len(view), self._remaining)
        # A read that takes the rest of the transfer also takes whatever of the next message's
        # header has arrived, in the same system call: one recvmsg per frame when the device
        # is ahead of the host (it never waits for that header: it returns what is there).
        takes_rest = want == self._remaining
        got = 0
        try:
            while got < want:
                buffers = [view[got:want]]
                if takes_rest:
                    buffers.append(self._msg_view)
                n = self._recv(sock, buffers, deadline)
                if n > want - got:
                    self._msg_got = n - (want - got)
                    n = want - got
                got += n
        finally:
            # Bytes received by a read that then times out are gone, as on the hardware.
            self._remaining -= got
        return got

    def _recv(self, sock: socket.socket, buffers: list[memoryview], deadline: float | None) -> int:
        """One ``recvmsg_into`` on the blocking socket; the read's timeout is the socket's
        receive timeout (SO_RCVTIMEO, set only when it changes: no system call per read), and
        the deadline is checked between the calls of one read."""
        if deadline is not None and time.monotonic() >= deadline:
            raise usb_error("timeout", "no data from the FX3 within the read's timeout")
        try:
            n = sock.recvmsg_into(buffers)[0]
        except (TimeoutError, BlockingIOError):
            raise usb_error("timeout", "no data from the FX3 within the read's timeout") from None
        except OSError as exc:
            raise _Gone(f"stream socket {self.path}: {exc}") from exc
        if n == 0:
            raise _Gone(f"the simulator closed the stream socket {self.path}")
        return n

    def ctrl_transfer(
        self,
        dev_handle: Handle,
        bmRequestType: int,
        bRequest: int,
        wValue: int,
        wIndex: int,
        data: array.array[int],
        timeout: int,
    ) -> int:
        if bmRequestType != 0x40 or bRequest != PACK_REQUEST:
            return int(
                super().ctrl_transfer(
                    dev_handle, bmRequestType, bRequest, wValue, wIndex, data, timeout
                )
            )
        # The streamer's vendor request: frames packed into transfers of up to wValue KiB.
        with self._lock:
            self._check_handle(dev_handle)
            sock = self._sock
        assert sock is not None
        try:
            with self._send_lock:
                sock.sendall(MSG.pack(MSG_SET_PACKING, wValue << 10))
        except OSError as exc:
            raise self._lost(sock, f"cannot send the packing request ({exc})") from None
        return 0

    def clear_halt(self, dev_handle: Handle, ep: int) -> None:
        with self._lock:
            self._check_handle(dev_handle)
            if ep != EP_IN:
                raise usb_error("not_found", f"no endpoint 0x{ep:02X}")
            self._halted = False
            sock = self._sock
        assert sock is not None
        try:
            with self._send_lock:
                sock.sendall(MSG.pack(MSG_CLEAR_HALT, 0))
        except OSError as exc:
            raise self._lost(sock, f"cannot send CLEAR_HALT ({exc})") from None

    def bulk_write(
        self, dev_handle: Handle, ep: int, intf: int, data: array.array[int], timeout: int
    ) -> int:
        raise usb_error("pipe", f"the FX3 streamer has no OUT endpoint 0x{ep:02X}")

    def intr_read(
        self, dev_handle: Handle, ep: int, intf: int, buff: array.array[int], timeout: int
    ) -> int:
        raise usb_error("pipe", "the FX3 streamer has no interrupt endpoint")

    def intr_write(
        self, dev_handle: Handle, ep: int, intf: int, data: array.array[int], timeout: int
    ) -> int:
        raise usb_error("pipe", "the FX3 streamer has no interrupt endpoint")


def get_backend(path: str | Path, **kwargs: Any) -> Fx3Backend:
    """A backend with one simulated FX3 fed from the simulator's stream socket at ``path``.

    The pyusb convention for backend modules; keyword arguments go to ``Fx3Backend``. Raises
    StreamLinkError if no simulator listens there."""
    return Fx3Backend(path, **kwargs)
