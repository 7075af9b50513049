"""Finding and claiming a USB device through pyusb, with errors that say what to do.

The camera's frame streamer (``camd.link.stream_device``) and the USB-to-SPI bridge
(``camd.sensor.mcp2210``) find their device with ``usb.core.find`` and claim its interface the
same way (detach a kernel driver, set the configuration if none is active, claim) and let it go
the same way; each says what failed in its own words and error type.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator
from typing import Any, Literal

import usb.core
import usb.util

NO_USB_LIBRARY = (
    "pyusb found no USB library: install libusb-1.0 (Debian/Ubuntu: `apt install libusb-1.0-0`)"
)

# The steps of claiming an interface, for the caller's messages.
ClaimStep = Literal["open", "detach", "configure", "claim"]
ClaimFailure = Callable[[ClaimStep, usb.core.USBError], Exception]


@contextlib.contextmanager
def usb_listing(error: Callable[[str], Exception], hint: str) -> Iterator[None]:
    """Around a ``usb.core.find`` (and the iteration of what it finds): pyusb's
    NoBackendError and USBError become ``error`` with a message; ``hint`` says what to check
    when the devices cannot be listed."""
    try:
        yield
    except usb.core.NoBackendError:
        raise error(NO_USB_LIBRARY) from None
    except usb.core.USBError as exc:
        raise error(f"cannot list USB devices ({exc}); {hint}") from exc


def detach_kernel_driver(dev: Any, interface: int, fail: ClaimFailure) -> bool:
    """Detach the kernel driver bound to ``interface``, if one is; True if one was (the caller
    attaches it again when it lets the device go). ``fail(step, exc)``: the error to raise."""
    try:
        active = bool(dev.is_kernel_driver_active(interface))
    except NotImplementedError:
        return False  # platforms without kernel drivers to detach
    except usb.core.USBError as exc:
        raise fail("open", exc) from exc
    if not active:
        return False
    try:
        dev.detach_kernel_driver(interface)
    except usb.core.USBError as exc:
        raise fail("detach", exc) from exc
    return True


def configure_and_claim(dev: Any, interface: int, fail: ClaimFailure) -> None:
    """Set the device's configuration unless one is active, then claim ``interface``;
    ``fail(step, exc)``: the error to raise."""
    try:
        dev.get_active_configuration()
    except usb.core.USBError:
        try:
            dev.set_configuration()
        except usb.core.USBError as exc:
            raise fail("configure", exc) from exc
    try:
        usb.util.claim_interface(dev, interface)
    except usb.core.USBError as exc:
        raise fail("claim", exc) from exc


def release_device(dev: Any, interface: int, *, reattach: bool) -> Exception | None:
    """Release ``interface`` (a device gone or never claimed has nothing to release), give the
    kernel driver back (``reattach``: it was detached), dispose of the device; the error that
    kept the driver from being attached again, if any, for the caller to report or not."""
    with contextlib.suppress(usb.core.USBError):
        usb.util.release_interface(dev, interface)
    failed: Exception | None = None
    if reattach:
        try:
            dev.attach_kernel_driver(interface)
        except (usb.core.USBError, NotImplementedError) as exc:
            failed = exc
    usb.util.dispose_resources(dev)
    return failed
