"""The live page as a bench viewer (issue 34, items 1, 3 and 5) in a real browser: Debian's
chromium driven by Playwright, against one daemon on the simulated hr400 (a 64-row window).

- Fit to window and zoom below 1x: "fit" shows all 2048 columns; at 1/2x and 1/4x (the display
  a block mean) the readout gives the sensor's ramp test pattern's exact raw DN ((row + col) mod
  4096) of the full-resolution pixel under the cursor, not a block's mean; the display is the
  block mean (the ramp's block means, on the canvas, the short last block's too); the wheel
  zooms across 1x.
- The clipping overlay's counts: on the ramp, known before: no pixel at full scale (4095), one at
  0 (row 0, column 0); on bright bars at analogue gain x2 (the ADC clips before the full well)
  with no offset, the full-scale and zero pixels of the very frame fetched through
  /api/v1/live/frame, counted on the full frame whatever the zoom; the log histogram.
- The focus aid: the scene's blur swept 3, 2, 1, 0, 1, 2, 3 px (the simulator's ``blur_px``):
  the page's figure is highest at 0 and its best-so-far mark is a blur-0 frame's figure;
  ``camctl focus`` says the same and ``--reset`` forgets the best; resetting needs control (a
  refusal keeps the best), a history beyond 1200 is refused naming the range.

``CAMD_DOCS_SCREENSHOTS=1`` makes the fit test rewrite docs/img/live-fit.png (docs/live-view.md).

Not ``exclusive``: each value is waited for with a generous timeout; a busy machine makes the
page slower, not wrong.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest

from camd.client import CamdError
from tests.browser import PageLog
from tests.test_camctl import camctl_command, camctl_json
from tests.test_live_page import (
    ROWS,
    TOKEN,
    WORD_BITS,
    Bench,
    clean,
    frames_shown,
    live_bench,
    open_live,
    shot,
    wait_for,
)

DOCS_IMG = Path(__file__).resolve().parents[1] / "docs" / "img"
FULL_SCALE = (1 << WORD_BITS) - 1


@pytest.fixture(scope="module")
def bench(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Bench]:
    with live_bench(tmp_path_factory.mktemp("camd-live-page-view")) as bench:
        yield bench


@pytest.fixture(autouse=True)
def idle(bench: Bench) -> Iterator[None]:
    """Each test ends with nothing streaming, the sensor and scene as at the start."""
    yield
    with bench.client() as client:
        client.take_control(force=True)
        client.stop_stream()
        client.write_registers({"TEST_PATTERN.mode": "off", "GAIN.analog": "x1", "OFFSET": 100})
        client.set_scene("flat")
        for roi in client.rois()["rois"]:
            client.delete_roi(roi["name"])
        client.release_control()


def view_state(page: Any) -> dict[str, Any]:
    state: dict[str, Any] = page.evaluate(
        "(() => { const v = window.camdLive.view; return {zoom: v.zoom, originRow: v.originRow,"
        " originCol: v.originCol, cols: v.frame?.cols, rows: v.frame?.rows,"
        " width: v.size().width, height: v.size().height}; })()"
    )
    return state


def readout_at(page: Any, x: int, y: int) -> dict[str, str]:
    """Put the mouse at (x, y) CSS pixels from the canvas's top left (whole pixels, as
    chromium gives mouse events) and read the readout."""
    box = page.locator("#image").bounding_box()
    page.mouse.move(math.ceil(box["x"]) + x, math.ceil(box["y"]) + y)
    return {key: page.inner_text(f"#px-{key}") for key in ("row", "col", "raw", "sub")}


def pixel_under(page: Any, x: int, y: int) -> tuple[int, int]:
    """The full-resolution pixel whose area holds the point (x, y) of the canvas: at zoom z,
    image pixel (r, c) covers [(c - left) z, (c - left + 1) z) across, the same down."""
    state = view_state(page)
    box = page.locator("#image").bounding_box()
    fx = math.ceil(box["x"]) + x - box["x"]
    fy = math.ceil(box["y"]) + y - box["y"]
    zoom = state["zoom"]
    if zoom < 1:  # 1/k: k pixels per CSS pixel (1/3 is not exact in floating point)
        k = round(1 / zoom)
        return state["originRow"] + math.floor(fy * k), state["originCol"] + math.floor(fx * k)
    return state["originRow"] + math.floor(fy / zoom), state["originCol"] + math.floor(fx / zoom)


def stream_ramp(bench: Bench, page: Any, log: PageLog) -> None:
    with bench.client() as client:
        client.write_registers({"TEST_PATTERN.mode": "ramp"})
        client.start_stream(frames=0)
    open_live(page, log, bench, "viewer")
    wait_for("a frame", lambda: frames_shown(page) >= 1)


def test_fit_shows_every_column_and_the_readout_below_1x_gives_raw_dn(
    bench: Bench, page: tuple[Any, PageLog]
) -> None:
    browser_page, log = page
    stream_ramp(bench, browser_page, log)
    browser_page.select_option("#zoom", "fit")
    state = wait_for("the fitted view", lambda: (s := view_state(browser_page))["zoom"] < 1 and s)
    # The whole width in the canvas: 2048 columns at 1/k, the smallest whole k that fits.
    k = round(1 / state["zoom"])
    assert state["cols"] == 2048 and state["originCol"] == 0
    assert 2048 / k <= state["width"] < 2048 / (k - 1)
    # The last column is on the canvas: the readout at the image's right end reads it.
    right = math.ceil(2048 / k) - 1
    readout = readout_at(browser_page, right, 0)
    row, col = pixel_under(browser_page, right, 0)
    assert 2048 - k <= col <= 2047
    assert readout == {"row": str(row), "col": str(col), "raw": str((row + col) % 4096), "sub": "-"}
    shot(browser_page, "fit")
    if os.environ.get("CAMD_DOCS_SCREENSHOTS") == "1":  # the docs' picture, when asked only:
        browser_page.screenshot(path=str(DOCS_IMG / "live-fit.png"))  # a test run leaves no diff
    for zoom, top, left in [("0.5", 0, 0), ("0.25", 0, 0), ("0.5", 0, 201), ("0.25", 0, 1)]:
        browser_page.select_option("#zoom", zoom)
        browser_page.fill("#origin-col", str(left))
        browser_page.dispatch_event("#origin-col", "change")
        state = view_state(browser_page)
        assert state["zoom"] == float(zoom) and state["originRow"] == top
        k = round(1 / state["zoom"])
        assert state["originCol"] == left - left % k  # blocks start at multiples of k
        seen_cols = min(int(state["width"]), (2048 - state["originCol"]) // k)
        seen_rows = ROWS // k
        for x, y in [
            (0, 0),
            (seen_cols - 1, seen_rows - 1),
            (7, seen_rows // 2),
            (seen_cols // 3, 3),
        ]:
            row, col = pixel_under(browser_page, x, y)
            readout = readout_at(browser_page, x, y)
            # The pixel's own DN: a k x k block's mean would be (row + col) + (k - 1).
            expected = (row + col) % 4096
            assert readout == {"row": str(row), "col": str(col), "raw": str(expected), "sub": "-"}
    shot(browser_page, "zoom-quarter")
    # The display below 1x is the block mean: with the gray map over 0..255 DN (one grey level
    # a DN), block (i, j) of the ramp shows the mean of row + col over its k x k pixels,
    # k (i + j) + (k - 1); one pixel of each block (dropping the rest) would show k (i + j).
    set_contrast(browser_page, 0, 255)
    for zoom in ("0.5", "0.25"):
        browser_page.select_option("#zoom", zoom)
        k = round(1 / float(zoom))
        for i, j in [(0, 0), (3, 10), (5, 20), (1, 50)]:
            mean = k * (i + j) + (k - 1)
            assert canvas_rgb(browser_page, j, i) == [mean] * 3, (zoom, i, j)
    # The last block of a fitted 2048-column frame holds fewer columns: the mean of those.
    browser_page.select_option("#zoom", "fit")
    k = round(1 / view_state(browser_page)["zoom"])
    last = math.ceil(2048 / k) - 1
    cols_in_last = 2048 - k * last
    set_contrast(browser_page, 2000, 2255)
    mean = k * last + (cols_in_last - 1) / 2 + (k - 1) / 2  # of row + col over block (0, last)
    assert canvas_rgb(browser_page, last, 0) == [math.floor(mean - 2000)] * 3
    set_contrast(browser_page, 0, 4095)
    # The wheel (on the image: 10 px from the top) zooms across 1x and keeps the column under the
    # cursor where it is (but at 1/4x, where the whole width fits and the view cannot pan: there
    # it is 4 x 100).
    browser_page.select_option("#zoom", "1")
    browser_page.fill("#origin-col", "400")
    browser_page.dispatch_event("#origin-col", "change")
    readout_at(browser_page, 100, 10)
    zooms = [1.0]
    for delta in (100, 100, -100, -100, -100):
        before = pixel_under(browser_page, 100, 10)[1]
        browser_page.mouse.wheel(0, delta)
        wait_for("the zoom to change", lambda: view_state(browser_page)["zoom"] != zooms[-1])
        zooms.append(view_state(browser_page)["zoom"])
        col = pixel_under(browser_page, 100, 10)[1]
        assert col == (400 if zooms[-1] == 0.25 else before), (zooms, before, col)
        assert browser_page.input_value("#zoom") == str(zooms[-1]).removesuffix(".0")
    assert zooms == [1, 0.5, 0.25, 0.5, 1, 2]
    clean(log)


def set_contrast(page: Any, low: float, high: float) -> None:
    """Manual contrast (typing a bound switches to manual)."""
    for element, value in (("#lo", low), ("#hi", high)):
        page.fill(element, str(value))
        page.dispatch_event(element, "change")


def live_frame(bench: Bench) -> tuple[dict[str, Any], np.ndarray]:
    """The daemon's newest live frame (GET /api/v1/live/frame): its description and pixels."""
    with httpx.Client(base_url=bench.url, headers={"Authorization": f"Bearer {TOKEN}"}) as http:
        answer = http.get("/api/v1/live/frame")
    meta: dict[str, Any] = json.loads(answer.headers["X-Camd-Frame"])
    pixels = np.frombuffer(answer.content, dtype="<u2").reshape(meta["rows"], meta["cols"])
    return meta, pixels


def counts_shown(page: Any) -> tuple[int, int]:
    return int(page.inner_text("#sat-count")), int(page.inner_text("#zero-count"))


def canvas_rgb(page: Any, x: int, y: int) -> list[int]:
    rgb: list[int] = page.evaluate(
        f"Array.from(document.getElementById('image').getContext('2d')"
        f".getImageData({x}, {y}, 1, 1).data.slice(0, 3))"
    )
    return rgb


def test_the_clipping_overlay_counts_the_full_scale_and_zero_pixels_of_the_frame(
    bench: Bench, page: tuple[Any, PageLog]
) -> None:
    browser_page, log = page
    stream_ramp(bench, browser_page, log)
    browser_page.check("#clip-overlay")
    # The ramp (row + col) mod 4096 over 64 x 2048 pixels: known before it is shown.
    wait_for("the ramp's counts", lambda: counts_shown(browser_page) == (0, 1))
    browser_page.select_option("#zoom", "1")
    assert canvas_rgb(browser_page, 0, 0) == [0, 96, 255]  # pixel (0, 0), 0 DN: blue
    with bench.client() as client:
        client.stop_stream()
        client.write_registers({"TEST_PATTERN.mode": "off", "GAIN.analog": "x2", "OFFSET": 0})
        # Bright bars at gain x2: the ADC clips at 4095 before the full well on the bright
        # bars; without an offset the dark bars' noise reaches 0.
        client.set_scene("bars:photons=1e10")
        client.start_stream(frames=0)
        wait_for("bars on the page", lambda: counts_shown(browser_page)[0] > 1000)
        client.stop_stream()
    browser_page.select_option("#zoom", "fit")
    meta, pixels = live_frame(bench)
    assert meta["bits"] == WORD_BITS
    wait_for(
        "the page to show the last frame",
        lambda: browser_page.evaluate("window.camdLive.lastMeta.seq") == meta["seq"],
    )
    saturated, zero = int(np.sum(pixels == FULL_SCALE)), int(np.sum(pixels == 0))
    assert 0 < saturated < pixels.size and 0 < zero < pixels.size
    # Counted on the full frame although the fitted display is a block mean.
    assert browser_page.evaluate("window.camdLive.view.zoom") < 1
    wait_for("the frame's counts", lambda: counts_shown(browser_page) == (saturated, zero))
    assert f"{saturated} at full scale ({FULL_SCALE} DN)" in browser_page.inner_text("#clip-note")
    # Red where a block holds a full-scale pixel, somewhere on the canvas.
    red = browser_page.evaluate(
        "(() => { const c = document.getElementById('image');"
        " const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data; let n = 0;"
        " for (let i = 0; i < d.length; i += 4) if (d[i] === 255 && d[i + 1] === 32"
        " && d[i + 2] === 32) n++; return n; })()"
    )
    assert red > 0
    shot(browser_page, "clipping")
    # The log histogram: the same counts on a log scale (empty bins left out, not 0).
    browser_page.check("#hist-log")
    hist = browser_page.evaluate(
        "(() => { const h = window.camdLive.plots.hist;"
        " return {distr: h.scales.y.distr, y: Array.from(h.data[1])}; })()"
    )
    assert hist["distr"] == 3
    assert sum(v for v in hist["y"] if v is not None) == pixels.size
    assert all(v is None or v > 0 for v in hist["y"])
    shot(browser_page, "log-histogram")
    clean(log)


def focus_shown(page: Any) -> tuple[float, float, int]:
    """The page's figure, best and the frame counter of its newest figure."""
    state: dict[str, Any] = page.evaluate("window.camdLive.focus.shown")
    return state["value"], state["best"], state["counter"]


def figures_after(page: Any, counter: int) -> int:
    """Figures the page has of frames after frame ``counter``."""
    counters: list[int] = page.evaluate("window.camdLive.focus.counters()")
    return len([c for c in counters if c > counter])


def test_the_focus_figure_peaks_at_best_focus_when_the_blur_is_swept(
    bench: Bench, page: tuple[Any, PageLog]
) -> None:
    browser_page, log = page
    sweep = [3, 2, 1, 0, 1, 2, 3]
    with bench.client() as client:
        client.set_scene(f"bars:blur_px={sweep[0]}")
        client.add_roi("fine", 880, 0, 290, ROWS)  # the 0.25 cycles/pixel bar group
        client.start_stream(frames=0)
        open_live(browser_page, log, bench, "viewer")
        browser_page.check("#focus-on")
        wait_for("a focus figure", lambda: browser_page.inner_text("#focus-value") != "-")
        client.reset_focus_best()
        figures = []
        spans = []
        for blur in sweep:
            client.set_scene(f"bars:blur_px={blur}")
            # Frames made before the change may still be on their way: the figure of the step
            # is the one the page shows once 4 figures of later frames have come.
            latest = client.focus()["latest"]
            assert latest is not None
            changed_at = latest["counter"]
            wait_for(
                f"figures at blur {blur}",
                lambda at=changed_at: figures_after(browser_page, at) >= 4,  # type: ignore[misc]
            )
            value, _, counter = focus_shown(browser_page)
            assert float(browser_page.inner_text("#focus-value")) == pytest.approx(value, rel=1e-3)
            figures.append(value)
            spans.append((changed_at, counter))
        client.stop_stream()
        # The stream's last kept frame measured too: the figures are final.
        last_seq = live_frame(bench)[0]["seq"]
        focus = wait_for(
            "the last frame's figure",
            lambda: (
                (f := client.focus())["latest"] is not None and f["latest"]["seq"] == last_seq and f
            ),
        )
        best = focus["best"]["frame"]
    assert figures.index(max(figures)) == sweep.index(0), figures
    assert figures[0] < figures[1] < figures[2] < figures[3] > figures[4] > figures[5] > figures[6]
    # The best mark says blur 0's value: a figure of a frame of the blur-0 step, at least the
    # step's figure, above every other step's.
    assert best["counter"] > spans[3][0], (best, spans)
    assert best["value"] >= figures[3] and best["value"] > max(figures[:3] + figures[4:])
    wait_for("the best on the page", lambda: focus_shown(browser_page)[1] == best["value"])
    shown_value, _, shown_frame = browser_page.inner_text("#focus-best").partition(" at frame ")
    assert float(shown_value) == pytest.approx(best["value"], rel=1e-3)
    assert shown_frame == str(best["counter"])
    # On the plot, the best is marked where it is.
    marked = browser_page.evaluate(
        "(() => { const p = window.camdLive.focus.plot;"
        " return p.data[2].filter(v => v !== null && v !== undefined); })()"
    )
    assert marked == [best["value"]]
    # An ROI's figure: the one the daemon measured on its rectangle.
    wait_for(
        "the page's last figure", lambda: focus_shown(browser_page)[2] == focus["latest"]["counter"]
    )
    browser_page.select_option("#focus-target", "fine")
    fine = focus["latest"]["values"]["fine"]
    assert fine is not None and fine != focus["latest"]["values"]["frame"]
    assert float(browser_page.inner_text("#focus-value")) == pytest.approx(fine, rel=1e-3)
    assert browser_page.inner_text("#focus-best").endswith(
        f" at frame {focus['best']['fine']['counter']}"
    )
    browser_page.select_option("#focus-target", "frame")
    shot(browser_page, "focus")
    # The same through camctl: the figure and the best, the history; --reset forgets the best.
    shown = camctl_command(bench.url, "--token", TOKEN, "focus")
    assert shown.returncode == 0, shown.stderr
    assert f"at frame {best['counter']})" in shown.stdout and "  frame: " in shown.stdout
    doc = camctl_json(bench.url, "--token", TOKEN, "focus", "--history", "5")
    assert doc["best"]["frame"] == best and len(doc["history"]["counter"]) == 5
    assert camctl_json(bench.url, "--token", TOKEN, "focus", "--reset")["best"] == {}
    clean(log)


def test_resetting_the_best_needs_control_and_a_refusal_keeps_it(bench: Bench) -> None:
    with bench.client() as client, bench.client("other@bench") as other:
        client.write_registers({"TEST_PATTERN.mode": "ramp"})
        client.focus()  # asked: the daemon measures
        client.start_stream(frames=0)
        wait_for("a best figure", lambda: client.focus()["best"].get("frame"))
        client.stop_stream()
        before = client.focus()["best"]
        other.take_control()
        with pytest.raises(CamdError) as info:
            client.reset_focus_best()
        assert (info.value.http_status, info.value.code) == (423, "not_in_control")
        assert info.value.message.startswith("cannot reset the best focus figure: other@bench")
        assert client.focus()["best"] == before  # refused: nothing changed
        with httpx.Client(base_url=bench.url, headers={"Authorization": f"Bearer {TOKEN}"}) as http:
            answer = http.get("/api/v1/live/focus", params={"history": 1201})
        assert answer.status_code == 400 and "history" in answer.json()["error"]
        assert "1200" in answer.json()["error"]
        assert other.reset_focus_best()["best"] == {}
        other.release_control()
