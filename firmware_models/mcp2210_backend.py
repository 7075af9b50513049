"""The simulated Microchip MCP2210 USB-to-SPI bridge's host half: the pyusb backend the daemon
loads, with the chip model behind it and the client end of the simulator's SPI socket.

The host (``camd.sensor.mcp2210.Mcp2210Bridge``) finds and drives this device through
``usb.core.find(..., backend=...)`` and interrupt transfers exactly as it drives the real chip.
All of it runs in the host's process (the daemon, tests):

- ``Mcp2210Chip``: the chip's HID command processor (sans-I/O): 64-byte command report in,
  64-byte response report out, with the chip's volatile settings and its SPI transfer engine
  (report sequencing, busy while clocking, cancel), in front of an ``SpiTarget``;
- ``Mcp2210Backend`` / ``get_backend(target)``: a ``usb.backend.IBackend`` that enumerates one
  MCP2210 with its descriptors, string descriptors, an attached kernel HID driver that must be
  detached before the interface can be claimed, and the interrupt endpoints 0x01 (OUT) / 0x81
  (IN);
- ``SocketSpiTarget``: an ``SpiTarget`` in another process, the client end of the simulator's
  SPI socket. The simulated camera (``python -m firmware_models --spi-socket PATH``) serves its
  sensor's SPI slave there; the daemon's backend reaches it with
  ``get_backend(SocketSpiTarget(PATH))``.

The device half, the simulator's end of that socket (``SpiSocketServer``), is
``firmware_models.usb_spi``; the two share only the socket's framing
(``firmware_models.spi_wire``). This module imports neither the device half nor numpy.

The command set follows the MCP2210 datasheet (DS22288A, section 3); docs/usb-spi.md lists
what is modelled and where the model departs from the chip. The chip's constants are written
out here again rather than imported from camd, so that the model checks the host instead of
sharing its mistakes.
"""

from __future__ import annotations

import array
import select
import socket
import struct
import threading
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar, Protocol

from firmware_models.spi_wire import HEADER, MAX_SPI_MESSAGE, RESPONSE_OK, recv_exact
from firmware_models.usb_device import (
    SPEED_FULL,
    ConfigurationDescriptor,
    DeviceDescriptor,
    EndpointDescriptor,
    Handle,
    InterfaceDescriptor,
    SimulatedUsbDevice,
    UsbDescriptors,
    usb_error,
)

# -- the chip ---------------------------------------------------------------------------------

VENDOR_ID = 0x04D8
PRODUCT_ID = 0x00DE
REPORT_BYTES = 64
MAX_DATA_PER_REPORT = 60
EP_OUT = 0x01
EP_IN = 0x81
INTERFACE = 0
CONFIGURATION = 1
GP_PINS = 9
MIN_BIT_RATE = 1500
MAX_BIT_RATE = 12_000_000
DELAY_QUANTUM_S = 100e-6  # the chip's delays count in 100 us steps

CMD_GET_STATUS = 0x10
CMD_CANCEL_TRANSFER = 0x11
CMD_GET_CHIP_SETTINGS = 0x20
CMD_SET_CHIP_SETTINGS = 0x21
CMD_SET_SPI_SETTINGS = 0x40
CMD_GET_SPI_SETTINGS = 0x41
CMD_TRANSFER = 0x42

STATUS_OK = 0x00
STATUS_BUS_NOT_AVAILABLE = 0xF7
STATUS_BUSY = 0xF8
STATUS_UNKNOWN_COMMAND = 0xF9

ENGINE_FINISHED = 0x10
ENGINE_STARTED = 0x20
ENGINE_NOT_FINISHED = 0x30

PIN_GPIO = 0x00
PIN_CHIP_SELECT = 0x01
PIN_DEDICATED = 0x02

SPI_SETTINGS_BYTES = 17

# MISO with no slave selected: nobody drives the line, which reads 0 (pulled down, as in
# firmware_models.spi).
UNDRIVEN_MISO = 0x00


class SpiTarget(Protocol):
    """Whatever sits on the SPI bus behind the bridge's chip-select pin."""

    def transfer(self, mosi: bytes, *, mode: int) -> bytes:
        """One chip-select-low transaction: clock out ``mosi`` in SPI ``mode``, return MISO."""
        ...


@dataclass(slots=True)
class SpiTransferSettings:
    """The chip's volatile SPI transfer settings (commands 0x40 / 0x41)."""

    bit_rate: int = MAX_BIT_RATE
    idle_cs: int = 0x1FF
    active_cs: int = 0x000
    cs_to_data_delay: int = 0
    data_to_cs_delay: int = 0
    inter_byte_delay: int = 0
    bytes_per_transaction: int = 4
    mode: int = 0

    def pack(self) -> bytes:
        """The 17-byte wire layout (report bytes 4..20), little-endian."""
        return struct.pack(
            "<IHHHHHHB",
            self.bit_rate,
            self.idle_cs,
            self.active_cs,
            self.cs_to_data_delay,
            self.data_to_cs_delay,
            self.inter_byte_delay,
            self.bytes_per_transaction,
            self.mode,
        )

    @classmethod
    def unpack(cls, data: bytes) -> SpiTransferSettings:
        """Settings from report bytes 4..20."""
        fields = struct.unpack("<IHHHHHHB", data[:SPI_SETTINGS_BYTES])
        return cls(*fields)


@dataclass(slots=True)
class ChipSettings:
    """The chip's volatile chip settings (commands 0x20 / 0x21)."""

    pins: list[int] = field(default_factory=lambda: [PIN_GPIO] * GP_PINS)
    gpio_default_output: int = 0x1FF
    gpio_default_direction: int = 0x1FF  # 1 = input
    other: int = 0x00  # remote wake-up, interrupt mode, SPI bus release
    nvram_access_control: int = 0x00

    def pack(self) -> bytes:
        """Report bytes 4..18."""
        return bytes(self.pins) + struct.pack(
            "<HHBB",
            self.gpio_default_output,
            self.gpio_default_direction,
            self.other,
            self.nvram_access_control,
        )

    @classmethod
    def unpack(cls, data: bytes) -> ChipSettings:
        """Settings from report bytes 4..18."""
        output, direction, other, access = struct.unpack("<HHBB", data[GP_PINS : GP_PINS + 6])
        return cls(list(data[:GP_PINS]), output, direction, other, access)


@dataclass(slots=True)
class _Transaction:
    """One chip-select-low SPI transaction in progress in the transfer engine."""

    expected: int
    mode: int
    selected: bool
    mosi: bytearray = field(default_factory=bytearray)
    miso: bytes | None = None  # known once the whole transaction has been clocked
    delivered: int = 0

    @property
    def complete(self) -> bool:
        return len(self.mosi) == self.expected


@dataclass(slots=True)
class ChipCounters:
    """What the chip did, for tests and diagnostics."""

    commands: Counter[int] = field(default_factory=Counter)
    busy_replies: int = 0
    transactions: int = 0
    cancelled: int = 0
    ignored_bytes: int = 0  # data beyond the configured bytes per transaction


class Mcp2210Chip:
    """The MCP2210's command processor and SPI transfer engine, without USB.

    ``handle(report)`` takes one 64-byte command report and returns the 64-byte response. The
    SPI engine clocks at the configured bit rate with the configured delays, measured on
    ``clock``; while it clocks, TRANSFER SPI DATA and the setting commands answer 0xF8 (busy),
    as on the chip. The target sees a transaction once its last MOSI byte has arrived, with the
    chip select wired to GP``cs_pin``: it is selected only if that pin is designated a chip
    select and the transfer settings drive it high when idle and low when active.
    """

    def __init__(
        self,
        target: SpiTarget,
        *,
        cs_pin: int = 0,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if not 0 <= cs_pin < GP_PINS:
            raise ValueError(f"cs_pin {cs_pin} is not a GP pin (0 .. {GP_PINS - 1})")
        self.target = target
        self.cs_pin = cs_pin
        self.clock = clock
        self.counters = ChipCounters()
        self.chip_settings = ChipSettings()
        self.spi_settings = SpiTransferSettings()
        self._tx: _Transaction | None = None
        self._busy_until = 0.0

    def power_up(self) -> None:
        """Back to the power-up settings (the chip copies them from its NVRAM), engine idle."""
        self.chip_settings = ChipSettings()
        self.spi_settings = SpiTransferSettings()
        self._tx = None
        self._busy_until = 0.0

    @property
    def transfer_in_progress(self) -> bool:
        """A transaction has started and has not finished or been cancelled."""
        return self._tx is not None

    def handle(self, report: bytes) -> bytes:
        """Execute one command report; return the response report."""
        if len(report) != REPORT_BYTES:
            raise ValueError(f"an MCP2210 report is {REPORT_BYTES} bytes, got {len(report)}")
        code = report[0]
        self.counters.commands[code] += 1
        handler = self._handlers.get(code)
        if handler is None:
            return _reply(code, STATUS_UNKNOWN_COMMAND)
        reply = handler(self, report)
        if reply[1] == STATUS_BUSY:
            self.counters.busy_replies += 1
        return reply

    # -- commands ---------------------------------------------------------------------------

    def _get_status(self, report: bytes) -> bytes:
        return _reply(report[0], STATUS_OK, self._status_bytes())

    def _cancel(self, report: bytes) -> bytes:
        tx = self._tx
        if tx is not None:
            self.counters.cancelled += 1
            if not tx.complete and tx.mosi and tx.selected:
                # The bytes already clocked were a (short) chip-select-low transaction to the
                # slave; chip select goes high now.
                self.target.transfer(bytes(tx.mosi), mode=tx.mode)
        self._tx = None
        self._busy_until = 0.0
        return _reply(report[0], STATUS_OK, self._status_bytes())

    def _get_chip_settings(self, report: bytes) -> bytes:
        return _reply(report[0], STATUS_OK, b"\x00\x00" + self.chip_settings.pack())

    def _set_chip_settings(self, report: bytes) -> bytes:
        if self._engine_busy():
            return _reply(report[0], STATUS_BUSY)
        self.chip_settings = ChipSettings.unpack(report[4:])
        return _reply(report[0], STATUS_OK, b"\x00\x00" + self.chip_settings.pack())

    def _set_spi_settings(self, report: bytes) -> bytes:
        if self._engine_busy():
            return _reply(report[0], STATUS_BUSY)
        self.spi_settings = SpiTransferSettings.unpack(report[4:])
        return _reply(report[0], STATUS_OK, b"\x00\x00" + self.spi_settings.pack())

    def _get_spi_settings(self, report: bytes) -> bytes:
        return _reply(
            report[0], STATUS_OK, bytes([SPI_SETTINGS_BYTES, 0]) + self.spi_settings.pack()
        )

    def _transfer(self, report: bytes) -> bytes:
        code = report[0]
        now = self.clock()
        if now < self._busy_until:
            return _reply(code, STATUS_BUSY)
        data = report[4 : 4 + min(report[1], MAX_DATA_PER_REPORT)]
        tx = self._tx
        if tx is None:
            expected = self.spi_settings.bytes_per_transaction
            if not data or expected == 0:
                return _reply(code, STATUS_OK, bytes([0, ENGINE_FINISHED]))
            tx = _Transaction(expected, self.spi_settings.mode, self._selected())
            self._tx = tx
            self.counters.transactions += 1
            self._accept(tx, data, now, first=True)
            # The first report only starts the engine: its bytes are still being clocked.
            return _reply(code, STATUS_OK, bytes([0, ENGINE_STARTED]))
        clocked = len(tx.mosi)  # the engine is idle, so everything accepted so far is clocked
        self._accept(tx, data, now, first=False)
        received = b""
        if tx.miso is not None:
            end = min(clocked, tx.delivered + MAX_DATA_PER_REPORT)
            received = tx.miso[tx.delivered : end]
            tx.delivered = end
        if tx.complete and tx.delivered == tx.expected:
            self._tx = None
            return _reply(code, STATUS_OK, bytes([len(received), ENGINE_FINISHED]) + received)
        return _reply(code, STATUS_OK, bytes([len(received), ENGINE_NOT_FINISHED]) + received)

    _handlers: ClassVar[dict[int, Callable[[Mcp2210Chip, bytes], bytes]]] = {
        CMD_GET_STATUS: _get_status,
        CMD_CANCEL_TRANSFER: _cancel,
        CMD_GET_CHIP_SETTINGS: _get_chip_settings,
        CMD_SET_CHIP_SETTINGS: _set_chip_settings,
        CMD_SET_SPI_SETTINGS: _set_spi_settings,
        CMD_GET_SPI_SETTINGS: _get_spi_settings,
        CMD_TRANSFER: _transfer,
    }

    # -- the SPI engine ---------------------------------------------------------------------

    def _engine_busy(self) -> bool:
        # "USB transfer in progress": settings cannot change under a running transaction.
        return self._tx is not None or self.clock() < self._busy_until

    def _selected(self) -> bool:
        pin = 1 << self.cs_pin
        s = self.spi_settings
        return (
            self.chip_settings.pins[self.cs_pin] == PIN_CHIP_SELECT
            and bool(s.idle_cs & pin)
            and not s.active_cs & pin
        )

    def _accept(self, tx: _Transaction, data: bytes, now: float, *, first: bool) -> None:
        take = data[: tx.expected - len(tx.mosi)]
        self.counters.ignored_bytes += len(data) - len(take)
        if not take:
            return
        tx.mosi += take
        s = self.spi_settings
        rate = min(max(s.bit_rate, MIN_BIT_RATE), MAX_BIT_RATE)
        quanta = (s.cs_to_data_delay if first else 0) + s.inter_byte_delay * (len(take) - 1)
        if tx.complete:
            quanta += s.data_to_cs_delay
        self._busy_until = now + len(take) * 8 / rate + quanta * DELAY_QUANTUM_S
        if tx.complete:
            tx.miso = self._clock_out(tx)

    def _clock_out(self, tx: _Transaction) -> bytes:
        if not tx.selected:
            return bytes([UNDRIVEN_MISO]) * tx.expected
        miso = self.target.transfer(bytes(tx.mosi), mode=tx.mode)
        if len(miso) != tx.expected:
            raise RuntimeError(
                f"SPI target returned {len(miso)} MISO bytes for a {tx.expected}-byte transaction"
            )
        return bytes(miso)

    def _status_bytes(self) -> bytes:
        owner = 0x01 if self._tx is not None else 0x00  # 0x01: the USB bridge owns the bus
        # no external bus-release request, no password attempts, password not guessed
        return bytes([0x01, owner, 0x00, 0x00])


def _reply(code: int, status: int, body: bytes = b"") -> bytes:
    """A response report: command echo, status, then ``body`` from byte 2, zero padded."""
    out = bytes([code, status]) + body
    return out + bytes(REPORT_BYTES - len(out))


# -- USB descriptors --------------------------------------------------------------------------

MANUFACTURER = "Microchip Technology Inc."
PRODUCT = "MCP2210 USB to SPI Master"
DEFAULT_SERIAL = "0000000001"
LANGID_EN_US = 0x0409

# A vendor-defined HID report descriptor: 64-byte input and output reports, no report ID.
HID_REPORT_DESCRIPTOR = bytes.fromhex(
    "0600ff 0901 a101 1901 2940 1500 26ff00 7508 9540 8100 1901 2940 9100 c0".replace(" ", "")
)

_HID_DESCRIPTOR = struct.pack("<BBHBBBH", 9, 0x21, 0x0111, 0, 1, 0x22, len(HID_REPORT_DESCRIPTOR))


def _descriptors(vendor_id: int, product_id: int) -> UsbDescriptors:
    device = DeviceDescriptor(
        vendor_id,
        product_id,
        bus=1,
        address=7,
        port_number=2,
        bcdUSB=0x0200,
        bMaxPacketSize0=8,
        bcdDevice=0x0002,
        speed=SPEED_FULL,
    )
    configuration = ConfigurationDescriptor(
        bConfigurationValue=CONFIGURATION,
        bmAttributes=0x80,  # bus powered
        bMaxPower=50,  # 100 mA in 2 mA units
    )
    interface = InterfaceDescriptor(
        bInterfaceNumber=INTERFACE,
        bInterfaceClass=0x03,  # HID
        extra_descriptors=list(_HID_DESCRIPTOR),
    )
    endpoints = [
        EndpointDescriptor(EP_IN, bmAttributes=0x03, wMaxPacketSize=REPORT_BYTES, bInterval=1),
        EndpointDescriptor(EP_OUT, bmAttributes=0x03, wMaxPacketSize=REPORT_BYTES, bInterval=1),
    ]
    return UsbDescriptors(device, configuration, interface, endpoints)


# -- the pyusb backend ------------------------------------------------------------------------


class Mcp2210Backend(SimulatedUsbDevice):
    """A pyusb backend with one simulated MCP2210 on it, driving ``target`` over SPI.

    ``vendor_id`` / ``product_id`` / ``serial`` are what the chip enumerates with (the real
    chip's are programmable in its NVRAM). The interface starts with the kernel's HID driver
    bound to it, as on Linux: claiming it (which pyusb does on the first read or write) fails
    with EBUSY until ``detach_kernel_driver`` is called. ``unplug()`` makes every later call
    fail as for a disconnected device and hides it from enumeration.
    """

    def __init__(
        self,
        target: SpiTarget,
        *,
        vendor_id: int = VENDOR_ID,
        product_id: int = PRODUCT_ID,
        serial: str = DEFAULT_SERIAL,
        cs_pin: int = 0,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.chip = Mcp2210Chip(target, cs_pin=cs_pin, clock=clock)
        self.serial = serial
        super().__init__(
            name="MCP2210",
            descriptors=_descriptors(vendor_id, product_id),
            strings={1: MANUFACTURER, 2: PRODUCT, 3: serial},
            kernel_driver="HID",
        )
        self._response: bytes | None = None

    # -- hot-plug and reset ---------------------------------------------------------------------

    def _on_unplug(self) -> None:
        self._response = None

    def _on_plug(self) -> None:
        self.chip.power_up()

    def _on_reset(self) -> None:
        self._response = None
        self.chip.power_up()

    def _class_descriptor(
        self, recipient: int, desc_type: int, index: int, w_index: int
    ) -> bytes | None:
        if recipient == 0x01 and desc_type == 0x22 and w_index == INTERFACE:
            return HID_REPORT_DESCRIPTOR
        return None

    # -- transfers ------------------------------------------------------------------------------

    def intr_write(
        self, dev_handle: Handle, ep: int, intf: int, data: array.array[int], timeout: int
    ) -> int:
        with self._lock:
            self._check_claimed(dev_handle, intf)
            if ep != EP_OUT:
                raise usb_error("pipe", f"endpoint 0x{ep:02X} is not the OUT endpoint")
            report = bytes(data)
            if len(report) > REPORT_BYTES:
                raise usb_error("invalid", f"a report is at most {REPORT_BYTES} bytes")
            if self._response is not None:
                # The chip answers one command at a time: until the host has read the
                # response, the OUT endpoint NAKs and the write times out.
                raise usb_error("timeout", "the previous response has not been read")
            try:
                self._response = self.chip.handle(report.ljust(REPORT_BYTES, b"\x00"))
            except OSError as exc:
                # The SPI bus behind the simulated chip is gone (the simulator stopped): to the
                # host this is a device that vanished.
                raise usb_error("no_device", f"simulated SPI bus: {exc}") from exc
            return len(report)

    def intr_read(
        self, dev_handle: Handle, ep: int, intf: int, buff: array.array[int], timeout: int
    ) -> int:
        with self._lock:
            self._check_claimed(dev_handle, intf)
            if ep != EP_IN:
                raise usb_error("pipe", f"endpoint 0x{ep:02X} is not the IN endpoint")
            if self._response is None:
                # Nothing can arrive later: the simulated chip answers during the write.
                raise usb_error("timeout", "no response pending; send a command first")
            if len(buff) < REPORT_BYTES:
                raise usb_error("overflow", f"the report is {REPORT_BYTES} bytes")
            buff[:REPORT_BYTES] = array.array("B", self._response)
            self._response = None
            return REPORT_BYTES


def get_backend(target: SpiTarget, **kwargs: Any) -> Mcp2210Backend:
    """A backend with one simulated MCP2210 whose SPI bus leads to ``target``.

    The pyusb convention for backend modules; keyword arguments go to ``Mcp2210Backend``.
    """
    return Mcp2210Backend(target, **kwargs)


# -- the SPI bus between processes (the client end) ------------------------------------------


class SpiLinkError(ConnectionError):
    """The SPI socket to the simulated camera is unreachable or broke; the message says why."""


class SpiTargetError(RuntimeError):
    """The remote SPI target refused a transaction (the message is the simulator's)."""


class SocketSpiTarget:
    """The client end of an ``SpiSocketServer`` (``firmware_models.usb_spi``): an ``SpiTarget``
    in another process.

    Connects on first use and again after the simulator restarted (a connection found closed
    before a request is sent is replaced, once). A connection lost after a request was sent
    is an error, not retried: the transaction may have reached the sensor.
    """

    def __init__(self, path: str | Path, *, timeout_s: float = 2.0) -> None:
        if timeout_s <= 0:
            raise ValueError(f"timeout_s={timeout_s} must be positive")
        self.path = Path(path)
        self.timeout_s = timeout_s
        self._sock: socket.socket | None = None
        self._lock = threading.Lock()

    def transfer(self, mosi: bytes, *, mode: int) -> bytes:
        """One chip-select-low transaction on the simulator's SPI bus."""
        if not 0 <= mode <= 3:
            raise ValueError(f"SPI mode {mode} is not 0 .. 3")
        if len(mosi) + 1 > MAX_SPI_MESSAGE:
            raise ValueError(f"an SPI transaction is at most {MAX_SPI_MESSAGE - 1} bytes")
        request = HEADER.pack(len(mosi) + 1) + bytes([mode]) + bytes(mosi)
        with self._lock:
            sock = self._send(request)
            try:
                header = recv_exact(sock, HEADER.size)
                if header is None:
                    raise ConnectionResetError("the simulator closed the connection")
                (length,) = HEADER.unpack(header)
                body = recv_exact(sock, length) if length else None
                if body is None:
                    raise ConnectionResetError("empty response")
            except OSError as exc:
                self._drop()
                raise SpiLinkError(
                    f"SPI socket {self.path}: connection lost during a transaction ({exc}); "
                    "it may or may not have reached the sensor: read the register back"
                ) from exc
        if body[0] != RESPONSE_OK:
            raise SpiTargetError(f"simulated SPI target: {body[1:].decode(errors='replace')}")
        return body[1:]

    def close(self) -> None:
        """Close the connection (a later transfer reconnects)."""
        with self._lock:
            self._drop()

    def _send(self, request: bytes) -> socket.socket:
        for attempt in range(2):
            sock = self._connection()  # SpiLinkError, with the fix, if nothing listens
            try:
                if self._peer_closed(sock):
                    raise ConnectionResetError("the simulator closed the connection")
                sock.sendall(request)
                return sock
            except OSError as exc:
                self._drop()
                if attempt:
                    raise SpiLinkError(f"SPI socket {self.path}: cannot send ({exc})") from exc
        raise AssertionError("unreachable")

    def _connection(self) -> socket.socket:
        if self._sock is not None:
            return self._sock
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        sock.settimeout(self.timeout_s)
        try:
            sock.connect(str(self.path))
        except OSError as exc:
            sock.close()
            raise SpiLinkError(
                f"no simulated camera serves SPI on {self.path} ({exc.strerror or exc}); start "
                f"it with `python -m firmware_models --spi-socket {self.path}` or check the path"
            ) from exc
        self._sock = sock
        return sock

    @staticmethod
    def _peer_closed(sock: socket.socket) -> bool:
        # Between transactions the server sends nothing: readable now means it hung up (or the
        # stream is out of step); either way the connection is unusable.
        ready, _, _ = select.select([sock], [], [], 0)
        return bool(ready)

    def _drop(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None
