"""``camd bench pipeline``: the host's scan path on an unpaced stream, figures consistent.

A benchmark is not a test of speed: this checks that its figures agree with each other and
with the sensor's timing, and that the frames went through every stage (no threshold on a
rate).
"""

from __future__ import annotations

import argparse
import json

import pytest

from camd.bench.common import last_level_cache_bytes
from camd.bench.pipeline import line_rate_hz, measure, run
from camd.protocol.stream import HEADER_BYTES

# Not ``exclusive``: the stream is unpaced (the simulator sends as fast as the host reads, so
# nothing is lost however slow the host), and no figure is held to a rate: the checks are that
# the figures add up. Checked beside `stress-ng --cpu 2`.

HR400_LINE_S = 513 / 25e6  # config/sensors/hr400.toml: 513 sequencer clocks at 25 MHz


def test_the_line_rate_is_one_frame_per_max_m_2_line_periods() -> None:
    assert line_rate_hz("hr400", 96) == (pytest.approx(1 / (96 * HR400_LINE_S), rel=1e-12), 2048)
    assert line_rate_hz("hr400", 1)[0] == pytest.approx(1 / (2 * HR400_LINE_S), rel=1e-12)


def test_a_case_takes_frames_through_every_stage_and_adds_up() -> None:
    case = measure("hr400", 8, seconds=0.4, rounds=2, bank_mb=2.0)
    assert (case["profile"], case["stages"], case["cols"]) == ("hr400", 8, 2048)
    assert case["frame_bytes"] == HEADER_BYTES + 8 * 2048 * 2
    assert case["bank_frames"] == round(2e6 / case["frame_bytes"])  # 61 frames of 32 KiB
    assert case["line_rate_hz"] == pytest.approx(1 / (8 * HR400_LINE_S), rel=1e-12)
    # Every frame read went through the engine into the file: one line per frame (M = 8,
    # integer TDI), none lost or corrupt on a clean stream.
    assert case["frames_in"] > 0 and case["lines"] == case["frames_in"]
    assert (case["lost"], case["corrupt"]) == (0, 0)
    # The lines are on disk, compressed as a scan's are (Bitshuffle + LZ4: a few times smaller).
    assert case["file_mb"] > case["lines"] * 2048 * 4 / 1e6 * 0.1
    assert case["over_line_rate"] == pytest.approx(case["frames_per_s"] / case["line_rate_hz"])
    us = case["cpu_us_per_frame"]
    assert set(us) == {"read", "dispatch", "engine", "record", "other"}
    assert all(v >= 0 for v in us.values()) and us["read"] > 0 and us["engine"] > 0
    assert case["one_core_headroom"] == pytest.approx(
        1e6 / (case["cpu_us_per_frame_total"] * case["line_rate_hz"])
    )
    assert len(case["rounds"]) == 2


def test_each_m_is_raised_to_the_sensors_fewest_window_rows(
    capsys: pytest.CaptureFixture[str],
) -> None:
    # mt9m001's window is at least 3 rows: M = 1 (its fastest line rate) runs as 3, and a
    # second M of 2 is the same case, run once.
    args = argparse.Namespace(
        profiles="mt9m001", stages=(1, 2), seconds=0.2, rounds=1, bank_mb=2.0, json=True
    )
    assert run(args) == 0
    doc = json.loads(capsys.readouterr().out)
    assert [(c["profile"], c["stages"]) for c in doc["cases"]] == [("mt9m001", 3)]
    assert doc["cases"][0]["frames_in"] > 0


def test_the_cache_size_is_read_from_the_machine() -> None:
    size = last_level_cache_bytes()
    assert size is None or size >= 1 << 16


@pytest.mark.parametrize(
    ("option", "value"), [("stages", (0,)), ("rounds", 0), ("seconds", 0.0), ("bank_mb", -1.0)]
)
def test_bad_options_exit_2_with_the_ranges(
    option: str, value: object, capsys: pytest.CaptureFixture[str]
) -> None:
    args = argparse.Namespace(
        profiles="hr400", stages=(8,), seconds=0.2, rounds=1, bank_mb=0.0, json=True
    )
    setattr(args, option, value)
    assert run(args) == 2
    out = capsys.readouterr().out
    assert "--stages and --rounds must be >= 1, --seconds > 0, --bank-mb >= 0" in out
