"""Deliberate defects of the simulated camera, for proving that conformance checks can fail.

Each defect is a switch, off by default, named for what a faulty unit would do, and
implemented where the real firmware would have the fault (the FPGA's command processor, its
SPI read path, its sequencer, the FX3's framing, the wheel's exposure scheduler). A defect
that is off costs one attribute test on its path. ``camd conform`` (docs/conformance.md) runs
the suite against each and expects exactly the checks listed there to fail.

Turned on with ``python -m firmware_models --defect NAME`` (repeatable) or the daemon's
``[sim] defects = [...]`` (docs/config.md).
"""

from __future__ import annotations

from dataclasses import dataclass, fields

# name -> what the unit does wrong (docs/conformance.md has the checks each makes fail)
DEFECTS: dict[str, str] = {
    "stream_crc_polynomial": "the FX3 computes each frame's payload CRC with the Castagnoli "
    "polynomial (CRC-32C, 0x1EDC6F41) instead of CRC-32/ISO-HDLC; the header CRC is right",
    "replay_executes": "the FPGA executes a retried command frame (same sequence number and "
    "bytes) again instead of answering it from its at-most-once record",
    "register_readback_off_by_one": "REG_READ of one register (the sensor's `offset` role, "
    "else its `gain` role) answers the value plus one; the register holds what was written",
    "stream_counter_skip": "the FX3 skips one frame counter value every 4th frame: no frame "
    "is missing, but the counters jump",
    "frame_period_5pct": "the sequencer's line clock runs 5 % slow: frames are 5 % further "
    "apart (header timestamps) than the registers and the header's line_period_ns say",
    "wheel_ignores_delay": "a wheel acquisition exposes at each channel's entry pulse even "
    "with delay compensation on (WHEEL_GET and WHEEL_ACQUIRE still report T_delay)",
    "header_line_period_1pct": "the FPGA stamps each frame header's line_period_ns 1 % above "
    "the frame period the registers set; the frames themselves (timestamps) keep that period",
}

FRAME_PERIOD_FACTOR = 1.05  # frame_period_5pct
HEADER_PERIOD_FACTOR = 1.01  # header_line_period_1pct
COUNTER_SKIP_EVERY = 4  # stream_counter_skip: every 4th frame's counter jumps by one more


@dataclass(frozen=True, slots=True)
class Defects:
    """Which defects are on (all off by default)."""

    stream_crc_polynomial: bool = False
    replay_executes: bool = False
    register_readback_off_by_one: bool = False
    stream_counter_skip: bool = False
    frame_period_5pct: bool = False
    wheel_ignores_delay: bool = False
    header_line_period_1pct: bool = False

    @classmethod
    def parse(cls, names: list[str] | tuple[str, ...]) -> Defects:
        """The defects named; ValueError naming the valid ones for an unknown name."""
        unknown = [name for name in names if name not in DEFECTS]
        if unknown:
            raise ValueError(f"unknown defect(s) {', '.join(unknown)}; valid: {', '.join(DEFECTS)}")
        return cls(**{name: True for name in names})

    @property
    def names(self) -> list[str]:
        """The defects that are on."""
        return [f.name for f in fields(self) if getattr(self, f.name)]


NONE = Defects()


def _crc32c_table() -> list[int]:
    table = []
    for byte in range(256):
        crc = byte
        for _ in range(8):
            crc = (crc >> 1) ^ 0x82F63B78 if crc & 1 else crc >> 1  # reflected 0x1EDC6F41
        table.append(crc)
    return table


_CRC32C = _crc32c_table()


def crc32c(data: bytes | memoryview) -> int:
    """CRC-32C (Castagnoli): the wrong polynomial of ``stream_crc_polynomial``. Pure Python
    and slow (about 10 MB/s), paid only while that defect is on."""
    crc = 0xFFFFFFFF
    table = _CRC32C
    for byte in bytes(data):
        crc = (crc >> 8) ^ table[(crc ^ byte) & 0xFF]
    return crc ^ 0xFFFFFFFF
