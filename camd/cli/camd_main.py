"""``camd``: the server-side command (serve, sim, demo, bench, soak, conform, archive).

Each subcommand lives in its own module with ``add_parser(subparsers)`` and ``run(args) -> int``:
the user's commands here in ``camd.cli`` (serve in ``camd.daemon``), the tools that measure camd
in their own packages above it (``camd.bench``, ``camd.soak``), named by module path only.
``camd sim`` passes its arguments through to the simulator (``camd.cli.sim``), whose module is
imported only then: ``camd sim`` never loads the daemon, and the other commands never load the
simulator.
"""

from __future__ import annotations

import argparse
import importlib
import sys

import camd
from camd.datafile import DataFileError, bounded

# subcommand -> module providing add_parser() and run()
_SUBCOMMANDS = {
    "serve": "camd.daemon.serve",
    "demo": "camd.cli.demo",
    "bench": "camd.bench.command",
    "soak": "camd.soak.command",
    "conform": "camd.cli.conform",
    "archive": "camd.archive.command",
}


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The parser of ``camd``; with ``command`` (one of the subcommands) it knows that one only,
    so that only its module is imported: ``camd serve`` then loads neither the benchmarks nor
    the client (0.13 s of a core at each daemon's start), and parses and answers ``--help`` as
    the whole parser would."""
    parser = argparse.ArgumentParser(
        prog="camd",
        description="camd: control daemon for digital-TDI push-broom cameras (and its simulator).",
    )
    parser.add_argument("--version", action="version", version=f"camd {camd.__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name, module_name in _SUBCOMMANDS.items():
        if command in (None, name):
            importlib.import_module(module_name).add_parser(sub)
    if command is not None:
        return parser
    # Only listed here: main() hands `camd sim ...` to the simulator before parsing.
    sub.add_parser(
        "sim",
        help="run the simulated camera alone on a pseudo-terminal",
        description="Run the simulated camera (FPGA, sensor, link faults) behind a pseudo-terminal "
        "and print the tty it listens on. Options are those of `python -m firmware_models`.",
        add_help=False,
    )
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["sim"]:
        # The simulator owns its options; pass them through untouched (argparse's REMAINDER
        # would stumble on a leading --option).
        from camd.cli.sim import run_passthrough

        return run_passthrough(argv[1:])
    args = build_parser(argv[0] if argv[:1] and argv[0] in _SUBCOMMANDS else None).parse_args(argv)
    module = importlib.import_module(_SUBCOMMANDS[args.command])
    try:
        return int(module.run(args))
    except DataFileError as exc:  # a config or data file: file:line says what to change
        print(f"camd {args.command}: error: {bounded(str(exc))}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("camd: interrupted", file=sys.stderr)
        return 130
