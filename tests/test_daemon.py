"""`camd serve --sim` end to end: a real daemon process, a real simulator on a pty, real HTTP.

Each daemon is started as ``python -m camd serve ... --port 0`` and found through its
``camd serving http://HOST:PORT`` line; every process is stopped in a finally block.
"""

from __future__ import annotations

import contextlib
import json
import os
import select
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, TypeVar, cast

import httpx
import pytest
from websockets.exceptions import InvalidStatus
from websockets.sync.client import connect as ws_connect

REPO = Path(__file__).resolve().parent.parent
API = "/api/v1"
JSON_HEADER = {"content-type": "application/json"}
T = TypeVar("T")

# Fast telemetry and reconnects keep the whole file well under a minute.
FAST = """
[sim]
hk_period_s = 0.2
[telemetry]
poll_period_s = 0.2
[link]
reconnect_min_s = 0.05
reconnect_max_s = 0.3
"""
# FAST plus a 2 s wait for each attempt on the link (appended: FAST's last table is [link]).
# The config's 0.1 s is for a real line; on a busy machine a starved simulator can take longer
# than that to answer, which would count as a retry (or, six times over, a failed command).
PATIENT = FAST + "timeout_s = 2.0\n"
LINK_TIMEOUT_S = 2.0


def child_env() -> dict[str, str]:
    env = dict(os.environ)
    for key in ("CAMD_TOKEN", "NOTIFY_SOCKET", "WATCHDOG_USEC", "WATCHDOG_PID"):
        env.pop(key, None)
    env["PYTHONPATH"] = os.pathsep.join(p for p in [str(REPO), env.get("PYTHONPATH")] if p)
    env["PYTHONUNBUFFERED"] = "1"
    return env


def read_line(proc: subprocess.Popen[str], timeout_s: float) -> str:
    """The child's first stdout line, or '' if it exits or stays silent for ``timeout_s``."""
    assert proc.stdout is not None
    ready, _, _ = select.select([proc.stdout], [], [], timeout_s)
    return proc.stdout.readline() if ready else ""


class Daemon:
    """A `camd serve` subprocess and an HTTP client to it."""

    def __init__(self, tmp_path: Path, config: str = FAST, *extra: str) -> None:
        self.data_dir = tmp_path / "data"
        self.config_path = tmp_path / "camd.toml"
        self.config_path.write_text(config)
        self.stderr_path = tmp_path / "daemon.stderr"
        self.cmd = [sys.executable, "-m", "camd", "serve", "--config", str(self.config_path),
                    "--sim", "--port", "0", "--data-dir", str(self.data_dir), *extra]  # fmt: skip
        self.proc: subprocess.Popen[str] | None = None
        self.url = ""
        # Named, as camctl's requests are: a bodyless POST without it is refused (docs/api.md).
        self.http = httpx.Client(timeout=30.0, headers={"X-Camd-Client": "test-daemon"})

    def start(self) -> Daemon:
        with open(self.stderr_path, "w") as err:
            self.proc = subprocess.Popen(
                self.cmd, cwd=REPO, env=child_env(), stdout=subprocess.PIPE, stderr=err, text=True
            )
        line = read_line(self.proc, 30.0)
        assert line.startswith("camd serving http://"), f"{line!r}\n{self.stderr()}"
        self.url = line.split()[2]
        return self

    def stderr(self) -> str:
        return self.stderr_path.read_text()

    def stop(self) -> int | None:
        self.http.close()
        if self.proc is None:
            return None
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout=15)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        return self.proc.returncode

    def get(self, path: str, **kw: Any) -> httpx.Response:
        return self.http.get(self.url + path, **kw)

    def post(self, path: str, **kw: Any) -> httpx.Response:
        return self.http.post(self.url + path, **kw)

    def status(self) -> dict[str, Any]:
        r = self.get(f"{API}/status")
        assert r.status_code == 200, r.text
        return cast(dict[str, Any], r.json())

    def wait_state(self, state: str, timeout_s: float = 30.0) -> dict[str, Any]:
        return wait_for(lambda: self.status(), lambda s: s["state"] == state, timeout_s)


def wait_for(
    probe: Callable[[], T], done: Callable[[T], Any], timeout_s: float, poll_s: float = 0.05
) -> T:
    """Call ``probe`` until ``done(value)`` holds; fail the test after ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    value = probe()
    while not done(value):
        assert time.monotonic() < deadline, f"gave up after {timeout_s} s; last: {value}"
        time.sleep(poll_s)
        value = probe()
    return value


@contextlib.contextmanager
def idle_daemon(tmp: Path) -> Iterator[Daemon]:
    """A daemon on PATIENT in ``tmp``, idle; it must exit 0 (also tests/test_daemon_telemetry.py)."""
    d = Daemon(tmp, PATIENT)
    try:
        d.start()
        d.wait_state("idle")
        yield d
    finally:
        code = d.stop()
    assert code == 0, d.stderr()


@pytest.fixture(scope="module")
def daemon(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Daemon]:
    with idle_daemon(tmp_path_factory.mktemp("daemon")) as d:
        yield d


def error_of(r: httpx.Response, status: int, code: str) -> str:
    assert r.status_code == status, r.text
    body = r.json()
    assert set(body) == {"error", "code"} and body["code"] == code, body
    message: str = body["error"]
    return message


# -- the shared daemon ----------------------------------------------------------------------------


def test_status_idle_with_device_fields(daemon: Daemon) -> None:
    s = daemon.status()
    assert s["state"] == "idle" and s["reason"] is None and s["mode"] in ("area", "tdi")
    assert s["link"]["connected"] is True
    assert s["link"]["port"] == str(daemon.data_dir / "sim" / "camera.tty")
    assert isinstance(s["link"]["sim_pid"], int)
    dev = s["device"]
    assert dev["device_state"] == "idle" and dev["fault_code"] == 0
    assert dev["fw_version"] > 0 and dev["boot_count"] >= 1 and dev["uptime_s"] > 0
    assert s["daemon"]["pid"] == daemon.proc.pid if daemon.proc else False
    assert s["daemon"]["uptime_s"] > 0 and s["daemon"]["version"]


def test_ping_fifty(daemon: Daemon) -> None:
    r = daemon.post(f"{API}/ping", json={"count": 50, "size": 32})
    assert r.status_code == 200, r.text
    p = r.json()
    assert (p["count"], p["ok"], p["failed"], p["retries"], p["errors"]) == (50, 50, 0, 0, [])
    rtt = p["rtt_ms"]
    # No retries, so each answer came within one attempt's wait (in ms; a second of slack for
    # a busy machine to get from the answer to the clock).
    assert 0 < rtt["p50"] <= rtt["p99"] <= rtt["max"] < 1000 * (LINK_TIMEOUT_S + 1)


def test_ping_defaults_without_a_body(daemon: Daemon) -> None:
    p = daemon.post(f"{API}/ping").json()
    assert (p["count"], p["ok"]) == (10, 10)
    p = daemon.post(f"{API}/ping", json={"count": 3, "size": 0}).json()
    assert (p["count"], p["ok"]) == (3, 3)


def test_mode_tdi_then_status_shows_it(daemon: Daemon) -> None:
    r = daemon.post(f"{API}/mode", json={"mode": "tdi"})
    assert r.status_code == 200 and r.json() == {"mode": "tdi"}, r.text
    s = daemon.status()
    assert s["mode"] == "tdi" and s["device"]["mode"] == "tdi"
    assert daemon.post(f"{API}/mode", json={"mode": "area"}).json() == {"mode": "area"}


def test_link_counters(daemon: Daemon) -> None:
    # Under xdist this may be the first test on a fresh daemon: wait for a telemetry packet.
    doc = wait_for(
        lambda: daemon.get(f"{API}/link").json(),
        lambda d: d["host"]["telemetry"] > 0,
        timeout_s=30,
    )
    assert doc["host"]["sent"] > 0 and doc["host"]["acked"] > 0 and doc["host"]["telemetry"] > 0
    dev = doc["device"]
    assert dev["executed"] > 0 and dev["crc_errors"] == 0
    assert dev["injected"] == {
        "bit_errors": 0, "dropped_rx": 0, "dropped_tx": 0, "garbage_bursts": 0, "delayed": 0,
        "executed_twice": 0,
    }  # fmt: skip


def test_events_newest_last(daemon: Daemon) -> None:
    events = daemon.get(f"{API}/events", params={"limit": 1000}).json()["events"]
    assert any("disconnected -> idle" in e["message"] for e in events)
    assert [e["t_s"] for e in events] == sorted(e["t_s"] for e in events)
    assert len(daemon.get(f"{API}/events", params={"limit": 2}).json()["events"]) == 2


def test_metrics(daemon: Daemon) -> None:
    # Under xdist this may be the first test on a fresh daemon: wait for a first sample.
    text = wait_for(
        lambda: daemon.get("/metrics").text,
        lambda t: 'camd_telemetry_value{channel="fpga_temp_degc"' in t,
        timeout_s=30,
    )
    assert 'camd_state{state="idle"} 1.0' in text
    assert 'camd_state{state="fault"} 0.0' in text
    assert "camd_link_sent_total" in text and "camd_link_crc_errors_total" in text
    assert 'camd_telemetry_value{channel="fpga_temp_degc",unit="degC"}' in text


def test_openapi_lists_the_endpoints(daemon: Daemon) -> None:
    paths = daemon.get("/openapi.json").json()["paths"]
    for path in ("status", "ping", "link", "telemetry", "telemetry/history", "events", "mode",
                 "reset"):  # fmt: skip
        assert f"{API}/{path}" in paths


@pytest.mark.parametrize(
    ("method", "path", "kw", "words"),
    [
        ("post", "mode", {"json": {"mode": "foo"}}, ["mode", "'foo'", "area or tdi"]),
        ("post", "mode", {"json": {}}, ["mode", "required", "area or tdi"]),
        ("post", "ping", {"json": {"count": 0}}, ["count", "0", "1..100000"]),
        ("post", "ping", {"json": {"count": 100001}}, ["count", "1..100000"]),
        ("post", "ping", {"json": {"size": 257}}, ["size", "0..256"]),
        ("post", "ping", {"json": {"count": "many"}}, ["count", "'many'"]),
        ("post", "ping", {"json": {"cuont": 5}}, ["cuont", "unknown"]),
        ("post", "ping", {"content": b"{nope", "headers": JSON_HEADER}, ["not valid JSON"]),
        ("get", "telemetry/history", {"params": {"channel": "cpu"}}, ["'cpu'", "fpga_temp_degc"]),
        ("get", "telemetry/history", {}, ["channel", "required"]),
        ("get", "events", {"params": {"start": "soon"}}, ["start: 'soon' is not a time"]),
        ("get", "events", {"params": {"limit": 0}}, ["limit"]),
    ],
)
def test_bad_requests_are_400_naming_the_parameter(
    daemon: Daemon, method: str, path: str, kw: dict[str, Any], words: list[str]
) -> None:
    r = getattr(daemon, method)(f"{API}/{path}", **kw)
    message = error_of(r, 400, "bad_request")
    for word in words:
        assert word in message, message


def test_unknown_endpoint_is_a_json_error(daemon: Daemon) -> None:
    message = error_of(daemon.get(f"{API}/nope"), 404, "not_found")
    assert "/api/v1/nope" in message
    error_of(daemon.get(f"{API}/mode"), 405, "method_not_allowed")


# -- a red limit puts the daemon in fault -------------------------------------------------------


def test_red_limit_fault_refuses_mode_until_reset(tmp_path: Path) -> None:
    # vcc_io_v is ~3.3 V: limits around 0 V make every sample red.
    tight = PATIENT + "[telemetry.limits.vcc_io_v]\nyellow = [0.0, 0.1]\nred = [0.0, 0.2]\n"
    d = Daemon(tmp_path, tight)
    try:
        d.start()
        s = d.wait_state("fault")
        assert "red limit" in s["reason"] and "vcc_io_v" in s["reason"]

        message = error_of(d.post(f"{API}/mode", json={"mode": "tdi"}), 409, "illegal_state")
        assert "fault" in message and "vcc_io_v" in message and "camctl reset" in message
        assert d.post(f"{API}/ping", json={"count": 3}).json()["ok"] == 3  # legal in fault

        tel = d.get(f"{API}/telemetry").json()["latest"]
        assert tel["vcc_io_v"]["limit"] == "red"
        events = d.get(f"{API}/events").json()["events"]
        assert any(e["source"] == "limits" and e["level"] == "error" for e in events)

        r = d.post(f"{API}/reset")
        assert r.status_code == 200, r.text
        after = r.json()
        assert after["state"] == "idle" and after["mode"] == "area"
        # Still red but acknowledged by the reset: no new fault until it recovers. Three red
        # samples taken after the reset (not a fixed sleep, which a busy daemon could sleep
        # through without taking any) have been checked against the limits.
        reset_at = time.time()
        wait_for(
            lambda: d.get(
                f"{API}/telemetry/history", params={"channel": "vcc_io_v", "since_s": reset_at}
            ).json()["channels"][0]["t_s"],
            lambda t_s: len(t_s) >= 3,
            timeout_s=30,
        )
        assert d.status()["state"] == "idle"
        assert d.post(f"{API}/mode", json={"mode": "tdi"}).json() == {"mode": "tdi"}
        assert 'camd_state{state="idle"} 1.0' in d.get("/metrics").text
    finally:
        code = d.stop()
    assert code == 0, d.stderr()


# -- a lossy line: retries are counted, nothing is lost -------------------------------------------


def test_ping_over_a_lossy_line_counts_retries(tmp_path: Path) -> None:
    # 50 ms attempts, 40 retries: a lost frame costs 50 ms, a busy machine's late answer is a
    # replay (2 s per command before a failure), so every ping must get through.
    d = Daemon(tmp_path, FAST + "timeout_s = 0.05\nretries = 40\n", "--inject", "drop=0.05")
    try:
        d.start()
        d.wait_state("idle")
        p = d.post(f"{API}/ping", json={"count": 200}).json()
        assert p["ok"] == 200 and p["failed"] == 0, p
        assert p["retries"] > 0
        injected = d.get(f"{API}/link").json()["device"]["injected"]
        assert injected["dropped_rx"] + injected["dropped_tx"] > 0
    finally:
        d.stop()


# -- a serial port with no camera --------------------------------------------------------------------


def test_absent_serial_port_is_disconnected_with_the_port_named(tmp_path: Path) -> None:
    absent = str(tmp_path / "ttyUSB-absent")
    d = Daemon(tmp_path, FAST)
    d.cmd = [c for c in d.cmd if c != "--sim"] + ["--serial", absent]
    try:
        d.start()
        s = d.status()
        assert s["state"] == "disconnected" and s["device"] is None
        assert s["link"]["port"] == absent and s["link"]["sim_pid"] is None
        assert absent in s["reason"]
        message = error_of(d.post(f"{API}/ping"), 503, "disconnected")
        assert absent in message and "cable" in message
        assert d.get(f"{API}/link").json()["device"] is None
    finally:
        code = d.stop()
    assert code == 0, d.stderr()


# -- token -------------------------------------------------------------------------------------------


def test_token_required_when_configured(tmp_path: Path) -> None:
    d = Daemon(tmp_path, FAST + '[api]\ntoken = "s3cret"\n')
    try:
        d.start()
        message = error_of(d.get(f"{API}/status"), 401, "unauthorized")
        assert "Bearer" in message
        bad = {"Authorization": "Bearer wrong"}
        error_of(d.get(f"{API}/status", headers=bad), 401, "unauthorized")
        error_of(d.get("/metrics"), 401, "unauthorized")
        good = {"Authorization": "Bearer s3cret"}
        assert d.get(f"{API}/status", headers=good).status_code == 200
        assert d.get("/metrics", headers=good).status_code == 200
        # The pages and their files follow the same rule.
        error_of(d.get("/docs"), 401, "unauthorized")
        error_of(d.get("/static/vendor/swagger-ui/swagger-ui.css"), 401, "unauthorized")
        assert d.get("/docs", headers=good).status_code == 200
        # A browser's WebSocket cannot send headers: the token comes as ?token=.
        ws = d.url.replace("http://", "ws://") + f"{API}/live/ws"
        for refused in (ws, ws + "?token=wrong"):
            with pytest.raises(InvalidStatus) as info, ws_connect(refused, open_timeout=10):
                pass
            assert info.value.response.status_code == 403
        with ws_connect(ws + "?token=s3cret", open_timeout=10):
            pass
        with ws_connect(ws, additional_headers=good, open_timeout=10):
            pass
    finally:
        d.stop()


# -- refusals at start --------------------------------------------------------------------------------


def run_serve(tmp_path: Path, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "camd", "serve", "--data-dir", str(tmp_path / "data"), *args],
        cwd=REPO,
        env=child_env(),
        capture_output=True,
        text=True,
        timeout=30,
    )


def test_non_loopback_bind_without_token_is_refused(tmp_path: Path) -> None:
    done = run_serve(tmp_path, "--sim", "--host", "0.0.0.0", "--port", "0")
    assert done.returncode == 2
    assert "0.0.0.0" in done.stderr and "api.token" in done.stderr and "CAMD_TOKEN" in done.stderr
    assert done.stdout == ""


def test_bad_config_exits_2_naming_the_key(tmp_path: Path) -> None:
    cfg = tmp_path / "bad.toml"
    cfg.write_text("[link]\ntimeout = 0.5\n")
    done = run_serve(tmp_path, "--config", str(cfg))
    assert done.returncode == 2
    assert str(cfg) in done.stderr and "link.timeout" in done.stderr and "timeout_s" in done.stderr


def test_bad_inject_spec_exits_2(tmp_path: Path) -> None:
    done = run_serve(tmp_path, "--sim", "--port", "0", "--inject", "ber=2")
    assert done.returncode == 2, done.stderr
    assert "ber" in done.stderr


# -- the simulator dies; a new one is picked up --------------------------------------------------------


NOTICE_S = 20.0  # the bound on noticing a dead or a new simulator (reconnect_max_s is 0.3 s)


def test_simulator_killed_then_replaced(tmp_path: Path) -> None:
    # Without supervision (tests/test_sim_supervisor.py has it): a simulator started by hand
    # is picked up, as a camera powered up again would be.
    d = Daemon(tmp_path, PATIENT.replace("[sim]\n", "[sim]\nrestart = false\n"))
    new_sim: subprocess.Popen[str] | None = None
    try:
        d.start()
        s = d.wait_state("idle")
        sim_pid = s["link"]["sim_pid"]
        os.kill(sim_pid, signal.SIGKILL)

        # Noticed promptly (normally well under a second); NOTICE_S leaves a busy machine room.
        t0 = time.monotonic()
        s = d.wait_state("disconnected", timeout_s=NOTICE_S)
        assert time.monotonic() - t0 < NOTICE_S
        assert s["device"] is None and s["link"]["connected"] is False
        # The pty closes a moment before the killed child can be reaped.
        wait_for(lambda: d.status(), lambda s: s["link"]["sim_pid"] is None, timeout_s=NOTICE_S)

        port = str(d.data_dir / "sim" / "camera.tty")
        message = error_of(d.post(f"{API}/ping", json={"count": 1}), 503, "disconnected")
        assert port in message and "camd sim" in message
        error_of(d.post(f"{API}/mode", json={"mode": "tdi"}), 503, "disconnected")
        error_of(d.post(f"{API}/reset"), 503, "disconnected")
        # What does not need the device keeps answering.
        assert d.get(f"{API}/telemetry").status_code == 200
        assert d.get(f"{API}/link").json()["device"] is None
        events = wait_for(
            lambda: d.get(f"{API}/events").json()["events"],
            lambda evs: any("not restarted" in e["message"] for e in evs),
            timeout_s=NOTICE_S,
        )
        assert any(e["message"].startswith("state idle -> disconnected") for e in events)

        new_sim = subprocess.Popen(
            [sys.executable, "-m", "firmware_models", "--json", "--link", port],
            cwd=REPO,
            env=child_env(),
            stdout=subprocess.PIPE,
            text=True,
        )
        info = json.loads(read_line(new_sim, 20.0))
        assert info["link"] == port

        t0 = time.monotonic()
        s = d.wait_state("idle", timeout_s=NOTICE_S)
        assert time.monotonic() - t0 < NOTICE_S
        assert s["device"]["boot_count"] >= 1
        assert s["link"]["sim_pid"] is None  # not ours: the daemon never restarts a simulator
        assert d.post(f"{API}/ping", json={"count": 5}).json()["ok"] == 5
    finally:
        if new_sim is not None:
            new_sim.terminate()
            try:
                new_sim.wait(timeout=10)
            except subprocess.TimeoutExpired:
                new_sim.kill()
                new_sim.wait()
        code = d.stop()
    assert code == 0, d.stderr()


# -- the start: the simulated camera starts while the daemon still imports ---------------------------


def test_the_simulated_camera_is_spawned_before_the_daemon_imports_its_session(
    tmp_path: Path,
) -> None:
    # The simulator's start (its own imports, about 0.4 s of a core) runs beside the daemon's
    # import of the session, the API and uvicorn, not after them (camd/daemon/serve.py). Seen
    # in order, not timed: Python's import-time report (PYTHONPROFILEIMPORTTIME) and the
    # daemon's log share its stderr, so the spawn's log line comes before the session's import.
    d = Daemon(tmp_path, FAST)
    env = child_env()
    env["PYTHONPROFILEIMPORTTIME"] = "1"
    with open(d.stderr_path, "w") as err:
        d.proc = subprocess.Popen(d.cmd, cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=err, text=True)  # fmt: skip
    try:
        line = read_line(d.proc, 30.0)
        assert line.startswith("camd serving http://"), f"{line!r}\n{d.stderr()[-3000:]}"
        d.url = line.split()[2]
        assert d.status()["link"]["sim_pid"] is not None
    finally:
        code = d.stop()
    assert code == 0, d.stderr()[-3000:]
    lines = d.stderr().splitlines()
    spawned = [i for i, text in enumerate(lines) if "starting the simulated camera:" in text]
    imported = {
        module: [i for i, text in enumerate(lines) if text.split("|")[-1].strip() == module]
        for module in ("camd.daemon.session", "camd.daemon.api", "uvicorn")
    }
    assert len(spawned) == 1, lines[-40:]
    for module, where in imported.items():
        assert len(where) == 1, (module, where)
        assert spawned[0] < where[0], f"{module} was imported before the simulator was started"
    # What only a scan's quicklook needs (OpenCV, 25 ms of a core) is not loaded at start.
    assert not [text for text in lines if text.split("|")[-1].strip() == "cv2"]


# -- the stop: the simulated camera ends at once -------------------------------------------------------


def test_the_simulated_camera_ends_without_the_interpreters_teardown(tmp_path: Path) -> None:
    # Stopped, the simulator has closed its pty and sockets and has nothing left to save; the
    # interpreter's teardown after that (0.1-0.5 s) only delayed each daemon's stop, which waits
    # for it. An exit handler registered before it runs shows whether the teardown ran.
    code = (
        "import atexit, runpy; atexit.register(print, 'teardown ran', flush=True); "
        "runpy.run_module('firmware_models', run_name='__main__', alter_sys=True)"
    )
    link = tmp_path / "camera.tty"
    proc = subprocess.Popen(
        [sys.executable, "-c", code, "--json", "--link", str(link)],
        cwd=REPO, env=child_env(), stdout=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        line = read_line(proc, 30.0)
        assert json.loads(line)["link"] == str(link), line
        proc.send_signal(signal.SIGTERM)
        rest, _ = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0
    assert "teardown ran" not in rest
    assert not link.exists()  # its own cleanup did run
