"""Campaign jobs (docs/campaigns.md, "Campaign jobs"): a campaign run by the daemon's worker,
paused in the middle of an acquisition and resumed, cut off by a daemon restart and resumed,
aborted; what is refused, and that a refusal changes nothing. A real ``camd serve --sim``,
its worker processes, the API over HTTP and camctl as a user runs it.

The campaign is tests/plans/long_stare.py: two stares of 300 frames (a few seconds each), so a
pause lands inside one. Every interrupted run must give the same results.json, byte for byte,
as the uninterrupted run on the same camera.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from camd.cli._daemon_proc import DaemonProcess
from camd.client import CamdClient, CamdError

PLAN = Path(__file__).parent / "plans" / "long_stare.py"
WAIT_S = 180.0  # generous: a busy 2-core machine
ENDED = ("paused", "aborted", "passed", "failed", "error", "interrupted")

pytestmark = pytest.mark.slow


def _config(data: Path) -> list[str]:
    """The daemon's config: the simulated camera of the plan's profile and seed; the test
    plans (tests/plans) and ``data/own-campaigns`` as the operator's campaign directories."""
    data.mkdir(parents=True, exist_ok=True)
    (data / "own-campaigns").mkdir(exist_ok=True)
    path = data / "camd.toml"
    path.write_text(
        '[sim]\nprofile = "hr400"\nseed = 11\n[sensor]\nname = "hr400"\n'
        f"[campaigns]\ndirs = [{json.dumps(str(PLAN.parent))}, "
        f"{json.dumps(str(data / 'own-campaigns'))}]\n"
    )
    return ["--config", str(path)]


def _wait(what: str, check: Callable[[], Any]) -> Any:
    deadline = time.monotonic() + WAIT_S
    while not (value := check()):
        if time.monotonic() > deadline:
            raise AssertionError(f"waited {WAIT_S:g} s for {what}")
        time.sleep(0.05)
    return value


def _ended(client: CamdClient, job_id: int) -> dict[str, Any]:
    def ended() -> dict[str, Any] | None:
        job = dict(client.campaign_job(job_id))
        return job if job["state"] in ENDED else None

    return dict(_wait(f"job {job_id} to end", ended))


def _inside_acquisition(client: CamdClient, job_id: int, step: str) -> None:
    """Wait until the job's worker is acquiring ``step`` and frames are arriving."""

    seen: list[Any] = []

    def acquiring() -> bool:
        job = client.campaign_job(job_id)
        seen[:] = [{k: job.get(k) for k in ("state", "activity", "error", "steps_done")}]
        if job["state"] != "running" or f"acquire {step}" not in (job["activity"] or ""):
            return False
        stream = client.stream()
        seen.append({k: stream.get(k) for k in ("streaming", "error")} | {"stats": stream["stats"]})
        return stream["streaming"] and int(stream["stats"]["frames"]) > 10

    try:
        _wait(f"job {job_id} to be inside {step}", acquiring)
    except AssertionError as exc:  # say what was seen last: a failed job, a stalled stream
        raise AssertionError(f"{exc}; last seen: {seen}") from None


def _camctl(url: str, *args: str, client: str | None = None) -> subprocess.CompletedProcess[str]:
    env = None if client is None else {**os.environ, "CAMD_CLIENT": client}
    return subprocess.run(
        [sys.executable, "-m", "camd.cli.camctl", "--url", url, *args],
        capture_output=True, text=True, timeout=120, env=env,
    )  # fmt: skip


def _completed(out_dir: str) -> list[str]:
    return list(json.loads((Path(out_dir) / "state.json").read_text())["completed"])


@pytest.fixture(scope="module")
def daemon(tmp_path_factory: pytest.TempPathFactory) -> Iterator[DaemonProcess]:
    data = tmp_path_factory.mktemp("jobs") / "daemon"
    with DaemonProcess(data, extra_args=_config(data), start_timeout_s=60.0) as d:
        yield d


@pytest.fixture(scope="module")
def reference(daemon: DaemonProcess) -> bytes:
    """results.json of an uninterrupted job."""
    with CamdClient(daemon.url) as client:
        client.wait_ready(60.0)
        job = client.start_campaign(PLAN.stem)
        assert job["state"] == "running" and job["steps"] == 8 and job["runs"] == 1
        done = _ended(client, job["id"])
    assert done["state"] == "passed" and done["passed"] is True, done
    assert done["report"] == str(Path(done["out_dir"]) / "report.html")
    return (Path(done["out_dir"]) / "results.json").read_bytes()


def test_pause_inside_an_acquisition_then_resume_gives_the_uninterrupted_results(
    daemon: DaemonProcess, reference: bytes
) -> None:
    with CamdClient(daemon.url) as client:
        job = client.start_campaign(PLAN.stem)
        _inside_acquisition(client, job["id"], "stare1")
        assert client.pause_campaign(job["id"])["state"] == "pausing"
        done = _ended(client, job["id"])
        assert done["state"] == "paused", done
        # The stopped acquisition is not recorded: it is done again on resume.
        assert _completed(done["out_dir"]) == ["window", "scene0", "stare0", "stats0", "scene1"]
        assert not client.stream()["streaming"]
        assert client.control()["holder"] is None  # the worker gave control back
        assert not (Path(done["out_dir"]) / "results.json").exists()
        # Paused, it cannot be paused again; it can be resumed (camctl, and --wait follows it).
        with pytest.raises(CamdError) as refused:
            client.pause_campaign(job["id"])
        assert refused.value.http_status == 409 and refused.value.code == "wrong_state"
        assert f"resume it with `camctl campaign resume {job['id']}`" in refused.value.message
        status = _camctl(daemon.url, "campaign", "status", str(job["id"]))
        assert f"job {job['id']} long_stare: paused" in status.stdout, status.stderr
        resumed = _camctl(daemon.url, "campaign", "resume", str(job["id"]), "--wait")
        assert resumed.returncode == 0, resumed.stderr
        assert f"job {job['id']} long_stare: passed" in resumed.stdout
        final = client.campaign_job(job["id"])
    assert final["runs"] == 2 and final["passed"] is True
    assert (Path(final["out_dir"]) / "results.json").read_bytes() == reference


def test_abort_ends_the_job_and_keeps_its_files(daemon: DaemonProcess, reference: bytes) -> None:
    with CamdClient(daemon.url) as client:
        job = client.start_campaign(PLAN.stem)
        _inside_acquisition(client, job["id"], "stare0")
        # Another client may not abort it; with --force it may (logged).
        other = _camctl(daemon.url, "campaign", "abort", str(job["id"]), client="someone@else")
        assert other.returncode != 0
        assert "started it; ask them, or abort it anyway with" in other.stderr
        assert client.campaign_job(job["id"])["state"] == "running"
        _inside_acquisition(client, job["id"], "stare1")
        with CamdClient(daemon.url, client="someone@else") as other:
            assert other.abort_campaign(job["id"], force=True)["state"] == "aborting"
        done = _ended(client, job["id"])
        assert done["state"] == "aborted"
        assert _completed(done["out_dir"]) == ["window", "scene0", "stare0", "stats0", "scene1"]
        assert not (Path(done["out_dir"]) / "results.json").exists()
        with pytest.raises(CamdError) as refused:
            client.resume_campaign(job["id"])
        assert refused.value.code == "wrong_state"
        assert "start the campaign again as a new job" in refused.value.message
        events = [e["message"] for e in client.events(200)["events"]]
    assert f"job {job['id']}: abort forced by someone@else (started by" in " ".join(events)


def test_refusals_change_nothing(daemon: DaemonProcess, reference: bytes, tmp_path: Path) -> None:
    bad = daemon.data_dir / "own-campaigns" / "bad.yaml"
    bad.write_text("name: bad\nprofile: hr400\nsteps: []\n")
    with CamdClient(daemon.url) as client:
        before = client.campaign_jobs()["jobs"]
        with pytest.raises(CamdError) as invalid:
            client.start_campaign(bad.stem)
        assert invalid.value.http_status == 400 and "steps" in invalid.value.message
        with pytest.raises(CamdError) as unknown:
            client.start_campaign("no_such_campaign")
        assert unknown.value.http_status == 400
        assert "no campaign 'no_such_campaign'" in unknown.value.message
        assert "example_stare" in unknown.value.message  # the shipped ones are listed
        with pytest.raises(CamdError) as outside:
            client.start_campaign(PLAN.stem, out="/etc/camd-test-never")
        assert outside.value.http_status == 400
        assert "is outside the directories the daemon may write" in outside.value.message
        assert not Path("/etc/camd-test-never").exists()
        with pytest.raises(CamdError) as missing:
            client.campaign_job(999)
        assert missing.value.http_status == 404 and "no campaign job 999" in missing.value.message
        assert client.campaign_jobs()["jobs"] == before
        # One job at a time; and a client that does not hold control cannot start one.
        job = client.start_campaign(PLAN.stem, quick=True)
        with pytest.raises(CamdError) as busy:
            client.start_campaign(PLAN.stem)
        assert busy.value.http_status == 409
        assert f"campaign job {job['id']} (long_stare) is running" in busy.value.message
        assert _ended(client, job["id"])["state"] == "passed"
        with CamdClient(daemon.url, client="someone@else") as other:
            other.take_control(60.0)
            try:
                with pytest.raises(CamdError) as locked:
                    client.start_campaign(PLAN.stem)
            finally:
                other.release_control()
        assert locked.value.http_status == 423
        assert "cannot start a campaign: someone@else holds control" in locked.value.message
        assert len(client.campaign_jobs()["jobs"]) == len(before) + 1


def test_a_job_runs_no_file_a_client_names(daemon: DaemonProcess, tmp_path: Path) -> None:
    """A campaign job names a campaign of the daemon's campaign directories by name: a path
    (absolute, relative, with ..), a name with a slash or a suffix, an over-long name are each
    refused 400 before anything is loaded, so the Python file is never imported."""
    marker = tmp_path / "imported"
    evil = tmp_path / "evil_plan.py"
    evil.write_text(f"open({str(marker)!r}, 'w').write('ran as the daemon')\n")
    (daemon.data_dir / "own-campaigns" / "linked").mkdir(exist_ok=True)
    names = [
        str(evil),
        "evil_plan.py",
        f"../../{tmp_path.name}/evil_plan",
        "own-campaigns/evil_plan",
        "Long_Stare",
        "x" * 5000,
        "long_stare\x00",
    ]
    with CamdClient(daemon.url) as client:
        before = client.campaign_jobs()["jobs"]
        for name in names:
            with pytest.raises(CamdError) as refused:
                client.start_campaign(name)
            error = refused.value
            assert error.http_status == 400, (name, error)
            assert len(error.message) < 1200, (name, len(error.message))  # the value is cut
            if len(name) <= 100:
                assert "give a campaign's name" in error.message and "not a path" in error.message
                assert "[campaigns] dirs" in error.message
        assert client.campaign_jobs()["jobs"] == before
    assert not marker.exists()
    # camctl says how to go on with a file: put it in a campaign directory, or run it here.
    proc = _camctl(daemon.url, "campaign", "start", str(evil))
    assert proc.returncode != 0
    assert "takes a campaign's name, not a file" in proc.stderr
    assert f"`camctl campaign run {evil}`" in proc.stderr
    assert not marker.exists()


def test_a_daemon_restart_resumes_the_running_job(tmp_path: Path, reference: bytes) -> None:
    data = tmp_path / "daemon"
    args = _config(data)  # the camera of the module's daemon, which ran the reference
    with (
        DaemonProcess(data, extra_args=args, start_timeout_s=60.0) as first,
        CamdClient(first.url) as client,
    ):
        client.wait_ready(60.0)
        job = client.start_campaign(PLAN.stem)
        _inside_acquisition(client, job["id"], "stare1")
    # The daemon has stopped (SIGTERM) and stopped the worker: the job waits for the next one.
    stored = json.loads((data / "campaigns" / "jobs.json").read_text())["jobs"]
    entry = next(j for j in stored if j["id"] == job["id"])
    assert entry["state"] == "interrupted" and entry["resume_on_start"] is True
    with (
        DaemonProcess(data, extra_args=args, start_timeout_s=60.0) as second,
        CamdClient(second.url) as client,
    ):
        done = _ended(client, job["id"])
    assert done["state"] == "passed" and done["runs"] == 2, done
    log = (Path(done["out_dir"]) / "worker.log").read_text()
    assert f"job {job['id']} run 1:" in log and f"job {job['id']} run 2:" in log
    assert (Path(done["out_dir"]) / "results.json").read_bytes() == reference


def test_campaign_list_shows_paper_camera_steps_and_measured_run_times() -> None:
    from camd.campaign.catalog import run_times

    proc = subprocess.run(
        [sys.executable, "-m", "camd.cli.camctl", "--json", "campaign", "list"],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    rows = {c["name"]: c for c in json.loads(proc.stdout)["campaigns"]}
    mtf = rows["mtf_mismatch"]
    assert (mtf["paper"], mtf["profile"]) == ("YUAN13 §4", "mt9m001")
    # example_stare: 4 steps, then 4 per light level (3 levels, 2 with --quick).
    assert (rows["example_stare"]["steps"], rows["example_stare"]["steps_quick"]) == (16, 12)
    measured = run_times()
    for name, row in rows.items():
        assert row["run_time_s"] == measured[name]["full_s"] > 0, name
        assert row["run_time_quick_s"] == measured[name]["quick_s"] > 0, name
    table = subprocess.run(
        [sys.executable, "-m", "camd.cli.camctl", "campaign", "list"],
        capture_output=True, text=True, timeout=120, env={**os.environ, "COLUMNS": "120"},
    )  # fmt: skip
    assert table.returncode == 0, table.stderr
    assert "mtf_mismatch" in table.stdout and "YUAN13 §4" in table.stdout
