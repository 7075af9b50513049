"""The emergency stop as a latched state of the instrument (docs/api.md, "Emergency stop"):
nothing moves or acquires after it until a client with control releases it, a campaign job it
catches is paused and changes nothing more, the latch survives a daemon restart and a camera
that comes back turning its wheel is stopped again. A real ``camd serve --sim`` over HTTP,
camctl as a user runs it, the campaign job's real worker process.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from camd.cli._daemon_proc import DaemonProcess
from camd.client import CamdClient, CamdError
from camd.daemon.campaign_jobs import CampaignJobs
from tests.crash_support import wait_for
from tests.device_snapshot import snapshot
from tests.test_camctl import camctl
from tests.test_campaign_jobs import _config

PLAN = Path(__file__).parent / "plans" / "long_stare.py"
ENDLESS = Path(__file__).parent / "plans" / "endless_stare.py"
ENDED = ("paused", "aborted", "passed", "failed", "error", "interrupted")

pytestmark = pytest.mark.slow


def _latched(client: CamdClient, call: Callable[[], object]) -> str:
    """``call`` is refused because of the latch: 409 estop_latched; its message."""
    with pytest.raises(CamdError) as refused:
        call()
    error = refused.value
    assert (error.http_status, error.code) == (409, "estop_latched"), error
    assert "`camctl estop release`" in error.message, error.message
    return error.message


def _released(client: CamdClient) -> None:
    """Leave the daemon as the next test expects it: latch released, nobody in control, the
    stage enabled, the wheel at its nominal speed."""
    client.release_control()
    client.release_estop()
    client.enable_stage(True)
    client.set_wheel_speed(float(client.wheel()["nominal_speed_deg_s"]))


@pytest.fixture(scope="module")
def daemon(tmp_path_factory: pytest.TempPathFactory) -> Iterator[DaemonProcess]:
    data = tmp_path_factory.mktemp("estop") / "daemon"
    with DaemonProcess(data, extra_args=_config(data), start_timeout_s=60.0) as d:
        with CamdClient(d.url) as client:
            client.wait_ready(60.0)
        yield d


def test_the_latch_refuses_motion_and_acquisition_until_someone_with_control_releases_it(
    daemon: DaemonProcess,
) -> None:
    alice = CamdClient(daemon.url, client="alice")
    bob = CamdClient(daemon.url, client="bob")
    with alice, bob:
        alice.enable_stage(True)
        alice.run_stage(0.002)
        answer = bob.estop()  # whoever asks
        assert answer["stopped"] == ["stage", "wheel"] and answer["failed"] == []
        latch = answer["latch"]
        assert latch["latched"] and latch["by"] == "bob" and latch["stopped"] == ["stage", "wheel"]
        assert bob.status()["estop"]["latched"]
        before = snapshot(bob)
        assert before["stage"]["state"] == "estop"
        scan_file = daemon.data_dir / "refused-scan.h5"
        refused: dict[str, Callable[[], object]] = {
            "stream": lambda: alice.start_stream(0),
            "stare": lambda: alice.acquire(3, timeout_s=30),
            "scan": lambda: alice.start_scan(4, 10, out=str(scan_file), drive_stage=False),
            "stage enable": lambda: alice.enable_stage(True),
            "stage run": lambda: alice.run_stage(0.001),
            "stage move": lambda: alice.move_stage(0.05, wait=False),
            "stage home": lambda: alice.home_stage(wait=False),
            "wheel speed": lambda: alice.set_wheel_speed(30.0),
            "wheel run": lambda: alice.wheel_acquire([0, 1], timeout_s=30),
            "raw START_STREAM": lambda: alice.link_command(
                "START_STREAM", fields={"frames": 1, "stages": 1, "binning": "off"}
            ),
            "campaign": lambda: alice.start_campaign(PLAN.stem, quick=True),
        }
        messages = {what: _latched(alice, call) for what, call in refused.items()}
        assert messages["stream"].startswith("cannot start a stream: the emergency stop is latched")
        assert "(asked by bob)" in messages["wheel speed"]
        assert not scan_file.exists()
        # Nothing the refused requests asked was done; stopping and reading still work.
        assert snapshot(bob) == before
        assert alice.set_wheel_speed(0.0)["speed_deg_s"] == 0.0
        alice.stop_stage()
        again = alice.estop()  # never refused, latched or not
        assert again["latch"]["count"] == latch["count"] + 1
        assert again["latch"]["since_t_s"] == latch["since_t_s"]  # the same latch
        # Only someone with control releases it.
        alice.take_control(60)
        with pytest.raises(CamdError) as not_bob:
            bob.release_estop()
        assert not_bob.value.code == "not_in_control"
        assert bob.estop_state()["latched"]
        released = alice.release_estop()
        assert not released["latched"] and released["released_by"] == "alice"
        events = [e["message"] for e in bob.events(limit=30)["events"]]
        assert any(
            m.startswith("EMERGENCY STOP by bob: stopped stage, wheel; latched") for m in events
        )
        assert any(m.startswith("emergency stop released by alice") for m in events)
        # Released: the stage stays disabled and the wheel stopped until started.
        assert snapshot(bob)["stage"]["state"] == "estop"
        assert alice.acquire(3, timeout_s=60)["stats"]["frames"] == 3
        _released(alice)


def test_camctl_shows_the_latch_and_releases_it(daemon: DaemonProcess) -> None:
    url = daemon.url
    stop = camctl(url, "--client", "carol", "estop")
    assert stop.returncode == 0, stop.stderr
    assert "EMERGENCY STOP: stopped" in stop.stdout and "LATCHED since" in stop.stdout
    status = camctl(url, "status")
    assert status.returncode == 0 and "EMERGENCY STOP" in status.stdout
    assert "camctl estop release" in status.stdout
    shown = camctl(url, "estop", "status")
    assert shown.returncode == 0 and "LATCHED since" in shown.stdout and "carol" in shown.stdout
    refused = camctl(url, "stream", "--frames", "3")
    assert refused.returncode != 0
    assert "the emergency stop is latched" in refused.stderr, refused.stderr
    release = camctl(url, "--client", "carol", "estop", "release")
    assert release.returncode == 0, release.stderr
    assert "not latched (released at" in release.stdout and "carol" in release.stdout
    after = camctl(url, "status")  # released: no latch row, nor the raw latch document
    assert after.returncode == 0 and "EMERGENCY STOP" not in after.stdout
    assert "latched" not in after.stdout, after.stdout
    with CamdClient(url) as client:
        _released(client)


def test_an_emergency_stop_mid_scan_leaves_the_stage_standing(daemon: DaemonProcess) -> None:
    """A closed-loop scan driving the stage: the stop ends it "stopped", and nothing of the
    scan (its closed loop's speed trims, its stage's stop and return) moves the stage again."""
    with CamdClient(daemon.url) as client:
        out = daemon.data_dir / "estop-scan.h5"
        client.start_scan(32, 0, out=str(out), drive_stage=True, closed_loop=True)
        wait_for("lines on their way to the file", lambda: client.scan()["lines"] > 20)
        assert "acquisition" in client.estop()["stopped"]
        ended = client.wait_scan(60)
        assert ended["state"] == "stopped" and ended["error"] is None, ended
        deadline = time.monotonic() + 3.0
        while time.monotonic() < deadline:
            reading = client.motion()["reading"]
            assert reading["state"] == "estop" and reading["speed_m_s"] == 0.0, reading
            time.sleep(0.2)
        _released(client)


def test_an_emergency_stop_during_a_campaign_job_pauses_it_and_nothing_moves_after(
    daemon: DaemonProcess,
) -> None:
    with CamdClient(daemon.url, client="erin") as client:
        nominal = float(client.wheel()["nominal_speed_deg_s"])
        job = client.start_campaign(PLAN.stem)

        def acquiring() -> bool:
            doc = client.campaign_job(job["id"])
            stream = client.stream()
            return (
                "acquire stare1" in (doc["activity"] or "")
                and stream["streaming"]
                and int(stream["stats"]["frames"]) > 10
            )

        wait_for("the job to be inside stare1", acquiring)
        assert client.wheel()["speed_deg_s"] == pytest.approx(nominal)  # the baseline's
        stop = client.estop()
        assert "acquisition" in stop["stopped"] and "campaign job" in stop["stopped"]
        done = wait_for(
            "the job to end",
            lambda: (d := client.campaign_job(job["id"]))["state"] in ENDED and d,
        )
        assert done["state"] == "paused", done
        assert "emergency stop" in str(done["message"])
        # The worker changed nothing after the stop (its closing restore would have turned the
        # wheel again): watched for 3 s after the job ended.
        assert client.control()["holder"] is None
        deadline = time.monotonic() + 3.0
        while time.monotonic() < deadline:
            assert client.wheel()["speed_deg_s"] == 0.0
            assert client.motion()["reading"]["state"] == "estop"
            assert not client.stream()["streaming"]
            time.sleep(0.2)
        # The worker may not take control back, and the job does not go on by itself.
        with pytest.raises(CamdError) as worker:
            CamdClient(daemon.url, client=f"campaign-job-{job['id']}").take_control(30)
        assert worker.value.code == "not_in_control"
        assert "an emergency stop paused it" in worker.value.message
        _latched(client, lambda: client.resume_campaign(job["id"]))
        assert client.campaign_job(job["id"])["state"] == "paused"
        # Released, the operator resumes it: the stopped acquisition is done again.
        client.release_estop()
        assert client.resume_campaign(job["id"])["state"] == "running"
        final = wait_for(
            "the resumed job to end",
            lambda: (d := client.campaign_job(job["id"]))["state"] in ENDED and d,
        )
        assert final["state"] == "passed" and final["runs"] == 2, final
        _released(client)


def test_a_killed_worker_gives_control_back_at_once(daemon: DaemonProcess) -> None:
    with CamdClient(daemon.url, client="frank") as client:
        job = client.start_campaign(PLAN.stem)
        wait_for(
            "the job to be inside an acquisition",
            lambda: (
                "acquire stare" in (client.campaign_job(job["id"])["activity"] or "")
                and client.stream()["streaming"]
            ),
        )
        assert client.control()["holder"] == f"campaign-job-{job['id']}"
        pid = _worker_pid(job["id"], daemon.pid)
        os.kill(pid, signal.SIGKILL)
        killed_at = time.monotonic()
        wait_for("control to be free", lambda: client.control()["holder"] is None, timeout_s=30.0)
        freed_s = time.monotonic() - killed_at
        assert freed_s < 30.0
        ended = client.campaign_job(job["id"])
        assert ended["state"] == "error" and "status -9" in str(ended["message"])
        wait_for("its stare to stop", lambda: not client.stream()["streaming"], timeout_s=30.0)
        # Its starter may act again at once: no lease runs out first.
        assert client.acquire(3, timeout_s=60)["stats"]["frames"] == 3
        events = [e["message"] for e in client.events(limit=40)["events"]]
        assert (
            f"control of campaign-job-{job['id']} ended (its worker exited with status -9); control is free"
            in events
        )
        with contextlib.suppress(CamdError):
            client.abort_campaign(job["id"])


def _worker_pid(job_id: int, daemon_pid: int) -> int:
    """The pid of job ``job_id``'s worker under the daemon ``daemon_pid`` (from /proc: the
    daemon does not publish it). Its parent must be that daemon: another test's daemon on
    another worker has a job of that number too, and killing its worker failed both tests."""
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        with contextlib.suppress(OSError, ValueError, IndexError):
            argv = (entry / "cmdline").read_bytes().split(b"\0")
            status = (entry / "status").read_text()
            ppid = int(status.split("PPid:", 1)[1].split()[0])
            if (
                ppid == daemon_pid
                and b"camd.campaign.worker" in argv
                and argv[argv.index(b"--job") + 1] == str(job_id).encode()
            ):
                return int(entry.name)
    raise AssertionError(f"no worker process for job {job_id} under daemon {daemon_pid}")


def test_the_latch_outlives_the_daemon_and_a_camera_that_comes_back_turning(
    tmp_path: Path,
) -> None:
    """Latched, the daemon stops; the next one (with a new simulated camera, whose wheel turns
    from power-on) is still latched and stops the wheel as soon as the camera answers; so
    it does when its camera dies and is restarted."""
    data = tmp_path / "daemon"
    first = DaemonProcess(data, extra_args=_config(data), start_timeout_s=60.0)
    with first, CamdClient(first.url, client="gina") as client:
        client.wait_ready(60.0)
        client.estop()
    assert json.loads((data / "estop.json").read_text())["latch"]["latched"]
    second = DaemonProcess(data, extra_args=_config(data), start_timeout_s=60.0)
    with second, CamdClient(second.url) as client:
        client.wait_ready(60.0)
        assert client.status()["estop"]["by"] == "gina"
        wait_for("the wheel to be stopped again", lambda: client.wheel()["speed_deg_s"] == 0.0)
        wait_for(
            "the stage to be stopped again",
            lambda: client.motion()["reading"]["state"] == "estop",
        )
        _latched(client, lambda: client.set_wheel_speed(30.0))
        # The simulated camera dies; the daemon restarts it; it powers up turning.
        restarts = int(client.status()["link"]["sim_restarts"] or 0)
        sim_pid = client.status()["link"]["sim_pid"]
        assert sim_pid is not None
        os.kill(int(sim_pid), signal.SIGKILL)
        wait_for(
            "the simulated camera to be restarted and answer",
            lambda: (
                int((s := client.status())["link"]["sim_restarts"] or 0) > restarts
                and s["state"] == "idle"
            ),
        )
        wait_for("the wheel to be stopped again", lambda: client.wheel()["speed_deg_s"] == 0.0)
        again = [
                e for e in client.events(limit=60)["events"]
                if e["source"] == "estop" and "stopped again" in e["message"]
            ]  # fmt: skip
        assert len(again) >= 2, again  # at the start, and after the camera came back
        client.release_estop()
        assert not client.status()["estop"]["latched"]
    assert second.exit_code == 0


def test_a_job_is_not_resumed_at_start_past_a_latched_emergency_stop(tmp_path: Path) -> None:
    """jobs.json holds a job the last daemon was running when it stopped; with the latch on,
    the next start leaves it interrupted, saying how to go on, and starts no worker."""
    jobs = tmp_path / "campaigns" / "jobs.json"
    jobs.parent.mkdir(parents=True)
    job = {
        "id": 4, "campaign": "long_stare", "profile": "hr400", "file": str(PLAN),
        "out_dir": str(tmp_path / "campaigns" / "4-long_stare"), "quick": True,
        "started_by": "hank", "state": "running", "steps": 8, "created_t_s": 1.0,
        "requested": None, "run_time_s": 3.0, "runs": 1, "message": None, "passed": None,
        "report": None, "pid": None, "resume_on_start": True, "started_t_s": None,
    }  # fmt: skip
    jobs.write_text(json.dumps({"format": "camd-campaign-jobs", "version": 1, "jobs": [job]}))
    said: list[tuple[str, str, str]] = []
    campaigns = CampaignJobs(
        tmp_path, lambda *e: said.append(e), lambda: False, estop_latched=lambda: True
    )
    campaigns.attach("http://127.0.0.1:9", "")
    assert campaigns.resume_interrupted() == []
    doc = campaigns.job(4)
    assert doc["state"] == "interrupted"
    assert doc["message"] == (
        "not resumed at start: the emergency stop is latched; release it (`camctl estop "
        "release`), then `camctl campaign resume 4`"
    )
    assert json.loads(jobs.read_text())["jobs"][0]["state"] == "interrupted"
    assert not (tmp_path / "campaigns" / "4-long_stare" / "worker.log").exists()


def test_sigterm_during_a_campaign_job_is_clean(tmp_path: Path) -> None:
    """The daemon stops within the unit's stop timeout, with no traceback, while a job's
    worker waits on a stare far longer than uvicorn's grace for open requests (the stare is
    ended at once, so the request answers); the job resumes at the next start."""
    data = tmp_path / "daemon"
    daemon = DaemonProcess(data, extra_args=_config(data), start_timeout_s=60.0)
    with daemon, CamdClient(daemon.url) as client:
        client.wait_ready(60.0)
        job = client.start_campaign(ENDLESS.stem)
        try:
            wait_for(
                "the job to be inside its stare",
                lambda: (
                    "acquire stare" in (client.campaign_job(job["id"])["activity"] or "")
                    and int(client.stream()["stats"]["frames"]) > 10
                ),
            )
        except AssertionError as exc:  # say what was seen: a failed job, a stalled stream
            seen = (client.campaign_job(job["id"]), client.stream()["stats"])
            tail = daemon.log_path.read_text()[-3000:]
            raise AssertionError(f"{exc}; last seen: {seen}; daemon log ends:\n{tail}") from None
        asked = time.monotonic()
        daemon.stop()
        stop_s = time.monotonic() - asked
    assert daemon.exit_code == 0 and not daemon.killed
    log = daemon.log_path.read_text()
    run = log[log.rindex("--- 2") :]  # this start's lines
    assert "Traceback" not in run and "graceful shutdown exceeded" not in run, run[-3000:]
    assert "stream ended (the daemon is stopping)" in run
    assert stop_s < 20.0, f"stopping took {stop_s:.1f} s"
    jobs = json.loads((data / "campaigns" / "jobs.json").read_text())["jobs"]
    assert jobs[0]["state"] == "interrupted" and jobs[0]["resume_on_start"], jobs[0]


def test_the_live_page_shows_the_latch_and_releases_it(
    daemon: DaemonProcess, page: tuple[Any, Any]
) -> None:
    browser_page, log = page
    browser_page.goto(f"{daemon.url}/live")
    browser_page.on("dialog", lambda dialog: dialog.accept())
    browser_page.click("#estop")
    browser_page.wait_for_selector("#estop-latched:not([hidden])", timeout=30_000)
    assert "EMERGENCY STOP LATCHED" in browser_page.inner_text("#estop-latched")
    assert "stopped stage" in browser_page.inner_text("#estop-why")
    browser_page.click("#estop-release")
    browser_page.wait_for_selector("#estop-latched", state="hidden", timeout=30_000)
    with CamdClient(daemon.url) as client:
        state = client.estop_state()
        assert not state["latched"] and state["released_by"] == state["by"]
        _released(client)
    assert log.errors == []
