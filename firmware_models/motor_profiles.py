"""The step generator's motion profiles (pure): ramps, trapezoidal moves, their durations.

A profile is a list of constant-acceleration segments (``firmware_models.stage.Segment``) in
microsteps, microsteps per second and microsteps per second squared, from a start time on; the
last segment (at rest, or at a constant rate) lasts for ever. The stepper controller
(``firmware_models.motor``) plans every MOTOR_* motion with these and hands the result to the
stage.
"""

from __future__ import annotations

import math

from firmware_models.stage import Segment


def ramp_profile(t_s: float, p: float, v: float, rate: float, accel: float) -> list[Segment]:
    """From (``p``, ``v``) at ``t_s``: ramp at ``accel`` to ``rate`` and hold it."""
    if rate == v:
        return [Segment(t_s, p, v, 0.0)]
    tau = abs(rate - v) / accel
    acc = math.copysign(accel, rate - v)
    return [Segment(t_s, p, v, acc), Segment(t_s + tau, p + 0.5 * (v + rate) * tau, rate, 0.0)]


def move_profile(
    t_s: float, p: float, v: float, target: float, vmax: float, accel: float
) -> list[Segment]:
    """From (``p``, ``v``) at ``t_s``: reach ``target`` at rest, cruising at most at ``vmax``.

    Trapezoidal (accelerate, cruise, brake) when there is room, triangular when short; a stage
    moving away from the target, or too fast to stop before it, brakes to rest first. The last
    segment is the rest at ``target``, exactly."""
    segs: list[Segment] = []
    d = target - p
    if v != 0.0 and (v * d <= 0.0 or v * v / (2.0 * accel) > abs(d) * (1.0 + 1e-9) + 1e-9):
        tau = abs(v) / accel
        segs.append(Segment(t_s, p, v, -math.copysign(accel, v)))
        p += 0.5 * v * tau
        t_s += tau
        v = 0.0
        d = target - p
    distance = abs(d)
    if distance <= 1e-9 and v == 0.0:
        segs.append(Segment(t_s, target, 0.0, 0.0))
        return segs
    s = math.copysign(1.0, d)
    u = abs(v)
    phases: list[tuple[float, float]] = []  # (duration, signed acceleration)
    if u > 0.0 and u * u / (2.0 * accel) >= distance * (1.0 - 1e-12):
        brake = u * u / (2.0 * distance)  # on the braking curve already (within rounding)
        phases.append((u / brake, -s * brake))
    elif u > vmax:
        cruise = distance - u * u / (2.0 * accel)
        phases += [
            ((u - vmax) / accel, -s * accel),
            (cruise / vmax, 0.0),
            (vmax / accel, -s * accel),
        ]
    else:
        peak = math.sqrt(accel * distance + 0.5 * u * u)
        if peak <= vmax:
            phases += [((peak - u) / accel, s * accel), (peak / accel, -s * accel)]
        else:
            cruise = distance - (vmax * vmax - u * u) / (2.0 * accel) - vmax * vmax / (2.0 * accel)
            phases += [
                ((vmax - u) / accel, s * accel),
                (cruise / vmax, 0.0),
                (vmax / accel, -s * accel),
            ]
    for duration, acc in phases:
        if duration <= 0.0:
            continue
        segs.append(Segment(t_s, p, v, acc))
        p += v * duration + 0.5 * acc * duration * duration
        v += acc * duration
        t_s += duration
    segs.append(Segment(t_s, target, 0.0, 0.0))
    return segs


def trapezoid_time_s(distance: float, vmax: float, accel: float) -> float:
    """Duration of a rest-to-rest move: ``d / v + v / a``, or ``2 sqrt(d / a)`` when short."""
    distance = abs(distance)
    if distance >= vmax * vmax / accel:
        return distance / vmax + vmax / accel
    return 2.0 * math.sqrt(distance / accel)


def rebase(segments: list[Segment], t_s: float) -> list[Segment]:
    """The part of a profile from ``t_s`` on, its first segment starting at ``t_s``."""
    j = 0
    while j + 1 < len(segments) and segments[j + 1].t0_s <= t_s:
        j += 1
    p, v = segments[j].at(t_s)
    return [Segment(t_s, p, v, segments[j].a), *segments[j + 1 :]]
