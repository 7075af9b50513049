"""``camd bench store``: how much each compression filter saves, and how fast camd writes with it.

Three inputs, made by the simulated camera (hr400) and the TDI engine as a recording and a scan
get them: raw frames of a ``--rows`` x 2048 window (default 534, YE23's window) of the default
scene (a flat field at a quarter of the output range) and of the bar target (``bars``), and the
uint32 sums of a TDI scan of the bar target at M = 96, stored in chunks of 256 lines. Each input
set is at least twice the last-level cache (``camd.bench.common.beyond_cache_bytes``), so that
no filter reads it from a cache the baseline could not use.

Each filter of ``camd.store.compression.FILTERS`` writes each input through camd's own writers
(``FrameRecorder``, ``TdiRecorder``: SWMR, flushes, headroom, as the daemon writes) into a new
file in a RAM-backed directory (/dev/shm where there is one: the disk's speed is not what is
measured), and is measured against "off" (the baseline: the same writer storing the chunks as
they are), A/B alternated in rounds (``camd.bench.common.alternate``). Reported per input and
filter: the ratio (raw bytes over the bytes the chunks take in the file), the write rate in MB
of raw data per CPU-second of this process (one core: the filters run on the writing thread,
and any thread they started would be counted too) and per wall second, the speed against off,
and the one-core rate over hr400's full-window data rate (2048 x 2048 pixels of 2 bytes every
(2048 + 2) line periods: about 200 MB/s), the rate a recorder must keep up with.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import numpy.typing as npt

from camd.bench.common import (
    Alternation,
    add_round_options,
    alternate,
    beyond_cache_bytes,
    choice_list,
    machine,
)
from camd.store.compression import FILTERS, OFF, Compression

PROFILE = "hr400"
DEFAULT_ROWS = 534  # YE23's window (rows 757..1290), the demo's and the issue's stare
STAGES = 96  # M of the TDI sums
CHUNK_LINES = 256  # a scan's chunk of lines (TdiRecorder's default)
INPUTS = ("flat", "bars", "tdi")
SCENES = {"flat": "", "bars": "bars"}  # the default scene (a flat field), the bar target
INPUT_MB_MIN = 64.0  # each input set at least this, and twice the last-level cache
DEFAULT_SECONDS = 1.0
DEFAULT_ROUNDS = 3
DATASETS = {"flat": "frames", "bars": "frames", "tdi": "lines"}  # where each input is stored
Writer = Callable[[Path, Any, Compression], None]


def add_options(p: argparse.ArgumentParser) -> None:
    """The options of ``camd bench store`` but ``--json`` (camd.bench.command adds it)."""
    p.add_argument(
        "--filters",
        type=lambda text: choice_list(text, tuple(FILTERS), "filter"),
        default=tuple(FILTERS),
        metavar="NAMES",
        help=f"filters to measure, comma-separated (default all: {','.join(FILTERS)}); off is "
        "always measured, as the baseline",
    )
    p.add_argument(
        "--inputs",
        type=lambda text: choice_list(text, INPUTS, "input"),
        default=INPUTS,
        metavar="NAMES",
        help="inputs: flat (frames of the default scene), bars (frames of the bar target), "
        "tdi (TDI sums of the bar target, M = 96); default all",
    )
    p.add_argument(
        "--rows", type=int, default=DEFAULT_ROWS, help=f"frame window rows ({DEFAULT_ROWS})"
    )
    p.add_argument(
        "--input-mb",
        type=float,
        default=0.0,
        help=f"size of each input set, MB; 0 = twice the last-level cache, at least "
        f"{INPUT_MB_MIN:g}",
    )
    add_round_options(p)
    p.set_defaults(seconds=DEFAULT_SECONDS, rounds=DEFAULT_ROUNDS)


def full_window_mbyte_s(profile: str = PROFILE) -> float:
    """The camera's data rate at its full window, MB/s (1e6 bytes): every pixel of 2 bytes
    once a frame, a frame every (rows + 2) line periods (one line of exposure,
    docs/physics.md §3)."""
    from camd.sensor.profile import load_profile
    from camd.sensor.regmap import load_register_map
    from camd.sensor.timing_view import reset_timing
    from camd.timing.sequencer import sequencer_frame_period_s

    camera = load_profile(profile)
    rows, cols = int(camera.rows.value), int(camera.columns.value)
    line_s = reset_timing(load_register_map(camera.sensor)).line_period_s
    return 2 * rows * cols / sequencer_frame_period_s(1, rows, line_s) / 1e6


class _Camera:
    """The simulated camera's frames at a window of ``rows`` rows, the scene moving one row a
    frame (the synchronous speed of the window's TDI line period)."""

    def __init__(self, scene: str, rows: int) -> None:
        from camd.bench.sim import _set_window
        from firmware_models.fpga import FpgaModel

        self._fpga = FpgaModel(seed=1, sensor=PROFILE)
        _set_window(self._fpga, rows)
        with self._fpga.lock:
            self._fpga.sensor_link.train()  # as the daemon does: frames pass the link as sent
            if scene:
                self._fpga.camera.set_scene(scene)
        self._period_s = self._fpga.camera.sensor.timing().tdi_line_period_s
        self._next = 0

    def frames(self, count: int) -> npt.NDArray[np.uint16]:
        """The next ``count`` frames."""
        times = 1.0 + (self._next + np.arange(count)) * self._period_s
        self._next += count
        frames, _ = self._fpga.camera.render_block(times)
        return np.asarray(frames, dtype=np.uint16)

    def close(self) -> None:
        self._fpga.close()


def raw_frames(scene: str, rows: int, nbytes: int) -> npt.NDArray[np.uint16]:
    """Frames of ``scene`` at a window of ``rows`` rows, at least ``nbytes`` of them."""
    camera = _Camera(scene, rows)
    try:
        cols = camera.frames(1).shape[2]
        count = max(2, math.ceil(nbytes / (2 * rows * cols)))
        return np.concatenate([camera.frames(min(32, count - k)) for k in range(0, count, 32)])
    finally:
        camera.close()


def tdi_sums(nbytes: int) -> npt.NDArray[np.uint32]:
    """TDI sums of the bar target at M = ``STAGES``, whole chunks of lines, at least
    ``nbytes`` of them: the engine fed the camera's frames as a scan feeds it."""
    from camd.tdi import TdiEngine

    camera = _Camera(SCENES["bars"], STAGES)
    try:
        first = camera.frames(1)
        cols = first.shape[2]
        chunks = max(2, math.ceil(nbytes / (4 * cols * CHUNK_LINES)))
        engine = TdiEngine(STAGES, cols)
        blocks = [engine.push_many(first).data]
        have = len(blocks[0])
        while have < chunks * CHUNK_LINES + STAGES:
            block = engine.push_many(camera.frames(128))
            blocks.append(block.data)
            have += len(block.data)
        # Past the first M - 1 lines, which lack stages (a scan stores them, flagged).
        lines = np.concatenate(blocks)[STAGES : STAGES + chunks * CHUNK_LINES]
        return np.ascontiguousarray(lines, dtype=np.uint32)
    finally:
        camera.close()


def write_frames(path: Path, frames: npt.NDArray[np.uint16], compression: Compression) -> None:
    """``frames`` recorded to ``path`` by a ``FrameRecorder``."""
    from camd.protocol.stream import FrameFlags, FrameHeader, StreamMode
    from camd.store.recording import FrameRecorder

    rows, cols = frames.shape[1:]
    with FrameRecorder(path, frames_expected=len(frames), compression=compression) as rec:
        for i, pixels in enumerate(frames):
            header = FrameHeader(
                counter=i, timestamp_ns=i, line_period_ns=20_520, rows=rows, cols=cols,
                bits=12, mode=StreamMode.AREA, stages=0, stage_position=0,
                flags=FrameFlags(0), payload_bytes=pixels.nbytes, payload_crc32=0,
            )  # fmt: skip
            rec.add(header, pixels, received_ns=i)


def write_lines(path: Path, lines: npt.NDArray[np.uint32], compression: Compression) -> None:
    """``lines`` recorded to ``path`` by a ``TdiRecorder`` in blocks of a chunk, as a scan at
    full speed appends them."""
    from camd.store.tdi_recording import TdiRecorder

    n, width = lines.shape
    ones = np.ones(CHUNK_LINES, bool)
    stages = np.full(CHUNK_LINES, STAGES)
    with TdiRecorder(
        path, width=width, mode="sum", metadata={}, chunk_lines=CHUNK_LINES,
        compression=compression,
    ) as rec:  # fmt: skip
        for start in range(0, n, CHUNK_LINES):
            block = lines[start : start + CHUNK_LINES]
            k = len(block)
            rec.append(
                block, index=np.arange(start, start + k), stages_used=stages[:k],
                complete=ones[:k],
            )  # fmt: skip


def stored_bytes(
    kind: str, write: Writer, data: Any, compression: Compression, folder: Path
) -> int:
    """The bytes ``data``'s chunks take in a file ``write`` makes, read back through camd's
    reader and checked bit-exact (RuntimeError if not)."""
    from camd.store.recording_reading import read_recording
    from camd.store.tdi_reading import read_tdi_scan

    path = folder / f"stored-{compression.filter}.h5"
    write(path, data, compression)
    try:
        with h5py.File(path, "r") as f:
            stored = int(f[DATASETS[kind]].id.get_storage_size())
        back = read_tdi_scan(path).lines if kind == "tdi" else read_recording(path).frames
        if not np.array_equal(back, data):
            raise RuntimeError(f"{compression.describe()} did not read back bit-exact")
    finally:
        path.unlink()
    return stored


def _scratch_dir() -> str | None:
    """A RAM-backed directory for the files (/dev/shm), or None: the system's temporary one."""
    shm = Path("/dev/shm")
    return str(shm) if shm.is_dir() and os.access(shm, os.W_OK) else None


def _pass_rates(
    write: Writer, data: Any, compression: Compression, folder: Path, seconds: float
) -> tuple[float, float]:
    """Whole passes of ``write`` (a new file each, removed after) until ``seconds`` have gone:
    (MB per CPU-second of this process, MB per wall second)."""
    done = 0
    cpu0, t0 = time.process_time(), time.perf_counter()
    while True:
        path = folder / f"bench-{compression.filter}-{done}.h5"
        write(path, data, compression)
        path.unlink()
        done += 1
        wall = time.perf_counter() - t0
        if wall >= seconds:
            mbytes = done * data.nbytes / 1e6
            return mbytes / max(time.process_time() - cpu0, 1e-9), mbytes / wall


def _against_off(
    write: Writer,
    data: Any,
    compression: Compression,
    folder: Path,
    seconds: float,
    rounds: int,
    off_walls: list[float],
) -> tuple[Alternation, list[float]]:
    """``compression`` (B) A/B alternated with off (A): MB per CPU-second of each side's
    rounds, and B's MB per wall second (A's go to ``off_walls``)."""
    off = Compression.of(OFF)
    walls: list[float] = []

    def side(c: Compression, into: list[float]) -> float:
        cpu_rate, wall_rate = _pass_rates(write, data, c, folder, seconds)
        into.append(wall_rate)
        return cpu_rate

    return alternate(lambda: side(off, off_walls), lambda: side(compression, walls), rounds), walls


def measure_input(
    name: str, data: Any, filters: tuple[str, ...], *, seconds: float, rounds: int
) -> dict[str, Any]:
    """Every filter of ``filters`` on one input, each A/B alternated with off (whose own
    figures are the median of every alternation's off side)."""
    write: Writer = write_lines if name == "tdi" else write_frames
    target = full_window_mbyte_s()
    off = Compression.of(OFF)
    measured: dict[str, tuple[Alternation, list[float]]] = {}
    off_walls: list[float] = []
    with tempfile.TemporaryDirectory(prefix="camd-bench-store-", dir=_scratch_dir()) as tmp:
        folder = Path(tmp)
        stored = {f: stored_bytes(name, write, data, Compression.of(f), folder) for f in filters}
        stored.setdefault(OFF, stored_bytes(name, write, data, off, folder))
        for filt in [f for f in filters if f != OFF] or [OFF]:
            measured[filt] = _against_off(
                write, data, Compression.of(filt), folder, seconds, rounds, off_walls
            )
    off_rounds = [x for ab, _ in measured.values() for x in ab.a]
    results: dict[str, Any] = {}
    for filt in filters:
        if filt == OFF:
            cpu_rate, wall_rate, speed, spread = (
                statistics.median(off_rounds), statistics.median(off_walls), 1.0, [1.0, 1.0],
            )  # fmt: skip
        else:
            ab, walls = measured[filt]
            summary = ab.summary(4)
            cpu_rate, wall_rate = statistics.median(ab.b), statistics.median(walls)
            speed, spread = summary["ratio"], summary["ratio_range"]
        results[filt] = {
            "level": Compression.of(filt).level,
            "ratio": round(data.nbytes / stored[filt], 3),
            "stored_bytes": stored[filt],
            "mbyte_s_one_core": round(cpu_rate, 1),
            "mbyte_s_wall": round(wall_rate, 1),
            "speed_over_off": speed,
            "speed_over_off_range": spread,
            "over_camera_rate": round(cpu_rate / target, 2),
        }
    return {
        "input": name,
        "shape": list(data.shape),
        "dtype": str(data.dtype),
        "raw_bytes": int(data.nbytes),
        "off_mbyte_s_one_core": round(statistics.median(off_rounds), 1),
        "filters": results,
    }


def bench_store(
    filters: tuple[str, ...],
    inputs: tuple[str, ...],
    *,
    rows: int,
    input_mb: float,
    seconds: float,
    rounds: int,
) -> dict[str, Any]:
    """The whole benchmark's document (module docstring)."""
    nbytes = int(input_mb * 1e6) if input_mb > 0 else beyond_cache_bytes(int(INPUT_MB_MIN * 1e6))
    cases = []
    for name in inputs:
        data = tdi_sums(nbytes) if name == "tdi" else raw_frames(SCENES[name], rows, nbytes)
        cases.append(measure_input(name, data, filters, seconds=seconds, rounds=rounds))
    return {
        "profile": PROFILE,
        "rows": rows,
        "stages": STAGES,
        "chunk_lines": CHUNK_LINES,
        "camera_full_window_mbyte_s": round(full_window_mbyte_s(), 1),
        "inputs": cases,
        "seconds": seconds,
        "rounds": rounds,
        "machine": machine(),
    }


def run(args: argparse.Namespace) -> int:
    """``camd bench store``: print the table (one JSON document with --json)."""
    if args.rows < 1 or args.rounds < 1 or not args.seconds > 0 or args.input_mb < 0:
        print(
            "camd bench store: --rows and --rounds must be >= 1, --seconds > 0, --input-mb "
            ">= 0 (0: twice the last-level cache)"
        )
        return 2
    doc = bench_store(
        args.filters,
        args.inputs,
        rows=args.rows,
        input_mb=args.input_mb,
        seconds=args.seconds,
        rounds=args.rounds,
    )
    if args.json:
        print(json.dumps(doc))
        return 0
    print(
        f"camd bench store: {doc['profile']} frames of {doc['rows']} x 2048, TDI sums at M = "
        f"{doc['stages']} in chunks of {doc['chunk_lines']} lines; the camera's full window: "
        f"{doc['camera_full_window_mbyte_s']:.0f} MB/s"
    )
    for case in doc["inputs"]:
        print(f"{case['input']}: {case['raw_bytes'] / 1e6:.0f} MB of {case['dtype']}")
        for name, r in case["filters"].items():
            print(
                f"  {name:<16} ratio {r['ratio']:5.2f}   one core {r['mbyte_s_one_core']:7.0f} "
                f"MB/s ({r['over_camera_rate']:.2f}x the camera)   wall "
                f"{r['mbyte_s_wall']:7.0f} MB/s   speed/off {r['speed_over_off']:.2f}"
            )
    return 0
