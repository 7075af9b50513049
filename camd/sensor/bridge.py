"""The register bridge interface: how the host reaches the sensor's registers.

Two implementations: ``FpgaBridge`` (REG_READ / REG_WRITE / REG_WRITE_BURST over the RS-422
command link; the camera's FPGA runs the SPI master) and ``Mcp2210Bridge`` (a USB-SPI bridge chip
driven through pyusb, the host framing each SPI access itself). ``camd.sensor.SensorRegisters``
works on either. Bridges move raw register values by address; names, ranges and access rules
are checked above them, against the register map.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Sequence


class BridgeError(RuntimeError):
    """The bridge could not carry out an access; the message says what happened and what to do."""


class RegisterBridge(ABC):
    """Raw register access by address."""

    name: str = "bridge"

    @abstractmethod
    def read(self, address: int) -> int:
        """Read one register."""

    @abstractmethod
    def write(self, address: int, value: int) -> None:
        """Write one register."""

    def write_burst(self, writes: Sequence[tuple[int, int]]) -> None:
        """Write (address, value) pairs in order, with nothing else on the bus in between.

        The default writes one by one; bridges that can do better (the FPGA executes a whole
        burst from one command) override it.
        """
        for address, value in writes:
            self.write(address, value)

    def close(self) -> None:  # noqa: B027 - optional hook
        """Release the bridge's resources."""

    def __enter__(self) -> RegisterBridge:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
