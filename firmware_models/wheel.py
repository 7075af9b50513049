"""The simulated filter wheel: angle, channel windows, entry pulses and polariser transmission.

docs/physics.md §4 [YE23 §3.1, §3.3, §4]. The wheel of ``config/wheel.toml``
(``camd.motion.wheel_profile``) turns at a constant speed, changed only by ``set_speed``
(the angle stays continuous). Sans-clock: every method takes the device time ``t_s`` (seconds);
the model keeps the speed history, so any time can be asked about, before or after a change.

Geometry. The wheel angle is measured from channel 0's centre and grows as the wheel turns;
channel ``i`` is centred at ``profile.centre_deg(i)``. The entry point and the light window are
marks on the wheel: the entry pulse comes when the angle crosses ``centre - w0 T_center`` and a
channel lets light through while the angle is within ``w0 window / 2`` of its centre, ``w0``
the profile's speed. At that speed (the default, 73.245 deg/s) the pulse comes ``T_center``
(60 ms) before the centre crossing and the window lasts ``window`` (120 ms) centred on it; at
another speed the times scale by ``w0 / w`` (so the delay the FPGA computes from ``T_center``
misplaces the frame by ``(w - w0) T_center``: the ``T_center dw`` term of eq 8).

Polarisers. A polarising channel's transmission axis is ``polarizer_deg`` when it is centred
and turns with the wheel: ``polarizer_deg + (angle - centre)``. The reference polariser's axis
and the channel's are measured in the same sense (assumed). Light from a reference polariser
at ``reference_deg`` passes with Malus's law ``cos^2(reference - azimuth)``; unpolarised light
(no reference) passes half; a channel without a polariser passes all of either.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, overload

import numpy as np
import numpy.typing as npt

from camd.motion.wheel_profile import WheelProfile, load_wheel_profile

FloatArray = npt.NDArray[np.float64]

CROSSING_TOLERANCE_DEG = 1e-9
"""An angle this close past a mark counts as on it (float rounding of an earlier crossing)."""


@dataclass(frozen=True, slots=True)
class _Segment:
    """Constant speed from ``t_s`` on: ``angle(t) = angle_deg + speed_deg_s (t - t_s)``."""

    t_s: float
    angle_deg: float
    speed_deg_s: float


def _wrap180(angle_deg: Any) -> Any:
    """Angle difference folded into [-180, 180)."""
    return np.mod(np.asarray(angle_deg, dtype=np.float64) + 180.0, 360.0) - 180.0


def _finite(name: str, value: float) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ValueError(f"{name} must be a finite number, got {value!r}")
    return float(value)


class FilterWheel:
    """A filter wheel turning at piecewise-constant speed (docs/physics.md §4; see the module doc)."""

    def __init__(
        self,
        profile: WheelProfile | None = None,
        *,
        t_s: float = 0.0,
        angle_deg: float = 0.0,
        speed_deg_s: float | None = None,
    ) -> None:
        """The wheel at ``angle_deg`` at time ``t_s``, turning at ``speed_deg_s``.

        Defaults: the shipped profile, angle 0 (channel 0 centred) at t = 0, the profile's
        speed. The same speed holds before ``t_s``.
        """
        self.profile = load_wheel_profile() if profile is None else profile
        speed = self.profile.speed_deg_s.value if speed_deg_s is None else speed_deg_s
        self._segments: list[_Segment] = [
            _Segment(
                _finite("t_s", t_s),
                _finite("angle_deg", angle_deg) % 360.0,
                self._checked_speed(speed),
            )
        ]

    # -- speed and angle --------------------------------------------------------------------------

    @staticmethod
    def _checked_speed(speed_deg_s: float) -> float:
        speed = _finite("speed_deg_s", speed_deg_s)
        if speed < 0.0:
            raise ValueError(
                f"speed_deg_s must be >= 0 (the wheel turns one way; 0 stops it), got {speed:g}"
            )
        return speed

    def set_speed(self, speed_deg_s: float, t_s: float) -> None:
        """Turn at ``speed_deg_s`` from ``t_s`` on (0 stops the wheel); the angle is continuous.

        ``t_s`` must not precede the last speed change: device time only moves forward.
        """
        speed = self._checked_speed(speed_deg_s)
        t = _finite("t_s", t_s)
        last = self._segments[-1]
        if t < last.t_s:
            raise ValueError(
                f"set_speed at t = {t:.9g} s is before the last speed change at "
                f"{last.t_s:.9g} s; device time only moves forward"
            )
        if t == last.t_s:
            self._segments[-1] = _Segment(last.t_s, last.angle_deg, speed)
            return
        angle = (last.angle_deg + last.speed_deg_s * (t - last.t_s)) % 360.0
        self._segments.append(_Segment(t, angle, speed))

    def speed_deg_s(self, t_s: float) -> float:
        """The angular speed at ``t_s``."""
        return self._segments[self._index(_finite("t_s", t_s))].speed_deg_s

    def _index(self, t_s: float) -> int:
        starts = [segment.t_s for segment in self._segments]
        return max(int(np.searchsorted(starts, t_s, side="right")) - 1, 0)

    def _unwrapped(self, t_s: FloatArray) -> FloatArray:
        """Angle continuous within each speed segment (not reduced to [0, 360))."""
        starts = np.array([s.t_s for s in self._segments])
        index = np.maximum(np.searchsorted(starts, t_s, side="right") - 1, 0)
        angle0 = np.array([s.angle_deg for s in self._segments])[index]
        speed = np.array([s.speed_deg_s for s in self._segments])[index]
        result: FloatArray = angle0 + speed * (t_s - starts[index])
        return result

    @overload
    def angle_deg(self, t_s: float) -> float: ...

    @overload
    def angle_deg(self, t_s: npt.ArrayLike) -> FloatArray: ...

    def angle_deg(self, t_s: npt.ArrayLike) -> float | FloatArray:
        """Wheel angle from channel 0's centre at each time, 0 <= deg < 360."""
        times = np.asarray(t_s, dtype=np.float64)
        if not np.isfinite(times).all():
            raise ValueError("t_s must be finite")
        reduced = np.mod(self._unwrapped(times), 360.0)
        angle: FloatArray = np.where(reduced >= 360.0, 0.0, reduced)  # -tiny % 360 gives 360.0
        return float(angle) if angle.ndim == 0 else angle

    def channel_at(self, t_s: float) -> int | None:
        """The channel whose light window the sensor looks through at ``t_s``; None between."""
        angle = self.angle_deg(_finite("t_s", t_s))
        spacing = self.profile.spacing_deg
        nearest = round(angle / spacing) % self.profile.channel_count.value
        offset = float(_wrap180(angle - self.profile.centre_deg(nearest)))
        return nearest if abs(offset) <= self.profile.window_half_angle_deg else None

    # -- marks: entry pulses and centre crossings ----------------------------------------------------

    def _next_crossing_s(self, mark_deg: float, after_s: float, what: str) -> float:
        start = self._index(after_s)
        for i in range(start, len(self._segments)):
            segment = self._segments[i]
            t_from = after_s if i == start else segment.t_s
            t_to = self._segments[i + 1].t_s if i + 1 < len(self._segments) else math.inf
            if segment.speed_deg_s == 0.0:
                continue
            angle = segment.angle_deg + segment.speed_deg_s * (t_from - segment.t_s)
            ahead = (mark_deg - angle) % 360.0
            if ahead > 360.0 - CROSSING_TOLERANCE_DEG:
                ahead = 0.0
            t = t_from + ahead / segment.speed_deg_s
            if t < t_to:
                return t
        stopped = self._segments[-1].t_s
        raise ValueError(
            f"the wheel is stopped (speed 0 since t = {stopped:.9g} s): {what} never comes; "
            "set a speed first"
        )

    def next_entry_s(self, channel: int, after_s: float) -> float:
        """Time of ``channel``'s next entry pulse at or after ``after_s``.

        The pulse marks the angle ``centre - w0 T_center``: at the profile's speed ``T_center``
        (60 ms) before the centre crossing. Raises ValueError if the wheel is (or comes to be)
        stopped before it gets there.
        """
        mark = self.profile.centre_deg(channel) - self.profile.entry_lead_deg
        return self._next_crossing_s(
            mark, _finite("after_s", after_s), f"channel {channel}'s entry pulse"
        )

    def next_centre_s(self, channel: int, after_s: float) -> float:
        """Time at or after ``after_s`` at which ``channel``'s centre is in front of the sensor."""
        return self._next_crossing_s(
            self.profile.centre_deg(channel),
            _finite("after_s", after_s),
            f"channel {channel}'s centre",
        )

    def exposure_schedule(
        self, channel: int, after_s: float, frame_time_s: float, compensated: bool
    ) -> float:
        """Start time of a frame through ``channel``: its next entry pulse plus the delay.

        docs/physics.md §4 eq 5 via ``camd.timing.wheel.wheel_exposure``: the delay is
        ``T_center - T_frame / 2`` with compensation, 0 without. A frame that does not fit the
        light window is refused with the ValueError of ``check_wheel_exposure``.
        """
        exposure = self.profile.exposure(frame_time_s, compensated=compensated)
        return self.next_entry_s(channel, after_s) + exposure.delay_s

    # -- polarisers and transmission -------------------------------------------------------------------

    @overload
    def polarizer_azimuth_deg(self, channel: int, t_s: float) -> float: ...

    @overload
    def polarizer_azimuth_deg(self, channel: int, t_s: npt.ArrayLike) -> FloatArray: ...

    def polarizer_azimuth_deg(self, channel: int, t_s: npt.ArrayLike) -> float | FloatArray:
        """Transmission axis of ``channel``'s polariser: ``polarizer_deg + (angle - centre)``.

        The wheel angle from the centre is folded into [-180, 180), so the axis is continuous
        while the channel passes the sensor. ValueError for a channel without a polariser.
        """
        polarizer = self._polarizer_deg(channel)
        if polarizer is None:
            name = self.profile.channels[channel].name
            raise ValueError(
                f"channel {channel} ({name}) has no polariser; polarising channels: "
                f"{', '.join(str(c) for c in self.profile.polarizing_channels)}"
            )
        angle = self.angle_deg(t_s)
        result: FloatArray = polarizer + _wrap180(
            np.asarray(angle) - self.profile.centre_deg(channel)
        )
        return float(result) if result.ndim == 0 else result

    def _polarizer_deg(self, channel: int) -> float | None:
        entry = self.profile.channels[self.profile.check_channel(channel)].polarizer_deg
        return None if entry is None else float(entry.value)

    def row_transmission(
        self,
        channel: int,
        start_s: npt.ArrayLike,
        end_s: npt.ArrayLike,
        reference_deg: float | None,
    ) -> FloatArray:
        """Mean transmission of ``channel`` over each row's exposure ``[start_s, end_s]``.

        Per row (arrays broadcast): the time average over the exposure of the light the channel
        passes: ``cos^2(reference_deg - azimuth(t))`` through a polarising channel (Malus),
        0.5 with ``reference_deg`` None (unpolarised light), 1 through a channel without a
        polariser, and 0 whenever the wheel angle is outside the channel's light window
        (vignetting). The exposure is clipped exactly to the window and to each speed segment;
        on a piece where the wheel sweeps ``D`` radians and the reference-to-axis angle is ``u``
        at the middle, the mean of ``cos^2`` is ``(1 + cos(2 u) sin(D) / D) / 2`` (the time
        integral of ``cos^2`` of a linearly turning angle; ``D`` = 0 gives ``cos^2 u``). A row
        with ``start_s == end_s`` gets the instantaneous transmission.
        """
        polarizer = self._polarizer_deg(channel)
        start, end = np.broadcast_arrays(
            np.asarray(start_s, dtype=np.float64), np.asarray(end_s, dtype=np.float64)
        )
        if not (np.isfinite(start).all() and np.isfinite(end).all()):
            raise ValueError("start_s and end_s must be finite")
        if (end < start).any():
            row = int(np.flatnonzero(end < start)[0])
            raise ValueError(
                f"each row's exposure must end at or after its start; row {row} starts at "
                f"{float(start.flat[row]):.9g} s and ends at {float(end.flat[row]):.9g} s"
            )
        if reference_deg is not None:
            reference_deg = _finite("reference_deg", reference_deg)
        centre = self.profile.centre_deg(channel)
        half = self.profile.window_half_angle_deg

        def mean_over(angle_mid: FloatArray, sweep_deg: FloatArray) -> FloatArray:
            """Mean transmission inside the window over a sweep centred on ``angle_mid``."""
            if polarizer is None:
                return np.ones_like(angle_mid)
            if reference_deg is None:
                return np.full_like(angle_mid, 0.5)
            u = np.deg2rad(reference_deg - polarizer - (angle_mid - centre))
            sweep = np.deg2rad(sweep_deg)
            mean: FloatArray = 0.5 * (1.0 + np.cos(2.0 * u) * np.sinc(sweep / np.pi))
            return mean

        start_flat, end_flat = start.reshape(-1), end.reshape(-1)
        integral = np.zeros(start_flat.shape)
        for i, segment in enumerate(self._segments):
            lo = start_flat if i == 0 else np.maximum(start_flat, segment.t_s)
            upper = self._segments[i + 1].t_s if i + 1 < len(self._segments) else math.inf
            hi = np.minimum(end_flat, upper)
            inside = hi > lo
            if not inside.any():
                continue
            w = segment.speed_deg_s
            if w == 0.0:
                parked = abs(float(_wrap180(segment.angle_deg - centre))) <= half
                if parked:
                    mid = np.full(lo.shape, segment.angle_deg)
                    gain = mean_over(mid, np.zeros(lo.shape))
                    integral += np.where(inside, (hi - lo) * gain, 0.0)
                continue
            angle_lo = segment.angle_deg + w * (lo - segment.t_s)
            angle_hi = segment.angle_deg + w * (hi - segment.t_s)
            # Windows [centre - half + 360 k, centre + half + 360 k] that meet [angle_lo, angle_hi].
            k_first = np.ceil((angle_lo - centre - half) / 360.0)
            k_last = np.floor((angle_hi - centre + half) / 360.0)
            passes = int(np.max(np.where(inside, k_last - k_first + 1, 0)))
            for j in range(passes):
                k = k_first + j
                window_lo = segment.t_s + (centre - half + 360.0 * k - segment.angle_deg) / w
                window_hi = segment.t_s + (centre + half + 360.0 * k - segment.angle_deg) / w
                t1 = np.maximum(lo, window_lo)
                t2 = np.minimum(hi, window_hi)
                piece = inside & (k <= k_last) & (t2 > t1)
                if not piece.any():
                    continue
                t1, t2 = t1[piece], t2[piece]
                mid = segment.angle_deg + w * (0.5 * (t1 + t2) - segment.t_s)
                integral[piece] += (t2 - t1) * mean_over(mid, w * (t2 - t1))
        duration = end_flat - start_flat
        result = np.divide(integral, duration, out=np.zeros_like(integral), where=duration > 0)
        instant = duration == 0
        if instant.any():
            times = start_flat[instant]
            angle = self._unwrapped(times)
            in_window = np.abs(_wrap180(angle - centre)) <= half
            result[instant] = np.where(in_window, mean_over(angle, np.zeros(times.shape)), 0.0)
        shaped: FloatArray = result.reshape(start.shape)
        return shaped
