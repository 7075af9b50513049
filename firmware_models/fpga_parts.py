"""The parts of the simulated camera that the FPGA's command groups drive (``firmware_models.fpga``).

``FpgaModel`` builds the parts and hands itself to every group of command handlers as their
``DeviceParts``; a group keeps it (``PartsGroup``) and reaches what it drives through it, so the
wiring is written once instead of a constructor per group that copies its share of the parts.
"""

from __future__ import annotations

from typing import Protocol

from camd.protocol import Decoder
from firmware_models.camera import CameraModel
from firmware_models.defects import Defects
from firmware_models.fpga_commands import DeviceState
from firmware_models.fpga_link import CommandLink
from firmware_models.fx3 import StreamEngine
from firmware_models.housekeeping import HousekeepingModel
from firmware_models.imaging import ImagingPipeline
from firmware_models.inject import FaultInjector
from firmware_models.motor import MotorController
from firmware_models.sensor import SensorModel
from firmware_models.sensor_link import SensorLink
from firmware_models.spi import SpiMaster, SpiSlave
from firmware_models.wheel import FilterWheel


class DeviceParts(Protocol):
    """What the command groups drive of one camera (``FpgaModel`` has them all): ``state`` the
    groups share (``fpga_commands``), ``link`` the command link (SIM_FAIL_NEXT is armed on it),
    ``receiver`` the device's frame decoder (its CRC errors are GET_LINK_STATS'), ``injector`` the
    line's fault injector, ``spi`` the FPGA's SPI master and ``spi_slave`` the sensor's end,
    ``imaging_path`` what makes the frames that ``stream`` sends, ``defects`` the firmware defects
    the model was built with."""

    state: DeviceState
    link: CommandLink
    receiver: Decoder
    housekeeping: HousekeepingModel
    injector: FaultInjector
    camera: CameraModel
    sensor: SensorModel
    spi: SpiMaster
    spi_slave: SpiSlave
    sensor_link: SensorLink
    imaging_path: ImagingPipeline
    stream: StreamEngine
    motor: MotorController
    wheel: FilterWheel
    defects: Defects


class PartsGroup:
    """A group of command handlers that drives some of the device's ``parts``."""

    def __init__(self, parts: DeviceParts) -> None:
        self.parts = parts
