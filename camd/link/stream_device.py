"""The camera's FX3-class streamer on USB: found, configured, claimed, released.

``StreamDevice`` finds the streamer with pyusb (``backend=None``: libusb, the hardware; or the
simulated FX3's ``firmware_models.fx3_backend.get_backend(path)``), detaches a kernel driver,
sets its configuration and claims its interface (``open``), and gives all of it back
(``close``). It also sends the two requests the reader needs besides its bulk reads: the
transfer packing (``ask_packing``, docs/stream.md "Packed transfers") and the clearing of a
halted endpoint (``clear_halt``). The reader reads ``dev`` directly: nothing stands between
it and pyusb.
"""

from __future__ import annotations

import contextlib
import errno
from typing import Any

import usb.core
import usb.util

from camd.link.frame_types import StreamError, log
from camd.link.usb_access import (
    ClaimStep,
    configure_and_claim,
    detach_kernel_driver,
    release_device,
    usb_listing,
)

VENDOR_ID = 0x04B4  # Cypress FX3
PRODUCT_ID = 0x00F1  # the FX3 SDK's streamer example
ENDPOINT_IN = 0x81
INTERFACE = 0
# The streamer's vendor request for packed transfers (docs/stream.md "Packed transfers"):
# bmRequestType 0x40 (vendor, to the device), wValue = KiB of whole frames per transfer.
PACK_REQUEST = 0xB5
PACK_BYTES_MAX = 0xFFFF << 10  # wValue is 16 bits of KiB
# What a reader of small frames asks for: tens of small frames per read, a quarter of a
# millisecond of the fastest streams, a few hundred KiB of memory per slot.
PACK_BYTES = 256 << 10


class StreamDevice:
    """The streamer ``vendor_id:product_id`` through pyusb ``backend``; ``dev`` is the claimed
    device while open (None when closed), ``packet_bytes`` its bulk IN endpoint's packet size."""

    def __init__(self, *, vendor_id: int, product_id: int, backend: Any) -> None:
        self.vendor_id = vendor_id
        self.product_id = product_id
        self.backend = backend
        self.ident = f"{vendor_id:04x}:{product_id:04x}"
        self.dev: Any = None
        self.packet_bytes = 0
        self._detached = False

    def open(self, read_bytes: int) -> None:
        """Find the device, set its configuration, claim its interface; ``read_bytes`` (the
        stream's bytes per bulk read) must be whole packets of its endpoint."""
        if self.dev is not None:
            return
        with usb_listing(StreamError, self.hint()):
            dev = usb.core.find(
                idVendor=self.vendor_id, idProduct=self.product_id, backend=self.backend
            )
        if dev is None:
            raise StreamError(f"no USB frame-stream device {self.ident} found; {self.hint()}")
        try:
            self._claim(dev)
            ep = self._endpoint(dev)
        except BaseException:
            with contextlib.suppress(Exception):
                usb.util.dispose_resources(dev)
            raise
        self.packet_bytes = int(ep.wMaxPacketSize)
        if read_bytes % self.packet_bytes:
            usb.util.dispose_resources(dev)
            raise ValueError(
                f"read_bytes = {read_bytes} is not a multiple of the endpoint's "
                f"{self.packet_bytes}-byte packets (a read must end on a packet boundary); "
                "use 0 for whole frames"
            )
        self.dev = dev

    def hint(self) -> str:
        """What to check when the device cannot be found or opened."""
        vid_pid = f"{self.vendor_id:04x}:{self.product_id:04x}"
        return (
            f"check the camera's power and USB 3 cable, that `lsusb -d {vid_pid}` lists it "
            "(an FX3 without its firmware shows as 04b4:00f3), and that this user may open it "
            "(udev rule systemd/99-camd.rules, group plugdev; docs/hardware.md)"
            # A backend given is a simulated device's (real hardware is libusb's default).
            + ("; with the simulator, that it runs with --usb-socket" if self.backend else "")
        )

    def _claim(self, dev: Any) -> None:
        if detach_kernel_driver(dev, INTERFACE, self._claim_failed):
            self._detached = True
        configure_and_claim(dev, INTERFACE, self._claim_failed)

    def _claim_failed(self, step: ClaimStep, exc: usb.core.USBError) -> StreamError:
        """What ``_claim`` raises when ``step`` fails."""
        if step == "open":
            return StreamError(
                f"cannot open the USB frame-stream device {self.ident}: {exc}; {self.hint()}"
            )
        if step == "detach":
            return StreamError(f"cannot detach the kernel driver of {self.ident}: {exc}")
        if step == "configure":
            return StreamError(f"cannot configure {self.ident}: {exc}")
        return StreamError(
            f"cannot claim interface {INTERFACE} of {self.ident}: {exc}; is another "
            "program (another camd) reading the camera?"
        )

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
        """Release the interface, give the kernel driver back, dispose of the device."""
        dev, self.dev = self.dev, None
        if dev is None:
            return
        reattach, self._detached = self._detached, False
        release_device(dev, INTERFACE, reattach=reattach)  # a driver not given back: no matter

    def ask_packing(self, pack_bytes: int) -> bool:
        """Ask the streamer to pack frames into transfers of up to ``pack_bytes`` (0: one
        frame per transfer); False if it does not know the request (it stalls it)."""
        try:
            self.dev.ctrl_transfer(0x40, PACK_REQUEST, pack_bytes >> 10, INTERFACE, None)
        except usb.core.USBError as exc:
            if exc.errno == errno.EPIPE:
                log.info("frame stream %s: the device sends one frame per transfer", self.ident)
                return False
            if exc.errno == errno.ENODEV:
                return False  # gone: the reader says so
            raise StreamError(f"cannot set the transfer packing of {self.ident}: {exc}") from exc
        return True

    def clear_halt(self) -> None:
        """Clear a halt (a stall) of the bulk IN endpoint."""
        try:
            self.dev.clear_halt(ENDPOINT_IN)
        except usb.core.USBError as exc:
            raise StreamError(
                f"cannot clear the halt of endpoint 0x{ENDPOINT_IN:02X} on {self.ident}: {exc}; "
                "reset the camera"
            ) from exc
