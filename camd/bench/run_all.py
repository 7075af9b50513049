"""``camd bench all``: every benchmark, one after the other, and one document of their ratios.

Each benchmark runs in its own process (``python -m camd bench NAME --json``), so that one's
memory, threads and compiled kernels do not weigh on the next, and a failing one does not end
the others. The document gathers, under ``ratios``, each benchmark's headline figures against
its own baseline (bench/README.md says which baseline and why), under ``checks`` the counts
that must be zero (lost frames, server errors), and under ``benches`` every benchmark's whole
document, exit status and time.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any

from camd.bench.common import choice_list, machine

Doc = dict[str, Any]


def _ping(doc: Doc) -> tuple[Doc, Doc]:
    return {
        "ping camd/echo p50 (lower is better)": doc["ratio_p50"],
        "ping camd/echo p99 (lower is better)": doc["ratio_p99"],
    }, {"ping failed": doc["failed"]}


def _stream(doc: Doc) -> tuple[Doc, Doc]:
    return {"stream ingest/bare reads": doc["ratio"]}, {
        "stream lost": doc["lost"],
        "stream overruns": doc["overruns"],
    }


def _tdi(doc: Doc) -> tuple[Doc, Doc]:
    ratios = {
        f"tdi {s['stages']}x{s['width']} {path} engine/copy": r["over_copy"]
        for s in doc["shapes"]
        for path, r in s["paths"].items()
    }
    return ratios, {}


def _sim(doc: Doc) -> tuple[Doc, Doc]:
    return {
        f"sim {c['profile']} M={c['stages']} {c['kind']} frames/line rate": c["over_line_rate"]
        for c in doc["cases"]
    }, {}


def _pipeline(doc: Doc) -> tuple[Doc, Doc]:
    ratios: Doc = {}
    checks: Doc = {}
    for c in doc["cases"]:
        key = f"pipeline {c['profile']} M={c['stages']}"
        ratios[f"{key} frames/line rate"] = c["over_line_rate"]
        ratios[f"{key} one-core headroom"] = c["one_core_headroom"]
        checks[f"{key} lost"] = c["lost"]
    return ratios, checks


def _scan(doc: Doc) -> tuple[Doc, Doc]:
    key = f"scan {doc['profile']} M={doc['stages']}"
    return {
        f"{key} lines/line rate": doc["lines_per_s_over_line_rate"],
        f"{key} stream/line rate": doc["stream_rate_over_line_rate"],
    }, {f"{key} lost frames": doc["lost_frames"], f"{key} overruns": doc["overruns"]}


def _live(doc: Doc) -> tuple[Doc, Doc]:
    return {f"live {doc['viewers']} viewers/none": doc["ratio"]}, {
        "live lost": sum(doc["lost"].values())
    }


def _motion(doc: Doc) -> tuple[Doc, Doc]:
    cost, scan = doc["cost"], doc["scan"]
    key = f"motion {scan['profile']} M={scan['stages']}"
    # The CPU per block over the time the block spans: the core measuring every block takes.
    ratios: Doc = {}
    for c in cost["widths"]:
        name = f"{key} {c['columns']} columns CPU/block span (lower is better)"
        ratios[name] = c["core_fraction_every_block"]
    ratios[f"{key} scan lines/s on/off"] = scan["ratio"]
    checks = {
        f"{key} scan lost frames": sum(r["lost_frames"] for r in scan["off"] + scan["on"]),
        f"{key} scan overruns": sum(r["overruns"] for r in scan["off"] + scan["on"]),
    }
    return ratios, checks


def _store(doc: Doc) -> tuple[Doc, Doc]:
    ratios: Doc = {}
    for case in doc["inputs"]:
        for name, figures in case["filters"].items():
            if name == "off":
                continue
            key = f"store {case['input']} {name}"
            ratios[f"{key} compression ratio"] = figures["ratio"]
            ratios[f"{key} one-core MB/s / camera rate"] = figures["over_camera_rate"]
    return ratios, {}


def _fuzz(doc: Doc) -> tuple[Doc, Doc]:
    return {}, {
        "fuzz requests": doc["requests"],
        "fuzz server errors": doc["server_errors"],
        "fuzz hangs": doc["hangs"],
    }


@dataclass(frozen=True)
class Bench:
    """One benchmark of the set: its arguments in a full and a quick run, and its figures."""

    name: str
    full: tuple[str, ...]
    quick: tuple[str, ...]
    figures: Callable[[Doc], tuple[Doc, Doc]]


BENCHES: tuple[Bench, ...] = (
    Bench("ping", (), ("--count", "600", "--rounds", "3"), _ping),
    Bench("stream", (), ("--rounds", "3", "--seconds", "1"), _stream),
    Bench("tdi", (), ("--rounds", "3", "--seconds", "0.5", "--shapes", "96x2048"), _tdi),
    Bench("sim", (), ("--profiles", "hr400", "--stages", "8,96", "--seconds", "1"), _sim),
    Bench(
        "pipeline",
        (),
        ("--profiles", "hr400", "--stages", "1,96", "--rounds", "3", "--seconds", "1"),
        _pipeline,
    ),
    Bench("scan", (), ("--lines", "2000"), _scan),
    Bench("live", (), ("--rounds", "3", "--seconds", "1.5"), _live),
    Bench(
        "motion",
        (),
        ("--rounds", "1", "--lines", "2000", "--repeat", "1", "--frame-bank", "256"),
        _motion,
    ),
    Bench("store", (), ("--rounds", "1", "--filters", "off,bitshuffle-lz4,blosc2-zstd"), _store),
    Bench("fuzz", (), ("--requests", "500"), _fuzz),
)
"""Every benchmark, in the order run (``camd soak`` is not one: it is an hour long)."""

NAMES = tuple(b.name for b in BENCHES)


def add_options(p: argparse.ArgumentParser) -> None:
    """The options of ``camd bench all`` but ``--json`` (camd.bench.command adds it)."""
    p.add_argument(
        "--quick",
        action="store_true",
        help="shorter rounds and fewer cases (a few minutes; noisier figures)",
    )
    p.add_argument(
        "--only", type=_names, default=NAMES, metavar="NAMES", help="run only these, e.g. tdi,sim"
    )
    p.add_argument("--skip", type=_names, default=(), metavar="NAMES", help="leave these out")


def _names(text: str) -> tuple[str, ...]:
    return choice_list(text, NAMES, "benchmark")


def four_figures(value: float) -> float:
    """A ratio to four significant figures, not four decimals: a ratio of 0.00098103 reads
    0.000981, not 0.001 (a tiny benchmark's ratio lost its digits)."""
    return float(f"{value:.4g}")


def run_one(bench: Bench, *, quick: bool, python: str = sys.executable) -> Doc:
    """One benchmark in its own process: its document, exit status, time, figures."""
    argv = [
        python,
        "-m",
        "camd",
        "bench",
        bench.name,
        "--json",
        *(bench.quick if quick else bench.full),
    ]
    t0 = time.perf_counter()
    proc = subprocess.run(argv, capture_output=True, text=True, check=False)
    entry: Doc = {
        "argv": argv[2:],
        "exit_status": proc.returncode,
        "wall_s": round(time.perf_counter() - t0, 1),
    }
    try:
        doc = json.loads(proc.stdout.strip().splitlines()[-1])
    except (json.JSONDecodeError, IndexError):
        entry["error"] = (proc.stderr.strip() or proc.stdout.strip() or "no output")[-2000:]
        return entry
    entry["doc"] = doc
    try:
        entry["ratios"], entry["checks"] = bench.figures(doc)
    except (KeyError, TypeError) as exc:
        entry["error"] = f"its document lacks {exc}"
    return entry


def bench_all(
    names: tuple[str, ...], *, quick: bool, progress: Callable[[str], None] | None = None
) -> Doc:
    """Run ``names`` in order; one document."""
    from camd import __version__

    started = datetime.now(UTC).isoformat(timespec="seconds")
    t0 = time.perf_counter()
    before = machine()
    benches: Doc = {}
    ratios: Doc = {}
    checks: Doc = {}
    for bench in BENCHES:
        if bench.name not in names:
            continue
        if progress:
            progress(f"camd bench all: {bench.name} ...")
        entry = run_one(bench, quick=quick)
        benches[bench.name] = entry
        ratios.update(entry.get("ratios", {}))
        checks.update(entry.get("checks", {}))
        if progress:
            status = "failed: " + entry["error"][-300:] if "error" in entry else "done"
            progress(f"camd bench all: {bench.name} {status} ({entry['wall_s']:.0f} s)")
    return {
        "camd": __version__,
        "started": started,
        "quick": quick,
        "machine": before,
        "loadavg_after": machine()["loadavg"],
        "wall_s": round(time.perf_counter() - t0, 1),
        "ratios": {k: four_figures(v) if isinstance(v, float) else v for k, v in ratios.items()},
        "checks": checks,
        "failed": [n for n, e in benches.items() if "error" in e or e["exit_status"] != 0],
        "benches": benches,
    }


def run(args: argparse.Namespace) -> int:
    """``camd bench all``: exit status 0 when every benchmark ran and exited 0, else 1."""
    names = tuple(n for n in args.only if n not in args.skip)
    if not names:
        print("camd bench all: --only and --skip leave no benchmark to run", file=sys.stderr)
        return 2
    doc = bench_all(names, quick=args.quick, progress=_progress)
    if args.json:
        print(json.dumps(doc))
    else:
        _print_human(doc)
    return 1 if doc["failed"] else 0


def _progress(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


def _print_human(doc: Doc) -> None:
    width = max((len(k) for k in [*doc["ratios"], *doc["checks"]]), default=10)
    m = doc["machine"]
    print(
        f"camd {doc['camd']} bench all{' --quick' if doc['quick'] else ''}, {doc['started']}, "
        f"{m['cpu']} ({m['cpus']} cpus), {doc['wall_s']:.0f} s"
    )
    print("ratios against each benchmark's own baseline:")
    for key, value in doc["ratios"].items():
        shown = f"{value:.3f}" if isinstance(value, float) else str(value)
        print(f"  {key:<{width}}  {shown}")
    print("counts that should be 0 (fuzz requests: how many were sent):")
    for key, value in doc["checks"].items():
        print(f"  {key:<{width}}  {value}")
    for name in doc["failed"]:
        entry = doc["benches"][name]
        print(
            f"FAILED {name} (exit status {entry['exit_status']}): {entry.get('error', '')[-500:]}"
        )
