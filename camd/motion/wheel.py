"""The filter wheel as the daemon drives it: a small abstract interface and its RS-422 device.

``FilterWheel`` speaks degrees, degrees per second and seconds; its public methods check their
arguments and then call the ``_do_*`` hooks an implementation provides. ``FpgaWheel``
implements them with the WHEEL_* commands of config/protocol.toml (the simulated camera
answers the same commands, so tests run the code the bench runs). A wheel acquisition is not
here: it is a stream (WHEEL_ACQUIRE), started by the stream service.
"""

from __future__ import annotations

import abc
import math
from dataclasses import dataclass

from camd.motion.stage import Request
from camd.motion.wheel_profile import WheelProfile
from camd.protocol.dictionary import f32_decimal

MAX_SPEED_DEG_S = 360.0
MIN_SPEED_DEG_S = 1e-6  # a turn in 11.4 years; slower is 0 for the device (f32 period)
"""The fastest speed WHEEL_SET_SPEED accepts (one revolution a second)."""


class WheelSpeedError(ValueError):
    """A speed the wheel cannot turn at; the message gives the valid range."""


@dataclass(frozen=True, slots=True)
class WheelReading:
    """The wheel at one device time."""

    speed_deg_s: float
    angle_deg: float  # from channel 0's centre, 0 .. 360
    channel: int | None  # whose light window is in front of the sensor; None between windows
    compensation: bool  # exposure delay compensation on
    frame_time_s: float  # the device's T_frame for the registers now
    delay_s: float  # the device's T_delay (negative: the exposure cannot be centred)
    time_s: float  # device time of the sample


class FilterWheel(abc.ABC):
    """A filter wheel turning at a constant speed, with exposure delay compensation."""

    @staticmethod
    def check_speed(speed_deg_s: float) -> None:
        """Raise WheelSpeedError, with the valid range, for a speed the wheel cannot turn at."""
        if not math.isfinite(speed_deg_s) or not 0.0 <= speed_deg_s <= MAX_SPEED_DEG_S:
            raise WheelSpeedError(
                f"wheel speed {speed_deg_s!r} deg/s is outside 0 .. {MAX_SPEED_DEG_S:g} deg/s "
                "(0 stops the wheel)"
            )
        if 0.0 < speed_deg_s < MIN_SPEED_DEG_S:  # its period would not fit WHEEL_SET_SPEED
            raise WheelSpeedError(
                f"wheel speed {speed_deg_s!r} deg/s is too slow to turn at: use 0 (stop) or "
                f"{MIN_SPEED_DEG_S:g} .. {MAX_SPEED_DEG_S:g} deg/s"
            )

    def set_speed(self, speed_deg_s: float) -> None:
        """Turn at ``speed_deg_s`` (0 stops the wheel)."""
        self.check_speed(speed_deg_s)
        self._do_set_speed(speed_deg_s)

    def stop(self) -> None:
        """Stop turning (the emergency stop uses this: no check can refuse it)."""
        self._do_set_speed(0.0)

    def set_compensation(self, on: bool) -> None:
        """Switch exposure delay compensation on or off (the device refuses to switch it on
        when the exposure in the registers cannot be centred on a channel)."""
        self._do_set_compensation(on)

    def read(self) -> WheelReading:
        """Speed, angle, channel, compensation and the device's exposure timing now."""
        return self._do_read()

    @abc.abstractmethod
    def _do_set_speed(self, speed_deg_s: float) -> None: ...

    @abc.abstractmethod
    def _do_set_compensation(self, on: bool) -> None: ...

    @abc.abstractmethod
    def _do_read(self) -> WheelReading: ...


class FpgaWheel(FilterWheel):
    """The wheel behind the camera FPGA's WHEEL_* commands (``request`` sends one)."""

    def __init__(self, profile: WheelProfile, request: Request) -> None:
        self.profile = profile
        self._request = request

    def _do_set_speed(self, speed_deg_s: float) -> None:
        self._request("WHEEL_SET_SPEED", speed_deg_s=speed_deg_s)

    def _do_set_compensation(self, on: bool) -> None:
        self._request("WHEEL_COMPENSATION", enable="on" if on else "off")

    def _do_read(self) -> WheelReading:
        r = self._request("WHEEL_GET")
        channel = int(r["channel"])  # 255 between windows
        return WheelReading(
            speed_deg_s=f32_decimal(float(r["speed_deg_s"])),
            angle_deg=float(r["angle_deg"]),
            channel=channel if channel < self.profile.channel_count.value else None,
            compensation=r["compensation"] == "on",
            frame_time_s=float(r["frame_time_s"]),
            delay_s=float(r["delay_s"]),
            time_s=float(r["time_s"]),
        )
