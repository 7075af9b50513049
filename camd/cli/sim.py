"""``camd sim``: run the simulated camera alone and print where it listens.

With the backend factory (``camd.daemon.backends``) and the benchmarks that read the simulated
FX3 or measure the simulator (``camd.bench``), this is the only place camd names the simulated
device: it hands its arguments to ``firmware_models.cli``, which owns the simulator's
options. ``camd`` imports this module only when ``camd sim`` runs (``camd.cli.camd_main``).
"""

from __future__ import annotations

from firmware_models.cli import main as sim_main


def run_passthrough(sim_argv: list[str]) -> int:
    """Run the simulator with its own command-line arguments."""
    return sim_main(sim_argv, prog="camd sim")
