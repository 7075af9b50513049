"""The FPGA's filter-wheel commands (docs/physics.md §4, docs/wheel.md).

WHEEL_SET_SPEED, WHEEL_GET, WHEEL_COMPENSATION, WHEEL_ACQUIRE and SIM_SET_POLARIZER (the
scene's reference polariser); a group of handlers of ``firmware_models.fpga``. The wheel turns
from power-on at its nominal speed (config/wheel.toml). A wheel acquisition schedules each
frame's exposure on the wheel's channel and streams the frames through the imaging pipeline
with the channel's transmission in the light path.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from camd.protocol import CommandSpec
from camd.protocol.dictionary import FieldValue, f32_decimal
from firmware_models.errors import Nak
from firmware_models.fpga_commands import Handler, Outcome
from firmware_models.fpga_parts import DeviceParts, PartsGroup
from firmware_models.imaging import StreamRefused

# docs/protocol.md WHEEL_SET_SPEED: slower than this but not 0 is refused (OUT_OF_RANGE); the
# period of a slower turn would not fit the answer's f32 (a denormal speed made it 2.6e47 s).
MIN_SPEED_DEG_S = 1e-7


class WheelCommands(PartsGroup):
    """The filter wheel: its speed, the exposure delay compensation, acquisitions."""

    def __init__(self, parts: DeviceParts) -> None:
        super().__init__(parts)
        self.compensation = False
        self.polarizer_deg: float | None = None  # the scene's reference polariser, if any
        self._lead_s = 0.0  # how far the wheel's clock runs ahead of the device's (below)

    def handlers(self) -> dict[str, Handler]:
        """The commands of this group."""
        return {
            "WHEEL_SET_SPEED": self.wheel_set_speed,
            "WHEEL_GET": self.wheel_get,
            "WHEEL_COMPENSATION": self.wheel_compensation,
            "WHEEL_ACQUIRE": self.wheel_acquire,
            "SIM_SET_POLARIZER": self.sim_set_polarizer,
        }

    def _timing(self) -> tuple[float, float, float]:
        """(T_frame, T_delay for the registers now, exposure) (docs/physics.md §4 eqs 5, 6)."""
        timing = self.parts.sensor.timing()
        frame = timing.frame_time_s
        return frame, self.parts.wheel.profile.t_center_s.value - frame / 2, timing.exposure_s

    def _wheel_time_s(self, now_s: float) -> float:
        """Where the wheel's model time is: a wheel acquisition runs ahead of the wall clock
        (its frames are not paced), and the wheel is read and set there.

        The wheel's clock keeps that lead afterwards and goes on at the wall clock's rate: a
        clock held at the acquisition's end until the wall caught up made two WHEEL_GETs 0.2 s
        apart read the same time, and conformance's wheel.speed measured the wheel as standing
        (a busy machine, the check right after a wheel acquisition of several turns).
        """
        return now_s - self.parts.state.power_on_s + self._lead_s

    def wheel_set_speed(
        self, spec: CommandSpec, request: dict[str, FieldValue], now_s: float
    ) -> Outcome:
        if self.parts.imaging_path.streaming and self.parts.camera.transmission is not None:
            raise Nak("ILLEGAL_STATE", "WHEEL_SET_SPEED refused during a wheel acquisition")
        speed = f32_decimal(float(request["speed_deg_s"]))
        if 0.0 < speed < MIN_SPEED_DEG_S:
            # Checked before the wheel is touched: a refused command changes nothing.
            raise Nak(
                "OUT_OF_RANGE",
                f"speed {speed:.6g} deg/s is too slow: its period does not fit the answer's f32; "
                f"use 0 (stop) or at least {MIN_SPEED_DEG_S:g} deg/s",
            )
        self.parts.wheel.set_speed(speed, self._wheel_time_s(now_s))
        return Outcome(spec.encode_response(period_s=360.0 / speed if speed > 0 else 0.0))

    def wheel_get(self, spec: CommandSpec, request: dict[str, FieldValue], now_s: float) -> Outcome:
        t = self._wheel_time_s(now_s)
        frame, delay, _ = self._timing()
        channel = self.parts.wheel.channel_at(t)
        return Outcome(
            spec.encode_response(
                speed_deg_s=self.parts.wheel.speed_deg_s(t),
                angle_deg=self.parts.wheel.angle_deg(t),
                channel=255 if channel is None else channel,
                compensation="on" if self.compensation else "off",
                frame_time_s=frame,
                delay_s=delay,
                time_s=t,
            )
        )

    def wheel_compensation(
        self, spec: CommandSpec, request: dict[str, FieldValue], now_s: float
    ) -> Outcome:
        on = request["enable"] == "on"
        frame, delay, _ = self._timing()
        if on:
            try:
                self.parts.wheel.profile.exposure(frame, compensated=True)
            except ValueError as exc:
                raise Nak("OUT_OF_RANGE", f"WHEEL_COMPENSATION refused: {exc}") from None
        self.compensation = on
        return Outcome(spec.encode_response(frame_time_s=frame, delay_s=delay if on else 0.0))

    def wheel_acquire(
        self, spec: CommandSpec, request: dict[str, FieldValue], now_s: float
    ) -> Outcome:
        self.parts.state.require_no_fault(spec)
        if self.parts.imaging_path.streaming:
            raise Nak("ILLEGAL_STATE", "WHEEL_ACQUIRE refused: streaming; STOP_STREAM first")
        if not self.parts.sensor_link.trained:
            raise Nak(
                "LINK_UNTRAINED",
                "WHEEL_ACQUIRE refused: the sensor's LVDS link is not trained; TRAIN first",
            )
        raw = bytes(request["channels"])  # type: ignore[arg-type]
        count = self.parts.wheel.profile.channel_count.value
        if not raw or any(c >= count for c in raw):
            raise Nak(
                "OUT_OF_RANGE",
                f"WHEEL_ACQUIRE refused: channels {list(raw)}; give 1 to {count} channel "
                f"numbers 0..{count - 1}",
            )
        t = self._wheel_time_s(now_s)
        if self.parts.wheel.speed_deg_s(t) <= 0.0:
            raise Nak("ILLEGAL_STATE", "WHEEL_ACQUIRE refused: the wheel is stopped; "
                      "WHEEL_SET_SPEED first")  # fmt: skip
        frame, _, _ = self._timing()
        line = self.parts.sensor.timing().line_period_s
        # wheel_ignores_delay: the scheduler exposes at the entry pulse whatever is switched on.
        delayed = self.compensation and not self.parts.defects.wheel_ignores_delay
        starts: list[float] = []
        stamps: list[int] = []
        try:
            for _ in range(int(request["passes"])):
                for channel in raw:
                    start = self.parts.wheel.exposure_schedule(channel, t, frame, delayed)
                    starts.append(start + line)  # row 0 resets one line into the frame
                    stamps.append(round(float(self.parts.wheel.angle_deg(start)) * 1e4))
                    t = start + frame
        except ValueError as exc:
            raise Nak("OUT_OF_RANGE", f"WHEEL_ACQUIRE refused: {exc}") from None
        self._lead_s = max(self._lead_s, t - (now_s - self.parts.state.power_on_s))
        self.parts.camera.transmission = self._transmission()
        try:
            geometry = self.parts.imaging_path.start(
                device_time_s=starts[0],
                mode="area",
                frames=len(starts),
                stages=0,
                binning=False,
                schedule_s=starts,
                stamps=stamps,
                end_after=self.parts.state.end_stream_after,
            )
        except StreamRefused as exc:
            self.parts.camera.transmission = None
            raise Nak("OUT_OF_RANGE", f"WHEEL_ACQUIRE refused: {exc}") from None
        delay = self.parts.wheel.profile.t_center_s.value - frame / 2 if self.compensation else 0
        return Outcome(
            spec.encode_response(
                frames=len(starts),
                first_counter=geometry.first_counter,
                rows=geometry.rows,
                cols=geometry.cols,
                frame_time_s=frame,
                delay_s=delay,
            )
        )

    def _transmission(self) -> Callable[[Any, Any], Any]:
        """The light a frame's rows get through the wheel (``CameraModel.transmission``), with
        the polariser set now."""
        wheel, polarizer = self.parts.wheel, self.polarizer_deg

        def transmission(start_s: Any, end_s: Any) -> Any:
            mid = 0.5 * (float(start_s.min()) + float(end_s.max()))
            channel = wheel.channel_at(mid)
            if channel is None:
                return 0.0 * start_s
            return wheel.row_transmission(channel, start_s, end_s, polarizer)

        return transmission

    def sim_set_polarizer(
        self, spec: CommandSpec, request: dict[str, FieldValue], now_s: float
    ) -> Outcome:
        on = request["enable"] == "on"
        self.polarizer_deg = f32_decimal(float(request["angle_deg"])) if on else None
        return Outcome(spec.encode_response())
