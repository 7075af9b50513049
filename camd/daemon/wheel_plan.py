"""A wheel acquisition, planned whole before the camera is touched.

``plan_wheel(request, context)`` is pure: from the request and a snapshot of the wheel and the
registers (``WheelContext``: the wheel file, the wheel's speed and compensation now, the
registers' timing, a preview of what register writes would set) it computes, once, everything a
wheel acquisition needs (docs/wheel.md, docs/physics.md §3-4):

- the channels, each checked against the wheel file, and a wheel that turns (no entry pulse
  comes from a stopped one);
- the exposure in whole lines ``round(T_exp / T_line)`` (§3) and the register write that sets
  it, or none when the registers' exposure is kept;
- the fit of that exposure's frame in a channel's light window with the compensation asked for
  (or the wheel's), refused with camd's numbers (§4: ``T_frame = (n + k + 1) T_line`` eq 6
  within the window, and ``T_delay = T_center - T_frame / 2`` >= 0 with compensation, eq 5);
- the frame after the writes: T_frame, the delay applied, the imaging-centre offset (eq 4; eq 1
  without compensation) and its uncertainty (eq 8) (``exposure_info``);
- the region whose mean each frame reports, checked against the frame;
- what starts the stream: WHEEL_ACQUIRE's fields, the longest a frame takes (a revolution for
  its entry pulse, then the frame) and the recording's metadata.

Anything that cannot work is refused here, with a ``BadRequest`` that says what to change, so
that a refused acquisition changes nothing. ``WheelService`` then applies the plan step by step
(registers, compensation, the stream) and puts back what it changed if a step fails
(``camd.daemon.transaction``), as scans do (``camd.daemon.scan_plan``).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

from camd.daemon.errors import BadRequest
from camd.daemon.models import (
    TimingResponse,
    WheelAcquireRequest,
    WheelExposureInfo,
    WheelRegion,
)
from camd.motion.wheel_profile import WheelProfile
from camd.sensor.regmap import RegisterMap
from camd.timing import sequencer_frame_time_s
from camd.timing.wheel import exposure_delay_s, imaging_centre_angle_deg

Preview = Callable[[Mapping[str, int | str]], TimingResponse]
"""The timing register writes would set (validated as a write would be); nothing is sent."""


@dataclass(frozen=True, slots=True)
class WheelContext:
    """What the planner needs to know of the wheel and the camera now (read before planning)."""

    profile: WheelProfile  # config/wheel.toml
    speed_deg_s: float  # WHEEL_GET's speed (0: stopped)
    compensated: bool  # WHEEL_GET's delay compensation
    timing: TimingResponse  # what the registers set now
    preview: Preview
    regmap: RegisterMap
    columns: int  # window columns


@dataclass(frozen=True, slots=True)
class WheelPlan:
    """Everything a wheel acquisition needs, computed once (module docstring)."""

    request: WheelAcquireRequest
    channels: list[int]
    frames: int  # one per channel per pass
    speed_deg_s: float
    compensated: bool  # during the acquisition (and after it)
    was_compensated: bool  # the wheel's before: put back if the acquisition fails
    register_writes: dict[str, int | str]  # the exposure's; empty when it is kept
    exposure: WheelExposureInfo  # the frame the registers set after the writes
    frame_period_s: float  # the longest a frame takes: a revolution, then the frame
    stream_fields: dict[str, Any]  # WHEEL_ACQUIRE's
    metadata: dict[str, Any]  # the recording's ``stream`` group


def plan_wheel(request: WheelAcquireRequest, context: WheelContext) -> WheelPlan:
    """The whole acquisition, or a BadRequest saying what to change (module docstring)."""
    profile = context.profile
    channels = check_channels(profile, request.channels)
    speed = context.speed_deg_s
    if speed <= 0.0:
        raise BadRequest(
            "the filter wheel is stopped, so no entry pulse will come: start it first "
            f"(`camctl wheel speed {profile.speed_deg_s.value:g}`)"
        )
    compensated = context.compensated if request.compensated is None else request.compensated
    now = context.timing
    lines = now.exposure_lines
    if request.exposure_s is not None:
        lines = exposure_lines(request.exposure_s, now.line_period_s)
    writes = exposure_writes(context.regmap, lines) if lines != now.exposure_lines else {}
    after = context.preview(writes) if writes else now
    # The fit is checked for the exposure asked for, in whole lines of the line period now.
    asked = exposure_info(
        profile,
        lines,
        now.window_rows,
        now.line_period_s,
        compensated=compensated,
        speed_deg_s=speed,
        exposure_s=lines * now.line_period_s if request.exposure_s is not None else now.exposure_s,
    )
    if not asked.fits:
        raise BadRequest(
            f"wheel acquisition refused, nothing changed (exposure {lines} lines = "
            f"{asked.exposure_s * 1e3:.6g} ms, window {now.window_rows} rows, "
            f"compensation {'on' if compensated else 'off'}): {asked.refusal}"
        )
    check_region(request.region, now.window_rows, context.columns)
    exposure = exposure_now(profile, after, compensated=compensated, speed_deg_s=speed)
    return WheelPlan(
        request=request,
        channels=channels,
        frames=len(channels) * request.passes,
        speed_deg_s=speed,
        compensated=compensated,
        was_compensated=context.compensated,
        register_writes=writes,
        exposure=exposure,
        # A frame waits at most a revolution for its channel's entry pulse.
        frame_period_s=360.0 / speed + exposure.frame_time_s,
        stream_fields={"passes": request.passes, "channels": bytes(channels)},
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


# -- the computation (docs/physics.md §4) ---------------------------------------------------------


def exposure_now(
    profile: WheelProfile, timing: TimingResponse, *, compensated: bool, speed_deg_s: float
) -> WheelExposureInfo:
    """``exposure_info`` for the exposure the registers ``timing`` describes set."""
    return exposure_info(
        profile,
        timing.exposure_lines,
        timing.window_rows,
        timing.line_period_s,
        compensated=compensated,
        speed_deg_s=speed_deg_s,
        exposure_s=timing.exposure_s,
    )


def exposure_info(
    profile: WheelProfile,
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


# -- the checks -----------------------------------------------------------------------------------


def check_channels(profile: WheelProfile, channels: list[int]) -> list[int]:
    """The channels, each one of the wheel's; BadRequest naming the range otherwise."""
    count = profile.channel_count.value
    if not 1 <= len(channels) <= count:
        raise BadRequest(f"give 1 to {count} channels, got {len(channels)}")
    for channel in channels:
        try:
            profile.check_channel(channel)
        except ValueError as exc:
            raise BadRequest(f"{exc}; choose channels from 0 to {count - 1}") from None
    return list(channels)


def exposure_lines(exposure_s: float, line_period_s: float) -> int:
    """Whole lines ``round(T_exp / T_line)`` (docs/physics.md §3: T_exp = n T_line)."""
    lines = round(exposure_s / line_period_s)
    if lines < 1:
        raise BadRequest(
            f"exposure {exposure_s * 1e3:.6g} ms is less than half a line "
            f"({line_period_s * 1e6:.4g} us): give at least one line"
        )
    return lines


def exposure_writes(regmap: RegisterMap, lines: int) -> dict[str, int | str]:
    """The register write that sets ``lines`` exposure lines (the map's role, its bias)."""
    name = regmap.role("exposure_lines")
    if name is None:
        raise BadRequest(
            f"sensor {regmap.sensor} has no exposure register (role exposure_lines); "
            "leave exposure_s out and set the exposure another way"
        )
    _, spec = regmap.resolve(name)
    return {name: lines - (spec.bias if spec is not None else 0)}


def check_region(region: WheelRegion | None, rows: int, cols: int) -> None:
    """A region that fits the ``rows`` x ``cols`` frame (or none)."""
    if region is None:
        return
    if region.row + region.rows > rows or region.col + region.cols > cols:
        raise BadRequest(
            f"region rows {region.row}..{region.row + region.rows - 1}, columns "
            f"{region.col}..{region.col + region.cols - 1} does not fit the {rows} x {cols} "
            "frame; make it smaller"
        )
