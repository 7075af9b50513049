"""Conformance outcomes that cannot pass without testing (docs/conformance.md, "Outcomes"):
a check whose valid case another check exercises passes only if that check passed, else it
is "not run" with the reason; the checks that need the USB frame stream are "not run" for a
unit without one, and the report, the JSON and the exit status say so.

In-process: the engine with check functions registered for the test (the engine's own plugin
interface). Then a real simulated camera on a pty, driven by `camd serve --serial` as a real
camera would be, with no frame stream, and `camd conform` run against it."""

from __future__ import annotations

import json
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from camd.campaign.conformance.engine import (
    CheckFailed,
    CheckNotRun,
    CheckRecord,
    CheckStep,
    Evidence,
    Unit,
    check_function,
    run_plan,
)
from camd.campaign.conformance.report import document, render_html
from camd.campaign.conformance.suite import VALID_CASE_ELSEWHERE, plan
from camd.cli._daemon_proc import DaemonProcess
from camd.client import CamdClient
from camd.protocol import load_dictionary
from camd.sensor.regmap import load_register_map

REPO = Path(__file__).resolve().parent.parent
NO_STREAM_MESSAGE = "cannot open the frame stream: no device"
CALLS: list[str] = []  # the test check functions called, in order


@check_function("test_outcomes_pass")
def _passes(unit: Unit, *, name: str) -> Evidence:
    CALLS.append(name)
    return {"ran": name}


@check_function("test_outcomes_fail")
def _fails(unit: Unit, *, name: str) -> Evidence:
    CALLS.append(name)
    raise CheckFailed(f"{name} saw 3 headers of 12", {"headers": 3})


@check_function("test_outcomes_no_stream")
def _no_stream(unit: Unit, *, name: str) -> Evidence:
    CALLS.append(name)
    raise CheckNotRun("stream", NO_STREAM_MESSAGE, {"code": "disconnected"})


@pytest.fixture
def unit() -> Unit:
    # The engine hands the unit to the check functions; these ones never use its client.
    client = CamdClient("http://127.0.0.1:9")
    return Unit(client, "hr400", load_register_map("hr400"), load_dictionary(), True, {})


def _step(check_id: str, function: str, **kw: Any) -> CheckStep:
    return CheckStep(
        check_id, function, "docs/protocol.md §8. Error codes", check_id, {"name": check_id}, **kw
    )


def _run(unit: Unit, steps: list[CheckStep], **kw: Any) -> dict[str, CheckRecord]:
    CALLS.clear()
    seen: list[str] = []
    records = run_plan(unit, iter(steps), progress=lambda r: seen.append(r.id), **kw)
    assert set(CALLS) <= set(seen)  # progress saw every check that ran
    return {r.id: r for r in records}


VALID = {"t.stream": "its valid case"}


def test_a_dependent_runs_after_its_dependency_and_is_not_run_when_it_failed(unit: Unit) -> None:
    # The dependent comes first in the plan, as cmd.START_STREAM comes before stream.headers.
    steps = [
        _step("t.cmd", "test_outcomes_pass", depends_on=VALID),
        _step("t.stream", "test_outcomes_fail"),
    ]
    records = _run(unit, steps)
    assert CALLS == ["t.stream", "t.cmd"]  # the dependency ran first
    assert list(records) == ["t.cmd", "t.stream"]  # reported in plan order
    cmd = records["t.cmd"]
    assert cmd.outcome == "not_run"
    assert cmd.reason == (
        "its valid case is exercised by t.stream, which failed: t.stream saw 3 headers of 12"
    )
    assert cmd.evidence == {"ran": "t.cmd", "dependency": {"check": "t.stream", "outcome": "fail"}}
    assert cmd.as_dict()["depends_on"] == ["t.stream"]
    assert cmd.as_dict()["passed"] is False


def test_a_dependent_passes_when_its_dependency_passed(unit: Unit) -> None:
    steps = [
        _step("t.cmd", "test_outcomes_pass", depends_on=VALID),
        _step("t.stream", "test_outcomes_pass"),
    ]
    records = _run(unit, steps)
    assert {i: r.outcome for i, r in records.items()} == {"t.cmd": "pass", "t.stream": "pass"}


def test_a_dependents_own_failure_stays_a_failure(unit: Unit) -> None:
    steps = [
        _step("t.cmd", "test_outcomes_fail", depends_on=VALID),
        _step("t.stream", "test_outcomes_fail"),
    ]
    cmd = _run(unit, steps)["t.cmd"]
    assert (cmd.outcome, cmd.reason) == ("fail", "t.cmd saw 3 headers of 12")


def test_no_stream_means_the_stream_checks_and_their_dependents_are_not_run(unit: Unit) -> None:
    steps = [
        _step("t.cmd", "test_outcomes_pass", depends_on=VALID),
        _step("t.link", "test_outcomes_pass"),
        _step("t.stream", "test_outcomes_no_stream", needs=("stream",)),
        _step("t.stream2", "test_outcomes_pass", needs=("stream",)),
    ]
    records = _run(unit, steps)
    # The second stream check is not even tried: the first found the stream missing.
    assert CALLS == ["t.link", "t.stream", "t.cmd"]
    outcomes = {i: r.outcome for i, r in records.items()}
    assert outcomes == {"t.cmd": "not_run", "t.link": "pass", "t.stream": "not_run",
                        "t.stream2": "not_run"}  # fmt: skip
    assert records["t.stream"].reason == f"no frame stream: {NO_STREAM_MESSAGE}"
    assert records["t.stream2"].reason == (
        f"no frame stream: {NO_STREAM_MESSAGE} (found by t.stream)"
    )
    assert records["t.cmd"].reason == (
        f"its valid case is exercised by t.stream, which did not run: no frame stream: "
        f"{NO_STREAM_MESSAGE}"
    )


def test_only_a_dependent_selected_runs_its_dependency_too(unit: Unit) -> None:
    steps = [
        _step("t.cmd", "test_outcomes_pass", depends_on=VALID),
        _step("t.other", "test_outcomes_pass"),
        _step("t.stream", "test_outcomes_fail"),
    ]
    records = _run(unit, steps, only=lambda i: i == "t.cmd")
    assert list(records) == ["t.cmd", "t.stream"]
    assert records["t.cmd"].outcome == "not_run"


def test_a_skipped_dependency_leaves_the_dependent_not_run(unit: Unit) -> None:
    steps = [
        _step("t.cmd", "test_outcomes_pass", depends_on={"t.home": "its valid case"}),
        _step("t.home", "test_outcomes_pass", destructive=True),
    ]
    records = _run(unit, steps)
    assert records["t.home"].outcome == "skipped"
    assert records["t.cmd"].reason.startswith(
        "its valid case is exercised by t.home, which was skipped: destructive"
    )


def test_a_dependency_cycle_is_refused(unit: Unit) -> None:
    steps = [
        _step("t.a", "test_outcomes_pass", depends_on={"t.b": "x"}),
        _step("t.b", "test_outcomes_pass", depends_on={"t.a": "y"}),
    ]
    with pytest.raises(ValueError, match=r"t\.a, t\.b depend on each other in a cycle"):
        _run(unit, steps)


def test_the_report_counts_not_run_and_says_not_shown_to_conform(unit: Unit) -> None:
    steps = [
        _step("t.cmd", "test_outcomes_pass", depends_on=VALID),
        _step("t.link", "test_outcomes_pass"),
        _step("t.stream", "test_outcomes_no_stream", needs=("stream",)),
    ]
    records = list(_run(unit, steps).values())
    doc = document({"suite": "camd-conformance"}, records)
    assert doc["summary"] == {"pass": 1, "fail": 0, "not_run": 2, "skipped": 0, "checks": 3,
                              "conforms": False, "verdict": "incomplete"}  # fmt: skip
    assert doc["not_run"] == ["t.cmd", "t.stream"] and doc["failed"] == []
    assert [c["outcome"] for c in doc["checks"]] == ["not_run", "pass", "not_run"]
    page = render_html(doc)
    assert "camd conformance: NOT SHOWN TO CONFORM" in page
    assert "1 passed, 0 failed, 2 not run, 0 skipped of 3" in page
    row = page.split('<tr id="t.stream">')[1].split("</tr>")[0]
    assert ">NOT RUN</td>" in row and "no frame stream: cannot open" in row
    # One failure outweighs the not-run ones.
    failed = [*records, CheckRecord("t.x", "c", "t", "fail", "bad", {}, False, 0.0)]
    assert document({}, failed)["summary"]["verdict"] == "does_not_conform"
    passed = [r for r in records if r.outcome == "pass"]
    assert document({}, passed)["summary"]["verdict"] == "conforms"


def test_the_suite_declares_its_dependencies_as_data() -> None:
    steps = {s.id: s for s in plan(load_dictionary())}
    depending = {i: dict(s.depends_on) for i, s in steps.items() if s.depends_on}
    assert depending == {
        "cmd.START_STREAM": {"stream.headers": "its valid case"},
        "cmd.WHEEL_ACQUIRE": {"wheel.delay": "its valid case"},
        "cmd.MOTOR_HOME": {"motion.home": "its valid case"},
    }
    assert {f"cmd.{name}" for name in VALID_CASE_ELSEWHERE} == set(depending)
    needing = {i for i, s in steps.items() if s.needs}
    assert needing == {"stream.headers", "stream.counters", "stream.crc", "stream.frame_period",
                       "wheel.delay"}  # fmt: skip
    assert all(s.needs == ("stream",) for i, s in steps.items() if i in needing)


# -- a camera without a frame stream, on a real pty ------------------------------------------------


@pytest.fixture(scope="module")
def streamless(tmp_path_factory: pytest.TempPathFactory) -> Iterator[DaemonProcess]:
    """`camd sim` serving the command link only (no --usb-socket), and `camd serve --serial`
    on its pty: the daemon has a camera and no frame stream, as with a USB cable unplugged."""
    tmp = tmp_path_factory.mktemp("nostream")
    link = tmp / "camera.tty"
    sim = subprocess.Popen(
        [sys.executable, "-m", "camd", "sim", "--json", "--link", str(link)],
        stdout=subprocess.PIPE, text=True, cwd=REPO,
    )  # fmt: skip
    try:
        assert sim.stdout is not None
        info = json.loads(sim.stdout.readline())
        assert info["usb_socket"] is None
        daemon = DaemonProcess(tmp / "data", extra_args=["--serial", str(link)],
                               env={"CAMD_TOKEN": ""})  # fmt: skip
        daemon.command.remove("--sim")  # the camera is not the daemon's own simulator
        with daemon:
            with CamdClient(daemon.url) as client:
                client.wait_ready(60)
            yield daemon
    finally:
        sim.terminate()
        sim.wait(timeout=10)


def test_without_a_stream_the_stream_checks_are_not_run_and_the_exit_status_says_so(
    streamless: DaemonProcess, tmp_path: Path
) -> None:
    only = ["stream.*", "wheel.*", "cmd.START_STREAM", "cmd.WHEEL_ACQUIRE", "cmd.PING"]
    run = subprocess.run(
        [sys.executable, "-m", "camd", "conform", "--url", streamless.url, "--json",
         "--out", str(tmp_path), *(a for o in only for a in ("--only", o))],
        capture_output=True, text=True, timeout=300, cwd=REPO,
    )  # fmt: skip
    assert run.returncode == 4, (run.stdout, run.stderr)
    doc = json.loads(run.stdout)
    assert doc["conforms"] is False and doc["verdict"] == "incomplete"
    assert doc["failed"] == []
    assert set(doc["not_run"]) == {"stream.headers", "stream.counters", "stream.crc",
                                   "stream.frame_period", "wheel.delay", "cmd.START_STREAM",
                                   "cmd.WHEEL_ACQUIRE"}  # fmt: skip
    assert doc["summary"] == {"checks": 9, "pass": 2, "fail": 0, "not_run": 7, "skipped": 0}
    report = json.loads((tmp_path / "conformance.json").read_text())
    checks = {c["id"]: c for c in report["checks"]}
    assert {i for i, c in checks.items() if c["outcome"] == "pass"} == {"cmd.PING", "wheel.speed"}
    assert report["not_run"] == doc["not_run"]
    first = checks["stream.headers"]["reason"]
    assert first.startswith("no frame stream: no USB frame-stream device 04b4:00f1 found"), first
    assert checks["stream.crc"]["reason"] == f"{first} (found by stream.headers)"
    assert checks["cmd.START_STREAM"]["reason"] == (
        f"its valid case is exercised by stream.headers, which did not run: {first}"
    )
    assert checks["cmd.WHEEL_ACQUIRE"]["reason"].startswith(
        "its valid case is exercised by wheel.delay, which did not run: no frame stream"
    )
    # Its invalid cases did run, and the unit refused them as it must.
    cases = checks["cmd.START_STREAM"]["evidence"]["cases"]
    assert [c["ok"] for c in cases] == [True] * len(cases) and len(cases) >= 2
    assert "NOT RUN stream.headers: no frame stream: " in run.stderr
    assert "NOT RUN cmd.START_STREAM: its valid case is exercised by stream.headers" in run.stderr
    assert "NOT SHOWN TO CONFORM" in (tmp_path / "conformance.html").read_text()


def test_camctl_conform_exits_4_when_checks_did_not_run(
    streamless: DaemonProcess, tmp_path: Path
) -> None:
    run = subprocess.run(
        [sys.executable, "-m", "camd.cli.camctl", "--url", streamless.url, "conform",
         "--only", "cmd.START_STREAM", "--out", str(tmp_path)],
        capture_output=True, text=True, timeout=120, cwd=REPO,
    )  # fmt: skip
    assert run.returncode == 4, (run.stdout, run.stderr)
    # cmd.START_STREAM brought stream.headers, which it depends on, into the run.
    assert "NOT RUN stream.headers: no frame stream: " in run.stderr
    shown = " ".join(run.stdout.split())  # the console wraps long lines
    assert "conformance: NOT SHOWN TO CONFORM: 0 passed, 0 failed, 2 not run, 0 skipped of 2" in (
        shown
    )
    assert "not run: cmd.START_STREAM, stream.headers" in run.stderr  # plan order
