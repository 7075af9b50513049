"""A refused request changes nothing; one acquisition at a time; busy errors name what runs.

Over the full stack (HTTP -> camd serve -> simulated camera): the camera's state is read back
from the device itself (mode from GET_STATUS, every register, the stage's MOTOR_GET) before and
after each refused request and compared.
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import h5py
import httpx
import pytest

from camd.client import CamdClient, CamdError
from tests.device_snapshot import snapshot
from tests.test_camctl import camctl
from tests.test_sensor_stack import serve

# Not ``exclusive``: refusals, one acquisition at a time, busy errors; the scans run slowly
# (20 ms lines, binned: inside the daemon's queue) or until stopped, and nothing is asked of
# their timing. Checked beside `stress-ng --cpu 2`.


@contextlib.contextmanager
def small_window_daemon(tmp: Path) -> Iterator[str]:
    """A daemon on the simulated camera with a 16-row window (short frames: quick scans);
    yields its URL and checks it exits cleanly."""
    with serve(tmp, "fpga") as daemon:
        with CamdClient(daemon.url) as client:
            client.write_registers({"WIN_ROWS": 16, "EXPOSURE": 4})
        yield daemon.url
    assert daemon.exit_code in (0, -15), daemon.log_path.read_text()


@pytest.fixture(scope="module")
def url(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    with small_window_daemon(tmp_path_factory.mktemp("camd-trust")) as url:
        yield url


def test_a_refused_scan_changes_nothing(url: str, tmp_path: Path) -> None:
    """The issue's case: area mode, a driven scan into a directory that does not exist."""
    with CamdClient(url) as client:
        client.set_mode("area")
        client.enable_stage(True)
        client.move_stage(0.3)
        before = snapshot(client)
        out = str(tmp_path / "nodir/x.h5")
        proc = camctl(
            url, "scan", "--stages", "4", "--lines", "5", "--line-period-s", "3e-3", "--out", out
        )
        assert proc.returncode == 1
        assert f"the directory {tmp_path / 'nodir'} does not exist; create it first" in (
            proc.stderr
        )
        assert snapshot(client) == before
        # Beyond the stage's travel: refused with the numbers, nothing moved or written.
        with pytest.raises(CamdError) as info:
            client.start_scan(4, 10_000_000, out=str(tmp_path / "long.h5"), line_period_s=3e-3)
        assert info.value.code == "bad_request"
        assert "mm of travel" in info.value.message and "soft limits leave" in info.value.message
        assert snapshot(client) == before
        assert not (tmp_path / "long.h5").exists()
        # Stages that the line period's window cannot hold.
        with pytest.raises(CamdError, match="window rows but the scan's frames have"):
            client.start_scan(40, 5, out=str(tmp_path / "m.h5"), line_period_s=2e-4)
        assert snapshot(client) == before
        assert client.scan()["state"] in ("none", "done", "stopped")


def test_two_scans_at_once_one_runs_and_the_status_shows_it(url: str, tmp_path: Path) -> None:
    paths = [tmp_path / "a.h5", tmp_path / "b.h5"]
    answers: list[httpx.Response] = []
    lock = threading.Lock()
    barrier = threading.Barrier(2)

    # 20 ms lines: the scan runs 4 s, so the other request comes while it runs however late
    # a busy machine sends it (at the window's own line period, 200 lines take 0.1 s). Binned
    # 2x2: a line period's window is 974 rows, and a full-width TDI stream is 200 MB/s at any
    # line period; binned, the 203 frames are 202 MB, inside the daemon's queue (256 MB), so a
    # busy host that consumes them late still gets every line. Unbinned (1 GB) a loaded run
    # lost 8 of them to the queue.
    def start(path: Path) -> None:
        body = {"stages": 4, "lines": 200, "out": str(path), "drive_stage": False,
                "line_period_s": 0.020, "binning": "2x2"}  # fmt: skip
        with httpx.Client(base_url=url, timeout=60) as http:
            barrier.wait()
            response = http.post("/api/v1/scan/start", json=body)
        with lock:
            answers.append(response)

    threads = [threading.Thread(target=start, args=(p,)) for p in paths]
    for t in threads:
        t.start()
    for t in threads:
        t.join(90)
    codes = sorted(r.status_code for r in answers)
    assert codes == [200, 409], [r.text for r in answers]
    ran = next(r.json() for r in answers if r.status_code == 200)
    refused = next(r.json() for r in answers if r.status_code == 409)
    assert refused["code"] == "busy"
    assert f"a scan is running (M = 4, 200 lines to {ran['file']}" in refused["error"]
    assert "`camctl scan --stop`" in refused["error"]
    with CamdClient(url) as client:
        done = client.wait_scan(60)
        assert done["file"] == ran["file"] and done["state"] == "done"
        assert done["lines"] == 200 + 4 - 1
    loser = next(p for p in paths if str(p) != ran["file"])
    assert not loser.exists()


def test_requests_that_would_disturb_a_scan_are_refused_naming_it(url: str, tmp_path: Path) -> None:
    with CamdClient(url) as client:
        before = snapshot(client)
        scan = client.start_scan(4, 0, out=str(tmp_path / "long.h5"), drive_stage=False)
        try:
            for call, what in (
                (lambda: client.set_mode("area"), "cannot change the imaging mode"),
                (lambda: client.reset(), "cannot reset the camera"),
                (lambda: client.write_registers({"EXPOSURE": 3}), "cannot write sensor registers"),
                (
                    lambda: client.acquire(3),
                    "cannot take frames (`camctl stream --frames N`, `camctl stare`)",
                ),
                (lambda: client.start_scan(4, 5, drive_stage=False), "cannot start a scan"),
                (lambda: client.move_stage(0.2), "cannot move the stage"),
            ):
                with pytest.raises(CamdError) as info:
                    call()
                assert info.value.code == "busy", info.value.message
                assert info.value.message.startswith(f"{what}: a scan is running")
                assert f"to {scan['file']}" in info.value.message
                assert info.value.message.endswith("stop it with `camctl scan --stop`")
            assert client.scan()["file"] == scan["file"]
        finally:
            stopped = client.stop_scan()
        assert stopped["state"] == "stopped" and stopped["file"] == scan["file"]
        after = snapshot(client)
        # The scan put the camera in tdi mode; nothing the refused requests asked was done.
        assert after["registers"] == before["registers"]
        assert after["stage"] == before["stage"]


def test_an_emergency_stop_ends_a_running_scan_stopped_with_its_file_closed(
    url: str, tmp_path: Path
) -> None:
    with CamdClient(url) as client:
        scan = client.start_scan(4, 0, out=str(tmp_path / "estop.h5"), drive_stage=False)
        deadline = time.monotonic() + 60
        while client.scan()["lines"] == 0:  # lines on their way to the file
            assert time.monotonic() < deadline, client.scan()
            time.sleep(0.05)
        answer = client.estop()
        assert "acquisition" in answer["stopped"] and answer["failed"] == []
        ended = client.wait_scan(60)
        assert ended["state"] == "stopped" and ended["file"] == scan["file"]
        with h5py.File(scan["file"], "r") as f:  # no writer holds it open any more
            assert f.attrs["finished"] and f.attrs["state"] == "stopped"
            assert f["lines"].shape[0] == ended["lines"] > 0
        assert client.estop_state()["latched"]
        client.release_estop()  # nothing moves or acquires until then
        client.enable_stage(True)  # clears the stage's emergency stop
