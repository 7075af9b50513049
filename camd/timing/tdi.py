"""TDI line period from the scan, and the rolling-shutter window that fits it.

docs/physics.md §2 eqs 5-9 and 13 [TAO12]: each TDI line period holds one window frame of
``n_lines`` rows read at the row period, plus an idle "back path" that absorbs the remainder.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from camd.timing._checks import positive

EXACT_MULTIPLE_RTOL = 1e-9
"""Relative tolerance below which ``T_line,TDI / T_line,roll`` counts as a whole number.

Float division puts e.g. ``(3 * T_row) / T_row`` at 2.9999999999999996, and a plain floor would
then give 2 rows and a back path of a whole row period. A quotient within 1e-9 (relative) of an
integer is taken as that integer with a back path of exactly 0: the error is then below a
femtosecond for microsecond periods, far below any sequencer clock.
"""


def tdi_line_period_s(pixel_pitch_m: float, image_velocity_m_per_s: float) -> float:
    """TDI line period ``T_line,TDI = p / v_image``: the image moves one pitch per period.

    docs/physics.md §2 (general form of eq 5) [TAO12]. The velocity is the image speed on the focal
    plane; pass its magnitude (the scan direction does not change the period).
    """
    pitch = positive("pixel_pitch_m", pixel_pitch_m)
    velocity = positive("image_velocity_m_per_s", image_velocity_m_per_s)
    return pitch / velocity


def synchronous_stage_speed_m_s(
    pixel_pitch_m: float, tdi_line_period_s: float, magnification: float = 1.0
) -> float:
    """Stage speed that moves the image one pitch per TDI line period: ``p / (m T_line,TDI)``.

    docs/physics.md §2 (``T_line,TDI = p / v_image``, solved for ``v_image``) and §6 eq 9 [YUAN13]
    (``V_t = n_mag p / T_L`` on the object side, written here with ``v_image = m v_stage``, m the
    optics' image/object magnification). ``magnification`` 1 gives the image velocity itself.
    """
    pitch = positive("pixel_pitch_m", pixel_pitch_m)
    period = positive("tdi_line_period_s", tdi_line_period_s)
    return pitch / (positive("magnification", magnification) * period)


def velocity_mismatch(sync_speed_m_s: float, speed_m_s: float) -> float:
    """Velocity mismatch ``dV/V = (V - V_m) / V``: V the synchronous speed, V_m the actual one.

    docs/physics.md §6 [YUAN13]: positive when the image moves slower than one row per line period.
    Both speeds on the same side of the optics (stage or image); their sign is the direction.
    """
    sync = positive("sync_speed_m_s", sync_speed_m_s)
    return (sync - speed_m_s) / sync


def turntable_line_period_s(
    pixel_size_m: float, angular_velocity_rad_per_s: float, radius_m: float
) -> float:
    """TDI line period on a turntable ``T_line,TDI = a / (w * l)``.

    docs/physics.md §2 eq 5 [TAO12]: pixel size ``a``, angular velocity ``w``, sensor at distance
    ``l`` from the axis (drift angle 0, row-by-row accumulation).
    """
    size = positive("pixel_size_m", pixel_size_m)
    omega = positive("angular_velocity_rad_per_s", angular_velocity_rad_per_s)
    radius = positive("radius_m", radius_m)
    return size / (omega * radius)


@dataclass(frozen=True, slots=True)
class TdiWindow:
    """The rolling-shutter window that fits one TDI line period (docs/physics.md §2 eqs 6-9, 13).

    ``n_lines`` window rows (eq 8), ``back_path_s`` idle time at the end of each period (eq 9),
    ``max_stages`` = M0 = n_lines (eq 13), ``frame_time_s`` = n_lines * row period (eq 2).
    """

    n_lines: int
    back_path_s: float
    max_stages: int
    frame_time_s: float


def tdi_window(tdi_line_period_s: float, row_period_s: float) -> TdiWindow:
    """Window rows and back path for a TDI line period: eqs 6-9 and 13 of docs/physics.md §2 [TAO12].

    ``n_lines = floor(T_line,TDI / T_line,roll)`` (TAO12's rem(.) is floor) and
    ``T_back = T_line,TDI - n_lines * T_line,roll``, so ``0 <= T_back < T_line,roll``. A quotient
    within ``EXACT_MULTIPLE_RTOL`` of a whole number counts as that number with ``T_back = 0``.
    A TDI line period shorter than one row period leaves no room for a window and is refused.
    """
    tdi = positive("tdi_line_period_s", tdi_line_period_s)
    row = positive("row_period_s", row_period_s)
    quotient = tdi / row
    nearest = round(quotient)
    if nearest >= 1 and abs(quotient - nearest) <= EXACT_MULTIPLE_RTOL * quotient:
        n_lines, back = int(nearest), 0.0
    else:
        n_lines = math.floor(quotient)
        # Clamp: the subtraction can round a hair outside [0, row) although the floor is right.
        back = min(max(tdi - n_lines * row, 0.0), math.nextafter(row, 0.0))
    if n_lines < 1:
        raise ValueError(
            f"TDI line period {tdi:.6g} s is shorter than one row period {row:.6g} s: no window "
            "row fits; slow the scan (longer line period) or shorten the row period"
        )
    return TdiWindow(
        n_lines=n_lines, back_path_s=back, max_stages=n_lines, frame_time_s=n_lines * row
    )
