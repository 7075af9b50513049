"""What docs/protocol.md used to leave unsaid, now said, and kept true on both devices.

Issue 31 listed what a vendor building a camera from the documents had to guess. Each is now a
statement in docs/protocol.md (generated from config/protocol.toml and camd/protocol/docgen.py),
taken from what the reference device (the simulated camera, firmware_models) does. Each test
here runs the same commands on the reference device and on the device built from the documents
(tests/doc_device), checks the documented behaviour on both, and checks that the document says
it: so the document, the reference device and a device built from the document agree.

In-process and sans-I/O (both devices take frames and a time), so the whole file runs in about
a second.
"""

from __future__ import annotations

import struct
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest

from camd.protocol import Frame, FrameType, load_dictionary
from camd.protocol.docgen import REFUSED_IN_FAULT
from firmware_models.fpga import FpgaModel
from tests.doc_device import wire
from tests.doc_device.device import DocDevice

ROOT = Path(__file__).resolve().parent.parent
PROTOCOL_MD = (ROOT / "docs" / "protocol.md").read_text(encoding="utf-8")
DICT = load_dictionary()
HW_COMMANDS = [c for c in DICT.commands if c.opcode < 0xF0]


@dataclass
class Answer:
    kind: str  # "ACK" or the NAK's error name
    values: dict[str, Any] = field(default_factory=dict)
    events: list[str] = field(default_factory=list)
    event_values: list[dict[str, Any]] = field(default_factory=list)


class Unit:
    """One device, driven with frames: the simulated camera or the doc-built one."""

    def __init__(self, kind: str, sensor: str = "hr400") -> None:
        self.kind = kind
        self.sim: FpgaModel | None = None
        self.doc: DocDevice | None = None
        if kind == "simulator":
            self.sim = FpgaModel(DICT, seed=3, sensor=sensor)
        else:
            self.doc = DocDevice(sensor)
        self.seq = 0
        self.last: tuple[int, int, bytes] | None = None

    def close(self) -> None:
        if self.sim is not None:
            self.sim.close()

    def handle(self, kind: int, seq: int, opcode: int, payload: bytes, t_s: float) -> list[Any]:
        if self.sim is not None:
            return self.sim.handle(Frame(FrameType(kind), seq, opcode, payload), t_s)
        assert self.doc is not None
        return self.doc.handle(wire.Frame(kind, seq, opcode, payload), t_s)

    def send(self, name: str, t_s: float = 1.0, *, raw: bytes | None = None, **values: Any
             ) -> Answer:  # fmt: skip
        spec = DICT.command(name)
        payload = spec.encode_request(**values) if raw is None else raw
        self.seq = (self.seq + 1) % 256
        self.last = (self.seq, spec.opcode, payload)
        return self._answer(name, self.handle(1, self.seq, spec.opcode, payload, t_s))

    def resend(self, name: str, t_s: float = 1.0) -> Answer:
        """The last command again, same sequence number and bytes (a retry)."""
        assert self.last is not None
        return self._answer(name, self.handle(1, *self.last, t_s))

    def _answer(self, name: str, frames: list[Any]) -> Answer:
        first = frames[0]
        events = [f for f in frames[1:] if int(f.type) == int(FrameType.EVENT)]
        names = [DICT.event(f.opcode).name for f in events]
        values = [DICT.event(f.opcode).decode(f.payload) for f in events]
        if int(first.type) == int(FrameType.ACK):
            return Answer("ACK", DICT.command(name).decode_response(first.payload), names, values)
        code, _ = DICT.decode_nak(first.payload)
        return Answer(DICT.error(code).name, {}, names, values)

    def ack(self, name: str, t_s: float = 1.0, **values: Any) -> dict[str, Any]:
        answer = self.send(name, t_s, **values)
        assert answer.kind == "ACK", (self.kind, name, answer)
        return answer.values

    def housekeeping(self, t_s: float) -> None:
        if self.sim is not None:
            self.sim.housekeeping_frame(t_s)
        else:
            assert self.doc is not None
            self.doc.housekeeping_frame(t_s)

    def enter_fault(self, code: int) -> None:
        if self.sim is not None:
            self.ack("SIM_SET_FAULT", fault_code=code)
        else:
            assert self.doc is not None
            self.doc.raise_fault(code)


@pytest.fixture(params=["simulator", "doc_device"])
def unit(request: pytest.FixtureRequest) -> Iterator[Unit]:
    u = Unit(request.param)
    yield u
    u.close()


def _said(*phrases: str) -> None:
    for phrase in phrases:
        assert phrase in PROTOCOL_MD, f"docs/protocol.md does not say {phrase!r}"


def _plain_request(spec: Any) -> dict[str, Any]:
    """A request of well-formed values (not necessarily one the device accepts)."""
    values: dict[str, Any] = {}
    for f in spec.request:
        if f.enum is not None:
            values[f.name] = next(iter(f.enum))
        elif f.type == "bytes":
            values[f.name] = b""
        elif f.type == "str":
            values[f.name] = ""
        else:
            values[f.name] = f.min if f.min is not None and f.min > 0 else 0
    return values


def test_link_stats_count_naks_as_executed_and_every_frame_sent(unit: Unit) -> None:
    _said("ACKed or NAKed alike", "retries answered from the record are not counted",
          "EVENT frames (BOOT at power-on included) and TELEMETRY packets",
          "a frame that is not a COMMAND is counted, ignored and not answered")  # fmt: skip
    before = unit.ack("GET_LINK_STATS")
    unit.ack("PING", data=b"x")
    assert unit.send("REG_READ", address=0x7F).kind == "REG_UNKNOWN"
    assert unit.send("SET_MODE", mode="tdi").events == ["MODE_CHANGED"]
    assert unit.resend("SET_MODE").kind == "ACK"  # replayed, not executed
    assert unit.handle(int(FrameType.TELEMETRY), 9, 1, b"", 1.0) == []  # not a command
    unit.housekeeping(1.0)
    after = unit.ack("GET_LINK_STATS")
    delta = {k: int(after[k]) - int(before[k]) for k in after}
    # Executed: PING, the NAKed REG_READ, SET_MODE and this GET_LINK_STATS.
    assert delta["executed"] == 4 and delta["nacked"] == 1 and delta["replayed"] == 1
    # Received: those four, the retry and the telemetry frame.
    assert delta["rx_frames"] == 6
    # Sent: the first GET_LINK_STATS's ACK, PING's, the NAK, SET_MODE's ACK and its event,
    # the replayed ACK and the housekeeping packet (this GET_LINK_STATS's ACK goes after).
    assert delta["tx_frames"] == 7


def test_a_device_in_fault_refuses_exactly_the_documented_commands(unit: Unit) -> None:
    _said("refused with NAK DEVICE_FAULT: SET_MODE, TRAIN, START_STREAM")
    internal = DICT.error("INTERNAL").code
    unit.enter_fault(internal)
    status = unit.ack("GET_STATUS")
    assert (status["device_state"], status["fault_code"]) == ("fault", internal)
    refused = set()
    for spec in HW_COMMANDS:
        if spec.name == "RESET":
            continue
        answer = unit.send(spec.name, **_plain_request(spec))
        if answer.kind == "DEVICE_FAULT":
            refused.add(spec.name)
    assert refused == {name for name in REFUSED_IN_FAULT if not name.startswith("SIM_")}
    assert unit.send("RESET").kind == "ACK"
    status = unit.ack("GET_STATUS")
    assert (status["device_state"], status["fault_code"]) == ("idle", 0)


def test_device_state_is_idle_while_the_stage_moves_and_a_stream_runs(unit: Unit) -> None:
    _said("idle otherwise, also while a stream runs or the stage moves",
          "busy is reserved and never reported at version 1")  # fmt: skip
    unit.ack("REG_WRITE", address=0x11, value=16)  # WIN_ROWS: a small window
    assert unit.ack("TRAIN")["locked"] == "yes"
    unit.ack("MOTOR_ENABLE", enable="on")
    unit.ack("MOTOR_MOVE", 1.0, target_steps=390000, rate_hz=0)
    unit.ack("START_STREAM", 1.0, frames=0, stages=0, binning="off")
    assert unit.ack("MOTOR_GET", 1.01)["state"] in ("moving", "ramping", "running")
    assert unit.ack("GET_STREAM", 1.01)["streaming"] == "yes"
    assert unit.ack("GET_STATUS", 1.01)["device_state"] == "idle"
    unit.ack("STOP_STREAM", 1.02)


def test_reset_keeps_registers_stage_and_wheel_and_untrains_the_link(unit: Unit) -> None:
    _said("mode back to area (no MODE_CHANGED event)", "no LINK_LOST event; TRAIN again",
          "Kept: the sensor's registers", "RESET does not change it")  # fmt: skip
    assert unit.ack("TRAIN")["locked"] == "yes"
    unit.ack("REG_WRITE", address=0x11, value=100)  # WIN_ROWS
    unit.ack("SET_MODE", mode="tdi")
    unit.ack("MOTOR_ENABLE", enable="on")
    unit.ack("WHEEL_SET_SPEED", speed_deg_s=36.0)
    limits = unit.ack("MOTOR_GET_LIMITS")
    answer = unit.send("RESET", 2.0)
    assert (answer.kind, answer.events) == ("ACK", ["BOOT"])
    assert answer.event_values == [{"boot_count": 2}]
    assert unit.ack("GET_SENSOR", 2.0)["trained"] == "no"
    assert unit.ack("GET_LANE", 2.0, lane=0)["locked"] == "no"
    assert unit.ack("REG_READ", 2.0, address=0x11)["value"] == 100
    status = unit.ack("GET_STATUS", 2.0)
    assert (status["mode"], status["boot_count"], status["uptime_s"]) == ("area", 2, 0.0)
    assert unit.ack("MOTOR_GET", 2.0)["state"] == "idle"  # still enabled
    assert unit.ack("MOTOR_GET_LIMITS", 2.0) == limits
    assert unit.ack("WHEEL_GET", 2.0)["speed_deg_s"] == pytest.approx(36.0)


def test_an_empty_or_ragged_register_burst_is_bad_length_and_writes_nothing(unit: Unit) -> None:
    _said("An empty payload, or one that is not a whole number of 4-byte pairs, is refused "
          "with BAD_LENGTH; nothing is written.")  # fmt: skip
    for raw in (b"", b"\x00\x11\x00", b"\x00\x11\x00\x10\x00"):
        assert unit.send("REG_WRITE_BURST", raw=raw).kind == "BAD_LENGTH", raw
    # One bad pair (read-only CHIP_ID) refuses the whole burst: WIN_ROWS keeps its value.
    burst = struct.pack(">HHHH", 0x11, 200, 0x00, 0)
    assert unit.send("REG_WRITE_BURST", raw=burst).kind == "REG_READ_ONLY"
    assert unit.ack("REG_READ", address=0x11)["value"] == 534


def test_area_mode_takes_any_stage_count_and_tdi_mode_checks_it(unit: Unit) -> None:
    _said("in area mode any value is accepted and ignored, and the headers carry 0")
    unit.ack("REG_WRITE", address=0x11, value=16)  # WIN_ROWS
    unit.ack("TRAIN")
    assert unit.send("START_STREAM", frames=1, stages=4000, binning="off").kind == "ACK"
    unit.ack("STOP_STREAM")
    unit.ack("SET_MODE", mode="tdi")
    assert unit.send("START_STREAM", frames=1, stages=17, binning="off").kind == "OUT_OF_RANGE"
    assert unit.send("START_STREAM", frames=1, stages=0, binning="off").kind == "OUT_OF_RANGE"
    assert unit.send("START_STREAM", frames=1, stages=16, binning="off").kind == "ACK"
    unit.ack("STOP_STREAM")


def test_jogging_into_a_limit_the_stage_stands_at_is_out_of_range(unit: Unit) -> None:
    _said("towards a soft limit the stage stands at (at rest at the high limit, a positive "
          "rate; at the low limit, a negative one)", "while disabled, emergency-stopped or "
          "homing")  # fmt: skip
    unit.ack("MOTOR_ENABLE", enable="on")
    limits = unit.ack("MOTOR_GET_LIMITS")
    steps = unit.ack("MOTOR_GET")["steps"]
    unit.ack("MOTOR_SET_LIMITS", low_steps=steps, high_steps=limits["high_steps"],
             max_rate_hz=limits["max_rate_hz"], accel_hz_per_s=limits["accel_hz_per_s"])  # fmt: skip
    assert unit.send("MOTOR_SET_RATE", rate_hz=-1000.0).kind == "OUT_OF_RANGE"
    # Running into the high limit brakes to a stop there.
    rate = float(limits["max_rate_hz"])
    unit.ack("MOTOR_SET_RATE", 1.0, rate_hz=rate)
    travel_s = (limits["high_steps"] - steps) / rate + rate / limits["accel_hz_per_s"]
    end = unit.send("MOTOR_GET", 1.0 + travel_s + 1.0)
    assert (end.values["steps"], end.values["at_limit"], end.values["state"]) == (
        limits["high_steps"], "high", "idle")  # fmt: skip
    assert end.events == ["MOTOR_STOPPED"] and end.event_values[0]["reason"] == "limit_high"
    assert unit.send("MOTOR_SET_RATE", 30.0, rate_hz=1000.0).kind == "OUT_OF_RANGE"
    # Homing: jogging is refused while it runs.
    unit.ack("MOTOR_HOME", 30.0)
    assert unit.send("MOTOR_SET_RATE", 30.1, rate_hz=-1000.0).kind == "ILLEGAL_STATE"
    unit.ack("MOTOR_STOP", 30.2)


@pytest.mark.parametrize("kind", ["simulator", "doc_device"])
def test_train_on_a_parallel_sensor_is_acknowledged_and_changes_nothing(kind: str) -> None:
    _said("A sensor with a parallel interface has no link to train: TRAIN is acknowledged "
          "with lanes 0, locked_lanes 0, locked yes, bit_errors 0, verified_bits 0")  # fmt: skip
    unit = Unit(kind, sensor="mt9m001")
    try:
        answer = unit.send("TRAIN")
        assert answer.kind == "ACK"
        assert answer.values == {"lanes": 0, "locked_lanes": 0, "locked": "yes",
                                 "bit_errors": 0, "verified_bits": 0}  # fmt: skip
        assert answer.events == ["LINK_TRAINED"]
        assert answer.event_values == [{"locked": "yes", "bit_errors": 0}]
        sensor = unit.ack("GET_SENSOR")
        assert (sensor["interface"], sensor["lanes"], sensor["trained"]) == ("parallel", 0, "yes")
        assert unit.send("GET_LANE", lane=0).kind == "OUT_OF_RANGE"
    finally:
        unit.close()


def test_the_wheel_turns_from_power_on_and_its_windows_are_angles(unit: Unit) -> None:
    _said("From power-on the wheel turns at its nominal speed (config/wheel.toml speed_deg_s, "
          "73.245 deg/s) from angle 0 (channel 0 centred)",
          "within speed_deg_s x window_s / 2 of its centre i x 360 / channel_count")  # fmt: skip
    w0, half = 73.245, 73.245 * 0.120 / 2
    start = unit.ack("WHEEL_GET", 0.0)
    assert start["speed_deg_s"] == pytest.approx(w0, rel=1e-6)
    assert (start["angle_deg"], start["channel"]) == (0.0, 0)
    assert unit.ack("WHEEL_GET", 1.0)["angle_deg"] == pytest.approx(w0, rel=1e-5)
    centre = 360.0 / 13
    inside, outside = centre + half - 0.01, centre + half + 0.01
    assert unit.ack("WHEEL_GET", inside / w0)["channel"] == 1
    assert unit.ack("WHEEL_GET", outside / w0)["channel"] == 255
    # At another speed the windows stay where they are on the wheel.
    now = 2.0
    angle = unit.ack("WHEEL_GET", now)["angle_deg"]
    unit.ack("WHEEL_SET_SPEED", now, speed_deg_s=36.0)
    spin = 36.0
    ahead = (2 * centre + half - 0.02 - angle) % 360.0
    assert unit.ack("WHEEL_GET", now + ahead / spin)["channel"] == 2
    assert unit.ack("WHEEL_GET", now + (ahead + 0.04) / spin)["channel"] == 255


def test_a_wheel_speed_too_slow_for_its_period_is_refused_and_changes_nothing(unit: Unit) -> None:
    # Found by test_fpga_model's fuzzing: the speed 1.4e-45 deg/s (payload 00 00 00 01) made a
    # period of 2.6e47 s that no f32 holds, and the simulator answered INTERNAL.
    _said("A speed above 0 and below 1e-7 deg/s (a turn in 114 years, whose period might not fit "
          "the answer) is refused with OUT_OF_RANGE and changes nothing.")  # fmt: skip
    before = unit.ack("WHEEL_GET", 1.0)["speed_deg_s"]
    for raw in (b"\x00\x00\x00\x01", struct.pack(">f", 9.9e-8)):
        assert unit.send("WHEEL_SET_SPEED", 1.0, raw=raw).kind == "OUT_OF_RANGE"
    assert unit.ack("WHEEL_GET", 1.0)["speed_deg_s"] == before
    slowest = unit.ack("WHEEL_SET_SPEED", 1.0, speed_deg_s=1e-6)["period_s"]
    assert slowest == pytest.approx(3.6e8, rel=1e-6)
    assert unit.ack("WHEEL_SET_SPEED", 1.0, speed_deg_s=0.0)["period_s"] == 0.0


def test_a_refused_read_only_write_leaves_the_spi_error_flag_clear(unit: Unit) -> None:
    _said("a refused write never reaches the sensor, so it does not set the sensor's SPI "
          "error flag")  # fmt: skip
    assert unit.send("REG_WRITE", address=0x00, value=0).kind == "REG_READ_ONLY"  # CHIP_ID
    flags = unit.ack("REG_READ", address=0x02)["value"]  # FLAGS
    assert flags & 0b100 == 0  # FLAGS.spi_error


def test_every_command_checks_length_and_range_before_state(unit: Unit) -> None:
    _said("an opcode it does not implement gets NAK UNKNOWN_OPCODE; a payload length the "
          "command does not take (section 5) NAK BAD_LENGTH")  # fmt: skip
    unit.enter_fault(DICT.error("INTERNAL").code)
    for spec in HW_COMMANDS:
        longest = sum(f.size if f.size is not None else (f.max_len or 0) for f in spec.request)
        answer = unit.send(spec.name, raw=b"\x00" * (longest + 1))
        assert answer.kind == "BAD_LENGTH", (spec.name, answer)
    assert unit.send("SET_MODE", raw=b"\x07").kind == "OUT_OF_RANGE"  # before DEVICE_FAULT
    assert unit.send("SET_MODE", mode="tdi").kind == "DEVICE_FAULT"


def test_lvds_lanes_and_clock_roles_decide_which_lanes_can_lock(unit: Unit) -> None:
    """docs/sensors.md: hr400 LVDS_CTRL resets with every lane and the clock on (the daemon
    trains at reset values), and a lane switched off, or the clock lane, cannot lock."""
    sensors_md = (ROOT / "docs" / "sensors.md").read_text(encoding="utf-8")
    assert "| 0x25 | `LVDS_CTRL` | 16 | RW |  | 0x01FF |" in sensors_md
    assert "| `lvds_clock` | `LVDS_CTRL.clock` |" in sensors_md
    trained = unit.ack("TRAIN")
    assert (trained["locked"], trained["locked_lanes"]) == ("yes", 8)
    unit.ack("REG_WRITE", address=0x25, value=0x01FB)  # lane 2 off
    trained = unit.ack("TRAIN")
    assert (trained["locked"], trained["locked_lanes"]) == ("no", 7)
    assert unit.ack("GET_LANE", lane=2)["locked"] == "no"
    assert unit.ack("GET_SENSOR")["trained"] == "no"
    unit.ack("REG_WRITE", address=0x25, value=0x00FF)  # the clock lane off
    trained = unit.ack("TRAIN")
    assert (trained["locked"], trained["locked_lanes"]) == ("no", 0)
    unit.ack("REG_WRITE", address=0x25, value=0x01FF)
    assert unit.ack("TRAIN")["locked"] == "yes"


def test_device_time_counts_from_power_on_through_a_reset(unit: Unit) -> None:
    """MOTOR_GET and WHEEL_GET time_s: the device clock since power-on; RESET restarts the
    uptime only."""
    _said("seconds since power-on (RESET does not restart it, unlike uptime_s)")
    unit.send("RESET", 5.0)
    assert unit.ack("GET_STATUS", 7.0)["uptime_s"] == pytest.approx(2.0)
    assert unit.ack("MOTOR_GET", 7.0)["time_s"] == pytest.approx(7.0)
    assert unit.ack("WHEEL_GET", 7.0)["time_s"] == pytest.approx(7.0)
