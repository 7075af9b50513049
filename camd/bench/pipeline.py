"""``camd bench pipeline``: how fast can the host take a scan's frames, and at what CPU cost?

Frames come from a simulated FX3 in its own process, unpaced (as fast as the host reads),
replaying a bank of random frames larger than this machine's last-level cache, and go through
the host path a scan uses, whole: pyusb bulk reads of packed transfers, as the daemon asks
for them (``FrameStream``: header and payload CRC checks, counters, queue, dispatch), the
batcher, the TDI engine and the HDF5 recorder (``TdiPipeline``). The rate frames get through the engine is the most the host sustains; the
CPU of each thread, per frame, says where it goes. The baseline is the sensor: the fastest line
rate a window of M rows allows (one line of exposure: a frame every ``max(M, 2)`` line
periods, docs/physics.md §3), so ``over_line_rate`` is the host's headroom with every core it
wants, and ``one_core_headroom`` the headroom if all the host's work ran on one core
(frames per CPU-second over the line rate).
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from camd.bench.common import (
    beyond_cache_bytes,
    choice_list,
    int_list,
    last_level_cache_bytes,
    machine,
    thread_cpu_s,
    window_stages,
)
from camd.daemon.config_sections import StoreSection
from camd.store.compression import FILTERS, Compression
from camd.store.durability import FLUSH_PERIOD_S
from camd.store.tdi_layout import chunk_lines_for

DEFAULT_PROFILES = ("hr400", "ibis5", "ftf5066", "uvccd", "mt9m001")
# 1: each profile's fastest line rate (its fewest window rows), where the host's cost per
# frame counts most; 96: a full TDI window, where its cost per pixel does.
DEFAULT_STAGES = (1, 96)
DEFAULT_ROUNDS = 3
WARM_UP_S = 1.0
BANK_MB_MIN = 64  # the bank when the cache size cannot be read
BANK_MB_MAX = 2048
THREADS = {"read": "camd-frame-read", "dispatch": "camd-frame-dispatch", "tdi": "camd-tdi-worker"}


def add_options(p: argparse.ArgumentParser) -> None:
    """The options of ``camd bench pipeline`` but ``--json`` (camd.bench.command adds it)."""
    p.add_argument(
        "--profiles",
        default=",".join(DEFAULT_PROFILES),
        help="camera profiles, comma-separated (default all five shipped)",
    )
    p.add_argument(
        "--stages",
        type=lambda text: int_list(text, "--stages"),
        default=DEFAULT_STAGES,
        help="M = window rows, comma-separated (default 1,96; 1: the fastest line rate, raised "
        "to the sensor's fewest window rows; M is capped at the sensor's rows)",
    )
    p.add_argument("--seconds", type=float, default=2.0, help="length of each round (2)")
    p.add_argument("--rounds", type=int, default=DEFAULT_ROUNDS, help="rounds, medians (3)")
    p.add_argument(
        "--bank-mb",
        type=float,
        default=0.0,
        help="size of the replayed frame bank, MB (default 0: twice the last-level cache)",
    )
    p.add_argument(
        "--compression",
        type=lambda text: choice_list(text, tuple(FILTERS), "compression")[0],
        default=None,
        help=f"the scan file's compression: {', '.join(FILTERS)} (default: a scan's by the "
        "default config: off above store.scan_compression_max_mbyte_s, else bitshuffle-lz4)",
    )


def _threads() -> dict[str, int]:
    """Native ids of the pipeline's named threads."""
    ids = {t.name: t.native_id for t in threading.enumerate() if t.native_id is not None}
    return {key: ids[name] for key, name in THREADS.items() if name in ids}


def line_rate_hz(profile: str, stages: int) -> tuple[float, int]:
    """(the fastest line rate a window of ``stages`` rows allows, the sensor's columns)."""
    from camd.sensor.profile import load_profile
    from camd.sensor.regmap import load_register_map
    from camd.sensor.timing_view import reset_timing
    from camd.timing.sequencer import sequencer_frame_period_s

    camera = load_profile(profile)
    line_s = reset_timing(load_register_map(camera.sensor)).line_period_s
    return 1.0 / sequencer_frame_period_s(1, stages, line_s), int(camera.columns.value)


def measure(
    profile: str,
    stages: int,
    *,
    seconds: float,
    rounds: int,
    bank_mb: float,
    compression: str | None = None,
) -> dict[str, Any]:
    """One profile: the host path on an unpaced stream of M x columns frames."""
    from camd.bench.streamer import FrameStreamer
    from camd.link.frame_stream import PACK_BYTES, FrameStream
    from camd.pipeline.tdi_pipeline import TdiPipeline
    from camd.protocol.stream import HEADER_BYTES
    from camd.store.tdi_recording import TdiRecorder
    from camd.tdi import TdiEngine
    from firmware_models.fx3_backend import get_backend

    rate_hz, cols = line_rate_hz(profile, stages)
    # As a scan at this rate is stored by the default config, unless told.
    chosen = (
        StoreSection().compression_for(None, None, mbyte_s=4 * cols * rate_hz / 1e6)
        if compression is None
        else Compression.of(compression)
    )
    frame_bytes = HEADER_BYTES + 2 * stages * cols
    if bank_mb <= 0:
        bank_mb = beyond_cache_bytes(int(BANK_MB_MIN * 1e6)) / 1e6
    bank_mb = min(max(bank_mb, frame_bytes / 1e6), BANK_MB_MAX)
    bank = max(1, round(bank_mb * 1e6 / frame_bytes))
    samples: list[dict[str, float]] = []
    with tempfile.TemporaryDirectory(prefix="camd-bench-pipeline-") as tmp:
        sock = Path(tmp) / "fx3.sock"
        streamer = FrameStreamer(sock, stages, cols, bank=bank)
        backend = get_backend(sock)
        recorder = TdiRecorder(
            Path(tmp) / "scan.h5", width=cols, mode="sum", metadata={},
            chunk_lines=chunk_lines_for(1.0 / rate_hz, FLUSH_PERIOD_S),
            compression=chosen,
        )  # fmt: skip
        engine = TdiEngine(stages, cols)
        # Load (or compile) the kernel first, as a scan does (camd.daemon.scan_planner).
        TdiEngine(stages, cols).push_many(np.zeros((2, stages, cols), dtype=np.uint16))
        pipeline = TdiPipeline(engine, recorder, rows=stages)
        stream = FrameStream(
            backend=backend, queue_frames=4096, queue_bytes=256_000_000, pack_bytes=PACK_BYTES
        )
        try:
            stream.open()
            pipeline.start()
            stream.add_consumer(pipeline.consumer)
            stream.start(max_frame_bytes=frame_bytes)
            time.sleep(WARM_UP_S)
            for _ in range(rounds):
                samples.append(_sample_round(stream, pipeline, seconds))
            stream.stop()
            stats = stream.stats()
            pipeline.finish(flush=False)
        finally:
            stream.close()
            recorder.close()
            backend.close()
            streamer.close()
        file_mb = (Path(tmp) / "scan.h5").stat().st_size / 1e6
    progress = pipeline.progress()

    def median(key: str) -> float:
        return statistics.median(s[key] for s in samples)

    per_frame = {
        key: median(f"{key}_us") for key in ("read", "dispatch", "engine", "record", "other")
    }
    total_us = median("total_us")
    frames_per_s = median("frames_per_s")
    return {
        "profile": profile,
        "stages": stages,
        "cols": cols,
        "frame_bytes": frame_bytes,
        "bank_frames": bank,
        "bank_mb": bank * frame_bytes / 1e6,
        "line_rate_hz": rate_hz,
        "frames_per_s": frames_per_s,
        "over_line_rate": frames_per_s / rate_hz,
        "cpu_us_per_frame": per_frame,
        "cpu_us_per_frame_total": total_us,
        "one_core_headroom": 1e6 / (total_us * rate_hz) if total_us > 0 else None,
        "cores_used": median("cores"),
        "rounds": [{k: round(v, 3) for k, v in s.items()} for s in samples],
        "frames_in": progress.frames_in,
        "lines": progress.lines,
        "lost": stats.lost,
        "corrupt": stats.corrupt,
        "overruns": stats.overruns,
        "dropped_by_batcher": progress.dropped_frames,
        "file_mb": file_mb,
        "compression": chosen.filter,
    }


def _sample_round(stream: Any, pipeline: Any, seconds: float) -> dict[str, float]:
    """One round: frames through the engine per second, and CPU per frame by stage."""
    threads = _threads()

    def snapshot() -> tuple[float, float, dict[str, float], Any, Any]:
        cpu = {key: thread_cpu_s(tid) for key, tid in threads.items()}
        return time.perf_counter(), time.process_time(), cpu, pipeline.progress(), stream.stats()

    t0, proc0, cpu0, p0, s0 = snapshot()
    time.sleep(seconds)
    t1, proc1, cpu1, p1, s1 = snapshot()
    frames = max(1, p1.frames_in - p0.frames_in)
    read = s1.frames + s1.overruns - s0.frames - s0.overruns
    read_us = (cpu1.get("read", 0.0) - cpu0.get("read", 0.0)) / max(1, read) * 1e6
    dispatch_us = (cpu1.get("dispatch", 0.0) - cpu0.get("dispatch", 0.0)) / max(1, read) * 1e6
    engine_us = (p1.engine_cpu_s - p0.engine_cpu_s) / frames * 1e6
    record_us = (p1.record_cpu_s - p0.record_cpu_s) / frames * 1e6
    total_us = (proc1 - proc0) / frames * 1e6
    return {
        "seconds": t1 - t0,
        "frames_per_s": (p1.frames_in - p0.frames_in) / (t1 - t0),
        "read_us": read_us,
        "dispatch_us": dispatch_us,
        "engine_us": engine_us,
        "record_us": record_us,
        "other_us": max(0.0, total_us - read_us - dispatch_us - engine_us - record_us),
        "total_us": total_us,
        "cores": (proc1 - proc0) / (t1 - t0),
    }


def run(args: argparse.Namespace) -> int:
    """``camd bench pipeline``: print the figures (one JSON document with --json)."""
    if min(args.stages) < 1 or args.rounds < 1 or not args.seconds > 0 or args.bank_mb < 0:
        print(
            "camd bench pipeline: --stages and --rounds must be >= 1, --seconds > 0, "
            "--bank-mb >= 0 (0: twice the last-level cache)"
        )
        return 2
    profiles = [p.strip() for p in args.profiles.split(",") if p.strip()]
    cases = []
    for profile in profiles:
        for stages in window_stages(profile, args.stages):
            cases.append(
                measure(
                    profile,
                    stages,
                    seconds=args.seconds,
                    rounds=args.rounds,
                    bank_mb=args.bank_mb,
                    compression=getattr(args, "compression", None),
                )
            )
    if args.json:
        doc = {
            "cases": cases,
            "last_level_cache_bytes": last_level_cache_bytes(),
            "machine": machine(),
        }
        print(json.dumps(doc))
        return 0
    for c in cases:
        us = c["cpu_us_per_frame"]
        print(
            f"{c['profile']} M = {c['stages']} x {c['cols']}: {c['frames_per_s']:.0f} frames/s "
            f"through the engine, {c['over_line_rate']:.2f}x the line rate "
            f"({c['line_rate_hz']:.0f}/s); one core: {c['one_core_headroom']:.2f}x"
        )
        print(
            f"  CPU per frame: read {us['read']:.1f} us, dispatch {us['dispatch']:.1f} us, "
            f"TDI {us['engine']:.1f} us, record {us['record']:.1f} us, other {us['other']:.1f} "
            f"us; total {c['cpu_us_per_frame_total']:.1f} us ({c['cores_used']:.2f} cores)"
        )
        print(
            f"  lost {c['lost']}, corrupt {c['corrupt']}, overruns {c['overruns']}, dropped by "
            f"the batcher {c['dropped_by_batcher']}; bank {c['bank_frames']} frames "
            f"({c['bank_mb']:.0f} MB)"
        )
    return 0
