"""Register maps: the shipped ones validate; corrupted copies fail naming file, line and register."""

from __future__ import annotations

from pathlib import Path

import pytest

from camd.sensor.regmap import (
    ROLES,
    FieldSpec,
    RegisterMap,
    RegisterMapError,
    RegisterSpec,
    RegisterValueError,
    list_sensors,
    load_register_map,
)
from camd.sensor.timing_view import reset_timing

ROOT = Path(__file__).resolve().parents[1]
SENSORS = ROOT / "config" / "sensors"
REQUIRED_ROLES = (
    "window_start_row",
    "window_rows",
    "exposure_lines",
    "gain",
    "offset",
    "readout_mode",
    "test_pattern",
)


def test_the_five_sensor_maps_are_shipped() -> None:
    assert {"ftf5066", "hr400", "ibis5", "mt9m001", "uvccd"} <= set(list_sensors())


@pytest.mark.parametrize("sensor", ["ftf5066", "hr400", "ibis5", "mt9m001", "uvccd"])
def test_every_shipped_map_loads_with_the_roles_the_timing_needs(sensor: str) -> None:
    regmap = load_register_map(sensor)
    assert regmap.sensor == sensor
    for role in REQUIRED_ROLES:
        assert regmap.role(role) is not None, role
        regmap.resolve(regmap.roles[role])  # the target exists
    assert set(regmap.roles) <= set(ROLES)
    # A map loaded by path is the same map.
    assert load_register_map(SENSORS / f"{sensor}.toml") == regmap


def test_modelled_flags_and_clock_roles() -> None:
    assert load_register_map("hr400").modelled is True
    assert load_register_map("ibis5").modelled is True
    assert load_register_map("mt9m001").modelled is False  # from the public datasheet
    assert load_register_map("hr400").role("back_path") == "BACK_PATH"
    assert load_register_map("ibis5").role("row_blanking") == "ROW_BLANK.clocks"
    assert load_register_map("ibis5").role("back_path") == "BACK_PATH.clocks"
    assert load_register_map("mt9m001").role("row_blanking") == "HBLANK.clocks"
    assert load_register_map("uvccd").modelled is True  # a CCD has no register file of its own
    assert load_register_map("uvccd").role("row_blanking") == "ROW_BLANK.clocks"


def test_mt9m001_follows_the_datasheet() -> None:
    m = load_register_map("mt9m001")
    expected = {
        0x00: ("CHIP_VERSION", "ro", 0x8411),
        0x01: ("ROW_START", "rw", 0x000C),
        0x02: ("COL_START", "rw", 0x0014),
        0x03: ("ROW_SIZE", "rw", 0x03FF),
        0x04: ("COL_SIZE", "rw", 0x04FF),
        0x05: ("HBLANK", "rw", 0x0009),
        0x06: ("VBLANK", "rw", 0x0019),
        0x07: ("OUTPUT_CONTROL", "rw", 0x0002),
        0x09: ("SHUTTER_WIDTH", "rw", 0x0419),
        0x0B: ("RESTART", "rw", 0x0000),
        0x0C: ("SHUTTER_DELAY", "rw", 0x0000),
        0x0D: ("RESET", "rw", 0x0000),
        0x1E: ("READ_OPTIONS1", "rw", 0x8000),
        0x20: ("READ_OPTIONS2", "rw", 0x1104),
        0x2B: ("GAIN_GREEN1", "rw", 0x0008),
        0x2C: ("GAIN_BLUE", "rw", 0x0008),
        0x2D: ("GAIN_RED", "rw", 0x0008),
        0x2E: ("GAIN_GREEN2", "rw", 0x0008),
        0x35: ("GLOBAL_GAIN", "rw", 0x0008),
        0x5F: ("CAL_THRESHOLD", "rw", 0x0904),
        0x60: ("OFFSET_G1", "rw", 0x0000),
        0x62: ("CAL_CTRL", "rw", 0x0498),
        0xF1: ("CHIP_ENABLE", "rw", 0x0001),
    }
    for address, (name, access, reset) in expected.items():
        reg = m.register(address)
        assert (reg.name, reg.access, reg.reset) == (name, access, reset), hex(address)
    # The FPGA's bridge framing: command byte, 8-bit address, 16-bit data.
    assert (m.spi.rw_bits, m.spi.read_code, m.spi.write_code) == (8, 1, 0)
    assert (m.spi.address_bits, m.spi.data_bits, m.spi.frame_bits) == (8, 16, 32)
    assert m.timing.clock_hz == 48e6
    assert m.register("SHUTTER_WIDTH").field("rows").bits == (13, 0)
    assert "two-wire" in m.spi.doc


def test_reset_timing_matches_the_papers_and_the_datasheet() -> None:
    # HR400: 513 sequencer clocks at 25 MHz = 20.52 us; n = 2, k = 534 -> 537 lines.
    hr400 = reset_timing(load_register_map("hr400"))
    assert hr400.line_period_s == pytest.approx(20.52e-6, rel=1e-12)
    assert hr400.frame_time_s == pytest.approx(11.01924e-3, rel=1e-12)
    # IBIS5: t_rb 3.5 us + 1280 pixels / 40 MHz = 35.5 us (TAO12 eq 4).
    assert reset_timing(load_register_map("ibis5")).line_period_s == pytest.approx(35.5e-6)
    # MT9M001 datasheet Table 3: 1524 pixel clocks = 31.75 us at the reset values.
    mt9m001 = reset_timing(load_register_map("mt9m001"))
    assert mt9m001.line_period_s == pytest.approx(1524 / 48e6, rel=1e-12)
    assert mt9m001.line_period_s == pytest.approx(31.75e-6, rel=1e-12)
    assert (mt9m001.window_start_row, mt9m001.window_rows) == (12, 1024)  # ROW_SIZE + 1


# -- corrupted copies ---------------------------------------------------------------------------


def corrupt(tmp_path: Path, sensor: str, old: str, new: str) -> tuple[Path, int]:
    """A copy of a shipped map with ``old`` replaced once; returns (path, line of the change)."""
    text = (SENSORS / f"{sensor}.toml").read_text(encoding="utf-8")
    assert text.count(old) >= 1, old
    changed = text.replace(old, new, 1)
    line = text[: text.index(old)].count("\n") + 1
    path = tmp_path / f"{sensor}.toml"
    path.write_text(changed, encoding="utf-8")
    return path, line


CORRUPTIONS = [
    (
        "overlapping fields",
        "hr400",
        '{ name = "digital", bits = [7, 0]',
        '{ name = "digital", bits = [8, 0]',
        "register GAIN: field 'digital' bits 8..0 overlap field 'analog' bits 9..8",
    ),
    (
        "field beyond the width",
        "hr400",
        '{ name = "dn", bits = [11, 0]',
        '{ name = "dn", bits = [16, 0]',
        "register OFFSET: field 'dn' bits 16..0 exceed the register's 16 bits",
    ),
    (
        "reset value out of width",
        "hr400",
        "reset = 534",
        "reset = 0x10000",
        "register WIN_ROWS: reset value 0x10000 does not fit the register's 16 bits",
    ),
    (
        "reset value out of a field's range",
        "hr400",
        "reset = 100",
        "reset = 1100",
        "register OFFSET: reset value 0x44C is invalid: field 'dn': 1100 is out of range "
        "(valid: 0 .. 1023 (0 .. 1023 DN))",
    ),
    (
        "reset value not in a field's enum",
        "hr400",
        'reset = 0x0000\ndoc = "Readout mode."',
        'reset = 0x0002\ndoc = "Readout mode."',
        "register READOUT: reset value 0x2 is invalid: field 'mode': 2 is not valid; use one of "
        "rolling (0), binning_2x2 (1)",
    ),
    (
        "reset bits outside the fields",
        "hr400",
        "reset = 0x01FF",
        "reset = 0x03FF",
        "register LVDS_CTRL: reset value 0x3FF sets bits (0x200) that no field covers",
    ),
    (
        "duplicate register name",
        "hr400",
        'name = "OFFSET"',
        'name = "GAIN"',
        "register GAIN: duplicate register name (also entry #11 of [[registers]])",
    ),
    (
        "duplicate address",
        "hr400",
        "address = 0x21",
        "address = 0x20",
        "register OFFSET: address 0x20 is already register GAIN",
    ),
    (
        "address beyond the SPI address bits",
        "hr400",
        "address = 0x25",
        "address = 0x80",
        "register LVDS_CTRL: address 0x80 does not fit the SPI frame's 7 address bits",
    ),
    (
        "unknown role target",
        "hr400",
        'window_rows = "WIN_ROWS"',
        'window_rows = "WIN_ROWZ"',
        "role window_rows: no register or group WIN_ROWZ",
    ),
    (
        "role target field missing",
        "ibis5",
        'offset = "OFFSET.dn"',
        'offset = "OFFSET.lsb"',
        "role offset: register OFFSET has no field lsb",
    ),
    (
        "counted role on an enum",
        "hr400",
        'window_rows = "WIN_ROWS"',
        'window_rows = "READOUT.mode"',
        "role window_rows: field READOUT.mode is an enum; the role needs a number",
    ),
    (
        "clock role scale disagrees with the clock",
        "ibis5",
        '{ name = "clocks", bits = [15, 0], unit = "s", scale = 2.5e-8 }',
        '{ name = "clocks", bits = [15, 0], unit = "s", scale = 4e-8 }',
        "register BACK_PATH: field 'clocks' plays the back_path role, which counts clocks of "
        "timing.clock_hz = 4e+07 Hz, so its scale must be 2.5e-08 s, not 4e-08",
    ),
    (
        "group member missing",
        "hr400",
        'registers = ["EXP_HI", "EXP_LO"]',
        'registers = ["EXP_HI", "EXP_LOW"]',
        "group EXPOSURE: no register EXP_LOW",
    ),
    (
        "hold register inside its group",
        "ibis5",
        'hold = "GROUP_HOLD.hold"',
        'hold = "EXP_HI.lines_hi"',
        "group EXPOSURE: hold register EXP_HI must be a non-volatile RW register outside the group",
    ),
    (
        "soft reset names a missing field",
        "hr400",
        'field = "SOFT_RESET.key"',
        'field = "SOFT_RESET.code"',
        "soft_reset: register SOFT_RESET has no field code",
    ),
    (
        "mirroring register not volatile",
        "mt9m001",
        "volatile = true\nreset = 0x0008\nmirrors",
        "volatile = false\nreset = 0x0008\nmirrors",
        "register GLOBAL_GAIN: a register that mirrors others reads back what they hold: declare "
        "it volatile = true",
    ),
    (
        "pulse field reset to 1",
        "mt9m001",
        'reset = 0x0000\ndoc = "Frame restart (Reg0x0B)."',
        'reset = 0x0001\ndoc = "Frame restart (Reg0x0B)."',
        "register RESTART: reset value 0x1 sets pulse field 'restart', which always reads 0",
    ),
    (
        "a wrong type",
        "hr400",
        'width = 16\naccess = "rw"\nreset = 757',
        'width = "wide"\naccess = "rw"\nreset = 757',
        "register WIN_START: width: 'wide' is a string, the wrong type; write an integer, "
        "without quotes",
    ),
    (  # issue 31: strict types, a number in quotes is not taken as one
        "a number in quotes",
        "hr400",
        'width = 16\naccess = "rw"\nreset = 757',
        'width = "16"\naccess = "rw"\nreset = 757',
        "register WIN_START: width: '16' is a string, the wrong type; write an integer, "
        "without quotes",
    ),
]


@pytest.mark.parametrize(
    ("sensor", "old", "new", "message"),
    [case[1:] for case in CORRUPTIONS],
    ids=[case[0] for case in CORRUPTIONS],
)
def test_corrupted_map_names_file_line_and_register(
    tmp_path: Path, sensor: str, old: str, new: str, message: str
) -> None:
    path, line = corrupt(tmp_path, sensor, old, new)
    changed_line = path.read_text(encoding="utf-8").splitlines()[line - 1]
    with pytest.raises(RegisterMapError) as info:
        load_register_map(path)
    assert str(info.value) == f"{path}:{info.value.line}: {message}"
    assert info.value.path == path
    # The line is the one that was changed (or, for a multi-line change, one of its lines).
    span = range(line, line + new.count("\n") + 1)
    assert info.value.line in span, (info.value.line, changed_line)


def test_window_of_the_reset_values_must_fit_the_array(tmp_path: Path) -> None:
    path, line = corrupt(tmp_path, "hr400", "reset = 757", "reset = 1800")
    with pytest.raises(RegisterMapError) as info:
        load_register_map(path)
    assert info.value.line == line
    assert str(info.value) == (
        f"{path}:{line}: register WIN_START: reset values: WIN_START = 1800 and WIN_ROWS = 534: "
        "the window's last row would be 2333, beyond the sensor's last row 2047; lower WIN_START "
        "or WIN_ROWS (the window must fit rows 0 .. 2047)"
    )


def test_lvds_output_needs_the_training_roles(tmp_path: Path) -> None:
    path, _ = corrupt(tmp_path, "hr400", 'training_word = "TRAINING_WORD.word"\n', "")
    with pytest.raises(RegisterMapError) as info:
        load_register_map(path)
    assert "output: an lvds output needs the training_word and test_pattern roles" in str(
        info.value
    )
    text = path.read_text(encoding="utf-8").splitlines()
    assert text[info.value.line - 1].startswith("interface = ")  # type: ignore[operator]


def test_toml_syntax_error_has_the_line(tmp_path: Path) -> None:
    path, line = corrupt(tmp_path, "ibis5", "rows = 1024", "rows = = 1024")
    with pytest.raises(RegisterMapError) as info:
        load_register_map(path)
    assert info.value.line == line
    assert str(info.value).startswith(f"{path}:{line}: ")


def test_top_level_and_table_errors_point_at_their_key(tmp_path: Path) -> None:
    path, line = corrupt(tmp_path, "hr400", "address_bits = 7", "address_bits = 17")
    with pytest.raises(RegisterMapError) as info:
        load_register_map(path)
    assert str(info.value) == (
        f"{path}:{line}: spi.address_bits: 17 is out of range; allowed: 1 <= address_bits <= 16"
    )
    path, line = corrupt(tmp_path, "hr400", "columns = 2048", "columns = 0")
    with pytest.raises(RegisterMapError) as info:
        load_register_map(path)
    assert str(info.value) == f"{path}:{line}: columns: 0 is out of range; allowed: 1 <= columns"


def test_unknown_sensor_name_lists_the_known_ones() -> None:
    with pytest.raises(FileNotFoundError, match=r"known: .*hr400.*ibis5.*mt9m001"):
        load_register_map("nosuch")


# -- values against the map ---------------------------------------------------------------------


HR400 = load_register_map("hr400")


def test_whole_register_values_are_checked_field_by_field() -> None:
    gain = HR400.register("GAIN")
    assert gain.check_value(0x0240) == 0x0240
    with pytest.raises(RegisterValueError) as info:
        gain.check_value(0x0210)
    assert (
        str(info.value) == "GAIN.digital: 16 is out of range (valid: 32 .. 255 (0.5 .. 3.98438 x))"
    )
    with pytest.raises(RegisterValueError) as info:
        gain.check_value(0x1040)
    assert str(info.value) == (
        "GAIN: 0x1040 sets bit(s) 12, which no field uses; they must be 0 "
        "(fields: analog 9..8, digital 7..0)"
    )
    with pytest.raises(RegisterValueError) as info:
        gain.check_value(0x10000)
    assert str(info.value) == "GAIN: 0x10000 (65536) does not fit 16 bits (valid: 0 .. 0xFFFF)"
    # A register with one field from bit 0 is a number: checked as that field.
    with pytest.raises(RegisterValueError) as info:
        HR400.register("WIN_ROWS").check_value(5000)
    assert (
        str(info.value) == "WIN_ROWS.rows: 5000 is out of range (valid: 1 .. 2048 (1 .. 2048 row))"
    )


def test_values_of_names_groups_and_counted_roles() -> None:
    values = {reg.name: reg.reset for reg in HR400.registers}
    values.update(EXP_HI=0x1, EXP_LO=0x2345, GAIN=0x0340)

    def raw(reg: RegisterSpec) -> int:
        return values[reg.name]

    assert HR400.value_of("EXPOSURE", raw) == 0x12345
    assert HR400.value_of("gain.analog", raw) == "x8"
    assert HR400.value_of("GAIN.digital", raw) == 0x40
    assert HR400.value_of("GAIN", raw) == 0x0340
    assert HR400.split_group(HR400.group("EXPOSURE"), 0x12345) == [
        (HR400.register("EXP_HI"), 0x1),
        (HR400.register("EXP_LO"), 0x2345),
    ]
    with pytest.raises(
        RegisterValueError, match=r"EXPOSURE: 0 is out of range \(valid: 1 .. 1048575 line\)"
    ):
        HR400.split_group(HR400.group("EXPOSURE"), 0)
    mt = load_register_map("mt9m001")

    def reset(name: str) -> int | str:
        return mt.value_of(name, lambda reg: reg.reset)

    assert mt.role_count("window_rows", reset) == 1024  # ROW_SIZE 0x3FF + bias 1
    assert mt.role_count("window_columns", reset) == 1280
    assert mt.role_count("back_path", reset) is None


def test_window_check_counts_from_the_first_active_row() -> None:
    mt = load_register_map("mt9m001")
    values = {"ROW_START.row": 12, "ROW_SIZE.rows_minus_1": 1023}
    values |= {"COL_START.column": 20, "COL_SIZE.columns_minus_1": 1279}
    mt.check_window(lambda name: values[name])
    values["ROW_START.row"] = 13
    with pytest.raises(RegisterValueError) as info:
        mt.check_window(lambda name: values[name])
    assert str(info.value) == (
        "ROW_START.row = 13 and ROW_SIZE.rows_minus_1 = 1023: the window's last row would be "
        "1036, beyond the sensor's last row 1035; lower ROW_START.row or ROW_SIZE.rows_minus_1 "
        "(the window must fit rows 12 .. 1035)"
    )


def test_field_and_map_models_can_be_built_in_code() -> None:
    field = FieldSpec(name="rows_minus_1", bits=(10, 0), bias=1)
    assert field.count(1023) == 1024
    reg = RegisterSpec(name="X", address=1, width=16, access="rw", fields=[field])
    assert reg.decode(5) == {"rows_minus_1": 5}
    data = HR400.model_dump()
    assert RegisterMap.model_validate(data) == HR400


def test_role_write_is_role_count_inverted_bias_included() -> None:
    # The MT9M001 holds rows - 1 (bias 1): 8 rows are raw 7; the HR400's WIN_ROWS has no bias.
    assert load_register_map("mt9m001").role_write("window_rows", 8) == ("ROW_SIZE.rows_minus_1", 7)
    assert load_register_map("hr400").role_write("window_rows", 8) == ("WIN_ROWS", 8)


def test_a_biased_field_s_range_names_the_counted_quantity() -> None:
    # Raw 2 .. 1023 of rows_minus_1 are 3 .. 1024 rows: the message must not say "2 .. 1023 row".
    field = load_register_map("mt9m001").resolve("ROW_SIZE.rows_minus_1")[1]
    assert field is not None
    assert field.valid_range() == "2 .. 1023 (3 .. 1024 row)"
    assert load_register_map("mt9m001").role_write("back_path", 0) is None  # it has none
