"""sd_notify: datagrams to a real AF_UNIX socket (path and abstract), and `camd serve` as
systemd sees it: READY=1, WATCHDOG=1 every half watchdog interval, STOPPING=1 and exit 0."""

from __future__ import annotations

import itertools
import os
import signal
import socket
import subprocess
import sys
import time
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest

from camd.daemon import notify

REPO = Path(__file__).resolve().parent.parent


@pytest.fixture
def path_socket(tmp_path: Path) -> Iterator[tuple[socket.socket, str]]:
    # AF_UNIX paths are limited to ~108 bytes; pytest's tmp_path can be longer.
    path = f"/tmp/camd-notify-{uuid.uuid4().hex[:12]}.sock"
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(path)
    try:
        yield sock, path
    finally:
        sock.close()
        os.unlink(path)


@pytest.fixture
def abstract_socket() -> Iterator[tuple[socket.socket, str]]:
    name = f"camd-notify-test-{uuid.uuid4().hex}"
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind("\0" + name)
    try:
        yield sock, "@" + name
    finally:
        sock.close()


def receive(sock: socket.socket, timeout_s: float) -> str | None:
    sock.settimeout(timeout_s)
    try:
        return sock.recv(4096).decode()
    except TimeoutError:
        return None


@pytest.mark.parametrize("kind", ["path", "abstract"])
def test_notify_sends_one_datagram(
    kind: str,
    path_socket: tuple[socket.socket, str],
    abstract_socket: tuple[socket.socket, str],
) -> None:
    sock, address = path_socket if kind == "path" else abstract_socket
    env = {"NOTIFY_SOCKET": address}
    assert notify.notify("READY=1", "STATUS=up", env=env)
    assert receive(sock, 2.0) == "READY=1\nSTATUS=up"


def test_functions_use_the_environment(
    monkeypatch: pytest.MonkeyPatch, path_socket: tuple[socket.socket, str]
) -> None:
    sock, address = path_socket
    monkeypatch.setenv("NOTIFY_SOCKET", address)
    assert notify.ready("serving")
    assert receive(sock, 2.0) == "READY=1\nSTATUS=serving"
    assert notify.watchdog()
    assert receive(sock, 2.0) == "WATCHDOG=1"
    assert notify.status("camera idle")
    assert receive(sock, 2.0) == "STATUS=camera idle"
    assert notify.stopping()
    assert receive(sock, 2.0) == "STOPPING=1"


def test_no_socket_is_a_no_op(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("NOTIFY_SOCKET", raising=False)
    assert notify.ready() is False
    assert notify.notify("READY=1", env={"NOTIFY_SOCKET": ""}) is False


def test_unreachable_socket_is_logged_not_raised(tmp_path: Path) -> None:
    assert notify.notify("READY=1", env={"NOTIFY_SOCKET": str(tmp_path / "absent")}) is False


def test_watchdog_interval() -> None:
    pid = str(os.getpid())
    assert notify.watchdog_interval_s({}) is None
    assert notify.watchdog_interval_s({"WATCHDOG_USEC": "10000000"}) == 10.0
    assert notify.watchdog_interval_s({"WATCHDOG_USEC": "1000000", "WATCHDOG_PID": pid}) == 1.0
    assert notify.watchdog_interval_s({"WATCHDOG_USEC": "1000000", "WATCHDOG_PID": "1"}) is None
    assert notify.watchdog_interval_s({"WATCHDOG_USEC": "soon"}) is None
    assert notify.watchdog_interval_s({"WATCHDOG_USEC": "0"}) is None


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


WATCHDOG_S = 4.0  # the daemon's WATCHDOG_USEC, in seconds


@pytest.mark.parametrize("kind", ["path", "abstract"])
@pytest.mark.timeout(120)
def test_serve_talks_to_systemd(
    kind: str,
    tmp_path: Path,
    path_socket: tuple[socket.socket, str],
    abstract_socket: tuple[socket.socket, str],
) -> None:
    sock, address = path_socket if kind == "path" else abstract_socket
    env = dict(os.environ)
    env.pop("CAMD_TOKEN", None)
    env.pop("WATCHDOG_PID", None)
    env.update(
        NOTIFY_SOCKET=address,
        WATCHDOG_USEC=str(int(WATCHDOG_S * 1e6)),
        PYTHONPATH=os.pathsep.join([str(REPO), env.get("PYTHONPATH", "")]),
    )
    cmd = [sys.executable, "-m", "camd", "serve", "--sim", "--port", str(free_port()),
           "--data-dir", str(tmp_path / "data")]  # fmt: skip
    with open(tmp_path / "stderr.log", "w") as err:
        proc = subprocess.Popen(
            cmd, cwd=REPO, env=env, stdout=subprocess.DEVNULL, stderr=err, text=True
        )
    try:
        messages: list[tuple[float, str]] = []
        deadline = time.monotonic() + 30
        while not any("READY=1" in m.split("\n") for _, m in messages):
            assert time.monotonic() < deadline, (tmp_path / "stderr.log").read_text()
            msg = receive(sock, 1.0)
            if msg is not None:
                messages.append((time.monotonic(), msg))
        ready_at = messages[-1][0]

        # Petted every half WATCHDOG_USEC (2 s); what matters is that no gap reaches the
        # watchdog timeout itself, where systemd would restart the daemon. That leaves 2 s for
        # a busy machine to run the daemon's loop late, rather than a slack of a fraction of it.
        watchdogs: list[float] = []
        deadline = ready_at + 30
        while len(watchdogs) < 4:
            assert time.monotonic() < deadline, watchdogs
            msg = receive(sock, 0.2)
            if msg is not None and "WATCHDOG=1" in msg.split("\n"):
                watchdogs.append(time.monotonic())
        gaps = [b - a for a, b in itertools.pairwise(watchdogs)]
        assert max(gaps) < WATCHDOG_S, gaps
        # And at about half of it: a loop petting only at the timeout would have no gap under
        # 3 s (a late loop makes gaps longer, so this fails only if three in a row are late).
        assert min(gaps) < 0.75 * WATCHDOG_S, gaps

        proc.send_signal(signal.SIGTERM)
        stopping = False
        deadline = time.monotonic() + 10
        while not stopping and time.monotonic() < deadline:
            msg = receive(sock, 0.5)
            stopping = msg is not None and "STOPPING=1" in msg.split("\n")
        assert stopping, "no STOPPING=1 after SIGTERM"
        assert proc.wait(timeout=15) == 0, (tmp_path / "stderr.log").read_text()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
