"""The FPGA's sensor commands: registers over the SPI master, the LVDS link and their counters.

REG_READ, REG_WRITE, REG_WRITE_BURST, GET_SENSOR, TRAIN, GET_LANE, SIM_GET_SPI_STATS and
SIM_RESKEW (docs/simulator.md, "What the FPGA model does"); a group of handlers of
``firmware_models.fpga``.
"""

from __future__ import annotations

import struct

from camd.protocol import CommandSpec, Frame
from camd.protocol.dictionary import FieldValue
from camd.sensor.regmap import RegisterMap, RegisterSpec
from firmware_models.errors import Nak
from firmware_models.fpga_commands import Handler, Outcome, wrap_u32
from firmware_models.fpga_parts import DeviceParts, PartsGroup


class SensorCommands(PartsGroup):
    """The sensor's registers (through ``spi``, the FPGA's SPI master) and its LVDS link."""

    def __init__(self, parts: DeviceParts) -> None:
        super().__init__(parts)
        self.regmap = parts.sensor.regmap
        # register_readback_off_by_one: the register whose reads are off (None: no defect).
        self._off_by_one_address = (
            _off_by_one_register(self.regmap)
            if parts.defects.register_readback_off_by_one
            else None
        )

    def handlers(self) -> dict[str, Handler]:
        """The commands of this group."""
        return {
            "REG_READ": self.reg_read,
            "REG_WRITE": self.reg_write,
            "REG_WRITE_BURST": self.reg_write_burst,
            "GET_SENSOR": self.get_sensor,
            "TRAIN": self.train,
            "GET_LANE": self.get_lane,
            "SIM_GET_SPI_STATS": self.sim_get_spi_stats,
            "SIM_RESKEW": self.sim_reskew,
        }

    # -- registers over the SPI master ----------------------------------------------------------

    def _register(self, spec: CommandSpec, address: int) -> RegisterSpec:
        if not self.regmap.has_register(address):
            raise Nak(
                "REG_UNKNOWN",
                f"{spec.name}: {self.regmap.sensor} has no register at address 0x{address:02X}",
            )
        return self.regmap.register(address)

    def _check_write(self, spec: CommandSpec, address: int, value: int) -> None:
        reg = self._register(spec, address)
        if not reg.writable:
            raise Nak(
                "REG_READ_ONLY", f"{spec.name}: register {reg.name} (0x{address:02X}) is read-only"
            )
        if value > reg.mask:
            raise Nak(
                "OUT_OF_RANGE",
                f"{spec.name}: 0x{value:X} does not fit register {reg.name}'s {reg.width} bits",
            )

    def reg_read(self, spec: CommandSpec, request: dict[str, FieldValue], now_s: float) -> Outcome:
        address = int(request["address"])
        reg = self._register(spec, address)
        if not reg.readable:
            raise Nak(
                "REG_WRITE_ONLY", f"REG_READ: register {reg.name} (0x{address:02X}) is write-only"
            )
        value = self.parts.spi.read(address)
        if address == self._off_by_one_address:
            value = (value + 1) & reg.mask  # register_readback_off_by_one
        return Outcome(spec.encode_response(address=address, value=value))

    def reg_write(self, spec: CommandSpec, request: dict[str, FieldValue], now_s: float) -> Outcome:
        address, value = int(request["address"]), int(request["value"])
        self._check_write(spec, address, value)
        self.parts.spi.write(address, value)
        self.parts.imaging_path.note_registers(now_s - self.parts.state.power_on_s)
        return Outcome(spec.encode_response(address=address, value=value))

    def reg_write_burst(
        self, spec: CommandSpec, request: dict[str, FieldValue], now_s: float
    ) -> Outcome:
        data = request["pairs"]
        assert isinstance(data, bytes)
        if not data or len(data) % 4:
            raise Nak(
                "BAD_LENGTH",
                f"REG_WRITE_BURST: {len(data)} bytes of pairs; send 1 to 255 (address u16, "
                "value u16) pairs, 4 bytes each",
            )
        pairs = list(struct.iter_unpack(">HH", data))
        for address, value in pairs:  # all checked before the first is written
            self._check_write(spec, address, value)
        for address, value in pairs:
            self.parts.spi.write(address, value)
        self.parts.imaging_path.note_registers(now_s - self.parts.state.power_on_s)
        return Outcome(spec.encode_response(count=len(pairs)))

    def sim_get_spi_stats(
        self, spec: CommandSpec, request: dict[str, FieldValue], now_s: float
    ) -> Outcome:
        values = {
            "transactions": self.parts.spi_slave.transactions,
            "reads": sum(self.parts.sensor.reads.values()),
            "writes": sum(self.parts.sensor.writes.values()),
            "errors": self.parts.spi_slave.errors,
        }
        return Outcome(spec.encode_response(**wrap_u32(values)))

    # -- the LVDS link ----------------------------------------------------------------------------

    def get_sensor(
        self, spec: CommandSpec, request: dict[str, FieldValue], now_s: float
    ) -> Outcome:
        link = self.parts.sensor_link
        return Outcome(
            spec.encode_response(
                interface=self.regmap.output.interface,
                lanes=link.lanes,
                trained="yes" if link.trained else "no",
                imaging="yes" if self.parts.imaging_path.streaming else "no",
                sensor=self.regmap.sensor,
            )
        )

    def train(self, spec: CommandSpec, request: dict[str, FieldValue], now_s: float) -> Outcome:
        self.parts.state.require_no_fault(spec)
        if self.parts.imaging_path.streaming:
            raise Nak("ILLEGAL_STATE", "TRAIN refused while imaging; send STOP_IMAGING first")
        report = self.parts.sensor_link.train()
        locked = "yes" if report.locked else "no"
        event = self.parts.state.event("LINK_TRAINED", locked=locked, bit_errors=report.bit_errors)
        return Outcome(
            spec.encode_response(
                lanes=report.lanes,
                locked_lanes=report.locked_lanes,
                locked=locked,
                bit_errors=report.bit_errors,
                verified_bits=report.verified_bits,
            ),
            (event,),
        )

    def get_lane(self, spec: CommandSpec, request: dict[str, FieldValue], now_s: float) -> Outcome:
        lane = int(request["lane"])
        link = self.parts.sensor_link
        if lane >= link.lanes:
            raise Nak(
                "OUT_OF_RANGE",
                f"GET_LANE: lane {lane} does not exist; the link has {link.lanes} lanes "
                f"(0..{link.lanes - 1})"
                if link.lanes
                else "GET_LANE: the sensor has no LVDS lanes",
            )
        result = link.lane(lane)
        return Outcome(
            spec.encode_response(
                lane=lane,
                tap=result.tap,
                eye_width=result.eye_width_taps,
                slips=result.slips,
                shift=result.shift,
                locked="yes" if result.locked else "no",
            )
        )

    def sim_reskew(
        self, spec: CommandSpec, request: dict[str, FieldValue], now_s: float
    ) -> Outcome:
        was_trained = self.parts.sensor_link.trained
        self.parts.sensor_link.reskew(int(request["seed"]))
        events: tuple[Frame, ...] = ()
        if was_trained and not self.parts.sensor_link.trained:
            events = (self.parts.state.event("LINK_LOST"),)
            if self.parts.imaging_path.streaming:
                # Garbled frames are no frames: the FPGA stops the stream and says so.
                produced, next_counter = self.parts.imaging_path.stop()
                events += (
                    self.parts.state.event(
                        "STREAM_DONE", frames_sent=produced, next_counter=next_counter
                    ),
                )
        return Outcome(spec.encode_response(), events)


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
