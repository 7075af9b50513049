"""The simulated sensor's register file behaves as silicon: access rules, hold, reset, status."""

from __future__ import annotations

import pytest

from camd.sensor.regmap import RegisterMap, load_register_map
from firmware_models.sensor import SensorModel

HR400 = load_register_map("hr400")
IBIS5 = load_register_map("ibis5")
MT9M001 = load_register_map("mt9m001")


@pytest.fixture
def hr400() -> SensorModel:
    return SensorModel(HR400, seed=1)


@pytest.mark.parametrize("regmap", [HR400, IBIS5, MT9M001], ids=lambda m: m.sensor)
def test_power_on_values_are_the_reset_values(regmap: RegisterMap) -> None:
    model = SensorModel(regmap)
    for reg in regmap.registers:
        expected = 0 if not reg.readable else reg.reset
        assert model.spi_read(reg.address) == expected, reg.name
        assert model.register_value(reg.name) == reg.reset


def test_read_only_write_is_ignored_and_flags_an_spi_error(hr400: SensorModel) -> None:
    hr400.spi_write(0x00, 0x1234)  # CHIP_ID
    assert hr400.spi_read(0x00) == 0x0400
    assert hr400.value("FLAGS.spi_error") == 1
    assert hr400.writes[0x00] == 1  # the access reached the sensor, and was ignored
    hr400.spi_write(0x02, 0b100)  # W1C: clear it
    assert hr400.value("FLAGS.spi_error") == 0


def test_parts_without_an_error_flag_just_ignore_read_only_writes() -> None:
    model = SensorModel(MT9M001)
    model.spi_write(0x00, 0)
    assert model.spi_read(0x00) == 0x8411


def test_write_only_reads_zero_but_unknown_addresses_are_harmless(hr400: SensorModel) -> None:
    hr400.spi_write(0x03, 0x1234)  # SOFT_RESET, not the key
    assert hr400.spi_read(0x03) == 0
    assert hr400.register_value("SOFT_RESET") == 0x1234
    assert hr400.spi_read(0x7E) == 0
    hr400.spi_write(0x7E, 0xFFFF)
    assert hr400.reads[0x7E] == 1 and hr400.writes[0x7E] == 1


def test_w1c_clears_only_the_bits_written_as_one(hr400: SensorModel) -> None:
    hr400.raise_flag("FLAGS.overexposure")
    hr400.raise_flag("FLAGS.sync_error")
    assert hr400.register_value("FLAGS") == 0b011
    hr400.spi_write(0x02, 0b001)
    assert hr400.register_value("FLAGS") == 0b010
    hr400.spi_write(0x02, 0b000)
    assert hr400.register_value("FLAGS") == 0b010


def test_soft_reset_key_restores_every_register(hr400: SensorModel) -> None:
    hr400.spi_write(0x10, 10)
    hr400.spi_write(0x21, 7)
    hr400.spi_write(0x03, 0x1234)  # a wrong key does nothing
    assert hr400.register_value("WIN_START") == 10
    hr400.spi_write(0x03, 0x5A5A)
    assert hr400.register_value("WIN_START") == 757
    assert hr400.register_value("OFFSET") == 100


def test_mt9m001_reset_bit_resets_and_reads_back() -> None:
    model = SensorModel(MT9M001)
    model.spi_write(0x09, 100)  # shutter width
    model.spi_write(0x0D, 1)
    assert model.register_value("SHUTTER_WIDTH") == 0x0419
    assert model.spi_read(0x0D) == 1
    model.spi_write(0x0D, 0)
    assert model.spi_read(0x0D) == 0


def test_group_hold_latches_and_applies_together(hr400: SensorModel) -> None:
    hold, hi, lo = 0x04, 0x12, 0x13
    hr400.spi_write(hold, 1)
    hr400.spi_write(hi, 0x1)
    hr400.spi_write(lo, 0x2345)
    # Nothing in force yet: reads and the exposure keep the old value.
    assert hr400.spi_read(lo) == 2 and hr400.spi_read(hi) == 0
    assert hr400.exposure_lines == 2
    hr400.spi_write(hold, 0)
    assert hr400.exposure_lines == 0x12345
    assert hr400.value("EXPOSURE") == 0x12345


def test_writes_without_hold_apply_at_once(hr400: SensorModel) -> None:
    hr400.spi_write(0x13, 7)
    assert hr400.exposure_lines == 7


def test_pulse_bits_act_and_read_back_zero() -> None:
    model = SensorModel(MT9M001)
    model.spi_write(0x0B, 0b11)  # restart (pulse) + pause
    assert model.spi_read(0x0B) == 0b10


def test_global_gain_writes_all_four_colour_gains() -> None:
    model = SensorModel(MT9M001)
    model.spi_write(0x35, 0x20)
    assert [model.spi_read(a) for a in (0x2B, 0x2C, 0x2D, 0x2E)] == [0x20] * 4
    model.spi_write(0x2B, 0x10)
    assert model.spi_read(0x35) == 0x10  # reads the green1 gain
    assert model.gain == 0x10


def test_frame_counter_advances_and_wraps(hr400: SensorModel) -> None:
    for _ in range(257):
        hr400.note_frame()
    assert hr400.value("STATUS.frame_count") == 1
    hr400.set_status("STATUS.running", 1)
    assert hr400.spi_read(0x01) == 0x0101
    with pytest.raises(ValueError, match="is a setting, not status"):
        hr400.set_status("OFFSET.dn", 1)
    with pytest.raises(ValueError, match="not a write-1-to-clear flag"):
        hr400.raise_flag("STATUS.running")


def test_power_on_reset_keeps_the_access_counts(hr400: SensorModel) -> None:
    hr400.spi_write(0x21, 5)
    hr400.power_on_reset()
    assert hr400.register_value("OFFSET") == 100
    assert hr400.writes[0x21] == 1


def test_roles_and_timing_follow_the_registers(hr400: SensorModel) -> None:
    assert (hr400.window_start_row, hr400.window_rows, hr400.exposure_lines) == (757, 534, 2)
    assert (hr400.gain, hr400.offset, hr400.readout_mode, hr400.test_pattern) == (
        "x1",
        100,
        "rolling",
        "off",
    )
    assert hr400.line_period_s == pytest.approx(513 / 25e6, rel=1e-12)
    hr400.spi_write(0x11, 100)
    hr400.spi_write(0x14, 250)  # back path: 250 clocks = 10 us
    timing = hr400.timing()
    assert timing.window_rows == 100 and timing.max_stages == 100
    assert timing.back_path_s == pytest.approx(10e-6, rel=1e-12)
    assert timing.frame_period_s == pytest.approx(100 * 20.52e-6 + 10e-6, rel=1e-12)
    assert timing.tdi_line_period_s == timing.frame_period_s


def test_mt9m001_counts_rows_from_the_size_register() -> None:
    model = SensorModel(MT9M001)
    model.spi_write(0x03, 533)  # 534 rows
    model.spi_write(0x04, 639)  # 640 columns
    model.spi_write(0x05, 100)  # 100 clocks of horizontal blanking
    assert model.window_rows == 534
    assert model.line_period_s == pytest.approx((640 + 244 + 100 - 19) / 48e6, rel=1e-12)
    model.spi_write(0x05, 5)  # below the minimum: taken as 19
    assert model.line_period_s == pytest.approx((640 + 244) / 48e6, rel=1e-12)


def test_register_value_by_address_text(hr400: SensorModel) -> None:
    assert hr400.register_value("0x10") == 757
    assert hr400.register_value(0x10) == 757
    assert hr400.register_value("win_start") == 757
