"""A daemon whose data disk is full (docs/faults.md): it still trips its red limit, says once
that the telemetry archive cannot be written, shows the events it keeps in memory and archives
them when space returns (docs/api.md, "Telemetry"); a campaign job it cannot record is refused
507 and changes nothing. A real ``camd serve --sim`` on a small tmpfs.
"""

from __future__ import annotations

import sqlite3
from pathlib import Path

import pytest

from camd.cli._daemon_proc import DaemonProcess
from camd.client import CamdClient, CamdError
from tests.crash_support import fill_disk, small_disk, wait_for

# The simulated camera's uptime_s grows with time: a red limit at this many seconds is the
# channel that crosses it while the test holds the disk full.
RED_AT_UPTIME_S = 20.0

pytestmark = pytest.mark.slow


def test_a_red_limit_trips_while_the_data_disk_is_full(tmp_path: Path) -> None:
    config = tmp_path / "camd.toml"
    config.write_text(
        "[telemetry]\npoll_period_s = 0.2\n"
        "[telemetry.limits.uptime_s]\n"
        f"yellow = [0.0, {RED_AT_UPTIME_S}]\nred = [0.0, {RED_AT_UPTIME_S}]\n"
    )
    with small_disk(tmp_path / "disk", 16) as disk:
        daemon = DaemonProcess(
            disk, extra_args=["--config", str(config)], log_name="../daemon.log",
            start_timeout_s=60.0,
        )  # fmt: skip
        with daemon, CamdClient(daemon.url) as client:
            client.wait_ready(60.0)
            fill_disk(disk)
            broken = wait_for(
                "the archive to find the disk full",
                lambda: client.telemetry()["archive_error"],
            )
            assert "full" in broken, broken
            uptime = float(client.telemetry()["latest"]["uptime_s"]["value"])
            assert uptime < RED_AT_UPTIME_S - 1.0, (
                f"the camera's uptime reached {uptime:g} s before the disk was full: the test "
                "cannot tell a red limit tripped on a full disk from one tripped before"
            )
            status = wait_for(
                "the red limit's fault", lambda: (s := client.status())["state"] == "fault" and s
            )
            assert "red limit: uptime_s" in str(status["reason"])
            # The limit's event and the archive's warning are shown though not archived.
            events = client.events(200)["events"]
            warnings = [e for e in events if e["source"] == "telemetry"]
            assert len(warnings) == 1 and "cannot be written" in warnings[0]["message"]
            assert any(
                e["source"] == "limits" and e["level"] == "error" and "uptime_s" in e["message"]
                for e in events
            )
            # The latest values stay current while nothing is archived.
            t0 = float(client.telemetry()["latest"]["uptime_s"]["t_s"])
            wait_for(
                "a newer sample",
                lambda: float(client.telemetry()["latest"]["uptime_s"]["t_s"]) > t0,
            )
            (disk / "filler").unlink()
            wait_for(
                "the archive to take writes again", lambda: not client.telemetry()["archive_error"]
            )
            recovered = wait_for(
                "the recovery event",
                lambda: [
                    e for e in client.events(200)["events"]
                    if e["source"] == "telemetry" and "written again" in e["message"]
                ],
            )  # fmt: skip
            assert len(recovered) == 1
            assert daemon.running
        assert daemon.exit_code == 0
        # The events kept in memory were archived: the file has the red limit's event.
        db = sqlite3.connect(disk / "telemetry.sqlite")
        try:
            messages = [
                m for (m,) in db.execute("SELECT message FROM events WHERE source = 'limits'")
            ]
        finally:
            db.close()
        assert any("uptime_s" in m and "red" in m for m in messages), messages
        log = (tmp_path / "daemon.log").read_text()
        assert "Traceback" not in log, log[-2000:]


def test_a_campaign_job_on_a_full_disk_is_refused_and_changes_nothing(tmp_path: Path) -> None:
    with small_disk(tmp_path / "disk", 16) as disk:
        daemon = DaemonProcess(disk, log_name="../daemon.log", start_timeout_s=60.0)
        with daemon, CamdClient(daemon.url, client="ida") as client:
            client.wait_ready(60.0)
            client.take_control(120.0)
            before = client.control()
            fill_disk(disk)
            with pytest.raises(CamdError) as refused:
                client.start_campaign("example_stare", quick=True)
            error = refused.value
            assert (error.http_status, error.code) == (507, "insufficient_storage"), error
            assert "the disk is full" in error.message and "free some space" in error.message
            # Nothing changed: no job, ida's lease as it was, nothing left on the disk.
            assert client.campaign_jobs()["jobs"] == []
            after = client.control()
            assert (after["holder"], after["expires_t_s"]) == ("ida", before["expires_t_s"])
            assert not list((disk / "campaigns").glob("1-*"))
            (disk / "filler").unlink()
            job = client.start_campaign("example_stare", quick=True)
            assert job["id"] == 1 and job["state"] == "running"
            done = wait_for(
                "the job to end",
                lambda: (j := client.campaign_job(1))["state"] not in ("running", "pausing") and j,
            )
            assert done["state"] == "passed", done
        assert daemon.exit_code == 0
