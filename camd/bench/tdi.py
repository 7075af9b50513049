"""``camd bench tdi``: the TDI engine against ``np.copyto`` of the same bytes, on one thread each.

For each shape (M stages x N columns) and each path:

- **integer**: ``rows_per_line = 1`` (the synchronous scan), ``TdiEngine.push_many`` in blocks
  of the daemon's own batch size (``camd.pipeline.batcher.batch_frames_for``);
- **fractional**: ``rows_per_line = 1.02`` (a 2 % velocity mismatch: every stage interpolated
  between two rows), ``push_many`` likewise;
- **drift**: ``cols_per_line = 0.02`` (a drift angle of 1.15 degrees: every stage interpolated
  between two columns), ``push_many`` likewise;
- **push**: ``rows_per_line = 1``, ``TdiEngine.push`` one frame per call (a live stream that
  hands over frames one at a time).

The baseline is ``np.copyto`` of the same frame set into a preallocated array, on one thread as
the engine is: the memory-bandwidth floor of touching the same input bytes. The frame set of each path is larger than the machine's last-level cache
(twice it, read from sysfs, and at least 256 MB), so neither side runs from cache. Baseline and
engine alternate (A B, B A, ...) in ``--rounds`` rounds of ``--seconds`` each, whole passes; the
figure is Gpix/s of *input* (frames x rows x N per second), and the ratio is the median of the
rounds' own engine/copy ratios.

Before anything is timed the engine's output (``push_many`` in blocks, and ``push`` on the first
frames) is compared with ``tdi_batch``: a fast but wrong engine fails the bench (exit status 1).
"""

from __future__ import annotations

import argparse
import importlib.metadata
import json
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Literal

import numpy as np
import numpy.typing as npt

from camd.bench.common import (
    DEFAULT_ROUNDS,
    MIN_ROUND_S,
    add_round_options,
    alternate,
    beyond_cache_bytes,
    choice_list,
    machine,
    rate_over,
)

if TYPE_CHECKING:
    from camd.tdi import TdiEngine

Frames = npt.NDArray[np.uint16]
KernelName = Literal["auto", "numba", "numpy"]

SHAPES: tuple[tuple[int, int], ...] = ((96, 2048), (32, 4096))
"""(stages M, width N) measured by default."""


@dataclass(frozen=True)
class PathSpec:
    """One way of running the engine: its geometry and whether it is fed one frame a call."""

    rows_per_line: float = 1.0
    cols_per_line: float = 0.0
    one_frame_per_call: bool = False


PATHS: dict[str, PathSpec] = {
    "integer": PathSpec(),
    "fractional": PathSpec(rows_per_line=1.02),
    "drift": PathSpec(cols_per_line=0.02),
    "push": PathSpec(one_frame_per_call=True),
}
"""The paths measured, in order."""

TARGETS = {"integer": 1.3, "fractional": 0.8, "drift": 0.7, "push": 0.9}
"""Goals for engine / copy of the same bytes on the same (one) thread: integer TDI reads each
pixel once and writes 1/M of it, so it can beat a copy, which reads and writes every pixel."""

MIN_FRAME_SET_BYTES = 256 << 20
"""The smallest frame set, whatever the cache: 256 MiB."""

PUSH_FRAMES = 256
"""Frames per pass of the push path (the pass moves on through the frame set)."""


class TdiMismatch(RuntimeError):
    """The engine's output differs from ``tdi_batch``'s on the same frames."""


def add_options(p: argparse.ArgumentParser) -> None:
    """The options of ``camd bench tdi`` but ``--json`` (camd.bench.command adds it)."""
    add_round_options(p)
    p.add_argument(
        "--block",
        type=int,
        default=0,
        help="frames per push_many call (default 0: the daemon's batch for the frame size)",
    )
    p.add_argument(
        "--frames-mb",
        type=float,
        default=0.0,
        help="size of each frame set in MB (default 0: twice the last-level cache, at least "
        "256 MiB)",
    )
    p.add_argument(
        "--kernel",
        choices=("auto", "numba", "numpy"),
        default="auto",
        help="the engine's kernel (default auto: numba when it imports)",
    )
    p.add_argument(
        "--shapes",
        type=_parse_shapes,
        default=SHAPES,
        metavar="MxN[,MxN...]",
        help="stages x width to measure (default 96x2048,32x4096)",
    )
    p.add_argument(
        "--paths",
        type=_parse_paths,
        default=tuple(PATHS),
        metavar="P[,P...]",
        help="paths to measure (default integer,fractional,drift,push)",
    )


def _parse_shapes(text: str) -> tuple[tuple[int, int], ...]:
    shapes = []
    for item in text.split(","):
        m, sep, n = item.strip().lower().partition("x")
        if not sep or not m.isdigit() or not n.isdigit() or int(m) < 1 or int(n) < 1:
            raise argparse.ArgumentTypeError(f"{item!r} is not MxN, e.g. 96x2048")
        shapes.append((int(m), int(n)))
    return tuple(shapes)


def _parse_paths(text: str) -> tuple[str, ...]:
    return choice_list(text, tuple(PATHS), "path")


def run(args: argparse.Namespace) -> int:
    """``camd bench tdi``: exit status 0, 1 if the engine disagrees with tdi_batch, 2 on usage."""
    if not args.seconds > 0 or args.rounds < 1 or args.block < 0 or args.frames_mb < 0:
        print(
            "camd bench tdi: --seconds must be > 0, --rounds >= 1, --block and "
            "--frames-mb >= 0 (0: the default)",
            file=sys.stderr,
        )
        return 2
    progress = None if args.json else _progress
    try:
        result = bench_tdi(
            shapes=args.shapes,
            paths=args.paths,
            seconds=args.seconds,
            rounds=args.rounds,
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


# -- the frames and the check -------------------------------------------------------------------


def make_frames(count: int, rows: int, width: int, seed: int = 0) -> Frames:
    """(count, rows, width) uint16 random 12-bit frames, contiguous."""
    rng = np.random.default_rng(seed)
    return rng.integers(0, 4096, size=(count, rows, width), dtype=np.uint16)


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
) -> None:
    """Compare ``engine`` (push_many in blocks) and ``push_engine`` (push, on the first frames)
    with ``tdi_batch(frames, **batch)``; raise TdiMismatch on any difference. Both engines must
    be fresh (or reset)."""
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


# -- the measurement ------------------------------------------------------------------------------


def bench_path(
    *,
    stages: int,
    width: int,
    path: str,
    frames: Frames,
    seconds: float,
    rounds: int,
    block: int,
    kernel: KernelName,
    make_engine: Callable[..., TdiEngine] | None = None,
) -> dict[str, Any]:
    """One shape, one path: verify the engine on ``frames``, then copy (A) and engine (B)
    alternated. ``make_engine(stages, width, **geometry)`` builds the engines (default
    ``TdiEngine``), so that a caller can check that a wrong engine is caught."""
    from camd.tdi import TdiEngine

    spec = PATHS[path]
    geometry: dict[str, Any] = {
        "rows_per_line": spec.rows_per_line,
        "cols_per_line": spec.cols_per_line,
        "kernel": kernel,
    }
    build: Callable[..., TdiEngine] = TdiEngine if make_engine is None else make_engine
    engine = build(stages, width, **geometry)
    push_engine = build(stages, width, **geometry)
    count, rows = int(frames.shape[0]), int(frames.shape[1])
    label = f"{stages} x {width} {path} (kernel {engine.kernel})"
    # Untimed: compiles the kernels, faults in every page, checks the bits.
    verify_engine(engine, push_engine, frames, block, label, stages=stages, **geometry)
    dst = np.empty_like(frames)
    np.copyto(dst, frames)
    frame_pixels = rows * width
    cursor = [0]

    def copy_pass() -> float:
        np.copyto(dst, frames)
        return float(count * frame_pixels)

    def engine_pass() -> float:
        engine.reset()
        for s in range(0, count, block):
            engine.push_many(frames[s : s + block])
        return float(count * frame_pixels)

    push_frames = min(PUSH_FRAMES, count)

    def push_pass() -> float:
        start = cursor[0]
        cursor[0] = (start + push_frames) % (count - push_frames + 1)
        for frame in frames[start : start + push_frames]:
            push_engine.push(frame)
        return float(push_frames * frame_pixels)

    subject = push_pass if spec.one_frame_per_call else engine_pass
    rounds_ab = alternate(
        lambda: rate_over(copy_pass, seconds) / 1e9,
        lambda: rate_over(subject, seconds) / 1e9,
        rounds,
    )
    summary = rounds_ab.summary()
    target = TARGETS[path]
    return {
        "rows_per_line": spec.rows_per_line,
        "cols_per_line": spec.cols_per_line,
        "subject": "push" if spec.one_frame_per_call else "push_many",
        "rows": rows,
        "frames": count,
        "frame_set_mb": round(frames.nbytes / 1e6, 1),
        "block": 1 if spec.one_frame_per_call else block,
        "copy_gpix_s": summary["a"],
        "engine_gpix_s": summary["b"],
        "over_copy": summary["ratio"],
        "over_copy_range": summary["ratio_range"],
        "rounds_copy_gpix_s": summary["rounds_a"],
        "rounds_engine_gpix_s": summary["rounds_b"],
        "target": target,
        "met": summary["ratio"] >= target,
    }


def frame_set_bytes(frames_mb: float) -> int:
    """The size of each frame set: ``frames_mb`` MB if given, else beyond the cache."""
    if frames_mb > 0:
        return int(frames_mb * 1e6)
    return beyond_cache_bytes(MIN_FRAME_SET_BYTES)


def bench_tdi(
    *,
    shapes: Sequence[tuple[int, int]] = SHAPES,
    paths: Sequence[str] = tuple(PATHS),
    seconds: float = MIN_ROUND_S,
    rounds: int = DEFAULT_ROUNDS,
    block: int = 0,
    frames_mb: float = 0.0,
    kernel: KernelName = "auto",
    make_engine: Callable[..., TdiEngine] | None = None,
    progress: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """The whole bench: every path of every shape; one document."""
    from camd.pipeline.batcher import batch_frames_for
    from camd.tdi import TdiEngine

    set_bytes = frame_set_bytes(frames_mb)
    resolved = TdiEngine(1, 1, kernel=kernel).kernel
    before = machine()
    doc_shapes = []
    t0 = time.perf_counter()
    for stages, width in shapes:
        entry: dict[str, Any] = {"stages": stages, "width": width, "paths": {}}
        cache: dict[int, Frames] = {}
        for path in paths:
            spec = PATHS[path]
            rows = TdiEngine(
                stages,
                width,
                rows_per_line=spec.rows_per_line,
                cols_per_line=spec.cols_per_line,
                kernel="numpy",
            ).rows_needed
            count = max(2 * stages, PUSH_FRAMES, set_bytes // (rows * width * 2))
            if rows not in cache:
                cache.clear()  # one frame set in memory at a time (with its copy)
                cache[rows] = make_frames(count, rows, width)
            path_block = block or batch_frames_for(rows, width)
            if progress:
                progress(
                    f"  {stages} x {width} {path}: {count} frames of {rows} x {width} "
                    f"({cache[rows].nbytes / 1e6:.0f} MB), blocks of {path_block}"
                )
            entry["paths"][path] = bench_path(
                stages=stages,
                width=width,
                path=path,
                frames=cache[rows],
                seconds=seconds,
                rounds=rounds,
                block=path_block,
                kernel=kernel,
                make_engine=make_engine,
            )
        doc_shapes.append(entry)
    met = {
        path: all(s["paths"][path]["met"] for s in doc_shapes if path in s["paths"])
        for path in paths
    }
    return {
        "shapes": doc_shapes,
        "targets": {p: TARGETS[p] for p in paths},
        "met": met,
        "kernel": resolved,
        "numba": _numba_version(),
        "numpy": np.__version__,
        "machine": before,
        # The load average after, too: other work on a shared machine shows in the rounds.
        "loadavg_after": machine()["loadavg"],
        "seconds": seconds,
        "rounds": rounds,
        "frame_set_bytes": set_bytes,
        "wall_s": round(time.perf_counter() - t0, 1),
    }


def _numba_version() -> str | None:
    try:
        return importlib.metadata.version("numba")
    except importlib.metadata.PackageNotFoundError:
        return None


# -- human output ---------------------------------------------------------------------------------


def _print_human(result: dict[str, Any]) -> None:
    from rich import box
    from rich.console import Console
    from rich.table import Table

    out = Console(highlight=False, soft_wrap=False, width=max(120, Console().width))
    table = Table(
        title=f"TDI engine vs np.copyto of the same bytes, Gpix/s of input (kernel "
        f"{result['kernel']}, one thread each; {result['rounds']} rounds of "
        f"{result['seconds']:g} s a side, A/B alternated)",
        box=box.SIMPLE_HEAVY,
        show_edge=False,
        title_justify="left",
    )
    for name, justify in (
        ("M x N", "left"),
        ("path", "left"),
        ("frames x rows", "right"),
        ("block", "right"),
        ("copy", "right"),
        ("engine", "right"),
        ("engine/copy", "right"),
        ("range", "right"),
        ("goal", "right"),
        ("", "left"),
    ):
        table.add_column(name, justify=justify)  # type: ignore[arg-type]
    for s in result["shapes"]:
        for path, r in s["paths"].items():
            low, high = r["over_copy_range"]
            table.add_row(
                f"{s['stages']} x {s['width']}",
                path,
                f"{r['frames']} x {r['rows']}",
                str(r["block"]),
                f"{r['copy_gpix_s']:.2f}",
                f"{r['engine_gpix_s']:.2f}",
                f"{r['over_copy']:.2f}",
                f"{low:.2f}-{high:.2f}",
                f">= {r['target']:g}",
                "met" if r["met"] else "NOT met",
            )
    out.print(table)
    m = result["machine"]
    cache = m["last_level_cache_bytes"]
    out.print(
        f"integer: rows_per_line 1; fractional: 1.02; drift: cols_per_line 0.02; push: push() "
        f"one frame per call. Frame sets of {result['frame_set_bytes'] / 1e6:.0f} MB (last-level "
        f"cache {cache / 2**20:.0f} MiB); every engine output was checked against tdi_batch, "
        f"bit for bit, before timing. {m['cpu']}, {m['cpus']} cpus, load average "
        f"{m['loadavg'][0]:g} before, {result['loadavg_after'][0]:g} after."
        if cache
        else f"Frame sets of {result['frame_set_bytes'] / 1e6:.0f} MB (cache size unknown)."
    )
