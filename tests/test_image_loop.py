"""camd.motion.image_loop: the line period and the drift from the image (issue 35 item 4).

The plant is docs/physics.md §10's: an image moving ``u`` rows a second at an angle ``theta``,
seen by a rolling shutter of row time ``T_row``, steps ``s = u T / (1 + u T_row)`` rows and
``s tan(theta)`` columns between frames ``T`` apart.
"""

from __future__ import annotations

import math

import pytest

from camd.motion.image_loop import ImageLoop

T_ROW_S = 513 / 25e6  # hr400's row time
PLANNED_S = 97 * T_ROW_S + 9.56e-6  # the 2 ms line period of a 97-row window


def frames_step(speed_rows_s: float, period_s: float, theta_deg: float) -> tuple[float, float]:
    s = speed_rows_s * period_s / (1 + speed_rows_s * T_ROW_S)
    return s, s * math.tan(math.radians(theta_deg))


@pytest.mark.parametrize("row_time_s", [T_ROW_S, 0.0])
@pytest.mark.parametrize(("magnification_error", "theta_deg"), [(0.005, 0.3), (-0.02, -1.0)])
def test_the_loop_brings_the_frames_to_one_row_a_line_and_the_drift_to_the_image(
    row_time_s: float, magnification_error: float, theta_deg: float
) -> None:
    # the encoder holds the stage at the planned line period's synchronous speed; the optics
    # make the image 1 + e times as fast
    speed = (1 + magnification_error) / PLANNED_S
    loop = ImageLoop(line_period_s=PLANNED_S, row_time_s=row_time_s, gain=0.6)
    period, drift = PLANNED_S, 0.0
    for _ in range(30):
        s, t = frames_step(speed, period, theta_deg)
        if row_time_s == 0.0:  # a global shutter: the frames step the image's own speed
            s, t = speed * period, speed * period * math.tan(math.radians(theta_deg))
        setting = loop.update(s, t, period)
        period, drift = setting.line_period_s, setting.cols_per_line
    # the fixed point: T* = 1 / u + T_row, where s = 1 exactly; the drift tan(theta) a line
    assert period == pytest.approx(1 / speed + row_time_s, rel=1e-9)
    assert drift == pytest.approx(math.tan(math.radians(theta_deg)), rel=1e-9)
    assert not setting.limited and loop.updates == 30
    if row_time_s:
        s, _ = frames_step(speed, period, theta_deg)
        assert s == pytest.approx(1.0, abs=1e-9)


def test_one_dead_beat_step_lands_on_the_target() -> None:
    loop = ImageLoop(line_period_s=PLANNED_S, row_time_s=T_ROW_S, gain=1.0)
    speed = 1.01 / PLANNED_S
    s, t = frames_step(speed, PLANNED_S, 0.5)
    setting = loop.update(s, t, PLANNED_S)
    assert setting.line_period_s == pytest.approx(1 / speed + T_ROW_S, rel=1e-12)
    assert setting.cols_per_line == pytest.approx(math.tan(math.radians(0.5)), rel=1e-12)


def test_the_limits_hold_and_say_so() -> None:
    # an image 30 % fast would want the period 23 % shorter: held at 10 %, flagged
    loop = ImageLoop(line_period_s=PLANNED_S, row_time_s=T_ROW_S, gain=1.0, max_trim=0.1)
    s, t = frames_step(1.3 / PLANNED_S, PLANNED_S, 20.0)
    setting = loop.update(s, t, PLANNED_S)
    assert setting.line_period_s == pytest.approx(0.9 * PLANNED_S)
    assert setting.cols_per_line == pytest.approx(0.2)  # tan(20 deg) = 0.36, held at 0.2
    assert setting.limited


def test_a_block_that_says_nothing_changes_nothing() -> None:
    loop = ImageLoop(line_period_s=PLANNED_S, row_time_s=T_ROW_S, cols_per_line=0.01)
    for s, t in ((math.nan, math.nan), (0.0, 0.0), (-1.0, 0.0)):
        setting = loop.update(s, t, PLANNED_S)
        assert (setting.line_period_s, setting.cols_per_line) == (PLANNED_S, 0.01)
    assert loop.updates == 0


def test_bad_settings_say_what_to_give() -> None:
    with pytest.raises(ValueError, match="0 <= it < the line period"):
        ImageLoop(line_period_s=1e-3, row_time_s=2e-3)
    with pytest.raises(ValueError, match="use 0 < gain <= 1"):
        ImageLoop(line_period_s=1e-3, row_time_s=0.0, gain=0.0)
