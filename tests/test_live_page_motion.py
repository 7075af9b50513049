"""The live page's motion panel (issue 35: "the measured dV/V, M dV/V and theta shown on the live
page beside the encoder's figure") in a real browser: Debian's chromium driven by Playwright,
against one daemon on the simulated hr400 (a 64-row window).

- Before any TDI frame the panel says nothing was measured yet.
- A TDI scan of a natural texture whose optics carry a 1 % magnification error and whose camera
  is turned 0.5 degrees (as tests/test_image_motion_live.py): the page shows the newest block's
  dV/V, its standard error, M dV/V, M and theta, the scan's means over its measurable blocks and
  "no encoder" (the simulator's ideal stage latches none), each the very figure of
  ``GET /api/v1/live/motion`` and ``GET /api/v1/scan`` to the digits shown; and the figures are
  the scene's (dV/V = -e, theta = r), so a panel showing another field would fail.
- A driven stage 4 % slow: the encoder's last, max and RMS M |dV/V| and its level (yellow,
  coloured as the telemetry's) beside the image's M dV/V, both the stage's 1.28 px of smear.
- A flat field has no texture to register: the page shows the block's reason, no numbers.

Not ``exclusive``: each value is waited for with a generous timeout; a busy machine makes the
page slower, not wrong.
"""

from __future__ import annotations

import re
import time
from collections.abc import Iterator
from typing import Any

import pytest

from camd.client_types import ImageMotionBlock, ScanResponse
from tests.browser import PageLog
from tests.test_live_page import Bench, back_to_idle, clean, live_bench, open_live, shot, wait_for

MAGNIFICATION_ERROR = 0.01
ROTATION_DEG = 0.5
STAGES = 32
LINES = 1500
LINE_PERIOD_S = 2e-3
SCENE = f"natural:photons=1e9,magnification_error={MAGNIFICATION_ERROR},rotation_deg={ROTATION_DEG}"
FLAT = "flat:photons=1e9"
DRIVEN_DV_OVER_V = 0.04  # the stage 4 % slow: M dV/V = 1.28 px at M = 32, past yellow (1)
NOTHING_YET = (
    "no TDI frames measured yet: the image's motion is measured from TDI streams and scans"
)


@pytest.fixture(scope="module")
def bench(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Bench]:
    with live_bench(tmp_path_factory.mktemp("camd-live-page-motion")) as bench:
        yield bench


@pytest.fixture(autouse=True)
def idle(bench: Bench) -> Iterator[None]:
    """Each test ends with nothing streaming or scanning and the scene flat again."""
    yield
    back_to_idle(bench)
    with bench.client() as client:
        client.take_control(force=True)
        client.set_scene("flat")
        client.release_control()


def fixed(value: float | None, digits: int = 3) -> str:
    """As the page writes a figure (JavaScript's toFixed: the same decimal rounding of the
    same double as Python's format, but at an exact tie, which a measured figure never is)."""
    return "-" if value is None else f"{value:.{digits}f}"


def percent(value: float | None) -> str:
    return "-" if value is None else f"{100 * value:.3f}"


def text(page: Any, element: str) -> str:
    """An element's text, shown or hidden (textContent)."""
    return str(page.text_content(f"#{element}")).strip()


def scan_to_the_end(bench: Bench, scene: str) -> tuple[ScanResponse, ImageMotionBlock]:
    """A TDI scan of ``scene`` on the simulator's ideal stage, to its end; the scan's document
    and the monitor's newest block once it no longer changes."""
    with bench.client() as client:
        client.take_control(force=True)
        client.start_scan(
            STAGES, LINES, scene=scene, line_period_s=LINE_PERIOD_S, drive_stage=False
        )
        doc = client.wait_scan(timeout_s=300)
        client.release_control()
        assert doc["state"] == "done", doc["error"]
        latest = client.image_motion()["latest"]
        assert latest is not None
        assert client.scan()["image_motion"] == doc["image_motion"]  # settled
    return doc, latest


def shown_block(page: Any) -> str:
    """The frame counters of the block the page shows (its age line)."""
    return text(page, "mo-age")


def shown_at_the_end(page: Any, frames: str) -> None:
    """Wait until the page shows the scan's last block and its document once done."""
    wait_for("the scan's last block", lambda: frames in shown_block(page))
    wait_for("the scan's end", lambda: page.evaluate("window.camdLive.motionScan?.state") == "done")


def test_the_panel_shows_the_image_and_the_encoder_figures_the_api_gives(
    bench: Bench, page: tuple[Any, PageLog]
) -> None:
    browser_page, log = page
    with bench.client() as client:
        assert client.image_motion()["latest"] is None  # a fresh daemon: nothing measured
    open_live(browser_page, log, bench, "viewer")
    assert text(browser_page, "mo-note") == NOTHING_YET
    assert browser_page.is_hidden("#mo-table") and browser_page.is_hidden("#mo-scan")
    assert text(browser_page, "mo-enc-state") == "no scan"

    doc, latest = scan_to_the_end(bench, SCENE)
    frames = f"(frames {latest['counter_first']}-{latest['counter_last']})"
    shown_at_the_end(browser_page, frames)
    image = doc["image_motion"]
    assert image is not None and image["latest"] == latest
    # The scene's motion, so the figures compared below are the right ones: the image runs
    # ahead by the magnification error, dV/V = -e, and drifts at the camera's turn
    # (docs/physics.md §10; tests/test_image_motion_live.py).
    assert latest["measurable"] and image["measurable_blocks"] >= 2
    assert latest["dv_over_v"] == pytest.approx(-MAGNIFICATION_ERROR, abs=0.5 * MAGNIFICATION_ERROR)
    assert latest["theta_deg"] == pytest.approx(ROTATION_DEG, abs=0.15)
    assert latest["stages"] == STAGES

    # The newest block, to the digits shown.
    assert browser_page.is_visible("#mo-table")
    assert text(browser_page, "mo-dv") == percent(latest["dv_over_v"])
    assert text(browser_page, "mo-dv-err") == percent(latest["dv_over_v_stderr"])
    assert text(browser_page, "mo-mdv") == fixed(latest["m_dv_over_v"])
    assert text(browser_page, "mo-stages") == str(STAGES)
    assert text(browser_page, "mo-theta") == fixed(latest["theta_deg"])
    assert text(browser_page, "mo-note") == latest["why"]
    # Its age: whole seconds between the measurement and the page's last poll, so at most the
    # time since the measurement now.
    age = re.fullmatch(r"measured (\d+) s ago " + re.escape(frames), shown_block(browser_page))
    assert age is not None, shown_block(browser_page)
    assert 0 <= int(age.group(1)) <= round(time.time() - latest["measured_t_s"]) + 1

    # The scan's means over its measurable blocks.
    assert browser_page.is_visible("#mo-scan-table")
    assert text(browser_page, "mo-scan-blocks") == (
        f"mean over {image['measurable_blocks']} blocks (of {image['blocks']} measured)"
    )
    assert text(browser_page, "mo-scan-dv") == percent(image["dv_over_v_mean"])
    assert text(browser_page, "mo-scan-dv-sem") == percent(image["dv_over_v_sem"])
    assert text(browser_page, "mo-scan-mdv") == fixed(image["m_dv_over_v_mean"])
    assert text(browser_page, "mo-scan-theta") == fixed(image["theta_deg_mean"])

    # The simulator's ideal stage (not driven) has no encoder in the frame headers.
    assert doc["mismatch_max"] is None
    encoder_check(browser_page, doc)
    shot(browser_page, "motion")
    clean(log)


def encoder_check(page: Any, doc: ScanResponse) -> None:
    """The encoder's column shows the scan document's figures (or says there are none)."""
    if doc["mismatch_max"] is None:
        assert text(page, "mo-enc-state") == "no encoder"
        for element in ("mo-enc-last", "mo-enc-max", "mo-enc-rms", "mo-enc-level"):
            assert text(page, element) == "-"
        return
    assert text(page, "mo-enc-state") == "scan done"
    assert text(page, "mo-enc-last") == fixed(doc["mismatch_last"])
    assert text(page, "mo-enc-max") == fixed(doc["mismatch_max"])
    assert text(page, "mo-enc-rms") == fixed(doc["mismatch_rms"])
    assert text(page, "mo-enc-level") == doc["mismatch_level"]
    level_class = page.get_attribute("#mo-enc-level-row", "class")
    assert level_class == f"level-{doc['mismatch_level']}"


def test_a_flat_field_shows_why_it_is_not_measurable(
    bench: Bench, page: tuple[Any, PageLog]
) -> None:
    browser_page, log = page
    open_live(browser_page, log, bench, "viewer")
    doc, latest = scan_to_the_end(bench, FLAT)
    frames = f"(frames {latest['counter_first']}-{latest['counter_last']})"
    shown_at_the_end(browser_page, frames)
    image = doc["image_motion"]
    assert image is not None
    # No texture, nothing to register: no block of the scan is measurable.
    assert not latest["measurable"] and latest["dv_over_v"] is None
    assert image["blocks"] >= 1 and image["measurable_blocks"] == 0
    assert latest["why"]
    assert text(browser_page, "mo-note") == f"not measurable: {latest['why']}"
    assert browser_page.is_hidden("#mo-table")
    for element in ("mo-dv", "mo-dv-err", "mo-mdv", "mo-theta"):
        assert text(browser_page, element) == "-"
    assert text(browser_page, "mo-scan-blocks") == (
        f"none of its {image['blocks']} blocks measurable"
    )
    assert browser_page.is_hidden("#mo-scan-table")
    for element in ("mo-scan-dv", "mo-scan-dv-sem", "mo-scan-mdv", "mo-scan-theta"):
        assert text(browser_page, element) == "-"
    shot(browser_page, "motion-flat")
    clean(log)


def test_a_driven_stage_shows_the_encoders_figure_beside_the_images(
    bench: Bench, page: tuple[Any, PageLog]
) -> None:
    browser_page, log = page
    open_live(browser_page, log, bench, "viewer")
    with bench.client() as client:
        client.take_control(force=True)
        client.start_scan(
            STAGES, LINES, scene="natural:photons=1e9", line_period_s=LINE_PERIOD_S,
            dv_over_v=DRIVEN_DV_OVER_V,
        )  # fmt: skip
        doc = client.wait_scan(timeout_s=300)
        client.release_control()
        assert doc["state"] == "done", doc["error"]
        latest = client.image_motion()["latest"]
        assert latest is not None
    frames = f"(frames {latest['counter_first']}-{latest['counter_last']})"
    shown_at_the_end(browser_page, frames)
    # The stage runs (1 - dV/V) x the synchronous speed: the encoder sees M dV/V = 1.28 px of
    # smear per line (docs/physics.md §6), the image the same slip from the frames (§10); past
    # the yellow limit 1 (motion.yellow), so the level is yellow. Measured over two runs:
    # encoder RMS 1.276, 1.279; last (the largest line of the last batch) 1.282, 1.318; max
    # 1.41, 1.46; image 1.31, 1.30.
    smear = STAGES * DRIVEN_DV_OVER_V
    assert doc["mismatch_rms"] == pytest.approx(smear, abs=0.05)
    assert doc["mismatch_last"] == pytest.approx(smear, abs=0.15)
    assert doc["mismatch_level"] == "yellow"
    assert latest["measurable"]
    assert latest["m_dv_over_v"] == pytest.approx(smear, abs=0.1)
    encoder_check(browser_page, doc)
    row = browser_page.locator("#mo-enc-level-row")
    assert row.evaluate("r => getComputedStyle(r).backgroundColor") == "rgb(249, 168, 37)"
    assert text(browser_page, "mo-mdv") == fixed(latest["m_dv_over_v"])
    assert text(browser_page, "mo-dv") == percent(latest["dv_over_v"])
    shot(browser_page, "motion-driven")
    clean(log)
