"""The pure wheel-acquisition planner (camd.daemon.wheel_plan), without a camera.

A plan is made against the hr400's real register map and register layer with the registers at
their reset values (534 window rows, 2 exposure lines); the preview sends nothing, so no bridge
is needed. Every expected number is worked out here from docs/physics.md §3-4 and the wheel file
(config/wheel.toml: w0 = 73.245 deg/s, T_center = 60 ms, a 120 ms light window, 13 channels):

    T_line = 513 / 25 MHz = 20.52 us, T_frame = (n + k + 1) T_line               §3, eq 6
    T_delay = T_center - T_frame / 2                                               §4 eq 5
    centre - channel centre = w (T_delay + T_frame / 2) - w0 T_center              §4 eqs 1, 4
    dP = sqrt(dP_entry^2 + (T dw)^2 + (w0 20e-6 T)^2), T pulse to frame centre     §4 eq 8

with k = 534, dP_entry = 0.087 deg, dw = 0.03 deg/s. 3 ms is n = round(3e-3 / T_line) = 146
lines; the longest frame the window takes is n + 535 <= 120 ms / 20.52 us = 5847.95, n = 5312.
"""

from __future__ import annotations

import math
from typing import Any

import pytest

from camd.daemon.errors import BadRequest
from camd.daemon.models import WheelAcquireRequest
from camd.daemon.sensor_service import RegisterSnapshot
from camd.daemon.wheel_plan import WheelContext, WheelPlan, plan_wheel
from camd.motion.wheel_profile import load_wheel_profile
from camd.sensor.registers import SensorRegisters
from camd.sensor.regmap import load_register_map

REGMAP = load_register_map("hr400")
PROFILE = load_wheel_profile()
T_LINE_S = 513 / 25e6
ROWS = 534  # the reset window
W0 = 73.245
T_CENTER_S = 0.060
REVOLUTION_S = 360 / W0


def context(*, speed_deg_s: float = W0, compensated: bool = False) -> WheelContext:
    registers = SensorRegisters(REGMAP, bridge=None)  # type: ignore[arg-type]
    snapshot = RegisterSnapshot(REGMAP, registers, {r.name: r.reset for r in REGMAP.registers})
    return WheelContext(
        profile=PROFILE,
        speed_deg_s=speed_deg_s,
        compensated=compensated,
        timing=snapshot.timing(),
        preview=snapshot.preview,
        regmap=REGMAP,
        columns=snapshot.columns(),
    )


def plan(ctx: WheelContext | None = None, **request: Any) -> WheelPlan:
    return plan_wheel(WheelAcquireRequest.model_validate(request), ctx or context())


def refusal(ctx: WheelContext | None = None, **request: Any) -> str:
    with pytest.raises(BadRequest) as info:
        plan(ctx, **request)
    return str(info.value)


def frame_time_s(lines: int) -> float:
    return (lines + ROWS + 1) * T_LINE_S


def eq8_deg(pulse_to_centre_s: float) -> float:
    return math.sqrt(
        0.087**2 + (pulse_to_centre_s * 0.03) ** 2 + (W0 * 20e-6 * pulse_to_centre_s) ** 2
    )


# -- a plan's values ------------------------------------------------------------------------------


def test_a_compensated_plan_sets_the_exposure_and_centres_each_frame_on_its_channel() -> None:
    p = plan(channels=[3, 9], passes=2, exposure_s=0.003, compensated=True)
    frame = frame_time_s(146)  # 681 x 20.52 us = 13.97412 ms
    assert p.register_writes == {"EXPOSURE": 146}  # the group counts lines (no bias)
    assert (p.channels, p.frames, p.speed_deg_s) == ([3, 9], 4, W0)
    assert (p.compensated, p.was_compensated) == (True, False)
    e = p.exposure
    assert (e.exposure_lines, e.window_rows, e.fits, e.refusal) == (146, ROWS, True, None)
    assert e.exposure_s == pytest.approx(146 * T_LINE_S, rel=1e-12)
    assert e.frame_time_s == pytest.approx(frame, rel=1e-12)
    assert frame == pytest.approx(13.97412e-3, rel=1e-12)
    assert e.delay_s == pytest.approx(T_CENTER_S - frame / 2, rel=1e-12)  # 53.01294 ms
    assert e.applied_delay_s == pytest.approx(T_CENTER_S - frame / 2, rel=1e-12)
    assert e.centre_offset_deg == pytest.approx(0.0, abs=1e-12)  # eq 4 at w0
    assert e.centre_error_deg == pytest.approx(eq8_deg(T_CENTER_S), rel=1e-12)
    # A frame waits at most a revolution for its channel's entry pulse, then exposes.
    assert p.frame_period_s == pytest.approx(REVOLUTION_S + frame, rel=1e-12)
    assert p.stream_fields == {"passes": 2, "channels": bytes([3, 9])}
    assert p.metadata == {
        "wheel": "ye23",
        "channels": [3, 9],
        "passes": 2,
        "compensation": "on",
        "speed_deg_s": W0,
        "frame_time_s": e.frame_time_s,
        "delay_s": e.applied_delay_s,
        "stage_position_unit": "wheel angle at the exposure start, 1e-4 deg",
    }


def test_without_compensation_the_centre_drifts_by_half_a_frame() -> None:
    p = plan(context(compensated=True), channels=[0], exposure_s=0.060, compensated=False)
    frame = frame_time_s(2924)  # 3459 x 20.52 us = 70.97868 ms
    assert (p.compensated, p.was_compensated) == (False, True)
    assert p.exposure.applied_delay_s == 0.0
    # eq 1: the frame starts at the pulse, w0 T_center before the channel centre.
    assert p.exposure.centre_offset_deg == pytest.approx(W0 * (frame / 2 - T_CENTER_S), abs=1e-9)
    assert p.exposure.centre_offset_deg == pytest.approx(-1.7952832917, abs=1e-9)
    assert p.exposure.centre_error_deg == pytest.approx(eq8_deg(frame / 2), rel=1e-12)
    assert p.metadata["compensation"] == "off" and p.metadata["delay_s"] == 0.0


def test_off_nominal_speed_misplaces_a_compensated_frame_by_dw_t_center() -> None:
    p = plan(context(speed_deg_s=80.0, compensated=True), channels=[2], exposure_s=0.015)
    # The entry point is a mark on the wheel, w0 T_center before the centre.
    assert p.exposure.centre_offset_deg == pytest.approx((80.0 - W0) * T_CENTER_S, abs=1e-9)
    assert p.frame_period_s == pytest.approx(360 / 80.0 + frame_time_s(731), rel=1e-12)
    assert p.compensated and p.was_compensated  # kept: the wheel's own setting


def test_the_registers_exposure_is_kept_when_none_is_asked_or_it_rounds_to_the_same() -> None:
    for request in ({}, {"exposure_s": 2.4 * T_LINE_S}):  # 2.4 lines round to the reset's 2
        p = plan(channels=[5], **request)
        assert p.register_writes == {}
        e = p.exposure
        assert (e.exposure_lines, e.compensated) == (2, False)
        assert e.exposure_s == pytest.approx(2 * T_LINE_S, rel=1e-12)
        assert e.frame_time_s == pytest.approx(frame_time_s(2), rel=1e-12)


def test_the_longest_exposure_the_window_takes_is_planned() -> None:
    p = plan(channels=[11], exposure_s=5312 * T_LINE_S, compensated=True)
    assert p.register_writes == {"EXPOSURE": 5312}
    assert p.exposure.frame_time_s == pytest.approx(119.98044e-3, rel=1e-12)


# -- refusals, each before anything is touched -----------------------------------------------------


def test_a_frame_beyond_the_light_window_is_refused_with_the_numbers() -> None:
    message = refusal(channels=[11], exposure_s=5313 * T_LINE_S, compensated=True)
    assert message == (
        "wheel acquisition refused, nothing changed (exposure 5313 lines = 109.023 ms, window "
        "534 rows, compensation on): frame time T_frame = (n + k + 1) T_line = 120.001 ms "
        "exceeds the channel's light window of 120 ms (the image would be vignetted or the next "
        "entry pulse missed): shorten the exposure or use fewer window rows, by at least "
        "0.00096 ms of frame time"
    )


def test_channels_a_stopped_wheel_a_short_exposure_and_a_region_are_refused() -> None:
    assert refusal(channels=[2, 13]) == (
        "channel 13 does not exist: the ye23 wheel has channels 0 .. 12; choose channels from "
        "0 to 12"
    )
    assert refusal(context(speed_deg_s=0.0), channels=[1]) == (
        "the filter wheel is stopped, so no entry pulse will come: start it first "
        "(`camctl wheel speed 73.245`)"
    )
    assert refusal(channels=[1], exposure_s=5e-6) == (
        "exposure 0.005 ms is less than half a line (20.52 us): give at least one line"
    )
    assert refusal(channels=[1], region={"row": 530, "rows": 10, "cols": 4}) == (
        "region rows 530..539, columns 0..3 does not fit the 534 x 2048 frame; make it smaller"
    )


def test_the_first_refusal_wins_in_the_order_the_service_always_checked() -> None:
    # Bad channels and a stopped wheel: the channels are named first.
    stopped = context(speed_deg_s=0.0)
    assert refusal(stopped, channels=[13]).startswith("channel 13 does not exist")
    # A stopped wheel and an exposure that does not fit: the wheel first.
    assert refusal(stopped, channels=[1], exposure_s=0.2).startswith("the filter wheel is stopped")
