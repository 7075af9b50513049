"""A simulated FX3 streamer in its own process, for the USB and host-pipeline benchmarks."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any


class FrameStreamer:
    """``python -m firmware_models.fx3`` in its own process, as the simulator is in production:
    unpaced, replaying ``bank`` random frames of ``rows`` x ``cols`` (TDI mode, M = rows)."""

    def __init__(self, socket_path: Path, rows: int, cols: int, *, bank: int = 4) -> None:
        self.proc = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "firmware_models.fx3",
                "--socket",
                str(socket_path),
                "--rows",
                str(rows),
                "--cols",
                str(cols),
                "--bank",
                str(bank),
            ],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
        )
        assert self.proc.stdout is not None
        line = self.proc.stdout.readline()
        if not line:
            self.proc.wait(timeout=5)
            raise RuntimeError(f"the simulated FX3 exited with status {self.proc.returncode}")
        self.ready: dict[str, Any] = json.loads(line)

    def close(self) -> dict[str, Any]:
        """End the process (closing its stdin); its engine counters."""
        assert self.proc.stdin is not None and self.proc.stdout is not None
        self.proc.stdin.close()
        out = self.proc.stdout.read()
        self.proc.wait(timeout=10)
        lines = out.strip().splitlines()
        return json.loads(lines[-1]) if lines else {}
