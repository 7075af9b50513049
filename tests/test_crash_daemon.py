"""The daemon's recordings survive it: ``kill -9`` in the middle of a scan and of a stare, then
a new daemon on the same data directory; and a disk that fills up under a running recording.

Each test runs a real ``camd serve --sim`` (the simulated camera through the same code paths)
and opens the files afterwards with plain h5py and camd's readers. The full-disk tests that leave
the daemon serving share one, put back as it was found after each (tests/daemon_reset.py).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import pytest

from camd.cli._daemon_proc import DaemonProcess
from camd.client import CamdClient, CamdError
from camd.store.recording_reading import read_recording
from camd.store.tdi_recording import read_tdi_scan
from tests.crash_support import NO_HEADROOM, blocks_past_end, fill_disk, small_disk, wait_for
from tests.daemon_reset import Found, put_back

REPO_ROOT = str(Path(__file__).resolve().parent.parent)
NO_TOKEN = {"CAMD_TOKEN": ""}
WAIT_S = 120.0  # generous: the suite runs on a busy 2-core machine

pytestmark = pytest.mark.slow


@contextmanager
def _daemon(data: Path) -> Iterator[tuple[DaemonProcess, CamdClient]]:
    daemon = DaemonProcess(data, env=NO_TOKEN, start_timeout_s=WAIT_S).start()
    client = CamdClient(daemon.url, timeout_s=60)
    try:
        client.wait_ready(WAIT_S)
        yield daemon, client
    finally:
        client.close()
        daemon.stop()


@dataclass(frozen=True)
class Shared:
    """The module's daemon for the tests that do not kill it, with its data directory."""

    client: CamdClient
    data: Path


@pytest.fixture(scope="module")
def shared_daemon(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Shared, Found]]:
    data = tmp_path_factory.mktemp("camd-crash-shared") / "data"
    with _daemon(data) as (_, client):
        yield Shared(client, data), Found.of(client)


@pytest.fixture
def shared(shared_daemon: tuple[Shared, Found]) -> Iterator[Shared]:
    """The module's daemon, put back as it was found after each test (tests/daemon_reset.py):
    the full-disk tests stop its recordings, not the daemon, and leave it serving."""
    daemon, found = shared_daemon
    yield daemon
    put_back(daemon.client, found)


def _kill9(daemon: DaemonProcess) -> None:
    os.kill(daemon.pid, signal.SIGKILL)
    wait_for("the daemon to die", lambda: not daemon.running)


def _event(client: CamdClient, text: str) -> dict[str, Any]:
    """The first event whose message contains ``text`` (waiting for it)."""

    def find() -> dict[str, Any] | None:
        for event in client.events(limit=500)["events"]:
            if text in event["message"]:
                return dict(event)
        return None

    found: dict[str, Any] = wait_for(f"an event with {text!r}", find)
    return found


def test_a_daemon_killed_mid_scan_leaves_a_file_that_the_next_one_repairs(
    tmp_path: Path,
) -> None:
    data, out = tmp_path / "data", tmp_path / "scan.h5"
    with _daemon(data) as (daemon, client):
        client.start_scan(8, 0, out=str(out), quicklook=False)  # until stopped
        flushed = wait_for(
            "500 lines on disk", lambda: (n := client.scan()["lines_flushed"]) >= 500 and n
        )
        _kill9(daemon)
    # What the dead daemon left: readable by SWMR readers, marked unfinished.
    scan = read_tdi_scan(out)
    n = len(scan.lines)
    assert n >= flushed
    assert scan.attrs["finished"] is False
    assert np.all(np.diff(scan.line_index) > 0) and scan.stages_used.max() == 8
    assert int(scan.lines[scan.complete].min()) > 0  # every complete line holds the scene
    with pytest.raises(OSError, match="already open for write"):
        h5py.File(out, "r")

    with _daemon(data) as (_, client):
        found = _event(client, f"found at start: scan {out} was left open")
        assert found["level"] == "warning"
        assert f": {n} lines kept, marked incomplete (finished = False)" in found["message"]
        assert "stage stopped at" in _event(client, "a scan was cut off")["message"]
        assert client.status()["state"] == "idle"
        assert client.motion()["reading"]["state"] in ("idle", "disabled")
        assert client.scan()["state"] == "none"  # the new daemon runs nothing
    with h5py.File(out, "r") as f:  # repaired: any HDF5 reader opens it now
        assert f["lines"].shape[0] == n == f.attrs["lines"]
        assert f.attrs["finished"] is np.False_ and "killed" in f.attrs["interrupted"]
    assert np.array_equal(read_tdi_scan(out).lines, scan.lines)
    assert blocks_past_end(out) < NO_HEADROOM
    assert list((data / "open-recordings").glob("*.json")) == []


def _camctl(url: str, *args: str) -> subprocess.Popen[str]:
    env = {k: v for k, v in os.environ.items() if k not in ("CAMD_URL", "CAMD_TOKEN")}
    env["PYTHONPATH"] = os.pathsep.join(p for p in (REPO_ROOT, env.get("PYTHONPATH")) if p)
    return subprocess.Popen(
        [sys.executable, "-m", "camd.cli.camctl", "--url", url, *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )


def test_a_daemon_killed_mid_stare_leaves_a_file_that_the_next_one_repairs(
    tmp_path: Path,
) -> None:
    data, out = tmp_path / "data", tmp_path / "stare.h5"
    with _daemon(data) as (daemon, client):
        stare = _camctl(daemon.url, "stare", "--frames", "400", "--out", str(out))
        try:
            flushed = wait_for(
                "20 frames on disk",
                lambda: (n := client.stream()["frames_flushed"]) >= 20 and n,
            )
            _kill9(daemon)
            _, err = stare.communicate(timeout=WAIT_S)
        finally:
            if stare.poll() is None:
                stare.kill()
                stare.wait()
        assert stare.returncode != 0 and err.strip()  # camctl says the daemon went away
    rec = read_recording(out)
    n = len(rec.frames)
    assert n >= flushed and rec.attrs["finished"] is False
    assert rec.crc_mismatches() == []  # every kept frame is the camera's, bit for bit
    assert np.all(np.diff(rec.columns["frame_counter"].astype(np.int64)) >= 1)

    with _daemon(data) as (_, client):
        found = _event(client, f"found at start: recording {out} was left open")
        assert f": {n} of 400 frames kept, marked incomplete" in found["message"]
        assert client.status()["state"] == "idle"
        assert client.stream()["streaming"] is False
        # The camera works: a new stare records.
        again = client.acquire(5, mode="area", record=str(tmp_path / "after.h5"))
        assert again["stats"]["frames"] == 5
    with h5py.File(out, "r") as f:
        assert f["frames"].shape[0] == n == f.attrs["frames"]
    assert read_recording(tmp_path / "after.h5").attrs["finished"] is True


def test_a_full_disk_stops_a_stare_and_the_daemon_keeps_serving(
    tmp_path: Path, shared: Shared
) -> None:
    client, data = shared.client, shared.data
    # 2.2 MB frames, flushed once a second: room for a few seconds of them.
    with small_disk(tmp_path / "small", 400) as disk:
        out = disk / "stare.h5"
        client.start_stream(0, mode="area", record=str(out))
        wait_for("5 frames on disk", lambda: client.stream()["frames_flushed"] >= 5)
        fill_disk(disk)
        wait_for("the stream to stop", lambda: not client.stream()["streaming"])
        event = _event(client, f"recording {out} stopped")
        assert event["level"] == "error"
        assert f"the disk holding {disk} is full (No space left on device)" in event["message"]
        assert "stopping the stream" in event["message"]
        kept = client.stream()["frames_flushed"]
        # The daemon goes on: it answers, its camera streams (to another disk), it archives.
        assert client.ping(3)["ok"] == 3
        wait_for("idle", lambda: client.status()["state"] == "idle")
        other = client.acquire(4, mode="area", record=str(tmp_path / "other.h5"))
        assert other["stats"]["frames"] == 4
        assert len(client.history("fpga_temp_degc")["channels"][0]["value"]) > 0
        rec = read_recording(out)
        assert len(rec.frames) == kept >= 5
        assert rec.attrs["finished"] is False and "is full" in rec.attrs["error"]
        assert rec.crc_mismatches() == []
        with h5py.File(out, "r") as f:  # closed properly: any reader opens it
            assert f.attrs["frames"] == kept
        assert blocks_past_end(out) < NO_HEADROOM
        assert list((data / "open-recordings").glob("*.json")) == []


def test_a_full_disk_stops_a_scan_and_the_daemon_keeps_serving(
    tmp_path: Path, shared: Shared
) -> None:
    client, data = shared.client, shared.data
    with small_disk(tmp_path / "small", 64) as disk:
        out = disk / "scan.h5"
        client.start_scan(8, 0, out=str(out), quicklook=False, drive_stage=False)
        wait_for("200 lines on disk", lambda: client.scan()["lines_flushed"] >= 200)
        fill_disk(disk)
        # A failed scan shows "failed" once its file is closed: read at once, it is whole.
        wait_for("the scan to end", lambda: client.scan()["state"] not in ("running",))
        status = client.scan()
        assert status["state"] == "failed"
        assert f"the disk holding {disk} is full" in (status["error"] or "")
        wait_for("idle", lambda: client.status()["state"] == "idle")
        assert client.ping(3)["ok"] == 3
        scan = read_tdi_scan(out)
        assert len(scan.lines) == scan.attrs["lines"] == status["lines_flushed"] >= 200
        assert scan.attrs["state"] == "failed" and "No space left" in scan.attrs["error"]
        assert np.all(np.diff(scan.line_index) > 0)
        with h5py.File(out, "r") as f:  # closed properly: any reader opens it
            assert f["lines_flushed"][0] == len(scan.lines)
        assert blocks_past_end(out) < NO_HEADROOM
        assert _journal(data) == []


def _journal(data: Path) -> list[str]:
    """The paths the daemon's journal of open recordings names."""
    return sorted(
        json.loads(entry.read_text())["path"] for entry in (data / "open-recordings").glob("*.json")
    )


def test_a_stare_that_fills_the_disk_is_a_507_and_keeps_every_frame_written(
    tmp_path: Path, shared: Shared
) -> None:
    client, data = shared.client, shared.data
    # 2.2 MB frames at up to 60 a second: 150 of them fit the 400 MiB disk with the headroom,
    # so the stare starts.
    with small_disk(tmp_path / "small", 400) as disk:
        out = disk / "stare.h5"
        answer: dict[str, Any] = {}

        def stare() -> None:
            with CamdClient(client.url, timeout_s=WAIT_S) as own:
                try:
                    answer["doc"] = own.acquire(150, mode="area", record=str(out))
                except CamdError as exc:
                    answer["error"] = exc

        thread = threading.Thread(target=stare)
        thread.start()
        # The disk fills while the stare runs (150 frames take seconds; filling, a fraction).
        # This stare's frames: the daemon is shared, and its stream document shows the last
        # test's stream until this one starts.
        wait_for(
            "3 frames",
            lambda: (
                (doc := client.stream())["recording"] == str(out)
                and doc["streaming"]
                and doc["stats"]["frames"] >= 3
            ),
        )
        assert _journal(data) == [str(out)]  # noted while it is open
        fill_disk(disk)
        thread.join(WAIT_S)
        failure = answer["error"]
        assert (failure.http_status, failure.code) == (507, "insufficient_storage")
        kept = client.stream()["frames_flushed"]
        doc = client.stream()
        delivered, lost = doc["stats"]["frames"], doc["stats"]["lost"]  # with what did not fit
        assert (
            f"the recording {out} stopped: the disk holding {disk} is full (No space left on "
            f"device); free some space or record to another disk; the recording keeps the "
            f"{kept} frames written before; the stream was stopped: {delivered} of 150 frames "
            f"delivered, {lost} lost, {doc['frames_not_sent']} not sent; the recording {out} is "
            f"closed with {kept} of them" == failure.message
        )
        assert delivered >= kept + 1  # also those that came before the stop took effect
        assert (doc["ended_early"] or "").startswith(f"the recording {out} stopped")
        # The stop reaches the camera while it sends, or after it has sent all 150 when the host
        # is behind (a fresh-clone run: the camera ended the stream 37 ms before the write of
        # frame 73 failed, the host still writing the frames it had buffered): then none is
        # "not sent"; either way the count is what the camera did not send.
        assert doc["frames_not_sent"] == 150 - (doc["frames_sent"] or 0) >= 0
        # The daemon lives: it answers, and records elsewhere.
        assert client.ping(3)["ok"] == 3
        assert (
            client.acquire(3, mode="area", record=str(tmp_path / "next.h5"))["stats"]["frames"] == 3
        )
        # The file: closed properly, it holds every frame whose write went through.
        with h5py.File(out, "r") as f:
            assert f["frames"].shape[0] == f["frames_flushed"][0] == f.attrs["frames"] == kept
            assert f.attrs["finished"] is np.False_ and "is full" in f.attrs["error"]
        rec = read_recording(out)
        assert rec.crc_mismatches() == [] and kept >= 3
        assert np.diff(rec.columns["frame_counter"].astype(np.int64)).tolist() == [1] * (kept - 1)
        assert _journal(data) == []  # taken off once the file was whole
        assert blocks_past_end(out) < NO_HEADROOM


def test_a_daemon_killed_on_a_full_disk_leaves_a_file_the_next_repairs_there(
    tmp_path: Path,
) -> None:
    data = tmp_path / "data"
    # 2.2 MB frames at up to 60 a second, flushed once a second: seconds of room.
    with small_disk(tmp_path / "small", 400) as disk:
        out = disk / "stare.h5"
        with _daemon(data) as (daemon, client):
            client.start_stream(0, mode="area", record=str(out))
            flushed = wait_for(
                "frames on disk", lambda: (n := client.stream()["frames_flushed"]) >= 1 and n
            )
            # Frozen mid-recording, the disk filled under it, then killed: it never closed.
            os.kill(daemon.pid, signal.SIGSTOP)
            fill_disk(disk)
            _kill9(daemon)
        assert _journal(data) == [str(out)]
        assert os.statvfs(disk).f_bavail == 0
        with _daemon(data) as (_, client):
            found = _event(client, f"found at start: recording {out} was left open")
            assert found["level"] == "warning"
            n = int(found["message"].split(": ")[-1].split(" frames kept")[0])
            assert n >= flushed
            assert client.status()["state"] == "idle"
        # Repaired on the full disk (into the dead writer's headroom): any reader opens it.
        with h5py.File(out, "r") as f:
            assert f["frames"].shape[0] == f["frames_flushed"][0] == f.attrs["frames"] == n
            assert "killed" in f.attrs["interrupted"]
        assert read_recording(out).crc_mismatches() == []
        assert _journal(data) == []


def test_a_start_the_disk_cannot_hold_is_refused_with_nothing_left_behind(
    tmp_path: Path, shared: Shared
) -> None:
    client, data = shared.client, shared.data
    with small_disk(tmp_path / "small", 20) as disk:
        # The issue's stare: 8 frames of the hr400's 534 x 2048 window into 20 MiB fit only
        # without the 4 MiB the recorder keeps to close the file if the disk fills.
        out = disk / "stare.h5"
        with pytest.raises(CamdError) as refused:
            client.acquire(8, mode="area", record=str(out))
        assert (refused.value.http_status, refused.value.code) == (400, "bad_request")
        assert (
            "the recording needs about 17.5 MB, and 4.2 MB more held back to close the file "
            f"safely if the disk fills, but {disk} has 21.0 MB free" in refused.value.message
        )
        assert list(disk.iterdir()) == [] and _journal(data) == []
        # The same name, for what fits: it records.
        assert client.acquire(4, mode="area", record=str(out))["stats"]["frames"] == 4
        assert read_recording(out).attrs["finished"] is True
        out.unlink()
        # A full disk refuses stares and scans alike, and leaves nothing.
        fill_disk(disk)
        scan = disk / "scan.h5"
        with pytest.raises(CamdError, match=f"but {disk} has 0.0 MB free"):
            client.acquire(1, mode="area", record=str(out))
        with pytest.raises(CamdError, match=f"but {disk} has 0.0 MB free"):
            client.start_scan(8, 50, out=str(scan), quicklook=False, drive_stage=False)
        assert [p.name for p in disk.iterdir()] == ["filler"] and _journal(data) == []
        assert client.status()["state"] == "idle"
        # Space again: both names work.
        (disk / "filler").unlink()
        client.start_scan(8, 50, out=str(scan), quicklook=False, drive_stage=False)
        assert client.wait_scan(WAIT_S)["state"] == "done"
        assert client.acquire(1, mode="area", record=str(out))["stats"]["frames"] == 1
        assert read_tdi_scan(scan).attrs["complete_lines"] == 50
