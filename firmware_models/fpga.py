"""The simulated camera FPGA's command processor (sans-I/O: frames in, frames out).

``FpgaModel.handle(frame, now_s)`` executes one received command frame against the command
dictionary of ``config/protocol.toml`` and returns the frames the device sends back: an ACK or
NAK, then any unsolicited EVENT frames the command caused. Time is passed in, never read, so
the model is deterministic for a given seed and sequence of calls; ``firmware_models.pty_server``
puts it behind a real pseudo-terminal.

The model puts the camera together and does nothing else itself: the parts (sensor and its SPI
bus and LVDS link, camera physics, imaging pipeline, stream engine, stepper stage, filter
wheel, housekeeping), the device end of the command link (``firmware_models.fpga_link``:
at-most-once execution, failures on purpose, request checks) and the groups of command
handlers, one per part (``fpga_control``, ``fpga_sensor``, ``fpga_stream``, ``fpga_motion``,
``fpga_wheel``, ``fpga_sim``; what they share is ``firmware_models.fpga_commands``), whose
tables make the link's dispatch table.
"""

from __future__ import annotations

import threading
from collections import Counter
from collections.abc import Callable

from camd.motion.stage_profile import StageProfile, load_stage_profile
from camd.motion.wheel_profile import load_wheel_profile
from camd.protocol import Decoder, Dictionary, Frame, FrameType, load_dictionary
from camd.sensor.profile import load_profile
from camd.sensor.regmap import RegisterMap, load_register_map
from firmware_models.camera import CameraModel
from firmware_models.defects import NONE, Defects
from firmware_models.fpga_commands import FW_VERSION, U32_WRAP, DeviceState, dispatch_table
from firmware_models.fpga_control import ControlCommands
from firmware_models.fpga_link import CommandLink, LinkCounters
from firmware_models.fpga_motion import MotionCommands, stage_faults
from firmware_models.fpga_sensor import SensorCommands
from firmware_models.fpga_sim import SimCommands
from firmware_models.fpga_stream import StreamCommands
from firmware_models.fpga_wheel import WheelCommands
from firmware_models.fx3 import StreamEngine, StreamSocketServer
from firmware_models.housekeeping import HousekeepingModel
from firmware_models.imaging import ImagingPipeline
from firmware_models.inject import FaultInjector
from firmware_models.motor import MotorController
from firmware_models.sensor import SensorModel
from firmware_models.sensor_link import SensorLink
from firmware_models.spi import SpiMaster, SpiSlave
from firmware_models.wheel import FilterWheel

__all__ = ["FW_VERSION", "FpgaModel", "LinkCounters"]


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
        self.stream.ready = self.imaging_path.ready
        self.stream.defects = self.imaging_path.defects = defects
        # The scan stage: a stepper the MOTOR_* commands drive (firmware_models.fpga_motion).
        stage_profile = stage if isinstance(stage, StageProfile) else load_stage_profile(stage)
        self.motor = MotorController(
            stage_profile, seed=seed or 0, faults=stage_faults(stage_profile, self.injector.spec)
        )
        # Straight to the step counter: a frame's header asks for the revision (a block of
        # frames for the counts), so no call in between.
        counter = self.motor.counter
        self.imaging_path.encoder_at = counter.encoder_counts
        self.imaging_path.encoder_revision = lambda: counter.revision
        # The filter wheel turns from power-on at its nominal speed (config/wheel.toml).
        self.wheel = FilterWheel(load_wheel_profile(), t_s=0.0)
        # Events that no command caused (STREAM_DONE from the stream thread) wait here until
        # the transport collects them; ``wake`` tells it there are some.
        self._unsent_events: list[Frame] = []
        self.wake: Callable[[], None] | None = None
        self.receiver = Decoder()
        self.housekeeping = HousekeepingModel(seed=seed, power_on_s=power_on_s)
        self.state = DeviceState(self.dictionary, power_on_s)
        self.link = CommandLink(self.state, defects=defects)
        self.control = ControlCommands(self)
        self._wheel_commands = WheelCommands(self)
        self.link.table = dispatch_table([
            self.control,
            SensorCommands(self),
            StreamCommands(self),
            MotionCommands(self),
            self._wheel_commands,
            SimCommands(self),
        ])  # fmt: skip

    # -- frames in, frames out ------------------------------------------------------------

    def handle(self, frame: Frame, now_s: float) -> list[Frame]:
        """Execute (or replay) one received frame; return the frames to send, in order."""
        with self.lock:
            return self.link.receive(frame, now_s)

    def silent(self, now_s: float) -> bool:
        """True while the device is off the line (SIM_FAIL_NEXT silence): it answers nothing,
        and the transport sends nothing it makes (events, telemetry) until ``now_s`` passes."""
        return self.link.silent(now_s)

    def take_unsolicited(self, now_s: float | None = None) -> list[Frame]:
        """Events raised outside any command since the last call, in order; with ``now_s``,
        also the stage's stops due by then (MOTOR_STOPPED)."""
        with self.lock:
            if now_s is not None:
                for name, values in self.motor.poll_events(now_s - self.power_on_s):
                    self._unsent_events.append(self.state.event(name, **values))
            frames, self._unsent_events = self._unsent_events, []
        return self.link.sent(frames)

    def next_event_s(self) -> float | None:
        """When (transport clock) the next unsolicited event is due, if one is planned."""
        with self.lock:
            due = self.motor.next_event_s()
        return None if due is None else due + self.power_on_s

    def boot_frames(self, now_s: float) -> list[Frame]:
        """The frames the device sends when it starts: a BOOT event."""
        return self.link.sent([self.state.event("BOOT", boot_count=self.boot_count)])

    def housekeeping_frame(self, now_s: float) -> Frame:
        """One periodic HOUSEKEEPING telemetry frame sampled at ``now_s``."""
        packet = self.dictionary.telemetry_packet("HOUSEKEEPING")
        payload = packet.encode(**self.control.housekeeping_values(now_s))
        frame = self.state.unsolicited(FrameType.TELEMETRY, packet.opcode, payload)
        return self.link.sent([frame])[0]

    def _stream_done(self, frames_sent: int, next_counter: int) -> None:
        """A counted stream ended by itself (stream thread): tell the host with STREAM_DONE.

        A stream stopped by a command (STOP_STREAM, RESET, SIM_RESKEW) is reported by that
        command, not here (``ImagingPipeline.stop``)."""
        with self.lock:
            self._unsent_events.append(
                self.state.event(
                    "STREAM_DONE", frames_sent=frames_sent % U32_WRAP, next_counter=next_counter
                )
            )
        wake = self.wake
        if wake is not None:
            wake()

    # -- the parts ------------------------------------------------------------------------

    def close(self) -> None:
        """Stop any stream and end the stream engine's thread."""
        self.imaging_path.stop()
        self.stream.close()

    def attach_stream_server(self, server: StreamSocketServer) -> None:
        """Send the stream to a host over ``server`` (``--usb-socket``)."""
        self.stream.server = server

    def execution_count(self, command: str | int) -> int:
        """How many times a command (by name or opcode) was executed, replays not counted."""
        opcode = command if isinstance(command, int) else self.dictionary.command(command).opcode
        return self.link.executions[opcode]

    # -- the state, as the commands leave it ------------------------------------------------

    @property
    def imaging(self) -> bool:
        """The sensor's sequencer runs and frames stream (START_STREAM)."""
        return self.imaging_path.streaming

    @property
    def counters(self) -> LinkCounters:
        """The command link's counters (GET_LINK_STATS, plus ``ignored`` and ``silenced``)."""
        return self.link.counters

    @property
    def executions(self) -> Counter[int]:
        """Opcode -> commands executed (not replayed)."""
        return self.link.executions

    @property
    def power_on_s(self) -> float:
        """The transport clock at power-on (device time 0)."""
        return self.state.power_on_s

    @property
    def mode(self) -> str:
        """The imaging mode, ``area`` or ``tdi`` (SET_MODE)."""
        return self.state.mode

    @property
    def fault_code(self) -> int:
        """The active fault's code, 0 for none (SIM_SET_FAULT, RESET)."""
        return self.state.fault_code

    @property
    def boot_count(self) -> int:
        """Boots since power-on, this one included (RESET adds one)."""
        return self.state.boot_count

    @property
    def device_state(self) -> str:
        """The GET_STATUS device_state: ``fault`` while a fault is active, else ``idle``."""
        return self.state.device_state

    @property
    def wheel_compensation(self) -> bool:
        """The wheel's exposure delay compensation is on (WHEEL_COMPENSATION)."""
        return self._wheel_commands.compensation

    @property
    def polarizer_deg(self) -> float | None:
        """The scene's reference polariser angle, None without one (SIM_SET_POLARIZER)."""
        return self._wheel_commands.polarizer_deg
