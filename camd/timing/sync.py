"""Synchronous scan motion: the stage speed and step rate that match a TDI line period.

docs/physics.md §2 eqs 5-9 and 13 [TAO12] give the line period from the scan speed and the window
that fits it; §6 eq 9 [YUAN13] gives the synchronous speed for a line period and the stepper's
step rate from it. ``scan_speed`` is that speed for a line period, the speed the stage runs at
and their mismatch, written once for the scan planner (``camd.daemon.scan_plan``) and
``synchronous_motion``, which solves either way round (from a line period, or from a stage
speed) and reports the numbers ``camctl sync`` shows; ``line_mismatch`` measures the mismatch
each TDI line saw from the encoder counts the FPGA latches into the frame headers.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from camd.timing._checks import count, positive, real
from camd.timing.tdi import (
    synchronous_stage_speed_m_s,
    tdi_line_period_s,
    tdi_window,
    velocity_mismatch,
)

FloatArray = npt.NDArray[np.float64]


def step_rate_hz(stage_speed_m_s: float, metres_per_microstep: float) -> float:
    """Stepper step rate for a stage speed: ``F = V / (travel per microstep)``.

    docs/physics.md §6 [YUAN13 eq 9]: "the stepper's step rate follows from V_t and the travel per
    (micro)step". Signed: a negative speed gives a negative (reverse) rate.
    """
    speed = real("stage_speed_m_s", stage_speed_m_s)
    return speed / positive("metres_per_microstep", metres_per_microstep)


def turntable_angular_velocity_rad_s(
    pixel_size_m: float, tdi_line_period_s: float, radius_m: float
) -> float:
    """Turntable angular velocity for a TDI line period: eq 5 solved for w, ``w = a / (T l)``.

    docs/physics.md §2 eq 5 [TAO12]: pixel size ``a``, sensor at ``l = radius_m`` from the axis.
    """
    size = positive("pixel_size_m", pixel_size_m)
    period = positive("tdi_line_period_s", tdi_line_period_s)
    return size / (period * positive("radius_m", radius_m))


@dataclass(frozen=True, slots=True)
class ScanSpeed:
    """A scan's stage speeds for one TDI line period (``scan_speed``).

    ``sync_speed_m_s`` the synchronous stage speed ``p / (m T)``; ``speed_m_s`` the speed the
    stage runs at (a magnitude: the scan direction is the caller's); ``dv_over_v`` their
    mismatch ``(V - V_m) / V``.
    """

    sync_speed_m_s: float
    speed_m_s: float
    dv_over_v: float


def scan_speed(
    *,
    pixel_pitch_m: float,
    image_scale: float,
    line_period_s: float,
    stage_speed_m_s: float | None = None,
    dv_over_v: float = 0.0,
) -> ScanSpeed:
    """The stage speed for a TDI line period: docs/physics.md §6, "Synchronous drive" (eq 9) and
    "Velocity mismatch".

    The synchronous speed moves the image one pitch per line period, ``V = p / (m T)`` (§6 eq 9
    with ``n_mag = 1 / m``; §2's general eq 5 solved for the speed), ``m = image_scale`` the
    focal-plane metres per stage metre. The stage runs at ``stage_speed_m_s`` (its magnitude),
    or at ``V`` when that is None, times ``1 - dv_over_v``: a deliberate mismatch, 0 normally.
    The mismatch reported is ``dV/V = (V - V_m) / V`` of the speed it runs at. ``line_period_s``
    is the period the camera realises (whole clocks), not the one asked for.
    """
    period = positive("line_period_s", line_period_s)
    offset = real("dv_over_v", dv_over_v)
    if offset >= 1.0:
        raise ValueError(
            f"dv_over_v must be < 1 (at 1 or more the stage would stand or run backwards), "
            f"got {dv_over_v!r}"
        )
    sync = synchronous_stage_speed_m_s(pixel_pitch_m, period, image_scale)
    base = sync if stage_speed_m_s is None else abs(real("stage_speed_m_s", stage_speed_m_s))
    speed = base * (1.0 - offset)
    return ScanSpeed(sync_speed_m_s=sync, speed_m_s=speed, dv_over_v=velocity_mismatch(sync, speed))


@dataclass(frozen=True, slots=True)
class SyncSolution:
    """Open-loop synchronisation of a scan (the keys of ``camctl sync --json``).

    ``line_period_s`` TDI line period, ``row_time_s`` rolling line period (eq 4), ``n_lines``
    window rows (eq 8), ``back_path_s`` (eq 9), ``m0`` the largest stage count (eq 13),
    ``stages`` M, ``sync_speed`` the synchronous stage speed in m/s (§6 eq 9; for a turntable
    the arc speed at the sensor's radius), ``step_rate_hz`` the stepper rate for it, and the
    mismatch ``dv_over_v`` (§6) of the stage speed actually set, with ``m_dv_over_v`` =
    M dV/V (the smear in pixels over M stages; the tolerance is |M dV/V| < 2).
    """

    line_period_s: float
    row_time_s: float
    n_lines: int
    back_path_s: float
    m0: int
    stages: int
    sync_speed: float
    step_rate_hz: float
    dv_over_v: float
    m_dv_over_v: float

    def as_dict(self) -> dict[str, Any]:
        """The fields by name, in the contract's order."""
        return asdict(self)


def synchronous_motion(
    *,
    row_time_s: float,
    pixel_pitch_m: float,
    image_scale: float,
    metres_per_microstep: float,
    line_period_s: float | None = None,
    stage_speed_m_s: float | None = None,
    stages: int | None = None,
) -> SyncSolution:
    """Solve the synchronous motion from a line period or from a stage speed (docs/physics.md §2, §6).

    - ``line_period_s`` only: the stage speed ``V = p / (m T)`` (§6 eq 9, ``m = image_scale``,
      the focal-plane metres per stage metre) and its step rate; dV/V = 0.
    - ``stage_speed_m_s`` only: the line period ``T = p / (m V)`` (§2, general eq 5); dV/V = 0.
    - both: the stage runs at ``stage_speed_m_s`` against the line period; dV/V is their
      mismatch ``(V_sync - V) / V_sync``.

    The speeds and the mismatch are ``scan_speed``'s for the line period.

    The window follows from the line period (eqs 6-9, 13). ``stages`` defaults to M0; more
    stages than the window has rows are refused with the numbers.
    """
    if line_period_s is None and stage_speed_m_s is None:
        raise ValueError("give line_period_s or stage_speed_m_s (or both): nothing to solve from")
    pitch = positive("pixel_pitch_m", pixel_pitch_m)
    scale = positive("image_scale", image_scale)
    if line_period_s is None:
        assert stage_speed_m_s is not None
        period = tdi_line_period_s(pitch, scale * abs(real("stage_speed_m_s", stage_speed_m_s)))
    else:
        period = positive("line_period_s", line_period_s)
    window = tdi_window(period, row_time_s)
    m = window.max_stages if stages is None else count("stages", stages, 1)
    if m > window.max_stages:
        raise ValueError(
            f"stages = {m} do not fit: a line period of {period * 1e3:.6g} ms holds "
            f"{window.n_lines} rows of {row_time_s * 1e6:.6g} us (M0 = {window.max_stages}); "
            f"use at most {window.max_stages} stages or a longer line period (a slower scan)"
        )
    solved = scan_speed(
        pixel_pitch_m=pitch,
        image_scale=scale,
        line_period_s=period,
        stage_speed_m_s=stage_speed_m_s,
    )
    sync, mismatch = solved.sync_speed_m_s, solved.dv_over_v
    return SyncSolution(
        line_period_s=period,
        row_time_s=float(row_time_s),
        n_lines=window.n_lines,
        back_path_s=window.back_path_s,
        m0=window.max_stages,
        stages=m,
        sync_speed=sync,
        step_rate_hz=step_rate_hz(sync, metres_per_microstep),
        dv_over_v=mismatch,
        m_dv_over_v=m * mismatch,
    )


def line_mismatch(
    encoder_counts: npt.ArrayLike,
    frame_counters: npt.ArrayLike,
    *,
    stages: int,
    counts_per_pixel: float,
) -> FloatArray:
    """The smear of each TDI line in pixels, from the encoder count latched at each frame start.

    docs/physics.md §6 [YUAN13]: over n line periods the image should move n pitches; it moved
    ``d = |e_k - e_(k-n)| / counts_per_pixel`` pitches, so a line that integrated n periods is
    smeared by ``n - d = n dV/V`` pixels, dV/V being the mean mismatch over those periods. For a
    line with all M stages (n = M) this is M dV/V, the quantity whose tolerance is 2. A line
    early in a run, or after lost frames (gaps in ``frame_counters``), integrated fewer periods:
    n is the span from the earliest frame among the last M counters, and its smear is smaller.
    The first frame of a run has no earlier one: NaN. ``counts_per_pixel`` is encoder counts per
    image pitch of stage travel; the direction of travel does not matter.
    """
    encoder = np.asarray(encoder_counts, dtype=np.float64)
    counters = np.asarray(frame_counters, dtype=np.int64)
    if encoder.shape != counters.shape or encoder.ndim != 1:
        raise ValueError(
            f"encoder_counts {encoder.shape} and frame_counters {counters.shape} must be "
            "1-D arrays of the same length (one per frame)"
        )
    m = count("stages", stages, 1)
    per_pixel = positive("counts_per_pixel", counts_per_pixel)
    result = np.full(encoder.shape, np.nan)
    if encoder.size < 2:
        return result
    # For each frame, the earliest frame whose counter is within the last M periods.
    first = np.searchsorted(counters, counters - m, side="left")
    index = np.arange(encoder.size)
    spans = counters - counters[first]
    valid = spans > 0
    moved = np.abs(encoder[index[valid]] - encoder[first[valid]]) / per_pixel
    result[valid] = spans[valid] - moved
    return result
