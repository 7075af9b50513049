"""The simulated FPGA's sensor commands driven with frames: REG_*, TRAIN, GET_LANE, streaming.

The FPGA model drives the sensor's register file through its SPI master model, and the LVDS
link through the training model; these tests check what the device answers and what the
sensor ends up holding.
"""

from __future__ import annotations

import struct
from collections.abc import Iterator
from typing import Any

import pytest

from camd.protocol import Dictionary, Frame, FrameType, load_dictionary
from camd.protocol.dictionary import FieldValue
from camd.sensor.regmap import load_register_map
from firmware_models.fpga import FpgaModel

HR400 = load_register_map("hr400")


@pytest.fixture(scope="module")
def dictionary() -> Dictionary:
    return load_dictionary()


@pytest.fixture
def model(dictionary: Dictionary) -> Iterator[FpgaModel]:
    fpga = FpgaModel(dictionary, seed=3)
    yield fpga
    fpga.close()


def call(model: FpgaModel, name: str, seq: int = 1, **values: Any) -> list[Frame]:
    spec = model.dictionary.command(name)
    frame = Frame(FrameType.COMMAND, seq, spec.opcode, spec.encode_request(**values))
    return model.handle(frame, 1.0)


def ack(model: FpgaModel, name: str, seq: int = 1, **values: Any) -> dict[str, FieldValue]:
    frames = call(model, name, seq, **values)
    assert frames and frames[0].type == FrameType.ACK, frames
    return model.dictionary.command(name).decode_response(frames[0].payload)


def nak(model: FpgaModel, name: str, seq: int = 1, **values: Any) -> tuple[str, str]:
    frames = call(model, name, seq, **values)
    assert len(frames) == 1 and frames[0].type == FrameType.NAK, frames
    code, detail = model.dictionary.decode_nak(frames[0].payload)
    return model.dictionary.error(code).name, detail


def event_names(model: FpgaModel, frames: list[Frame]) -> list[str]:
    names = []
    for frame in frames:
        if frame.type == FrameType.EVENT:
            names.append(model.dictionary.event(frame.opcode).name)
    return names


def address(name: str) -> int:
    return HR400.register(name).address


def test_reg_write_then_read_goes_through_spi_to_the_sensor(model: FpgaModel) -> None:
    before = model.spi_slave.transactions
    assert ack(model, "REG_WRITE", address=address("WIN_ROWS"), value=100) == {
        "address": address("WIN_ROWS"),
        "value": 100,
    }
    assert model.sensor.register_value("WIN_ROWS") == 100
    assert ack(model, "REG_READ", seq=2, address=address("WIN_ROWS"))["value"] == 100
    assert model.spi_slave.transactions == before + 2  # one SPI frame each
    assert model.sensor.window_rows == 100


def test_reset_values_read_back(model: FpgaModel) -> None:
    for seq, reg in enumerate(r for r in HR400.registers if r.readable and not r.volatile):
        assert ack(model, "REG_READ", seq=seq % 256, address=reg.address)["value"] == reg.reset


@pytest.mark.parametrize(
    ("command", "values", "error", "detail"),
    [
        ("REG_READ", {"address": 0x03}, "REG_WRITE_ONLY", "register SOFT_RESET (0x03) is write-only"),
        ("REG_WRITE", {"address": 0x00, "value": 1}, "REG_READ_ONLY", "register CHIP_ID (0x00) is read-only"),
        ("REG_WRITE", {"address": 0x01, "value": 1}, "REG_READ_ONLY", "register STATUS (0x01) is read-only"),
        ("REG_READ", {"address": 0x7E}, "REG_UNKNOWN", "hr400 has no register at address 0x7E"),
        ("REG_WRITE", {"address": 0x7E, "value": 0}, "REG_UNKNOWN", "hr400 has no register at address 0x7E"),
    ],
)  # fmt: skip
def test_wrong_access_is_a_nak_and_touches_nothing(
    model: FpgaModel, command: str, values: dict[str, int], error: str, detail: str
) -> None:
    writes = sum(model.sensor.writes.values())
    transactions = model.spi_slave.transactions
    name, text = nak(model, command, **values)
    assert name == error
    assert detail in text
    assert sum(model.sensor.writes.values()) == writes
    assert model.spi_slave.transactions == transactions  # refused before the SPI bus


def test_burst_is_all_or_nothing(model: FpgaModel) -> None:
    good = struct.pack(">HH", address("WIN_START"), 10) + struct.pack(">HH", address("OFFSET"), 7)
    bad = good + struct.pack(">HH", address("CHIP_ID"), 1)
    name, detail = nak(model, "REG_WRITE_BURST", pairs=bad)
    assert name == "REG_READ_ONLY" and "CHIP_ID" in detail
    assert model.sensor.register_value("WIN_START") == HR400.register("WIN_START").reset
    assert model.sensor.register_value("OFFSET") == HR400.register("OFFSET").reset
    assert ack(model, "REG_WRITE_BURST", seq=2, pairs=good) == {"count": 2}
    assert model.sensor.register_value("WIN_START") == 10
    assert model.sensor.register_value("OFFSET") == 7


def test_burst_with_a_partial_pair_is_bad_length(model: FpgaModel) -> None:
    name, detail = nak(model, "REG_WRITE_BURST", pairs=b"\x00\x10\x00")
    assert name == "BAD_LENGTH" and "4 bytes each" in detail


def test_burst_under_group_hold_changes_exposure_at_once(model: FpgaModel) -> None:
    hold = address("GROUP_HOLD")
    pairs = [(hold, 1), (address("EXP_HI"), 0x1), (address("EXP_LO"), 0x2345), (hold, 0)]
    ack(model, "REG_WRITE_BURST", pairs=b"".join(struct.pack(">HH", a, v) for a, v in pairs))
    assert model.sensor.exposure_lines == 0x12345


def test_value_wider_than_the_register_is_out_of_range(dictionary: Dictionary) -> None:
    # Every hr400 register is 16 bits wide, as wide as the command's u16: use a narrower map.
    data = HR400.model_dump()
    for reg in data["registers"]:
        if reg["name"] == "OFFSET":
            reg["width"] = 12
            reg["fields"][0]["bits"] = (11, 0)
    narrow = type(HR400).model_validate(data)
    model = FpgaModel(dictionary, seed=3, sensor=narrow)
    name, detail = nak(model, "REG_WRITE", address=address("OFFSET"), value=0x1000)
    assert name == "OUT_OF_RANGE"
    assert "0x1000 does not fit register OFFSET's 12 bits" in detail


def test_get_sensor_identifies_the_sensor_and_link(model: FpgaModel) -> None:
    assert ack(model, "GET_SENSOR") == {
        "interface": "lvds",
        "lanes": 8,
        "trained": "no",
        "imaging": "no",
        "sensor": "hr400",
    }


def test_streaming_is_refused_until_trained(model: FpgaModel) -> None:
    name, detail = nak(model, "START_STREAM", frames=0, stages=0, binning="off")
    assert name == "LINK_UNTRAINED" and "send TRAIN" in detail
    frames = call(model, "TRAIN", seq=2)
    values = model.dictionary.command("TRAIN").decode_response(frames[0].payload)
    assert values["locked"] == "yes" and values["lanes"] == 8 and values["locked_lanes"] == 8
    assert values["bit_errors"] == 0
    assert values["verified_bits"] == 16 * 2048 * 12
    assert event_names(model, frames) == ["LINK_TRAINED"]
    started = ack(model, "START_STREAM", seq=3, frames=0, stages=0, binning="off")
    assert started["rows"] == 534 and started["cols"] == 2048 and started["bits"] == 12
    assert started["mode"] == "area" and started["first_counter"] == 0
    assert ack(model, "GET_SENSOR", seq=4)["imaging"] == "yes"
    assert nak(model, "TRAIN", seq=5)[0] == "ILLEGAL_STATE"  # not while streaming
    name, detail = nak(model, "START_STREAM", seq=6, frames=0, stages=0, binning="off")
    assert name == "ILLEGAL_STATE" and "already streaming" in detail
    stopped = ack(model, "STOP_STREAM", seq=7)
    assert stopped["next_counter"] == stopped["frames_sent"]
    assert ack(model, "GET_SENSOR", seq=8)["imaging"] == "no"


def test_training_restores_the_test_pattern_register(model: FpgaModel) -> None:
    ack(model, "REG_WRITE", address=address("TEST_PATTERN"), value=2)  # ramp
    ack(model, "TRAIN", seq=2)
    assert model.sensor.register_value("TEST_PATTERN") == 2


def test_lanes_report_their_training(model: FpgaModel) -> None:
    ack(model, "TRAIN")
    for lane in range(8):
        values = ack(model, "GET_LANE", seq=lane + 2, lane=lane)
        assert values["lane"] == lane and values["locked"] == "yes"
        assert values["eye_width"] > 0
    name, detail = nak(model, "GET_LANE", seq=20, lane=8)
    assert name == "OUT_OF_RANGE" and "the link has 8 lanes (0..7)" in detail


def test_training_locks_and_captures_bit_exact_for_many_skews(dictionary: Dictionary) -> None:
    import numpy as np

    rng = np.random.default_rng(7)
    frame = rng.integers(0, 4096, size=(8, 2048), dtype=np.uint16)
    for seed in range(20):
        model = FpgaModel(dictionary, seed=seed)
        untrained = model.sensor_link.capture(frame)
        assert not np.array_equal(untrained, frame), seed
        assert ack(model, "TRAIN")["locked"] == "yes", seed
        np.testing.assert_array_equal(model.sensor_link.capture(frame), frame)


def test_reskew_and_reset_lose_the_training(model: FpgaModel) -> None:
    ack(model, "TRAIN")
    frames = call(model, "SIM_RESKEW", seq=2, seed=99)
    assert event_names(model, frames) == ["LINK_LOST"]
    assert ack(model, "GET_SENSOR", seq=3)["trained"] == "no"
    ack(model, "TRAIN", seq=4)
    ack(model, "RESET", seq=5)
    assert ack(model, "GET_SENSOR", seq=6)["trained"] == "no"
    # The sensor's registers belong to the sensor: an FPGA reset keeps them.
    ack(model, "REG_WRITE", seq=7, address=address("WIN_ROWS"), value=64)
    ack(model, "RESET", seq=8)
    assert model.sensor.register_value("WIN_ROWS") == 64


def test_losing_the_training_ends_the_stream_with_stream_done(model: FpgaModel) -> None:
    ack(model, "TRAIN")
    ack(model, "REG_WRITE", seq=2, address=address("WIN_ROWS"), value=8)
    ack(model, "START_STREAM", seq=3, frames=0, stages=0, binning="off")
    frames = call(model, "SIM_RESKEW", seq=4, seed=99)
    assert event_names(model, frames) == ["LINK_LOST", "STREAM_DONE"]
    done = model.dictionary.event("STREAM_DONE").decode(frames[-1].payload)
    assert done["next_counter"] == done["frames_sent"]  # the first stream starts at counter 0
    assert ack(model, "GET_SENSOR", seq=5)["imaging"] == "no"
    # No second STREAM_DONE from the engine once its last frame is out.
    assert model.stream.wait_idle(5.0)
    assert model.take_unsolicited() == []


def test_a_counted_stream_ends_with_one_stream_done(model: FpgaModel) -> None:
    ack(model, "TRAIN")
    ack(model, "REG_WRITE", seq=2, address=address("WIN_ROWS"), value=8)
    started = ack(model, "START_STREAM", seq=3, frames=5, stages=0, binning="off")
    assert model.stream.wait_idle(10.0)
    (event,) = model.take_unsolicited()
    assert model.dictionary.event(event.opcode).name == "STREAM_DONE"
    done = model.dictionary.event("STREAM_DONE").decode(event.payload)
    assert done == {"frames_sent": 5, "next_counter": started["first_counter"] + 5}
    stopped = ack(model, "STOP_STREAM", seq=4)  # harmless after the end
    assert stopped["next_counter"] == started["first_counter"] + 5
    assert model.take_unsolicited() == []


def test_a_replayed_write_is_not_applied_twice(model: FpgaModel) -> None:
    spec = model.dictionary.command("REG_WRITE")
    frame = Frame(
        FrameType.COMMAND, 9, spec.opcode, spec.encode_request(address=address("OFFSET"), value=5)
    )
    model.handle(frame, 1.0)
    model.handle(frame, 1.1)  # the host's retry after a lost ACK
    assert model.sensor.writes[address("OFFSET")] == 1
    stats = ack(model, "SIM_GET_SPI_STATS", seq=10)
    assert stats["writes"] == 1
