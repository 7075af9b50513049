"""The sensor's SPI bus at the bit level: a master, a slave and the clock waveform between them.

One register access is one chip-select-low transaction of ``SpiLayout.frame_bits`` clocks,
framed by ``camd.sensor.spi_frame`` (command, address, data, MSB first). ``SpiSlave.transfer``
plays the whole transaction edge by edge: the master drives SCLK in *its* SPI mode, each side
samples and shifts on the edges its *own* mode names, so a master and a slave in different
modes see what real hardware would see.

The waveform (SPI modes: CPOL = mode >> 1 is the clock's idle level, CPHA = mode & 1):

- SCLK idles at the master's CPOL; each bit is a leading edge (away from idle) then a trailing
  edge (back to idle), so the edges alternate rising/falling, 2 x frame_bits of them.
- A device samples on rising edges in modes 0 and 3 and on falling edges in modes 1 and 2
  (CPHA 0: the leading edge of its own CPOL; CPHA 1: the trailing one) and shifts its output
  on the other kind of edge.
- CPHA 0: the first bit is on the line when chip select falls and each shift edge puts out
  the next one. CPHA 1: nothing is driven until the first shift edge, which puts out bit 0.
- Idle lines read 0: MOSI before a CPHA-1 master's first bit, MISO while the slave drives
  nothing (an undriven line with a pull-down) and every bit after the frame.
- A device reacts to edges only; it has no notion of the idle level (a slave whose CPOL
  differs from the master's just sees its leading and trailing edges swapped).

Same-edge capture. When modes differ, one side can sample on the very edge on which the other
shifts. Which bit it then captures is a race: ``capture="old"`` (the default) takes the bit
from before the edge, as on real boards at moderate clock rates, where the launching side's
clock-to-output delay exceeds the sampler's hold time (and as a synchronous RTL simulation
shows); ``capture="new"`` takes the freshly launched bit (e.g. a late-arriving clock at the
sampler). Either way such bits have no timing margin; they are counted in
``SpiSlave.same_edge_samples``. With equal modes no bit is ever captured on a shift edge.

What a mismatch does, in "old" capture (``master -> slave`` modes; "late" = every bit one
clock late with a 0 in front, i.e. the word shifted right by one):

- MOSI, what the slave decodes: late for 1->0, 1->3, 3->1 and 3->2 (a CPHA-1 master and a
  slave that samples on the master's leading edge), so it acts on a different address and
  value, finds no valid command, or even takes a read for a write; intact for all others
  (a CPHA-0 master holds each bit across both edges).
- MISO, what a read returns: the value >> 1 for 0->1, 0->3, 2->1 and 2->3; << 1 for 1->2 and
  3->0; for 0->2 and 2->0 the data MSB reads 0 (the slave would have to shift it out half a
  clock before it has sampled the last address bit); for the four cases with a late MOSI,
  whatever the late frame decodes as (with read code 1 / write code 0, a read arrives as a
  write of another register and zeros come back).

So every mismatch corrupts reads in general, and write-then-read-back catches it; writes of
a CPHA-0 master arrive intact at a slave in any mode (with zero hold margin when the slave
samples on the master's shift edge, see ``same_edge_samples``).

Frames whose length is not ``frame_bytes``, or whose command code is neither the read nor the
write code, are ignored (MISO all zeros, the register file untouched) and counted in ``errors``.
The length is checked before clocking: the model's slave, like sensors that count clocks and
drop a frame with the wrong count, never acts on a wrong-length frame, not even a read.
"""

from __future__ import annotations

from typing import Literal, Protocol

from camd.sensor.regmap import SpiLayout
from camd.sensor.spi_frame import (
    decode_spi_frame,
    decode_spi_response,
    encode_spi_frame,
    encode_spi_response,
)

Capture = Literal["old", "new"]


class RegisterTarget(Protocol):
    """The register file behind the SPI slave (the simulated sensor implements it).

    Must accept any address that fits the layout's address bits: a mismatched SPI mode can
    decode any of them. Unmapped addresses read 0 and ignore writes, as on real sensors.
    """

    def spi_read(self, address: int) -> int:
        """The register's value for a read (the slave keeps the low ``data_bits``)."""
        ...

    def spi_write(self, address: int, value: int) -> None:
        """Store a write (the register file applies its own access rules)."""
        ...


def _check_mode(mode: int) -> int:
    if isinstance(mode, bool) or not isinstance(mode, int) or not 0 <= mode <= 3:
        raise ValueError(f"SPI mode must be 0, 1, 2 or 3, got {mode!r}")
    return mode


def _samples_on_rising(mode: int) -> bool:
    """Modes 0 and 3 sample on rising edges, modes 1 and 2 on falling edges."""
    return ((mode >> 1) ^ (mode & 1)) == 0


def _bits(word: int, count: int) -> list[int]:
    """``word`` as ``count`` bits, most significant first."""
    return [(word >> (count - 1 - i)) & 1 for i in range(count)]


class SpiSlave:
    """The sensor's SPI slave in mode ``layout.mode``, in front of a register file.

    ``transfer`` runs one transaction clocked by a master in any mode (module docstring). On
    a read the slave calls ``target.spi_read`` as soon as it has sampled the address and
    shifts the value out in the data phase (MISO = ``encode_spi_response``); a write reaches
    ``target.spi_write`` when chip select rises after a full frame with the write code.

    Counters: ``transactions`` (every transfer), ``reads`` and ``writes`` (accesses that reached
    the target), ``errors`` (frames ignored: wrong length or unknown command code),
    ``same_edge_samples`` (bits either side captured on the edge the other side shifted on).
    """

    def __init__(
        self, layout: SpiLayout, target: RegisterTarget, *, capture: Capture = "old"
    ) -> None:
        if capture not in ("old", "new"):
            raise ValueError(f"capture must be 'old' or 'new', got {capture!r}")
        self.layout = layout
        self.target = target
        self.capture: Capture = capture
        self.transactions = 0
        self.reads = 0
        self.writes = 0
        self.errors = 0
        self.same_edge_samples = 0

    @property
    def mode(self) -> int:
        """The slave's own SPI mode (from the register map's layout)."""
        return self.layout.mode

    def transfer(self, mosi: bytes, *, mode: int) -> bytes:
        """One chip-select-low transaction; returns the MISO bytes the master sampled.

        ``mode`` is the master's SPI mode: it sets the clock's idle level and when the master
        shifts MOSI and samples MISO. ``len(mosi)`` bytes are clocked, 8 clocks per byte.
        """
        _check_mode(mode)
        self.transactions += 1
        layout = self.layout
        if len(mosi) != layout.frame_bytes:
            self.errors += 1
            return bytes(len(mosi))
        received, miso_word, access_ok = self._clock(mode, int.from_bytes(mosi, "big"))
        if not access_ok:
            self.errors += 1
            return bytes(layout.frame_bytes)
        access = decode_spi_frame(layout, received.to_bytes(layout.frame_bytes, "big"))
        if access is not None and not access.read:
            self.target.spi_write(access.address, access.data)
            self.writes += 1
        return miso_word.to_bytes(layout.frame_bytes, "big")

    def _clock(self, master_mode: int, mosi_word: int) -> tuple[int, int, bool]:
        """Play the edges of one frame: (word the slave sampled, word the master sampled, ok).

        ``ok`` is False when the slave found no valid command code (it then drove nothing).
        """
        layout = self.layout
        n_bits = layout.frame_bits
        header_bits = layout.rw_bits + layout.address_bits
        mosi_bits = _bits(mosi_word, n_bits)
        master_rising = _samples_on_rising(master_mode)
        slave_rising = _samples_on_rising(layout.mode)
        old = self.capture == "old"

        # CPHA 0 devices put bit 0 on the line at chip select; CPHA 1 devices at their first
        # shift edge. ``*_next`` is the index of the bit the next shift edge puts out.
        master_cpha0 = (master_mode & 1) == 0
        slave_cpha0 = (layout.mode & 1) == 0
        mosi = mosi_bits[0] if master_cpha0 else 0
        master_next = 1 if master_cpha0 else 0
        miso_bits = [0] * n_bits  # zeros until a read has fetched the register
        miso = 0  # nothing in the first slot of any response (the command slot)
        slave_next = 1 if slave_cpha0 else 0

        rx_slave = 0
        rx_slave_count = 0
        rx_master = 0
        command_ok = True
        level = master_mode >> 1
        for _ in range(2 * n_bits):
            level ^= 1
            rising = level == 1
            master_samples = rising == master_rising
            slave_samples = rising == slave_rising
            if master_samples != slave_samples:
                # The other side shifts on this very edge: the sampled bit has no margin.
                self.same_edge_samples += 1
            before = (mosi, miso)
            # Shift edges: each side that does not sample on this edge puts out its next bit.
            if not master_samples:
                mosi = mosi_bits[master_next] if master_next < n_bits else 0
                master_next += 1
            if not slave_samples:
                miso = miso_bits[slave_next] if slave_next < n_bits else 0
                slave_next += 1
            sampled_mosi, sampled_miso = before if old else (mosi, miso)
            if master_samples:
                rx_master = (rx_master << 1) | sampled_miso
            if slave_samples:
                rx_slave = (rx_slave << 1) | sampled_mosi
                rx_slave_count += 1
                if rx_slave_count == layout.rw_bits:
                    command_ok = rx_slave in (layout.read_code, layout.write_code)
                elif rx_slave_count == header_bits and command_ok:
                    miso_bits = self._fetch(rx_slave, miso_bits)
        return rx_slave, rx_master, command_ok

    def _fetch(self, header: int, miso_bits: list[int]) -> list[int]:
        """After the address phase: for a read, fetch the register and load the MISO bits."""
        layout = self.layout
        padded = (header << layout.data_bits).to_bytes(layout.frame_bytes, "big")
        access = decode_spi_frame(layout, padded)
        if access is None or not access.read:
            return miso_bits
        value = self.target.spi_read(access.address) & ((1 << layout.data_bits) - 1)
        self.reads += 1
        response = int.from_bytes(encode_spi_response(layout, value), "big")
        return _bits(response, layout.frame_bits)


class SpiMaster:
    """The FPGA's (or a bridge's) SPI master: register reads and writes through a ``SpiSlave``.

    ``mode`` defaults to the layout's mode; set another to model a misconfigured master.
    ``transactions`` counts the transfers this master started.
    """

    def __init__(self, layout: SpiLayout, slave: SpiSlave, *, mode: int | None = None) -> None:
        self.layout = layout
        self.slave = slave
        self.mode = layout.mode if mode is None else _check_mode(mode)
        self.transactions = 0

    def transfer(self, mosi: bytes) -> bytes:
        """One raw transaction of ``mosi`` (any length) in the master's mode; the MISO bytes."""
        self.transactions += 1
        return self.slave.transfer(mosi, mode=self.mode)

    def read(self, address: int) -> int:
        """Read a register: a read frame out, the value from the data slot of MISO."""
        frame = encode_spi_frame(self.layout, read=True, address=address)
        return decode_spi_response(self.layout, self.transfer(frame))

    def write(self, address: int, value: int) -> None:
        """Write a register: one write frame (the slave answers nothing)."""
        self.transfer(encode_spi_frame(self.layout, read=False, address=address, data=value))

    def bus_time_s(self, clock_hz: float) -> float:
        """Time SCLK runs for one frame at ``clock_hz``: ``frame_bits / clock_hz``.

        Chip-select setup and hold are not included. Refuses a clock above the layout's
        ``max_clock_hz`` (the sensor's limit).
        """
        if isinstance(clock_hz, bool) or not isinstance(clock_hz, int | float) or not clock_hz > 0:
            raise ValueError(f"SPI clock must be > 0 Hz, got {clock_hz!r}")
        if clock_hz > self.layout.max_clock_hz:
            raise ValueError(
                f"SPI clock {clock_hz:g} Hz exceeds the sensor's maximum "
                f"{self.layout.max_clock_hz:g} Hz"
            )
        return self.layout.frame_bits / clock_hz
