"""Real or simulated: the one place where the config chooses each device backend.

The daemon drives the same interfaces whatever the camera is: the command link on a serial
port (or the simulator's pty), the frame stream through pyusb, the sensor's registers through
a register bridge, and the simulator's own controls. Only here does camd import the host halves
of the simulated hardware (firmware_models): the pyusb backends of the simulated FX3 and
MCP2210, and the simulator process; everything else receives what these functions return.
"""

from __future__ import annotations

import logging
from typing import Any, Literal

from camd.daemon.config import Config
from camd.daemon.device import DeviceAccess
from camd.daemon.models import BackendInfo, BackendsInfo
from camd.daemon.sim_control import FirmwareSimulator, NoSimulator, SimulatorControl
from camd.daemon.simulator import SimulatorProcess
from camd.link import CommandLink
from camd.sensor.bridge import RegisterBridge
from camd.sensor.fpga_bridge import FpgaBridge
from camd.sensor.mcp2210 import Mcp2210Bridge
from camd.sensor.regmap import RegisterMap
from firmware_models.fx3_backend import get_backend as fx3_backend
from firmware_models.mcp2210_backend import SocketSpiTarget
from firmware_models.mcp2210_backend import get_backend as mcp2210_backend

log = logging.getLogger(__name__)


def simulator_process(config: Config) -> SimulatorProcess | None:
    """The simulated camera to spawn (``link.device = "sim"``), or None for hardware."""
    return SimulatorProcess.for_config(config)


def simulator_control(device: DeviceAccess) -> SimulatorControl:
    """The simulator's controls, or their refusal on real hardware."""
    return FirmwareSimulator(device) if device.simulated else NoSimulator(device)


def frame_stream_backend(config: Config) -> Any:
    """The pyusb backend of the frame stream: the simulated FX3 (``stream.backend = "sim"``,
    or "auto" with the simulated link) on its socket, or None for libusb (real hardware)."""
    if config.stream_backend == "sim":
        return fx3_backend(config.sim_usb_socket)
    return None


def register_bridge(
    config: Config, regmap: RegisterMap, link: CommandLink | None
) -> RegisterBridge:
    """The bridge to the sensor's registers that ``sensor.bridge`` names: the FPGA's REG_*
    commands over the command link, or an MCP2210 USB-SPI bridge (real, or the simulated chip
    wired to the spawned simulator's SPI bus)."""
    if config.sensor.bridge == "fpga":
        if link is None:
            raise RuntimeError("the session has no command link")
        return FpgaBridge(link)
    usb = config.sensor.usb_spi
    backend: Any = None
    if config.usb_spi_backend == "sim":
        backend = mcp2210_backend(SocketSpiTarget(config.sim_spi_socket))
    return Mcp2210Bridge(
        regmap.spi,
        backend=backend,
        vendor_id=usb.vendor_id,
        product_id=usb.product_id,
        serial=usb.serial or None,
        cs_pin=usb.cs_pin,
    )


REGISTERS_OVER_LINK = "REG_* commands over the command link"


def describe(config: Config) -> BackendsInfo:
    """Which camera each interface talks to (the status's ``backends``): the simulator's
    or real hardware, with the port, socket or USB id."""
    link = (
        BackendInfo(kind="sim", backend="sim", detail=str(config.sim_link_path))
        if config.simulated_link
        else BackendInfo(kind="hardware", backend="serial", detail=config.link.device)
    )
    stream_usb = f"USB {config.stream.vendor_id:04x}:{config.stream.product_id:04x}"
    stream = (
        BackendInfo(kind="sim", backend="sim", detail=f"socket {config.sim_usb_socket}")
        if config.stream_backend == "sim"
        else BackendInfo(kind="hardware", backend="libusb", detail=stream_usb)
    )
    if config.sensor.bridge == "fpga":
        # The FPGA's SPI master is reached through the command link: the link's camera.
        registers = BackendInfo(kind=link.kind, backend="fpga", detail=REGISTERS_OVER_LINK)
    elif config.usb_spi_backend == "sim":
        registers = BackendInfo(
            kind="sim", backend="usb-spi", detail=f"simulated MCP2210 on {config.sim_spi_socket}"
        )
    else:
        usb = config.sensor.usb_spi
        serial = f", serial {usb.serial}" if usb.serial else ""
        registers = BackendInfo(
            kind="hardware",
            backend="usb-spi",
            detail=f"MCP2210 USB {usb.vendor_id:04x}:{usb.product_id:04x}{serial}",
        )
    kinds = {link.kind, stream.kind, registers.kind}
    camera: Literal["sim", "hardware", "mixed"] = "mixed" if len(kinds) > 1 else link.kind
    return BackendsInfo(camera=camera, link=link, stream=stream, registers=registers)


def summary(info: BackendsInfo) -> str:
    """One line: ``link serial /dev/ttyUSB0, stream libusb USB 04b4:00f1, registers fpga
    (REG_* commands over the command link)``."""
    link, stream, registers = info.link, info.stream, info.registers
    return (
        f"link {link.backend} {link.detail}, stream {stream.backend} {stream.detail}, "
        f"registers {registers.backend} ({registers.detail})"
    )


def mixed_parts(info: BackendsInfo) -> str:
    """``link=serial /dev/ttyUSB0, stream=sim``: for a mixed camera, which interface is which."""
    parts = {"link": info.link, "stream": info.stream, "registers": info.registers}
    return ", ".join(
        f"{name}={part.backend} {part.detail}" if part.kind == "hardware" else f"{name}=sim"
        for name, part in parts.items()
    )


def log_choice(config: Config) -> None:
    """Log which camera each interface talks to when the daemon starts; a mix of simulated
    and real interfaces is a warning that says which is which and how to make them one."""
    info = describe(config)
    log.info("camera backends (%s): %s", info.camera, summary(info))
    if info.camera == "mixed":
        log.warning(
            "camera backends mixed: %s; this is what the config asks for ([stream] backend, "
            '[sensor.usb_spi] backend); set them to "auto" to follow the link, or run '
            "`camd serve --hardware --serial PORT` for real hardware throughout",
            mixed_parts(info),
        )
