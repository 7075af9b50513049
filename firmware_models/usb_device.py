"""What every simulated USB device of the camera has in common, as a pyusb backend base class.

``SimulatedUsbDevice`` is a ``usb.backend.IBackend`` with one device on it: descriptors
(device, configuration, one interface, its endpoints, string descriptors) served both to
pyusb's descriptor calls and to GET_DESCRIPTOR control requests, open handles, configuration,
interface claiming, an optional kernel driver that must be detached first (as on Linux), and
hot-plug (``unplug()`` / ``plug()``). Errors are raised as pyusb's libusb1 backend raises them
(``usb_error``), so the host code under test handles the simulated device exactly as the
hardware. Subclasses add the transfers (``firmware_models.mcp2210_backend``: interrupt reports
of an MCP2210; ``firmware_models.fx3_backend``: bulk IN frames of an FX3).

The simulators serve their buses to other processes on Unix sockets; ``claim_socket_path`` /
``release_socket_path`` are the socket-file handling they share (a stale file from a simulator
that died is replaced, a live one is an error).
"""

from __future__ import annotations

import array
import contextlib
import errno
import os
import socket
import stat
import struct
import threading
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import NamedTuple, Self

import usb.backend
import usb.core

LANGID_EN_US = 0x0409

# usb.util's speed constants, written out so the descriptors read as the bus does.
SPEED_FULL = 2
SPEED_HIGH = 3
SPEED_SUPER = 4

# -- descriptors ------------------------------------------------------------------------------


@dataclass(slots=True)
class DeviceDescriptor:
    """The standard device descriptor, with the bus position pyusb also reads from it."""

    idVendor: int
    idProduct: int
    bus: int
    address: int
    port_number: int
    bLength: int = 18
    bDescriptorType: int = 0x01
    bcdUSB: int = 0x0200
    bDeviceClass: int = 0x00  # defined at interface level
    bDeviceSubClass: int = 0x00
    bDeviceProtocol: int = 0x00
    bMaxPacketSize0: int = 8
    bcdDevice: int = 0x0002
    iManufacturer: int = 1
    iProduct: int = 2
    iSerialNumber: int = 3
    bNumConfigurations: int = 1
    port_numbers: tuple[int, ...] | None = None
    speed: int = SPEED_FULL

    def to_bytes(self) -> bytes:
        return struct.pack(
            "<BBHBBBBHHHBBBB",
            self.bLength,
            self.bDescriptorType,
            self.bcdUSB,
            self.bDeviceClass,
            self.bDeviceSubClass,
            self.bDeviceProtocol,
            self.bMaxPacketSize0,
            self.idVendor,
            self.idProduct,
            self.bcdDevice,
            self.iManufacturer,
            self.iProduct,
            self.iSerialNumber,
            self.bNumConfigurations,
        )


@dataclass(slots=True)
class ConfigurationDescriptor:
    """The configuration descriptor; ``wTotalLength`` is set by ``SimulatedUsbDevice``."""

    bLength: int = 9
    bDescriptorType: int = 0x02
    wTotalLength: int = 9
    bNumInterfaces: int = 1
    bConfigurationValue: int = 1
    iConfiguration: int = 0
    bmAttributes: int = 0x80  # bus powered
    bMaxPower: int = 50
    extra_descriptors: list[int] = field(default_factory=list)

    def to_bytes(self) -> bytes:
        return struct.pack(
            "<BBHBBBBB",
            self.bLength,
            self.bDescriptorType,
            self.wTotalLength,
            self.bNumInterfaces,
            self.bConfigurationValue,
            self.iConfiguration,
            self.bmAttributes,
            self.bMaxPower,
        )


@dataclass(slots=True)
class InterfaceDescriptor:
    """The interface descriptor; ``extra_descriptors`` (e.g. HID) follow it on the wire."""

    bLength: int = 9
    bDescriptorType: int = 0x04
    bInterfaceNumber: int = 0
    bAlternateSetting: int = 0
    bNumEndpoints: int = 0
    bInterfaceClass: int = 0xFF  # vendor specific
    bInterfaceSubClass: int = 0x00
    bInterfaceProtocol: int = 0x00
    iInterface: int = 0
    extra_descriptors: list[int] = field(default_factory=list)

    def to_bytes(self) -> bytes:
        return struct.pack(
            "<BBBBBBBBB",
            self.bLength,
            self.bDescriptorType,
            self.bInterfaceNumber,
            self.bAlternateSetting,
            self.bNumEndpoints,
            self.bInterfaceClass,
            self.bInterfaceSubClass,
            self.bInterfaceProtocol,
            self.iInterface,
        )


@dataclass(slots=True)
class EndpointDescriptor:
    """An endpoint descriptor; ``extra_descriptors`` (e.g. a SuperSpeed companion) follow it."""

    bEndpointAddress: int
    bLength: int = 7
    bDescriptorType: int = 0x05
    bmAttributes: int = 0x03  # interrupt
    wMaxPacketSize: int = 64
    bInterval: int = 1
    bRefresh: int = 0
    bSynchAddress: int = 0
    extra_descriptors: list[int] = field(default_factory=list)

    def to_bytes(self) -> bytes:
        return struct.pack(
            "<BBBBHB",
            self.bLength,
            self.bDescriptorType,
            self.bEndpointAddress,
            self.bmAttributes,
            self.wMaxPacketSize,
            self.bInterval,
        )


class UsbDescriptors(NamedTuple):
    """A simulated device's descriptors: the device, its one configuration with one
    interface, and that interface's endpoints (what ``SimulatedUsbDevice`` enumerates)."""

    device: DeviceDescriptor
    configuration: ConfigurationDescriptor
    interface: InterfaceDescriptor
    endpoints: Sequence[EndpointDescriptor]


# -- errors -----------------------------------------------------------------------------------

# libusb error codes, as pyusb's libusb1 backend reports them
LIBUSB_ERRORS: dict[str, tuple[int, int, str]] = {
    "io": (-1, errno.EIO, "Input/output error"),
    "invalid": (-2, errno.EINVAL, "Invalid parameter"),
    "no_device": (-4, errno.ENODEV, "No such device (it may have been disconnected)"),
    "not_found": (-5, errno.ENOENT, "Entity not found"),
    "busy": (-6, errno.EBUSY, "Resource busy"),
    "timeout": (-7, errno.ETIMEDOUT, "Operation timed out"),
    "overflow": (-8, errno.EOVERFLOW, "Overflow"),
    "pipe": (-9, errno.EPIPE, "Pipe error"),
}


def usb_error(kind: str, detail: str = "") -> Exception:
    """The exception pyusb raises for libusb error ``kind`` (a key of LIBUSB_ERRORS)."""
    code, err, text = LIBUSB_ERRORS[kind]
    message = f"{text} ({detail})" if detail else text
    if kind == "timeout":
        return usb.core.USBTimeoutError(message, code, err)  # type: ignore[no-any-return]
    return usb.core.USBError(message, code, err)  # type: ignore[no-any-return]


# -- the device -------------------------------------------------------------------------------


class DeviceId:
    """The backend's identification of its one device (opaque to pyusb)."""


@dataclass(eq=False, slots=True)
class Handle:
    """An open device handle."""

    open: bool = True
    claimed: set[int] = field(default_factory=set)


class SimulatedUsbDevice(usb.backend.IBackend):  # type: ignore[misc]
    """A pyusb backend with one simulated device: enumeration, descriptors, handles, claiming.

    ``name`` (e.g. "MCP2210") and ``kernel_driver`` (e.g. "HID", or None when no kernel
    driver binds to the interface) appear in error messages. With a kernel driver bound,
    claiming the interface and setting the configuration fail with EBUSY until
    ``detach_kernel_driver`` is called, as on Linux. ``unplug()`` makes every later call fail
    as for a disconnected device and hides it from enumeration; ``plug()`` enumerates it again
    (old handles stay dead). Subclasses implement the transfers and may refine the hooks
    ``_on_plug``, ``_on_unplug``, ``_on_reset``, ``_class_descriptor`` and ``clear_halt``.
    """

    def __init__(
        self,
        *,
        name: str,
        descriptors: UsbDescriptors,
        strings: Mapping[int, str],
        kernel_driver: str | None = None,
    ) -> None:
        super().__init__()
        device, configuration, interface, endpoints = descriptors
        self.name = name
        self.kernel_driver = kernel_driver
        self.kernel_driver_attached = kernel_driver is not None
        self.plugged = True
        self._lock = threading.RLock()
        self._id = DeviceId()
        self._device = device
        self._configuration = configuration
        self._interface = interface
        self._endpoints = tuple(endpoints)
        self._strings = dict(strings)
        interface.bNumEndpoints = len(self._endpoints)
        configuration.wTotalLength = len(self._configuration_bytes())
        self._active_configuration = configuration.bConfigurationValue  # set at enumeration
        self._handles: list[Handle] = []

    @property
    def interface_number(self) -> int:
        return int(self._interface.bInterfaceNumber)

    @property
    def configuration_value(self) -> int:
        return int(self._configuration.bConfigurationValue)

    # -- hot-plug -----------------------------------------------------------------------------

    def unplug(self) -> None:
        """Disconnect the simulated device: later calls fail with ENODEV."""
        with self._lock:
            self.plugged = False
            self._on_unplug()

    def plug(self) -> None:
        """Reconnect: the device enumerates again, configured, with its kernel driver bound."""
        with self._lock:
            self.plugged = True
            self.kernel_driver_attached = self.kernel_driver is not None
            self._active_configuration = self.configuration_value
            self._handles = []
            self._on_plug()

    def _on_unplug(self) -> None:
        """Called (under the lock) when the device goes away."""

    def _on_plug(self) -> None:
        """Called (under the lock) when the device comes back, powered up."""

    def _on_reset(self) -> None:
        """Called (under the lock) by a USB port reset."""

    # -- enumeration and descriptors -------------------------------------------------------------

    def enumerate_devices(self) -> Iterator[DeviceId]:
        with self._lock:
            devices = [self._id] if self.plugged else []
        yield from devices

    def get_parent(self, dev: DeviceId) -> None:
        return None

    def get_device_descriptor(self, dev: DeviceId) -> DeviceDescriptor:
        self._check_device(dev)
        return self._device

    def get_configuration_descriptor(self, dev: DeviceId, config: int) -> ConfigurationDescriptor:
        self._check_device(dev)
        if config != 0:
            raise IndexError(f"the {self.name} has one configuration, not index {config}")
        return self._configuration

    def get_interface_descriptor(
        self, dev: DeviceId, intf: int, alt: int, config: int
    ) -> InterfaceDescriptor:
        self._check_device(dev)
        if (intf, alt, config) != (0, 0, 0):
            raise IndexError(f"the {self.name} has one interface, not {intf}/{alt}/{config}")
        return self._interface

    def get_endpoint_descriptor(
        self, dev: DeviceId, ep: int, intf: int, alt: int, config: int
    ) -> EndpointDescriptor:
        self.get_interface_descriptor(dev, intf, alt, config)
        if not 0 <= ep < len(self._endpoints):
            raise IndexError(
                f"the {self.name} interface has {len(self._endpoints)} endpoint(s), not index {ep}"
            )
        return self._endpoints[ep]

    # -- handles, configuration, interfaces ----------------------------------------------------

    def open_device(self, dev: DeviceId) -> Handle:
        with self._lock:
            self._check_device(dev)
            self._check_plugged()
            handle = Handle()
            self._handles.append(handle)
            return handle

    def close_device(self, dev_handle: Handle) -> None:
        with self._lock:
            dev_handle.open = False
            dev_handle.claimed.clear()
            if dev_handle in self._handles:
                self._handles.remove(dev_handle)

    def set_configuration(self, dev_handle: Handle, config_value: int) -> None:
        with self._lock:
            self._check_handle(dev_handle)
            if config_value not in (0, self.configuration_value):
                raise usb_error("not_found", f"no configuration {config_value}")
            if self.kernel_driver_attached or self._claimed_by_anyone():
                # Linux refuses to (re)configure while a driver holds an interface.
                raise usb_error("busy", "an interface is in use; detach the kernel driver first")
            self._active_configuration = config_value

    def get_configuration(self, dev_handle: Handle) -> int:
        with self._lock:
            self._check_handle(dev_handle)
            return self._active_configuration

    def set_interface_altsetting(self, dev_handle: Handle, intf: int, altsetting: int) -> None:
        with self._lock:
            self._check_handle(dev_handle)
            if (intf, altsetting) != (self.interface_number, 0):
                raise usb_error("not_found", f"no interface {intf} alternate {altsetting}")

    def claim_interface(self, dev_handle: Handle, intf: int) -> None:
        with self._lock:
            self._check_handle(dev_handle)
            self._check_interface(intf)
            if self.kernel_driver_attached:
                raise usb_error(
                    "busy", f"the kernel {self.kernel_driver} driver is bound to the interface"
                )
            if any(intf in h.claimed for h in self._handles if h is not dev_handle):
                raise usb_error("busy", "another handle has claimed the interface")
            if self._active_configuration != self.configuration_value:
                raise usb_error("not_found", "the device is not configured")
            dev_handle.claimed.add(intf)

    def release_interface(self, dev_handle: Handle, intf: int) -> None:
        with self._lock:
            self._check_handle(dev_handle)
            if intf not in dev_handle.claimed:
                raise usb_error("not_found", f"interface {intf} is not claimed")
            dev_handle.claimed.discard(intf)

    def is_kernel_driver_active(self, dev_handle: Handle, intf: int) -> bool:
        with self._lock:
            self._check_handle(dev_handle)
            self._check_interface(intf)
            return self.kernel_driver_attached

    def detach_kernel_driver(self, dev_handle: Handle, intf: int) -> None:
        with self._lock:
            self._check_handle(dev_handle)
            self._check_interface(intf)
            if not self.kernel_driver_attached:
                raise usb_error("not_found", "no kernel driver is bound")
            self.kernel_driver_attached = False

    def attach_kernel_driver(self, dev_handle: Handle, intf: int) -> None:
        with self._lock:
            self._check_handle(dev_handle)
            self._check_interface(intf)
            if self.kernel_driver is None:
                raise usb_error("not_found", f"no kernel driver exists for the {self.name}")
            if self.kernel_driver_attached or self._claimed_by_anyone():
                raise usb_error("busy", "the interface is claimed or already has a driver")
            self.kernel_driver_attached = True

    def clear_halt(self, dev_handle: Handle, ep: int) -> None:
        with self._lock:
            self._check_handle(dev_handle)

    def reset_device(self, dev_handle: Handle) -> None:
        with self._lock:
            self._check_handle(dev_handle)
            self._on_reset()

    # -- control transfers ----------------------------------------------------------------------

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
        with self._lock:
            self._check_handle(dev_handle)
            device_to_host = bool(bmRequestType & 0x80)
            kind = (bmRequestType >> 5) & 0x03
            recipient = bmRequestType & 0x1F
            if not (device_to_host and kind == 0 and bRequest == 0x06):
                if device_to_host and kind == 0 and bRequest == 0x08:  # GET_CONFIGURATION
                    return fill(data, bytes([self._active_configuration]))
                raise usb_error("pipe", f"request 0x{bRequest:02X} not supported (stall)")
            desc_type, index = wValue >> 8, wValue & 0xFF
            special = self._class_descriptor(recipient, desc_type, index, wIndex)
            if special is not None:
                return fill(data, special)
            return fill(data, self._descriptor(desc_type, index))

    def _class_descriptor(
        self, recipient: int, desc_type: int, index: int, w_index: int
    ) -> bytes | None:
        """A class-specific descriptor (e.g. a HID report descriptor), or None."""
        return None

    def _configuration_bytes(self) -> bytes:
        parts = [self._configuration.to_bytes(), self._interface.to_bytes()]
        parts.append(bytes(self._interface.extra_descriptors))
        for ep in self._endpoints:
            parts += [ep.to_bytes(), bytes(ep.extra_descriptors)]
        return b"".join(parts)

    def _descriptor(self, desc_type: int, index: int) -> bytes:
        if desc_type == 0x01:
            return self._device.to_bytes()
        if desc_type == 0x02 and index == 0:
            return self._configuration_bytes()
        if desc_type == 0x03:
            if index == 0:
                return struct.pack("<BBH", 4, 0x03, LANGID_EN_US)
            if index in self._strings:
                text = self._strings[index].encode("utf-16-le")
                return bytes([2 + len(text), 0x03]) + text
        raise usb_error("pipe", f"no descriptor type 0x{desc_type:02X} index {index} (stall)")

    # -- checks -----------------------------------------------------------------------------------

    def _check_device(self, dev: DeviceId) -> None:
        if dev is not self._id:
            raise ValueError("not a device of this backend")

    def _check_plugged(self) -> None:
        if not self.plugged:
            raise usb_error("no_device")

    def _check_handle(self, dev_handle: Handle) -> None:
        self._check_plugged()
        if not dev_handle.open or dev_handle not in self._handles:
            raise usb_error("no_device", "the handle is closed or from before a reconnect")

    def _check_interface(self, intf: int) -> None:
        if intf != self.interface_number:
            raise usb_error("not_found", f"no interface {intf}")

    def _check_claimed(self, dev_handle: Handle, intf: int) -> None:
        self._check_handle(dev_handle)
        if intf not in dev_handle.claimed:
            raise usb_error("io", f"interface {intf} is not claimed")

    def _claimed_by_anyone(self) -> bool:
        return any(h.claimed for h in self._handles)


def fill(buff: array.array[int], payload: bytes) -> int:
    """Copy a control-IN payload into pyusb's buffer, truncated to wLength as on the bus."""
    n = min(len(buff), len(payload))
    buff[:n] = array.array("B", payload[:n])
    return n


# -- the Unix socket a simulator serves its bus on ------------------------------------------


def claim_socket_path(path: Path, what: str) -> None:
    """Make ``path`` free for a new listening socket.

    A socket file nobody listens on (left by a simulator that died) is removed; a file that is
    not a socket, or a socket another simulator listens on, is an error naming ``what`` (e.g.
    "SPI") so the user knows which simulator holds it."""
    try:
        mode = os.lstat(path).st_mode
    except FileNotFoundError:
        return
    if not stat.S_ISSOCK(mode):
        raise FileExistsError(f"{path} exists and is not a socket; choose another path")
    probe = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    try:
        probe.connect(str(path))
    except OSError:
        os.unlink(path)  # nobody listens: left behind by a simulator that died
        return
    finally:
        probe.close()
    raise OSError(errno.EADDRINUSE, f"another simulator already serves {what} on {path}")


def release_socket_path(path: Path, inode: int | None) -> None:
    """Remove the socket file at ``path`` if it is still the one with ``inode`` (ours)."""
    with contextlib.suppress(FileNotFoundError):
        if os.lstat(path).st_ino == inode:
            os.unlink(path)


class UnixSocketServer:
    """A simulator's listening Unix socket at ``path`` and the thread that accepts on it.

    Subclasses implement ``_accept_loop`` (it must return once ``_stopping`` is set and
    ``_wake_w`` was written to) and ``stop``; ``start`` claims the path (a stale socket file is
    replaced, a live one is an error naming ``what``), binds, listens and starts the thread.
    """

    what = "a simulated bus"  # in messages: "another simulator already serves <what> on ..."
    backlog = 4

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._listener: socket.socket | None = None
        self._inode: int | None = None
        self._wake_r: socket.socket | None = None
        self._wake_w: socket.socket | None = None
        self._stopping = threading.Event()
        self._thread: threading.Thread | None = None

    def __enter__(self) -> Self:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def start(self) -> None:
        """Bind, listen and start the accept thread."""
        if self._thread is not None:
            raise RuntimeError(f"the {self.what} socket server is already running")
        claim_socket_path(self.path, self.what)
        listener = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        try:
            listener.bind(str(self.path))
            listener.listen(self.backlog)
        except OSError:
            listener.close()
            raise
        self._listener = listener
        self._stopping.clear()
        self._wake_r, self._wake_w = socket.socketpair()
        self._inode = os.stat(self.path).st_ino
        self._thread = threading.Thread(
            target=self._accept_loop, name=f"{self.what} socket {self.path}", daemon=True
        )
        self._thread.start()

    def stop(self) -> None:
        raise NotImplementedError

    def _release(self) -> None:
        """After the accept thread has ended: close the listener and the wake-up pair, and
        remove the socket file if it is still ours."""
        if self._listener is not None:
            self._listener.close()
            self._listener = None
        release_socket_path(self.path, self._inode)
        for sock in (self._wake_r, self._wake_w):
            if sock is not None:
                sock.close()
        self._wake_r = self._wake_w = None

    def _accept_loop(self) -> None:
        raise NotImplementedError
