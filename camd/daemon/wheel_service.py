"""The filter wheel in the daemon: status, speed, delay compensation and wheel acquisitions.

``WheelService`` belongs to a DeviceSession (docs/wheel.md, docs/physics.md §4). The FPGA waits for
each channel's entry pulse and, with compensation on, for ``T_delay = T_center - T_frame / 2``
before it exposes (WHEEL_COMPENSATION, WHEEL_ACQUIRE). camd computes the same numbers on its
side, from the exposure and window in the sensor's registers and ``config/wheel.toml``
(``WheelProfile.exposure``, i.e. ``camd.timing.wheel``), so that:

- an exposure that cannot fit the channel's light window (``T_frame > window``, or with
  compensation ``T_delay < 0``) is refused before anything is written, with camd's numbers in
  the message, not only the device's NAK;
- every frame of an acquisition is reported with its predicted imaging-centre angle (eq 4, or
  eq 1 without compensation) and that angle's uncertainty (eq 8), next to the wheel angle the
  FPGA latched at the exposure start (the frame header's ``stage_position``, 1e-4 deg).

A wheel acquisition is a counted stream started by WHEEL_ACQUIRE instead of START_STREAM
(``StreamService.acquire(start=...)``): the same USB reader, recording and state machine
(idle -> streaming -> idle on STREAM_DONE).
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from camd.daemon.device import DeviceAccess
from camd.daemon.errors import BadRequest, SessionError
from camd.daemon.models import (
    StreamStartRequest,
    TimingResponse,
    WheelAcquireRequest,
    WheelAcquireResponse,
    WheelChannelInfo,
    WheelExposureInfo,
    WheelFrame,
    WheelRegion,
    WheelStatus,
)
from camd.daemon.sensor_service import SensorService
from camd.daemon.state import Request
from camd.daemon.stream_service import StreamService, StreamStart
from camd.daemon.transaction import Apply
from camd.link.frame_stream import ReceivedFrame
from camd.motion.wheel import FilterWheel, FpgaWheel, WheelReading, WheelSpeedError
from camd.motion.wheel_profile import WheelProfile, load_wheel_profile
from camd.store.recording import RecordingError, check_new_file
from camd.timing import sequencer_frame_time_s
from camd.timing.wheel import exposure_delay_s, imaging_centre_angle_deg

ANGLE_UNIT_DEG = 1e-4
"""A wheel frame header's ``stage_position`` counts the wheel angle in these units."""

_COUNTER_WRAP = 1 << 32


@dataclass(frozen=True, slots=True)
class _Seen:
    """What the consumer keeps of one frame (the pixels are only valid during the call)."""

    counter: int
    stage_position: int
    timestamp_ns: int
    mean: float


class _FrameMeans:
    """Stream consumer: each frame's counter, header angle and mean signal (of a region)."""

    def __init__(self, region: WheelRegion | None) -> None:
        self.region = region
        self.seen: list[_Seen] = []
        self._lock = threading.Lock()

    def __call__(self, frame: ReceivedFrame) -> None:
        pixels = frame.pixels
        region = self.region
        if region is not None:
            pixels = pixels[
                region.row : region.row + region.rows, region.col : region.col + region.cols
            ]
        mean = float(pixels.mean(dtype=np.float64))
        header = frame.header
        with self._lock:
            self.seen.append(
                _Seen(header.counter, header.stage_position, header.timestamp_ns, mean)
            )

    def frames(self) -> list[_Seen]:
        with self._lock:
            return list(self.seen)


class WheelService:
    """Filter-wheel requests for one device session (module docstring)."""

    def __init__(self, device: DeviceAccess, sensor: SensorService, stream: StreamService) -> None:
        self.device = device
        self.sensor = sensor
        self.stream = stream
        self._profile: WheelProfile | None = None
        self._wheel: FilterWheel | None = None

    @property
    def profile(self) -> WheelProfile:
        """The wheel of ``config/wheel.toml`` (loaded once)."""
        if self._profile is None:
            try:
                self._profile = load_wheel_profile()
            except (OSError, ValueError) as exc:
                raise BadRequest(f"the wheel file: {exc}") from None
        return self._profile

    @property
    def wheel(self) -> FilterWheel:
        """The wheel behind the camera's WHEEL_* commands (the simulated camera answers them)."""
        if self._wheel is None:
            self._wheel = FpgaWheel(
                self.profile,
                lambda command, **fields: self.device.request(command, **fields).values,
            )
        return self._wheel

    # -- requests -----------------------------------------------------------------------------------

    def status(self) -> WheelStatus:
        """WHEEL_GET, the wheel file's numbers and camd's computation for the registers now."""
        self.device.require(Request.WHEEL_READ)
        reading = self.wheel.read()
        timing = self.sensor.timing()
        profile = self.profile
        speed = reading.speed_deg_s
        compensated = reading.compensation
        return WheelStatus(
            wheel=profile.wheel,
            speed_deg_s=speed,
            nominal_speed_deg_s=profile.speed_deg_s.value,
            period_s=360.0 / speed if speed > 0 else None,
            angle_deg=reading.angle_deg,
            channel=reading.channel,
            compensation=compensated,
            t_center_s=profile.t_center_s.value,
            window_s=profile.window_s.value,
            device_frame_time_s=reading.frame_time_s,
            device_delay_s=reading.delay_s,
            exposure=self._exposure_now(timing, compensated=compensated, speed_deg_s=speed),
            channels=self._channels_info(),
            time_s=reading.time_s,
        )

    def stop_now(self) -> bool:
        """Stop the wheel at once, whatever the daemon's state (``POST /api/v1/estop``)."""
        self.wheel.stop()
        self.device.log_event("warning", "wheel", "filter wheel stopped (emergency stop)")
        return True

    def set_speed(self, speed_deg_s: float) -> WheelStatus:
        """Turn the wheel at ``speed_deg_s`` (0 stops it). If the answer is lost, the wheel may
        have changed speed: the speed before is put back (``Apply``). Turning it is refused
        while the emergency stop is latched; stopping it never is."""
        if speed_deg_s != 0.0:
            self.device.estop.check("turn the filter wheel")
        self.device.require(Request.WHEEL_SET)
        wheel = self.wheel
        try:
            wheel.check_speed(speed_deg_s)
        except WheelSpeedError as exc:
            raise BadRequest(str(exc)) from None
        before = wheel.read().speed_deg_s
        with Apply("wheel speed change", self._events, source="wheel") as apply:
            apply.step(
                lambda: wheel.set_speed(speed_deg_s),
                lambda: wheel.set_speed(before),
                f"wheel speed {before:g} deg/s",
            )
            apply.done()
        nominal = self.profile.speed_deg_s.value
        message = f"filter wheel speed set to {speed_deg_s:g} deg/s"
        level = "info"
        if speed_deg_s > 0 and not math.isclose(speed_deg_s, nominal, rel_tol=1e-6):
            # T_center is a time at the nominal speed; the entry point is a mark on the wheel.
            level = "warning"
            shift = (speed_deg_s - nominal) * self.profile.t_center_s.value
            message += (
                f", not the wheel file's {nominal:g} deg/s: a compensated frame's centre lands "
                f"{shift:+.4g} deg from the channel centre (the T_center dw term of eq 8)"
            )
        self.device.log_event(level, "wheel", message)
        return self.status()

    def set_compensation(self, on: bool) -> WheelStatus:
        """Switch exposure delay compensation on or off. Switching on is refused (400, nothing
        changed) when the exposure in the registers cannot be centred on a channel."""
        self.device.require(Request.WHEEL_SET)
        if on:
            timing = self.sensor.timing()
            info = self._exposure_now(
                timing, compensated=True, speed_deg_s=self.profile.speed_deg_s.value
            )
            if not info.fits:
                raise BadRequest(
                    f"delay compensation not switched on (exposure {info.exposure_lines} lines "
                    f"= {info.exposure_s * 1e3:.6g} ms, window {info.window_rows} rows): "
                    f"{info.refusal}"
                )
        wheel = self.wheel
        before = wheel.read().compensation
        with Apply("delay compensation switch", self._events, source="wheel") as apply:
            apply.step(
                lambda: wheel.set_compensation(on),
                lambda: wheel.set_compensation(before),
                f"delay compensation {'on' if before else 'off'}",
            )
            apply.done()
        self.device.log_event(
            "info", "wheel", f"exposure delay compensation {'on' if on else 'off'}"
        )
        return self.status()

    def acquire(self, request: WheelAcquireRequest) -> WheelAcquireResponse:
        """One frame through each channel per pass, each timed by its entry pulse (and the
        delay); per frame its imaging-centre angle, uncertainty and mean signal.

        Checked before anything is written: the channels, a wheel that turns, the exposure
        (``exposure_s``, or the registers') against the light window with the compensation
        asked for (or the wheel's), the region and the recording path. The exposure and
        compensation it sets stay set after it; a run that fails puts them back.
        """
        if request.record is not None:
            # Resolved and confined first: everything after names the file it will write.
            record = self.stream.allowed_record(request.record)
            request = request.model_copy(update={"record": str(record)})
        slot = self.device.acquisition
        what = f"channels {','.join(map(str, request.channels))} x {request.passes}"
        acquisition = slot.claim(
            "wheel", what + (f" to {request.record}" if request.record else "")
        )
        try:
            with slot.applying(acquisition):
                return self._acquire(request)
        except BaseException:
            slot.abandon(acquisition)
            raise
        finally:
            slot.release(acquisition)

    def _acquire(self, request: WheelAcquireRequest) -> WheelAcquireResponse:
        # The camera first, before the exposure registers or the compensation are changed.
        self.stream.preflight("take wheel frames")
        profile = self.profile
        channels = self._check_channels(request.channels)
        reading: WheelReading = self.wheel.read()
        speed = reading.speed_deg_s
        if speed <= 0.0:
            raise BadRequest(
                "the filter wheel is stopped, so no entry pulse will come: start it first "
                f"(`camctl wheel speed {profile.speed_deg_s.value:g}`)"
            )
        device_compensated = reading.compensation
        compensated = device_compensated if request.compensated is None else request.compensated
        timing = self.sensor.timing()
        lines = timing.exposure_lines
        if request.exposure_s is not None:
            lines = self._exposure_lines(request.exposure_s, timing.line_period_s)
        planned = self.exposure_info(
            lines,
            timing.window_rows,
            timing.line_period_s,
            compensated=compensated,
            speed_deg_s=speed,
            exposure_s=lines * timing.line_period_s
            if request.exposure_s is not None
            else timing.exposure_s,
        )
        if not planned.fits:
            raise BadRequest(
                f"wheel acquisition refused, nothing changed (exposure {lines} lines = "
                f"{planned.exposure_s * 1e3:.6g} ms, window {timing.window_rows} rows, "
                f"compensation {'on' if compensated else 'off'}): {planned.refusal}"
            )
        self._check_region(request.region, timing.window_rows, self.sensor.window_columns())
        self._check_record(request.record)

        with Apply("wheel acquisition", self._events, source="wheel") as apply:
            if lines != timing.exposure_lines:
                snapshot = self.sensor.snapshot()
                writes = self._exposure_writes(lines)
                changed = snapshot.changed(writes)
                apply.step(
                    lambda: self.sensor.write(writes),
                    lambda: self.sensor.restore(snapshot, changed),
                    "registers " + ", ".join(changed),
                )
                timing = self.sensor.timing()
            if compensated != device_compensated:
                apply.step(
                    lambda: self.wheel.set_compensation(compensated),
                    lambda: self.wheel.set_compensation(device_compensated),
                    f"delay compensation {'on' if device_compensated else 'off'}",
                )
            exposure = self._exposure_now(timing, compensated=compensated, speed_deg_s=speed)
            means = _FrameMeans(request.region)
            start = StreamStart(
                command="WHEEL_ACQUIRE",
                fields={"passes": request.passes, "channels": bytes(channels)},
                # A frame waits at most a revolution for its channel's entry pulse.
                frame_period_s=360.0 / speed + exposure.frame_time_s,
                metadata={
                    "wheel": profile.wheel,
                    "channels": channels,
                    "passes": request.passes,
                    "compensation": "on" if compensated else "off",
                    "speed_deg_s": speed,
                    "frame_time_s": exposure.frame_time_s,
                    "delay_s": exposure.applied_delay_s,
                    "stage_position_unit": "wheel angle at the exposure start, 1e-4 deg",
                },
            )
            stream = self.stream.acquire(
                StreamStartRequest(
                    frames=len(channels) * request.passes,
                    record=request.record,
                    timeout_s=request.timeout_s,
                ),
                start=start,
                consumer=means,
            )
            apply.done()
        device_after = self._device_numbers()
        frames = [
            self._frame(seen, stream.first_counter, channels, exposure, speed)
            for seen in means.frames()
        ]
        self.device.log_event(
            "info",
            "wheel",
            f"wheel acquisition: {len(frames)} of {stream.frames_requested} frames through "
            f"channels {','.join(map(str, channels))} x {request.passes}, compensation "
            f"{'on' if compensated else 'off'}, T_frame {exposure.frame_time_s * 1e3:.6g} ms, "
            f"delay {(exposure.applied_delay_s or 0.0) * 1e3:.6g} ms",
        )
        return WheelAcquireResponse(
            channels=channels,
            passes=request.passes,
            speed_deg_s=speed,
            exposure=exposure,
            device_frame_time_s=device_after.get("frame_time_s"),
            device_delay_s=device_after.get("delay_s"),
            region=request.region,
            frames=frames,
            stream=stream,
        )

    # -- the computation (docs/physics.md §4) ---------------------------------------------------------------

    def _exposure_now(
        self, timing: TimingResponse, *, compensated: bool, speed_deg_s: float
    ) -> WheelExposureInfo:
        """``exposure_info`` for the exposure the registers set now."""
        return self.exposure_info(
            timing.exposure_lines,
            timing.window_rows,
            timing.line_period_s,
            compensated=compensated,
            speed_deg_s=speed_deg_s,
            exposure_s=timing.exposure_s,
        )

    def exposure_info(
        self,
        exposure_lines: int,
        window_rows: int,
        line_period_s: float,
        *,
        compensated: bool,
        speed_deg_s: float,
        exposure_s: float,
    ) -> WheelExposureInfo:
        """T_frame (eq 6), T_delay (eq 5), the fit, the imaging-centre offset and its error.

        The offset is eq 4 with the wheel's actual speed: the entry point is a mark on the
        wheel, ``w0 T_center`` before the centre (``w0`` the file's speed), so at another speed
        a compensated frame lands ``(w - w0) T_center`` off the centre (docs/wheel.md). A
        stopped wheel is computed at the file's speed (where it will be once started).
        """
        profile = self.profile
        frame = sequencer_frame_time_s(exposure_lines, window_rows, line_period_s)
        delay = exposure_delay_s(profile.t_center_s.value, frame)
        speed = speed_deg_s if speed_deg_s > 0 else profile.speed_deg_s.value
        common: dict[str, Any] = {
            "exposure_s": exposure_s,
            "exposure_lines": exposure_lines,
            "window_rows": window_rows,
            "line_period_s": line_period_s,
            "frame_time_s": frame,
            "delay_s": delay,
            "compensated": compensated,
        }
        try:
            fitted = profile.exposure(frame, compensated=compensated)
        except ValueError as exc:
            return WheelExposureInfo(
                **common,
                fits=False,
                refusal=str(exc),
                applied_delay_s=None,
                centre_offset_deg=None,
                centre_error_deg=None,
            )
        offset = imaging_centre_angle_deg(-profile.entry_lead_deg, speed, fitted.delay_s, frame)
        return WheelExposureInfo(
            **common,
            fits=True,
            refusal=None,
            applied_delay_s=fitted.delay_s,
            centre_offset_deg=offset,
            centre_error_deg=fitted.centre_error_deg,
        )

    # -- helpers ------------------------------------------------------------------------------------------

    def _channels_info(self) -> list[WheelChannelInfo]:
        profile = self.profile
        return [
            WheelChannelInfo(
                channel=i,
                name=c.name,
                band=c.band.value,
                centre_deg=profile.centre_deg(i),
                polarizer_deg=None if c.polarizer_deg is None else c.polarizer_deg.value,
            )
            for i, c in enumerate(profile.channels)
        ]

    def _check_channels(self, channels: list[int]) -> list[int]:
        count = self.profile.channel_count.value
        if not 1 <= len(channels) <= count:
            raise BadRequest(f"give 1 to {count} channels, got {len(channels)}")
        for channel in channels:
            try:
                self.profile.check_channel(channel)
            except ValueError as exc:
                raise BadRequest(f"{exc}; choose channels from 0 to {count - 1}") from None
        return list(channels)

    def _exposure_lines(self, exposure_s: float, line_period_s: float) -> int:
        """Whole lines ``round(T_exp / T_line)`` (docs/physics.md §3: T_exp = n T_line)."""
        lines = round(exposure_s / line_period_s)
        if lines < 1:
            raise BadRequest(
                f"exposure {exposure_s * 1e3:.6g} ms is less than half a line "
                f"({line_period_s * 1e6:.4g} us): give at least one line"
            )
        return lines

    def _exposure_writes(self, lines: int) -> dict[str, int | str]:
        """The register write that sets ``lines`` exposure lines (the map's role, its bias)."""
        regmap = self.sensor.regmap
        name = regmap.role("exposure_lines")
        if name is None:
            raise BadRequest(
                f"sensor {regmap.sensor} has no exposure register (role exposure_lines); "
                "leave exposure_s out and set the exposure another way"
            )
        _, spec = regmap.resolve(name)
        return {name: lines - (spec.bias if spec is not None else 0)}

    @staticmethod
    def _check_region(region: WheelRegion | None, rows: int, cols: int) -> None:
        if region is None:
            return
        if region.row + region.rows > rows or region.col + region.cols > cols:
            raise BadRequest(
                f"region rows {region.row}..{region.row + region.rows - 1}, columns "
                f"{region.col}..{region.col + region.cols - 1} does not fit the {rows} x {cols} "
                "frame; make it smaller"
            )

    @staticmethod
    def _check_record(record: str | None) -> None:
        # The stream service checks this too, but only after the exposure has been written.
        # ``acquire`` has resolved and confined the path already.
        if record is None:
            return
        try:
            check_new_file(Path(record))
        except RecordingError as exc:
            raise BadRequest(str(exc)) from None

    def _events(self, level: str, source: str, message: str) -> None:
        self.device.log_event(level, source, message)

    def _device_numbers(self) -> dict[str, float]:
        """The FPGA's T_frame and applied delay (WHEEL_GET), to show beside camd's."""
        try:
            reading = self.wheel.read()
        except SessionError:
            return {}
        delay = reading.delay_s if reading.compensation else 0.0
        return {"frame_time_s": reading.frame_time_s, "delay_s": delay}

    def _frame(
        self,
        seen: _Seen,
        first_counter: int,
        channels: list[int],
        exposure: WheelExposureInfo,
        speed_deg_s: float,
    ) -> WheelFrame:
        profile = self.profile
        index = (seen.counter - first_counter) % _COUNTER_WRAP
        channel = channels[index % len(channels)]
        offset = exposure.centre_offset_deg or 0.0
        start_angle = seen.stage_position * ANGLE_UNIT_DEG
        return WheelFrame(
            counter=seen.counter,
            channel=channel,
            name=profile.channels[channel].name,
            start_angle_deg=start_angle,
            centre_deg=(profile.centre_deg(channel) + offset) % 360.0,
            centre_offset_deg=offset,
            centre_error_deg=exposure.centre_error_deg or 0.0,
            header_centre_deg=(start_angle + speed_deg_s * exposure.frame_time_s / 2.0) % 360.0,
            mean=seen.mean,
            timestamp_s=seen.timestamp_ns * 1e-9,
        )
