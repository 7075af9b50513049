"""The live view's focus aid in process (camd.pipeline.focus): figures, history, best, watching.

Frames are offered to a real ``LiveTap`` as the stream would offer them; their pixels are a bar
target blurred by the simulator's own optics blur (``firmware_models.scene.blur_cells``), so the
sweep 3, 2, 1, 0, 1, 2, 3 px has its sharpest frame known: the one of blur 0.
"""

from __future__ import annotations

import time

import numpy as np
import pytest

from camd.analysis.roi import Roi
from camd.analysis.sharpness import grey_gradient_sharpness
from camd.pipeline.focus import FRAME_TARGET, FocusMonitor, focus_values
from camd.pipeline.live import LiveTap
from firmware_models.scene import blur_cells
from tests.test_live_view import received

ROWS, COLS = 48, 160


def bars(blur_px: float) -> np.ndarray:
    """Bars of a 6-pixel period along track, 100 .. 3000 DN, blurred by ``blur_px``."""
    rows = np.arange(ROWS)[:, None]
    sharp = np.where(rows % 6 < 3, 3000.0, 100.0) * np.ones((1, COLS))
    return np.rint(blur_cells(sharp, blur_px, oversample=1, x_oversample=1)).astype(np.uint16)


def offer(tap: LiveTap, counter: int, pixels: np.ndarray) -> None:
    tap(received(counter, pixels))


def test_the_figures_are_the_grey_gradient_of_the_frame_and_of_each_roi() -> None:
    tap = LiveTap(max_rate_hz=1e9)
    pixels = bars(0.7)
    pixels[:, 100:] = 500  # a flat part: G = 0 there
    offer(tap, 7, pixels)
    frame = tap.latest()
    assert frame is not None
    rois = [Roi("bars", 10, 4, 50, 30), Roi("flat", 110, 0, 40, 40), Roi("wide", 0, 0, 200, 8)]
    values = focus_values(frame, rois)
    assert values == {
        FRAME_TARGET: grey_gradient_sharpness(pixels),
        "bars": grey_gradient_sharpness(pixels[4:34, 10:60]),
        "flat": 0.0,
        "wide": None,  # does not fit this 160-column frame
    }
    offer(tap, 8, np.zeros((ROWS, COLS), dtype=np.uint16))
    dark = tap.latest()
    assert dark is not None and focus_values(dark, [])[FRAME_TARGET] is None  # no level: no G


def test_a_blur_sweep_peaks_at_best_focus_and_the_best_is_kept_until_reset() -> None:
    tap = LiveTap(max_rate_hz=1e9)
    monitor = FocusMonitor(tap.wait_newer, lambda: [Roi("centre", 40, 10, 80, 28)], history_max=5)
    sweep = [3, 2, 1, 0, 1, 2, 3]
    figures = []
    for counter, blur in enumerate(sweep, start=100):
        offer(tap, counter, bars(blur))
        frame = tap.latest()
        assert frame is not None
        figures.append(monitor.add(frame).values[FRAME_TARGET])
    assert figures.index(max(figures)) == sweep.index(0)
    assert figures[0] < figures[1] < figures[2] < figures[3] > figures[4] > figures[5]
    snap = monitor.snapshot(history=100)
    # The history is bounded (5 kept of 7), oldest first; the best is blur 0's frame (counter 103)
    assert [p.counter for p in snap.history] == [102, 103, 104, 105, 106]
    assert snap.measured == 7
    assert snap.best[FRAME_TARGET].value == figures[3] and snap.best[FRAME_TARGET].counter == 103
    assert snap.best["centre"].counter == 103
    assert [p.counter for p in monitor.snapshot(history=0).history] == [106]
    monitor.reset_best()
    assert monitor.snapshot(history=0).best == {}
    offer(tap, 200, bars(2))
    frame = tap.latest()
    assert frame is not None
    monitor.add(frame)
    best = monitor.snapshot(history=0).best[FRAME_TARGET]
    assert best.counter == 200 and best.value == pytest.approx(figures[1])


def wait_until(predicate, timeout_s: float = 30.0) -> None:  # type: ignore[no-untyped-def]
    deadline = time.monotonic() + timeout_s
    while not predicate():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.01)


def test_the_thread_measures_only_while_watched() -> None:
    now = [1000.0]
    tap = LiveTap(max_rate_hz=1e9)
    monitor = FocusMonitor(tap.wait_newer, list, rate_hz=50.0, watch_s=30.0, clock=lambda: now[0])
    try:
        offer(tap, 1, bars(1))
        time.sleep(0.2)
        assert monitor.snapshot(0).measured == 0  # nobody asked: nothing measured, no thread
        monitor.watch()
        wait_until(lambda: monitor.snapshot(0).measured == 1)
        assert monitor.watching()
        now[0] += 31.0  # the last look was 31 s ago: measuring stops
        assert not monitor.watching()
        # The thread may be waiting for a frame already: the next one may still be measured.
        offer(tap, 2, bars(1))
        wait_until(lambda: tap.wait_newer(1, 0) is not None)
        time.sleep(0.3)
        settled = monitor.snapshot(0).measured
        for counter in range(3, 6):
            offer(tap, counter, bars(1))
            time.sleep(0.05)
        time.sleep(0.3)
        assert monitor.snapshot(0).measured == settled <= 2
        monitor.watch()
        wait_until(lambda: monitor.snapshot(0).history[-1].counter == 5)
    finally:
        monitor.close()
