"""``camd bench``: benchmarks that print ratios against a baseline measured in the same run.

These machines are shared and noisy, so an absolute time means little; each benchmark measures
a baseline doing the same bare work in the same run and reports the ratio.

``camd bench ping``: the command round trip through the whole stack (daemon -> CommandLink ->
pyserial -> pty -> simulated FPGA -> back), as `camctl ping` reports it, against a bare pty echo
of the same frame bytes by a separate process (the floor any pty transport can reach).

``camd bench stream``: frame ingest (``camd.link.frame_stream.FrameStream``: pyusb bulk reads
into its slots, reassembly, header and payload CRC checks, queue, dispatch to a no-op
consumer) against bare bulk reads of the same stream into one buffer through the same pyusb
backend and socket, with no parsing. The simulated FX3 runs in its own process
(``python -m firmware_models.fx3``), unpaced, replaying a bank of random 12-bit frames; this
process reads it through the FX3's host half (``firmware_models.fx3_backend``).

``camd bench tdi``: the TDI engine (``camd.tdi``), ``tdi_batch`` and a naive per-line numpy loop
against ``np.copyto`` of the same input bytes (the memory-bandwidth floor); it lives in
``camd.cli.bench_tdi``.

``camd bench scan`` (``camd.cli.bench_scan``): a scan through the daemon at the sensor's line
rate. ``camd bench live`` (``camd.cli.bench_live``): the daemon's stream ingest with live
viewers attached against none, in alternating rounds of the same run. ``camd bench fuzz``
(``camd.cli.bench_fuzz``): the daemon's API fuzzed from its own /openapi.json (schemathesis),
no baseline: counts of requests, status codes, server errors and hangs.
"""

from __future__ import annotations

import argparse
import array
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
import usb.core
import usb.util

from camd.cli import bench_fuzz, bench_live, bench_pipeline, bench_scan, bench_sim, bench_tdi
from camd.cli.bench_streamer import FrameStreamer
from camd.link.frame_stream import FrameStream
from camd.protocol import FrameType, encode_frame, load_dictionary
from firmware_models.fx3_backend import PRODUCT_ID, VENDOR_ID, get_backend

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
    stream = which.add_parser(
        "stream",
        help="frame ingest vs bare bulk reads of the same stream",
        description="Frame ingest (FrameStream with a no-op consumer) against bare bulk reads of "
        "the same USB stream into one buffer, from a simulated FX3 in its own process.",
    )
    stream.add_argument("--rows", type=int, default=534, help="window rows (default 534, hr400)")
    stream.add_argument("--cols", type=int, default=2048, help="window columns (default 2048)")
    stream.add_argument(
        "--seconds", type=float, default=2.5, help="measuring time per side (default 2.5)"
    )
    stream.add_argument("--queue-frames", type=int, default=8, help="FrameStream queue (default 8)")
    stream.add_argument("--json", action="store_true", help="print one JSON document")
    bench_tdi.add_parser(which)
    bench_scan.add_parser(which)
    bench_pipeline.add_parser(which)
    bench_sim.add_parser(which)
    bench_live.add_parser(which)
    bench_fuzz.add_parser(which)


def run(args: argparse.Namespace) -> int:
    if args.bench == "tdi":
        return bench_tdi.run(args)
    if args.bench == "scan":
        return bench_scan.run(args)
    if args.bench == "sim":
        return bench_sim.run(args)
    if args.bench == "pipeline":
        return bench_pipeline.run(args)
    if args.bench == "live":
        return bench_live.run(args)
    if args.bench == "fuzz":
        return bench_fuzz.run(args)
    if args.bench == "stream":
        return _run_stream(args)
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


# -- camd bench stream --------------------------------------------------------------------------


def _run_stream(args: argparse.Namespace) -> int:
    if args.rows < 1 or args.cols < 1 or not args.seconds > 0 or args.queue_frames < 1:
        print(
            "camd bench stream: --rows, --cols and --queue-frames must be >= 1, --seconds > 0",
            file=sys.stderr,
        )
        return 2
    result = bench_stream(
        rows=args.rows, cols=args.cols, seconds=args.seconds, queue_frames=args.queue_frames
    )
    if args.json:
        print(json.dumps(result))
    else:
        print(
            f"frame stream, {args.rows} x {args.cols} uint16 frames "
            f"({result['frame_bytes'] / 1e6:.2f} MB), {args.seconds:g} s per side"
        )
        print(f"  bare bulk reads : {result['baseline_mbyte_s']:8.1f} MB/s")
        print(
            f"  FrameStream     : {result['ingest_mbyte_s']:8.1f} MB/s "
            f"({result['mpix_per_s']:.1f} Mpix/s, {result['frames']} frames, "
            f"{result['lost']} lost, {result['overruns']} overruns)"
        )
        print(f"  ratio ingest/bare: {result['ratio']:.2f}")
    return 0


def bare_bulk_mbyte_s(socket_path: Path, frame_bytes: int, seconds: float) -> dict[str, Any]:
    """Bulk reads of whole transfers into one buffer, no parsing: the transport's floor."""
    backend = get_backend(socket_path)
    dev = usb.core.find(idVendor=VENDOR_ID, idProduct=PRODUCT_ID, backend=backend)
    try:
        dev.set_configuration()
        usb.util.claim_interface(dev, 0)
        # The same read size as FrameStream's: one frame plus a byte, in whole packets.
        size = (frame_bytes + 1 + 1023) // 1024 * 1024
        buf = array.array("B", [0]) * size
        dev.read(0x81, buf, 5000)  # the first transfer: the stream is flowing
        total = transfers = 0
        t0 = time.perf_counter()
        end = t0 + seconds
        while True:
            total += dev.read(0x81, buf, 5000)
            transfers += 1
            now = time.perf_counter()
            if now >= end:
                break
        return {"mbyte_s": total / (now - t0) / 1e6, "transfers": transfers}
    finally:
        usb.util.dispose_resources(dev)
        backend.close()


def ingest_mbyte_s(
    socket_path: Path, frame_bytes: int, seconds: float, queue_frames: int
) -> dict[str, Any]:
    """FrameStream with a no-op consumer: delivered bytes per second after the first frame."""
    backend = get_backend(socket_path)
    with FrameStream(backend=backend, queue_frames=queue_frames) as stream:
        stream.add_consumer(lambda frame: None)
        stream.start(max_frame_bytes=frame_bytes)
        if not stream.wait_frames(1, 10.0):
            raise RuntimeError(f"FrameStream delivered no frame: {stream.error or stream.problem}")
        before, t0 = stream.stats(), time.perf_counter()
        time.sleep(seconds)
        after, t1 = stream.stats(), time.perf_counter()
        stream.stop()
    backend.close()
    frames = after.frames - before.frames
    return {
        "mbyte_s": (after.bytes - before.bytes) / (t1 - t0) / 1e6,
        "mpix_per_s": frames * (frame_bytes - 64) / 2 / (t1 - t0) / 1e6,
        "stats": after.as_dict(),
        "frames": frames,
    }


def bench_stream(
    *, rows: int, cols: int, seconds: float, queue_frames: int, rounds: int = 5
) -> dict[str, Any]:
    """Both sides against one simulated FX3 process, alternating in ``rounds`` rounds (so a
    slow spell of this shared machine hits both); the median MB/s of each and their ratio."""
    frame_bytes = 64 + 2 * rows * cols
    bases: list[dict[str, Any]] = []
    ingests: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory(prefix="camd-bench-") as tmp:
        sock = Path(tmp) / "fx3.sock"
        streamer = FrameStreamer(sock, rows, cols)
        try:
            for _ in range(rounds):
                bases.append(bare_bulk_mbyte_s(sock, frame_bytes, seconds / rounds))
                ingests.append(ingest_mbyte_s(sock, frame_bytes, seconds / rounds, queue_frames))
        finally:
            device = streamer.close()
    base = sorted(bases, key=lambda r: r["mbyte_s"])[len(bases) // 2]
    ingest = sorted(ingests, key=lambda r: r["mbyte_s"])[len(ingests) // 2]
    stats = ingest["stats"]
    return {
        "ingest_mbyte_s": ingest["mbyte_s"],
        "baseline_mbyte_s": base["mbyte_s"],
        "ratio": ingest["mbyte_s"] / base["mbyte_s"],
        "mpix_per_s": ingest["mpix_per_s"],
        "rows": rows,
        "cols": cols,
        "frame_bytes": frame_bytes,
        "seconds": seconds,
        "rounds": rounds,
        "ingest_rounds_mbyte_s": [round(r["mbyte_s"], 1) for r in ingests],
        "baseline_rounds_mbyte_s": [round(r["mbyte_s"], 1) for r in bases],
        "frames": ingest["frames"],
        "baseline_transfers": base["transfers"],
        "lost": stats["lost"],
        "corrupt": stats["corrupt"],
        "short": stats["short"],
        "overruns": stats["overruns"],
        "out_of_order": stats["out_of_order"],
        "device": device,
    }
