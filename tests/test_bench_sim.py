"""``camd bench sim``: the simulated camera streaming unpaced into a byte-counting reader.

A benchmark is not a test of speed: this checks that its figures are consistent with each
other and with the sensor's timing (no threshold on a rate).
"""

from __future__ import annotations

import argparse
import os

import pytest

from camd.bench.sim import measure, run
from camd.protocol.stream import HEADER_BYTES

# Not ``exclusive``: no figure is held to a rate; the checks are that the figures agree with
# each other and with the sensor's timing. Checked beside `stress-ng --cpu 2`.

HR400_LINE_S = 513 / 25e6  # config/sensors/hr400.toml: 513 sequencer clocks at 25 MHz


@pytest.mark.parametrize("kind", ["bank", "render"])
def test_a_case_reports_frames_against_the_line_rate_m_rows_allow(kind: str) -> None:
    case = measure("hr400", 8, kind, 0.3)
    assert (case["profile"], case["stages"], case["kind"], case["cols"]) == ("hr400", 8, kind, 2048)
    # A window of 8 rows and one line of exposure: a frame every max(8, 2) line periods.
    assert case["line_rate_hz"] == pytest.approx(1 / (8 * HR400_LINE_S), rel=1e-9)
    assert case["frames_per_s"] > 0
    assert case["over_line_rate"] == pytest.approx(case["frames_per_s"] / case["line_rate_hz"])
    assert case["frame_bytes"] == HEADER_BYTES + 8 * 2048 * 2
    # The bytes the engine sent: the frames' (the counts are read a moment apart).
    assert case["mbyte_per_s"] == pytest.approx(
        case["frames_per_s"] * case["frame_bytes"] / 1e6, rel=0.05
    )
    # One thread uses at most one core; Linux counts its CPU time in clock ticks, user and
    # system apart, so two readings 0.3 s apart may be a few ticks off (1.062 seen once).
    ticks_s = 3 / os.sysconf("SC_CLK_TCK")
    assert 0 < case["engine_cpu_cores"] <= 1.0 + ticks_s / case["seconds"]


def test_a_window_of_one_row_still_takes_two_line_periods() -> None:
    case = measure("hr400", 1, "bank", 0.2)
    assert case["line_rate_hz"] == pytest.approx(1 / (2 * HR400_LINE_S), rel=1e-9)


@pytest.mark.parametrize(
    ("option", "value"),
    [("stages", "eight"), ("stages", "0"), ("kinds", "paint"), ("seconds", 0.0)],
)
def test_bad_options_exit_2_with_the_fix(
    option: str, value: object, capsys: pytest.CaptureFixture[str]
) -> None:
    args = argparse.Namespace(profiles="hr400", stages="8", kinds="bank", seconds=0.2, json=True)
    setattr(args, option, value)
    assert run(args) == 2
    out = capsys.readouterr().out
    assert out.startswith("camd bench sim: ")
    assert {"stages": "--stages", "kinds": "--kinds", "seconds": "--seconds"}[option] in out


def test_a_scene_is_rendered_and_a_bad_one_exits_2(capsys: pytest.CaptureFixture[str]) -> None:
    case = measure("hr400", 8, "render", 0.2, "bars:lux=3")
    assert case["frames_per_s"] > 0
    args = argparse.Namespace(
        profiles="hr400", stages="8", kinds="render", seconds=0.2, json=True, scene="bars:lux=x"
    )
    assert run(args) == 2
    assert capsys.readouterr().out.startswith("camd bench sim: --scene 'bars:lux=x': scene lux")


def test_windows_are_kept_within_what_each_sensor_allows() -> None:
    from camd.bench.common import window_rows_range, window_stages

    # The MT9M001 holds rows - 1 with a minimum of 2: its fewest window rows are 3.
    assert window_rows_range("mt9m001") == (3, 1024)
    assert window_rows_range("hr400") == (1, 2048)
    assert window_rows_range("uvccd") == (1, 500)
    # Each M raised to the fewest rows, capped at the sensor's rows, each run once, in order.
    assert window_stages("mt9m001", (96, 1, 2, 3)) == [3, 96]
    assert window_stages("uvccd", (1, 8, 600, 500)) == [1, 8, 500]
