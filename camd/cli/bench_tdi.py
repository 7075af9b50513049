"""``camd bench tdi``: the TDI engine against ``np.copyto`` of the same bytes and a naive loop.

In one run, on the same frames (uint16, random 12-bit, a frame set far larger than the L3 cache),
for each shape (M stages x N columns) and for integer (``rows_per_line = 1``) and fractional
(``rows_per_line = 1.02``) TDI:

- **engine**: ``TdiEngine.push_many`` over the frame set in blocks of ``--block`` frames, as the
  daemon feeds it;
- **batch**: ``tdi_batch`` on the whole frame set;
- **naive**: a straightforward per-line numpy loop (line k = the sum over i of
  ``frames[k - i, i]``, gathered by fancy indexing), on a window of lines that moves through the
  frame set; on the fractional path it interpolates each stage in float32 with the engine's
  1/256-pixel weights, so its result is close to the engine's but not bit-identical;
- **copy**: ``np.copyto`` of the whole frame set into a preallocated array (the memory-bandwidth
  baseline);
- **push x1**: ``TdiEngine.push`` one frame per call, on a few hundred frames (an extra figure:
  the same work plus one call, and no threads' share of a block, per frame).

Every figure is Gpix/s of *input* (frames x rows x N per second, the same definition for all).
The methods alternate in rounds, each method running whole passes until it has spent
``seconds / rounds`` in the round, so that a slow spell of this shared machine hits all of them;
the median of the rounds is reported and the ratios are ratios of medians.

Before anything is timed the engine's output (``push_many`` in blocks, and ``push`` on the first
frames) is compared with ``tdi_batch``: a fast but wrong engine fails the bench (exit status 1).
"""

from __future__ import annotations

import argparse
import importlib
import importlib.metadata
import json
import math
import os
import platform
import statistics
import sys
import time
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any, Literal

import numpy as np
import numpy.typing as npt

if TYPE_CHECKING:
    from camd.tdi import TdiEngine

Frames = npt.NDArray[np.uint16]
KernelName = Literal["auto", "numba", "numpy"]

SHAPES: tuple[tuple[int, int], ...] = ((96, 2048), (32, 4096))
"""(stages M, width N) measured by default: the issue's two shapes."""

FRACTIONAL_ROWS_PER_LINE = 1.02
"""The fractional path's ``rows_per_line``: a 2 % velocity mismatch."""

TARGETS = {
    "integer_engine_over_copy": 1.0,
    "fractional_engine_over_copy": 0.5,
    "integer_floor": 0.7,
}
"""The issue's targets for engine / copy (below ``integer_floor`` the issue is not done)."""

METHODS = ("copy", "engine", "batch", "naive", "push")
"""The order of the methods within a round."""

PUSH_FRAMES = 256
"""Frames per pass of the push-one-frame-per-call figure."""

ROUNDS = 9
"""Rounds of the alternation: short turns (``seconds / ROUNDS`` each) so that a slow spell of a
shared machine is spread over all the methods; an odd count, so the median is one of them."""

NAIVE_LINES = 32
"""Output lines per pass of the naive loop."""

DEFAULT_FRAMES_MB = 320.0


class TdiMismatch(RuntimeError):
    """The engine's output differs from ``tdi_batch``'s on the same frames."""


def add_parser(which: Any) -> None:
    """Register ``camd bench tdi`` on the ``camd bench`` subparsers."""
    tdi = which.add_parser(
        "tdi",
        help="TDI engine vs np.copyto of the same bytes and a naive numpy loop",
        description="The streaming TDI engine, tdi_batch and a naive per-line numpy loop against "
        "np.copyto of the same input bytes, in Gpix/s of input, for integer and fractional "
        "rows_per_line.",
    )
    tdi.add_argument(
        "--seconds",
        type=float,
        default=1.0,
        help="measured time per method, shape and path (default 1.0)",
    )
    tdi.add_argument(
        "--block", type=int, default=256, help="frames per push_many call (default 256)"
    )
    tdi.add_argument(
        "--frames-mb",
        type=float,
        default=DEFAULT_FRAMES_MB,
        help=f"size of each frame set in MB (default {DEFAULT_FRAMES_MB:g}; L3 is far smaller)",
    )
    tdi.add_argument(
        "--kernel",
        choices=("auto", "numba", "numpy"),
        default="auto",
        help="the engine's kernel (default auto: numba when it imports)",
    )
    tdi.add_argument(
        "--shapes",
        type=_parse_shapes,
        default=SHAPES,
        metavar="MxN[,MxN...]",
        help="stages x width to measure (default 96x2048,32x4096)",
    )
    tdi.add_argument("--json", action="store_true", help="print one JSON document")


def _parse_shapes(text: str) -> tuple[tuple[int, int], ...]:
    shapes = []
    for item in text.split(","):
        m, sep, n = item.strip().lower().partition("x")
        if not sep or not m.isdigit() or not n.isdigit() or int(m) < 1 or int(n) < 1:
            raise argparse.ArgumentTypeError(f"{item!r} is not MxN, e.g. 96x2048")
        shapes.append((int(m), int(n)))
    return tuple(shapes)


def run(args: argparse.Namespace) -> int:
    """``camd bench tdi``: exit status 0, 1 if the engine disagrees with tdi_batch, 2 on usage."""
    if not args.seconds > 0 or args.block < 1 or not args.frames_mb > 0:
        print(
            "camd bench tdi: --seconds and --frames-mb must be > 0, --block >= 1", file=sys.stderr
        )
        return 2
    progress = None if args.json else _progress
    try:
        result = bench_tdi(
            shapes=args.shapes,
            seconds=args.seconds,
            block=args.block,
            frames_mb=args.frames_mb,
            kernel=args.kernel,
            progress=progress,
        )
    except TdiMismatch as exc:
        print(f"camd bench tdi: error: {exc}", file=sys.stderr)
        return 1
    if args.json:
        print(json.dumps(result))
    else:
        _print_human(result)
    return 0


def _progress(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


# -- the methods --------------------------------------------------------------------------------


def make_frames(count: int, rows: int, width: int, seed: int = 0) -> Frames:
    """(count, rows, width) uint16 random 12-bit frames, contiguous."""
    rng = np.random.default_rng(seed)
    return rng.integers(0, 4096, size=(count, rows, width), dtype=np.uint16)


def naive_integer(frames: Frames, first: int, count: int, stages: int) -> npt.NDArray[np.uint32]:
    """Lines ``first .. first + count - 1`` (each >= stages - 1) the straightforward way."""
    idx = np.arange(stages)
    out = np.empty((count, frames.shape[2]), dtype=np.uint32)
    for j in range(count):
        k = first + j
        out[j] = frames[k - idx, idx].sum(axis=0, dtype=np.uint32)
    return out


def naive_weights(
    stages: int, rows_per_line: float, rows: int
) -> tuple[npt.NDArray[np.intp], npt.NDArray[np.intp], npt.NDArray[np.float32]]:
    """Per stage: the row, the next row and its weight, in 1/256 pixel as docs/tdi.md rounds it."""
    from camd.tdi import FIXED_POINT_ONE as one

    r0 = np.empty(stages, dtype=np.intp)
    w = np.empty(stages, dtype=np.float32)
    for i in range(stages):
        y = i * rows_per_line
        whole = math.floor(y)
        weight = math.floor((y - whole) * one + 0.5)
        if weight == one:
            whole, weight = whole + 1, 0
        r0[i], w[i] = whole, weight / one
    return r0, np.minimum(r0 + 1, rows - 1), w


def naive_fractional(
    frames: Frames,
    first: int,
    count: int,
    taps: tuple[npt.NDArray[np.intp], npt.NDArray[np.intp], npt.NDArray[np.float32]],
) -> npt.NDArray[np.uint32]:
    """Lines the straightforward way with linear interpolation in float32 (not bit-identical)."""
    r0, r1, w = taps
    idx = np.arange(len(r0))
    w1 = w[:, None]
    w0 = np.float32(1) - w1
    out = np.empty((count, frames.shape[2]), dtype=np.uint32)
    for j in range(count):
        k = first + j
        line = (w0 * frames[k - idx, r0] + w1 * frames[k - idx, r1]).sum(axis=0)
        out[j] = np.rint(line)
    return out


def _blocks(
    engine: TdiEngine, frames: Frames, block: int
) -> tuple[npt.NDArray[Any], npt.NDArray[np.bool_]]:
    """Feed ``frames`` to ``engine`` in blocks; the blocks' outputs, concatenated."""
    datas, completes = [], []
    for s in range(0, len(frames), block):
        out = engine.push_many(frames[s : s + block])
        datas.append(out.data)
        completes.append(out.complete)
    return np.concatenate(datas), np.concatenate(completes)


def verify_engine(
    engine: TdiEngine, push_engine: TdiEngine, frames: Frames, block: int, label: str, **batch: Any
) -> npt.NDArray[Any]:
    """Compare ``engine`` (push_many in blocks) and ``push_engine`` (push, on the first frames)
    with ``tdi_batch(frames, **batch)``; raise TdiMismatch on any difference. Both engines must
    be fresh (or reset). Returns tdi_batch's lines."""
    from camd.tdi import tdi_batch

    ref, ref_complete = tdi_batch(frames, **batch)
    data, complete = _blocks(engine, frames, block)
    problems = []
    if data.dtype != ref.dtype or data.shape != ref.shape:
        problems.append(
            f"push_many gives {data.dtype}{data.shape}, tdi_batch {ref.dtype}{ref.shape}"
        )
    elif not np.array_equal(data, ref):
        bad = np.flatnonzero((data != ref).any(axis=1))
        problems.append(
            f"push_many (blocks of {block}) differs from tdi_batch in {len(bad)} of {len(ref)} "
            f"lines, the first at line {int(bad[0])}"
        )
    if not np.array_equal(complete, ref_complete):
        problems.append("push_many's complete flags differ from tdi_batch's")
    for k in range(min(len(frames), PUSH_FRAMES)):
        line = push_engine.push(frames[k])
        if not np.array_equal(line.data, ref[k]) or line.complete != bool(ref_complete[k]):
            problems.append(f"push() differs from tdi_batch at line {k}")
            break
    if problems:
        raise TdiMismatch(f"{label}: " + "; ".join(problems) + " (a wrong engine is not timed)")
    return np.asarray(ref)


# -- the measurement ------------------------------------------------------------------------------


def _measure(
    passes: dict[str, Callable[[], int]], seconds: float, rounds: int
) -> dict[str, list[float]]:
    """Run the methods in turn, ``rounds`` times, each for whole passes until it has spent
    ``seconds / rounds`` in the round; per method the Gpix/s of each round."""
    quantum = seconds / rounds
    gpix: dict[str, list[float]] = {name: [] for name in passes}
    for _ in range(rounds):
        for name, one_pass in passes.items():
            pixels = 0
            t0 = time.perf_counter()
            while True:
                pixels += one_pass()
                elapsed = time.perf_counter() - t0
                if elapsed >= quantum:
                    break
            gpix[name].append(pixels / elapsed / 1e9)
    return gpix


def bench_path(
    *,
    stages: int,
    width: int,
    frame_count: int,
    rows_per_line: float,
    seconds: float,
    block: int,
    kernel: KernelName,
    rounds: int = ROUNDS,
    make_engine: Callable[..., TdiEngine] | None = None,
    progress: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """One shape, one path: verify the engine, then time the five methods on the same frames.

    ``make_engine(stages, width, rows_per_line=..., kernel=...)`` builds the engines (default
    ``TdiEngine``), so that a caller can check that a wrong engine is caught.
    """
    from camd.tdi import TdiEngine, tdi_batch

    build: Callable[..., TdiEngine] = TdiEngine if make_engine is None else make_engine
    integer = float(rows_per_line).is_integer()
    engine = build(stages, width, rows_per_line=rows_per_line, kernel=kernel)
    push_engine = build(stages, width, rows_per_line=rows_per_line, kernel=kernel)
    rows = int(engine.rows_needed)
    label = f"{stages} x {width}, rows_per_line {rows_per_line:g}, kernel {engine.kernel}"
    if progress:
        progress(f"  {label}: {frame_count} frames of {rows} x {width}")
    frames = make_frames(frame_count, rows, width)
    frame_pixels = rows * width
    batch_kw: dict[str, Any] = {"stages": stages, "rows_per_line": rows_per_line, "kernel": kernel}

    # Warm-up, untimed: compiles the kernels, faults in every page, checks the bits.
    ref = verify_engine(engine, push_engine, frames, block, label, **batch_kw)
    dst = np.empty_like(frames)
    np.copyto(dst, frames)
    lines = frame_count - stages + 1  # lines whose every stage has a frame
    naive_lines = min(NAIVE_LINES, lines)
    taps = naive_weights(stages, rows_per_line, rows)

    def naive(first: int, count: int) -> npt.NDArray[np.uint32]:
        if integer:
            return naive_integer(frames, first, count, stages)
        return naive_fractional(frames, first, count, taps)

    check = (
        naive(stages - 1, naive_lines).astype(np.int64) - ref[stages - 1 : stages - 1 + naive_lines]
    )
    naive_max_diff = int(np.abs(check).max())
    if integer and naive_max_diff:
        raise RuntimeError(f"{label}: the naive loop disagrees with tdi_batch (a bench bug)")

    cursor = {"naive": 0, "push": 0}

    def copy_pass() -> int:
        np.copyto(dst, frames)
        return frame_count * frame_pixels

    def engine_pass() -> int:
        engine.reset()
        for s in range(0, frame_count, block):
            engine.push_many(frames[s : s + block])
        return frame_count * frame_pixels

    def batch_pass() -> int:
        tdi_batch(frames, **batch_kw)
        return frame_count * frame_pixels

    def naive_pass() -> int:
        start = cursor["naive"]
        cursor["naive"] = (start + naive_lines) % (lines - naive_lines + 1)
        naive(stages - 1 + start, naive_lines)
        return naive_lines * frame_pixels

    push_frames = min(PUSH_FRAMES, frame_count)

    def push_pass() -> int:
        start = cursor["push"]
        cursor["push"] = (start + push_frames) % (frame_count - push_frames + 1)
        for frame in frames[start : start + push_frames]:
            push_engine.push(frame)
        return push_frames * frame_pixels

    passes = {
        "copy": copy_pass,
        "engine": engine_pass,
        "batch": batch_pass,
        "naive": naive_pass,
        "push": push_pass,
    }
    gpix = _measure(passes, seconds, rounds)
    med = {name: statistics.median(values) for name, values in gpix.items()}
    return {
        "rows_per_line": rows_per_line,
        "rows": rows,
        "frames": frame_count,
        "frame_set_mb": frames.nbytes / 1e6,
        "engine_gpix_s": med["engine"],
        "batch_gpix_s": med["batch"],
        "naive_gpix_s": med["naive"],
        "copy_gpix_s": med["copy"],
        "push_gpix_s": med["push"],
        "engine_over_copy": med["engine"] / med["copy"],
        "engine_over_naive": med["engine"] / med["naive"],
        "batch_over_copy": med["batch"] / med["copy"],
        "rounds_gpix_s": {name: [round(v, 3) for v in values] for name, values in gpix.items()},
        "naive_lines_per_pass": naive_lines,
        "naive_max_abs_diff_dn": naive_max_diff,
        "push_frames_per_pass": push_frames,
        "state_bytes": int(getattr(engine, "state_bytes", 0)),
    }


def frame_count_for(stages: int, width: int, frames_mb: float) -> int:
    """Frames in a set of about ``frames_mb`` MB of the largest (fractional) frames; at least
    2 M so that lines with every stage exist."""
    from camd.tdi.taps import stage_taps

    rows = stage_taps(stages, width, rows_per_line=FRACTIONAL_ROWS_PER_LINE).rows_needed
    return max(2 * stages, int(frames_mb * 1e6 // (rows * width * 2)))


def bench_tdi(
    *,
    shapes: Sequence[tuple[int, int]] = SHAPES,
    seconds: float = 1.0,
    block: int = 256,
    frames_mb: float = DEFAULT_FRAMES_MB,
    kernel: KernelName = "auto",
    rounds: int = ROUNDS,
    make_engine: Callable[..., TdiEngine] | None = None,
    progress: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """The whole bench: for every shape the integer and the fractional path; one document."""
    resolved, threads = _engine_setup(kernel)
    load_before = os.getloadavg()[0]
    doc_shapes = []
    for stages, width in shapes:
        count = frame_count_for(stages, width, frames_mb)
        entry: dict[str, Any] = {"stages": stages, "width": width}
        for name, rpl in (("integer", 1.0), ("fractional", FRACTIONAL_ROWS_PER_LINE)):
            entry[name] = bench_path(
                stages=stages,
                width=width,
                frame_count=count,
                rows_per_line=rpl,
                seconds=seconds,
                block=block,
                kernel=kernel,
                rounds=rounds,
                make_engine=make_engine,
                progress=progress,
            )
        entry["rows"] = entry["integer"]["rows"]
        entry["frames"] = count
        doc_shapes.append(entry)
    met = {
        "integer_engine_over_copy": all(
            s["integer"]["engine_over_copy"] >= TARGETS["integer_engine_over_copy"]
            for s in doc_shapes
        ),
        "fractional_engine_over_copy": all(
            s["fractional"]["engine_over_copy"] >= TARGETS["fractional_engine_over_copy"]
            for s in doc_shapes
        ),
        "integer_floor": all(
            s["integer"]["engine_over_copy"] >= TARGETS["integer_floor"] for s in doc_shapes
        ),
    }
    return {
        "shapes": doc_shapes,
        "targets": dict(TARGETS),
        "met": met,
        "kernel": resolved,
        "threads": threads,
        "numba": _numba_version(),
        "numpy": np.__version__,
        "cpu": _cpu(),
        "cpus": os.cpu_count(),
        # The 1-minute load average before and after: other work on a shared machine slows the
        # engine's threads more than the one-thread copy.
        "loadavg": [round(load_before, 2), round(os.getloadavg()[0], 2)],
        "seconds": seconds,
        "rounds": rounds,
        "block": block,
        "frames_mb": frames_mb,
    }


# -- the machine ----------------------------------------------------------------------------------


def _numba_version() -> str | None:
    try:
        return importlib.metadata.version("numba")
    except importlib.metadata.PackageNotFoundError:
        return None


def _engine_setup(kernel: KernelName) -> tuple[str, int]:
    """The kernel ``kernel`` resolves to (``auto``: numba when it imports) and the engine's
    thread count."""
    from camd.tdi import TdiEngine

    probe = TdiEngine(1, 1, kernel=kernel)
    return str(probe.kernel), int(probe.threads)


def _cpu() -> str:
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


# -- human output ---------------------------------------------------------------------------------


def _print_human(result: dict[str, Any]) -> None:
    from rich import box
    from rich.console import Console
    from rich.table import Table

    out = Console(highlight=False, soft_wrap=False, width=max(120, Console().width))
    table = Table(
        title=f"TDI, Gpix/s of input (kernel {result['kernel']}, {result['threads']} thread(s); "
        f"medians of {result['rounds']} rounds, {result['seconds']:g} s per method)",
        box=box.SIMPLE_HEAVY,
        show_edge=False,
        title_justify="left",
    )
    table.add_column("M x N")
    table.add_column("rows/line", justify="right")
    table.add_column("frames", justify="right")
    for name in (
        "copy",
        "engine",
        "batch",
        "naive",
        "push x1",
        "eng/copy",
        "eng/naive",
        "batch/copy",
    ):
        table.add_column(name, justify="right")
    for s in result["shapes"]:
        for path in ("integer", "fractional"):
            r = s[path]
            table.add_row(
                f"{s['stages']} x {s['width']}",
                f"{r['rows_per_line']:g}",
                f"{r['frames']} x {r['rows']}",
                *(f"{r[k + '_gpix_s']:.2f}" for k in ("copy", "engine", "batch", "naive", "push")),
                f"{r['engine_over_copy']:.2f}",
                f"{r['engine_over_naive']:.1f}",
                f"{r['batch_over_copy']:.2f}",
            )
    out.print(table)
    out.print(
        f"engine: push_many in blocks of {result['block']} frames; batch: tdi_batch on the whole "
        f"set; push x1: push() one frame per call, {PUSH_FRAMES} frames a pass (an extra "
        "figure); naive: a per-line numpy loop (fractional: float32 interpolation, not "
        "bit-identical); copy: np.copyto of the same input bytes (one thread). Every engine "
        "output was checked against tdi_batch, bit for bit, before timing. Load average "
        f"before / after: {result['loadavg'][0]:g} / {result['loadavg'][1]:g}."
    )
    t = result["targets"]
    for key, path, target in (
        ("integer_engine_over_copy", "integer", t["integer_engine_over_copy"]),
        ("fractional_engine_over_copy", "fractional", t["fractional_engine_over_copy"]),
        ("integer_floor", "integer", t["integer_floor"]),
    ):
        got = ", ".join(
            f"{s['stages']}x{s['width']} {s[path]['engine_over_copy']:.2f}"
            for s in result["shapes"]
        )
        verdict = "met" if result["met"][key] else "NOT met"
        what = "floor (below it the issue is not done)" if key == "integer_floor" else "target"
        out.print(f"{path} engine/copy >= {target:g} {what}: {verdict} ({got})")
