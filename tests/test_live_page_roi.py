"""The live page's ROIs and telemetry plots in a real browser (Debian's chromium, Playwright).

One daemon on the simulated hr400 (a 64-row window, the ramp test pattern: DN = (row + col)
mod 4096 at every pixel) with fpga_temp_degc's yellow range made to exclude the simulator's
temperature, as tests/test_live_page.py has it, and sensor_temp_degc's red range. What is checked could be wrong: the statistics
the page lists for an ROI drawn with the mouse against the pattern's own numbers over that
rectangle (computed here, not by camd), the ROI the daemon has against the rectangle drawn, the
outline's colour painted on the image, the plot's history against the same numbers, and the
colour painted on the telemetry plot's canvas at a data point beyond the yellow limit (and
beyond the red one, and inside both). The
screenshots (test-artifacts/live-roi.png, live-telemetry-plots.png) are those of
docs/live-view.md (docs/img/live-roi.png; live-telemetry.png after 4 minutes of streaming).
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest

from tests.browser import PageLog, artifacts_dir
from tests.test_live_page import (
    CONFIG,
    ROWS,
    TESTER,
    WORD_BITS,
    Bench,
    back_to_idle,
    clean,
    frames_shown,
    live_bench,
    move_to_pixel,
    open_live,
    set_view,
    take_control_on_page,
    wait_for,
    wait_for_text,
)

# As tests/test_live_page.py's, and sensor_temp_degc's red range made to exclude the simulator's
# temperature too, without a fault (which would stop the stream).
CONFIG_RED = (
    CONFIG
    + """
[telemetry]
red_is_fault = false

[telemetry.limits.sensor_temp_degc]
yellow = [0.0, 1.0]
red = [0.0, 2.0]
"""
)
YELLOW = [249, 168, 37, 255]  # live.css --yellow, #f9a825
RED = [211, 47, 47, 255]  # live.css --red, #d32f2f
OK = [79, 195, 247, 255]  # live.css --accent, #4fc3f7: inside the yellow range


@pytest.fixture(scope="module")
def bench(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Bench]:
    with live_bench(tmp_path_factory.mktemp("camd-live-roi"), CONFIG_RED) as bench:
        yield bench


@pytest.fixture(autouse=True)
def idle(bench: Bench) -> Iterator[None]:
    """Each test ends with nothing streaming, no ROI, the pattern off and nobody in control."""
    yield
    back_to_idle(bench)


def rois(bench: Bench) -> list[dict[str, Any]]:
    """GET /api/v1/live/roi's ROIs."""
    with bench.client() as client:
        return [dict(roi) for roi in client.rois()["rois"]]


def ramp(top: int, left: int, height: int, width: int) -> np.ndarray:
    """The test pattern over a rectangle, from its definition (not from camd)."""
    rows, cols = np.mgrid[top : top + height, left : left + width]
    return (rows + cols) % (1 << WORD_BITS)


def drag(page: Any, start: tuple[int, int], end: tuple[int, int]) -> None:
    """Press the mouse over image pixel ``start`` (row, col), move to ``end``, release."""
    move_to_pixel(page, *start)
    page.mouse.down()
    move_to_pixel(page, (start[0] + end[0]) // 2, (start[1] + end[1]) // 2)
    move_to_pixel(page, *end)
    page.mouse.up()


def listed(page: Any, name: str) -> dict[str, str]:
    """The page's list row of ROI ``name``: each statistic's text ({} while it has none)."""
    cells = page.locator(f'#roi-list tr[data-roi="{name}"] td[data-stat]')
    return {c.get_attribute("data-stat"): c.inner_text() for c in cells.all()}


def shows(page: Any, name: str, pixels: np.ndarray) -> dict[str, str] | None:
    """The list row of ``name`` once it shows ``pixels``' mean, min and max (else None)."""
    row = listed(page, name)
    try:
        mean, lo, hi = float(row["mean_dn"]), float(row["min_dn"]), float(row["max_dn"])
    except (KeyError, ValueError):
        return None
    wanted = (float(pixels.mean()), float(pixels.min()), float(pixels.max()))
    return row if (round(mean, 2), lo, hi) == (round(wanted[0], 2), wanted[1], wanted[2]) else None


def outline_pixel(page: Any, x: int, y: int) -> list[int]:
    """The image canvas's RGBA at CSS pixel (x, y)."""
    return list(
        page.evaluate(
            """([x, y]) => { const d = devicePixelRatio || 1, c = document.getElementById('image');
                return Array.from(c.getContext('2d').getImageData(x * d, y * d, 1, 1).data); }""",
            [x, y],
        )
    )


def test_an_roi_drawn_on_the_ramp_lists_the_patterns_statistics_and_can_be_edited_and_deleted(
    bench: Bench, page: tuple[Any, PageLog]
) -> None:
    browser_page, log = page
    with bench.client() as client:
        client.write_registers({"TEST_PATTERN.mode": "ramp"})
        client.take_control(ttl_s=120)
        client.start_stream(frames=0)
        open_live(browser_page, log, bench, "operator")
        wait_for("a frame", lambda: frames_shown(browser_page) >= 1)
        browser_page.click("#roi-tool")
        browser_page.fill("#roi-name", "dark")
        # Without control the daemon refuses, the page shows its message, nothing is defined.
        drag(browser_page, (10, 100), (40, 299))
        refusal = wait_for_text(browser_page, "the refusal", "#message", "define ROI dark: ")
        assert f"{TESTER} holds control" in refusal
        assert rois(bench) == []
        browser_page.click("#message")
        client.stop_stream()
        client.release_control()
    take_control_on_page(browser_page)
    browser_page.click("#ctl-stream-start")
    wait_for("a frame", lambda: frames_shown(browser_page) >= 1)

    # Drawn with the mouse at 1x from pixel (10, 100) to (40, 299), both included.
    drag(browser_page, (10, 100), (40, 299))
    wait_for("the ROI in the daemon", lambda: rois(bench))
    assert rois(bench) == [{"name": "dark", "x": 100, "y": 10, "width": 200, "height": 31}]
    pixels = ramp(10, 100, 31, 200)
    row = wait_for(
        "the pattern's statistics in the list", lambda: shows(browser_page, "dark", pixels)
    )
    assert float(row["std_dn"]) == pytest.approx(float(pixels.std()), abs=0.01)
    assert float(row["sum_dn"]) == float(pixels.sum())
    assert row["saturated"] == "0" and row["bg_mean_dn"] == "-"  # no background captured
    # The outline is painted on the image in the ROI's colour: its left edge at column 100 is
    # CSS pixel 100 of the canvas at 1x from the view's origin, pixel (100 - 90) x 4 = 40 at 4x
    # from column 90 (two device pixels wide, across the border).
    colour = browser_page.evaluate("window.camdLive.roi.colourOf('dark')")
    assert outline_pixel(browser_page, 100, 25) == colour
    set_view(browser_page, 4, 0, 90)
    assert outline_pixel(browser_page, 40, 25 * 4) == colour
    assert outline_pixel(browser_page, 44, 25 * 4) != colour  # inside: the image
    set_view(browser_page, 1, 0, 0)
    # The plot: the daemon's history of the chosen statistic, every frame the pattern's mean.
    history = wait_for(
        "the plotted history",
        lambda: (
            (h := browser_page.evaluate("window.camdLive.roi.plotted('dark')"))
            and len(h) >= 3
            and h
        ),
    )
    assert {round(v, 6) for v in history} == {round(float(pixels.mean()), 6)}
    browser_page.locator("#image-panel").screenshot(path=str(artifacts_dir() / "live-roi.png"))

    # Moved with the mouse: pressed inside it, 5 rows down and 20 columns right.
    drag(browser_page, (20, 200), (25, 220))
    wait_for("the moved ROI", lambda: rois(bench)[0]["x"] == 120)
    assert rois(bench) == [{"name": "dark", "x": 120, "y": 15, "width": 200, "height": 31}]
    wait_for("the moved statistics", lambda: shows(browser_page, "dark", ramp(15, 120, 31, 200)))
    # Edited by number: 50 columns wide.
    width = browser_page.locator('#roi-list tr[data-roi="dark"] input[data-field="width"]')
    width.fill("50")
    width.dispatch_event("change")
    wait_for("the narrower ROI", lambda: rois(bench)[0]["width"] == 50)
    assert rois(bench) == [{"name": "dark", "x": 120, "y": 15, "width": 50, "height": 31}]
    wait_for("the narrower statistics", lambda: shows(browser_page, "dark", ramp(15, 120, 31, 50)))
    # Resized with the mouse: its bottom-right corner (row 45, column 169) pulled to (50, 189).
    drag(browser_page, (45, 169), (50, 189))
    wait_for("the resized ROI", lambda: rois(bench)[0]["width"] == 70)
    assert rois(bench) == [{"name": "dark", "x": 120, "y": 15, "width": 70, "height": 36}]
    wait_for("the resized statistics", lambda: shows(browser_page, "dark", ramp(15, 120, 36, 70)))
    # A rectangle outside the frame: the daemon's message, the ROI unchanged.
    width.fill("5000")
    width.dispatch_event("change")
    wait_for(
        "the refusal",
        lambda: f"outside the 2048 x {ROWS} frame" in browser_page.inner_text("#message"),
    )
    assert rois(bench)[0]["width"] == 70
    browser_page.click("#message")  # read: clicked away
    # A background of the same pattern: the daemon's mean minus the background's over the ROI.
    browser_page.click("#bg-capture")
    wait_for("the background", lambda: "mean of 16 frames" in browser_page.inner_text("#bg-state"))
    wait_for(
        "the background-subtracted mean",
        lambda: listed(browser_page, "dark").get("bg_mean_dn", "-") != "-",
    )
    assert abs(float(listed(browser_page, "dark")["bg_mean_dn"])) < 0.005
    browser_page.click("#bg-clear")
    # Deleted.
    browser_page.click('#roi-list tr[data-roi="dark"] button[data-action="delete"]')
    wait_for("no ROI in the daemon", lambda: rois(bench) == [])
    wait_for("no ROI listed", lambda: browser_page.locator("#roi-list tr[data-roi]").count() == 0)
    browser_page.click("#ctl-stream-stop")
    wait_for("the stream to stop", lambda: browser_page.inner_text("#state") != "state: streaming")
    browser_page.click("#release-control")
    # An ROI defined elsewhere (a script) is listed with its rectangle.
    with bench.client() as client:
        client.take_control()
        client.add_roi("bar", 500, 20, 300, 30)
        client.release_control()
    fields = '#roi-list tr[data-roi="bar"] input[data-field]'
    wait_for("the script's ROI", lambda: browser_page.locator(fields).count() == 4)
    assert [i.input_value() for i in browser_page.locator(fields).all()] == [
        "500",
        "20",
        "300",
        "30",
    ]
    clean(log, expected="status of 4")


def painted(page: Any, channel: str) -> dict[str, Any] | None:
    """The colour on the telemetry plot's canvas at its newest data point (None before one)."""
    return page.evaluate(
        """(channel) => {
            const u = window.camdLive.telemetryPlots?.plots[channel];
            if (!u) return null;
            const mean = u.data[1];
            let i = mean.length - 1;
            while (i >= 0 && mean[i] === null) i--;
            if (i < 0) return null;
            const x = Math.round(u.valToPos(u.data[0][i], 'x', true));
            const y = Math.round(u.valToPos(mean[i], 'y', true));
            return {value: mean[i], colour: Array.from(u.ctx.getImageData(x, y, 1, 1).data)};
        }""",
        channel,
    )


def test_a_telemetry_plot_paints_a_channel_beyond_its_yellow_limit_yellow_and_red_beyond_red(
    bench: Bench, page: tuple[Any, PageLog]
) -> None:
    browser_page, log = page
    open_live(browser_page, log, bench, "viewer")
    for channel in ("fpga_temp_degc", "vcc_core_v", "sensor_temp_degc"):
        browser_page.check(f'#tmp-channels input[value="{channel}"]')
    browser_page.select_option("#tmp-range", "600")
    browser_page.click("#tmp-plot")
    hot = wait_for("a plotted FPGA temperature", lambda: painted(browser_page, "fpga_temp_degc"))
    assert hot["value"] > 1.0  # outside yellow [0, 1] degC, inside red [-20, 200]
    assert hot["colour"] == YELLOW, hot
    fine = wait_for("a plotted core voltage", lambda: painted(browser_page, "vcc_core_v"))
    assert fine["colour"] == OK, fine
    alarm = wait_for(
        "a plotted sensor temperature", lambda: painted(browser_page, "sensor_temp_degc")
    )
    assert alarm["value"] > 2.0 and alarm["colour"] == RED, alarm  # outside red [0, 2] degC
    # The limits drawn: the plot says which, in the unit of the channel.
    legend = browser_page.inner_text('#tmp-plots [data-channel="fpga_temp_degc"] .tmp-title')
    assert re.search(r"yellow 0 \.\. 1 degC, red -20 \.\. 200", legend), legend
    # Drag-zoom on the time axis, then reset to the whole range.
    plot = "window.camdLive.telemetryPlots.plots.fpga_temp_degc"
    whole = browser_page.evaluate(f"[{plot}.scales.x.min, {plot}.scales.x.max]")
    assert whole[1] - whole[0] == pytest.approx(600)  # the range asked, 10 min
    over = browser_page.locator('#tmp-plots [data-channel="fpga_temp_degc"] .u-over').bounding_box()
    y = over["y"] + over["height"] / 2
    browser_page.mouse.move(over["x"] + over["width"] * 0.3, y)
    browser_page.mouse.down()
    browser_page.mouse.move(over["x"] + over["width"] * 0.5, y, steps=4)
    browser_page.mouse.move(over["x"] + over["width"] * 0.7, y, steps=4)
    browser_page.mouse.up()
    zoomed = browser_page.evaluate(f"[{plot}.scales.x.min, {plot}.scales.x.max]")
    assert whole[0] < zoomed[0] < zoomed[1] < whole[1], (whole, zoomed)
    other = "window.camdLive.telemetryPlots.plots.vcc_core_v"
    assert browser_page.evaluate(f"[{other}.scales.x.min, {other}.scales.x.max]") == zoomed
    browser_page.click("#tmp-reset")
    reset = browser_page.evaluate(
        f"[{plot}.scales.x.min, {plot}.scales.x.max, ...window.camdLive.telemetryPlots.range]"
    )
    assert reset[:2] == reset[2:] and reset[3] - reset[2] == pytest.approx(600), reset
    # A custom range as the API takes it: the last 5 minutes; a time it cannot read, its message.
    browser_page.select_option("#tmp-range", "custom")
    browser_page.fill("#tmp-start", "-5m")
    browser_page.click("#tmp-plot")
    wait_for(
        "the 5-minute range",
        lambda: (
            browser_page.evaluate("(r => r[1] - r[0])(window.camdLive.telemetryPlots.range)")
            == pytest.approx(300)
        ),
    )
    browser_page.fill("#tmp-start", "yesterday")
    browser_page.click("#tmp-plot")
    note = wait_for_text(browser_page, "the refusal", "#tmp-note", "telemetry history:")
    assert "yesterday" in note, note
    browser_page.select_option("#tmp-range", "600")
    wait_for("the plots again", lambda: painted(browser_page, "fpga_temp_degc"))
    browser_page.locator("#telemetry-plots").screenshot(
        path=str(artifacts_dir() / "live-telemetry-plots.png")
    )
    clean(log, expected="status of 400")
