"""``camd``: the server-side command (serve, sim, demo).

Each subcommand lives in its own module with ``add_parser(subparsers)`` and ``run(args) -> int``;
modules are imported only when their subcommand runs, so ``camd sim`` never loads the daemon.
"""

from __future__ import annotations

import argparse
import importlib
import sys

import camd

# subcommand -> module providing add_parser() and run()
_SUBCOMMANDS = {
    "serve": "camd.daemon.serve",
    "sim": "camd.cli.sim",
    "demo": "camd.cli.demo",
    "bench": "camd.cli.bench",
}


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="camd",
        description="camd: control daemon for digital-TDI push-broom cameras (and its simulator).",
    )
    parser.add_argument("--version", action="version", version=f"camd {camd.__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for module_name in _SUBCOMMANDS.values():
        importlib.import_module(module_name).add_parser(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["sim"]:
        # The simulator owns its options; pass them through untouched (argparse's REMAINDER
        # would stumble on a leading --option).
        from camd.cli.sim import run_passthrough

        return run_passthrough(argv[1:])
    args = build_parser().parse_args(argv)
    module = importlib.import_module(_SUBCOMMANDS[args.command])
    try:
        return int(module.run(args))
    except KeyboardInterrupt:
        print("camd: interrupted", file=sys.stderr)
        return 130
