"""The FPGA register bridge: sensor registers through REG_* commands on the RS-422 link.

The camera's FPGA runs the SPI master (docs/physics.md §3, §9); the host sends REG_READ, REG_WRITE and
REG_WRITE_BURST. A burst is executed by the FPGA as one uninterrupted SPI sequence, which is what
makes a group-hold write atomic. The link's at-most-once execution means a write retried after
a lost acknowledge is not applied twice. Link errors (LinkDown, CommandTimeout,
CommandRejected) pass through unchanged for the caller to report.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence

from camd.link import CommandLink
from camd.sensor.bridge import RegisterBridge

MAX_BURST_PAIRS = 255  # REG_WRITE_BURST carries at most 1020 bytes of 4-byte pairs


class FpgaBridge(RegisterBridge):
    """Register access through the camera FPGA's SPI master, over ``link``."""

    name = "fpga"

    def __init__(self, link: CommandLink) -> None:
        self.link = link

    def read(self, address: int) -> int:
        return int(self.link.request("REG_READ", address=address).values["value"])

    def write(self, address: int, value: int) -> None:
        self.link.request("REG_WRITE", address=address, value=value)

    def write_burst(self, writes: Sequence[tuple[int, int]]) -> None:
        """Write the pairs with one REG_WRITE_BURST per 255 (atomic within each command)."""
        for start in range(0, len(writes), MAX_BURST_PAIRS):
            chunk = writes[start : start + MAX_BURST_PAIRS]
            pairs = b"".join(struct.pack(">HH", address, value) for address, value in chunk)
            self.link.request("REG_WRITE_BURST", pairs=pairs)
