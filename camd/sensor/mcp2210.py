"""Sensor register access through a Microchip MCP2210 USB-to-SPI bridge, driven with pyusb.

The MCP2210 is a USB HID device: every command is one 64-byte report on the interrupt OUT
endpoint, answered by one 64-byte report on the interrupt IN endpoint (datasheet DS22288A,
section 3). The host frames each register access itself (``camd.sensor.spi_frame``) and sends
it as one SPI transaction: the chip asserts chip select, clocks the frame, releases chip select.

TRANSFER SPI DATA (0x42) is a conversation, not a call: the first report starts the engine
and is answered without data (engine status 0x20); later reports collect the received bytes
(0x30: more to come, 0x10: finished). While the engine clocks, the chip answers 0xF8 (busy)
and the host asks again. docs/usb-spi.md describes the commands used.
"""

from __future__ import annotations

import errno
import logging
import math
import struct
import threading
import time
from collections.abc import Sequence
from typing import Any

import usb.core
import usb.util

from camd.link.usb_access import (
    ClaimStep,
    configure_and_claim,
    detach_kernel_driver,
    release_device,
    usb_listing,
)
from camd.sensor.bridge import BridgeError, RegisterBridge
from camd.sensor.regmap import SpiLayout
from camd.sensor.spi_frame import decode_spi_response, encode_spi_frame

log = logging.getLogger(__name__)

VENDOR_ID = 0x04D8
PRODUCT_ID = 0x00DE
MIN_BIT_RATE_HZ = 1500.0
MAX_BIT_RATE_HZ = 12e6
GP_PINS = 9

_REPORT = 64
_MAX_DATA = 60
_EP_OUT = 0x01
_EP_IN = 0x81
_INTERFACE = 0

_GET_STATUS = 0x10
_CANCEL = 0x11
_GET_CHIP_SETTINGS = 0x20
_SET_CHIP_SETTINGS = 0x21
_SET_SPI_SETTINGS = 0x40
_GET_SPI_SETTINGS = 0x41
_TRANSFER = 0x42

_OK = 0x00
_BUSY = 0xF8
_FINISHED = 0x10
_STARTED = 0x20
_NOT_FINISHED = 0x30
_PIN_CHIP_SELECT = 0x01
_ALL_PINS = (1 << GP_PINS) - 1
_SPI_SETTINGS = struct.Struct("<IHHHHHHB")  # report bytes 4..20

_STATUS_TEXT = {
    0xF7: "the SPI bus is owned by an external master; release it (or check the board wiring)",
    0xF8: "the chip is busy with an SPI transfer",
    0xF9: "the chip does not know this command; check that the device is an MCP2210",
    0xFA: "the chip's EEPROM write failed; power-cycle the bridge",
    0xFB: "access blocked: the chip's settings are password-protected or locked; "
    "unlock them with Microchip's MCP2210 utility",
    0xFC: "access rejected: the chip's settings are permanently locked",
    0xFD: "access denied: wrong password",
}

# What failed, step by step, when the interface is claimed (camd.link.usb_access).
_CLAIM_FAILURES: dict[ClaimStep, str] = {
    "open": "cannot open the MCP2210",
    "detach": "cannot detach the kernel HID driver",
    "configure": "cannot configure the MCP2210",
    "claim": "cannot claim the MCP2210's interface",
}
_NOT_FOUND_HINT = (
    "check the cable and the bridge's power, that `lsusb -d 04d8:00de` lists it, and that "
    "this user may open it (udev rule systemd/99-camd.rules, group plugdev; see docs/usb-spi.md)"
)


class Mcp2210Bridge(RegisterBridge):
    """Register access over SPI through an MCP2210, one SPI transaction per register access.

    Opening finds the chip by VID/PID (and serial number, if given) through pyusb, detaches the
    kernel's HID driver (re-attached on ``close()``), cancels any transfer left over by a
    previous program, designates GP``cs_pin`` as the chip select and sets the SPI transfer
    settings for the sensor's frame layout: mode, ``layout.frame_bytes`` per transaction,
    chip select idle high and active low, no extra delays, and the bit rate (by default the
    fastest both the chip and the sensor allow). Every failure raises ``BridgeError`` with
    what to check.
    """

    name = "mcp2210"

    def __init__(
        self,
        layout: SpiLayout,
        *,
        backend: Any = None,
        vendor_id: int = VENDOR_ID,
        product_id: int = PRODUCT_ID,
        serial: str | None = None,
        cs_pin: int = 0,
        bit_rate_hz: float | None = None,
        timeout_s: float = 1.0,
    ) -> None:
        if not 0 <= cs_pin < GP_PINS:
            raise ValueError(f"cs_pin={cs_pin}: the MCP2210 has GP0 .. GP{GP_PINS - 1}")
        if not timeout_s > 0:
            raise ValueError(f"timeout_s={timeout_s} must be positive")
        if layout.frame_bytes > _MAX_DATA:
            # Every frame goes out in one TRANSFER SPI DATA report.
            raise ValueError(f"an SPI frame of {layout.frame_bytes} bytes exceeds one report")
        self.layout = layout
        self.cs_pin = cs_pin
        self.timeout_s = timeout_s
        self.bit_rate_hz = self._bit_rate(layout, bit_rate_hz)
        self._timeout_ms = max(1, round(timeout_s * 1000))
        self._lock = threading.Lock()
        self._detached = False
        self._dev: Any = self._find(backend, vendor_id, product_id, serial)
        self.serial_number: str | None = self._serial_of(self._dev)
        try:
            self._claim()
            self._configure()
        except BaseException:
            self.close()
            raise

    # -- RegisterBridge ---------------------------------------------------------------------------

    def read(self, address: int) -> int:
        """Read one register: one SPI transaction with the read frame."""
        mosi = encode_spi_frame(self.layout, read=True, address=address)
        with self._lock:
            miso = self._transfer(mosi)
        return decode_spi_response(self.layout, miso)

    def write(self, address: int, value: int) -> None:
        """Write one register: one SPI transaction with the write frame."""
        mosi = encode_spi_frame(self.layout, read=False, address=address, data=value)
        with self._lock:
            self._transfer(mosi)

    def write_burst(self, writes: Sequence[tuple[int, int]]) -> None:
        """Write (address, value) pairs in order, chip select toggling between frames."""
        frames = [encode_spi_frame(self.layout, read=False, address=a, data=v) for a, v in writes]
        # Holding the lock for the whole burst keeps other threads' accesses off the bus.
        with self._lock:
            for mosi in frames:
                self._transfer(mosi)

    def close(self) -> None:
        """Release the interface, give the device back to the kernel's HID driver."""
        with self._lock:
            dev, self._dev = self._dev, None
            if dev is None:
                return
            failed = release_device(dev, _INTERFACE, reattach=self._detached)
            if failed is not None:
                log.warning("MCP2210: could not re-attach the kernel HID driver: %s", failed)

    # -- chip commands --------------------------------------------------------------------------

    def chip_status(self) -> dict[str, int]:
        """GET STATUS (0x10): bus owner (0 none, 1 USB bridge, 2 external master) and more."""
        with self._lock:
            reply = self._command(_GET_STATUS)
        return {
            "bus_release_pending": int(reply[2] == 0x00),
            "bus_owner": reply[3],
            "password_attempts": reply[4],
            "password_guessed": reply[5],
        }

    def cancel(self) -> None:
        """CANCEL SPI TRANSFER (0x11): abort a transaction in progress, release chip select."""
        with self._lock:
            self._command(_CANCEL)

    # -- opening --------------------------------------------------------------------------------

    @staticmethod
    def _bit_rate(layout: SpiLayout, requested: float | None) -> int:
        limit = min(layout.max_clock_hz, MAX_BIT_RATE_HZ)
        rate = limit if requested is None else requested
        if not MIN_BIT_RATE_HZ <= rate <= limit:
            raise ValueError(
                f"bit_rate_hz={rate:g}: the MCP2210 clocks {MIN_BIT_RATE_HZ:g} .. "
                f"{MAX_BIT_RATE_HZ:g} Hz and the sensor allows at most {layout.max_clock_hz:g} Hz"
            )
        return math.floor(rate)  # never faster than asked

    @staticmethod
    def _serial_of(dev: Any) -> str | None:
        try:
            serial = dev.serial_number
        except (usb.core.USBError, ValueError):
            return None  # string descriptors need permission to open the device
        return serial if isinstance(serial, str) else None

    def _find(self, backend: Any, vendor_id: int, product_id: int, serial: str | None) -> Any:
        ident = f"VID 0x{vendor_id:04X}, PID 0x{product_id:04X}"
        with usb_listing(BridgeError, _NOT_FOUND_HINT):
            found = list(
                usb.core.find(
                    find_all=True, idVendor=vendor_id, idProduct=product_id, backend=backend
                )
            )
        if serial is not None:
            ident += f", serial {serial}"
            found = [d for d in found if self._serial_of(d) == serial]
        if not found:
            raise BridgeError(f"no MCP2210 USB-SPI bridge found ({ident}); {_NOT_FOUND_HINT}")
        if len(found) > 1:
            serials = ", ".join(str(self._serial_of(d)) for d in found)
            raise BridgeError(
                f"{len(found)} MCP2210 bridges found ({ident}; serials {serials}): "
                "name the sensor's bridge by its serial number"
            )
        return found[0]

    def _claim(self) -> None:
        if detach_kernel_driver(self._dev, _INTERFACE, self._claim_failed):
            self._detached = True
        configure_and_claim(self._dev, _INTERFACE, self._claim_failed)

    def _claim_failed(self, step: ClaimStep, exc: usb.core.USBError) -> BridgeError:
        """What ``_claim`` raises when ``step`` fails."""
        return self._usb_error(_CLAIM_FAILURES[step], exc)

    def _configure(self) -> None:
        # A transaction left half-done by a previous program would swallow our first frame.
        self._command(_CANCEL)
        chip = bytearray(self._command(_GET_CHIP_SETTINGS)[4:19])
        if chip[self.cs_pin] != _PIN_CHIP_SELECT:
            chip[self.cs_pin] = _PIN_CHIP_SELECT
            self._command(_SET_CHIP_SETTINGS, bytes(chip))
            if self._command(_GET_CHIP_SETTINGS)[4 + self.cs_pin] != _PIN_CHIP_SELECT:
                raise BridgeError(
                    f"the MCP2210 did not take GP{self.cs_pin} as chip select; "
                    "check its settings with Microchip's MCP2210 utility"
                )
        wanted = (
            self.bit_rate_hz,
            _ALL_PINS,  # idle: every chip select high
            _ALL_PINS & ~(1 << self.cs_pin),  # active: only the sensor's low
            0,  # chip select to data delay
            0,  # data to chip select delay
            0,  # delay between bytes
            self.layout.frame_bytes,
            self.layout.mode,
        )
        self._command(_SET_SPI_SETTINGS, _SPI_SETTINGS.pack(*wanted))
        reply = self._command(_GET_SPI_SETTINGS)
        got = _SPI_SETTINGS.unpack(reply[4 : 4 + _SPI_SETTINGS.size])
        if got != wanted:
            raise BridgeError(
                f"the MCP2210 kept SPI settings {got} instead of {wanted} "
                "(bit rate, idle CS, active CS, delays, bytes per transaction, mode); "
                "is another program reconfiguring it?"
            )

    # -- the conversation -----------------------------------------------------------------------

    def _transfer(self, mosi: bytes) -> bytes:
        """One SPI transaction of ``layout.frame_bytes`` bytes; the MISO bytes."""
        try:
            return self._exchange(mosi, time.monotonic() + self.timeout_s)
        except BridgeError:
            if self._dev is not None:
                # A half-done transaction would take the next frame as its continuation.
                self._abort()
            raise

    def _exchange(self, mosi: bytes, deadline: float) -> bytes:
        reply = self._transfer_report(mosi, deadline)
        engine, miso = reply[3], bytearray(self._received(reply))
        while engine != _FINISHED:
            if engine not in (_STARTED, _NOT_FINISHED):
                raise BridgeError(
                    f"the MCP2210 reported SPI engine status 0x{engine:02X}; "
                    "unplug and replug the bridge"
                )
            if time.monotonic() > deadline:
                raise BridgeError(
                    f"the MCP2210 did not finish an SPI transaction within {self.timeout_s:g} s "
                    "(transfer cancelled); is another program changing its transfer settings?"
                )
            reply = self._transfer_report(b"", deadline)
            engine = reply[3]
            miso += self._received(reply)
        if len(miso) != len(mosi):
            raise BridgeError(
                f"the MCP2210 returned {len(miso)} bytes for a {len(mosi)}-byte SPI "
                "transaction; is another program changing its transfer settings?"
            )
        return bytes(miso)

    def _transfer_report(self, data: bytes, deadline: float) -> bytes:
        """Send a TRANSFER SPI DATA report, asking again while the chip is busy."""
        pause = min(1e-3, 8 * self.layout.frame_bytes / self.bit_rate_hz)
        while True:
            reply = self._command(_TRANSFER, data, byte1=len(data), check=False)
            if reply[1] == _OK:
                return reply
            if reply[1] != _BUSY:
                raise self._status_error(_TRANSFER, reply[1])
            if time.monotonic() > deadline:
                raise BridgeError(
                    f"the MCP2210 stayed busy for more than {self.timeout_s:g} s during an SPI "
                    "transaction (transfer cancelled); check the bit rate and that nothing else "
                    "uses the bridge, then retry"
                )
            time.sleep(pause)

    @staticmethod
    def _received(reply: bytes) -> bytes:
        count = reply[2]
        if count > _MAX_DATA:
            raise BridgeError(f"the MCP2210 claimed {count} received bytes in one report (max 60)")
        return reply[4 : 4 + count]

    def _abort(self) -> None:
        try:
            self._command(_CANCEL)
        except BridgeError as exc:
            log.warning("MCP2210: could not cancel the SPI transfer: %s", exc)

    def _command(
        self, code: int, payload: bytes = b"", *, byte1: int = 0, check: bool = True
    ) -> bytes:
        """Send one command report, return the response report (status checked if ``check``)."""
        dev = self._dev
        if dev is None:
            raise BridgeError("the MCP2210 bridge is closed; open a new one")
        report = bytearray(_REPORT)
        report[0], report[1] = code, byte1
        report[4 : 4 + len(payload)] = payload
        try:
            dev.write(_EP_OUT, report, self._timeout_ms)
            reply = bytes(dev.read(_EP_IN, _REPORT, self._timeout_ms))
        except usb.core.USBError as exc:
            raise self._usb_error(f"USB transfer of command 0x{code:02X} failed", exc) from exc
        if len(reply) != _REPORT or reply[0] != code:
            raise BridgeError(
                f"the MCP2210 answered command 0x{code:02X} with {reply[:4].hex(' ')}...; "
                "another program may be talking to it: close it, then reopen the bridge"
            )
        if check and reply[1] != _OK:
            raise self._status_error(code, reply[1])
        return reply

    @staticmethod
    def _status_error(code: int, status: int) -> BridgeError:
        text = _STATUS_TEXT.get(status, "unknown status; unplug and replug the bridge")
        return BridgeError(f"MCP2210 command 0x{code:02X} failed with 0x{status:02X}: {text}")

    def _usb_error(self, what: str, exc: Exception) -> BridgeError:
        err = getattr(exc, "errno", None)
        if isinstance(exc, usb.core.USBTimeoutError) or err == errno.ETIMEDOUT:
            hint = (
                f"no answer within {self.timeout_s:g} s; unplug and replug the bridge, and make "
                "sure no other program talks to it"
            )
        elif err == errno.ENODEV:
            hint = "the bridge was disconnected; check the cable, then reopen the bridge"
        elif err == errno.EACCES:
            hint = (
                "permission denied; install the udev rule (systemd/99-camd.rules) and add this "
                "user to group plugdev, or run as the camd service user"
            )
        elif err == errno.EBUSY:
            hint = (
                "the interface is busy; close other programs using the bridge (another camd, "
                "the MCP2210 utility) and let camd detach the kernel HID driver"
            )
        else:
            hint = "unplug and replug the bridge, then retry"
        return BridgeError(f"{what}: {exc}; {hint}")
