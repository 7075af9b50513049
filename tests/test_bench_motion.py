"""``camd bench motion`` on the smallest settings that run both parts: the figures it reports
are what they say they are.

No timing threshold: the CPU times are whatever the machine gives; what is checked is how the
figures follow from them, and that the daemon measured blocks with the measurement on and none
with it off.
"""

from __future__ import annotations

import argparse
import json

import pytest

from camd.bench.motion import block_figures, motion_config, run
from camd.pipeline.image_motion import _offsets

ROW_S = 513 / 25e6  # hr400's T_row: 513 clocks of 25 MHz


def args(**overrides: object) -> argparse.Namespace:
    values: dict[str, object] = {
        "parts": ("cost", "scan"), "stages": 32, "frames_per_block": 6, "columns_max": 64,
        "cpu_fraction": 0.25, "widths": None, "blocks": 2, "repeat": 1,
        "scene": "natural:photons=1e9,magnification_error=0.005", "lines": 300,
        "frame_bank": 16, "rounds": 1, "json": True,
    }  # fmt: skip
    values.update(overrides)
    return argparse.Namespace(**values)


def test_budget_figures_follow_from_the_cpu_per_block() -> None:
    # 40 ms a block of 16 frames spanning 77 lines of 1.97 ms (151.7 ms): a quarter core's
    # budget starts a block every 151.7 + 40 / 0.25 = 311.7 ms.
    line_s = 96 * ROW_S
    f = block_figures(0.040, 16, 77, line_s, 0.25)
    assert f["cpu_s_per_frame"] == pytest.approx(0.0025)
    assert f["block_span_s"] == pytest.approx(77 * line_s)
    assert f["core_fraction_every_block"] == pytest.approx(0.040 / (77 * line_s))
    assert f["budget_block_period_s"] == pytest.approx(77 * line_s + 0.160)
    assert f["budget_frames_measured_fraction"] == pytest.approx(16 * line_s / (77 * line_s + 0.16))
    assert f["budget_core_fraction"] == pytest.approx(0.040 / (77 * line_s + 0.16))
    assert f["budget_core_fraction"] < 0.25


def test_the_daemons_motion_section_differs_only_in_image_measure() -> None:
    on, off = motion_config(True, 16, 512, 0.25), motion_config(False, 16, 512, 0.25)
    assert on.replace("image_measure = true", "image_measure = false") == off
    assert on.splitlines() == [
        "[motion]", "image_measure = true", "image_frames_per_block = 16",
        "image_columns_max = 512", "image_cpu_fraction = 0.25",
    ]  # fmt: skip


def test_both_parts_on_the_smallest_settings(capsys: pytest.CaptureFixture[str]) -> None:
    assert run(args()) == 0
    doc = json.loads(capsys.readouterr().out)
    cost = doc["cost"]
    offsets = _offsets(32, 6)
    assert cost["offsets"] == list(offsets) and cost["frames_per_block"] == 6
    assert cost["block_span_lines"] == offsets[-1] + 1
    assert cost["line_period_s"] == pytest.approx(32 * ROW_S, rel=1e-9)
    assert [c["columns"] for c in cost["widths"]] == [64, 2048]
    for c in cost["widths"]:
        per_block = c["cpu_s_per_block"]
        assert c["cpu_s_per_block_range"][0] <= per_block <= c["cpu_s_per_block_range"][1]
        assert c["cpu_s_per_frame"] == pytest.approx(per_block / 6)
        span_s = cost["block_span_lines"] * 32 * ROW_S
        assert c["core_fraction_every_block"] == pytest.approx(per_block / span_s)
        assert c["measurable"] and c["pairs"] == 5  # a textured scene: every pair registered
    scan = doc["scan"]
    (off,), (on,) = scan["off"], scan["on"]
    assert (off["blocks_measured"], off["frames_measured"], off["motion_cpu_s"]) == (0, 0, 0.0)
    assert on["blocks_measured"] > 0 and on["motion_cpu_s"] > 0
    # A block is at most frames_per_block frames, of the frames the streams delivered.
    assert on["blocks_measured"] * 3 <= on["frames_measured"] <= on["blocks_measured"] * 6
    assert on["frames_measured"] <= on["tdi_frames_seen"]
    # The scan streams its lines and the M - 1 lines that fill the window first.
    assert off["lines"] == on["lines"] == 300 + 31
    assert scan["ratio"] == pytest.approx(on["lines_per_s"] / off["lines_per_s"], rel=1e-4)
    assert scan["stream_ratio"] == pytest.approx(
        on["stream_frames_per_s"] / off["stream_frames_per_s"], rel=1e-4
    )
    assert scan["meets_goal"] == (scan["ratio"] >= 0.95)


def test_bad_options_are_refused(capsys: pytest.CaptureFixture[str]) -> None:
    assert run(args(frames_per_block=2, rounds=0)) == 2
    assert capsys.readouterr().out == (
        "camd bench motion: give --stages >= 1, --frames-per-block >= 3, --columns-max >= 16; "
        "--blocks, --repeat, --lines and --rounds >= 1\n"
    )
