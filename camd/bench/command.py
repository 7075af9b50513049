"""``camd bench``: benchmarks that print ratios against a baseline measured in the same run.

These machines are shared and noisy, so an absolute time means little; each benchmark measures
a baseline doing the same bare work in the same run, alternated with it, and reports the ratio
(``camd.bench.common`` holds the shared rules; bench/README.md names each baseline and why
it is the fair one). One module of ``camd.bench`` per benchmark, named as its subcommand but
``all`` (``run_all``):

- ``ping``: the command round trip through the whole stack against a bare pty echo of the same
  frame bytes;
- ``stream``: frame ingest (``FrameStream``) against bare bulk reads of the same stream on the
  same two threads;
- ``tdi``: the TDI engine against ``np.copyto`` of the same bytes on the same threads;
- ``sim`` and ``pipeline``: the simulated camera's and the host path's frame rates against the
  sensor's fastest line rate;
- ``scan``: a scan through the daemon at the sensor's line rate;
- ``live``: the daemon's ingest with live viewers against none;
- ``motion``: the live image motion measurement's CPU per block on one core against the time
  the block spans, and a scan's ingest with it on against off;
- ``store``: each compression filter's ratio and one-core write rate through camd's writers
  against no compression and the camera's full-window data rate;
- ``fuzz``: the API fuzzed from its own /openapi.json (counts, no baseline);
- ``all``: every one of them, one document of ratios.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from types import ModuleType
from typing import Any

from camd.bench import (
    fuzz,
    live,
    motion,
    ping,
    pipeline,
    run_all,
    scan,
    sim,
    store,
    stream,
    tdi,
)
from camd.client import CamdError


@dataclass(frozen=True, slots=True)
class _Bench:
    """A benchmark's subcommand: its module (``add_options(parser)`` and ``run(args) -> int``)
    and the texts of its ``--help``."""

    module: ModuleType
    help: str
    description: str


# Every benchmark by its subcommand's name, in the order ``camd bench --help`` lists them.
_BENCHES = {
    "ping": _Bench(
        ping,
        "command round trip vs a bare pty echo",
        "Round trip of PING through the daemon and the simulated camera, against a "
        "bare pty echo of the same bytes by a separate process, alternated in rounds.",
    ),
    "stream": _Bench(
        stream,
        "frame ingest vs bare bulk reads on the same two threads",
        "Frame ingest (FrameStream with a no-op consumer) against bare bulk reads "
        "of the same USB stream on the same two threads (reads into a ring of slots, handed "
        "to a second thread untouched), from a simulated FX3 in its own process, alternated.",
    ),
    "tdi": _Bench(
        tdi,
        "TDI engine vs np.copyto of the same bytes, one thread each",
        "The TDI engine's integer, fractional, drift and push-one-frame paths "
        "against np.copyto of the same input bytes, one thread each, in Gpix/s "
        "of input, A/B alternated, on frame sets larger than the last-level cache.",
    ),
    "scan": _Bench(
        scan,
        "a TDI scan at the sensor's line rate: lines/s, losses, CPU",
        "A scan through the daemon at the fastest line period M window rows allow, "
        "against that line rate.",
    ),
    "pipeline": _Bench(
        pipeline,
        "the host's scan path as fast as it goes: headroom over the line rate, CPU/frame",
        "Frames from an unpaced simulated FX3 through FrameStream, the batcher, "
        "the TDI engine and the HDF5 recorder: the sustained frame rate against the fastest "
        "line rate M rows allow, and the CPU per frame of each stage.",
    ),
    "sim": _Bench(
        sim,
        "the simulated camera's frame rate against the sensor's line rate",
        "The simulated camera streaming unpaced into a reader in its own process: "
        "frames/s against the fastest line rate a window of M rows allows.",
    ),
    "live": _Bench(
        live,
        "stream ingest with live viewers attached vs none",
        "Stream ingest of the daemon (frames and MB received per second) with N live "
        "viewers attached (B) against none (A), in alternating rounds on one continuous stream "
        "of the simulated hr400; prints the median B/A.",
    ),
    "motion": _Bench(
        motion,
        "image motion measurement: CPU per block on one core; scan ingest on vs off",
        "The live image motion measurement (ImageMotionMonitor): measure_tdi_motion's CPU per "
        "block of simulated hr400 TDI windows on one core, against the time the block spans "
        "at the fastest line period; and a scan through the daemon with the measurement off "
        "(A) and on (B), alternated in rounds; prints the median B/A against the goal 0.95.",
    ),
    "store": _Bench(
        store,
        "compression filters: ratio and one-core write rate vs none and the camera's rate",
        "Each compression filter writing the simulator's frames (the default scene, the bar "
        "target) and TDI sums through camd's writers: the ratio, and MB/s of raw data per "
        "CPU-second against no compression (A/B alternated) and hr400's full-window data rate.",
    ),
    "fuzz": _Bench(
        fuzz,
        "fuzz the daemon's API from its /openapi.json (schemathesis)",
        "Requests generated by schemathesis from the daemon's own /openapi.json, "
        "valid and invalid, against a daemon on the simulated camera: no 5xx, no hang, "
        "answers as documented, and a refused request changes nothing on the device. "
        f"Needs the test extra ({fuzz.INSTALL}).",
    ),
    "all": _Bench(
        run_all,
        "every benchmark, one document of ratios",
        "Runs every benchmark in its own process and prints their ratios against "
        "their baselines (and the counts that must be zero) in one document.",
    ),
}


def add_parser(sub: Any) -> None:
    """Register ``camd bench`` and one subcommand per benchmark, each with its options and the
    ``--json`` that every one of them takes."""
    p: argparse.ArgumentParser = sub.add_parser(
        "bench",
        help="benchmarks (ratios against a same-run baseline)",
        description="Benchmarks that report ratios against a baseline measured in the same run.",
    )
    which = p.add_subparsers(dest="bench", metavar="BENCH", required=True)
    for name, bench in _BENCHES.items():
        options = which.add_parser(name, help=bench.help, description=bench.description)
        bench.module.add_options(options)
        options.add_argument("--json", action="store_true", help="print one JSON document")


def run(args: argparse.Namespace) -> int:
    try:
        return int(_BENCHES[args.bench].module.run(args))
    except CamdError as exc:
        # The daemon refused what the benchmark asked (a scan too long for the stage's travel,
        # say): its message says what to change; a traceback would bury it.
        print(f"camd bench {args.bench}: error: {exc.message}", file=sys.stderr)
        return 1
