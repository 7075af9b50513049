"""``camd bench stream``: frame ingest (``FrameStream``) against bare reads on the same threads.

Subject: ``camd.link.frame_stream.FrameStream`` with a no-op consumer: its reader thread does
pyusb bulk reads into preallocated slots, its dispatcher thread checks each frame (header and
payload CRC, counters, reassembly) and hands it to the consumer.

Baseline: the same two threads doing none of that work. A reader thread does pyusb bulk reads
of whole transfers, of the same size, through the same backend and socket, into a ring of slots
of the same size, and hands each filled slot to a second thread, which gives it back untouched.
A one-thread baseline (reads into one buffer) is not a floor for a two-thread ingest: on a
2-core machine the ingest's reader overlaps its own hand-off with the next read, so it can beat
one thread and the ratio then bounds nothing.

Both read from one simulated FX3 in its own process (``python -m firmware_models.fx3``),
unpaced, replaying a bank of random 12-bit frames twice the size of the last-level cache, so
that neither side reads from a cache. The two sides alternate in rounds (A B, B A, ...) and the
ratio is the median of the rounds' ingest / bare ratios.
"""

from __future__ import annotations

import argparse
import array
import json
import queue
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import usb.core
import usb.util

from camd.bench.common import (
    DEFAULT_ROUNDS,
    add_round_options,
    alternate,
    beyond_cache_bytes,
    machine,
)
from camd.bench.streamer import FrameStreamer
from camd.link.frame_stream import FrameStream
from camd.protocol.stream import HEADER_BYTES
from firmware_models.fx3_backend import PRODUCT_ID, VENDOR_ID, get_backend

BARE_SLOTS = 8
"""Slots in the baseline's ring (FrameStream starts with 3 and grows as its queue does)."""

BANK_MIN_BYTES = 64 << 20
"""The smallest frame bank (also when the cache size cannot be read)."""

BANK_MAX_BYTES = 2 << 30
"""The largest frame bank: the simulator holds it in memory."""


def add_options(p: argparse.ArgumentParser) -> None:
    """The options of ``camd bench stream`` but ``--json`` (camd.bench.command adds it)."""
    p.add_argument("--rows", type=int, default=534, help="window rows (default 534, hr400)")
    p.add_argument("--cols", type=int, default=2048, help="window columns (default 2048)")
    add_round_options(p)
    p.add_argument(
        "--bank-mb",
        type=float,
        default=0.0,
        help="the simulator's frame bank, MB (default 0: twice the last-level cache)",
    )
    p.add_argument("--queue-frames", type=int, default=8, help="FrameStream queue (default 8)")


def run(args: argparse.Namespace) -> int:
    """``camd bench stream``: exit status 0, 2 on a bad option."""
    if (
        args.rows < 1
        or args.cols < 1
        or not args.seconds > 0
        or args.rounds < 1
        or args.queue_frames < 1
        or args.bank_mb < 0
    ):
        print(
            "camd bench stream: --rows, --cols, --rounds and --queue-frames must be >= 1, "
            "--seconds > 0, --bank-mb >= 0 (0: twice the last-level cache)",
            file=sys.stderr,
        )
        return 2
    result = bench_stream(
        rows=args.rows,
        cols=args.cols,
        seconds=args.seconds,
        rounds=args.rounds,
        queue_frames=args.queue_frames,
        bank_mb=args.bank_mb,
    )
    if args.json:
        print(json.dumps(result))
        return 0
    print(
        f"frame stream, {args.rows} x {args.cols} uint16 frames "
        f"({result['frame_bytes'] / 1e6:.2f} MB; bank {result['bank_frames']} frames, "
        f"{result['bank_mb']:.0f} MB), {result['rounds']} rounds of {args.seconds:g} s a side"
    )
    print(f"  bare reads, 2 threads: {result['baseline_mbyte_s']:8.1f} MB/s")
    print(
        f"  FrameStream          : {result['ingest_mbyte_s']:8.1f} MB/s "
        f"({result['mpix_per_s']:.1f} Mpix/s; {result['lost']} lost, "
        f"{result['overruns']} overruns)"
    )
    low, high = result["ratio_range"]
    print(f"  ratio ingest/bare: {result['ratio']:.2f} (rounds {low:.2f}-{high:.2f})")
    return 0


def transfer_bytes(frame_bytes: int) -> int:
    """FrameStream's read size for frames of ``frame_bytes``: a frame and a byte, in whole
    1024-byte packets (a short last packet ends the transfer)."""
    return (frame_bytes + 1 + 1023) // 1024 * 1024


def bare_reads(socket_path: Path, frame_bytes: int, seconds: float) -> dict[str, Any]:
    """The baseline: bulk reads into a ring of slots on a reader thread, each slot handed to
    a second thread that gives it back untouched; MB/s after the first transfer."""
    backend = get_backend(socket_path)
    dev = usb.core.find(idVendor=VENDOR_ID, idProduct=PRODUCT_ID, backend=backend)
    free: queue.SimpleQueue[array.array[int]] = queue.SimpleQueue()
    full: queue.SimpleQueue[tuple[array.array[int], int] | None] = queue.SimpleQueue()
    size = transfer_bytes(frame_bytes)
    for _ in range(BARE_SLOTS):
        free.put(array.array("B", [0]) * size)
    stop = threading.Event()
    got = {"bytes": 0, "transfers": 0}
    lock = threading.Lock()
    failure: list[BaseException] = []

    def reader() -> None:
        try:
            while not stop.is_set():
                buf = free.get()
                full.put((buf, int(dev.read(0x81, buf, 5000))))
        except BaseException as exc:  # report it to the caller, whatever it is
            failure.append(exc)
        finally:
            full.put(None)

    def returner() -> None:
        while (item := full.get()) is not None:
            with lock:
                got["bytes"] += item[1]
                got["transfers"] += 1
            free.put(item[0])

    try:
        dev.set_configuration()
        usb.util.claim_interface(dev, 0)
        threads = [
            threading.Thread(target=reader, name="bench-read", daemon=True),
            threading.Thread(target=returner, name="bench-return", daemon=True),
        ]
        for t in threads:
            t.start()
        deadline = time.monotonic() + 10.0
        while not got["transfers"] and not failure and time.monotonic() < deadline:
            time.sleep(0.001)
        if not got["transfers"]:
            raise RuntimeError(f"bare reads got no transfer: {failure or 'timeout'}")
        with lock:
            b0, n0 = got["bytes"], got["transfers"]
        t0 = time.perf_counter()
        time.sleep(seconds)
        with lock:
            b1, n1 = got["bytes"], got["transfers"]
        t1 = time.perf_counter()
        stop.set()
        for t in threads:
            t.join(timeout=10)
        if failure:
            raise RuntimeError(f"bare reads failed: {failure[0]}")
        return {"mbyte_s": (b1 - b0) / (t1 - t0) / 1e6, "transfers": n1 - n0}
    finally:
        stop.set()
        usb.util.dispose_resources(dev)
        backend.close()


def ingest(
    socket_path: Path, frame_bytes: int, seconds: float, queue_frames: int
) -> dict[str, Any]:
    """FrameStream with a no-op consumer: delivered MB/s after the first frame."""
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
        "mpix_per_s": frames * (frame_bytes - HEADER_BYTES) / 2 / (t1 - t0) / 1e6,
        "stats": after.as_dict(),
        "frames": frames,
    }


def bench_stream(
    *,
    rows: int,
    cols: int,
    seconds: float,
    queue_frames: int,
    rounds: int = DEFAULT_ROUNDS,
    bank_mb: float = 0.0,
) -> dict[str, Any]:
    """Both sides against one simulated FX3 process, alternated; MB/s of each, the ratio."""
    frame_bytes = HEADER_BYTES + 2 * rows * cols
    bank_bytes = int(bank_mb * 1e6) if bank_mb > 0 else beyond_cache_bytes(BANK_MIN_BYTES)
    bank = max(2, min(bank_bytes, BANK_MAX_BYTES) // frame_bytes)
    bases: list[dict[str, Any]] = []
    ingests: list[dict[str, Any]] = []

    with tempfile.TemporaryDirectory(prefix="camd-bench-") as tmp:
        sock = Path(tmp) / "fx3.sock"
        streamer = FrameStreamer(sock, rows, cols, bank=bank)
        try:

            def bare_round() -> float:
                bases.append(bare_reads(sock, frame_bytes, seconds))
                return float(bases[-1]["mbyte_s"])

            def ingest_round() -> float:
                ingests.append(ingest(sock, frame_bytes, seconds, queue_frames))
                return float(ingests[-1]["mbyte_s"])

            result = alternate(bare_round, ingest_round, rounds)
        finally:
            device = streamer.close()
    summary = result.summary()
    stats = [r["stats"] for r in ingests]
    return {
        "ingest_mbyte_s": summary["b"],
        "baseline_mbyte_s": summary["a"],
        "ratio": summary["ratio"],
        "ratio_range": summary["ratio_range"],
        "mpix_per_s": sorted(r["mpix_per_s"] for r in ingests)[len(ingests) // 2],
        "rows": rows,
        "cols": cols,
        "frame_bytes": frame_bytes,
        "bank_frames": bank,
        "bank_mb": bank * frame_bytes / 1e6,
        "seconds": seconds,
        "rounds": rounds,
        "ingest_rounds_mbyte_s": summary["rounds_b"],
        "baseline_rounds_mbyte_s": summary["rounds_a"],
        "frames": sum(r["frames"] for r in ingests),
        "baseline_transfers": sum(r["transfers"] for r in bases),
        "lost": sum(s["lost"] for s in stats),
        "corrupt": sum(s["corrupt"] for s in stats),
        "short": sum(s["short"] for s in stats),
        "overruns": sum(s["overruns"] for s in stats),
        "out_of_order": sum(s["out_of_order"] for s in stats),
        "device": device,
        "machine": machine(),
    }
