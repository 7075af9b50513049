"""The command processor of a camera built from the documents (see the package docstring).

``DocDevice.handle(frame, now_s)`` takes one received frame and returns the frames to send:
the ACK or NAK, then the events the command caused (docs/protocol.md §4). Time is passed in.
Each behaviour names the sentence of the documents it implements.
"""

from __future__ import annotations

import math
import struct
import tomllib
from dataclasses import dataclass
from typing import Any

from tests.doc_device.wire import (
    ACK,
    COMMAND,
    EVENT,
    NAK,
    REPO,
    TELEMETRY,
    BadLength,
    Dictionary,
    Frame,
    OutOfRange,
    ReceiverCounters,
    load_dictionary,
)

FW_VERSION = 0x0100  # GET_STATUS fw_version: major * 256 + minor, our 1.0


class Refused(Exception):
    """Answer the command with a NAK carrying this error (docs/protocol.md §8)."""

    def __init__(self, error: str, detail: str) -> None:
        super().__init__(detail)
        self.error, self.detail = error, detail


# -- the sensor's registers (docs/sensors.md §1, §2; config/sensors/<name>.toml) ---------------


def _mask(bits: list[int]) -> int:
    hi, lo = bits
    return ((1 << (hi - lo + 1)) - 1) << lo


@dataclass(slots=True)
class Register:
    name: str
    address: int
    width: int
    access: str
    reset: int
    volatile: bool
    fields: dict[str, tuple[int, dict[str, int] | None]]  # name -> (mask, enum)

    @property
    def readable(self) -> bool:
        return self.access != "wo"

    @property
    def writable(self) -> bool:
        return self.access != "ro"


class SensorRegisters:
    """The sensor behind the FPGA's SPI master: its map, values, group hold and soft reset."""

    def __init__(self, sensor: str) -> None:
        data = tomllib.loads((REPO / "config" / "sensors" / f"{sensor}.toml").read_text())
        self.name = sensor
        self.data = data
        self.output = data["output"]
        self.timing = data["timing"]
        self.roles: dict[str, str] = data.get("roles", {})
        self.registers: dict[int, Register] = {}
        self.by_name: dict[str, Register] = {}
        for r in data["registers"]:
            fields = {f["name"]: (_mask(f["bits"]), f.get("enum")) for f in r.get("fields", [])}
            reg = Register(r["name"], int(r["address"]), int(r["width"]), r["access"],
                           int(r.get("reset", 0)), bool(r.get("volatile", False)), fields)  # fmt: skip
            self.registers[reg.address] = reg
            self.by_name[reg.name] = reg
        # Group hold (docs/sensors.md §1 [[groups]]): writes to the members are latched while
        # the hold bit is 1 and applied together when it returns to 0.
        self.hold: dict[str, tuple[str, int]] = {}
        for g in data.get("groups", []):
            if g.get("hold"):
                reg_name, field_name = g["hold"].split(".")
                for member in g["registers"]:
                    self.hold[member] = (reg_name, self.by_name[reg_name].fields[field_name][0])
        self.values = {a: r.reset for a, r in self.registers.items()}
        self.latched: dict[int, int] = {}
        soft = data.get("soft_reset")
        self.soft_reset: tuple[str, int] | None = None
        if soft:
            reg_name, _ = soft["field"].split(".")
            self.soft_reset = (reg_name, int(soft["value"]))

    def field(self, name: str) -> int:
        """A register's or REGISTER.field's value now."""
        reg_name, _, field_name = name.partition(".")
        reg = self.by_name[reg_name]
        value = self.values[reg.address]
        if not field_name:
            return value
        mask = reg.fields[field_name][0]
        return (value & mask) >> ((mask & -mask).bit_length() - 1)

    def group_value(self, group: str) -> int:
        g = next(g for g in self.data.get("groups", []) if g["name"] == group)
        value = 0
        for member in g["registers"]:
            reg = self.by_name[member]
            value = (value << reg.width) | self.values[reg.address]
        return value

    def role_value(self, role: str) -> int:
        target = self.roles[role]
        if any(g["name"] == target for g in self.data.get("groups", [])):
            return self.group_value(target)
        return self.field(target)

    def write(self, address: int, value: int) -> None:
        """One SPI write, as the sensor applies it."""
        reg = self.registers[address]
        if self.soft_reset and reg.name == self.soft_reset[0]:
            if value == self.soft_reset[1]:
                self.values = {a: r.reset for a, r in self.registers.items()}
                self.latched.clear()
            return
        if reg.access == "w1c":
            self.values[address] &= ~value
            return
        held = self.hold.get(reg.name)
        if held is not None and self.values[self.by_name[held[0]].address] & held[1]:
            self.latched[address] = value
            return
        self.values[address] = value
        for member, (hold_reg, bit) in self.hold.items():
            if hold_reg == reg.name and not value & bit:
                target = self.by_name[member].address
                if target in self.latched:
                    self.values[target] = self.latched.pop(target)

    # -- timing (docs/sensors.md "Timing": model sequencer) -------------------------------

    def line_period_s(self) -> float:
        return float(self.timing["clocks_per_line"]) / float(self.timing["clock_hz"])

    def frame_time_s(self) -> float:
        """docs/wheel.md: T_frame = (n + k + 1) T_line."""
        n, k = self.role_value("exposure_lines"), self.role_value("window_rows")
        return (n + k + 1) * self.line_period_s()

    def frame_period_s(self) -> float:
        """docs/sensors.md: frame period max(k, n + 1) T_line + back path (in clocks)."""
        n, k = self.role_value("exposure_lines"), self.role_value("window_rows")
        back = self.role_value("back_path") / float(self.timing["clock_hz"]) if (
            "back_path" in self.roles) else 0.0  # fmt: skip
        return max(k, n + 1) * self.line_period_s() + back


# -- the stage (docs/motion.md) -----------------------------------------------------------


@dataclass(slots=True)
class Piece:
    """Constant acceleration from ``t_s``: position ``p``, rate ``v``, acceleration ``a``."""

    t_s: float
    p: float
    v: float
    a: float

    def at(self, t_s: float) -> tuple[float, float]:
        dt = t_s - self.t_s
        return self.p + self.v * dt + 0.5 * self.a * dt * dt, self.v + self.a * dt


class Stage:
    """docs/motion.md "State machine", "Power-on", with an ideal motor (no stall)."""

    def __init__(self, profile: str = "linear_rail") -> None:
        data = tomllib.loads((REPO / "config" / "stages" / f"{profile}.toml").read_text())
        usteps = data["full_steps_per_rev"]["value"] * data["microsteps"]["value"]
        self.m_per_step = data["lead_m_per_rev"]["value"] / usteps
        self.counts_per_m = data["linear_encoder_counts_per_m"]["value"]
        travel = round(data["travel_m"]["value"] / self.m_per_step)
        self.hw_low, self.hw_high = 0, travel
        self.low, self.high = 0, travel
        self.hw_max_rate = data["max_speed_m_s"]["value"] / self.m_per_step
        self.hw_accel = int(data["max_accel_m_s2"]["value"] / self.m_per_step)
        self.max_rate, self.accel = self.hw_max_rate, self.hw_accel
        self.home_rate = data["home_speed_m_s"]["value"] / self.m_per_step
        self.driver = "disabled"
        self.homed = False
        # Power-on: in the middle of the travel, at rest.
        self.pieces = [Piece(0.0, travel / 2, 0.0, 0.0)]
        self.end_s: float | None = None  # when the motion in progress stops, None: at rest
        self.kind = "idle"  # ramping/running (jog), moving, homing
        self.reason = "done"
        self.events: list[tuple[float, dict[str, Any]]] = []

    def _piece(self, t_s: float) -> Piece:
        return next(p for p in reversed(self.pieces) if p.t_s <= t_s)

    def at(self, t_s: float) -> tuple[float, float]:
        if self.end_s is not None and t_s >= self.end_s:
            return self._piece(self.end_s).at(self.end_s)[0], 0.0
        return self._piece(t_s).at(t_s)

    def steps(self, t_s: float) -> int:
        return round(self.at(t_s)[0])

    def encoder(self, t_s: float) -> int:
        return math.floor(self.at(t_s)[0] * self.m_per_step * self.counts_per_m + 1e-9)

    def advance(self, t_s: float) -> None:
        """A motion that ended by ``t_s`` becomes a MOTOR_STOPPED event."""
        if self.end_s is not None and self.end_s <= t_s:
            end = self.end_s
            p, _ = self._piece(end).at(end)
            self.pieces = [Piece(end, float(round(p)), 0.0, 0.0)]
            self.end_s = None
            if self.kind == "homing":
                self.pieces = [Piece(end, 0.0, 0.0, 0.0)]
                self.homed = True
            self.kind = "idle"
            self.events.append((end, {"reason": self.reason, "steps": self.steps(end),
                                      "encoder": self.encoder(end)}))  # fmt: skip

    def state(self, t_s: float) -> str:
        if self.driver != "enabled":
            return self.driver
        if self.end_s is None:
            return "idle"
        if self.kind in ("moving", "homing"):
            return self.kind
        return "ramping" if self._piece(t_s).a else "running"

    def plan_to(self, t_s: float, target: float, rate: float, kind: str, reason: str) -> float:
        """A trapezoid to ``target`` at cruise ``rate``; a moving stage first brakes to rest
        (docs/motion.md MOVE: "it first brakes to rest"). Returns when it will stand still."""
        p, v = self.at(t_s)
        a = float(self.accel)
        pieces: list[Piece] = []
        t = t_s
        if v:
            brake = abs(v) / a
            pieces.append(Piece(t, p, v, -math.copysign(a, v)))
            p, t = p + v * brake / 2, t + brake
        distance = target - p
        sign = math.copysign(1.0, distance)
        d = abs(distance)
        if d > 0:
            if d >= rate * rate / a:  # cruises
                ramp = rate / a
                cruise = (d - rate * rate / a) / rate
                pieces += [Piece(t, p, 0.0, sign * a),
                           Piece(t + ramp, p + sign * rate * ramp / 2, sign * rate, 0.0),
                           Piece(t + ramp + cruise, target - sign * rate * ramp / 2, sign * rate,
                                 -sign * a)]  # fmt: skip
                t += 2 * ramp + cruise
            else:  # a triangle
                half = math.sqrt(d / a)
                pieces += [Piece(t, p, 0.0, sign * a),
                           Piece(t + half, p + sign * d / 2, sign * a * half, -sign * a)]  # fmt: skip
                t += 2 * half
        pieces.append(Piece(t, target, 0.0, 0.0))
        self._replace(t_s, pieces, t, kind, reason)
        return t - t_s

    def stop(self, t_s: float, reason: str = "done") -> float:
        p, v = self.at(t_s)
        if self.end_s is None:
            return 0.0
        brake = abs(v) / self.accel
        self._replace(t_s, [Piece(t_s, p, v, -math.copysign(self.accel, v) if v else 0.0),
                            Piece(t_s + brake, p + v * brake / 2, 0.0, 0.0)],
                      t_s + brake, self.kind, reason)  # fmt: skip
        return brake

    def halt(self, t_s: float) -> None:
        """ESTOP: the pulses stop at once."""
        p, _ = self.at(t_s)
        self.pieces = [Piece(t_s, float(round(p)), 0.0, 0.0)]
        self.end_s = None
        self.kind = "idle"

    def _replace(
        self, t_s: float, pieces: list[Piece], end_s: float, kind: str, reason: str
    ) -> None:
        self.pieces = [p for p in self.pieces if p.t_s < t_s] + pieces
        self.end_s, self.kind, self.reason = end_s, kind, reason


# -- the filter wheel (docs/wheel.md, config/wheel.toml) ------------------------------------


class Wheel:
    """Constant-speed wheel; angle from channel 0's centre, channel i at i * 360 / count."""

    def __init__(self) -> None:
        data = tomllib.loads((REPO / "config" / "wheel.toml").read_text())
        self.count = int(data["channel_count"]["value"])
        self.nominal_deg_s = float(data["speed_deg_s"]["value"])
        self.t_center_s = float(data["t_center_s"]["value"])
        self.window_s = float(data["window_s"]["value"])
        # docs/protocol.md WHEEL_GET: at power-on the wheel turns at the nominal speed, angle 0.
        self.t0_s, self.angle0, self.speed = 0.0, 0.0, self.nominal_deg_s

    def angle(self, t_s: float) -> float:
        return (self.angle0 + self.speed * (t_s - self.t0_s)) % 360.0

    def set_speed(self, speed: float, t_s: float) -> None:
        self.angle0, self.t0_s, self.speed = self.angle(t_s), t_s, speed

    def channel(self, t_s: float) -> int | None:
        """The light window as an angle: nominal speed x window_s, centred on the channel."""
        spacing = 360.0 / self.count
        angle = self.angle(t_s)
        nearest = round(angle / spacing) % self.count
        off = (angle - nearest * spacing + 180.0) % 360.0 - 180.0
        return nearest if abs(off) <= self.nominal_deg_s * self.window_s / 2 else None


# -- the device ---------------------------------------------------------------------------

# docs/protocol.md §4 "Device in fault": the commands refused with DEVICE_FAULT.
REFUSED_IN_FAULT = frozenset({
    "SET_MODE", "TRAIN", "START_STREAM", "WHEEL_ACQUIRE", "MOTOR_ENABLE", "MOTOR_SET_RATE",
    "MOTOR_MOVE", "MOTOR_HOME", "MOTOR_SET_LIMITS",
})  # fmt: skip

VERIFY_ROWS = 16  # rows of the PRBS frame TRAIN checks (the device's own choice)


class DocDevice:
    """A camera built from docs/protocol.md and the data files; hardware, so the simulator-only
    opcodes are unknown (docs/protocol.md §4)."""

    def __init__(self, sensor: str = "hr400", stage: str = "linear_rail") -> None:
        self.dictionary: Dictionary = load_dictionary()
        self.sensor = SensorRegisters(sensor)
        self.stage = Stage(stage)
        self.wheel = Wheel()
        self.compensation = False
        self.mode = "area"
        self.fault_code = 0
        self.boot_count = 1
        self.uptime_from_s = 0.0
        self.lvds = self.sensor.output["interface"] == "lvds"
        # GET_SENSOR lanes: "LVDS data lanes (0 for a parallel interface)".
        self.lanes = int(self.sensor.output.get("lanes", 0)) if self.lvds else 0
        self.trained = not self.lvds  # a parallel interface is always trained (GET_SENSOR)
        self.lane_results: list[tuple[int, int, int, int, bool]] = []
        self.streaming = False
        self.stream_end_s: float | None = None
        self.frames_sent = 0
        self.next_counter = 0
        self.counters = {"rx_frames": 0, "executed": 0, "replayed": 0, "nacked": 0, "tx_frames": 0}
        self.record: tuple[Frame, Frame] | None = None
        # The transport's receiver counts CRC errors and resyncs (PtyDevice sets it).
        self.receiver_counters = ReceiverCounters()
        self._unsolicited_seq = 0

    # -- frames ----------------------------------------------------------------------------

    def handle(self, frame: Frame, now_s: float) -> list[Frame]:
        self.counters["rx_frames"] += 1
        if frame.type != COMMAND:
            return []
        if self.record is not None and self.record[0] == frame:  # §4 at-most-once
            self.counters["replayed"] += 1
            return self.sent([self.record[1]])
        self.counters["executed"] += 1
        events: list[Frame] = []
        command = self.dictionary.commands.get(frame.opcode)
        try:
            if command is None or frame.opcode >= 0xF0:
                raise Refused("UNKNOWN_OPCODE", f"opcode 0x{frame.opcode:02X} is not implemented")
            try:
                request = command.request.decode(frame.payload)
            except BadLength as exc:
                raise Refused("BAD_LENGTH", f"{command.name}: {exc}") from None
            except OutOfRange as exc:
                raise Refused("OUT_OF_RANGE", f"{command.name}: {exc}") from None
            if self.fault_code and command.name in REFUSED_IN_FAULT:
                raise Refused("DEVICE_FAULT", f"{command.name} refused in fault; RESET clears it")
            handler = getattr(self, "_" + command.name.lower())
            values = handler(request, now_s, events)
            answer = Frame(ACK, frame.seq, frame.opcode, command.response.encode(**values))
        except Refused as refusal:
            self.counters["nacked"] += 1
            payload = self.dictionary.nak_payload(refusal.error, refusal.detail)
            answer = Frame(NAK, frame.seq, frame.opcode, payload)
            events = []
        self.record = (frame, answer)
        return self.sent([answer, *events])

    def sent(self, frames: list[Frame]) -> list[Frame]:
        """Every frame the device sends counts in tx_frames (§5 GET_LINK_STATS)."""
        self.counters["tx_frames"] += len(frames)
        return frames

    def event(self, name: str, **values: Any) -> Frame:
        opcode, layout = self.dictionary.events[name]
        return self._unsolicited(EVENT, opcode, layout.encode(**values))

    def _unsolicited(self, kind: int, opcode: int, payload: bytes) -> Frame:
        seq = self._unsolicited_seq
        self._unsolicited_seq = (seq + 1) % 256
        return Frame(kind, seq, opcode, payload)

    def boot_frames(self) -> list[Frame]:
        return self.sent([self.event("BOOT", boot_count=self.boot_count)])

    def housekeeping_frame(self, now_s: float) -> Frame:
        opcode, layout = self.dictionary.telemetry["HOUSEKEEPING"]
        payload = layout.encode(**self._housekeeping(now_s))
        return self.sent([self._unsolicited(TELEMETRY, opcode, payload)])[0]

    def unsolicited(self, now_s: float) -> list[Frame]:
        """Events due by ``now_s`` that no command caused: stage stops, a counted stream's end."""
        frames: list[Frame] = []
        self.stage.advance(now_s)
        for _, values in self.stage.events:
            frames.append(self.event("MOTOR_STOPPED", **values))
        self.stage.events.clear()
        if self.streaming and self.stream_end_s is not None and now_s >= self.stream_end_s:
            self.streaming = False
            frames.append(self.event("STREAM_DONE", frames_sent=self.frames_sent,
                                     next_counter=self.next_counter))  # fmt: skip
        return self.sent(frames)

    def raise_fault(self, code: int) -> list[Frame]:
        """The device enters fault (hardware would, on its own; tests call this)."""
        self.fault_code = code
        return self.sent([self.event("FAULT", fault_code=code)])

    # -- general ----------------------------------------------------------------------------

    def _housekeeping(self, now_s: float) -> dict[str, Any]:
        return {"uptime_s": now_s - self.uptime_from_s, "fpga_temp_degc": 45.0,
                "sensor_temp_degc": 25.0, "vcc_core_v": 1.0, "vcc_io_v": 3.3,
                "vcc_sensor_v": 3.3, "supply_current_a": 0.8,
                "executed": self.counters["executed"] % 2**32}  # fmt: skip

    def _ping(self, r: dict[str, Any], now_s: float, ev: list[Frame]) -> dict[str, Any]:
        return {"data": r["data"]}

    def _get_status(self, r: dict[str, Any], now_s: float, ev: list[Frame]) -> dict[str, Any]:
        # device_state: fault while a fault is active, else idle; never busy (§5 GET_STATUS).
        return {"mode": self.mode, "device_state": "fault" if self.fault_code else "idle",
                "fault_code": self.fault_code, "uptime_s": now_s - self.uptime_from_s,
                "fw_version": FW_VERSION, "boot_count": self.boot_count}  # fmt: skip

    def _get_housekeeping(self, r: dict[str, Any], now_s: float, ev: list[Frame]) -> dict[str, Any]:
        return self._housekeeping(now_s)

    def _reset(self, r: dict[str, Any], now_s: float, ev: list[Frame]) -> dict[str, Any]:
        # §5 RESET: mode area, fault cleared, uptime restarted, the stream stopped (no
        # STREAM_DONE), the LVDS link untrained (no LINK_LOST); registers, stage and wheel kept.
        self.mode, self.fault_code = "area", 0
        self.streaming = False
        self.trained = not self.lvds
        self.lane_results = []
        self.boot_count = (self.boot_count + 1) % 0x10000
        self.uptime_from_s = now_s
        ev.append(self.event("BOOT", boot_count=self.boot_count))
        return {}

    def _set_mode(self, r: dict[str, Any], now_s: float, ev: list[Frame]) -> dict[str, Any]:
        if r["mode"] != self.mode:
            self.mode = r["mode"]
            ev.append(self.event("MODE_CHANGED", mode=self.mode))
        return {"mode": self.mode}

    def _get_link_stats(self, r: dict[str, Any], now_s: float, ev: list[Frame]) -> dict[str, Any]:
        rx = self.receiver_counters
        c = self.counters
        return {"rx_frames": c["rx_frames"], "crc_errors": rx.crc_errors,
                "resyncs": rx.resyncs, "bytes_dropped": rx.bytes_dropped,
                "executed": c["executed"], "replayed": c["replayed"], "nacked": c["nacked"],
                "tx_frames": c["tx_frames"]}  # fmt: skip

    # -- registers ------------------------------------------------------------------------

    def _register(self, name: str, address: int) -> Register:
        reg = self.sensor.registers.get(address)
        if reg is None:
            raise Refused("REG_UNKNOWN", f"{name}: no register at 0x{address:02X}")
        return reg

    def _check_write(self, name: str, address: int, value: int) -> None:
        reg = self._register(name, address)
        if not reg.writable:
            # Refused before the SPI write: the sensor never sees it (FLAGS.spi_error stays).
            raise Refused("REG_READ_ONLY", f"{name}: {reg.name} is read-only")
        if value >> reg.width:
            raise Refused("OUT_OF_RANGE", f"{name}: 0x{value:X} is wider than {reg.name}")

    def _reg_read(self, r: dict[str, Any], now_s: float, ev: list[Frame]) -> dict[str, Any]:
        reg = self._register("REG_READ", r["address"])
        if not reg.readable:
            raise Refused("REG_WRITE_ONLY", f"REG_READ: {reg.name} is write-only")
        return {"address": reg.address, "value": self.sensor.values[reg.address]}

    def _reg_write(self, r: dict[str, Any], now_s: float, ev: list[Frame]) -> dict[str, Any]:
        self._check_write("REG_WRITE", r["address"], r["value"])
        self.sensor.write(r["address"], r["value"])
        return {"address": r["address"], "value": r["value"]}

    def _reg_write_burst(self, r: dict[str, Any], now_s: float, ev: list[Frame]) -> dict[str, Any]:
        data: bytes = r["pairs"]
        if not data or len(data) % 4:  # §5 REG_WRITE_BURST: empty or ragged is BAD_LENGTH
            raise Refused("BAD_LENGTH", f"REG_WRITE_BURST: {len(data)} bytes; send 4-byte pairs")
        pairs = list(struct.iter_unpack(">HH", data))
        for address, value in pairs:
            self._check_write("REG_WRITE_BURST", address, value)
        for address, value in pairs:
            self.sensor.write(address, value)
        return {"count": len(pairs)}

    def _get_sensor(self, r: dict[str, Any], now_s: float, ev: list[Frame]) -> dict[str, Any]:
        return {"interface": self.sensor.output["interface"], "lanes": self.lanes,
                "trained": "yes" if self.trained else "no",
                "imaging": "yes" if self.streaming else "no", "sensor": self.sensor.name}  # fmt: skip

    # -- LVDS training -------------------------------------------------------------------

    def _train(self, r: dict[str, Any], now_s: float, ev: list[Frame]) -> dict[str, Any]:
        if self.streaming:
            raise Refused("ILLEGAL_STATE", "TRAIN refused while imaging; STOP_STREAM first")
        if not self.lvds:
            # §5 TRAIN on a parallel sensor: acknowledged, 0 lanes, locked, nothing verified.
            ev.append(self.event("LINK_TRAINED", locked="yes", bit_errors=0))
            return {"lanes": 0, "locked_lanes": 0, "locked": "yes", "bit_errors": 0,
                    "verified_bits": 0}  # fmt: skip
        # docs/sensors.md roles: a lane sends data only while its lvds_lanes bit is 1 and the
        # lvds_clock lane is on; a lane that sends nothing cannot lock.
        clock = not self.sensor.roles.get("lvds_clock") or bool(
            self.sensor.role_value("lvds_clock")
        )
        bits = (
            self.sensor.role_value("lvds_lanes")
            if self.sensor.roles.get("lvds_lanes")
            else (1 << self.lanes) - 1
        )
        enabled = [clock and bool(bits >> i & 1) for i in range(self.lanes)]
        self.lane_results = [(i, 16, 20 if on else 0, 0, 0, on) for i, on in enumerate(enabled)]
        locked = all(enabled)
        columns = int(self.sensor.data["columns"])
        verified = VERIFY_ROWS * columns * int(self.sensor.output["word_bits"]) if locked else 0
        self.trained = locked
        ev.append(self.event("LINK_TRAINED", locked="yes" if locked else "no", bit_errors=0))
        return {"lanes": self.lanes, "locked_lanes": sum(enabled),
                "locked": "yes" if locked else "no", "bit_errors": 0, "verified_bits": verified}  # fmt: skip

    def _get_lane(self, r: dict[str, Any], now_s: float, ev: list[Frame]) -> dict[str, Any]:
        lane = r["lane"]
        if lane >= self.lanes:
            raise Refused("OUT_OF_RANGE", f"GET_LANE: lane {lane}; the link has {self.lanes}")
        if lane < len(self.lane_results):
            _, tap, eye, slips, shift, on = self.lane_results[lane]
        else:
            tap, eye, slips, shift, on = 0, 0, 0, 0, False
        return {"lane": lane, "tap": tap, "eye_width": eye, "slips": slips, "shift": shift,
                "locked": "yes" if on else "no"}  # fmt: skip

    # -- stream (no USB here: frames go nowhere, but the counters run) ------------------------

    def _start_stream(self, r: dict[str, Any], now_s: float, ev: list[Frame]) -> dict[str, Any]:
        if self.streaming:
            raise Refused("ILLEGAL_STATE", "START_STREAM refused: already streaming")
        if not self.trained:
            raise Refused("LINK_UNTRAINED", "START_STREAM refused: TRAIN first")
        rows = self.sensor.role_value("window_rows")
        cols = int(self.sensor.data["columns"])
        # §5 START_STREAM stages: checked in tdi mode only; in area mode any value is taken and
        # the frame headers carry 0.
        if self.mode == "tdi" and not 1 <= r["stages"] <= rows:
            raise Refused("OUT_OF_RANGE", f"START_STREAM: stages {r['stages']}; use 1..{rows}")
        binned = r["binning"] == "2x2"
        if binned and (rows % 2 or cols % 2):
            raise Refused("OUT_OF_RANGE", "START_STREAM: 2x2 binning needs an even window")
        period = self.sensor.frame_period_s()
        self.streaming = True
        first = self.next_counter
        frames = r["frames"]
        self.frames_sent = frames
        self.next_counter = first + frames
        self.stream_end_s = now_s + frames * period if frames else None
        bits = int(self.sensor.output["word_bits"]) + (2 if binned else 0)
        return {"mode": self.mode, "rows": rows // 2 if binned else rows,
                "cols": cols // 2 if binned else cols, "bits": bits,
                "frame_period_s": period, "first_counter": first}  # fmt: skip

    def _stop_stream(self, r: dict[str, Any], now_s: float, ev: list[Frame]) -> dict[str, Any]:
        self.streaming = False
        return {"frames_sent": self.frames_sent, "next_counter": self.next_counter}

    def _get_stream(self, r: dict[str, Any], now_s: float, ev: list[Frame]) -> dict[str, Any]:
        return {"streaming": "yes" if self.streaming else "no", "frames_sent": self.frames_sent,
                "next_counter": self.next_counter, "host_connected": "no"}  # fmt: skip

    # -- stage ---------------------------------------------------------------------------

    def _driver_on(self, name: str) -> None:
        if self.stage.driver != "enabled":
            raise Refused("ILLEGAL_STATE", f"{name} refused: the driver is {self.stage.driver}")
        if self.stage.kind == "homing" and self.stage.end_s is not None:
            raise Refused("ILLEGAL_STATE", f"{name} refused while homing")

    def _stage_now(self, now_s: float, ev: list[Frame]) -> float:
        self.stage.advance(now_s)
        for _, values in self.stage.events:
            ev.append(self.event("MOTOR_STOPPED", **values))
        self.stage.events.clear()
        return now_s

    def _motor_enable(self, r: dict[str, Any], now_s: float, ev: list[Frame]) -> dict[str, Any]:
        t = self._stage_now(now_s, ev)
        if r["enable"] == "on":
            self.stage.driver = "enabled"
        elif self.stage.end_s is not None:
            raise Refused("ILLEGAL_STATE", "MOTOR_ENABLE off refused while moving; MOTOR_STOP")
        elif self.stage.driver != "estop":
            self.stage.driver = "disabled"
        return {"steps": self.stage.steps(t), "encoder": self.stage.encoder(t)}

    def _motor_set_rate(self, r: dict[str, Any], now_s: float, ev: list[Frame]) -> dict[str, Any]:
        t = self._stage_now(now_s, ev)
        self._driver_on("MOTOR_SET_RATE")
        rate = float(r["rate_hz"])
        if abs(rate) > self.stage.max_rate * (1 + 1e-12):
            raise Refused("OUT_OF_RANGE", f"MOTOR_SET_RATE: {rate:g} is above the maximum")
        _, v = self.stage.at(t)
        if rate == 0.0:
            return {"ramp_s": self.stage.stop(t), "steps": self.stage.steps(t)}
        steps = self.stage.steps(t)
        limit, reason = (
            (self.stage.high, "limit_high") if rate > 0 else (self.stage.low, "limit_low")
        )
        # docs/motion.md: jogging further into a limit the stage stands at is refused.
        if (steps >= limit if rate > 0 else steps <= limit) and v == 0.0:
            raise Refused("OUT_OF_RANGE", f"MOTOR_SET_RATE: the stage stands at the limit {limit}")
        self.stage.plan_to(t, limit, abs(rate), "running", reason)
        return {"ramp_s": abs(rate - v) / self.stage.accel, "steps": steps}

    def _motor_move(self, r: dict[str, Any], now_s: float, ev: list[Frame]) -> dict[str, Any]:
        t = self._stage_now(now_s, ev)
        self._driver_on("MOTOR_MOVE")
        target = r["target_steps"]
        if not self.stage.low <= target <= self.stage.high:
            raise Refused("OUT_OF_RANGE", f"MOTOR_MOVE: target {target} outside the limits")
        rate = float(r["rate_hz"]) or self.stage.max_rate
        if rate > self.stage.max_rate * (1 + 1e-12):
            raise Refused("OUT_OF_RANGE", f"MOTOR_MOVE: rate {rate:g} above the maximum")
        return {"duration_s": self.stage.plan_to(t, target, rate, "moving", "done")}

    def _motor_stop(self, r: dict[str, Any], now_s: float, ev: list[Frame]) -> dict[str, Any]:
        t = self._stage_now(now_s, ev)
        return {"steps": self.stage.steps(t), "stop_s": self.stage.stop(t)}

    def _motor_home(self, r: dict[str, Any], now_s: float, ev: list[Frame]) -> dict[str, Any]:
        t = self._stage_now(now_s, ev)
        self._driver_on("MOTOR_HOME")
        if self.stage.end_s is not None:
            raise Refused("ILLEGAL_STATE", "MOTOR_HOME refused while moving")
        rate = min(self.stage.home_rate, self.stage.max_rate)
        return {"duration_s": self.stage.plan_to(t, 0.0, rate, "homing", "homed")}

    def _motor_get(self, r: dict[str, Any], now_s: float, ev: list[Frame]) -> dict[str, Any]:
        t = self._stage_now(now_s, ev)
        _, v = self.stage.at(t)
        steps = self.stage.steps(t)
        at_limit = "none"
        if v == 0.0:
            at_limit = (
                "low" if steps <= self.stage.low else "high" if steps >= self.stage.high else "none"
            )
        return {"state": self.stage.state(t), "homed": "yes" if self.stage.homed else "no",
                "steps": steps, "encoder": self.stage.encoder(t), "rate_hz": v,
                "encoder_rate_hz": v * self.stage.m_per_step * self.stage.counts_per_m,
                "at_limit": at_limit, "time_s": t}  # fmt: skip

    def _motor_set_limits(self, r: dict[str, Any], now_s: float, ev: list[Frame]) -> dict[str, Any]:
        t = self._stage_now(now_s, ev)
        s = self.stage
        if s.end_s is not None:
            raise Refused("ILLEGAL_STATE", "MOTOR_SET_LIMITS refused while moving")
        low, high = r["low_steps"], r["high_steps"]
        if low >= high or low < s.hw_low or high > s.hw_high:
            raise Refused("OUT_OF_RANGE", f"MOTOR_SET_LIMITS: [{low}, {high}]")
        if (
            not 0 < r["max_rate_hz"] <= s.hw_max_rate * (1 + 1e-12)
            or r["accel_hz_per_s"] > s.hw_accel
        ):
            raise Refused("OUT_OF_RANGE", "MOTOR_SET_LIMITS: beyond the driver's maxima")
        if not low <= s.steps(t) <= high:
            raise Refused("OUT_OF_RANGE", "MOTOR_SET_LIMITS: the stage stands outside")
        s.low, s.high = low, high
        s.max_rate, s.accel = float(r["max_rate_hz"]), int(r["accel_hz_per_s"])
        return {}

    def _motor_get_limits(self, r: dict[str, Any], now_s: float, ev: list[Frame]) -> dict[str, Any]:
        s = self.stage
        return {"low_steps": s.low, "high_steps": s.high, "max_rate_hz": s.max_rate,
                "accel_hz_per_s": s.accel}  # fmt: skip

    def _motor_estop(self, r: dict[str, Any], now_s: float, ev: list[Frame]) -> dict[str, Any]:
        t = self._stage_now(now_s, ev)
        moving = self.stage.end_s is not None
        self.stage.halt(t)
        self.stage.driver = "estop"
        if moving:
            ev.append(self.event("MOTOR_STOPPED", reason="estop", steps=self.stage.steps(t),
                                 encoder=self.stage.encoder(t)))  # fmt: skip
        return {"steps": self.stage.steps(t), "encoder": self.stage.encoder(t)}

    # -- wheel --------------------------------------------------------------------------

    def _wheel_timing(self) -> tuple[float, float]:
        frame = self.sensor.frame_time_s()
        return frame, self.wheel.t_center_s - frame / 2

    def _wheel_set_speed(self, r: dict[str, Any], now_s: float, ev: list[Frame]) -> dict[str, Any]:
        speed = float(r["speed_deg_s"])
        if 0.0 < speed < 1e-7:  # docs/protocol.md WHEEL_SET_SPEED: its period would not fit
            raise Refused("OUT_OF_RANGE", f"WHEEL_SET_SPEED: {speed:g} deg/s is too slow")
        self.wheel.set_speed(speed, now_s)
        return {"period_s": 360.0 / speed if speed > 0 else 0.0}

    def _wheel_get(self, r: dict[str, Any], now_s: float, ev: list[Frame]) -> dict[str, Any]:
        frame, delay = self._wheel_timing()
        channel = self.wheel.channel(now_s)
        return {"speed_deg_s": self.wheel.speed, "angle_deg": self.wheel.angle(now_s),
                "channel": 255 if channel is None else channel,
                "compensation": "on" if self.compensation else "off",
                "frame_time_s": frame, "delay_s": delay, "time_s": now_s}  # fmt: skip

    def _wheel_compensation(
        self, r: dict[str, Any], now_s: float, ev: list[Frame]
    ) -> dict[str, Any]:
        frame, delay = self._wheel_timing()
        on = r["enable"] == "on"
        if on and (frame > self.wheel.window_s or delay < 0):
            raise Refused("OUT_OF_RANGE", f"WHEEL_COMPENSATION: T_frame {frame:g} s cannot fit")
        self.compensation = on
        return {"frame_time_s": frame, "delay_s": delay if on else 0.0}

    def _wheel_acquire(self, r: dict[str, Any], now_s: float, ev: list[Frame]) -> dict[str, Any]:
        if self.streaming:
            raise Refused("ILLEGAL_STATE", "WHEEL_ACQUIRE refused: streaming")
        if not self.trained:
            raise Refused("LINK_UNTRAINED", "WHEEL_ACQUIRE refused: TRAIN first")
        channels = bytes(r["channels"])
        if not channels or max(channels) >= self.wheel.count:
            raise Refused("OUT_OF_RANGE", f"WHEEL_ACQUIRE: channels {list(channels)}")
        if self.wheel.speed <= 0:
            raise Refused("ILLEGAL_STATE", "WHEEL_ACQUIRE refused: the wheel is stopped")
        frame, delay = self._wheel_timing()
        if frame > self.wheel.window_s or (self.compensation and delay < 0):
            raise Refused("OUT_OF_RANGE", "WHEEL_ACQUIRE: the exposure does not fit the window")
        frames = r["passes"] * len(channels)
        first = self.next_counter
        self.next_counter += frames
        self.frames_sent = frames
        self.streaming = True
        self.stream_end_s = now_s + frames * 360.0 / self.wheel.count / self.wheel.speed
        return {"frames": frames, "first_counter": first,
                "rows": self.sensor.role_value("window_rows"),
                "cols": int(self.sensor.data["columns"]), "frame_time_s": frame,
                "delay_s": delay if self.compensation else 0.0}  # fmt: skip
