"""The simulated camera FPGA's command processor (sans-I/O: frames in, frames out).

``FpgaModel.handle(frame, now_s)`` executes one received command frame against the command
dictionary of ``config/protocol.toml`` and returns the frames the device sends back: an ACK or
NAK, then any unsolicited EVENT frames the command caused. Time is passed in, never read, so
the model is deterministic for a given seed and sequence of calls; ``firmware_models.pty_server``
puts it behind a real pseudo-terminal.

At-most-once execution
----------------------
The host runs strict stop-and-wait: it sends one command, waits for its answer and, if the
answer is lost, re-sends the *identical* frame (same sequence number, same bytes). The device
keeps a record of the last command it executed and the ACK/NAK it produced. A command frame
equal to the recorded one is answered by re-sending the recorded ACK/NAK without executing it
again; any other command frame executes and replaces the record.

One entry is enough because a stop-and-wait host never re-sends an older command after it has
sent a newer one: the only command that can legitimately arrive again is the last one. Comparing
the whole frame (not just the sequence number) means a new command that happens to reuse the
sequence number after the 8-bit counter wrapped, or after the host restarted, still executes.
The record survives RESET, so a retried RESET is not executed twice. Events are not part of the
record: they reported a state change that happened once.

That it holds is measured, not assumed: the device also remembers the last
``_RECENT_EXECUTED`` command frames it executed, and an execution of a frame equal to one of
them counts ``executed_twice`` (SIM_GET_INJECTED). A command that legitimately repeats another
frame byte for byte needs the 8-bit sequence number to come round, 256 commands later, far
outside that window; only a host restarting at a random sequence number could, rarely, repeat
a recent frame. 0 is expected on any line.

Failures on purpose
-------------------
SIM_FAIL_NEXT arms one failure of a coming command (by opcode, after ``skip`` of them): a NAK
with a chosen error code, or a silence of ``duration_s`` (a dropped line: ``silent(now_s)`` is
true, frames received are ignored and the transport sends nothing). The failed command is not
executed, so the host's recovery from a request that fails part-way can be tested. The third
kind, ``end_stream``, lets the command (START_STREAM, WHEEL_ACQUIRE) execute but ends the stream
it starts after ``frames`` frames with STREAM_DONE, as a camera that ends a stream early.
"""

from __future__ import annotations

import math
import struct
import threading
from collections import Counter, deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, fields
from typing import Any

from camd.motion.stage_profile import StageProfile, load_stage_profile
from camd.motion.wheel_profile import load_wheel_profile
from camd.protocol import (
    CommandSpec,
    Decoder,
    Dictionary,
    FieldSpec,
    Frame,
    FrameType,
    PayloadError,
    ProtocolError,
    load_dictionary,
)
from camd.protocol.dictionary import FieldValue, f32_decimal
from camd.sensor.profile import load_profile
from camd.sensor.regmap import RegisterMap, RegisterSpec, load_register_map
from firmware_models.camera import CameraModel
from firmware_models.defects import NONE, Defects
from firmware_models.errors import Nak
from firmware_models.fx3 import StreamEngine, StreamSocketServer
from firmware_models.housekeeping import HousekeepingModel
from firmware_models.imaging import ImagingPipeline, StreamRefused
from firmware_models.inject import FaultInjector, InjectSpec
from firmware_models.motor import MotorController
from firmware_models.sensor import SensorModel
from firmware_models.sensor_link import SensorLink
from firmware_models.spi import SpiMaster, SpiSlave
from firmware_models.stage import StageFaults
from firmware_models.wheel import FilterWheel

FW_VERSION = 0x0100  # 1.0, major * 256 + minor as GET_STATUS reports it
_U32_WRAP = 2**32
_SEQ_WRAP = 256
# Executed command frames remembered to detect one executed twice (module docstring); far
# below the 256 commands after which the host's sequence number repeats.
_RECENT_EXECUTED = 32


_Nak = Nak  # raised by a command handler to answer with a NAK


@dataclass(slots=True)
class LinkCounters:
    """The device side of the command link, as GET_LINK_STATS reports it (plus ``ignored``)."""

    rx_frames: int = 0  # frames handed to the model after the receiver (and any line loss)
    executed: int = 0
    replayed: int = 0
    nacked: int = 0
    tx_frames: int = 0
    ignored: int = 0  # received frames of a type other than COMMAND
    silenced: int = 0  # received while silent (SIM_FAIL_NEXT silence): not seen, not answered
    executed_twice: int = 0  # executions of a frame equal to a recently executed one

    def as_dict(self) -> dict[str, int]:
        """The counters by name."""
        return {f.name: getattr(self, f.name) for f in fields(self)}


@dataclass(frozen=True, slots=True)
class _Record:
    """The last executed command and its ACK/NAK (see the module docstring)."""

    command: Frame
    response: Frame


@dataclass(frozen=True, slots=True)
class _Outcome:
    """What a successful handler produced: the ACK payload and any events."""

    payload: bytes
    events: tuple[Frame, ...] = ()


@dataclass(slots=True)
class _FailNext:
    """The failure SIM_FAIL_NEXT armed: the command it fails and how."""

    action: str  # "nak", "silence" or "end_stream"
    opcode: int
    skip: int  # commands with ``opcode`` still to let through
    error_code: int  # action nak
    duration_s: float  # action silence
    frames: int = 0  # action end_stream: the stream ends after this many frames


_Handler = Callable[[CommandSpec, dict[str, FieldValue], float], _Outcome]


class FpgaModel:
    """The simulated FPGA: mode, fault state, boot count, link counters, at-most-once record.

    ``receiver`` is the device's frame decoder: a transport feeds received bytes to it and hands
    the frames to ``handle``; GET_LINK_STATS reports its CRC errors, resyncs and dropped bytes.
    ``injector`` is the line's fault injector, which the SIM_* commands read and reconfigure
    (the transport applies it); a fault-free one is created if none is given.
    """

    def __init__(
        self,
        dictionary: Dictionary | None = None,
        *,
        seed: int | None = 0,
        power_on_s: float = 0.0,
        injector: FaultInjector | None = None,
        sensor: str | RegisterMap = "hr400",
        stage: str | StageProfile = "linear_rail",
        defects: Defects = NONE,
    ) -> None:
        self.dictionary = dictionary if dictionary is not None else load_dictionary()
        self.defects = defects
        # Commands (pty thread) and the USB-SPI socket (its own thread) share the sensor.
        self.lock = threading.RLock()
        self.regmap = sensor if isinstance(sensor, RegisterMap) else load_register_map(sensor)
        self.sensor = SensorModel(self.regmap, seed=seed or 0)
        self.spi_slave = SpiSlave(self.regmap.spi, self.sensor)
        self.spi = SpiMaster(self.regmap.spi, self.spi_slave)
        self.sensor_link = SensorLink(self.regmap, self.spi, seed=seed or 0)
        self.injector = injector if injector is not None else FaultInjector(seed=seed)
        self.power_on_s = power_on_s
        # The camera profile has the sensor's name (config/profiles/<name>.toml).
        self.camera = CameraModel(load_profile(self.regmap.sensor), self.sensor, seed=seed or 0)
        self.stream = StreamEngine(
            inject=self.injector.spec, seed=seed or 0, on_done=self._stream_done
        )
        self.imaging_path = ImagingPipeline(
            self.camera,
            self.sensor,
            self.sensor_link,
            self.stream,
            lock=self.lock,
        )
        self.stream.source = self.imaging_path.frame
        self.stream.prepare = self.imaging_path.prepare
        self.stream.defects = self.imaging_path.defects = defects
        # register_readback_off_by_one: the register whose reads are off (None: no defect).
        self._off_by_one_address = (
            _off_by_one_register(self.regmap) if defects.register_readback_off_by_one else None
        )
        # The scan stage: a stepper the MOTOR_* commands drive. The target rides on it once
        # the motor has been enabled; until then (or after SIM_SET_STAGE) an ideal stage moves
        # it, tracking the line period, so a plain stream needs no motion set-up.
        stage_profile = stage if isinstance(stage, StageProfile) else load_stage_profile(stage)
        self.motor = MotorController(
            stage_profile, seed=seed or 0, faults=_stage_faults(stage_profile, self.injector.spec)
        )
        self.imaging_path.encoder_at = self.motor.encoder_counts
        self.imaging_path.encoder_revision = lambda: self.motor.revision
        # The filter wheel turns from power-on at its nominal speed (config/wheel.toml).
        self.wheel = FilterWheel(load_wheel_profile(), t_s=0.0)
        self.wheel_compensation = False
        self.polarizer_deg: float | None = None  # the scene's reference polariser, if any
        self._wheel_until_s = 0.0  # model time the last wheel acquisition's frames reach
        # Events that no command caused (STREAM_DONE from the stream thread) wait here until
        # the transport collects them; ``wake`` tells it there are some.
        self._unsent_events: list[Frame] = []
        self.wake: Callable[[], None] | None = None
        self.receiver = Decoder()
        self.housekeeping = HousekeepingModel(seed=seed, power_on_s=power_on_s)
        self.mode = "area"
        self.fault_code = 0
        self.boot_count = 1
        self.counters = LinkCounters()
        self.executions: Counter[int] = Counter()  # opcode -> commands executed (not replayed)
        self._record: _Record | None = None
        self._recent: deque[Frame] = deque(maxlen=_RECENT_EXECUTED)  # executed command frames
        self._unsolicited_seq = 0
        self._fail_next: _FailNext | None = None
        # While a command armed with SIM_FAIL_NEXT end_stream executes: its stream's length.
        self._cut_stream_after: int | None = None
        self._silent_until_s = -math.inf  # transport clock; SIM_FAIL_NEXT silence
        self._handlers: dict[str, _Handler] = {
            "PING": self._ping,
            "GET_STATUS": self._get_status,
            "GET_HOUSEKEEPING": self._get_housekeeping,
            "RESET": self._reset,
            "SET_MODE": self._set_mode,
            "GET_LINK_STATS": self._get_link_stats,
            "SIM_GET_INJECTED": self._sim_get_injected,
            "SIM_SET_INJECT": self._sim_set_inject,
            "SIM_SET_FAULT": self._sim_set_fault,
            "REG_READ": self._reg_read,
            "REG_WRITE": self._reg_write,
            "REG_WRITE_BURST": self._reg_write_burst,
            "GET_SENSOR": self._get_sensor,
            "TRAIN": self._train,
            "GET_LANE": self._get_lane,
            "START_STREAM": self._start_stream,
            "STOP_STREAM": self._stop_stream,
            "GET_STREAM": self._get_stream,
            "SIM_GET_STREAM_STATS": self._sim_get_stream_stats,
            "SIM_SET_SCENE": self._sim_set_scene,
            "SIM_SET_STAGE": self._sim_set_stage,
            "SIM_GET_SPI_STATS": self._sim_get_spi_stats,
            "SIM_RESKEW": self._sim_reskew,
            **{name: self._motor for name in self.motor.commands},
            "WHEEL_SET_SPEED": self._wheel_set_speed,
            "WHEEL_GET": self._wheel_get,
            "WHEEL_COMPENSATION": self._wheel_compensation,
            "WHEEL_ACQUIRE": self._wheel_acquire,
            "SIM_SET_POLARIZER": self._sim_set_polarizer,
            "SIM_SET_SEED": self._sim_set_seed,
            "SIM_FAIL_NEXT": self._sim_fail_next,
        }

    # -- frames in, frames out ------------------------------------------------------------

    def handle(self, frame: Frame, now_s: float) -> list[Frame]:
        """Execute (or replay) one received frame; return the frames to send, in order."""
        with self.lock:
            return self._handle(frame, now_s)

    def _handle(self, frame: Frame, now_s: float) -> list[Frame]:
        if self.silent(now_s):
            self.counters.silenced += 1
            return []
        self.counters.rx_frames += 1
        if frame.type != FrameType.COMMAND:
            self.counters.ignored += 1
            return []
        record = self._record
        # replay_executes: the record is never consulted, so a retry executes again.
        if record is not None and record.command == frame and not self.defects.replay_executes:
            self.counters.replayed += 1
            return self._sent([record.response])
        cut_after = None
        if self._fails_now(frame):
            armed = self._fail_next
            assert armed is not None
            if armed.action != "end_stream":
                return self._fail(frame, now_s)
            # It executes; the stream it starts ends early (START_STREAM, WHEEL_ACQUIRE).
            self._fail_next, cut_after = None, armed.frames
        self.counters.executed += 1
        if frame in self._recent:
            self.counters.executed_twice += 1  # at-most-once broken (module docstring)
        self._recent.append(frame)
        self.executions[frame.opcode] += 1
        self._cut_stream_after = cut_after
        try:
            response, events = self._execute(frame, now_s)
        finally:
            self._cut_stream_after = None
        if response.type == FrameType.NAK:
            self.counters.nacked += 1
        self._record = _Record(frame, response)
        return self._sent([response, *events])

    def silent(self, now_s: float) -> bool:
        """True while the device is off the line (SIM_FAIL_NEXT silence): it answers nothing,
        and the transport sends nothing it makes (events, telemetry) until ``now_s`` passes."""
        return now_s < self._silent_until_s

    def _fails_now(self, frame: Frame) -> bool:
        """Count ``frame`` against the armed failure; True if it is the one to fail."""
        armed = self._fail_next
        if armed is None or frame.opcode != armed.opcode:
            return False
        if armed.skip > 0:
            armed.skip -= 1
            return False
        return True

    def _fail(self, frame: Frame, now_s: float) -> list[Frame]:
        """Fail ``frame`` as armed (it is not executed) and disarm."""
        armed = self._fail_next
        assert armed is not None
        self._fail_next = None
        if armed.action == "silence":
            self._silent_until_s = now_s + armed.duration_s
            self.counters.silenced += 1
            return []
        name = self.dictionary.command(frame.opcode).name
        payload = self.dictionary.encode_nak(
            armed.error_code, f"{name} failed on purpose (SIM_FAIL_NEXT)"
        )
        response = Frame(FrameType.NAK, frame.seq, frame.opcode, payload)
        self.counters.nacked += 1
        # Recorded like any answer: a retry of this frame gets the same NAK, not an execution.
        self._record = _Record(frame, response)
        return self._sent([response])

    @property
    def imaging(self) -> bool:
        """The sensor's sequencer runs and frames stream (START_STREAM)."""
        return self.imaging_path.streaming

    def close(self) -> None:
        """Stop any stream and end the stream engine's thread."""
        self.imaging_path.stop()
        self.stream.close()

    def attach_stream_server(self, server: StreamSocketServer) -> None:
        """Send the stream to a host over ``server`` (``--usb-socket``)."""
        self.stream.server = server

    def take_unsolicited(self, now_s: float | None = None) -> list[Frame]:
        """Events raised outside any command since the last call, in order; with ``now_s``,
        also the stage's stops due by then (MOTOR_STOPPED)."""
        with self.lock:
            if now_s is not None:
                for name, values in self.motor.poll_events(now_s - self.power_on_s):
                    self._unsent_events.append(self._event(name, **values))
            frames, self._unsent_events = self._unsent_events, []
        return self._sent(frames)

    def next_event_s(self) -> float | None:
        """When (transport clock) the next unsolicited event is due, if one is planned."""
        with self.lock:
            due = self.motor.next_event_s()
        return None if due is None else due + self.power_on_s

    def boot_frames(self, now_s: float) -> list[Frame]:
        """The frames the device sends when it starts: a BOOT event."""
        return self._sent([self._event("BOOT", boot_count=self.boot_count)])

    def housekeeping_frame(self, now_s: float) -> Frame:
        """One periodic HOUSEKEEPING telemetry frame sampled at ``now_s``."""
        packet = self.dictionary.telemetry_packet("HOUSEKEEPING")
        payload = packet.encode(**self._housekeeping_values(now_s))
        return self._sent([self._unsolicited(FrameType.TELEMETRY, packet.opcode, payload)])[0]

    def execution_count(self, command: str | int) -> int:
        """How many times a command (by name or opcode) was executed, replays not counted."""
        opcode = command if isinstance(command, int) else self.dictionary.command(command).opcode
        return self.executions[opcode]

    @property
    def device_state(self) -> str:
        """The GET_STATUS device_state: ``fault`` while a fault is active, else ``idle``."""
        return "fault" if self.fault_code else "idle"

    # -- execution ------------------------------------------------------------------------

    def _execute(self, frame: Frame, now_s: float) -> tuple[Frame, tuple[Frame, ...]]:
        spec = self.dictionary.command_for_opcode(frame.opcode)
        handler = self._handlers.get(spec.name) if spec is not None else None
        try:
            if spec is None or handler is None:
                raise _Nak(
                    "UNKNOWN_OPCODE",
                    f"opcode 0x{frame.opcode:02X} is not implemented by this device",
                )
            request = self._decode_request(spec, frame.payload)
            outcome = handler(spec, request, now_s)
        except _Nak as nak:
            payload = self.dictionary.encode_nak(nak.error, nak.detail)
            return Frame(FrameType.NAK, frame.seq, frame.opcode, payload), ()
        except ProtocolError as exc:
            # A response that cannot be encoded is a model bug; answer like firmware would.
            payload = self.dictionary.encode_nak("INTERNAL", str(exc))
            return Frame(FrameType.NAK, frame.seq, frame.opcode, payload), ()
        return Frame(FrameType.ACK, frame.seq, frame.opcode, outcome.payload), outcome.events

    def _decode_request(self, spec: CommandSpec, payload: bytes) -> dict[str, FieldValue]:
        try:
            values = spec.decode_request(payload)
        except PayloadError as exc:
            # The codec raises PayloadError for a wrong size and for an undefined enum value
            # alike; the host needs to know which, so tell them apart by the length.
            if _length_fits(spec.request, len(payload)):
                raise _Nak("OUT_OF_RANGE", str(exc)) from None
            expected = _expected_length(spec.request)
            raise _Nak("BAD_LENGTH", f"{exc}; {spec.name} takes {expected}") from None
        _check_ranges(spec, values)
        return values

    def _sent(self, frames: list[Frame]) -> list[Frame]:
        self.counters.tx_frames += len(frames)
        return frames

    def _unsolicited(self, type_: FrameType, opcode: int, payload: bytes) -> Frame:
        # Telemetry and events answer no command, so they number themselves.
        seq = self._unsolicited_seq
        self._unsolicited_seq = (seq + 1) % _SEQ_WRAP
        return Frame(type_, seq, opcode, payload)

    def _event(self, name: str, **values: Any) -> Frame:
        packet = self.dictionary.event(name)
        return self._unsolicited(FrameType.EVENT, packet.opcode, packet.encode(**values))

    def _housekeeping_values(self, now_s: float) -> dict[str, float | int]:
        values: dict[str, float | int] = dict(self.housekeeping.sample(now_s))
        values["executed"] = self.counters.executed % _U32_WRAP
        return values

    def _require_no_fault(self, spec: CommandSpec) -> None:
        if self.fault_code:
            try:
                fault = f"{self.dictionary.error(self.fault_code).name} ({self.fault_code})"
            except KeyError:
                fault = f"code {self.fault_code}"
            raise _Nak("DEVICE_FAULT", f"{spec.name} refused in fault {fault}; RESET clears it")

    # -- command handlers -----------------------------------------------------------------

    def _ping(self, spec: CommandSpec, request: dict[str, FieldValue], now_s: float) -> _Outcome:
        return _Outcome(spec.encode_response(data=request["data"]))

    def _get_status(
        self, spec: CommandSpec, request: dict[str, FieldValue], now_s: float
    ) -> _Outcome:
        return _Outcome(
            spec.encode_response(
                mode=self.mode,
                device_state=self.device_state,
                fault_code=self.fault_code,
                uptime_s=self.housekeeping.uptime_s(now_s),
                fw_version=FW_VERSION,
                boot_count=self.boot_count,
            )
        )

    def _get_housekeeping(
        self, spec: CommandSpec, request: dict[str, FieldValue], now_s: float
    ) -> _Outcome:
        return _Outcome(spec.encode_response(**self._housekeeping_values(now_s)))

    def _reset(self, spec: CommandSpec, request: dict[str, FieldValue], now_s: float) -> _Outcome:
        # Link counters and the at-most-once record deliberately survive: see the module doc.
        # The FPGA's deserializer restarts too: the sensor link must be trained again. The
        # sensor's registers are the sensor's and survive an FPGA reset.
        self.mode = "area"
        self.fault_code = 0
        self.imaging_path.stop()  # the reset stops the sequencer: no STREAM_DONE
        self.sensor_link.untrain()
        self.boot_count = (self.boot_count + 1) % 0x10000
        self.housekeeping.restart_uptime(now_s)
        return _Outcome(spec.encode_response(), (self._event("BOOT", boot_count=self.boot_count),))

    def _set_mode(
        self, spec: CommandSpec, request: dict[str, FieldValue], now_s: float
    ) -> _Outcome:
        self._require_no_fault(spec)
        mode = str(request["mode"])
        events: tuple[Frame, ...] = ()
        if mode != self.mode:
            self.mode = mode
            events = (self._event("MODE_CHANGED", mode=mode),)
        return _Outcome(spec.encode_response(mode=self.mode), events)

    def _get_link_stats(
        self, spec: CommandSpec, request: dict[str, FieldValue], now_s: float
    ) -> _Outcome:
        rx = self.receiver.stats
        values = {
            "rx_frames": self.counters.rx_frames,
            "crc_errors": rx.crc_errors,
            "resyncs": rx.resyncs,
            "bytes_dropped": rx.bytes_dropped,
            "executed": self.counters.executed,
            "replayed": self.counters.replayed,
            "nacked": self.counters.nacked,
            "tx_frames": self.counters.tx_frames,
        }
        return _Outcome(spec.encode_response(**_wrap_u32(values)))

    def _sim_get_injected(
        self, spec: CommandSpec, request: dict[str, FieldValue], now_s: float
    ) -> _Outcome:
        values = {**self.injector.counters(), "executed_twice": self.counters.executed_twice}
        return _Outcome(spec.encode_response(**_wrap_u32(values)))

    def _sim_set_inject(
        self, spec: CommandSpec, request: dict[str, FieldValue], now_s: float
    ) -> _Outcome:
        rates = {name: f32_decimal(float(value)) for name, value in request.items()}
        # Keys the command does not carry (added to InjectSpec later) keep their value.
        merged = {**self.injector.spec.model_dump(), **rates}
        try:
            self.injector.set(InjectSpec.checked(**merged))
        except ValueError as exc:
            raise _Nak("OUT_OF_RANGE", str(exc)) from None
        self.stream.inject = self.injector.spec  # the frame_* rates, for the next frame
        return _Outcome(spec.encode_response())

    def _sim_set_fault(
        self, spec: CommandSpec, request: dict[str, FieldValue], now_s: float
    ) -> _Outcome:
        code = int(request["fault_code"])
        self.fault_code = code
        return _Outcome(spec.encode_response(), (self._event("FAULT", fault_code=code),))

    # -- sensor registers over the SPI master ---------------------------------------------------

    def _register(self, spec: CommandSpec, address: int) -> RegisterSpec:
        if not self.regmap.has_register(address):
            raise _Nak(
                "REG_UNKNOWN",
                f"{spec.name}: {self.regmap.sensor} has no register at address 0x{address:02X}",
            )
        return self.regmap.register(address)

    def _check_write(self, spec: CommandSpec, address: int, value: int) -> None:
        reg = self._register(spec, address)
        if not reg.writable:
            raise _Nak(
                "REG_READ_ONLY", f"{spec.name}: register {reg.name} (0x{address:02X}) is read-only"
            )
        if value > reg.mask:
            raise _Nak(
                "OUT_OF_RANGE",
                f"{spec.name}: 0x{value:X} does not fit register {reg.name}'s {reg.width} bits",
            )

    def _reg_read(
        self, spec: CommandSpec, request: dict[str, FieldValue], now_s: float
    ) -> _Outcome:
        address = int(request["address"])
        reg = self._register(spec, address)
        if not reg.readable:
            raise _Nak(
                "REG_WRITE_ONLY", f"REG_READ: register {reg.name} (0x{address:02X}) is write-only"
            )
        value = self.spi.read(address)
        if address == self._off_by_one_address:
            value = (value + 1) & reg.mask  # register_readback_off_by_one
        return _Outcome(spec.encode_response(address=address, value=value))

    def _reg_write(
        self, spec: CommandSpec, request: dict[str, FieldValue], now_s: float
    ) -> _Outcome:
        address, value = int(request["address"]), int(request["value"])
        self._check_write(spec, address, value)
        self.spi.write(address, value)
        self.imaging_path.note_registers(now_s - self.power_on_s)
        return _Outcome(spec.encode_response(address=address, value=value))

    def _reg_write_burst(
        self, spec: CommandSpec, request: dict[str, FieldValue], now_s: float
    ) -> _Outcome:
        data = request["pairs"]
        assert isinstance(data, bytes)
        if not data or len(data) % 4:
            raise _Nak(
                "BAD_LENGTH",
                f"REG_WRITE_BURST: {len(data)} bytes of pairs; send 1 to 255 (address u16, "
                "value u16) pairs, 4 bytes each",
            )
        pairs = list(struct.iter_unpack(">HH", data))
        for address, value in pairs:  # all checked before the first is written
            self._check_write(spec, address, value)
        for address, value in pairs:
            self.spi.write(address, value)
        self.imaging_path.note_registers(now_s - self.power_on_s)
        return _Outcome(spec.encode_response(count=len(pairs)))

    def _get_sensor(
        self, spec: CommandSpec, request: dict[str, FieldValue], now_s: float
    ) -> _Outcome:
        link = self.sensor_link
        return _Outcome(
            spec.encode_response(
                interface=self.regmap.output.interface,
                lanes=link.lanes,
                trained="yes" if link.trained else "no",
                imaging="yes" if self.imaging else "no",
                sensor=self.regmap.sensor,
            )
        )

    def _train(self, spec: CommandSpec, request: dict[str, FieldValue], now_s: float) -> _Outcome:
        self._require_no_fault(spec)
        if self.imaging:
            raise _Nak("ILLEGAL_STATE", "TRAIN refused while imaging; send STOP_IMAGING first")
        report = self.sensor_link.train()
        locked = "yes" if report.locked else "no"
        event = self._event("LINK_TRAINED", locked=locked, bit_errors=report.bit_errors)
        return _Outcome(
            spec.encode_response(
                lanes=report.lanes,
                locked_lanes=report.locked_lanes,
                locked=locked,
                bit_errors=report.bit_errors,
                verified_bits=report.verified_bits,
            ),
            (event,),
        )

    def _get_lane(
        self, spec: CommandSpec, request: dict[str, FieldValue], now_s: float
    ) -> _Outcome:
        lane = int(request["lane"])
        link = self.sensor_link
        if lane >= link.lanes:
            raise _Nak(
                "OUT_OF_RANGE",
                f"GET_LANE: lane {lane} does not exist; the link has {link.lanes} lanes "
                f"(0..{link.lanes - 1})"
                if link.lanes
                else "GET_LANE: the sensor has no LVDS lanes",
            )
        result = link.lane(lane)
        return _Outcome(
            spec.encode_response(
                lane=lane,
                tap=result.tap,
                eye_width=result.eye_width_taps,
                slips=result.slips,
                shift=result.shift,
                locked="yes" if result.locked else "no",
            )
        )

    def _start_stream(
        self, spec: CommandSpec, request: dict[str, FieldValue], now_s: float
    ) -> _Outcome:
        self._require_no_fault(spec)
        if self.imaging:
            raise _Nak(
                "ILLEGAL_STATE", "START_STREAM refused: already streaming; STOP_STREAM first"
            )
        if not self.sensor_link.trained:
            raise _Nak(
                "LINK_UNTRAINED",
                "START_STREAM refused: the sensor's LVDS link is not trained; send TRAIN first",
            )
        self.camera.transmission = None  # a plain stream: no wheel in the light path
        try:
            geometry = self.imaging_path.start(
                device_time_s=now_s - self.power_on_s,
                mode=self.mode,
                frames=int(request["frames"]),
                stages=int(request["stages"]),
                binning=request["binning"] == "2x2",
                end_after=self._cut_stream_after,
            )
        except StreamRefused as exc:
            raise _Nak("OUT_OF_RANGE", f"START_STREAM refused: {exc}") from None
        return _Outcome(
            spec.encode_response(
                mode=geometry.mode,
                rows=geometry.rows,
                cols=geometry.cols,
                bits=geometry.bits,
                frame_period_s=geometry.frame_period_s,
                first_counter=geometry.first_counter,
            )
        )

    def _stop_stream(
        self, spec: CommandSpec, request: dict[str, FieldValue], now_s: float
    ) -> _Outcome:
        produced, next_counter = self.imaging_path.stop()
        return _Outcome(spec.encode_response(frames_sent=produced, next_counter=next_counter))

    def _get_stream(
        self, spec: CommandSpec, request: dict[str, FieldValue], now_s: float
    ) -> _Outcome:
        server = self.stream.server
        return _Outcome(
            spec.encode_response(
                streaming="yes" if self.imaging else "no",
                frames_sent=self.stream.frames_produced % _U32_WRAP,
                next_counter=self.imaging_path.next_counter,
                host_connected="yes" if server is not None and server.connected else "no",
            )
        )

    def _sim_get_stream_stats(
        self, spec: CommandSpec, request: dict[str, FieldValue], now_s: float
    ) -> _Outcome:
        counters = self.stream.counters.as_dict()
        names = [f.name for f in spec.response]
        return _Outcome(spec.encode_response(**_wrap_u32({k: counters[k] for k in names})))

    def _sim_set_scene(
        self, spec: CommandSpec, request: dict[str, FieldValue], now_s: float
    ) -> _Outcome:
        try:
            self.camera.set_scene(str(request["spec"]))
        except (ValueError, OSError) as exc:
            raise _Nak("OUT_OF_RANGE", f"SIM_SET_SCENE: {exc}") from None
        return _Outcome(spec.encode_response())

    def _sim_set_stage(
        self, spec: CommandSpec, request: dict[str, FieldValue], now_s: float
    ) -> _Outcome:
        track = request["track"] == "yes"
        speed = f32_decimal(float(request["speed_m_s"]))
        if not track and speed <= 0.0:
            raise _Nak("OUT_OF_RANGE", "SIM_SET_STAGE: a fixed speed must be > 0 m/s")
        self.camera.stage_speed_m_s = None if track else speed
        self.camera.stage = None  # an ideal stage from now on, not the stepper
        sync = self.camera.synchronous_speed_m_s()
        now = sync if track else speed
        return _Outcome(spec.encode_response(speed_m_s=now, sync_speed_m_s=sync))

    # -- the scan stage (docs/motion.md) --------------------------------------------------

    def _motor(self, spec: CommandSpec, request: dict[str, FieldValue], now_s: float) -> _Outcome:
        # Stopping the stage, and reading it, are always allowed: a fault must not keep it moving.
        if spec.name not in (
            "MOTOR_ESTOP", "MOTOR_STOP", "MOTOR_GET", "MOTOR_GET_LIMITS", "SIM_GET_STAGE"
        ):  # fmt: skip
            self._require_no_fault(spec)
        t = now_s - self.power_on_s
        values = {
            k: f32_decimal(v) if isinstance(v, float) and spec.name.startswith("SIM_")
            else v
            for k, v in request.items()
        }  # fmt: skip
        answer = self.motor.handle(spec.name, t, values)
        if spec.name == "MOTOR_ENABLE" and request["enable"] == "on":
            self._ride_the_stepper()
        events = tuple(self._event(n, **v) for n, v in self.motor.poll_events(t))
        return _Outcome(spec.encode_response(**answer), events)

    def _ride_the_stepper(self) -> None:
        """From now on the target moves with the stepper stage (module docs)."""
        profile = self.motor.profile
        self.camera.stage = self.motor.stage
        self.camera.stage_image_scale = profile.image_scale(self.camera.profile.magnification.value)

    # -- the filter wheel (docs/physics.md §4, docs/wheel.md) -------------------------------------

    def _wheel_timing(self) -> tuple[float, float, float]:
        """(T_frame, T_delay for the registers now, exposure) (docs/physics.md §4 eqs 5, 6)."""
        timing = self.sensor.timing()
        frame = timing.frame_time_s
        return frame, self.wheel.profile.t_center_s.value - frame / 2, timing.exposure_s

    def _wheel_set_speed(
        self, spec: CommandSpec, request: dict[str, FieldValue], now_s: float
    ) -> _Outcome:
        if self.imaging and self.camera.transmission is not None:
            raise _Nak("ILLEGAL_STATE", "WHEEL_SET_SPEED refused during a wheel acquisition")
        speed = f32_decimal(float(request["speed_deg_s"]))
        t = max(now_s - self.power_on_s, self._wheel_until_s)
        self.wheel.set_speed(speed, t)
        return _Outcome(spec.encode_response(period_s=360.0 / speed if speed > 0 else 0.0))

    def _wheel_get(
        self, spec: CommandSpec, request: dict[str, FieldValue], now_s: float
    ) -> _Outcome:
        # A wheel acquisition runs ahead of the wall clock (its frames are not paced): the
        # wheel is read where its model time is, as WHEEL_SET_SPEED and WHEEL_ACQUIRE see it.
        t = max(now_s - self.power_on_s, self._wheel_until_s)
        frame, delay, _ = self._wheel_timing()
        channel = self.wheel.channel_at(t)
        return _Outcome(
            spec.encode_response(
                speed_deg_s=self.wheel.speed_deg_s(t),
                angle_deg=self.wheel.angle_deg(t),
                channel=255 if channel is None else channel,
                compensation="on" if self.wheel_compensation else "off",
                frame_time_s=frame,
                delay_s=delay,
                time_s=t,
            )
        )

    def _wheel_compensation(
        self, spec: CommandSpec, request: dict[str, FieldValue], now_s: float
    ) -> _Outcome:
        on = request["enable"] == "on"
        frame, delay, _ = self._wheel_timing()
        if on:
            try:
                self.wheel.profile.exposure(frame, compensated=True)
            except ValueError as exc:
                raise _Nak("OUT_OF_RANGE", f"WHEEL_COMPENSATION refused: {exc}") from None
        self.wheel_compensation = on
        return _Outcome(spec.encode_response(frame_time_s=frame, delay_s=delay if on else 0.0))

    def _wheel_acquire(
        self, spec: CommandSpec, request: dict[str, FieldValue], now_s: float
    ) -> _Outcome:
        self._require_no_fault(spec)
        if self.imaging:
            raise _Nak("ILLEGAL_STATE", "WHEEL_ACQUIRE refused: streaming; STOP_STREAM first")
        if not self.sensor_link.trained:
            raise _Nak(
                "LINK_UNTRAINED",
                "WHEEL_ACQUIRE refused: the sensor's LVDS link is not trained; TRAIN first",
            )
        raw = bytes(request["channels"])  # type: ignore[arg-type]
        count = self.wheel.profile.channel_count.value
        if not raw or any(c >= count for c in raw):
            raise _Nak(
                "OUT_OF_RANGE",
                f"WHEEL_ACQUIRE refused: channels {list(raw)}; give 1 to {count} channel "
                f"numbers 0..{count - 1}",
            )
        t = max(now_s - self.power_on_s, self._wheel_until_s)
        if self.wheel.speed_deg_s(t) <= 0.0:
            raise _Nak("ILLEGAL_STATE", "WHEEL_ACQUIRE refused: the wheel is stopped; "
                       "WHEEL_SET_SPEED first")  # fmt: skip
        frame, _, _ = self._wheel_timing()
        line = self.sensor.timing().line_period_s
        # wheel_ignores_delay: the scheduler exposes at the entry pulse whatever is switched on.
        delayed = self.wheel_compensation and not self.defects.wheel_ignores_delay
        starts: list[float] = []
        stamps: list[int] = []
        try:
            for _ in range(int(request["passes"])):
                for channel in raw:
                    start = self.wheel.exposure_schedule(channel, t, frame, delayed)
                    starts.append(start + line)  # row 0 resets one line into the frame
                    stamps.append(round(float(self.wheel.angle_deg(start)) * 1e4))
                    t = start + frame
        except ValueError as exc:
            raise _Nak("OUT_OF_RANGE", f"WHEEL_ACQUIRE refused: {exc}") from None
        self._wheel_until_s = t
        wheel, polarizer = self.wheel, self.polarizer_deg

        def transmission(start_s: Any, end_s: Any) -> Any:
            mid = 0.5 * (float(start_s.min()) + float(end_s.max()))
            channel = wheel.channel_at(mid)
            if channel is None:
                return 0.0 * start_s
            return wheel.row_transmission(channel, start_s, end_s, polarizer)

        self.camera.transmission = transmission
        try:
            geometry = self.imaging_path.start(
                device_time_s=starts[0],
                mode="area",
                frames=len(starts),
                stages=0,
                binning=False,
                schedule_s=starts,
                stamps=stamps,
                end_after=self._cut_stream_after,
            )
        except StreamRefused as exc:
            self.camera.transmission = None
            raise _Nak("OUT_OF_RANGE", f"WHEEL_ACQUIRE refused: {exc}") from None
        delay = self.wheel.profile.t_center_s.value - frame / 2 if self.wheel_compensation else 0
        return _Outcome(
            spec.encode_response(
                frames=len(starts),
                first_counter=geometry.first_counter,
                rows=geometry.rows,
                cols=geometry.cols,
                frame_time_s=frame,
                delay_s=delay,
            )
        )

    def _sim_set_polarizer(
        self, spec: CommandSpec, request: dict[str, FieldValue], now_s: float
    ) -> _Outcome:
        on = request["enable"] == "on"
        self.polarizer_deg = f32_decimal(float(request["angle_deg"])) if on else None
        return _Outcome(spec.encode_response())

    def _sim_set_seed(
        self, spec: CommandSpec, request: dict[str, FieldValue], now_s: float
    ) -> _Outcome:
        # Only the streams that make one acquisition differ from the next: a campaign resumed
        # after a restart re-seeds before each step and so sees the noise it saw the first time.
        seed = int(request["seed"])
        self.camera.reseed_noise(seed)
        self.stream.reseed(seed)
        return _Outcome(spec.encode_response())

    def _sim_fail_next(
        self, spec: CommandSpec, request: dict[str, FieldValue], now_s: float
    ) -> _Outcome:
        action = str(request["action"])
        if action == "off":
            self._fail_next = None
            return _Outcome(spec.encode_response())
        opcode = int(request["opcode"])
        if self.dictionary.command_for_opcode(opcode) is None:
            raise _Nak(
                "OUT_OF_RANGE",
                f"SIM_FAIL_NEXT: opcode 0x{opcode:02X} is not a command of the dictionary",
            )
        code = int(request["error_code"])
        duration_s = float(request["duration_s"])
        if action == "nak":
            try:
                self.dictionary.error(code)
            except KeyError:
                codes = ", ".join(f"{e.code} {e.name}" for e in self.dictionary.errors)
                raise _Nak(
                    "OUT_OF_RANGE",
                    f"SIM_FAIL_NEXT: error_code {code} is not an error of the dictionary; "
                    f"use one of {codes}",
                ) from None
        elif action == "silence" and duration_s <= 0.0:
            raise _Nak("OUT_OF_RANGE", "SIM_FAIL_NEXT: a silence needs duration_s > 0")
        elif action == "end_stream" and opcode not in self._stream_opcodes():
            raise _Nak(
                "OUT_OF_RANGE",
                f"SIM_FAIL_NEXT: end_stream needs a command that starts a stream (START_STREAM, "
                f"WHEEL_ACQUIRE), not opcode 0x{opcode:02X}",
            )
        self._fail_next = _FailNext(
            action, opcode, int(request["skip"]), code, duration_s, int(request["frames"])
        )
        return _Outcome(spec.encode_response())

    def _stream_opcodes(self) -> set[int]:
        """The commands that start a counted stream (SIM_FAIL_NEXT end_stream applies)."""
        return {self.dictionary.command(name).opcode for name in ("START_STREAM", "WHEEL_ACQUIRE")}

    def _stream_done(self, frames_sent: int, next_counter: int) -> None:
        """A counted stream ended by itself (stream thread): tell the host with STREAM_DONE.

        A stream stopped by a command (STOP_STREAM, RESET, SIM_RESKEW) is reported by that
        command, not here (``ImagingPipeline.stop``)."""
        with self.lock:
            self._unsent_events.append(
                self._event(
                    "STREAM_DONE", frames_sent=frames_sent % _U32_WRAP, next_counter=next_counter
                )
            )
        wake = self.wake
        if wake is not None:
            wake()

    def _sim_get_spi_stats(
        self, spec: CommandSpec, request: dict[str, FieldValue], now_s: float
    ) -> _Outcome:
        values = {
            "transactions": self.spi_slave.transactions,
            "reads": sum(self.sensor.reads.values()),
            "writes": sum(self.sensor.writes.values()),
            "errors": self.spi_slave.errors,
        }
        return _Outcome(spec.encode_response(**_wrap_u32(values)))

    def _sim_reskew(
        self, spec: CommandSpec, request: dict[str, FieldValue], now_s: float
    ) -> _Outcome:
        was_trained = self.sensor_link.trained
        self.sensor_link.reskew(int(request["seed"]))
        events: tuple[Frame, ...] = ()
        if was_trained and not self.sensor_link.trained:
            events = (self._event("LINK_LOST"),)
            if self.imaging:
                # Garbled frames are no frames: the FPGA stops the stream and says so.
                produced, next_counter = self.imaging_path.stop()
                events += (
                    self._event("STREAM_DONE", frames_sent=produced, next_counter=next_counter),
                )
        return _Outcome(spec.encode_response(), events)


# -- payload checks the codec leaves to the device -------------------------------------------


def _off_by_one_register(regmap: RegisterMap) -> int:
    """The register register_readback_off_by_one reads wrong: the ``offset`` role's, else the
    ``gain`` role's (registers that set no timing, so only the read-back check sees it)."""
    for role in ("offset", "gain"):
        target = regmap.role(role)
        if target is not None:
            name = target.split(".")[0]
            if regmap.has_register(name):
                return regmap.register(name).address
    raise ValueError(
        f"register_readback_off_by_one: {regmap.sensor} has no offset or gain role to apply it to"
    )


def _length_bounds(fields_: list[FieldSpec]) -> tuple[int, int]:
    """(shortest, longest) payload laid out as ``fields_``, in bytes."""
    fixed = sum(f.size for f in fields_ if f.size is not None)
    variable = sum(f.max_size for f in fields_ if f.size is None)
    return fixed, fixed + variable


def _length_fits(fields_: list[FieldSpec], length: int) -> bool:
    shortest, longest = _length_bounds(fields_)
    return shortest <= length <= longest


def _expected_length(fields_: list[FieldSpec]) -> str:
    shortest, longest = _length_bounds(fields_)
    if shortest != longest:
        return f"{shortest} to {longest} payload bytes"
    return f"{shortest} payload byte{'' if shortest == 1 else 's'}"


def _check_ranges(spec: CommandSpec, values: Mapping[str, FieldValue]) -> None:
    """NAK OUT_OF_RANGE for a decoded value outside its field's min/max (decode does not check)."""
    for f in spec.request:
        value = values[f.name]
        if f.enum is not None or not isinstance(value, int | float):
            continue
        lo = -math.inf if f.min is None else _as_sent(f, f.min)
        hi = math.inf if f.max is None else _as_sent(f, f.max)
        if not lo <= value <= hi:  # NaN fails too
            raise _Nak(
                "OUT_OF_RANGE",
                f"{spec.name}.{f.name}: {value:g} is out of range (valid: {f.valid_range()})",
            )


def _as_sent(f: FieldSpec, bound: float) -> float:
    """A bound as it looks after the trip through the wire type (f32 rounds 0.01 up or down)."""
    if f.type == "f32":
        return float(struct.unpack(">f", struct.pack(">f", bound))[0])
    return bound


def _stage_faults(profile: StageProfile, spec: InjectSpec) -> StageFaults:
    """The stage's imperfections: the profile's defaults, overridden by --inject stage_*."""
    given = {
        key.removeprefix("stage_"): getattr(spec, key)
        for key in spec.model_fields_set
        if key.startswith("stage_")
    }
    return StageFaults.from_profile(profile).updated(**given)


def _wrap_u32(values: Mapping[str, int]) -> dict[str, int]:
    # Device counters are u32 registers: they wrap rather than refuse to be reported.
    return {name: value % _U32_WRAP for name, value in values.items()}
