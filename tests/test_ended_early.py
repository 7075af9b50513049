"""Acquisitions that end short are never done: a stream, a stare and a scan that the camera ends
early (the simulator's SIM_FAIL_NEXT end_stream, POST /api/v1/sim/fail-next end_after_frames),
and a scan cut by a killed simulator. Each says why it ended early, counts the frames that never
came, keeps a file that says so, and camctl exits 1 with the reason (docs/stream.md, "Streams
that end early"; docs/scan.md, "The result").

One daemon (camd serve --sim, hr400 with a 32-row window: frames at a few kHz) for the module;
the killed simulator comes last and is waited back.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import h5py
import numpy as np
import pytest

from camd.client import CamdClient, CamdError
from camd.store import read_recording
from camd.store.tdi_recording import read_tdi_scan
from tests.crash_support import wait_for
from tests.test_camctl import camctl, camctl_env, camctl_json
from tests.test_sensor_stack import serve

pytestmark = pytest.mark.slow

ROWS = 32  # a small window keeps the simulator fast
WAIT_S = 120.0  # generous: the suite runs on a busy 2-core machine


@pytest.fixture(scope="module")
def url(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    with serve(tmp_path_factory.mktemp("camd-ended-early"), "fpga") as daemon:
        camctl_json(daemon.url, "reg", "write", f"WIN_ROWS={ROWS}", "EXPOSURE=4")
        yield daemon.url
    assert daemon.exit_code in (0, -15), daemon.log_path.read_text()


@pytest.fixture
def client(url: str) -> Iterator[CamdClient]:
    with CamdClient(url, timeout_s=60) as c:
        yield c
        c.clear_fail_next()


def test_a_stare_the_camera_ends_early_fails_with_its_counts_and_its_file(
    url: str, client: CamdClient, tmp_path: Path
) -> None:
    out = tmp_path / "stare.h5"
    client.fail_next("START_STREAM", end_after_frames=3)
    proc = camctl(url, "stare", "--frames", "10", "--out", str(out))
    assert proc.returncode == 1, proc.stdout
    assert "Traceback" not in proc.stderr
    doc = client.stream()
    assert (doc["frames_requested"], doc["frames_sent"], doc["frames_not_sent"]) == (10, 3, 7)
    assert doc["ended_early"] == "the camera ended the stream after 3 of 10 frames (STREAM_DONE)"
    # The 3 frames sent came, or are counted lost (a loaded host may miss a stream's first).
    got, lost = doc["stats"]["frames"], doc["stats"]["lost"]
    assert got + lost == 3 and doc["frames_flushed"] == got
    assert (
        "camctl: error: the stream ended before its 10 frames: the camera ended the stream "
        f"after 3 of 10 frames (STREAM_DONE); {got} of 10 frames delivered, {lost} lost, 7 not "
        f"sent; the recording {out} is closed with {got} of them" in proc.stderr
    )
    rec = read_recording(out)
    assert len(rec.frames) == rec.attrs["frames"] == got and rec.attrs["frames_expected"] == 10
    assert rec.attrs["finished"] is True and rec.attrs["ended_early"] == doc["ended_early"]
    assert rec.metadata["stream"]["frames_not_sent"] == 7
    assert rec.crc_mismatches() == []
    with h5py.File(out, "r") as f:
        assert f["frames_flushed"][0] == got
    assert client.status()["state"] == "idle"


def test_a_stream_the_camera_ends_early_is_an_ended_early_error(client: CamdClient) -> None:
    client.fail_next("START_STREAM", end_after_frames=5)
    with pytest.raises(CamdError) as failed:
        client.acquire(20, mode="tdi", stages=8)
    assert failed.value.code == "ended_early"
    assert "the camera ended the stream after 5 of 20 frames (STREAM_DONE)" in str(failed.value)
    doc = client.stream()
    got, lost = doc["stats"]["frames"], doc["stats"]["lost"]
    assert got + lost == 5 and doc["frames_not_sent"] == 15
    assert f"{got} of 20 frames delivered, {lost} lost, 15 not sent" in str(failed.value)
    # The next stream is whole again: nothing of the fault or the shortfall is left.
    doc = client.acquire(6, mode="area")
    assert (doc["stats"]["frames"], doc["frames_not_sent"], doc["ended_early"]) == (6, 0, None)


def test_a_stream_until_stopped_that_the_camera_ends_says_so(client: CamdClient) -> None:
    client.fail_next("START_STREAM", end_after_frames=4)
    client.start_stream(0, mode="area")
    doc = wait_for("the stream to end", lambda: not (d := client.stream())["streaming"] and d)
    assert doc["ended_early"] == "the camera ended the stream after 4 frames (STREAM_DONE)"
    assert (doc["frames_sent"], doc["frames_not_sent"]) == (4, 0)
    assert doc["stats"]["frames"] + doc["stats"]["lost"] == 4
    # The event is logged just after the stream document says it ended: wait for it.
    wait_for(
        "the stream's end event",
        lambda: any(
            e["message"].startswith(
                "stream ended (the camera ended the stream after 4 frames (STREAM_DONE))"
            )
            for e in client.events(limit=50)["events"]
        ),
    )


def test_a_stream_stopped_on_request_did_not_end_early(client: CamdClient) -> None:
    client.start_stream(1_000_000, mode="area")
    wait_for("frames", lambda: client.stream()["stats"]["frames"] >= 3)
    doc = client.stop_stream()
    assert doc["ended_early"] is None
    # Its frames not sent are counted all the same: the camera's own count.
    sent = doc["frames_sent"]
    assert sent is not None and doc["frames_not_sent"] == 1_000_000 - sent > 0


def test_a_stare_stopped_by_another_client_is_not_done(
    url: str, client: CamdClient, tmp_path: Path
) -> None:
    out = tmp_path / "stopped.h5"
    stare = subprocess.Popen(
        [sys.executable, "-m", "camd.cli.camctl", "--url", url, "stare", "--frames", "20000",
         "--out", str(out)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=camctl_env(),
    )  # fmt: skip
    try:

        def flushed() -> bool:
            # A stare that ended at once (refused) says why, instead of a 120 s wait for frames.
            if stare.poll() is not None:
                raise AssertionError(f"the stare ended first: {stare.communicate()}")
            return int(client.stream()["frames_flushed"]) >= 3

        wait_for("3 frames on disk", flushed)
        stopped = client.stop_stream()
        _, err = stare.communicate(timeout=WAIT_S)
    finally:
        if stare.poll() is None:
            stare.kill()
            stare.wait()
    assert stare.returncode == 1
    kept, sent = stopped["frames_flushed"], stopped["frames_sent"]
    assert sent is not None and stopped["ended_early"] is None  # as asked, by its stopper
    assert (
        "camctl: error: the stream was stopped before its 20000 frames (`camctl stream "
        "--stop`, an emergency stop or the daemon stopping): "
        f"{stopped['stats']['frames']} of 20000 frames delivered, {stopped['stats']['lost']} "
        f"lost, {20000 - sent} not "
        f"sent; the recording {out} is closed with {kept} of them" in err
    )
    assert read_recording(out).attrs["frames"] == kept >= 3


def test_fail_next_end_after_frames_is_for_commands_that_start_a_stream(
    client: CamdClient,
) -> None:
    with pytest.raises(CamdError) as refused:
        client.fail_next("PING", end_after_frames=3)
    assert refused.value.code == "bad_request"
    assert (
        "end_after_frames ends the stream a command starts: give command START_STREAM or "
        "WHEEL_ACQUIRE, not PING" in str(refused.value)
    )
    with pytest.raises(CamdError, match=r"give one of error .*, not several or none"):
        client.fail_next("START_STREAM", error="BUSY", end_after_frames=3)
    # Nothing was armed: a stream runs whole.
    assert client.acquire(4, mode="area")["stats"]["frames"] == 4


def _scan_args(out: Path, lines: int, url: str) -> list[str]:
    with CamdClient(url) as c:
        row_s = float(c.timing()["line_period_s"])
    # 48 rows' time a line (about 1 kHz): steady on a busy machine.
    return [
        "scan", "--no-stage", "--stages", "8", "--lines", str(lines), "--line-period-s",
        repr(48 * row_s), "--out", str(out), "--no-quicklook",
    ]  # fmt: skip


def test_a_scan_the_camera_ends_early_is_not_done(
    url: str, client: CamdClient, tmp_path: Path
) -> None:
    out = tmp_path / "scan.h5"
    client.fail_next("START_STREAM", end_after_frames=20)
    try:
        proc = camctl(url, *_scan_args(out, 100, url))
    finally:
        camctl_json(url, "reg", "write", f"WIN_ROWS={ROWS}")  # the module's window again
    assert proc.returncode == 1, proc.stdout
    why = "the stream ended early: the camera ended the stream after 20 of 107 frames (STREAM_DONE)"
    doc = client.scan()
    assert (doc["state"], doc["error"]) == ("ended_early", why)
    assert (doc["frames_requested"], doc["not_sent_frames"]) == (107, 87)
    # The 20 frames sent made a line each, or are counted lost (a loaded host may miss some).
    n, lost = doc["lines"], doc["lost_frames"]
    assert n + lost == 20 and doc["lines_flushed"] == n > 0
    assert (
        f"camctl: error: the scan ended early: {why}; {n} of 100 lines, 87 frames not sent, "
        f"{lost} lost; {out} holds the lines that came" in proc.stderr
    )
    scan = read_tdi_scan(out)
    assert len(scan.lines) == scan.attrs["lines"] == n
    assert (scan.attrs["state"], scan.attrs["error"]) == ("ended_early", why)
    assert scan.metadata["counters"]["not_sent_frames"] == 87
    assert (
        np.all(np.diff(scan.line_index) > 0) and 0 <= scan.line_index[0] <= scan.line_index[-1] < 20
    )


def test_a_scan_cut_by_a_killed_simulator_counts_the_frames_that_never_came(
    url: str, client: CamdClient, tmp_path: Path
) -> None:
    out = tmp_path / "killed.h5"
    lines = 200_000  # minutes of scan: the simulator is killed long before
    camctl_json(url, *_scan_args(out, lines, url), "--detach")
    try:
        wait_for("200 lines", lambda: client.scan()["lines"] >= 200)
        pid = client.status()["link"]["sim_pid"]
        assert isinstance(pid, int)
        os.kill(pid, signal.SIGKILL)
        doc = client.wait_scan(WAIT_S)
    finally:
        wait_for(
            "the simulator back and the daemon idle",
            lambda: (
                (s := client.status())["link"]["sim_state"] == "running" and s["state"] == "idle"
            ),
        )
        camctl_json(url, "reg", "write", f"WIN_ROWS={ROWS}", "EXPOSURE=4")
    assert doc["state"] == "failed"
    assert (doc["error"] or "").startswith("the stream ended early: the USB frame stream failed")
    stream = doc["stream"]
    # The camera could not say what it sent: every frame the host neither got nor knows it
    # missed is counted as not sent, none is left uncounted.
    accounted = (
        stream["frames"] + stream["lost"] + stream["corrupt"] + stream["short"]
        + stream["overruns"]
    )  # fmt: skip
    assert doc["frames_requested"] == lines + 7
    assert doc["not_sent_frames"] == doc["frames_requested"] - accounted > lines - 100_000
    assert doc["lost_frames"] + doc["lines"] <= accounted
    scan = read_tdi_scan(out)
    assert len(scan.lines) == scan.attrs["lines"] == doc["lines_flushed"] >= 200
    assert scan.attrs["state"] == "failed"
    assert scan.metadata["counters"]["not_sent_frames"] == doc["not_sent_frames"]
