"""``camd bench live`` runs and reports sane figures (never a timing threshold: that is the
benchmark's job, not a test's)."""

from __future__ import annotations

import argparse
import json
import subprocess
import sys

import pytest

from camd.bench import live as bench_live
from camd.bench import live_viewers

# Not ``exclusive``: no figure is held to a rate (the benchmark's job, not a test's); the
# checks are that the figures add up, which a busy machine changes nothing of. Checked beside
# `stress-ng --cpu 2`.


def test_one_short_round_with_websocket_viewers() -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "camd", "bench", "live", "--viewer-kind", "ws",
         "--rounds", "1", "--seconds", "1", "--viewers", "2", "--json"],
        capture_output=True, text=True, timeout=240, check=False,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stdout + proc.stderr
    result = json.loads(proc.stdout)
    assert (result["viewer_kind"], result["viewers"], result["rounds"]) == ("ws", 2, 1)
    assert result["viewer_kind_why"] == "--viewer-kind ws" and result["deflate_offered"] is True
    stream = result["stream"]
    assert (stream["profile"], stream["mode"], stream["rows"], stream["cols"]) == (
        "hr400", "area", bench_live.DEFAULT_ROWS, 2048,
    )  # fmt: skip
    assert stream["exposure_lines"] == 1 and stream["frame_bytes"] == 64 + 2 * 16 * 2048
    # The shortest frame period of the window: max(k, n + 1) = k line periods (physics.md §3).
    assert stream["frame_period_s"] == pytest.approx(16 * stream["line_period_s"], rel=1e-6)
    (only,) = result["per_round"]
    assert only["order"] == "AB"
    for phase in (only["A"], only["B"]):
        assert phase["frames"] > 0 and phase["frames_per_s"] > 0 and phase["mbyte_per_s"] > 0
        assert phase["lost"] >= 0 and phase["overruns"] >= 0
        # Bytes and frames agree: every frame is the same size.
        assert phase["mbyte_per_s"] * 1e6 == pytest.approx(
            phase["frames_per_s"] * stream["frame_bytes"], rel=1e-6
        )
        assert set(phase["cpu_cores"]) == {"daemon", "sim", "viewers"}
    assert only["A"]["viewer_frames_per_s"] == []
    assert len(only["B"]["viewer_frames_per_s"]) == 2
    assert all(rate > 0 for rate in only["B"]["viewer_frames_per_s"])
    assert (
        result["ratio"]
        == only["ratio"]
        == pytest.approx(only["B"]["frames_per_s"] / only["A"]["frames_per_s"])
    )
    assert result["ratio"] > 0 and result["ratio_min"] <= result["ratio"] <= result["ratio_max"]
    assert result["met"] == (result["ratio"] >= result["goal"] == 0.95)
    assert isinstance(result["host_bound"], bool)
    assert "ratio B/A (frames/s): median" in bench_live.render(result)


def test_bad_options_exit_2(capsys: pytest.CaptureFixture[str]) -> None:
    base = dict(rounds=1, seconds=1.0, viewers=1, rows=16, frame_bank=16, page="/live",
                viewer_kind="ws", no_deflate=False, json=True)  # fmt: skip
    for change in ({"rounds": 0}, {"seconds": 0.0}, {"viewers": 0}, {"rows": 4096},
                   {"page": "live"}):  # fmt: skip
        assert bench_live.run(argparse.Namespace(**{**base, **change})) == 2
    assert "camd bench live:" in capsys.readouterr().err


def test_without_a_browser_it_says_what_to_install(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(live_viewers, "chromium_path", lambda: None)
    kind, why = bench_live.default_kind()
    assert kind == "ws"
    assert "apt-get install chromium" in why and "pip install -e '.[test]'" in why
    with pytest.raises(bench_live.BenchError, match="apt-get install chromium"):
        bench_live.BrowserViewers("http://127.0.0.1:1/live", 1)


def test_per_setting_counts_the_bytes_each_transport_sends() -> None:
    # Two settings, half a second each, in this process: the figures must add up, whatever
    # the rate a busy machine gives.
    result = bench_live.bench_per_setting(
        seconds=0.5, rows=16, pin=False,
        settings=["bin=1&compression=none", "bin=4&compression=deflate"],
    )  # fmt: skip
    full, small = result["per_setting"]
    assert (full["transport"], small["transport"]) == (
        "bin=1&compression=none", "bin=4&compression=deflate",
    )  # fmt: skip
    for row in (full, small):
        assert row["viewer_frames_per_s"] > 0 and row["ingest_frames_per_s"] > 0
    # Full frames: 16 x 2048 pixels of 2 bytes and a description of a few hundred bytes each.
    per_frame = full["viewer_bytes_per_s"] / full["viewer_frames_per_s"]
    assert 16 * 2048 * 2 < per_frame < 16 * 2048 * 2 + 1000
    # 4 x 4 block means deflated: at most a sixteenth of that (plus the description).
    assert small["viewer_bytes_per_s"] / small["viewer_frames_per_s"] < 16 * 2048 * 2 / 16 + 1000
    assert "MB/s at 20/s" in bench_live.render_per_setting(result)
