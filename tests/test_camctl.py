"""camctl as a user runs it: its entry point talking real HTTP on loopback to a live daemon,
as a command (``camctl_command``) and, for the suite's many other camctl runs, in this process
(``camctl``: the same code from ``main`` on, without a Python start each).

The daemon runs the simulated camera (``camd serve --sim``); the lossy-line test adds bit errors
and dropped frames and checks that 1000 pings all succeed through retries.
"""

from __future__ import annotations

import contextlib
import csv
import io
import json
import os
import socket
import sqlite3
import subprocess
import sys
import threading
import time
import traceback
from collections.abc import Iterator
from contextlib import redirect_stderr, redirect_stdout
from pathlib import Path
from subprocess import CompletedProcess  # not `subprocess.`: tests/tiers.py reads that as a start
from typing import Any

import pytest

import camd
from camd.cli._daemon_proc import DaemonProcess
from camd.cli.camctl import main as camctl_main
from camd.client import CamdClient

HOST_KEYS = {"sent", "acked", "nacked", "retries", "timeouts", "crc_errors", "failed"}
DEVICE_KEYS = {"executed", "replayed", "crc_errors", "injected"}
NO_TOKEN = {"CAMD_TOKEN": ""}
REPO_ROOT = str(Path(camd.__file__).resolve().parent.parent)


CLIENT_ENV = ("CAMD_URL", "CAMD_TOKEN")  # what a user's shell may set for camctl


def camctl_env() -> dict[str, str]:
    """Our environment without the client's variables, with this checkout importable."""
    env = {k: v for k, v in os.environ.items() if k not in CLIENT_ENV}
    env["PYTHONPATH"] = os.pathsep.join(p for p in (REPO_ROOT, env.get("PYTHONPATH")) if p)
    return env


def camctl(url: str, *args: str, timeout_s: float = 120) -> subprocess.CompletedProcess[str]:
    """``camctl --url URL ARGS...`` run in this process, returned as the finished command.

    The command's own code from its entry point on (``camd.cli.camctl.main``: its parser, its
    client over real HTTP, its output and exit status) without starting a Python for it (0.35 to
    0.45 s each, most of it imports): its stdout and stderr are captured, argparse's exit is its
    exit status, an exception is a traceback on stderr and status 1, and it sees the environment
    ``camctl_env`` gives the command (no $CAMD_URL, $CAMD_TOKEN). ``timeout_s`` bounds
    ``camctl_command`` only (here the test's timeout does). ``camctl_command`` runs the
    installed command itself; each command group keeps a test that does.
    """
    del timeout_s
    argv = ["--url", url, *args]
    out, err = io.StringIO(), io.StringIO()
    with _IN_PROCESS, _without_client_env(), redirect_stdout(out), redirect_stderr(err):
        try:
            status = camctl_main(argv)
        except SystemExit as exc:  # argparse: a usage error, --help, --version
            status = _exit_status(exc.code)
        except Exception:  # what the interpreter would print, and its status
            traceback.print_exc()
            status = 1
    return CompletedProcess(["camctl", *argv], status, out.getvalue(), err.getvalue())


def camctl_command(
    url: str, *args: str, timeout_s: float = 120
) -> subprocess.CompletedProcess[str]:
    """Run ``camctl --url URL ARGS...`` as a command (``python -m camd.cli.camctl``) and return
    the finished process."""
    return subprocess.run(
        [sys.executable, "-m", "camd.cli.camctl", "--url", url, *args],
        capture_output=True,
        text=True,
        timeout=timeout_s,
        env=camctl_env(),
        check=False,
    )


_IN_PROCESS = threading.Lock()  # one at a time: sys.stdout and sys.stderr are the process's


@contextlib.contextmanager
def _without_client_env() -> Iterator[None]:
    saved = {key: os.environ.pop(key) for key in CLIENT_ENV if key in os.environ}
    try:
        yield
    finally:
        os.environ.update(saved)


def _exit_status(code: object) -> int:
    """The exit status ``sys.exit(code)`` gives a process (a message goes to stderr)."""
    if code is None:
        return 0
    if isinstance(code, int):
        return code
    print(code, file=sys.stderr)
    return 1


def camctl_json(url: str, *args: str) -> Any:
    """Run a camctl command with --json; it must succeed and print exactly one JSON document."""
    return one_document(camctl(url, *args, "--json"))


def camctl_command_json(url: str, *args: str) -> Any:
    """``camctl_json`` run as a command (``camctl_command``)."""
    return one_document(camctl_command(url, *args, "--json"))


def one_document(proc: subprocess.CompletedProcess[str]) -> Any:
    """What a successful camctl --json printed: exactly one JSON document."""
    assert proc.returncode == 0, proc.stderr
    assert "Traceback" not in proc.stderr
    return json.loads(proc.stdout)  # json.loads rejects anything after the one document


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


@pytest.fixture(scope="module")
def url(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    # The daemon takes $CAMD_TOKEN as its api.token: clear it so that no token is required.
    # 20 retries of 0.1 s: a busy machine's late answer is a retry, not a failed ping.
    tmp = tmp_path_factory.mktemp("camd-camctl")
    (tmp / "camd.toml").write_text("[link]\nretries = 20\n")
    with DaemonProcess(
        tmp / "data", extra_args=["--config", str(tmp / "camd.toml")], env=NO_TOKEN
    ) as daemon:
        # The daemon announces its URL before its first talk with the camera: wait for that
        # (a busy machine can take its time), so that every test starts with the camera idle.
        with CamdClient(daemon.url) as client:
            client.wait_ready(60)
        yield daemon.url
    assert daemon.exit_code in (0, -15), daemon.log_path.read_text()


def test_status_json_is_one_document_with_state_idle(url: str) -> None:
    doc = camctl_json(url, "status")
    assert doc["state"] == "idle"
    assert {"state", "reason", "mode", "link", "device", "daemon"} <= set(doc)
    # --json is accepted before the command too
    proc = subprocess.run(
        [sys.executable, "-m", "camd.cli.camctl", "--json", "--url", url, "status"],
        capture_output=True,
        text=True,
        timeout=60,
        env=camctl_env(),
        check=False,
    )
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout)["state"] == "idle"


def test_ping_200(url: str) -> None:
    doc = camctl_json(url, "ping", "--count", "200")
    assert (doc["count"], doc["ok"], doc["failed"]) == (200, 200, 0)
    rtt = doc["rtt_ms"]
    assert 0 < rtt["p50"] <= rtt["p99"] <= rtt["max"]
    assert "retries" in doc


def test_link_has_host_and_device_counters(url: str) -> None:
    camctl_json(url, "ping", "--count", "200", "--size", "8")
    doc = camctl_json(url, "link")
    assert set(doc["host"]) >= HOST_KEYS
    assert set(doc["device"]) >= DEVICE_KEYS
    assert doc["device"]["executed"] >= 200
    assert doc["host"]["acked"] >= 200


def test_telemetry_values_change_over_time(url: str) -> None:
    # Under xdist this may be the first test on a fresh daemon: wait for a first sample.
    deadline = time.monotonic() + 30
    first = camctl_json(url, "telemetry")
    while not first["latest"]:
        assert time.monotonic() < deadline, "no telemetry yet"
        time.sleep(0.5)
        first = camctl_json(url, "telemetry")
    for name, sample in first["latest"].items():
        assert isinstance(sample["value"], int | float), name
        assert isinstance(sample["unit"], str), name
        assert sample["limit"] in ("ok", "yellow", "red"), name
    assert first["archive"].endswith((".sqlite", ".db", ".sqlite3"))
    # Housekeeping arrives about every second: soon there is a newer sample (30 s: a busy
    # machine can stretch each camctl run to seconds).
    deadline = time.monotonic() + 30
    while True:
        time.sleep(1.0)
        second = camctl_json(url, "telemetry")
        newer = [
            name
            for name, sample in second["latest"].items()
            if sample["t_s"] > first["latest"].get(name, {"t_s": float("inf")})["t_s"]
        ]
        if newer and second["samples"] > first["samples"]:
            break
        assert time.monotonic() < deadline, f"telemetry did not change: {first} -> {second}"
    assert any(second["latest"][n]["value"] != first["latest"][n]["value"] for n in newer)

    channel = newer[0]
    (hist,) = camctl_json(url, "telemetry", "--history", channel, "--limit", "3")["channels"]
    assert hist["channel"] == channel
    assert 0 < len(hist["value"]) == len(hist["t_s"]) == len(hist["source"]) <= 3


def test_telemetry_history_range_bucket_and_csv_are_the_archived_samples(url: str) -> None:
    """--start/--end as Unix times and as ISO 8601 give the same closed range; --csv prints the
    archive's rows of two channels; --bucket-s the per-bucket min/mean/max/count of them."""
    archive = camctl_json(url, "telemetry")["archive"]
    start_s = float(int(time.time()))  # a whole second: its ISO 8601 form is exact
    end_s = start_s + 2.0
    # Closed: each source is archived in order by one thread (a sample's channels together),
    # so once both have a sample at or after end_s the range's rows no longer change, however
    # busy the machine.
    after = [
        "telemetry",
        "--history",
        "uptime_s",
        "--start",
        repr(end_s),
        "--end",
        repr(end_s + 3600),
    ]
    deadline = time.monotonic() + 60
    while set(camctl_json(url, *after)["channels"][0]["source"]) != {"tlm", "poll"}:
        assert time.monotonic() < deadline, "no packet or no poll after the range"
        time.sleep(0.2)
    channels = ["uptime_s", "fpga_temp_degc"]
    db = sqlite3.connect(f"file:{archive}?mode=ro", uri=True)
    try:
        written = [
            (ch, *row)
            for ch in channels
            for row in db.execute(
                "SELECT source, t_s, value FROM samples WHERE channel = ? AND t_s >= ? AND t_s < ? "
                "ORDER BY t_s, source",
                (ch, start_s, end_s),
            )
        ]
    finally:
        db.close()
    assert written
    iso = [time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(t)) for t in (start_s, end_s)]
    args = ["telemetry", "--history", ",".join(channels), "--start", iso[0], "--end", iso[1]]
    proc = camctl(url, *args, "--csv")
    assert proc.returncode == 0, proc.stderr
    rows = list(csv.reader(io.StringIO(proc.stdout)))
    assert rows[0] == ["channel", "unit", "source", "t_s", "time_utc", "value"]
    assert [(c, s, float(t), float(v)) for c, _, s, t, _, v in rows[1:]] == written

    doc = camctl_json(url, *args, "--bucket-s", "1")
    for got in doc["channels"]:
        mine = [w for w in written if w[0] == got["channel"]]
        expected = []
        for b in (0, 1):
            for src in ("poll", "tlm"):
                v = [w[3] for w in mine if w[1] == src and start_s + b <= w[2] < start_s + b + 1]
                if v:
                    expected.append((start_s + b, src, min(v), max(v), len(v)))
        assert list(zip(got["t_s"], got["source"], got["min"], got["max"], got["count"],
                        strict=True)) == expected  # fmt: skip
    table = camctl(url, *args, "--bucket-s", "1")
    assert table.returncode == 0 and "1 s buckets" in table.stdout and "mean" in table.stdout

    bad = camctl(url, "telemetry", "--history", "uptime_s", "--start=-1h", "--end=-2h")
    assert bad.returncode == 1 and "is not before end" in bad.stderr, bad.stderr
    events = camctl_json(url, "events", "--level", "info,warning", "--source", "link,daemon",
                         "--start", repr(start_s - 3600), "--end=now")["events"]  # fmt: skip
    assert events and {(e["level"] in ("info", "warning"), e["source"] in ("link", "daemon"))
                       for e in events} == {(True, True)}  # fmt: skip
    misplaced = camctl(url, "telemetry", "--csv")
    assert misplaced.returncode == 2 and "--csv go(es) with --history" in misplaced.stderr


def test_mode_tdi_then_status_shows_it(url: str) -> None:
    assert camctl_json(url, "mode", "tdi") == {"mode": "tdi"}
    assert camctl_json(url, "status")["mode"] == "tdi"
    assert camctl_json(url, "mode", "area") == {"mode": "area"}
    events = camctl_json(url, "events", "--limit", "5")["events"]
    assert 0 < len(events) <= 5


def test_mode_foo_is_a_usage_error_naming_the_modes(url: str) -> None:
    proc = camctl(url, "mode", "foo")
    assert proc.returncode == 2
    assert "area" in proc.stderr and "tdi" in proc.stderr
    assert proc.stdout == ""


def test_api_error_exits_1_with_the_daemons_message(url: str) -> None:
    proc = camctl(url, "telemetry", "--history", "no_such_channel", "--json")
    assert proc.returncode == 1
    assert proc.stderr.startswith("camctl: error: ")
    assert "no_such_channel" in proc.stderr and "Traceback" not in proc.stderr
    assert proc.stdout == ""


def test_human_output(url: str) -> None:
    proc = camctl(url, "status")
    assert proc.returncode == 0, proc.stderr
    assert "idle" in proc.stdout and "state" in proc.stdout
    for command in (["ping", "--count", "5"], ["link"], ["telemetry"], ["events"], ["reset"]):
        proc = camctl(url, *command)
        assert proc.returncode == 0, (command, proc.stderr)
        assert proc.stdout.strip(), command
    assert "p99" in camctl(url, "ping", "--count", "5").stdout


def test_unreachable_daemon_exits_3_with_the_hint() -> None:
    url = f"http://127.0.0.1:{free_port()}"
    for args in (["status"], ["ping", "--count", "3", "--json"]):
        proc = camctl(url, *args)
        assert proc.returncode == 3
        assert proc.stderr.startswith("camctl: error: ")
        assert "camd serve --sim" in proc.stderr and "Traceback" not in proc.stderr
        assert proc.stdout == ""


def test_lossy_line_1000_pings_all_succeed_through_retries(tmp_path: Path) -> None:
    # 0.1 s attempts (the default), 20 retries: a lost frame costs 0.1 s, and a busy machine's
    # late answers cost retries (2 s per command before a failure), not failed pings.
    config = tmp_path / "camd.toml"
    config.write_text("[link]\nretries = 20\n")
    with DaemonProcess(
        tmp_path / "data",
        inject="ber=1e-4,drop=0.01",
        extra_args=["--config", str(config)],
        env=NO_TOKEN,
    ) as daemon:
        # The camera first: "camd serving" says the API serves, not that the camera has been
        # probed (and on this line its probe and training take retries); camctl run in process
        # asks within milliseconds of that line, where its own start used to take 0.4 s.
        with CamdClient(daemon.url) as client:
            client.wait_ready(60)
        doc = camctl_json(daemon.url, "ping", "--count", "1000")
        link = camctl_json(daemon.url, "link")
    assert (doc["count"], doc["ok"], doc["failed"]) == (1000, 1000, 0), doc.get("errors")
    assert doc["retries"] > 0
    assert link["host"]["retries"] >= doc["retries"]
    injected = link["device"]["injected"]
    assert injected is not None and sum(injected.values()) > 0


def test_token_is_required_and_accepted(tmp_path: Path) -> None:
    with DaemonProcess(tmp_path, env={"CAMD_TOKEN": "s3cret"}) as daemon:
        refused = camctl(daemon.url, "status", "--json")
        with_option = camctl(daemon.url, "status", "--json", "--token", "s3cret")
        env = camctl_env() | {"CAMD_TOKEN": "s3cret"}
        with_env = subprocess.run(
            [sys.executable, "-m", "camd.cli.camctl", "--url", daemon.url, "status", "--json"],
            capture_output=True,
            text=True,
            timeout=60,
            env=env,
            check=False,
        )
    assert refused.returncode == 1 and refused.stdout == ""
    assert refused.stderr.startswith("camctl: error: ") and "token" in refused.stderr.lower()
    assert with_option.returncode == 0, with_option.stderr
    assert json.loads(with_option.stdout)["state"] in ("idle", "disconnected")
    assert with_env.returncode == 0, with_env.stderr
