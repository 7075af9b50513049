"""camd.daemon.scan_image_loop: a scan's image loop between the monitor's blocks, the camera's
line period and the TDI pipeline's drift (no daemon: a real monitor, the writer and the pipeline
recorded).

The blocks are made as docs/physics.md §10 says the frames step: an image moving ``u`` rows a
second, a rolling shutter of row time ``T_row``, ``s = u T / (1 + u T_row)`` at line period T.
"""

from __future__ import annotations

import math
from typing import Any

import pytest

from camd.analysis.image_motion import ImageMotion
from camd.daemon.scan_image_loop import ScanImageLoop
from camd.motion.closed_loop import LinePeriodSetting
from camd.pipeline.image_motion import ImageMotionMonitor, MotionBlock

T_ROW_S = 513 / 25e6
PLANNED_S = 97 * T_ROW_S + 9.56e-6  # 2 ms: a 97-row window and its back path


class Recorded:
    """The camera's line period writer and the pipeline's drift, as the loop calls them."""

    def __init__(self, fail: Exception | None = None) -> None:
        self.periods: list[LinePeriodSetting] = []
        self.drifts: list[float] = []
        self.events: list[tuple[str, str]] = []
        self.fail = fail

    def write(self, setting: LinePeriodSetting) -> None:
        if self.fail is not None:
            raise self.fail
        self.periods.append(setting)

    def request_drift(self, cols_per_line: float) -> None:
        self.drifts.append(cols_per_line)

    def event(self, level: str, message: str) -> None:
        self.events.append((level, message))


def make_loop(monitor: ImageMotionMonitor, recorded: Recorded) -> ScanImageLoop:
    pipeline: Any = recorded  # request_drift is all the loop asks of the pipeline
    return ScanImageLoop(
        monitor, pipeline, recorded.write, line_period_s=PLANNED_S, row_time_s=T_ROW_S,
        stages=96, max_lines=97, rows_per_line=1.0, cols_per_line=0.0, gain=1.0,
        max_trim=0.1, max_cols_per_line=0.2, events=recorded.event,
    )  # fmt: skip


def block(
    counter: int, speed_rows_s: float, period_s: float, *, rolling: bool = True
) -> MotionBlock:
    lag = T_ROW_S if rolling else 0.0
    s = speed_rows_s * period_s / (1 + speed_rows_s * lag)
    t = s * math.tan(math.radians(0.3))
    motion = ImageMotion(s, t, 1e-5, 1e-5, 16, 15, True, "15 pairs registered")
    return MotionBlock(counter, counter + 40, 16, 96, period_s, (768, 1280), 0.0, 0.01, motion)


@pytest.mark.parametrize("rolling", [True, False])
def test_the_shutter_the_stream_started_with_sets_the_target(rolling: bool) -> None:
    # The loop is made before the scan's stream starts; the monitor learns the sensor's row
    # time (or that it has none) only then: the first block must already use it.
    monitor = ImageMotionMonitor()
    recorded = Recorded()
    loop = make_loop(monitor, recorded)
    monitor.stream_started(T_ROW_S if rolling else None)
    monitor.last_counter = 100
    speed = 1.005 / PLANNED_S
    loop.start()
    try:
        loop._on_block(block(0, speed, PLANNED_S, rolling=rolling))  # the monitor's call
    finally:
        loop.stop()
    (setting,) = recorded.periods
    want = 1 / speed + (T_ROW_S if rolling else 0.0)  # T* = 1/u + T_row (docs/motion.md)
    assert setting.line_period_s == pytest.approx(want, rel=1e-9)
    # realised as the encoder's line-period loop realises it: window rows and back path
    assert setting.n_lines == math.floor(want / T_ROW_S)
    assert setting.back_path_s == pytest.approx(want - setting.n_lines * T_ROW_S, rel=1e-9)
    assert recorded.drifts == [pytest.approx(math.tan(math.radians(0.3)), rel=1e-9)]
    assert loop.info().updates == 1 and loop.record.line_period_s == [setting.line_period_s]


def test_blocks_that_say_nothing_or_came_before_the_change_change_nothing() -> None:
    monitor = ImageMotionMonitor()
    monitor.stream_started(T_ROW_S)
    recorded = Recorded()
    loop = make_loop(monitor, recorded)
    speed = 1.005 / PLANNED_S
    loop.start()
    try:
        flat = block(0, speed, PLANNED_S)
        nan = math.nan
        flat = MotionBlock(0, 40, 16, 96, PLANNED_S, (768, 1280), 0.0, 0.01,
                           ImageMotion(nan, nan, nan, nan, 16, 0, False, "scene texture too low"))  # fmt: skip
        loop._on_block(flat)
        assert recorded.periods == []
        monitor.last_counter = 500
        loop._on_block(block(0, speed, PLANNED_S))  # acted on; the change lands after 504
        loop._on_block(block(300, speed, PLANNED_S))  # measured before it: not acted on
        assert len(recorded.periods) == 1
        loop._on_block(block(505, speed, recorded.periods[0].line_period_s))
        assert len(recorded.periods) == 2
    finally:
        loop.stop()
    loop._on_block(block(900, speed, PLANNED_S))  # stopped: nothing more
    assert len(recorded.periods) == 2


def test_a_failed_write_stops_the_loop_not_the_scan_and_says_so() -> None:
    monitor = ImageMotionMonitor()
    monitor.stream_started(T_ROW_S)
    recorded = Recorded(fail=RuntimeError("link lost"))
    loop = make_loop(monitor, recorded)
    loop.start()
    try:
        loop._on_block(block(0, 1.005 / PLANNED_S, PLANNED_S))
        loop._on_block(block(100, 1.005 / PLANNED_S, PLANNED_S))
    finally:
        loop.stop()
    assert loop.info().error == "image loop stopped: link lost"
    assert recorded.events == [
        ("warning", "image loop stopped: link lost; the scan continues with the last setting")
    ]
    assert recorded.drifts == []


def test_a_limit_is_held_and_said_once() -> None:
    monitor = ImageMotionMonitor()
    monitor.stream_started(T_ROW_S)
    recorded = Recorded()
    loop = make_loop(monitor, recorded)
    fast = 1.3 / PLANNED_S  # wants the period 23 % shorter: held at 10 %
    loop.start()
    try:
        for counter in (0, 100, 200):
            monitor.last_counter = counter + 50
            loop._on_block(block(counter, fast, PLANNED_S))
    finally:
        loop.stop()
    # The loop holds its trim at 10 % (1.8 ms); the window cannot hold 96 stages in fewer than
    # 96 rows, so what is written is the shortest period it can: 96 row times, no back path.
    assert loop.info().line_period_s == pytest.approx(0.9 * PLANNED_S)
    assert [(p.n_lines, p.back_path_s) for p in recorded.periods] == [(96, 0.0)] * 3
    assert recorded.periods[0].line_period_s == pytest.approx(96 * T_ROW_S, rel=1e-12)
    assert loop.info().limited
    assert [e for e in recorded.events if "at its limit" in e[1]] == [recorded.events[0]]
    assert len(recorded.events) == 1
