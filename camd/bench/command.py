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
- ``fuzz``: the API fuzzed from its own /openapi.json (counts, no baseline);
- ``all``: every one of them, one document of ratios.
"""

from __future__ import annotations

import argparse
from typing import Any

from camd.bench import (
    fuzz,
    live,
    ping,
    pipeline,
    run_all,
    scan,
    sim,
    stream,
    tdi,
)

_RUN = {
    "ping": ping.run,
    "stream": stream.run,
    "tdi": tdi.run,
    "scan": scan.run,
    "pipeline": pipeline.run,
    "sim": sim.run,
    "live": live.run,
    "fuzz": fuzz.run,
    "all": run_all.run,
}


def add_parser(sub: Any) -> None:
    p: argparse.ArgumentParser = sub.add_parser(
        "bench",
        help="benchmarks (ratios against a same-run baseline)",
        description="Benchmarks that report ratios against a baseline measured in the same run.",
    )
    which = p.add_subparsers(dest="bench", metavar="BENCH", required=True)
    for module in (
        ping,
        stream,
        tdi,
        scan,
        pipeline,
        sim,
        live,
        fuzz,
        run_all,
    ):
        module.add_parser(which)


def run(args: argparse.Namespace) -> int:
    return _RUN[args.bench](args)
