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

A wheel acquisition is planned whole before the camera is touched
(``camd.daemon.wheel_plan.plan_wheel``, pure: every refusal is raised there), then applied step
by step, each step with its undo (``camd.daemon.transaction.Apply``): the exposure registers,
the compensation, then a counted stream started by WHEEL_ACQUIRE instead of START_STREAM
(``StreamService.acquire(start=...)``: the same USB reader, recording and state machine,
idle -> streaming -> idle on STREAM_DONE). A failure on the way, the stream's included, puts
back what was changed and says so.
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from camd.daemon.device import DeviceAccess
from camd.daemon.errors import BadRequest, SessionError
from camd.daemon.models import (
    StreamResponse,
    StreamStartRequest,
    WheelAcquireRequest,
    WheelAcquireResponse,
    WheelChannelInfo,
    WheelExposureInfo,
    WheelFrame,
    WheelRegion,
    WheelStatus,
)
from camd.daemon.sensor_service import RegisterSnapshot, SensorService
from camd.daemon.state import Request
from camd.daemon.stream_service import StreamService, StreamStart
from camd.daemon.transaction import Apply, apply_one
from camd.daemon.wheel_plan import WheelContext, WheelPlan, exposure_now, plan_wheel
from camd.link.frame_stream import ReceivedFrame
from camd.motion.wheel import FilterWheel, FpgaWheel, WheelSpeedError
from camd.motion.wheel_profile import WheelProfile, load_wheel_profile
from camd.store.recording import RecordingError, check_new_file

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
            exposure=exposure_now(profile, timing, compensated=compensated, speed_deg_s=speed),
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
        apply_one(
            "wheel speed change",
            self._events,
            lambda: wheel.set_speed(speed_deg_s),
            lambda: wheel.set_speed(before),
            f"wheel speed {before:g} deg/s",
            source="wheel",
        )
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
            profile = self.profile
            info = exposure_now(
                profile, timing, compensated=True, speed_deg_s=profile.speed_deg_s.value
            )
            if not info.fits:
                raise BadRequest(
                    f"delay compensation not switched on (exposure {info.exposure_lines} lines "
                    f"= {info.exposure_s * 1e3:.6g} ms, window {info.window_rows} rows): "
                    f"{info.refusal}"
                )
        wheel = self.wheel
        before = wheel.read().compensation
        apply_one(
            "delay compensation switch",
            self._events,
            lambda: wheel.set_compensation(on),
            lambda: wheel.set_compensation(before),
            f"delay compensation {'on' if before else 'off'}",
            source="wheel",
        )
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
        plan, snapshot = self._plan(request)
        # The planner is pure; the file is checked here, still before anything is changed.
        self._check_record(request.record)
        stream, means = self._apply(plan, snapshot)
        device_after = self._device_numbers()
        exposure, speed, channels = plan.exposure, plan.speed_deg_s, plan.channels
        frames = [
            self._frame(seen, stream.first_counter, channels, exposure, speed)
            for seen in means.frames()
        ]
        self.device.log_event(
            "info",
            "wheel",
            f"wheel acquisition: {len(frames)} of {stream.frames_requested} frames through "
            f"channels {','.join(map(str, channels))} x {request.passes}, compensation "
            f"{'on' if plan.compensated else 'off'}, T_frame {exposure.frame_time_s * 1e3:.6g} "
            f"ms, delay {(exposure.applied_delay_s or 0.0) * 1e3:.6g} ms",
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

    def _plan(self, request: WheelAcquireRequest) -> tuple[WheelPlan, RegisterSnapshot]:
        """Read what the plan needs (the wheel, the registers), then plan: nothing is changed."""
        profile = self.profile
        reading = self.wheel.read()
        snapshot = self.sensor.snapshot()
        context = WheelContext(
            profile=profile,
            speed_deg_s=reading.speed_deg_s,
            compensated=reading.compensation,
            timing=snapshot.timing(),
            preview=snapshot.preview,
            regmap=self.sensor.regmap,
            columns=snapshot.columns(),
        )
        return plan_wheel(request, context), snapshot

    def _apply(
        self, plan: WheelPlan, snapshot: RegisterSnapshot
    ) -> tuple[StreamResponse, _FrameMeans]:
        """Change the camera as planned, step by step, and take the frames; on a failure the
        steps done so far are undone (newest first) and the error says what was restored. The
        exposure and compensation stay set after a run that succeeds."""
        request, sensor, wheel = plan.request, self.sensor, self.wheel
        with Apply("wheel acquisition", self._events, source="wheel") as apply:
            writes = plan.register_writes
            if writes:
                changed = snapshot.changed(writes)
                apply.step(
                    lambda: sensor.write(writes),
                    lambda: sensor.restore(snapshot, changed),
                    "registers " + ", ".join(changed),
                )
            if plan.compensated != plan.was_compensated:
                apply.step(
                    lambda: wheel.set_compensation(plan.compensated),
                    lambda: wheel.set_compensation(plan.was_compensated),
                    f"delay compensation {'on' if plan.was_compensated else 'off'}",
                )
            means = _FrameMeans(request.region)
            start = StreamStart(
                command="WHEEL_ACQUIRE",
                fields=plan.stream_fields,
                frame_period_s=plan.frame_period_s,
                metadata=plan.metadata,
            )
            stream = self.stream.acquire(
                StreamStartRequest(
                    frames=plan.frames, record=request.record, timeout_s=request.timeout_s
                ),
                start=start,
                consumer=means,
            )
            apply.done()
        return stream, means

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
