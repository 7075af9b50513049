"""``camd bench ping``: the command round trip through the whole stack against a bare pty echo.

Subject: PING through the daemon (``POST /api/v1/ping``, as ``camctl ping`` asks it): the
daemon's CommandLink -> pyserial -> pty -> simulated FPGA -> back; the daemon times each PING.
Baseline: the same frame bytes written to a pty and echoed back by a separate process, read
through pyserial: the floor any pty transport can reach. Both are started once and warmed;
then the two sides alternate (A B, B A, ...) in ``--rounds`` rounds, so that a slow spell of the
machine falls on both; the ratio is the median of the rounds' camd / echo ratios of p50 (and of
p99). Each side's turn lasts about ``--seconds`` (as many round trips as the warm-up says fit),
or ``--count / rounds`` round trips when ``--count`` is given.
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

from camd.bench.common import (
    DEFAULT_ROUNDS,
    MIN_ROUND_S,
    Alternation,
    add_round_options,
    alternate,
    machine,
)
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

MIN_PER_ROUND = 10
MAX_PER_ROUND = 100_000  # the API's most PINGs per request
CALIBRATION = 200  # round trips timed per side to size the rounds


def add_options(p: argparse.ArgumentParser) -> None:
    """The options of ``camd bench ping`` but ``--json`` (camd.bench.command adds it)."""
    p.add_argument(
        "--count",
        type=int,
        default=0,
        help="round trips per side, in all (default 0: as many as fit in --seconds a round)",
    )
    p.add_argument("--size", type=int, default=16, help="PING payload bytes, 0..256 (16)")
    add_round_options(p)


def run(args: argparse.Namespace) -> int:
    """``camd bench ping``: exit status 0, 2 on a bad option."""
    fixed = args.count != 0
    if (
        args.rounds < 1
        or (fixed and args.count < MIN_PER_ROUND * args.rounds)
        or not args.seconds > 0
        or not 0 <= args.size <= 256
    ):
        print(
            f"camd bench ping: --rounds must be >= 1, --seconds > 0, --count 0 (by time) or at "
            f"least {MIN_PER_ROUND} per round ({MIN_PER_ROUND * max(1, args.rounds)} for "
            f"{args.rounds} rounds), --size 0..256",
            file=sys.stderr,
        )
        return 2
    result = bench_ping(count=args.count, size=args.size, rounds=args.rounds, seconds=args.seconds)
    if args.json:
        print(json.dumps(result))
        return 0
    b, c = result["baseline"], result["camd"]
    print(
        f"PING round trip, {args.size}-byte payload, {result['rounds']} rounds alternated of "
        f"{result['count_per_round']['baseline']} echoes and {result['count_per_round']['camd']} "
        "PINGs"
    )
    print(f"  bare pty echo : p50 {b['p50_ms']:.3f} ms   p99 {b['p99_ms']:.3f} ms")
    print(f"  camd (full)   : p50 {c['p50_ms']:.3f} ms   p99 {c['p99_ms']:.3f} ms")
    low, high = result["ratio_p50_range"]
    print(
        f"  ratio camd/echo: p50 {result['ratio_p50']:.1f}x (rounds {low:.1f}-{high:.1f})   "
        f"p99 {result['ratio_p99']:.1f}x; {result['failed']} failed"
    )
    return 0


class PtyEcho:
    """A pty whose other end a separate process echoes back, opened with pyserial."""

    def __init__(self) -> None:
        master, slave = os.openpty()
        tty.setraw(slave)
        self._proc = subprocess.Popen(
            [sys.executable, "-c", _ECHO, str(master)], pass_fds=(master,)
        )
        os.close(master)
        self._slave = slave
        self._port = serial.Serial(os.ttyname(slave), timeout=1.0)

    def rtt_s(self, frame: bytes, count: int) -> np.ndarray:
        """Round-trip times of ``frame``, ``count`` times."""
        rtt = np.empty(count)
        for i in range(count):
            t0 = time.perf_counter()
            self._port.write(frame)
            got = self._port.read(len(frame))
            rtt[i] = time.perf_counter() - t0
            if got != frame:
                raise RuntimeError("pty echo returned different bytes; is the pty raw?")
        return rtt

    def close(self) -> None:
        self._port.close()
        os.close(self._slave)
        self._proc.terminate()
        self._proc.wait(timeout=5)


def bench_ping(
    *, count: int, size: int, rounds: int = DEFAULT_ROUNDS, seconds: float = MIN_ROUND_S
) -> dict[str, Any]:
    """Both sides, alternated; p50/p99 (ms) of each and the camd/baseline ratios. ``count``
    round trips per side in all, or 0: each turn as many as fit in ``seconds``."""
    from camd.cli._daemon_proc import DaemonProcess
    from camd.client import CamdClient

    opcode = load_dictionary().command("PING").opcode
    frame = encode_frame(FrameType.COMMAND, 0, opcode, bytes(size))
    base: list[tuple[float, float]] = []
    subject: list[tuple[float, float]] = []
    failed = 0

    with tempfile.TemporaryDirectory(prefix="camd-bench-") as tmp, DaemonProcess(Path(tmp)) as d:
        client = CamdClient(d.url)
        echo = PtyEcho()
        try:
            # The daemon serves before its camera has answered and its sensor is checked; a
            # PING before then is refused (disconnected), so wait as the other benches do.
            client.wait_ready(60)
            # Warm (connection, link, simulator) and time both sides, to size the rounds.
            t0 = time.perf_counter()
            client.ping(count=CALIBRATION, size=size)
            t1 = time.perf_counter()
            echo.rtt_s(frame, CALIBRATION)
            t2 = time.perf_counter()
            if count:
                echo_n = camd_n = max(MIN_PER_ROUND, count // rounds)
            else:
                echo_n, camd_n = (
                    min(MAX_PER_ROUND, max(MIN_PER_ROUND, round(seconds * CALIBRATION / t)))
                    for t in (t2 - t1, t1 - t0)
                )

            def echo_round() -> float:
                rtt = echo.rtt_s(frame, echo_n) * 1e3
                base.append((float(np.percentile(rtt, 50)), float(np.percentile(rtt, 99))))
                return base[-1][0]

            def camd_round() -> float:
                nonlocal failed
                doc = client.ping(count=camd_n, size=size)
                failed += doc["failed"]
                rtt = doc["rtt_ms"]
                if rtt["p50"] is None or rtt["p99"] is None:
                    raise RuntimeError(f"no PING came back: {doc['errors']}")
                subject.append((rtt["p50"], rtt["p99"]))
                return rtt["p50"]

            p50 = alternate(echo_round, camd_round, rounds)
        finally:
            echo.close()
            client.close()
    p99 = Alternation(a=[b[1] for b in base], b=[s[1] for s in subject])
    s50, s99 = p50.summary(), p99.summary()
    return {
        "count": camd_n * rounds,
        "count_per_round": {"baseline": echo_n, "camd": camd_n},
        "size": size,
        "rounds": rounds,
        "failed": failed,
        "camd": {"p50_ms": s50["b"], "p99_ms": s99["b"]},
        "baseline": {"p50_ms": s50["a"], "p99_ms": s99["a"]},
        "ratio_p50": s50["ratio"],
        "ratio_p99": s99["ratio"],
        "ratio_p50_range": s50["ratio_range"],
        "ratio_p99_range": s99["ratio_range"],
        "rounds_p50_ms": {"baseline": s50["rounds_a"], "camd": s50["rounds_b"]},
        "machine": machine(),
    }
