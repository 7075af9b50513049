"""The register-burst planner (``camd.daemon.register_plan``), without a daemon.

A write or a configuration's load is planned against a snapshot of the register file read from
the simulated sensor (``firmware_models.sensor.SensorModel`` behind a direct SPI bridge, as in
tests/test_sensor_registers.py): every refusal comes from the plan, with the message the API
answers, and planning sends nothing on the bus. The plan names the settings a failure writes
back, with their values in the snapshot: those the burst changes, also those a register it
writes mirrors into, never an action (a soft reset, flags cleared by writing 1) or a volatile
register. tests/test_register_apply.py applies such plans, and makes them fail part-way, on a
real daemon.
"""

from __future__ import annotations

import pytest

from camd.daemon.errors import BadRequest
from camd.daemon.models import RegisterConfig
from camd.daemon.register_plan import (
    RegisterSnapshot,
    check_configuration,
    plan_configuration,
    plan_write,
)
from camd.sensor.registers import SensorRegisters
from camd.sensor.regmap import load_register_map
from firmware_models.sensor import SensorModel
from tests.test_sensor_registers import DirectBridge

HR400 = load_register_map("hr400")
MT9M001 = load_register_map("mt9m001")


def snapshot_of(sensor: str) -> tuple[RegisterSnapshot, SensorRegisters, DirectBridge]:
    """A snapshot of a simulated sensor at its reset values, and what it was read through."""
    regmap = load_register_map(sensor)
    bridge = DirectBridge(SensorModel(regmap))
    registers = SensorRegisters(regmap, bridge)
    return RegisterSnapshot(regmap, registers, registers.raw_values()), registers, bridge


def refusal(call: object, *args: object) -> str:
    with pytest.raises(BadRequest) as info:
        call(*args)  # type: ignore[operator]
    return str(info.value)


# -- a write ---------------------------------------------------------------------------------------


def test_a_write_restores_what_it_changes_with_the_snapshot_values() -> None:
    snap, _, bridge = snapshot_of("hr400")
    read = len(bridge.accesses)
    plan = plan_write(snap, {"GAIN": 0x150, "OFFSET": 120, "BACK_PATH": 0})
    assert plan.what == "register write"
    assert plan.writes == {"GAIN": 0x150, "OFFSET": 120, "BACK_PATH": 0}
    # BACK_PATH is already 0: writing it changes nothing, so nothing is put back.
    assert plan.restore == {"GAIN": HR400.register("GAIN").reset, "OFFSET": 100}
    assert plan.restore_label == "registers GAIN, OFFSET"
    assert len(bridge.accesses) == read  # planning sent nothing


def test_fields_and_groups_restore_their_registers() -> None:
    snap, _, _ = snapshot_of("hr400")
    plan = plan_write(snap, {"GAIN.analog": "x2", "EXPOSURE": 1000, "WIN_ROWS": 100})
    assert plan.writes == {"GAIN.analog": "x2", "EXPOSURE": 1000, "WIN_ROWS": 100}
    # EXPOSURE = 1000 changes its low word only; the group's hold ends as it began.
    assert plan.restore == {"GAIN": 0x40, "EXP_LO": 2, "WIN_ROWS": 534}


def test_actions_are_not_restored() -> None:
    snap, _, _ = snapshot_of("hr400")
    assert plan_write(snap, {"FLAGS": 1}).restore == {}
    assert plan_write(snap, {"SOFT_RESET": 0x5A5A}).restore == {}


def test_a_register_that_mirrors_others_restores_them() -> None:
    snap, _, _ = snapshot_of("mt9m001")
    assert snap.changed({"TEST_DATA": 7, "GLOBAL_GAIN": 0x20}) == [
        "TEST_DATA", "GLOBAL_GAIN", "GAIN_GREEN1", "GAIN_BLUE", "GAIN_RED", "GAIN_GREEN2",
    ]  # fmt: skip
    plan = plan_write(snap, {"TEST_DATA": 7, "GLOBAL_GAIN": 0x20})
    # GLOBAL_GAIN itself is volatile (it reads back the green1 gain): the gains it set are
    # what is put back.
    assert plan.restore == {
        "TEST_DATA": 0, "GAIN_GREEN1": 8, "GAIN_BLUE": 8, "GAIN_RED": 8, "GAIN_GREEN2": 8,
    }  # fmt: skip
    # Set to what they hold, the gains change nothing.
    assert plan_write(snap, {"GLOBAL_GAIN": 8}).restore == {}


@pytest.mark.parametrize(
    ("writes", "message"),
    [
        ({}, "nothing to write: give one or more NAME=VALUE"),
        ({"STATUS": 1}, "STATUS (0x01) is read-only; it cannot be written"),
        ({"NOPE": 1}, "hr400 has no register named 'NOPE'; `camctl reg dump` lists them"),
        (
            {"GAIN.analog": "x3"},
            "GAIN.analog: 'x3' is not valid; use one of x1 (0), x2 (1), x4 (2), x8 (3)",
        ),
        (
            {"WIN_ROWS": 2049},
            "WIN_ROWS.rows: 2049 is out of range (valid: 1 .. 2048 (1 .. 2048 row))",
        ),
        (
            {"WIN_ROWS": 2000, "WIN_START": 100},
            "WIN_START = 100 and WIN_ROWS = 2000: the window's last row would be 2099, beyond "
            "the sensor's last row 2047; lower WIN_START or WIN_ROWS (the window must fit rows "
            "0 .. 2047)",
        ),
        (
            {"GROUP_HOLD.hold": 1, "EXPOSURE": 5},
            "GROUP_HOLD.hold = 1 together with EXPOSURE: the group write sets and clears the "
            "hold itself; leave GROUP_HOLD.hold at 0 or write it separately",
        ),
    ],
)
def test_a_write_that_would_be_refused_is_refused_by_its_plan(
    writes: dict[str, int | str], message: str
) -> None:
    snap, _, bridge = snapshot_of("hr400")
    read = len(bridge.accesses)
    assert refusal(plan_write, snap, writes) == message
    assert len(bridge.accesses) == read


# -- a configuration -------------------------------------------------------------------------------


def configuration(registers: SensorRegisters, **changes: int) -> RegisterConfig:
    return RegisterConfig(sensor="mt9m001", registers={**registers.configuration(), **changes})


def test_a_configuration_restores_the_registers_it_changes() -> None:
    snap, registers, bridge = snapshot_of("mt9m001")
    config = configuration(registers, GAIN_RED=11, TEST_DATA=9)
    read = len(bridge.accesses)
    check_configuration(registers, config)
    plan = plan_configuration(snap, config)
    assert plan.what == "configuration load"
    assert plan.writes == config.registers
    assert plan.restore == {"GAIN_RED": 8, "TEST_DATA": 0}
    assert len(bridge.accesses) == read


@pytest.mark.parametrize(
    ("sensor", "registers", "message"),
    [
        (
            "hr400",
            {"GAIN_RED": 8},
            "the configuration is a configuration for sensor 'hr400', but this camera's sensor "
            "is 'mt9m001'; load a configuration saved from a mt9m001 (`camctl reg save FILE`)",
        ),
        (
            "mt9m001",
            {"NOPE": 1},
            "the configuration: registers.NOPE: mt9m001 has no register named 'NOPE'; remove it "
            "(`camctl reg dump` lists the registers)",
        ),
        (
            "mt9m001",
            {"GLOBAL_GAIN": 1},
            "the configuration: registers.GLOBAL_GAIN: a volatile RW register is not part of a "
            "configuration (only RW and WO non-volatile registers are); remove it",
        ),
    ],
)
def test_a_configuration_for_another_sensor_or_with_no_settings_is_refused_before_reading(
    sensor: str, registers: dict[str, int], message: str
) -> None:
    _, sensor_registers, _ = snapshot_of("mt9m001")
    config = RegisterConfig(sensor=sensor, registers=registers)
    assert refusal(check_configuration, sensor_registers, config) == message


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        (
            {"OFFSET_G1": 1 << 16},
            "the configuration: OFFSET_G1: 0x10000 (65536) does not fit 16 bits (valid: 0 .. "
            "0xFFFF); nothing was written",
        ),
        (
            {"ROW_START": 1000, "ROW_SIZE": 1023},
            "the configuration: ROW_START.row = 1000 and ROW_SIZE.rows_minus_1 = 1023: the "
            "window's last row would be 2023, beyond the sensor's last row 1035; lower "
            "ROW_START.row or ROW_SIZE.rows_minus_1 (the window must fit rows 12 .. 1035); "
            "nothing was written",
        ),
    ],
)
def test_a_configuration_with_a_bad_value_is_refused_whole(
    changes: dict[str, int], message: str
) -> None:
    snap, registers, _ = snapshot_of("mt9m001")
    assert refusal(plan_configuration, snap, configuration(registers, **changes)) == message
