"""The simulated camera's supervision (camd/daemon/sim_supervisor.py, docs/simulator.md).

First the backoff and give-up arithmetic and the supervisor's decisions, with a fake clock and
a fake process (no sleeps, no children). Then end to end: a real `camd serve --sim`, its
simulator killed with SIGKILL during streams (restarted, streaming again, the broken stream's
recording readable), the same with the USB-SPI register bridge, and the hardware case: a
simulator started separately (`camd sim`), killed and started again by hand, which the
daemon's reconnect picks up on all three links.
"""

from __future__ import annotations

import json
import os
import select
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest

from camd.daemon.config import config_from_dict
from camd.daemon.errors import SimulatorError
from camd.daemon.sim_supervisor import RestartPolicy, SimSupervisor
from camd.store.recording_reading import read_recording
from tests.test_daemon import API, REPO, Daemon, child_env, read_line, wait_for

# -- the policy: pure arithmetic ------------------------------------------------------------------


def test_backoff_doubles_to_its_cap_then_gives_up() -> None:
    policy = RestartPolicy(backoff_min_s=0.5, backoff_max_s=30.0, stable_s=60.0, limit=8)
    delays = [policy.on_failure(up_s=1.0) for _ in range(9)]
    assert delays == [0.5, 1.0, 2.0, 4.0, 8.0, 16.0, 30.0, 30.0, None]


def test_a_stable_run_starts_the_backoff_afresh() -> None:
    policy = RestartPolicy(backoff_min_s=0.5, backoff_max_s=30.0, stable_s=60.0, limit=3)
    assert [policy.on_failure(1.0) for _ in range(3)] == [0.5, 1.0, 2.0]
    # Up for a minute before it died: not one of a run of rapid failures.
    assert policy.on_failure(60.0) == 0.5
    assert policy.failures == 1
    assert [policy.on_failure(0.0) for _ in range(3)] == [1.0, 2.0, None]


# -- the supervisor, with a fake clock and a fake process -------------------------------------------


class FakeProcess:
    """Stands for SimulatorProcess: dies on demand, starts (or fails to) at once."""

    def __init__(self) -> None:
        self.link_path = Path("/tmp/x/camera.tty")
        self.pid = 100
        self.code: int | None = None
        self.stopped = False
        self.starts = 0
        self.fail_starts = 0  # the next this many starts fail
        self.forgotten = 0  # forget_link calls: the dead child's stale link removed

    @property
    def last_pid(self) -> int | None:
        return self.pid

    def returncode(self) -> int | None:
        return self.code

    def start(self) -> dict[str, Any]:
        self.starts += 1
        if self.fail_starts:
            self.fail_starts -= 1
            raise SimulatorError("the simulated camera exited with status 1 before it was ready")
        self.pid += 1
        self.code = None
        return {"pid": self.pid, "tty": "/dev/pts/9"}

    def stop_child(self) -> None:
        self.code = -15

    def refuses_link(self) -> str | None:
        return None if self.code is None else "the simulated camera is not running yet"

    def forget_link(self) -> None:
        self.forgotten += 1


class Clock:
    def __init__(self) -> None:
        self.t = 1000.0

    def __call__(self) -> float:
        return self.t


@pytest.fixture
def rig() -> tuple[FakeProcess, Clock, list[tuple[str, str]], Callable[..., SimSupervisor]]:
    process, clock, events = FakeProcess(), Clock(), []

    def make(**kw: Any) -> SimSupervisor:
        policy = RestartPolicy(
            backoff_min_s=0.5, backoff_max_s=4.0, stable_s=60.0, limit=kw.pop("limit", 3)
        )
        return SimSupervisor(
            process,
            policy,
            lambda level, _source, message: events.append((level, message)),
            clock=clock,
            spawn=lambda run: run(),  # the restart runs at once, on this thread
            **kw,
        )

    return process, clock, events, make


def test_a_death_is_reported_then_restarted_after_the_backoff(rig: Any) -> None:
    process, clock, events, make = rig
    sup = make()
    sup.check()
    assert (sup.state, events) == ("running", [])
    clock.t += 5.0
    process.code = -9
    sup.check()
    assert sup.state == "restarting" and process.starts == 0
    # The dead child's link is removed, and not reopened until the restarted one runs.
    assert process.forgotten == 1
    assert sup.refuses_link() == "the simulated camera is not running yet"
    assert events == [
        (
            "error",
            "the simulated camera (pid 100) was killed by SIGKILL after running 5.0 s; "
            "restarting it in 0.5 s (restart 1, failure 1 in a row of at most 3)",
        )
    ]
    clock.t += 0.4
    sup.check()
    assert process.starts == 0  # the backoff is not over
    clock.t += 0.1
    sup.check()
    assert (process.starts, sup.restarts, sup.state) == (1, 1, "running")
    level, message = events[-1]
    assert level == "warning"
    assert message.startswith("simulated camera restarted (restart 1): pid 101, tty /dev/pts/9")
    assert "registers are at their power-on defaults" in message
    assert sup.refuses_link() is None


def test_rapid_failures_back_off_longer_then_give_up(rig: Any) -> None:
    process, clock, events, make = rig
    sup = make()
    waits = []
    for _ in range(3):
        process.code = 1
        sup.check()
        assert sup.state == "restarting"
        t0 = clock.t
        while process.code is not None:
            clock.t += 0.25
            sup.check()
        waits.append(clock.t - t0)
    assert waits == [0.5, 1.0, 2.0] and sup.restarts == 3
    process.code = 1
    sup.check()
    assert sup.state == "gave_up"
    level, message = events[-1]
    assert level == "error"
    assert message.startswith("the simulated camera (pid 103) exited with status 1")
    assert "giving up after 3 restarts in a row" in message
    assert "camd sim --link /tmp/x/camera.tty" in message
    clock.t += 100.0
    sup.check()
    assert process.starts == 3  # given up: never started again


def test_a_failed_start_counts_as_a_failure(rig: Any) -> None:
    process, clock, events, make = rig
    sup = make()
    process.code = -9
    process.fail_starts = 1
    sup.check()
    clock.t += 0.5
    sup.check()  # the start fails: back off longer
    assert (sup.state, sup.restarts) == ("restarting", 0)
    assert "did not start again" in events[-1][1] and "restarting it in 1 s" in events[-1][1]
    clock.t += 1.0
    sup.check()
    assert (sup.state, sup.restarts, process.starts) == ("running", 1, 2)


def test_the_daemons_own_stop_is_not_restarted(rig: Any) -> None:
    process, clock, events, make = rig
    sup = make()
    process.stopped = True
    process.code = -15
    clock.t += 10.0
    sup.check()
    assert (sup.state, events, process.starts) == ("running", [], 0)


def test_restart_off_only_reports(rig: Any) -> None:
    process, _clock, events, make = rig
    sup = make(restart=False)
    process.code = -9
    sup.check()
    sup.check()
    assert sup.state == "exited" and process.starts == 0 and len(events) == 1
    assert "it is not restarted (sim.restart = false)" in events[0][1]
    # Not restarted: the link is the operator's, for a simulator started by hand.
    assert process.forgotten == 1 and sup.refuses_link() is None


def test_config_keys_and_their_order() -> None:
    sim = config_from_dict({}).sim
    assert (sim.restart, sim.restart_backoff_min_s, sim.restart_backoff_max_s) == (True, 0.5, 30.0)
    assert (sim.restart_stable_s, sim.restart_limit) == (60.0, 5)
    with pytest.raises(ValueError, match="restart_backoff_min_s"):
        config_from_dict({"sim": {"restart_backoff_min_s": 5.0, "restart_backoff_max_s": 1.0}})


# -- end to end: a real daemon and its simulator ----------------------------------------------------

SUPERVISED = """
[sim]
hk_period_s = 0.2
restart_backoff_min_s = 0.2
restart_backoff_max_s = 1.0
restart_limit = 10
[telemetry]
poll_period_s = 0.2
[link]
reconnect_min_s = 0.05
reconnect_max_s = 0.3
"""
DEADLINE_S = 90.0  # a restart takes seconds; a busy machine may take many more


def events(d: Daemon) -> list[str]:
    r = d.get(f"{API}/events", params={"limit": 1000})
    assert r.status_code == 200, r.text
    return [e["message"] for e in r.json()["events"]]


def stream_doc(d: Daemon) -> dict[str, Any]:
    r = d.get(f"{API}/stream")
    assert r.status_code == 200, r.text
    doc: dict[str, Any] = r.json()
    return doc


def acquire(d: Daemon, frames: int) -> dict[str, Any]:
    r = d.post(f"{API}/stream/acquire", json={"frames": frames, "mode": "area"})
    assert r.status_code == 200, r.text
    doc: dict[str, Any] = r.json()
    assert doc["stats"]["frames"] == frames and not doc["streaming"], json.dumps(doc, indent=1)
    return doc


def small_window(d: Daemon) -> None:
    r = d.post(f"{API}/registers", json={"values": {"WIN_ROWS": 16}})
    assert r.status_code == 200, r.text


@pytest.fixture
def supervised(tmp_path: Path) -> Iterator[Daemon]:
    d = Daemon(tmp_path, SUPERVISED)
    try:
        d.start()
        d.wait_state("idle", timeout_s=60)
        yield d
    finally:
        code = d.stop()
    assert code == 0, d.stderr()


def kill_and_wait_restarted(d: Daemon, restarts: int) -> dict[str, Any]:
    """SIGKILL the daemon's simulator; wait until it runs again, restarted ``restarts`` times
    in all, and the daemon is idle on it."""
    pid = d.status()["link"]["sim_pid"]
    assert isinstance(pid, int)
    os.kill(pid, signal.SIGKILL)
    s = wait_for(
        d.status,
        lambda s: (
            s["link"]["sim_restarts"] == restarts
            and s["link"]["sim_state"] == "running"
            and s["state"] == "idle"
        ),
        timeout_s=DEADLINE_S,
        poll_s=0.2,
    )
    assert s["link"]["sim_pid"] not in (None, pid)
    said = events(d)
    assert f"the simulated camera (pid {pid}) was killed by SIGKILL" in "\n".join(said)
    assert any(
        m.startswith(f"simulated camera restarted (restart {restarts}): pid {s['link']['sim_pid']}")
        for m in said
    )
    return s


@pytest.mark.slow
def test_simulator_killed_three_times_during_a_stream(supervised: Daemon, tmp_path: Path) -> None:
    d = supervised
    s = d.status()
    assert (s["link"]["sim_state"], s["link"]["sim_restarts"]) == ("running", 0)
    for n in (1, 2, 3):
        small_window(d)
        recording = tmp_path / f"killed-{n}.h5"
        r = d.post(
            f"{API}/stream/start", json={"frames": 0, "mode": "area", "record": str(recording)}
        )
        assert r.status_code == 200, r.text
        wait_for(lambda: stream_doc(d), lambda doc: doc["stats"]["frames"] >= 3, DEADLINE_S)

        kill_and_wait_restarted(d, n)

        # The stream that was running ended, saying why, and its recording is whole.
        doc = wait_for(lambda: stream_doc(d), lambda doc: not doc["streaming"], DEADLINE_S)
        said = "\n".join(events(d))
        assert "the stream cannot go on: " in said and f"its recording {recording}" in said
        rec = read_recording(recording)
        assert len(rec.frames) >= 3 and len(rec.frames) == doc["stats"]["frames"]
        # A new stream on the new simulator, without restarting the daemon.
        acquire(d, 3)
    assert d.status()["link"]["sim_restarts"] == 3


@pytest.mark.slow
def test_an_acquisition_cut_by_the_simulators_death_fails_clearly(supervised: Daemon) -> None:
    d = supervised
    small_window(d)
    pid = d.status()["link"]["sim_pid"]
    # A long acquisition, cut short: the client gets a clear 503 once the stream ends.
    result: dict[str, Any] = {}

    def run() -> None:
        with httpx.Client(timeout=DEADLINE_S) as http:
            r = http.post(d.url + f"{API}/stream/acquire", json={"frames": 100000, "mode": "area"})
        result["status"], result["body"] = r.status_code, r.json()

    t = threading.Thread(target=run)
    t.start()
    wait_for(lambda: stream_doc(d), lambda doc: doc["stats"]["frames"] >= 3, DEADLINE_S)
    os.kill(pid, signal.SIGKILL)
    t.join(DEADLINE_S)
    assert not t.is_alive()
    assert result["status"] == 503, result
    assert result["body"]["error"].startswith("the stream ended before its 100000 frames: ")
    wait_for(
        d.status,
        lambda s: s["link"]["sim_restarts"] == 1 and s["state"] == "idle",
        DEADLINE_S,
        0.2,
    )
    acquire(d, 3)


@pytest.mark.slow
def test_the_stale_link_of_a_killed_simulator_is_not_reopened(tmp_path: Path) -> None:
    """A killed simulator leaves its link symlink pointing at a freed pty, whose number the
    kernel soon gives to another process (on a loaded test machine, another test's simulator:
    the daemon then trained that camera and streamed 0 frames from its own). Here the stale
    link is pointed at a pty this test holds, as a reused number would be: until the restarted
    simulator has pointed the link at its own pty the daemon must not open it."""
    d = Daemon(tmp_path, SUPERVISED.replace("restart_backoff_min_s = 0.2", "restart_backoff_min_s = 4.0")
               .replace("restart_backoff_max_s = 1.0", "restart_backoff_max_s = 4.0"))  # fmt: skip
    master, slave = os.openpty()
    try:
        d.start()
        s = d.wait_state("idle", timeout_s=60)
        link, pid = Path(s["link"]["port"]), s["link"]["sim_pid"]
        assert link.is_symlink()
        os.kill(pid, signal.SIGKILL)
        stale = link.with_name(link.name + ".test")
        os.symlink(os.ttyname(slave), stale)
        os.replace(stale, link)  # the dead pty's number, now another process's
        # The daemon reconnects within 0.3 s (link.reconnect_max_s); the restart is 4 s away.
        heard = b""
        deadline = time.monotonic() + 3.0
        while time.monotonic() < deadline:
            ready, _, _ = select.select([master], [], [], 0.1)
            if ready:
                heard += os.read(master, 4096)
        assert heard == b"", f"the daemon wrote {len(heard)} bytes to another process's pty"
        s = d.status()
        assert s["link"]["connected"] is False
        assert "not running" in (s["link"]["last_error"] or "") or "points at" in (
            s["link"]["last_error"] or ""
        ), s["link"]
        s = wait_for(
            d.status,
            lambda s: s["link"]["sim_restarts"] == 1 and s["state"] == "idle",
            DEADLINE_S,
            0.2,
        )
        assert os.readlink(link) != os.ttyname(slave)
        acquire(d, 3)
    finally:
        os.close(master)
        os.close(slave)
        code = d.stop()
    assert code == 0, d.stderr()


@pytest.mark.slow
def test_usb_spi_registers_after_a_restart(tmp_path: Path) -> None:
    d = Daemon(tmp_path, SUPERVISED + '[sensor]\nbridge = "usb-spi"\n')
    try:
        d.start()
        d.wait_state("idle", timeout_s=60)
        r = d.post(f"{API}/registers", json={"values": {"WIN_ROWS": 16, "OFFSET": 77}})
        assert r.status_code == 200, r.text
        kill_and_wait_restarted(d, 1)
        # The new simulator's sensor is at its power-on defaults, read through a reopened bridge.
        r = d.get(f"{API}/registers/OFFSET")
        assert r.status_code == 200, r.text
        reset_offset = r.json()["value"]
        assert reset_offset != 77
        r = d.post(f"{API}/registers", json={"values": {"WIN_ROWS": 16, "OFFSET": 78}})
        assert r.status_code == 200, r.text
        assert d.get(f"{API}/registers/OFFSET").json()["value"] == 78
        assert d.get(f"{API}/registers").json()["bridge"] == "usb-spi"
        acquire(d, 3)
    finally:
        code = d.stop()
    assert code == 0, d.stderr()


# -- the hardware case: a simulator the daemon did not start -----------------------------------------


def start_sim(data_dir: Path) -> tuple[subprocess.Popen[str], dict[str, Any]]:
    sim = data_dir / "sim"
    proc = subprocess.Popen(
        [sys.executable, "-m", "camd", "sim", "--json", "--hk-period-s", "0.2",
         "--link", str(sim / "camera.tty"), "--usb-socket", str(sim / "usb.sock"),
         "--spi-socket", str(sim / "spi.sock")],
        cwd=REPO, env=child_env(), stdout=subprocess.PIPE, text=True,
    )  # fmt: skip
    line = read_line(proc, 60.0)
    assert line, "camd sim printed nothing"
    return proc, json.loads(line)


def stop_sim(proc: subprocess.Popen[str]) -> None:
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


@pytest.mark.slow
def test_hardware_reconnect_covers_stream_and_spi(tmp_path: Path) -> None:
    """No simulator of the daemon's own: it plays the hardware, power-cycled by hand."""
    data_dir = tmp_path / "data"
    (data_dir / "sim").mkdir(parents=True)
    if len(str(data_dir / "sim" / "spi.sock")) > 100:
        pytest.skip("the temporary directory is too deep for a Unix socket path")
    port = data_dir / "sim" / "camera.tty"
    # A link on a port is hardware: the stream and the bridge are the simulator's only when
    # the config says so (a mixed config, docs/config.md).
    config = (
        '[telemetry]\npoll_period_s = 0.2\n[sensor]\nbridge = "usb-spi"\n'
        '[sensor.usb_spi]\nbackend = "sim"\n[stream]\nbackend = "sim"\n'
        f'[link]\ndevice = "{port}"\nreconnect_min_s = 0.05\nreconnect_max_s = 0.3\n'
    )
    sim, _ = start_sim(data_dir)
    d = Daemon(tmp_path, config)
    d.cmd.remove("--sim")
    try:
        d.start()
        s = d.wait_state("idle", timeout_s=60)
        assert (s["link"]["sim_pid"], s["link"]["sim_state"], s["link"]["sim_restarts"]) == (
            None, None, None,
        )  # fmt: skip
        # Accepted, and said: a real link with the simulator's stream and bridge.
        assert s["backends"]["camera"] == "mixed"
        assert (s["backends"]["stream"]["kind"], s["backends"]["registers"]["kind"]) == (
            "sim", "sim",
        )  # fmt: skip
        assert f"camera backends mixed: link=serial {port}, stream=sim, registers=sim" in (
            d.stderr()
        )
        small_window(d)
        recording = tmp_path / "cut.h5"
        r = d.post(
            f"{API}/stream/start", json={"frames": 0, "mode": "area", "record": str(recording)}
        )
        assert r.status_code == 200, r.text
        wait_for(lambda: stream_doc(d), lambda doc: doc["stats"]["frames"] >= 3, DEADLINE_S)
        os.kill(sim.pid, signal.SIGKILL)
        sim.wait()
        d.wait_state("disconnected", timeout_s=DEADLINE_S)
        wait_for(lambda: stream_doc(d), lambda doc: not doc["streaming"], DEADLINE_S)
        assert len(read_recording(recording).frames) >= 3

        sim, _ = start_sim(data_dir)  # the camera powered up again
        d.wait_state("idle", timeout_s=DEADLINE_S)
        r = d.post(f"{API}/registers", json={"values": {"WIN_ROWS": 16, "OFFSET": 79}})
        assert r.status_code == 200, r.text
        assert d.get(f"{API}/registers/OFFSET").json()["value"] == 79
        acquire(d, 3)
    finally:
        stop_sim(sim)
        code = d.stop()
    assert code == 0, d.stderr()
