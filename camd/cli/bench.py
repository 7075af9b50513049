"""``camd bench``: benchmarks that print ratios against a baseline measured in the same run.

These machines are shared and noisy, so an absolute time means little; each benchmark measures
a baseline doing the same bare work in the same run and reports the ratio.

``camd bench ping``: the command round trip through the whole stack (daemon -> CommandLink ->
pyserial -> pty -> simulated FPGA -> back), as `camctl ping` reports it, against a bare pty echo
of the same frame bytes by a separate process (the floor any pty transport can reach).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
import tty
from pathlib import Path
from typing import Any

import numpy as np
import serial

from camd.protocol import FrameType, encode_frame, load_dictionary

# Echo peer for the baseline: a separate process, like the simulator, copying bytes back.
_ECHO = """
import os, sys
fd = int(sys.argv[1])
while True:
    try:
        data = os.read(fd, 65536)
    except OSError:
        break
    if not data:
        break
    os.write(fd, data)
"""


def add_parser(sub: Any) -> None:
    p: argparse.ArgumentParser = sub.add_parser(
        "bench",
        help="benchmarks (ratios against a same-run baseline)",
        description="Benchmarks that report ratios against a baseline measured in the same run.",
    )
    which = p.add_subparsers(dest="bench", metavar="BENCH", required=True)
    ping = which.add_parser(
        "ping",
        help="command round trip vs a bare pty echo",
        description="Round trip of PING through the daemon and the simulated camera, against a "
        "bare pty echo of the same bytes by a separate process.",
    )
    ping.add_argument("--count", type=int, default=2000, help="round trips per side (default 2000)")
    ping.add_argument("--size", type=int, default=16, help="PING payload bytes (default 16)")
    ping.add_argument("--json", action="store_true", help="print one JSON document")


def run(args: argparse.Namespace) -> int:
    if args.count < 10:
        print("camd bench ping: --count must be at least 10", file=sys.stderr)
        return 2
    result = bench_ping(count=args.count, size=args.size)
    if args.json:
        print(json.dumps(result))
    else:
        b, c = result["baseline"], result["camd"]
        print(f"PING round trip, {args.count} commands of {args.size}-byte payload")
        print(f"  bare pty echo : p50 {b['p50_ms']:.3f} ms   p99 {b['p99_ms']:.3f} ms")
        print(f"  camd (full)   : p50 {c['p50_ms']:.3f} ms   p99 {c['p99_ms']:.3f} ms")
        print(f"  ratio camd/echo: p50 {result['ratio_p50']:.1f}x   p99 {result['ratio_p99']:.1f}x")
    return 0


def pty_echo_rtt_s(frame: bytes, count: int) -> np.ndarray:
    """Round-trip times of ``frame`` through a pty to an echoing process and back."""
    master, slave = os.openpty()
    tty.setraw(slave)
    echo = subprocess.Popen([sys.executable, "-c", _ECHO, str(master)], pass_fds=(master,))
    os.close(master)
    rtt = np.empty(count)
    try:
        with serial.Serial(os.ttyname(slave), timeout=1.0) as port:
            for i in range(count):
                t0 = time.perf_counter()
                port.write(frame)
                got = port.read(len(frame))
                rtt[i] = time.perf_counter() - t0
                if got != frame:
                    raise RuntimeError("pty echo returned different bytes; is the pty raw?")
    finally:
        os.close(slave)
        echo.terminate()
        echo.wait(timeout=5)
    return rtt


def bench_ping(*, count: int, size: int) -> dict[str, Any]:
    """Run both sides; return p50/p99 of each (ms) and the camd/baseline ratios."""
    from camd.cli._daemon_proc import DaemonProcess

    opcode = load_dictionary().command("PING").opcode
    frame = encode_frame(FrameType.COMMAND, 0, opcode, bytes(size))
    base = pty_echo_rtt_s(frame, count) * 1e3
    with tempfile.TemporaryDirectory(prefix="camd-bench-") as tmp, DaemonProcess(Path(tmp)) as d:
        out = subprocess.run(
            [
                sys.executable,
                "-m",
                "camd.cli.camctl",
                "--url",
                d.url,
                "ping",
                "--count",
                str(count),
                "--size",
                str(size),
                "--json",
            ],
            capture_output=True,
            text=True,
            check=True,
        )
    ping = json.loads(out.stdout)
    baseline = {"p50_ms": float(np.percentile(base, 50)), "p99_ms": float(np.percentile(base, 99))}
    camd_rtt = {"p50_ms": ping["rtt_ms"]["p50"], "p99_ms": ping["rtt_ms"]["p99"]}
    return {
        "count": count,
        "size": size,
        "failed": ping["failed"],
        "camd": camd_rtt,
        "baseline": baseline,
        "ratio_p50": camd_rtt["p50_ms"] / baseline["p50_ms"],
        "ratio_p99": camd_rtt["p99_ms"] / baseline["p99_ms"],
    }
