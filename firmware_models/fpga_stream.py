"""The FPGA's stream commands: START_STREAM, STOP_STREAM, GET_STREAM, SIM_GET_STREAM_STATS.

The imaging pipeline (``firmware_models.imaging``) makes the frames and the stream engine
(``firmware_models.fx3``) sends them (docs/stream.md); a group of handlers of
``firmware_models.fpga``.
"""

from __future__ import annotations

from camd.protocol import CommandSpec
from camd.protocol.dictionary import FieldValue
from firmware_models.errors import Nak
from firmware_models.fpga_commands import U32_WRAP, Handler, Outcome, wrap_u32
from firmware_models.fpga_parts import PartsGroup
from firmware_models.imaging import StreamRefused


class StreamCommands(PartsGroup):
    """Streams of window frames from the camera to the host."""

    def handlers(self) -> dict[str, Handler]:
        """The commands of this group."""
        return {
            "START_STREAM": self.start_stream,
            "STOP_STREAM": self.stop_stream,
            "GET_STREAM": self.get_stream,
            "SIM_GET_STREAM_STATS": self.sim_get_stream_stats,
        }

    def start_stream(
        self, spec: CommandSpec, request: dict[str, FieldValue], now_s: float
    ) -> Outcome:
        state = self.parts.state
        state.require_no_fault(spec)
        if self.parts.imaging_path.streaming:
            raise Nak("ILLEGAL_STATE", "START_STREAM refused: already streaming; STOP_STREAM first")
        if not self.parts.sensor_link.trained:
            raise Nak(
                "LINK_UNTRAINED",
                "START_STREAM refused: the sensor's LVDS link is not trained; send TRAIN first",
            )
        self.parts.camera.transmission = None  # a plain stream: no wheel in the light path
        try:
            geometry = self.parts.imaging_path.start(
                device_time_s=now_s - state.power_on_s,
                mode=state.mode,
                frames=int(request["frames"]),
                stages=int(request["stages"]),
                binning=request["binning"] == "2x2",
                end_after=state.end_stream_after,
            )
        except StreamRefused as exc:
            raise Nak("OUT_OF_RANGE", f"START_STREAM refused: {exc}") from None
        return Outcome(
            spec.encode_response(
                mode=geometry.mode,
                rows=geometry.rows,
                cols=geometry.cols,
                bits=geometry.bits,
                frame_period_s=geometry.frame_period_s,
                first_counter=geometry.first_counter,
            )
        )

    def stop_stream(
        self, spec: CommandSpec, request: dict[str, FieldValue], now_s: float
    ) -> Outcome:
        produced, next_counter = self.parts.imaging_path.stop()
        return Outcome(spec.encode_response(frames_sent=produced, next_counter=next_counter))

    def get_stream(
        self, spec: CommandSpec, request: dict[str, FieldValue], now_s: float
    ) -> Outcome:
        server = self.parts.stream.server
        return Outcome(
            spec.encode_response(
                streaming="yes" if self.parts.imaging_path.streaming else "no",
                frames_sent=self.parts.stream.frames_produced % U32_WRAP,
                next_counter=self.parts.imaging_path.next_counter,
                host_connected="yes" if server is not None and server.connected else "no",
            )
        )

    def sim_get_stream_stats(
        self, spec: CommandSpec, request: dict[str, FieldValue], now_s: float
    ) -> Outcome:
        counters = self.parts.stream.counters.as_dict()
        names = [f.name for f in spec.response]
        return Outcome(spec.encode_response(**wrap_u32({k: counters[k] for k in names})))
