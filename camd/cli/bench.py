"""``camd bench``: benchmarks that print ratios against a baseline measured in the same run.

These machines are shared and noisy, so an absolute time means little; each benchmark measures
a baseline doing the same bare work in the same run, alternated with it, and reports the ratio
(``camd.cli.bench_common`` holds the shared rules; bench/README.md names each baseline and why
it is the fair one). One module per benchmark:

- ``ping`` (``bench_ping``): the command round trip through the whole stack against a bare pty
  echo of the same frame bytes;
- ``stream`` (``bench_stream``): frame ingest (``FrameStream``) against bare bulk reads of the
  same stream on the same two threads;
- ``tdi`` (``bench_tdi``): the TDI engine against ``np.copyto`` of the same bytes on the same
  threads;
- ``sim`` (``bench_sim``) and ``pipeline`` (``bench_pipeline``): the simulated camera's and the
  host path's frame rates against the sensor's fastest line rate;
- ``scan`` (``bench_scan``): a scan through the daemon at the sensor's line rate;
- ``live`` (``bench_live``): the daemon's ingest with live viewers against none;
- ``fuzz`` (``bench_fuzz``): the API fuzzed from its own /openapi.json (counts, no baseline);
- ``all`` (``bench_all``): every one of them, one document of ratios.
"""

from __future__ import annotations

import argparse
from typing import Any

from camd.cli import (
    bench_all,
    bench_fuzz,
    bench_live,
    bench_ping,
    bench_pipeline,
    bench_scan,
    bench_sim,
    bench_stream,
    bench_tdi,
)

_RUN = {
    "ping": bench_ping.run,
    "stream": bench_stream.run,
    "tdi": bench_tdi.run,
    "scan": bench_scan.run,
    "pipeline": bench_pipeline.run,
    "sim": bench_sim.run,
    "live": bench_live.run,
    "fuzz": bench_fuzz.run,
    "all": bench_all.run,
}


def add_parser(sub: Any) -> None:
    p: argparse.ArgumentParser = sub.add_parser(
        "bench",
        help="benchmarks (ratios against a same-run baseline)",
        description="Benchmarks that report ratios against a baseline measured in the same run.",
    )
    which = p.add_subparsers(dest="bench", metavar="BENCH", required=True)
    for module in (
        bench_ping,
        bench_stream,
        bench_tdi,
        bench_scan,
        bench_pipeline,
        bench_sim,
        bench_live,
        bench_fuzz,
        bench_all,
    ):
        module.add_parser(which)


def run(args: argparse.Namespace) -> int:
    return _RUN[args.bench](args)
