"""The live view page (/live) in a real browser: Debian's chromium driven by Playwright.

One daemon on the simulated hr400 with a token (the page carries it in its cookie) and a
64-row window serves most tests; the waterfall test has a second daemon whose simulated stream
drops frames. Each test checks values that could be wrong: the readout against the sensor's
ramp test pattern ((row + col) mod 4096 at every pixel), the background-subtracted flat field
against 0 DN, the waterfall's red lines against the scan file's completeness flags, and the
telemetry row's colour against a limit the simulator's value is outside of. Screenshots of each
state go to test-artifacts/ (tests/browser.py).
"""

from __future__ import annotations

import contextlib
import math
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import h5py
import httpx
import numpy as np
import pytest

from camd.cli._daemon_proc import DaemonProcess
from camd.client import CamdClient
from tests.browser import PageLog, artifacts_dir

# Not ``exclusive``: what the page shows (pixel values, colours, the waterfall's marks against
# the file, who holds control), each waited for with a generous timeout; a busy machine makes
# the page slower, not wrong. Checked beside `stress-ng --cpu 2`.

TOKEN = "live-s3cret"
ROWS = 64
WORD_BITS = 12  # hr400's output words: the ramp wraps at 4096
TESTER = "tester@bench"  # the test's own client name (X-Camd-Client)
# fpga_temp_degc's yellow range made to exclude the simulator's temperature, red kept wide.
CONFIG = """
[sensor]
name = "hr400"
bridge = "fpga"

[telemetry.limits.fpga_temp_degc]
yellow = [0.0, 1.0]
red = [-20.0, 200.0]
"""


@dataclass
class Bench:
    url: str
    data_dir: Path

    def client(self, name: str = TESTER) -> CamdClient:
        return CamdClient(self.url, token=TOKEN, client=name)


@contextlib.contextmanager
def live_bench(tmp: Path, config_text: str = CONFIG) -> Iterator[Bench]:
    """A daemon in ``tmp`` on ``config_text`` with the token, its window ROWS rows (also for
    tests/test_live_page_roi.py)."""
    config = tmp / "camd.toml"
    config.write_text(config_text)
    with DaemonProcess(
        tmp, extra_args=["--config", str(config)], env={"CAMD_TOKEN": TOKEN}
    ) as daemon:
        bench = Bench(daemon.url, tmp)
        with bench.client() as client:
            client.wait_ready(60)
            client.write_registers({"WIN_ROWS": ROWS, "EXPOSURE": 4})
        yield bench
    assert daemon.exit_code in (0, -15), daemon.log_path.read_text()


@pytest.fixture(scope="module")
def bench(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Bench]:
    with live_bench(tmp_path_factory.mktemp("camd-live-page")) as bench:
        yield bench


def back_to_idle(bench: Bench) -> None:
    """Nothing streaming or scanning, no ROI, the test pattern off and nobody in control."""
    with bench.client() as client:
        client.take_control(force=True)
        client.stop_stream()
        client.stop_scan()
        for roi in client.rois()["rois"]:
            client.delete_roi(roi["name"])
        client.write_registers({"TEST_PATTERN.mode": "off"})
        client.release_control()


@pytest.fixture(autouse=True)
def idle(bench: Bench) -> Iterator[None]:
    """Each test starts and ends with nothing streaming and nobody in control."""
    yield
    back_to_idle(bench)


def wait_for(what: str, predicate: Callable[[], Any], timeout_s: float = 60.0) -> Any:
    """Poll until ``predicate()`` is truthy; fail naming ``what`` (generous: a busy machine)."""
    deadline = time.monotonic() + timeout_s
    while True:
        value = predicate()
        if value:
            return value
        if time.monotonic() > deadline:
            pytest.fail(f"timed out after {timeout_s} s waiting for {what}")
        time.sleep(0.1)


def wait_for_text(page: Any, what: str, selector: str, prefix: str) -> str:
    """The text of ``selector`` once it starts with ``prefix``."""
    text: str = wait_for(
        what,
        lambda: (shown := page.inner_text(selector)).startswith(prefix) and shown,
    )
    return text


def open_live(page: Any, log: PageLog, bench: Bench, client: str) -> Any:
    """Open /live as a browser would the first time: with ?token=, which becomes a cookie."""
    page.goto(f"{bench.url}/live?token={TOKEN}&client={client}")
    assert page.url == f"{bench.url}/live?client={client}"  # the token left the address
    wait_for("the page's first status poll", lambda: page.evaluate("window.camdLive?.polls ?? 0"))
    return page


def frames_shown(page: Any) -> int:
    return int(page.evaluate("window.camdLive.framesShown"))


def counter_shown(page: Any) -> int:
    return int(page.evaluate("window.camdLive.lastMeta?.counter ?? -1"))


def clean(log: PageLog, expected: str | None = None) -> None:
    """No console errors (but the browser's note of an ``expected`` refusal) and no request
    leaving loopback."""
    assert [e for e in log.errors if expected is None or expected not in e] == []
    assert log.off_loopback() == []


def shot(page: Any, name: str) -> None:
    page.screenshot(path=str(artifacts_dir() / f"live-{name}.png"), full_page=True)


# -- the page, its token and the live image -------------------------------------------------------


def test_without_the_token_the_page_is_refused_and_says_how(bench: Bench) -> None:
    with httpx.Client(base_url=bench.url, timeout=30) as http:
        refused = http.get("/live")
        assert refused.status_code == 401
        assert "open /live?token=<token> once" in refused.json()["error"]
        assert http.get("/live?token=wrong").status_code == 401
        opened = http.get(f"/live?token={TOKEN}", follow_redirects=False)
        assert opened.status_code == 303 and opened.headers["location"] == "/live"
        named = http.get(f"/live?client=bench+2&token={TOKEN}", follow_redirects=False)
        assert named.headers["location"] == "/live?client=bench+2"  # the rest kept, encoded
        assert "camd_token=" in opened.headers["set-cookie"]
        assert "HttpOnly" in opened.headers["set-cookie"]
        assert "SameSite=strict" in opened.headers["set-cookie"]
        # the cookie alone now opens the page, its scripts and the API
        assert http.get("/live").status_code == 200
        assert http.get("/static/live/main.js").status_code == 200
        assert http.get("/api/v1/status").status_code == 200


def test_the_page_loads_clean_and_the_image_follows_the_stream(
    bench: Bench, page: tuple[Any, PageLog]
) -> None:
    browser_page, log = page
    with bench.client() as client:
        client.start_stream(frames=0)
        open_live(browser_page, log, bench, "viewer")
        wait_for("3 frames shown", lambda: frames_shown(browser_page) >= 3)
        first = counter_shown(browser_page)
        wait_for("a newer frame", lambda: counter_shown(browser_page) > first)
        info = browser_page.inner_text("#frame-info")
        assert f"{ROWS}x2048" in info and "area" in info and "skipped" in info
        # The stream runs far faster than 20 frames a second: the page says what it skipped.
        skipped = int(browser_page.evaluate("window.camdLive.skippedTotal"))
        assert skipped > 0 and " in all)" in info
        assert browser_page.inner_text("#state") == "state: streaming"
        shot(browser_page, "stream")
        client.stop_stream()
    clean(log)


def move_to_pixel(page: Any, row: int, col: int) -> dict[str, str]:
    """Put the mouse over image pixel (row, col) given the page's zoom and view origin, and
    read the readout."""
    zoom = int(page.input_value("#zoom"))
    top = int(page.input_value("#origin-row"))
    left = int(page.input_value("#origin-col"))
    page.locator("#image").scroll_into_view_if_needed()
    box = page.locator("#image").bounding_box()
    # Chromium gives mouse events whole CSS pixels: the first whole pixel inside the image
    # pixel (the canvas may sit at a fractional offset).
    x = math.ceil(box["x"] + (col - left) * zoom)
    y = math.ceil(box["y"] + (row - top) * zoom)
    assert x < box["x"] + (col - left + 1) * zoom and y < box["y"] + (row - top + 1) * zoom
    assert box["x"] <= x < box["x"] + box["width"] and box["y"] <= y < box["y"] + box["height"]
    page.mouse.move(x, y)
    return {key: page.inner_text(f"#px-{key}") for key in ("row", "col", "raw", "sub")}


def set_view(page: Any, zoom: int, top: int, left: int) -> None:
    page.select_option("#zoom", str(zoom))
    page.fill("#origin-row", str(top))
    page.dispatch_event("#origin-row", "change")
    page.fill("#origin-col", str(left))
    page.dispatch_event("#origin-col", "change")


@pytest.mark.parametrize(
    ("zoom", "top", "left"), [(1, 0, 0), (1, 0, 700), (4, 0, 123), (12, 15, 1000), (16, 31, 1990)]
)
def test_the_pixel_readout_gives_the_test_patterns_row_column_and_dn(
    bench: Bench, page: tuple[Any, PageLog], zoom: int, top: int, left: int
) -> None:
    browser_page, log = page
    with bench.client() as client:
        client.write_registers({"TEST_PATTERN.mode": "ramp"})
        client.start_stream(frames=0)
        open_live(browser_page, log, bench, "viewer")
        wait_for("a frame", lambda: frames_shown(browser_page) >= 1)
        set_view(browser_page, zoom, top, left)
        # The view went where it was asked (each case leaves the image filling the canvas: the
        # 64 rows pan only from 9x up, on a 540-pixel canvas).
        assert int(browser_page.input_value("#origin-row")) == top
        assert int(browser_page.input_value("#origin-col")) == left
        box = browser_page.locator("#image").bounding_box()
        rows_seen = min(int(box["height"] // zoom), ROWS - top)
        cols_seen = int(box["width"] // zoom)
        for dr, dc in [
            (0, 0),
            (rows_seen - 1, cols_seen - 1),
            (rows_seen // 2, 7),
            (3, cols_seen // 3),
        ]:
            row, col = top + dr, left + dc
            readout = move_to_pixel(browser_page, row, col)
            expected = (row + col) % (1 << WORD_BITS)
            assert readout == {"row": str(row), "col": str(col), "raw": str(expected), "sub": "-"}
        shot(browser_page, f"readout-zoom{zoom}")
        client.stop_stream()
    clean(log)


# -- control, background, waterfall, telemetry ----------------------------------------------------


def take_control_on_page(page: Any) -> None:
    page.click("#take-control")
    wait_for("the page to hold control", lambda: page.is_hidden("#readonly"))
    assert page.is_enabled("#ctl-stream-start")


def test_background_subtraction_of_a_flat_scene_reads_zero(
    bench: Bench, page: tuple[Any, PageLog]
) -> None:
    browser_page, log = page
    with bench.client() as client:
        client.set_scene("flat")  # a quarter of the output range
    open_live(browser_page, log, bench, "operator")
    take_control_on_page(browser_page)
    browser_page.click("#ctl-stream-start")
    wait_for("frames", lambda: frames_shown(browser_page) >= 2)
    raw_mean = float(browser_page.inner_text("#raw-mean"))
    raw_std = float(browser_page.inner_text("#raw-std"))
    assert raw_mean > 500  # a lit flat field (black level 100 DN): something to remove
    browser_page.fill("#bg-frames", "16")
    browser_page.click("#bg-capture")
    wait_for("the background", lambda: "mean of 16 frames" in browser_page.inner_text("#bg-state"))
    browser_page.check("#bg-subtract")
    shown = frames_shown(browser_page)
    wait_for("two frames after the background", lambda: frames_shown(browser_page) >= shown + 2)
    sub_mean = float(browser_page.inner_text("#sub-mean"))
    sub_std = float(browser_page.inner_text("#sub-std"))
    # A flat field minus its own mean: ~0 DN on average; the per-pixel spread is the frame's
    # temporal noise (sqrt(1 + 1/16) of it), far below the lit level.
    assert abs(sub_mean) < 0.5, sub_mean
    assert 0 < sub_std < raw_mean / 10
    assert sub_std < 2 * max(raw_std, 1.0)
    readout = move_to_pixel(browser_page, 20, 300)
    assert readout["row"] == "20" and readout["col"] == "300", readout
    assert abs(float(readout["sub"])) < 6 * sub_std
    assert abs(int(readout["raw"]) - raw_mean) < 6 * max(raw_std, sub_std) + 1
    shot(browser_page, "background")
    browser_page.click("#ctl-stream-stop")
    wait_for("the stream to stop", lambda: browser_page.inner_text("#state") != "state: streaming")
    clean(log)


def test_an_observer_page_cannot_start_a_scan(bench: Bench, page: tuple[Any, PageLog]) -> None:
    browser_page, log = page
    with bench.client() as client:
        client.take_control(ttl_s=120)
        open_live(browser_page, log, bench, "observer")
        wait_for("the read-only banner", lambda: browser_page.is_visible("#readonly"))
        assert f"{TESTER} holds control" in browser_page.inner_text("#readonly")
        for button in ("#ctl-scan-start", "#ctl-stream-start", "#ctl-mode-set", "#bg-capture"):
            assert browser_page.is_disabled(button), button
        assert browser_page.is_enabled("#estop")  # never refused, whoever holds control
        before = client.scan()
        # Even asked directly, under the page's client name, the daemon refuses.
        answer = browser_page.evaluate(
            """async () => {
                const r = await fetch('/api/v1/scan/start', {method: 'POST',
                  headers: {'Content-Type': 'application/json', 'X-Camd-Client': 'observer'},
                  body: JSON.stringify({stages: 4, lines: 10})});
                return [r.status, await r.json()];
            }"""
        )
        assert answer[0] == 423 and answer[1]["code"] == "not_in_control"
        assert TESTER in answer[1]["error"]
        assert client.scan() == before
        shot(browser_page, "observer")
        client.release_control()
    clean(log, expected="status of 423")


def test_telemetry_beyond_its_yellow_limit_shows_yellow(
    bench: Bench, page: tuple[Any, PageLog]
) -> None:
    browser_page, log = page
    open_live(browser_page, log, bench, "viewer")
    row = browser_page.locator("#tm-fpga_temp_degc")
    wait_for("the FPGA temperature row", lambda: row.count() == 1)
    assert row.get_attribute("class") == "level-yellow"
    value = float(row.locator("td.value").inner_text().split()[0])
    assert value > 1.0  # outside [0, 1] degC, inside the red range
    # Painted yellow (the stylesheet's --yellow, #f9a825), not just named.
    colour = row.evaluate("r => getComputedStyle(r).backgroundColor")
    assert colour == "rgb(249, 168, 37)"
    ok_row = browser_page.locator("#tm-vcc_core_v")
    assert ok_row.get_attribute("class") == "level-ok"
    assert ok_row.evaluate("r => getComputedStyle(r).backgroundColor") == "rgba(0, 0, 0, 0)"
    shot(browser_page, "telemetry")
    clean(log)


@pytest.fixture(scope="module")
def lossy_bench(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Bench]:
    """A daemon whose simulated stream drops 1 % of the frames (no token: the open case)."""
    tmp = tmp_path_factory.mktemp("camd-live-lossy")
    with DaemonProcess(tmp, inject="frame_drop=0.01", env={"CAMD_TOKEN": ""}) as daemon:
        bench = Bench(daemon.url, tmp)
        with bench.client() as client:
            client.wait_ready(60)
            client.write_registers({"WIN_ROWS": 16, "EXPOSURE": 4})
        yield bench
    assert daemon.exit_code in (0, -15), daemon.log_path.read_text()


def test_the_waterfall_grows_and_marks_a_dropped_frames_lines_incomplete(
    lossy_bench: Bench, page: tuple[Any, PageLog], tmp_path: Path
) -> None:
    browser_page, log = page
    browser_page.goto(f"{lossy_bench.url}/live?client=viewer")
    wait_for(
        "the page's first status poll", lambda: browser_page.evaluate("window.camdLive?.polls ?? 0")
    )
    out = tmp_path / "scan.h5"
    with lossy_bench.client() as client:
        client.start_scan(4, 1500, out=str(out), line_period_s=3e-3)
        lines = lambda: int(browser_page.evaluate("window.camdLive.waterfall.lines"))  # noqa: E731
        first = wait_for("the first lines", lines)
        wait_for("more lines while the scan runs", lambda: lines() > first)
        client.wait_scan(120)
    wait_for("the last lines", lambda: "done" in browser_page.inner_text("#wf-scan"))
    with h5py.File(out, "r") as f:
        complete = np.asarray(f["complete"], dtype=bool)
        line_index = np.asarray(f["line_index"])
    incomplete_in_file = set(line_index[~complete].tolist())
    assert incomplete_in_file  # 1 % of 1500 frames dropped: some lines lack stages
    shown = browser_page.evaluate("window.camdLive.waterfall.incomplete")
    assert shown and set(shown) <= incomplete_in_file
    # The newest incomplete line still on screen is painted red in the gutter.
    rows = [browser_page.evaluate(f"window.camdLive.waterfall.rowOf({i})") for i in shown]
    on_screen = [(i, r) for i, r in zip(shown, rows, strict=True) if r is not None]
    assert on_screen
    index, row = on_screen[-1]
    gutter = browser_page.evaluate(
        f"Array.from(document.getElementById('waterfall').getContext('2d')"
        f".getImageData(1, {row}, 1, 1).data)"
    )
    assert gutter == [255, 40, 40, 255], (index, row, gutter)
    shot(browser_page, "waterfall")
    clean(log)


def test_with_control_the_page_sets_mode_and_exposure(
    bench: Bench, page: tuple[Any, PageLog]
) -> None:
    browser_page, log = page
    open_live(browser_page, log, bench, "operator")
    take_control_on_page(browser_page)
    wait_for("the exposure now", lambda: "now 4 lines" in browser_page.inner_text("#exposure-now"))
    browser_page.select_option("#ctl-mode", "tdi")
    browser_page.click("#ctl-mode-set")
    wait_for("the mode badge", lambda: browser_page.inner_text("#mode") == "mode: tdi")
    browser_page.fill("#ctl-exposure", "9")
    browser_page.click("#ctl-exposure-set")
    wait_for("the new exposure", lambda: "now 9 lines" in browser_page.inner_text("#exposure-now"))
    with bench.client() as client:
        assert client.status()["mode"] == "tdi"
        timing = client.timing()
        assert timing["exposure_lines"] == 9 and timing["exposure_register"] == "EXPOSURE"
        assert client.read_register("EXPOSURE")["value"] == 9
        # A refusal is shown with the daemon's message, and changes nothing: 0 lines is out of
        # the register's range.
        browser_page.fill("#ctl-exposure", "0")
        browser_page.click("#ctl-exposure-set")
        refusal = wait_for_text(browser_page, "the refusal", "#message", "set exposure 0")
        assert "out of range" in refusal or "1..1048575" in refusal, refusal
        assert client.read_register("EXPOSURE")["value"] == 9
        client.take_control(force=True)
        client.write_registers({"EXPOSURE": 4})
        client.set_mode("area")
        client.release_control()
    clean(log, expected="status of 400")


def test_the_page_shows_what_the_controlling_client_is_doing(
    bench: Bench, page: tuple[Any, PageLog]
) -> None:
    browser_page, log = page
    with bench.client("campaign runner") as client:
        client.take_control()
        client.set_activity("campaign example_stare: step 3/12 acquire dark", done=2, total=12)
        open_live(browser_page, log, bench, "viewer")
        wait_for("the activity", lambda: browser_page.inner_text("#activity"))
        assert browser_page.inner_text("#activity") == (
            "campaign example_stare: step 3/12 acquire dark (2/12)"
        )
        assert browser_page.inner_text("#control") == "control: campaign runner"
        client.release_control()
    wait_for("the activity to clear", lambda: browser_page.inner_text("#activity") == "")
    clean(log)
