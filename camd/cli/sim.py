"""``camd sim``: run the simulated camera alone and print where it listens.

This is one of the few places camd names the simulated device (architecture.md): it hands its
arguments to ``firmware_models.cli``, which owns the simulator's options.
"""

from __future__ import annotations

import argparse
from typing import Any


def add_parser(sub: Any) -> None:
    p: argparse.ArgumentParser = sub.add_parser(
        "sim",
        help="run the simulated camera alone on a pseudo-terminal",
        description="Run the simulated camera (FPGA, sensor, link faults) behind a pseudo-terminal "
        "and print the tty it listens on. Options are those of `python -m firmware_models`.",
        add_help=False,
    )
    p.add_argument("sim_args", nargs=argparse.REMAINDER, help="options for the simulator (--help)")


def run(args: argparse.Namespace) -> int:
    return run_passthrough(list(args.sim_args))


def run_passthrough(sim_argv: list[str]) -> int:
    """Run the simulator with its own command-line arguments."""
    from firmware_models.cli import main as sim_main

    return sim_main(sim_argv, prog="camd sim")
