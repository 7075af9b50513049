"""Filter-wheel dynamic delay compensation: when to start an exposure through a turning wheel.

docs/physics.md §4 [YE23 §3.1, §3.3, §4, eqs 1, 4-8]. The wheel turns at constant ``w`` and sends an
entry-point pulse ``T_center`` before each channel's centre is in front of the sensor. A
rolling-shutter frame of ``T_frame = (n + k + 1) T_line`` (eq 6: ``camd.timing.sequencer_frame_time_s``,
not repeated here) started at the pulse is centred ``w T_frame / 2`` past the entry point (eq 1),
so its centre, and the azimuth of a polariser in the wheel, moves with the exposure. Waiting
``T_delay = T_center - T_frame / 2`` first (eq 5) puts the centre on the channel centre whatever the
exposure (eq 4), with the uncertainty of eq 8.

- eq 5: ``exposure_delay_s``; the fit checks: ``check_wheel_exposure``
- eqs 1 and 4: ``imaging_centre_angle_deg``
- eq 8: ``imaging_centre_error_deg``
- all of it for one exposure: ``wheel_exposure`` -> ``WheelExposure``

Angles in degrees, times in seconds, speeds in degrees per second.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from camd.timing._checks import non_negative, positive, real


def exposure_delay_s(t_center_s: float, frame_time_s: float) -> float:
    """Delay from the entry pulse to the exposure start ``T_delay = T_center - T_frame / 2``.

    docs/physics.md §4 eq 5 [YE23]. The value is returned even when negative (the exposure is then
    too long to be centred on the channel: ``check_wheel_exposure`` refuses it). E.g.
    ``T_center`` = 60 ms and ``T_frame`` = 70.97868 ms (HR400, n = 2924, k = 534) give
    24.51066 ms.
    """
    center = non_negative("t_center_s", t_center_s)
    frame = positive("frame_time_s", frame_time_s)
    return center - frame / 2.0


def check_wheel_exposure(
    frame_time_s: float, *, t_center_s: float, window_s: float, compensated: bool
) -> None:
    """Refuse a frame that cannot fit a channel's light window (docs/physics.md §4, after eq 6).

    ``T_frame > window``: part of the frame would be vignetted or the next entry pulse missed.
    With compensation, ``T_delay < 0`` (eq 5): the exposure would have to start before the
    entry pulse to be centred. Without compensation only the window applies (the frame starts
    at the pulse). The ``ValueError`` states the numbers and what to change.
    """
    frame = positive("frame_time_s", frame_time_s)
    window = positive("window_s", window_s)
    delay = exposure_delay_s(t_center_s, frame)
    if frame > window:
        raise ValueError(
            f"frame time T_frame = (n + k + 1) T_line = {frame * 1e3:.6g} ms exceeds the "
            f"channel's light window of {window * 1e3:.6g} ms (the image would be vignetted or "
            f"the next entry pulse missed): shorten the exposure or use fewer window rows, "
            f"by at least {(frame - window) * 1e3:.6g} ms of frame time"
        )
    if compensated and delay < 0.0:
        raise ValueError(
            f"exposure delay T_delay = T_center - T_frame / 2 = {t_center_s * 1e3:.6g} ms - "
            f"{frame * 1e3:.6g} ms / 2 = {delay * 1e3:.6g} ms is negative: the frame cannot be "
            f"centred on the channel; shorten the exposure or use fewer window rows (T_frame "
            f"<= 2 T_center = {2.0 * t_center_s * 1e3:.6g} ms), or switch compensation off"
        )


def imaging_centre_angle_deg(
    entry_angle_deg: float, speed_deg_s: float, delay_s: float, frame_time_s: float
) -> float:
    """Wheel angle at the frame's centre ``P_frame = P_entry + w T_delay + w T_frame / 2``.

    docs/physics.md §4 eq 4 [YE23]; with ``delay_s`` = 0 it is eq 1 (exposure started at the entry
    pulse), ``P_entry + w T_frame / 2``. ``delay_s`` is the delay actually waited after the
    pulse, so it must be >= 0; the angle is not wrapped to [0, 360).
    """
    entry = real("entry_angle_deg", entry_angle_deg)
    speed = real("speed_deg_s", speed_deg_s)
    delay = non_negative("delay_s", delay_s)
    frame = positive("frame_time_s", frame_time_s)
    return entry + speed * delay + speed * frame / 2.0


def imaging_centre_error_deg(
    entry_angle_error_deg: float,
    t_center_s: float,
    speed_error_deg_s: float,
    speed_deg_s: float,
    t_center_error_s: float,
) -> float:
    """Uncertainty of the imaging-centre angle ``sqrt(dP_entry^2 + (T_center dw)^2 + (w dT_center)^2)``.

    docs/physics.md §4 eq 8 [YE23]: after compensation the centre is ``P_entry + w T_center``, and
    the entry angle, the speed and the delay timing err independently. With the instrument's
    0.087 deg, 60 ms, 0.03 deg/s, 73.245 deg/s and 20e-6 x 60 ms = 1.2 us it is 0.08702 deg
    (the entry angle dominates). For a frame started at the pulse pass ``T_frame / 2`` as
    ``t_center_s`` (the time from the pulse to the frame's centre) and its clock error.
    """
    entry = non_negative("entry_angle_error_deg", entry_angle_error_deg)
    center = non_negative("t_center_s", t_center_s)
    speed_error = non_negative("speed_error_deg_s", speed_error_deg_s)
    speed = real("speed_deg_s", speed_deg_s)
    center_error = non_negative("t_center_error_s", t_center_error_s)
    return math.sqrt(entry**2 + (center * speed_error) ** 2 + (speed * center_error) ** 2)


@dataclass(frozen=True, slots=True)
class WheelExposure:
    """One frame through a channel of the wheel (docs/physics.md §4 eqs 1, 4, 5, 8).

    ``frame_time_s`` T_frame (eq 6); ``delay_s`` the delay waited after the entry pulse (eq 5's
    T_delay with compensation, 0 without); ``centre_offset_deg`` the wheel angle of the frame's
    centre from the channel centre (0 with compensation, ``w (T_frame / 2 - T_center)``
    without: eq 4 minus the centre); ``centre_error_deg`` its uncertainty (eq 8).
    """

    frame_time_s: float
    delay_s: float
    centre_offset_deg: float
    centre_error_deg: float


def wheel_exposure(
    frame_time_s: float,
    *,
    speed_deg_s: float,
    t_center_s: float,
    window_s: float,
    compensated: bool,
    entry_angle_error_deg: float,
    speed_error_deg_s: float,
    clock_stability: float,
) -> WheelExposure:
    """Check a frame against the light window and place its centre on the wheel (docs/physics.md §4).

    Refuses what ``check_wheel_exposure`` refuses. The delay is eq 5 (compensated) or 0; the
    centre is eq 4 with the entry point ``w T_center`` before the channel centre; its error is
    eq 8 with ``dT_center = clock_stability * T_center``. Without compensation the time from the
    pulse to the frame's centre is ``T_frame / 2`` instead of ``T_center``, and eq 8 is applied
    with that time (the same three independent errors; derived, not in YE23).
    """
    frame = positive("frame_time_s", frame_time_s)
    speed = real("speed_deg_s", speed_deg_s)
    center = non_negative("t_center_s", t_center_s)
    stability = non_negative("clock_stability", clock_stability)
    check_wheel_exposure(frame, t_center_s=center, window_s=window_s, compensated=compensated)
    delay = exposure_delay_s(center, frame) if compensated else 0.0
    entry_deg = -speed * center  # the channel centre is at 0
    offset = imaging_centre_angle_deg(entry_deg, speed, delay, frame)
    pulse_to_centre_s = delay + frame / 2.0
    error = imaging_centre_error_deg(
        entry_angle_error_deg,
        pulse_to_centre_s,
        speed_error_deg_s,
        speed,
        stability * pulse_to_centre_s,
    )
    return WheelExposure(
        frame_time_s=frame, delay_s=delay, centre_offset_deg=offset, centre_error_deg=error
    )
