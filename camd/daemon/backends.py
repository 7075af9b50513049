"""Real or simulated: the one place where the config chooses each device backend.

The daemon drives the same interfaces whatever the camera is: the command link on a serial
port (or the simulator's pty), the frame stream through pyusb, the sensor's registers through
a register bridge, and the simulator's own controls. Only here does camd import the host halves
of the simulated hardware (firmware_models): the pyusb backends of the simulated FX3 and
MCP2210, and the simulator process; everything else receives what these functions return.
"""

from __future__ import annotations

import logging
from typing import Any

from camd.daemon.config import Config
from camd.daemon.device import DeviceAccess
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
    if config.link.device != "sim":
        return None
    sim = config.sim
    return SimulatorProcess(
        config.sim_link_path,
        inject=sim.inject,
        hk_period_s=sim.hk_period_s,
        seed=sim.seed,
        profile=sim.profile,
        spi_socket=config.sim_spi_socket,
        usb_socket=config.sim_usb_socket,
        scene=sim.scene,
        frame_bank=sim.frame_bank,
        stage=config.stage.profile,
        defects=tuple(sim.defects),
    )


def simulator_control(device: DeviceAccess) -> SimulatorControl:
    """The simulator's controls, or their refusal on real hardware."""
    return FirmwareSimulator(device) if device.simulated else NoSimulator(device)


def frame_stream_backend(config: Config) -> Any:
    """The pyusb backend of the frame stream: the simulated FX3 (``stream.backend = "sim"``)
    on its socket, or None for libusb (real hardware)."""
    if config.stream.backend == "sim":
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
    if usb.backend == "sim":
        backend = mcp2210_backend(SocketSpiTarget(config.sim_spi_socket))
    return Mcp2210Bridge(
        regmap.spi,
        backend=backend,
        vendor_id=usb.vendor_id,
        product_id=usb.product_id,
        serial=usb.serial or None,
        cs_pin=usb.cs_pin,
    )
