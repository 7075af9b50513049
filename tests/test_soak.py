"""``camd soak`` (camd/soak/command.py): a short run's JSON document has every figure, sane.

A benchmark, not a test of the daemon: the figures are checked for shape and consistency, not
against the soak's criteria, and nothing here depends on time.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from camd.soak.command import render
from camd.soak.workload import KINDS, build_inject
from tests.crash_support import REQUIRE_MOUNT

ROOT = Path(__file__).resolve().parent.parent


def _soak(*args: str, timeout_s: float = 280.0) -> subprocess.CompletedProcess[str]:
    # Without the suite's $CAMD_RECORD_DIRS: the soak's daemon writes where the soak allows.
    env = {k: v for k, v in os.environ.items() if k != "CAMD_RECORD_DIRS"}
    return subprocess.run(
        [sys.executable, "-m", "camd", "soak", *args],
        capture_output=True, text=True, timeout=timeout_s, cwd=ROOT, env=env,
    )  # fmt: skip


def _count(value: Any) -> int:
    assert isinstance(value, int) and not isinstance(value, bool), value
    assert value >= 0, value
    return value


@pytest.fixture(scope="module")
def soak_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, str, dict[str, Any]]:
    """One short soak: --minutes 0 --warmup-minutes 0 is one item of each kind."""
    work = tmp_path_factory.mktemp("soak") / "work"
    proc = _soak("--minutes", "0", "--warmup-minutes", "0", "--json", "--out", str(work))
    assert proc.returncode == 0, proc.stderr
    return work, proc.stderr, json.loads(proc.stdout)


@pytest.fixture(scope="module")
def soak_doc(soak_run: tuple[Path, str, dict[str, Any]]) -> dict[str, Any]:
    return soak_run[2]


def test_a_short_soak_runs_every_kind_and_reports_every_figure(
    soak_run: tuple[Path, str, dict[str, Any]],
) -> None:
    work, stderr, doc = soak_run
    assert "warm-up" in stderr and "start" in stderr  # progress on stderr

    assert doc["error"] is None and doc["interrupted"] is False
    assert doc["seed"] == 0 and doc["minutes"] == 0 and doc["warmup_minutes"] == 0
    assert "ber=0.0001" in doc["inject"] and "frame_drop=0.002" in doc["inject"]
    kinds = doc["workload"]["kinds"]
    assert set(kinds) == set(KINDS)
    for kind in KINDS:
        assert _count(kinds[kind]["runs"]) >= 1, kind
        _count(kinds[kind]["failed"])
    assert doc["workload"]["items"] == sum(k["runs"] for k in kinds.values())

    commands = doc["commands"]
    assert _count(commands["sent"]) > 0
    for key in ("failed", "failed_requests", "failed_checks", "device_unanswered"):
        _count(commands[key])
    _count(commands["executed_twice"])  # measured by the simulated device
    assert sum(_count(v) for v in commands["answered"].values()) == commands["sent"]
    assert _count(commands["device_commands"]) > 0
    assert _count(commands["link_host"]["sent"]) >= commands["device_commands"]
    assert _count(commands["link_device"]["executed"]) > 0
    assert isinstance(commands["errors"], list)

    frames = doc["frames"]
    for key in ("acquisitions", "requested", "delivered", "lost", "injected"):
        _count(frames[key])
    for value in frames["host"].values():
        _count(value)
    for value in frames["device"].values():
        _count(value)
    # stream, stare, scan and the campaign's three stares
    assert frames["acquisitions"] >= 6
    assert isinstance(frames["equal"], bool)
    assert frames["equal"] == (frames["lost"] == frames["injected"])

    resources = doc["resources"]
    for when in ("start", "end"):
        sample = resources[when]
        assert _count(sample["rss_kb"]) > 0
        assert _count(sample["fds"]) > 0
        assert _count(sample["threads"]) > 0
    assert set(resources["growth_pct"]) == {"rss_kb", "fds", "threads"}
    whats = [s["what"] for s in resources["series"]]
    assert (whats[0], whats[-1]) == ("start", "end")
    # Two samples (start, end): one each side; the growth is that of their RSS.
    assert resources["rss_samples"] == 1
    assert resources["rss_median_kb"] == {
        "start": resources["start"]["rss_kb"], "end": resources["end"]["rss_kb"],
    }  # fmt: skip
    rss = resources["rss_median_kb"]
    assert resources["growth_pct"]["rss_kb"] == round(
        100.0 * (rss["end"] - rss["start"]) / rss["start"], 2
    )

    assert set(doc["verdict"]) == {
        "failed_commands_0", "executed_twice_0", "lost_equals_injected",
        "rss_growth_below_5pct", "fds_flat", "threads_flat",
    }  # fmt: skip
    assert all(isinstance(v, bool) for v in doc["verdict"].values())
    assert doc["work_dir"] == str(work.resolve())
    assert work.exists() == doc["kept"]  # removed unless kept for a failure


def test_the_table_has_a_verdict_per_criterion(
    soak_doc: dict[str, Any], capsys: pytest.CaptureFixture[str]
) -> None:
    render(soak_doc)
    out = capsys.readouterr().out
    verdicts = [line for line in out.splitlines() if line.startswith("verdict: ")]
    assert len(verdicts) == 6
    assert all(line.endswith((": yes", ": NO")) for line in verdicts)
    for kind in KINDS:
        assert any(line.startswith(kind) for line in out.splitlines()), kind
    assert "executed twice" in out and "injected" in out and "RSS" in out


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--inject", "garbage"], "is not key=value"),
        (["--inject", "garbage=lots"], "is not a number"),
        (["--minutes", "-1"], "must be a number >= 0"),
        (["--warmup-minutes", "nan"], "must be a number >= 0"),
        (["--sample-s", "0"], "must be > 0"),
    ],
)
def test_bad_options_exit_2_before_starting_anything(args: list[str], message: str) -> None:
    proc = _soak(*args, timeout_s=60.0)
    assert proc.returncode == 2
    assert message in proc.stderr
    assert proc.stdout == ""


def test_a_non_empty_out_directory_is_refused(tmp_path: Path) -> None:
    (tmp_path / "something").write_text("x")
    proc = _soak("--out", str(tmp_path), timeout_s=60.0)
    assert proc.returncode == 2
    assert "not an empty directory" in proc.stderr
    assert (tmp_path / "something").exists()


def test_build_inject_spreads_the_frame_fault_rate() -> None:
    keys = build_inject(1e-4, 0.01, 0.004, "garbage=0.001,drop=0.02")
    assert keys == {
        "ber": 1e-4, "drop": 0.02, "frame_drop": 0.004, "frame_corrupt": 0.004,
        "frame_short": 0.004, "frame_stall": 0.001, "garbage": 0.001,
    }  # fmt: skip
    assert build_inject(0, 0, 0) == {}


def test_a_short_edge_soak_stops_fills_and_checks_everything(tmp_path: Path) -> None:
    """``camd soak --edges`` for 27 s: emergency stops during campaign jobs, the data disk
    filled once and emptied, every figure reported, and the daemon holding up to all of it."""
    if not REQUIRE_MOUNT and os.geteuid() != 0:
        pytest.skip("camd soak --edges mounts a tmpfs: root only (CI runs as root)")
    work = tmp_path / "edges"
    proc = _soak(
        "--edges", "--minutes", "0.45", "--estop-every-s", "9", "--disk-fills", "1",
        "--fill-hold-s", "6", "--json", "--out", str(work),
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    doc = json.loads(proc.stdout)
    counts = doc["counts"]
    assert _count(counts["estops"]) >= 1 and counts["estop_checks"] >= 10 * counts["estops"]
    assert counts["refused_while_latched"] == counts["estops"]
    assert counts["disk_filled"] == 1 and counts["disk_emptied"] == 1
    assert _count(counts["jobs_started"]) >= 1 and _count(doc["files"]["checked"]) >= 1
    assert doc["violations"] == [] and doc["files"]["unopenable"] == []
    assert doc["files"]["journal_left"] == []
    assert doc["crashes"] == 0 and doc["daemon"]["exit_code"] == 0
    assert doc["error_codes"].get("internal", 0) == 0 and doc["requests"]["no_answer"] == 0
    assert doc["verdict"] == {
        "crashes_0": True, "motion_after_estop_0": True, "files_openable": True,
        "no_internal_error": True,
    }  # fmt: skip
    assert "data disk filled" in proc.stderr and "emergency stop: job" in proc.stderr
