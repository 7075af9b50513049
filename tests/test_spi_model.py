"""The bit-level SPI bus model (firmware_models.spi): same-mode round trips, mismatched modes,
ignored frames and counters.

The corrupted values for mismatched modes are derived by hand in the comments from the
waveform rules in firmware_models/spi.py's docstring, not taken from the model.
"""

from __future__ import annotations

import itertools

import pytest
from hypothesis import given
from hypothesis import strategies as st

from camd.sensor.regmap import SpiLayout, load_register_map
from camd.sensor.spi_frame import encode_spi_frame
from firmware_models.spi import SpiMaster, SpiSlave


class DictTarget:
    """A register file as a dict; unmapped addresses read 0. Records every access."""

    def __init__(self, values: dict[int, int] | None = None) -> None:
        self.values: dict[int, int] = dict(values or {})
        self.log: list[tuple[str, int, int]] = []

    def spi_read(self, address: int) -> int:
        value = self.values.get(address, 0)
        self.log.append(("read", address, value))
        return value

    def spi_write(self, address: int, value: int) -> None:
        self.log.append(("write", address, value))
        self.values[address] = value


def hr400(mode: int) -> SpiLayout:
    """1 + 7 + 16 bits: R/W bit (read 1, write 0), 7-bit address, 16-bit data."""
    return SpiLayout(
        mode=mode,
        rw_bits=1,
        read_code=1,
        write_code=0,
        address_bits=7,
        data_bits=16,
        max_clock_hz=10e6,
    )


def mt9m001_like(mode: int) -> SpiLayout:
    """8 + 8 + 16 bits: a command byte (read 0x03, write 0x02), 8-bit address, 16-bit data."""
    return SpiLayout(
        mode=mode,
        rw_bits=8,
        read_code=0x03,
        write_code=0x02,
        address_bits=8,
        data_bits=16,
        max_clock_hz=1e6,
    )


LAYOUTS = {"hr400": hr400, "mt9m001": mt9m001_like}


def bus(
    layout: SpiLayout, master_mode: int | None = None, *, capture: str = "old"
) -> tuple[SpiMaster, SpiSlave, DictTarget]:
    target = DictTarget()
    slave = SpiSlave(layout, target, capture=capture)  # type: ignore[arg-type]
    return SpiMaster(layout, slave, mode=master_mode), slave, target


# -- same mode: bit exact ---------------------------------------------------------------------------


@pytest.mark.parametrize("capture", ["old", "new"])
@pytest.mark.parametrize("name", sorted(LAYOUTS))
@pytest.mark.parametrize("mode", [0, 1, 2, 3])
@given(data=st.data())
def test_same_mode_write_then_read_back_is_bit_exact(
    mode: int, name: str, capture: str, data: st.DataObject
) -> None:
    layout = LAYOUTS[name](mode)
    master, slave, target = bus(layout, capture=capture)
    accesses = data.draw(
        st.lists(
            st.tuples(
                st.integers(0, (1 << layout.address_bits) - 1),
                st.integers(0, (1 << layout.data_bits) - 1),
            ),
            min_size=1,
            max_size=8,
        )
    )
    expected: dict[int, int] = {}
    for address, value in accesses:
        master.write(address, value)
        expected[address] = value
        assert target.log[-1] == ("write", address, value)
        assert master.read(address) == value
        assert target.log[-1] == ("read", address, value)
    assert target.values == expected
    for address, value in expected.items():
        assert master.read(address) == value
    n = 2 * len(accesses) + len(expected)
    assert (master.transactions, slave.transactions) == (n, n)
    assert (slave.reads, slave.writes, slave.errors) == (
        len(accesses) + len(expected),
        len(accesses),
        0,
    )
    assert slave.same_edge_samples == 0  # equal modes never sample on the other side's shift edge


def test_shipped_hr400_layout_round_trips() -> None:
    layout = load_register_map("hr400").spi
    master, _, target = bus(layout)
    for address in range(1 << layout.address_bits):
        value = (address * 0x9E37) & 0xFFFF
        master.write(address, value)
        assert master.read(address) == value
    assert len(target.values) == 1 << layout.address_bits


def test_read_fetches_once_and_write_never_reads() -> None:
    master, slave, target = bus(hr400(0))
    target.values[0x12] = 0xA5A5
    assert master.read(0x12) == 0xA5A5
    master.write(0x13, 0x1234)
    assert target.log == [("read", 0x12, 0xA5A5), ("write", 0x13, 0x1234)]
    assert (slave.reads, slave.writes) == (1, 1)


def test_read_value_wider_than_data_bits_is_truncated() -> None:
    master, _, target = bus(hr400(0))
    target.values[1] = 0x1_BEEF  # a misbehaving register file: the bus has only 16 data bits
    assert master.read(1) == 0xBEEF


# -- mismatched modes: what real hardware sees ---------------------------------------------------------
# hr400 frame of write(0x55, 0xBEEF), MSB first:
#   0 | 1010101 | 1011111011101111
# hr400 frame of read(0x55):
#   1 | 1010101 | 0000000000000000


def test_cpha1_master_into_mode0_slave_writes_one_bit_late() -> None:
    # Master mode 1 puts bit i on MOSI at rising edge i; a mode-0 slave samples on rising edges,
    # capturing the bit from before the edge: idle 0, then bits 0..22. It decodes
    #   0 | 0101010 | 1101111101110111  = write of 0x2A (0x55 >> 1), value 0xDF77
    # (the address LSB 1 becomes the data MSB, the data LSB is lost).
    master, slave, target = bus(hr400(0), master_mode=1)
    master.write(0x55, 0xBEEF)
    assert target.log == [("write", 0x2A, 0xDF77)]
    assert (0x55 & 1) << 15 | 0xBEEF >> 1 == 0xDF77
    assert slave.errors == 0


def test_cpha1_master_into_mode0_slave_turns_a_read_into_a_write() -> None:
    # The read frame one bit late: 0 | 1101010 | 1000000000000000 = write 0x6A := 0x8000.
    master, _, target = bus(hr400(0), master_mode=1)
    target.values[0x55] = 0xBEEF
    assert master.read(0x55) == 0  # the slave drove nothing: it saw a write
    assert target.log == [("write", 0x6A, 0x8000)]
    assert target.values[0x6A] == 0x8000


def test_cpha0_master_reading_mode1_slave_gets_the_value_one_bit_late() -> None:
    # Master mode 0 holds MOSI across both edges, so the mode-1 slave (samples on falling edges)
    # decodes the read of 0x55 intact. It shifts bit j out at rising edge j; the master samples
    # at rising edge j the bit from before it, bit j - 1. The data slot thus shows the last
    # address-slot bit of the response (0) and data bits 15..1: 0xBEEF >> 1 = 0x5F77.
    master, slave, target = bus(hr400(1), master_mode=0)
    target.values[0x55] = 0xBEEF
    assert master.read(0x55) == 0x5F77
    assert target.log == [("read", 0x55, 0xBEEF)]
    assert slave.same_edge_samples == 48  # every edge of the 24 clocks is a race
    master.write(0x55, 0x1234)  # writes from a CPHA-0 master survive
    assert target.values[0x55] == 0x1234


def test_mode0_master_reading_mode2_slave_loses_the_data_msb() -> None:
    # Mode-2 slave: bit 0 at chip select, then the next bit at every rising edge; it samples
    # MOSI on falling edges. The master samples bit j at rising edge j, before the slave's
    # shift, so bits line up; but the data MSB (bit 8) must be shifted out at rising edge 7,
    # half a clock before the slave samples address bit 7 at falling edge 7 and fetches the
    # register. So the MSB reads 0: 0xBEEF -> 0x3EEF; a value with the MSB clear reads intact.
    master, _, target = bus(hr400(2), master_mode=0)
    target.values[0x55] = 0xBEEF
    target.values[0x56] = 0x3EEF
    assert master.read(0x55) == 0x3EEF
    assert master.read(0x56) == 0x3EEF


@pytest.mark.parametrize("name", sorted(LAYOUTS))
@pytest.mark.parametrize(
    ("master_mode", "slave_mode"),
    [(m, s) for m, s in itertools.product(range(4), repeat=2) if m != s],
)
def test_every_mismatch_fails_write_then_read_back(
    master_mode: int, slave_mode: int, name: str
) -> None:
    layout = LAYOUTS[name](slave_mode)
    master, _, target = bus(layout, master_mode=master_mode)
    address, value = 0x55, 0xBEEF
    master.write(address, value)
    landed = target.values.get(address) == value
    assert not (landed and master.read(address) == value)


@pytest.mark.parametrize(
    ("master_mode", "slave_mode"),
    [(m, s) for m, s in itertools.product(range(4), repeat=2) if m != s],
)
def test_mismatch_counts_races_only_when_sampling_edges_differ(
    master_mode: int, slave_mode: int
) -> None:
    # Modes 0/3 sample on rising edges, 1/2 on falling edges.
    master, slave, _ = bus(hr400(slave_mode), master_mode=master_mode)
    master.write(1, 1)
    rising = {0: True, 1: False, 2: False, 3: True}
    expected = 0 if rising[master_mode] == rising[slave_mode] else 48
    assert slave.same_edge_samples == expected


def test_new_capture_changes_which_mismatches_corrupt() -> None:
    # With "new" capture the mode-0 master's MOSI, sampled on its falling (shift) edges by a
    # mode-1 slave, is already the next bit: the slave sees the frame one bit early.
    # write(0x55, 0xBEEF) << 1 (a 0 shifted in): 1 | 0101011 | 0111110111011110 = a read of 0x2B.
    master, slave, target = bus(hr400(1), master_mode=0, capture="new")
    master.write(0x55, 0xBEEF)
    assert target.log == [("read", 0x2B, 0)]
    assert (slave.reads, slave.writes) == (1, 0)


# -- ignored frames ---------------------------------------------------------------------------------------


@pytest.mark.parametrize("length", [0, 1, 2, 4, 5])
@pytest.mark.parametrize("name", sorted(LAYOUTS))
def test_wrong_length_frames_are_ignored_and_counted(name: str, length: int) -> None:
    layout = LAYOUTS[name](0)
    if length == layout.frame_bytes:
        length += 1
    master, slave, target = bus(layout)
    target.values[0x01] = 0xFFFF
    mosi = (b"\xff" + bytes(7))[:length]  # starts with read bits set for either layout
    assert master.transfer(mosi) == bytes(length)
    assert target.log == []
    assert (slave.transactions, slave.errors, slave.reads, slave.writes) == (1, 1, 0, 0)
    # the bus still works afterwards
    assert master.read(0x01) == 0xFFFF
    assert slave.errors == 1


def test_unknown_command_code_is_ignored_and_counted() -> None:
    layout = mt9m001_like(0)
    master, slave, target = bus(layout)
    target.values[0x10] = 0xFFFF
    good = encode_spi_frame(layout, read=True, address=0x10)
    bad = b"\x55" + good[1:]  # command byte 0x55: neither read (0x03) nor write (0x02)
    assert master.transfer(bad) == bytes(layout.frame_bytes)
    assert master.transfer(b"\x55\x10\xbe\xef") == bytes(4)
    assert target.log == []
    assert (slave.transactions, slave.errors, slave.reads, slave.writes) == (2, 2, 0, 0)


# -- arguments and helpers ----------------------------------------------------------------------------------


def test_bad_modes_are_refused() -> None:
    layout = hr400(0)
    slave = SpiSlave(layout, DictTarget())
    with pytest.raises(ValueError, match="SPI mode must be 0, 1, 2 or 3"):
        slave.transfer(bytes(3), mode=4)
    with pytest.raises(ValueError, match="SPI mode must be 0, 1, 2 or 3"):
        SpiMaster(layout, slave, mode=-1)
    with pytest.raises(ValueError, match="capture must be 'old' or 'new'"):
        SpiSlave(layout, DictTarget(), capture="late")  # type: ignore[arg-type]
    assert slave.transactions == 0


def test_master_defaults_to_layout_mode_and_refuses_out_of_range_values() -> None:
    master, slave, _ = bus(hr400(3))
    assert master.mode == slave.mode == 3
    with pytest.raises(ValueError, match="does not fit 7 address bits"):
        master.write(0x80, 1)
    with pytest.raises(ValueError, match="does not fit 16 data bits"):
        master.write(0x01, 0x1_0000)
    assert master.transactions == 0


def test_bus_time() -> None:
    master, _, _ = bus(hr400(0))
    assert master.bus_time_s(10e6) == pytest.approx(2.4e-6)  # 24 clocks at 10 MHz
    master32, _, _ = bus(mt9m001_like(0))
    assert master32.bus_time_s(1e6) == pytest.approx(32e-6)  # 32 clocks at 1 MHz
    with pytest.raises(ValueError, match="exceeds the sensor's maximum"):
        master.bus_time_s(20e6)
    with pytest.raises(ValueError, match="must be > 0"):
        master.bus_time_s(0.0)
