"""Both USB devices camd finds (the frame streamer, the USB-to-SPI bridge) say the same, in
their own error types, when pyusb has no USB library or cannot list the devices; a claim
refused says which step failed and leaves the device as it was.

The backends here are pyusb backends whose listing fails, as libusb's does, and the simulated
MCP2210; the code under test is camd's own: FrameStream.open and Mcp2210Bridge.
"""

from __future__ import annotations

from typing import Any

import pytest
import usb.backend
import usb.core

from camd.link.frame_stream import FrameStream
from camd.link.frame_types import StreamError
from camd.sensor.bridge import BridgeError
from camd.sensor.mcp2210 import Mcp2210Bridge
from camd.sensor.regmap import load_register_map
from firmware_models.mcp2210_backend import get_backend
from firmware_models.sensor import SensorModel
from firmware_models.spi import SpiSlave

NO_LIBRARY = (
    "pyusb found no USB library: install libusb-1.0 (Debian/Ubuntu: `apt install libusb-1.0-0`)"
)


class _FailingListing(usb.backend.IBackend):  # type: ignore[misc]
    """A pyusb backend whose device listing raises ``error``."""

    def __init__(self, error: Exception) -> None:
        self.error = error

    def enumerate_devices(self) -> Any:
        raise self.error


def _stream_error(backend: Any) -> str:
    stream = FrameStream(backend=backend)
    with pytest.raises(StreamError) as caught:
        stream.open()
    return str(caught.value)


def _bridge_error(backend: Any) -> str:
    with pytest.raises(BridgeError) as caught:
        Mcp2210Bridge(load_register_map("hr400").spi, backend=backend)
    return str(caught.value)


def test_no_usb_library_says_what_to_install() -> None:
    backend = _FailingListing(usb.core.NoBackendError("No backend available"))
    assert _stream_error(backend) == NO_LIBRARY
    assert _bridge_error(backend) == NO_LIBRARY


def test_a_failed_listing_names_the_error_and_what_to_check() -> None:
    backend = _FailingListing(usb.core.USBError("Access denied", errno=13))
    stream = _stream_error(backend)
    assert stream.startswith("cannot list USB devices ([Errno 13] Access denied); check the ")
    assert "`lsusb -d 04b4:00f1`" in stream
    assert _bridge_error(backend) == (
        "cannot list USB devices ([Errno 13] Access denied); check the cable and the bridge's "
        "power, that `lsusb -d 04d8:00de` lists it, and that this user may open it (udev rule "
        "systemd/99-camd.rules, group plugdev; see docs/usb-spi.md)"
    )


def test_a_second_bridge_on_a_claimed_mcp2210_is_refused_and_the_first_keeps_it() -> None:
    regmap = load_register_map("hr400")
    backend = get_backend(SpiSlave(regmap.spi, SensorModel(regmap)))
    with Mcp2210Bridge(regmap.spi, backend=backend) as first:
        with pytest.raises(BridgeError) as caught:
            Mcp2210Bridge(regmap.spi, backend=backend)
        assert str(caught.value).startswith("cannot claim the MCP2210's interface: ")
        assert "another handle has claimed the interface" in str(caught.value)
        assert not backend.kernel_driver_attached  # the refused one gave nothing back
        first.read(0x10)
    assert backend.kernel_driver_attached  # the first gave the kernel driver back
