"""The simulated camera as a child process of the daemon (``link.device = "sim"``).

``SimulatorProcess`` runs ``python -m firmware_models --json --link ...`` with the sockets of
the simulated USB devices, waits for its one JSON start line, and stops it (SIGTERM, then
SIGKILL). The child gets SIGTERM when the daemon dies, even by SIGKILL (Linux).
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
from typing import Any

import camd
from camd.daemon.errors import SimulatorError

log = logging.getLogger(__name__)

SIM_START_TIMEOUT_S = 20.0  # the simulator imports numpy and the dictionary before its line
SIM_STOP_TIMEOUT_S = 5.0


def _set_parent_death_signal() -> None:
    """In the simulator child: receive SIGTERM when the daemon dies, even by SIGKILL."""
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
    ) -> None:
        self.link_path = link_path
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
        self.info: dict[str, Any] = {}
        self._proc: subprocess.Popen[str] | None = None
        self._exit_reported = False

    @property
    def pid(self) -> int | None:
        """The child's pid while it runs, else None."""
        return self._proc.pid if self._proc is not None and self._proc.poll() is None else None

    def returncode(self) -> int | None:
        """The exit status once the child has exited (reaping it), else None."""
        return None if self._proc is None else self._proc.poll()

    def start(self, timeout_s: float = SIM_START_TIMEOUT_S) -> dict[str, Any]:
        """Spawn the simulator and return its JSON start line as a dict.

        Raises SimulatorError if it exits or stays silent for ``timeout_s`` (it is then killed).
        """
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
        assert self._proc.stdout is not None
        lines: queue.Queue[str] = queue.Queue()
        reader = threading.Thread(
            target=self._drain, args=(self._proc.stdout, lines), name="sim-stdout", daemon=True
        )
        reader.start()
        try:
            line = lines.get(timeout=timeout_s)
        except queue.Empty:
            self.stop()
            raise SimulatorError(
                f"the simulated camera printed nothing within {timeout_s:g} s "
                f"({' '.join(self.command)}); see its messages above"
            ) from None
        if not line:
            code = self._proc.wait()
            raise SimulatorError(
                f"the simulated camera exited with status {code} before it was ready "
                f"({' '.join(self.command)}); its messages above say why (check [sim] in the "
                "config, e.g. the inject spec)",
                usage=code == 2,
            )
        try:
            self.info = json.loads(line)
        except json.JSONDecodeError:
            self.stop()
            raise SimulatorError(
                f"the simulated camera's start line is not JSON: {line.strip()!r}"
            ) from None
        return self.info

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
        if first:
            lines.put("")  # EOF before the start line: the child exited

    def exit_report(self) -> str | None:
        """Once, after the child exited on its own: a message saying so; else None."""
        code = self.returncode()
        if code is None or self._exit_reported:
            return None
        self._exit_reported = True
        how = f"killed by signal {-code}" if code < 0 else f"exited with status {code}"
        return (
            f"the simulated camera (pid {self._proc.pid if self._proc else '?'}) {how}; "
            f"it is not restarted: run `camd sim --link {self.link_path}` to reconnect"
        )

    def stop(self, timeout_s: float = SIM_STOP_TIMEOUT_S) -> None:
        """Terminate the child (SIGTERM, then SIGKILL) and reap it."""
        proc = self._proc
        if proc is None or proc.poll() is not None:
            return
        self._exit_reported = True  # our own doing, not worth an error event
        proc.terminate()
        try:
            proc.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            log.warning("the simulated camera ignored SIGTERM for %g s; killing it", timeout_s)
            proc.kill()
            proc.wait()
