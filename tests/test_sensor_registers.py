"""SensorRegisters against the simulated sensor's register file.

The bridge here is a test fixture: it calls SensorModel.spi_read / spi_write directly and records
every access, with the sensor's effective exposure after each one (the full stack over the pty and
the USB-SPI backend is tested in test_sensor_stack.py).
"""

from __future__ import annotations

import random
from collections.abc import Sequence
from pathlib import Path

import pytest

from camd.sensor.bridge import BridgeError, RegisterBridge
from camd.sensor.registers import RegisterDiff, SensorRegisters, VerifyError
from camd.sensor.regmap import (
    RegisterAccessError,
    RegisterMap,
    RegisterSpec,
    RegisterValueError,
    load_register_map,
)
from firmware_models.sensor import SensorModel

HR400 = load_register_map("hr400")
IBIS5 = load_register_map("ibis5")
MT9M001 = load_register_map("mt9m001")
T_LINE_S = 513 / 25e6  # docs/physics.md §3: 513 sequencer clocks at the hr400 map's 25 MHz


class DirectBridge(RegisterBridge):
    """Calls the model's SPI methods; records bursts, accesses and the exposure after each."""

    name = "direct"

    def __init__(self, model: SensorModel) -> None:
        self.model = model
        self.bursts: list[list[tuple[int, int]]] = []
        self.accesses: list[tuple[str, int, int]] = []
        self.exposure_after_write: list[int] = []

    def read(self, address: int) -> int:
        value = self.model.spi_read(address)
        self.accesses.append(("r", address, value))
        return value

    def write(self, address: int, value: int) -> None:
        self.model.spi_write(address, value)
        self.accesses.append(("w", address, value))
        if self.model.regmap.role("exposure_lines") is not None:
            self.exposure_after_write.append(self.model.exposure_lines)

    def write_burst(self, writes: Sequence[tuple[int, int]]) -> None:
        self.bursts.append(list(writes))
        super().write_burst(writes)


class StuckBitBridge(DirectBridge):
    """A bridge whose sensor drops bit 0 of one register (a wiring fault)."""

    def __init__(self, model: SensorModel, address: int) -> None:
        super().__init__(model)
        self.stuck = address

    def write(self, address: int, value: int) -> None:
        super().write(address, value & ~1 if address == self.stuck else value)


def make(regmap: RegisterMap = HR400) -> tuple[SensorRegisters, SensorModel, DirectBridge]:
    model = SensorModel(regmap)
    bridge = DirectBridge(model)
    return SensorRegisters(regmap, bridge), model, bridge


def random_value(reg: RegisterSpec, rng: random.Random) -> int:
    value = 0
    for field in reg.all_fields():
        raw = (
            rng.choice(list(field.enum.values())) if field.enum else rng.randint(field.lo, field.hi)
        )
        value = field.insert(value, raw)
    return value


def random_configuration(regmap: RegisterMap, seed: int) -> dict[str, int]:
    """Random in-range values for every RW non-volatile register; the window fits the array."""
    rng = random.Random(seed)
    values = {
        reg.name: random_value(reg, rng)
        for reg in regmap.registers
        if reg.access == "rw" and not reg.volatile
    }
    for reg in regmap.registers:  # no actions: a soft reset or a pulse would not read back
        if reg.name in values:
            values[reg.name] &= reg.kept_mask
            if regmap.is_soft_reset(reg, values[reg.name]):
                values[reg.name] = reg.reset
    for group in regmap.groups:
        hold = regmap.hold_of(group)
        if hold is not None:
            values[hold[0].name] = hold[1].insert(values[hold[0].name], 0)
        lo, hi = regmap.group_range(group)
        for reg, part in regmap.split_group(group, rng.randint(lo, hi)):
            values[reg.name] = part
    for start_role, size_role, first, total in (
        ("window_start_row", "window_rows", regmap.first_row, regmap.rows),
        ("window_start_column", "window_columns", regmap.first_column, regmap.columns),
    ):
        start_name, size_name = regmap.role(start_role), regmap.role(size_role)
        if start_name is None or size_name is None:
            continue
        start_reg, start_field = regmap.resolve(start_name)
        size_reg, size_field = regmap.resolve(size_name)
        assert isinstance(start_reg, RegisterSpec) and isinstance(size_reg, RegisterSpec)
        start_field = start_field or start_reg.all_fields()[0]
        size_field = size_field or size_reg.all_fields()[0]
        size_raw = rng.randint(size_field.lo, size_field.hi)
        count = size_field.count(size_raw)
        start = rng.randint(max(first, start_field.lo), first + total - count)
        values[size_reg.name] = size_field.insert(values[size_reg.name], size_raw)
        values[start_reg.name] = start_field.insert(values[start_reg.name], start)
    return values


# -- write, read back, verify -------------------------------------------------------------------


@pytest.mark.parametrize("regmap", [HR400, IBIS5, MT9M001], ids=lambda m: m.sensor)
@pytest.mark.parametrize("seed", range(5))
def test_every_rw_register_written_read_back_and_verified(regmap: RegisterMap, seed: int) -> None:
    regs, model, bridge = make(regmap)
    values = random_configuration(regmap, seed)
    written = regs.write(values)
    assert {r.name: r.value for r in written} == values
    assert len(bridge.bursts) == 1  # one call, one burst
    for name, value in values.items():
        assert model.register_value(name) == value, name
        assert regs.read(name).value == value
        assert regs.shadow_value(name) == value
    assert not regs.dirty


def test_write_by_address_text_and_labels_from_the_cli() -> None:
    regs, model, _ = make()
    regs.write({"0x10": "0x10", "GAIN.analog": "x2", "offset": "321"})
    assert model.register_value("WIN_START") == 0x10
    assert model.value("GAIN.analog") == "x2"
    assert model.register_value("OFFSET") == 321


OUT_OF_RANGE = [
    ({"WIN_ROWS": 0}, RegisterValueError, "WIN_ROWS.rows: 0 is out of range (valid: 1 .. 2048 (1 .. 2048 row))"),
    ({"WIN_ROWS.rows": 4000}, RegisterValueError, "WIN_ROWS.rows: 4000 is out of range (valid: 1 .. 2048 (1 .. 2048 row))"),
    ({"GAIN.digital": 31}, RegisterValueError, "GAIN.digital: 31 is out of range (valid: 32 .. 255 (0.5 .. 3.98438 x))"),
    ({"GAIN.analog": "x16"}, RegisterValueError, "GAIN.analog: 'x16' is not valid; use one of x1 (0), x2 (1), x4 (2), x8 (3)"),
    ({"GAIN": 0x1040}, RegisterValueError, "GAIN: 0x1040 sets bit(s) 12, which no field uses; they must be 0 (fields: analog 9..8, digital 7..0)"),
    ({"EXPOSURE": 0}, RegisterValueError, "EXPOSURE: 0 is out of range (valid: 1 .. 1048575 line)"),
    ({"EXPOSURE": 1 << 20}, RegisterValueError, "EXPOSURE: 1048576 is out of range (valid: 1 .. 1048575 line)"),
    ({"WIN_START": 1600}, RegisterValueError, "WIN_START = 1600 and WIN_ROWS = 534: the window's last row would be 2133, beyond the sensor's last row 2047; lower WIN_START or WIN_ROWS (the window must fit rows 0 .. 2047)"),
    ({"CHIP_ID": 1}, RegisterAccessError, "CHIP_ID (0x00) is read-only; it cannot be written"),
    ({"STATUS.running": 1}, RegisterAccessError, "STATUS.running (0x01) is read-only; it cannot be written"),
    ({"NO_SUCH": 1}, RegisterAccessError, "hr400 has no register named 'NO_SUCH'; `camctl reg dump` lists them"),
    ({"0x7E": 1}, RegisterAccessError, "hr400 has no register at address 0x7E; `camctl reg dump` lists them"),
    ({"GAIN.coarse": 1}, RegisterAccessError, "register GAIN has no field 'coarse'; fields: analog, digital"),
    ({"OFFSET": "lots"}, RegisterValueError, "OFFSET: 'lots' is not a number; give an integer (e.g. 0x0064) or set a field by name, e.g. OFFSET.dn=..."),
    ({"GROUP_HOLD.hold": 1, "EXPOSURE": 5}, RegisterValueError, "GROUP_HOLD.hold = 1 together with EXPOSURE: the group write sets and clears the hold itself; leave GROUP_HOLD.hold at 0 or write it separately"),
]  # fmt: skip


@pytest.mark.parametrize(("assignment", "error", "message"), OUT_OF_RANGE)
def test_invalid_writes_are_refused_exactly_and_nothing_is_written(
    assignment: dict[str, int | str], error: type[Exception], message: str
) -> None:
    regs, model, bridge = make()
    before = {reg.name: model.register_value(reg.name) for reg in HR400.registers}
    # A valid assignment in the same call must not be written either.
    with pytest.raises(error) as info:
        regs.write({"OFFSET": 7, **assignment})
    assert str(info.value) == message
    assert sum(model.writes.values()) == 0
    assert bridge.bursts == []
    assert {reg.name: model.register_value(reg.name) for reg in HR400.registers} == before


def test_reading_a_write_only_register_shows_the_host_copy_and_sends_nothing() -> None:
    """docs/cli.md, camctl reg read: a write-only register reads as the host's copy of the
    last value written (the sensor cannot return it); nothing goes to the sensor."""
    regs, model, _ = make()
    reading = regs.read("SOFT_RESET")
    assert (reading.value, reading.from_shadow) == (0, True)
    assert reading.as_dict() == {
        "name": "SOFT_RESET", "address": 0x03, "value": 0, "fields": {"key": "none"},
    }  # fmt: skip
    field = regs.read("SOFT_RESET.key")
    assert (field.value, field.fields, field.from_shadow) == (0, {"key": "none"}, True)
    assert sum(model.reads.values()) == 0 and sum(model.writes.values()) == 0
    assert not regs.read("OFFSET").from_shadow
    dump = {r.name: r for r in regs.dump()}
    assert dump["SOFT_RESET"].from_shadow and dump["SOFT_RESET"].value == 0
    assert not dump["OFFSET"].from_shadow


def test_field_write_is_read_modify_write() -> None:
    regs, model, bridge = make()
    regs.write({"GAIN.digital": 200})
    bridge.accesses.clear()
    regs.write({"GAIN.analog": "x8"})
    # The second write read GAIN fresh, wrote it, then read it back to verify.
    assert bridge.accesses == [("r", 0x20, 200), ("w", 0x20, 0x3C8), ("r", 0x20, 0x3C8)]
    assert model.register_value("GAIN") == (3 << 8) | 200
    assert regs.read("GAIN").fields == {"analog": "x8", "digital": 200}


def test_two_fields_of_one_register_in_one_call() -> None:
    regs, model, bridge = make()
    written = regs.write({"READOUT.mode": "binning_2x2", "READOUT.mirror": 1})
    assert model.register_value("READOUT") == 0x11
    assert [r.name for r in written] == ["READOUT"]
    assert bridge.bursts[-1] == [(0x22, 0x11)]


def test_w1c_field_write_clears_only_that_flag() -> None:
    regs, model, bridge = make()
    model.raise_flag("FLAGS.overexposure")
    model.raise_flag("FLAGS.sync_error")
    regs.write({"FLAGS.overexposure": 1})
    assert bridge.bursts[-1] == [(0x02, 0b001)]  # not read-modify-write
    assert model.value("FLAGS.sync_error") == 1
    assert model.value("FLAGS.overexposure") == 0


def test_group_write_is_one_burst_under_hold_and_changes_atomically() -> None:
    regs, model, bridge = make()
    regs.write({"EXPOSURE": 0x1FFFF})
    assert model.exposure_lines == 0x1FFFF
    bridge.exposure_after_write.clear()
    written = regs.write({"EXPOSURE": 0x20000})
    assert bridge.bursts[-1] == [(0x04, 1), (0x12, 0x2), (0x13, 0x0000), (0x04, 0)]
    # Between the parts the sensor kept the old value: no 0x2FFFF or 0x00000 in between.
    assert bridge.exposure_after_write == [0x1FFFF, 0x1FFFF, 0x1FFFF, 0x20000]
    assert [r.name for r in written] == ["EXP_HI", "EXP_LO"]
    assert regs.read("EXPOSURE").value == 0x20000
    assert regs.read_value("EXPOSURE") == 0x20000


def test_a_member_written_alone_is_held_too() -> None:
    regs, model, bridge = make()
    regs.write({"EXP_LO": 9, "OFFSET": 3})
    assert bridge.bursts[-1] == [(0x21, 3), (0x04, 1), (0x13, 9), (0x04, 0)]
    assert model.exposure_lines == 9


def test_all_registers_of_a_call_go_out_in_one_burst() -> None:
    regs, _, bridge = make()
    regs.write({"WIN_START": 100, "WIN_ROWS": 200, "EXPOSURE": 300, "OFFSET": 4})
    assert len(bridge.bursts) == 1
    assert [a for a, _ in bridge.bursts[0]] == [0x10, 0x11, 0x21, 0x04, 0x12, 0x13, 0x04]


def test_verify_catches_a_register_that_does_not_keep_its_value() -> None:
    model = SensorModel(HR400)
    regs = SensorRegisters(HR400, StuckBitBridge(model, 0x21))
    with pytest.raises(VerifyError) as info:
        regs.write({"OFFSET": 101, "WIN_START": 10})
    assert isinstance(info.value, BridgeError)
    assert info.value.mismatches == [RegisterDiff("OFFSET", 0x21, 101, 100)]
    assert str(info.value).startswith(
        "verify failed: OFFSET (0x21) written 0x0065, read back 0x0064."
    )
    regs.write({"OFFSET": 101}, verify=False)  # no read-back asked for: no error


def test_volatile_wo_and_w1c_are_not_read_back() -> None:
    regs, model, bridge = make(MT9M001)
    regs.write({"GLOBAL_GAIN": 0x20})  # volatile: mirrors the four colour gains
    assert [
        model.register_value(n) for n in ("GAIN_GREEN1", "GAIN_BLUE", "GAIN_RED", "GAIN_GREEN2")
    ] == [0x20] * 4
    verified = [a for kind, a, _ in bridge.accesses if kind == "r"]
    assert 0x35 not in verified and set(verified) == {0x2B, 0x2C, 0x2D, 0x2E}
    assert regs.shadow_value("GAIN_RED") == 0x20


def test_pulse_bits_act_and_verify_ignores_them() -> None:
    regs, model, bridge = make(MT9M001)
    written = regs.write({"RESTART": 0b11})
    assert bridge.bursts[-1] == [(0x0B, 0b11)]
    assert written[0].value == 0b10 and model.register_value("RESTART") == 0b10
    regs.write({"CAL_CTRL.recalibrate": 1})
    assert model.register_value("CAL_CTRL") == 0x0498


def test_soft_reset_resets_device_and_shadow() -> None:
    regs, model, _ = make()
    regs.write({"OFFSET": 5})
    regs.stage({"WIN_START": 3})
    regs.write({"SOFT_RESET.key": "reset"})
    assert model.register_value("OFFSET") == 100
    assert regs.shadow_value("OFFSET") == 100 and regs.shadow_value("WIN_START") == 757
    assert not regs.dirty
    assert regs.diff("reset") == []


def test_mt9m001_window_counts_from_row_12() -> None:
    regs, model, _ = make(MT9M001)
    regs.write({"ROW_START": 757 - 745, "ROW_SIZE": 533})
    assert (model.window_start_row, model.window_rows) == (12, 534)
    with pytest.raises(RegisterValueError) as info:
        regs.write({"ROW_START": 600})
    assert str(info.value) == (
        "ROW_START.row = 600 and ROW_SIZE.rows_minus_1 = 533: the window's last row would be "
        "1133, beyond the sensor's last row 1035; lower ROW_START.row or ROW_SIZE.rows_minus_1 "
        "(the window must fit rows 12 .. 1035)"
    )
    with pytest.raises(
        RegisterValueError, match=r"ROW_START.row: 11 is out of range \(valid: 12 .. 1035"
    ):
        regs.write({"ROW_START": 11})


# -- reads --------------------------------------------------------------------------------------


def test_read_by_name_address_field_and_group() -> None:
    regs, _, _ = make()
    regs.write({"GAIN.analog": "x4", "GAIN.digital": 96, "EXPOSURE": 0x54321})
    by_name = regs.read("gain")
    assert by_name.as_dict() == {
        "name": "GAIN",
        "address": 0x20,
        "value": (2 << 8) | 96,
        "fields": {"analog": "x4", "digital": 96},
    }
    assert regs.read("0x20") == by_name == regs.read(32) == regs.read("32")
    field = regs.read("GAIN.analog")
    assert (field.name, field.address, field.value, field.fields) == (
        "GAIN.analog",
        0x20,
        2,
        {"analog": "x4"},
    )
    group = regs.read("EXPOSURE")
    assert (group.name, group.address, group.value) == ("EXPOSURE", 0x12, 0x54321)
    assert group.fields == {"EXP_HI": 0x5, "EXP_LO": 0x4321}
    assert regs.read_value("GAIN.analog") == "x4"
    assert regs.read_value("GAIN") == 0x260


def test_dump_is_in_address_order_and_complete() -> None:
    regs, _, _ = make(MT9M001)
    dump = regs.dump()
    assert [r.address for r in dump] == sorted(r.address for r in MT9M001.registers)
    assert dump[0].name == "CHIP_VERSION" and dump[0].value == 0x8411


# -- shadow copy, stage and flush ---------------------------------------------------------------


def test_stage_changes_only_the_shadow_and_flush_sends_one_burst() -> None:
    regs, model, bridge = make()
    regs.stage({"OFFSET": 9, "GAIN.analog": "x2"})
    regs.stage({"EXPOSURE": 0x10001})
    assert regs.dirty == ("EXP_HI", "EXP_LO", "GAIN", "OFFSET")
    assert sum(model.writes.values()) == 0 and bridge.bursts == []
    assert regs.shadow_value("GAIN") == 0x0140
    written = regs.flush()
    assert bridge.bursts == [
        [(0x20, 0x0140), (0x21, 9), (0x04, 1), (0x12, 1), (0x13, 1), (0x04, 0)]
    ]
    assert {r.name for r in written} == {"EXP_HI", "EXP_LO", "GAIN", "OFFSET"}
    assert not regs.dirty
    assert model.register_value("OFFSET") == 9 and model.exposure_lines == 0x10001
    assert regs.flush() == [] and len(bridge.bursts) == 1  # nothing dirty, nothing sent


def test_a_dirty_group_member_flushes_the_whole_group_under_hold() -> None:
    regs, _, bridge = make()
    regs.stage({"EXP_LO": 5})
    regs.flush()
    assert bridge.bursts[-1] == [(0x04, 1), (0x12, 0), (0x13, 5), (0x04, 0)]


def test_stage_validates_like_write_and_refuses_actions() -> None:
    regs, _, bridge = make()
    with pytest.raises(RegisterValueError, match=r"WIN_ROWS\.rows: 0 is out of range"):
        regs.stage({"WIN_ROWS": 0})
    with pytest.raises(RegisterAccessError, match="cannot be staged; use write"):
        regs.stage({"SOFT_RESET.key": "reset"})
    with pytest.raises(RegisterAccessError, match="cannot be staged; use write"):
        regs.stage({"FLAGS.overexposure": 1})
    assert regs.dirty == () and bridge.bursts == []


def test_sync_reads_the_device_into_the_shadow() -> None:
    regs, model, _ = make()
    model.spi_write(0x21, 77)  # someone else changed it
    assert regs.shadow_value("OFFSET") == 100
    regs.stage({"WIN_START": 1})
    regs.sync()
    assert regs.shadow_value("OFFSET") == 77 and regs.dirty == ()


# -- diff, save, load ---------------------------------------------------------------------------


def test_diff_against_reset_and_values() -> None:
    regs, model, _ = make()
    assert regs.diff("reset") == []
    regs.write({"OFFSET": 321, "EXPOSURE": 0x10002})
    model.note_frame()  # volatile registers never show in a diff against reset
    assert regs.diff("reset") == [
        RegisterDiff("EXP_HI", 0x12, 0, 1),
        RegisterDiff("OFFSET", 0x21, 100, 321),
    ]
    assert regs.diff({"OFFSET": 321, "GAIN.analog": "x2", "EXPOSURE": "0x10002"}) == [
        RegisterDiff("GAIN.analog", 0x20, 1, 0)
    ]


def test_save_load_round_trip_is_bit_exact(tmp_path: Path) -> None:
    regs, _, bridge = make()
    regs.write(random_configuration(HR400, 7))
    saved = tmp_path / "a.toml"
    values = regs.save(saved)
    text = saved.read_text(encoding="utf-8")
    assert text.startswith("# camd sensor configuration")
    assert 'sensor = "hr400"' in text and "[registers]" in text
    assert "SOFT_RESET" not in values and "STATUS" not in values  # actions and status are not saved
    assert set(values) == {r.name for r in HR400.registers if r.configurable} - {"SOFT_RESET"}
    original = {r.name: r.value for r in regs.dump()}
    regs.write(random_configuration(HR400, 8))
    assert regs.diff(saved)
    bursts = len(bridge.bursts)
    loaded = regs.load(saved)
    assert len(bridge.bursts) == bursts + 1  # one burst
    assert {r.name: r.value for r in loaded} == values
    assert {r.name: r.value for r in regs.dump()} == original
    assert regs.diff(saved) == []
    again = tmp_path / "b.toml"
    regs.save(again)
    assert again.read_bytes() == saved.read_bytes()


def test_load_refuses_another_sensors_file_and_writes_nothing(tmp_path: Path) -> None:
    regs, model, _ = make()
    other = tmp_path / "other.toml"
    SensorRegisters(IBIS5, DirectBridge(SensorModel(IBIS5))).save(other)
    with pytest.raises(RegisterValueError) as info:
        regs.load(other)
    assert str(info.value) == (
        f"{other} is a configuration for sensor 'ibis5', but this camera's sensor is 'hr400'; "
        "load a configuration saved from a hr400 (`camctl reg save FILE`)"
    )
    assert sum(model.writes.values()) == 0


@pytest.mark.parametrize(
    ("body", "error", "message"),
    [
        ("OFFSET = 3\nNOPE = 1\n", RegisterAccessError, "registers.NOPE: hr400 has no register named 'NOPE'; remove it"),
        ("OFFSET = 3\nSTATUS = 1\n", RegisterAccessError, "registers.STATUS: a volatile RO register is not part of a configuration"),
        ("OFFSET = 3\nWIN_ROWS = 0\n", RegisterValueError, "WIN_ROWS.rows: 0 is out of range (valid: 1 .. 2048 (1 .. 2048 row)); nothing was written"),
        ("OFFSET = 3\nGAIN = true\n", RegisterValueError, "registers.GAIN = True is not a raw register value"),
    ],
)  # fmt: skip
def test_load_validates_the_whole_file_first(
    tmp_path: Path, body: str, error: type[Exception], message: str
) -> None:
    regs, model, _ = make()
    path = tmp_path / "bad.toml"
    path.write_text(f'sensor = "hr400"\n[registers]\n{body}', encoding="utf-8")
    with pytest.raises(error) as info:
        regs.load(path)
    assert message in str(info.value)
    assert str(path) in str(info.value)
    assert sum(model.writes.values()) == 0


def test_missing_configuration_file_is_a_clear_error(tmp_path: Path) -> None:
    regs, _, _ = make()
    with pytest.raises(RegisterValueError, match="cannot read the configuration"):
        regs.load(tmp_path / "none.toml")


# -- timing ---------------------------------------------------------------------------------------


def test_hr400_timing_matches_hand_computed_values() -> None:
    regs, _, _ = make()
    regs.write({"WIN_START": 757, "WIN_ROWS": 534, "EXPOSURE": 2, "BACK_PATH": 0})
    t = regs.timing()
    assert t.line_period_s == pytest.approx(20.52e-6, rel=1e-12)  # 513 / 25 MHz
    assert t.exposure_s == pytest.approx(41.04e-6, rel=1e-12)
    assert t.frame_time_s == pytest.approx(11.01924e-3, rel=1e-12)  # (2 + 534 + 1) lines
    assert t.frame_period_s == pytest.approx(534 * 20.52e-6, rel=1e-12)  # max(k, n + 1) = k
    assert t.max_stages == 534
    assert t.as_dict()["gain"] == "x1"
    assert t.exposure_register == "EXPOSURE"  # the register the live view writes
    assert set(t.as_dict()) == {
        "sensor", "line_period_s", "window_start_row", "window_rows", "exposure_lines",
        "exposure_s", "frame_time_s", "frame_period_s", "back_path_s", "tdi_line_period_s",
        "max_stages", "gain", "offset", "readout_mode", "test_pattern", "exposure_register",
    }  # fmt: skip
    regs.write({"EXPOSURE": 600, "BACK_PATH": 500})  # n >= k; back path 500 clocks = 20 us
    t = regs.timing()
    assert t.frame_time_s == pytest.approx(1135 * T_LINE_S, rel=1e-12)
    assert t.back_path_s == pytest.approx(20e-6, rel=1e-12)
    assert t.frame_period_s == pytest.approx(601 * T_LINE_S + 20e-6, rel=1e-12)
    assert t.tdi_line_period_s == t.frame_period_s


def test_ibis5_timing_follows_row_blanking() -> None:
    regs, _, _ = make(IBIS5)
    regs.write({"ROW_BLANK": 200, "WIN_ROWS": 64, "EXPOSURE": 10})
    t = regs.timing()
    assert t.line_period_s == pytest.approx(200 / 40e6 + 1280 / 40e6, rel=1e-12)  # 37 us
    assert t.frame_time_s == pytest.approx(75 * 37e-6, rel=1e-12)
    assert t.readout_mode == "rolling"


def test_mt9m001_timing_follows_the_datasheet_row_time() -> None:
    regs, _, _ = make(MT9M001)
    assert regs.timing().line_period_s == pytest.approx(31.75e-6, rel=1e-12)
    regs.write({"COL_SIZE": 639, "HBLANK": 100, "SHUTTER_WIDTH": 3})
    t = regs.timing()
    assert t.line_period_s == pytest.approx((640 + 244 + 100 - 19) / 48e6, rel=1e-12)
    assert t.exposure_lines == 3 and t.window_rows == 1024
