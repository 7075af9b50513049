"""The simulated camera as a child process of the daemon (``link.device = "sim"``).

``SimulatorProcess`` runs ``python -m firmware_models --json --link ...`` with the sockets of
the simulated USB devices, waits for its one JSON start line, and stops it (SIGTERM, then
SIGKILL). The child gets SIGTERM when the daemon dies, even by SIGKILL (Linux). ``start`` may
be called again after the child died: the same command, so the same options, pty link and
sockets (``camd.daemon.sim_supervisor`` does that); never after ``stop``.

``camd serve`` spawns the child (``spawn``) as soon as its config is read, before it imports the
session, the API and uvicorn: the child's start (its own imports, about 0.4 s of a core) then
runs beside the daemon's instead of after it, and ``start`` only waits for its line.
"""

from __future__ import annotations

import ctypes
import json
import logging
import os
import queue
import signal
import subprocess
import sys
import threading
from pathlib import Path
from typing import TYPE_CHECKING, Any

import camd
from camd.daemon.errors import SimulatorError

if TYPE_CHECKING:
    from camd.daemon.config import Config

log = logging.getLogger(__name__)

SIM_START_TIMEOUT_S = 20.0  # the simulator imports numpy and the dictionary before its line
SIM_STOP_TIMEOUT_S = 5.0


def _set_parent_death_signal() -> None:
    """In the simulator child: receive SIGTERM when the daemon dies, even by SIGKILL.

    Linux sends it when the *thread* that forked the child ends, not only the process: start
    the simulator from a thread that lives as long as the daemon (the main thread, or the
    supervisor's restart thread)."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        pr_set_pdeathsig = 1
        libc.prctl(pr_set_pdeathsig, signal.SIGTERM)
    except (OSError, AttributeError):
        pass  # not Linux: the simulator then outlives a killed daemon, as any child would


class SimulatorProcess:
    """The simulated camera as a child process: ``python -m firmware_models --json --link``."""

    def __init__(
        self,
        link_path: Path,
        *,
        inject: str = "",
        hk_period_s: float = 1.0,
        seed: int = 0,
        profile: str = "hr400",
        spi_socket: Path | None = None,
        usb_socket: Path | None = None,
        scene: str = "",
        frame_bank: int = 0,
        stage: str = "linear_rail",
        defects: tuple[str, ...] = (),
    ) -> None:
        self.link_path = link_path
        self.spi_socket = spi_socket
        self.usb_socket = usb_socket
        self.command = [
            sys.executable,
            "-m",
            "firmware_models",
            "--json",
            "--link",
            str(link_path),
            "--hk-period-s",
            f"{hk_period_s:g}",
            "--seed",
            str(seed),
            "--profile",
            profile,
            "--stage",
            stage,
        ]
        if inject:
            self.command += ["--inject", inject]
        if spi_socket is not None:
            self.command += ["--spi-socket", str(spi_socket)]
        if usb_socket is not None:
            self.command += ["--usb-socket", str(usb_socket)]
        if scene:
            self.command += ["--scene", scene]
        if frame_bank:
            self.command += ["--frame-bank", str(frame_bank)]
        for defect in defects:  # deliberate defects (docs/conformance.md)
            self.command += ["--defect", defect]
        self.info: dict[str, Any] = {}
        self._proc: subprocess.Popen[str] | None = None
        self._lock = threading.Lock()  # start and stop: a stopped process is never started
        self._stopped = False
        self._spawned_unwaited = False  # spawn() ran; the next start() waits for that child

    @classmethod
    def for_config(cls, config: Config) -> SimulatorProcess | None:
        """The simulated camera the config asks for (``link.device = "sim"``), not started;
        None for hardware."""
        if config.link.device != "sim":
            return None
        sim = config.sim
        return cls(
            config.sim_link_path,
            inject=sim.inject,
            hk_period_s=sim.hk_period_s,
            seed=sim.seed,
            profile=sim.profile,
            spi_socket=config.sim_spi_socket,
            usb_socket=config.sim_usb_socket,
            scene=sim.scene,
            frame_bank=sim.frame_bank,
            stage=config.stage.profile,
            defects=tuple(sim.defects),
        )

    @property
    def pid(self) -> int | None:
        """The child's pid while it runs, else None."""
        return self._proc.pid if self._proc is not None and self._proc.poll() is None else None

    @property
    def last_pid(self) -> int | None:
        """The pid of the last child started, running or not (None before the first start)."""
        return self._proc.pid if self._proc is not None else None

    @property
    def stopped(self) -> bool:
        """True once ``stop`` was called: the child's exit is then the daemon's own doing."""
        return self._stopped

    def returncode(self) -> int | None:
        """The exit status once the child has exited (reaping it), else None."""
        return None if self._proc is None else self._proc.poll()

    def refuses_link(self) -> str | None:
        """Why the link symlink must not be opened now, or None when it leads to this child.

        A killed simulator cannot remove its link, and the pty it pointed at is freed with it:
        the kernel soon gives the same /dev/pts number to another process (another camera's
        simulator on a shared PC), and a host reopening the stale link would talk to that
        process's device. So the link is this child's only while the child runs, its start
        line has named its pty and the link points there."""
        proc = self._proc
        tty = self.info.get("tty")
        if proc is None or proc.poll() is not None or not tty:
            return f"the simulated camera behind {self.link_path} is not running yet"
        try:
            target = os.readlink(self.link_path)
        except OSError as exc:
            return f"{self.link_path} cannot be read ({exc.strerror})"
        if target != tty:
            return f"{self.link_path} points at {target}, not at the simulated camera's pty {tty}"
        return None

    def forget_link(self) -> None:
        """Remove the link if it still points at the last child's pty, which a dead child
        could not do itself; a link that points elsewhere (a simulator started by hand, or
        the next child's) is left alone."""
        tty = self.info.get("tty")
        try:
            if tty and os.readlink(self.link_path) == tty:
                self.link_path.unlink()
        except OSError:
            pass  # already gone, or not a symlink: nothing of ours to remove

    def spawn(self) -> None:
        """Start the child now without waiting for its start line (``start`` waits for it):
        what the daemon does meanwhile runs beside the child's start. Starts no thread: the
        daemon limits its malloc arenas before its first thread (camd/daemon/heap.py)."""
        with self._lock:
            self._spawn_locked()
            self._spawned_unwaited = True

    def start(self, timeout_s: float = SIM_START_TIMEOUT_S) -> dict[str, Any]:
        """Spawn the simulator (unless ``spawn`` just did) and return its JSON start line as a
        dict.

        Raises SimulatorError if it exits or stays silent for ``timeout_s`` (it is then killed),
        or if ``stop`` was called (the daemon is shutting down).
        """
        with self._lock:
            if not self._spawned_unwaited:
                self._spawn_locked()
            self._spawned_unwaited = False
        proc = self._proc
        assert proc is not None and proc.stdout is not None
        lines: queue.Queue[str] = queue.Queue()
        reader = threading.Thread(
            target=self._drain, args=(proc.stdout, lines), name="sim-stdout", daemon=True
        )
        reader.start()
        try:
            line = lines.get(timeout=timeout_s)
        except queue.Empty:
            self.stop_child()
            raise SimulatorError(
                f"the simulated camera printed nothing within {timeout_s:g} s "
                f"({' '.join(self.command)}); see its messages above"
            ) from None
        if not line:
            code = proc.wait()
            raise SimulatorError(
                f"the simulated camera exited with status {code} before it was ready "
                f"({' '.join(self.command)}); its messages above say why (check [sim] in the "
                "config, e.g. the inject spec)",
                usage=code == 2,
            )
        try:
            self.info = json.loads(line)
        except json.JSONDecodeError:
            self.stop_child()
            raise SimulatorError(
                f"the simulated camera's start line is not JSON: {line.strip()!r}"
            ) from None
        return self.info

    def _spawn_locked(self) -> None:
        if self._stopped:
            raise SimulatorError("the simulated camera is not started: the daemon is stopping")
        if self._proc is not None and self._proc.poll() is None:
            raise RuntimeError(f"the simulated camera already runs (pid {self._proc.pid})")
        self.info = {}
        self._spawn()

    def _spawn(self) -> None:
        # The child listens on its sockets there: private to the daemon's user (made first:
        # the link's folder may be the same one).
        for socket_path in (self.spi_socket, self.usb_socket):
            if socket_path is not None:
                socket_path.parent.mkdir(mode=0o700, parents=True, exist_ok=True)
        self.link_path.parent.mkdir(parents=True, exist_ok=True)
        env = dict(os.environ)
        # The child is not the service: it must not talk to systemd in our name.
        for key in ("NOTIFY_SOCKET", "WATCHDOG_USEC", "WATCHDOG_PID"):
            env.pop(key, None)
        # Run the same checkout as this daemon even when camd is not installed.
        root = str(Path(camd.__file__).resolve().parent.parent)
        paths = [root, *[p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p]]
        env["PYTHONPATH"] = os.pathsep.join(dict.fromkeys(paths))
        env["PYTHONUNBUFFERED"] = "1"
        log.info("starting the simulated camera: %s", " ".join(self.command))
        self._proc = subprocess.Popen(
            self.command,
            stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE,
            stderr=None,  # its messages go where ours go (the journal under systemd)
            text=True,
            env=env,
            preexec_fn=_set_parent_death_signal if sys.platform == "linux" else None,
        )

    @staticmethod
    def _drain(stream: Any, lines: queue.Queue[str]) -> None:
        # The first line is the start line; later output is discarded so the pipe never fills.
        first = True
        for line in stream:
            if first:
                lines.put(line)
                first = False
            else:
                log.debug("sim: %s", line.rstrip())
        stream.close()  # EOF: the child exited
        if first:
            lines.put("")  # before its start line

    def stop(self, timeout_s: float = SIM_STOP_TIMEOUT_S) -> None:
        """Terminate the child (SIGTERM, then SIGKILL) and reap it; it is never started again."""
        with self._lock:
            self._stopped = True
        self.stop_child(timeout_s)

    def stop_child(self, timeout_s: float = SIM_STOP_TIMEOUT_S) -> None:
        """Terminate the current child (SIGTERM, then SIGKILL) and reap it."""
        proc = self._proc
        if proc is None or proc.poll() is not None:
            return
        proc.terminate()
        try:
            proc.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            log.warning("the simulated camera ignored SIGTERM for %g s; killing it", timeout_s)
            proc.kill()
            proc.wait()


def describe_exit(code: int) -> str:
    """How a child with exit status ``code`` (Popen's: negative for a signal) ended."""
    if code < 0:
        try:
            name = signal.Signals(-code).name
        except ValueError:
            name = f"signal {-code}"
        return f"was killed by {name}"
    return f"exited with status {code}"
