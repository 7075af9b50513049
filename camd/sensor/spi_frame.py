"""Sans-I/O framing of one register access on the sensor's SPI bus (see ``SpiLayout``).

Used by every SPI master: the simulated FPGA's SPI master, the USB-SPI bridge on the host and
the simulated sensor's SPI slave, so that the frame layout exists once.
"""

from __future__ import annotations

from dataclasses import dataclass

from camd.sensor.regmap import SpiLayout


@dataclass(frozen=True, slots=True)
class SpiAccess:
    """One decoded MOSI frame: a read or write of ``address`` (``data`` is 0 for a read)."""

    read: bool
    address: int
    data: int


def encode_spi_frame(layout: SpiLayout, *, read: bool, address: int, data: int = 0) -> bytes:
    """The MOSI bytes of one access: command, address, data, most significant bit first."""
    if not 0 <= address < 1 << layout.address_bits:
        raise ValueError(f"address 0x{address:X} does not fit {layout.address_bits} address bits")
    if not 0 <= data < 1 << layout.data_bits:
        raise ValueError(f"data 0x{data:X} does not fit {layout.data_bits} data bits")
    if read and data:
        raise ValueError("a read frame carries no data")
    code = layout.read_code if read else layout.write_code
    word = (((code << layout.address_bits) | address) << layout.data_bits) | data
    return word.to_bytes(layout.frame_bytes, "big")


def decode_spi_frame(layout: SpiLayout, mosi: bytes) -> SpiAccess | None:
    """Decode a MOSI frame; None when the command code is neither read nor write."""
    if len(mosi) != layout.frame_bytes:
        raise ValueError(f"an SPI frame is {layout.frame_bytes} bytes, got {len(mosi)}")
    word = int.from_bytes(mosi, "big")
    data = word & ((1 << layout.data_bits) - 1)
    address = (word >> layout.data_bits) & ((1 << layout.address_bits) - 1)
    code = word >> (layout.data_bits + layout.address_bits)
    if code == layout.read_code:
        return SpiAccess(True, address, 0)
    if code == layout.write_code:
        return SpiAccess(False, address, data)
    return None


def encode_spi_response(layout: SpiLayout, data: int) -> bytes:
    """The MISO bytes a sensor returns for a read of ``data`` (zeros outside the data slot)."""
    return (data & ((1 << layout.data_bits) - 1)).to_bytes(layout.frame_bytes, "big")


def decode_spi_response(layout: SpiLayout, miso: bytes) -> int:
    """The register value in the data slot of a read's MISO bytes."""
    if len(miso) != layout.frame_bytes:
        raise ValueError(f"an SPI frame is {layout.frame_bytes} bytes, got {len(miso)}")
    return int.from_bytes(miso, "big") & ((1 << layout.data_bits) - 1)
