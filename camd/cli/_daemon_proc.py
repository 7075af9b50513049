"""Start and stop a ``camd serve --sim`` subprocess (for ``camd demo`` and the tests).

The daemon prints one line ``camd serving http://HOST:PORT`` on stdout when it is ready;
``DaemonProcess`` waits for it, then keeps draining the daemon's stdout and stderr into a log
file in the data directory so that a chatty daemon never blocks on a full pipe::

    with DaemonProcess(tmp_path, inject="ber=1e-4") as daemon:
        client = CamdClient(daemon.url)
        ...
    print(daemon.exit_code)
"""

from __future__ import annotations

import collections
import json
import os
import re
import subprocess
import sys
import threading
import time
import weakref
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import IO, TypedDict, Unpack

import camd

__all__ = ["DaemonProcess", "DaemonStartError"]

READY_RE = re.compile(r"camd serving (https?://\S+)")
_TAIL_LINES = 40
_RUNNING: weakref.WeakSet[DaemonProcess] = weakref.WeakSet()  # started and not yet stopped


class DaemonStartError(RuntimeError):
    """The daemon exited or stayed silent before announcing its URL; the message carries the
    tail of its stderr and where the full log is."""


def running_daemons() -> list[DaemonProcess]:
    """The daemons started here and not yet stopped (a test run's report shows their logs)."""
    return list(_RUNNING)


class DaemonProcess:
    """A ``camd serve --sim --port 0`` subprocess, as a context manager.

    ``data_dir`` is the daemon's ``--data-dir`` (created if missing; the log ``daemon.log`` goes
    there too). ``inject`` is passed as ``--inject`` when not empty, each of ``record_dirs`` as
    ``--record-dir`` (clients may have the daemon write there too, besides ``data_dir``),
    ``extra_args`` are appended to the command line and ``env`` entries override the inherited
    environment. ``wrapper``, if given, is a command that runs the daemon's command in the same
    process (it execs it), e.g. ``["nice", "-n", "-5"]``: how the tests start it with the
    systemd unit's scheduling (tests/realtime_support.py).
    """

    def __init__(
        self,
        data_dir: str | os.PathLike[str],
        *,
        inject: str = "",
        record_dirs: Sequence[str | os.PathLike[str]] = (),
        extra_args: Sequence[str] = (),
        env: Mapping[str, str] | None = None,
        start_timeout_s: float = 30.0,
        stop_timeout_s: float = 10.0,
        log_name: str = "daemon.log",
        wrapper: Sequence[str] = (),
    ) -> None:
        self.data_dir = Path(data_dir)
        self.inject = inject
        self.start_timeout_s = start_timeout_s
        self.stop_timeout_s = stop_timeout_s
        self.log_path = self.data_dir / log_name
        self.command: list[str] = [
            *wrapper,
            sys.executable,
            "-m",
            "camd",
            "serve",
            "--sim",
            "--port",
            "0",
            "--data-dir",
            str(self.data_dir),
        ]
        if inject:
            self.command += ["--inject", inject]
        for folder in record_dirs:
            self.command += ["--record-dir", str(Path(folder).absolute())]
        self.command += list(extra_args)
        self._env = _child_env(env)
        self._proc: subprocess.Popen[str] | None = None
        self._url: str | None = None
        self._ready = threading.Event()
        self._log: IO[str] | None = None
        self._log_lock = threading.Lock()
        self._stderr_tail: collections.deque[str] = collections.deque(maxlen=_TAIL_LINES)
        self._threads: list[threading.Thread] = []
        self.exit_code: int | None = None
        self.killed = False  # True if the daemon ignored SIGTERM and had to be killed

    # -- properties -------------------------------------------------------------------------------

    @property
    def url(self) -> str:
        """The URL the daemon announced (``http://127.0.0.1:PORT``)."""
        if self._url is None:
            raise RuntimeError("the daemon has not been started (use `with DaemonProcess(...)`)")
        return self._url

    @property
    def pid(self) -> int:
        """The daemon's process id."""
        if self._proc is None:
            raise RuntimeError("the daemon has not been started (use `with DaemonProcess(...)`)")
        return self._proc.pid

    @property
    def running(self) -> bool:
        """True while the daemon process is alive."""
        return self._proc is not None and self._proc.poll() is None

    def log_tail(self, max_bytes: int = 16384) -> str:
        """The end of the daemon's log file (at most ``max_bytes``, from a line's start)."""
        try:
            with open(self.log_path, "rb") as log:
                log.seek(max(0, self.log_path.stat().st_size - max_bytes))
                tail = log.read().decode("utf-8", "replace")
        except OSError as exc:
            return f"(cannot read {self.log_path}: {exc})"
        return tail if len(tail) < max_bytes else tail.partition("\n")[2]

    def stderr_tail(self, lines: int = 20) -> str:
        """The last ``lines`` lines the daemon wrote to stderr."""
        with self._log_lock:
            tail = list(self._stderr_tail)[-lines:]
        return "".join(tail)

    # -- lifecycle --------------------------------------------------------------------------------

    def start(self) -> DaemonProcess:
        """Start the daemon and wait for its ``camd serving`` line.

        Raises DaemonStartError (after stopping the process) if it exits first or does not
        announce itself within ``start_timeout_s``.
        """
        if self._proc is not None:
            raise RuntimeError("this DaemonProcess was already started; make a new one")
        self.data_dir.mkdir(parents=True, exist_ok=True)
        self._log = open(self.log_path, "a", encoding="utf-8")  # noqa: SIM115 (closed in stop)
        self._write_log(
            f"--- {time.strftime('%Y-%m-%d %H:%M:%S')} start: {' '.join(self.command)}\n"
        )
        try:
            self._proc = self._spawn()
            _RUNNING.add(self)
        except OSError as exc:
            self.stop()
            raise DaemonStartError(f"cannot run {' '.join(self.command)}: {exc}") from None
        assert self._proc.stdout is not None and self._proc.stderr is not None
        self._threads = [
            threading.Thread(
                target=self._drain, args=(self._proc.stdout, False), name="camd-stdout", daemon=True
            ),
            threading.Thread(
                target=self._drain, args=(self._proc.stderr, True), name="camd-stderr", daemon=True
            ),
        ]
        for thread in self._threads:
            thread.start()

        deadline = time.monotonic() + self.start_timeout_s
        while not self._ready.wait(0.05):
            code = self._proc.poll()
            if code is not None:
                for thread in self._threads:
                    thread.join(timeout=2.0)  # collect the last of its stderr
                self.stop()
                raise DaemonStartError(
                    f"`camd serve` exited with status {code} before it was ready"
                    + self._start_failure_detail()
                )
            if time.monotonic() > deadline:
                self.stop()
                raise DaemonStartError(
                    f"`camd serve` did not print 'camd serving http://...' within "
                    f"{self.start_timeout_s:g} s" + self._start_failure_detail()
                )
        return self

    def stop(self) -> int | None:
        """Stop the daemon with SIGTERM (SIGKILL after ``stop_timeout_s``) and return its exit
        code (negative: killed by that signal). Safe to call more than once."""
        _RUNNING.discard(self)
        proc = self._proc
        if proc is None:
            self._close_log()
            return None
        if proc.poll() is None:
            proc.terminate()
            try:
                proc.wait(timeout=self.stop_timeout_s)
            except subprocess.TimeoutExpired:
                self.killed = True
                proc.kill()
                proc.wait()
            except KeyboardInterrupt:
                # A second Ctrl-C while waiting: do not leave the daemon behind.
                self.killed = True
                proc.kill()
                proc.wait()
                raise
        for thread in self._threads:
            thread.join(timeout=2.0)
        if self.exit_code is None:
            self.exit_code = proc.returncode
            how = " (killed after ignoring SIGTERM)" if self.killed else ""
            self._write_log(f"--- camd serve exited with status {self.exit_code}{how}\n")
        self._close_log()
        return self.exit_code

    def __enter__(self) -> DaemonProcess:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # -- internals --------------------------------------------------------------------------------

    def _spawn(self) -> subprocess.Popen[str]:
        return subprocess.Popen(
            self.command,
            stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            encoding="utf-8",
            errors="replace",
            bufsize=1,
            env=self._env,
            # Own process group: a Ctrl-C in the terminal reaches the demo, which then stops the
            # daemon in order, instead of both dying at once.
            start_new_session=True,
        )

    def _drain(self, stream: IO[str], is_stderr: bool) -> None:
        # Runs until the daemon closes the pipe (it exits): every line goes to the log.
        for line in stream:
            if is_stderr:
                with self._log_lock:
                    self._stderr_tail.append(line)
            elif not self._ready.is_set():
                match = READY_RE.search(line)
                if match:
                    self._url = match.group(1).rstrip("/")
                    self._ready.set()
            self._write_log(line)
        stream.close()

    def _close_log(self) -> None:
        with self._log_lock:
            if self._log is not None:
                self._log.close()
                self._log = None

    def _write_log(self, text: str) -> None:
        with self._log_lock:
            if self._log is not None:
                self._log.write(text)
                self._log.flush()

    def _start_failure_detail(self) -> str:
        tail = self.stderr_tail().rstrip()
        shown = f"; its stderr ends with:\n{tail}" if tail else "; it wrote nothing on stderr"
        return f" (command: {' '.join(self.command)}){shown}\nfull log: {self.log_path}"


def _child_env(overrides: Mapping[str, str] | None) -> dict[str, str]:
    """The daemon's environment: ours, unbuffered output, and our camd first on the import path,
    so that ``python -m camd`` runs this same checkout even when camd is not installed."""
    env = dict(os.environ)
    package_root = str(Path(camd.__file__).resolve().parent.parent)
    paths = [package_root] + [p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p]
    env["PYTHONPATH"] = os.pathsep.join(dict.fromkeys(paths))
    env["PYTHONUNBUFFERED"] = "1"  # the ready line must not sit in a pipe buffer
    if overrides:
        env.update(overrides)
    return env


class SimConfig(TypedDict, total=False):
    """The simulator's settings a daemon's config may give (docs/config.md, [sim]), but its
    profile: the default of each is the daemon's."""

    seed: int
    defects: Sequence[str]
    frame_bank: int
    scene: str


def write_sim_config(data_dir: Path, profile: str, **sim: Unpack[SimConfig]) -> Path:
    """``data_dir/camd.toml`` for ``camd serve --sim`` on camera ``profile`` (the simulator's and
    the sensor's) with the ``sim`` settings given; its path."""
    lines = ["[sim]", f"profile = {json.dumps(profile)}"]
    if "seed" in sim:
        lines.append(f"seed = {int(sim['seed'])}")
    if sim.get("defects"):
        lines.append(f"defects = {json.dumps(list(sim['defects']))}")
    if "frame_bank" in sim:
        lines.append(f"frame_bank = {int(sim['frame_bank'])}")
    if "scene" in sim:
        lines.append(f"scene = {json.dumps(sim['scene'])}")
    lines += ["[sensor]", f"name = {json.dumps(profile)}"]
    config = data_dir / "camd.toml"
    config.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return config


def start_sim_daemon(
    data_dir: Path, profile: str, *, record_dirs: Sequence[Path] = (), **sim: Unpack[SimConfig]
) -> DaemonProcess:
    """``camd serve --sim`` simulating camera ``profile`` with the ``sim`` settings given (a
    ``seed``, deliberate ``defects``, ...), its config, data and log in ``data_dir``, recording
    also into ``record_dirs``; started. What ``camctl campaign run --sim`` and ``camd conform
    --sim`` run on. DaemonStartError if it does not start."""
    data_dir.mkdir(parents=True, exist_ok=True)
    config = write_sim_config(data_dir, profile, **sim)
    daemon = DaemonProcess(
        data_dir,
        record_dirs=record_dirs,
        extra_args=["--config", str(config)],
        env={"CAMD_TOKEN": ""},
    )
    daemon.start()
    return daemon
