"""The FPGA's own commands: status, housekeeping, mode, reset and the command link's counters.

PING, GET_STATUS, GET_HOUSEKEEPING, RESET, SET_MODE and GET_LINK_STATS (docs/simulator.md,
"What the FPGA model does"); a group of handlers of ``firmware_models.fpga``.
"""

from __future__ import annotations

from camd.protocol import CommandSpec, Frame
from camd.protocol.dictionary import FieldValue
from firmware_models.fpga_commands import (
    FW_VERSION,
    U32_WRAP,
    Handler,
    Outcome,
    wrap_u32,
)
from firmware_models.fpga_parts import PartsGroup


class ControlCommands(PartsGroup):
    """Status, housekeeping, mode, RESET and the link's counters (``receiver``: the device's
    frame decoder, whose CRC errors, resyncs and dropped bytes GET_LINK_STATS reports)."""

    def handlers(self) -> dict[str, Handler]:
        """The commands of this group."""
        return {
            "PING": self.ping,
            "GET_STATUS": self.get_status,
            "GET_HOUSEKEEPING": self.get_housekeeping,
            "RESET": self.reset,
            "SET_MODE": self.set_mode,
            "GET_LINK_STATS": self.get_link_stats,
        }

    def housekeeping_values(self, now_s: float) -> dict[str, float | int]:
        """The HOUSEKEEPING packet's fields sampled at ``now_s``."""
        values: dict[str, float | int] = dict(self.parts.housekeeping.sample(now_s))
        values["executed"] = self.parts.link.counters.executed % U32_WRAP
        return values

    def ping(self, spec: CommandSpec, request: dict[str, FieldValue], now_s: float) -> Outcome:
        return Outcome(spec.encode_response(data=request["data"]))

    def get_status(
        self, spec: CommandSpec, request: dict[str, FieldValue], now_s: float
    ) -> Outcome:
        state = self.parts.state
        return Outcome(
            spec.encode_response(
                mode=state.mode,
                device_state=state.device_state,
                fault_code=state.fault_code,
                uptime_s=self.parts.housekeeping.uptime_s(now_s),
                fw_version=FW_VERSION,
                boot_count=state.boot_count,
            )
        )

    def get_housekeeping(
        self, spec: CommandSpec, request: dict[str, FieldValue], now_s: float
    ) -> Outcome:
        return Outcome(spec.encode_response(**self.housekeeping_values(now_s)))

    def reset(self, spec: CommandSpec, request: dict[str, FieldValue], now_s: float) -> Outcome:
        # Link counters and the at-most-once record deliberately survive (firmware_models.
        # fpga_link). The FPGA's deserializer restarts too: the sensor link must be trained
        # again. The sensor's registers are the sensor's and survive an FPGA reset.
        state = self.parts.state
        state.mode = "area"
        state.fault_code = 0
        self.parts.imaging_path.stop()  # the reset stops the sequencer: no STREAM_DONE
        self.parts.sensor_link.untrain()
        state.boot_count = (state.boot_count + 1) % 0x10000
        self.parts.housekeeping.restart_uptime(now_s)
        return Outcome(spec.encode_response(), (state.event("BOOT", boot_count=state.boot_count),))

    def set_mode(self, spec: CommandSpec, request: dict[str, FieldValue], now_s: float) -> Outcome:
        state = self.parts.state
        state.require_no_fault(spec)
        mode = str(request["mode"])
        events: tuple[Frame, ...] = ()
        if mode != state.mode:
            state.mode = mode
            events = (state.event("MODE_CHANGED", mode=mode),)
        return Outcome(spec.encode_response(mode=state.mode), events)

    def get_link_stats(
        self, spec: CommandSpec, request: dict[str, FieldValue], now_s: float
    ) -> Outcome:
        rx = self.parts.receiver.stats
        counters = self.parts.link.counters
        values = {
            "rx_frames": counters.rx_frames,
            "crc_errors": rx.crc_errors,
            "resyncs": rx.resyncs,
            "bytes_dropped": rx.bytes_dropped,
            "executed": counters.executed,
            "replayed": counters.replayed,
            "nacked": counters.nacked,
            "tx_frames": counters.tx_frames,
        }
        return Outcome(spec.encode_response(**wrap_u32(values)))
