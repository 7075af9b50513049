"""What a daemon's start loads: ``camd serve`` parses its command line with its own subcommand's
parser only, so that it imports neither the benchmarks, the soak, the demo, the conformance
command nor the HTTP client (the suite starts about 150 daemons); and that parser reads a
command line as the whole ``camd`` parser does."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from camd.cli.camd_main import build_parser

# Loaded by the other subcommands, never needed to serve.
NOT_FOR_SERVE = [
    "camd.bench.command",
    "camd.soak.command",
    "camd.cli.demo",
    "camd.cli.conform",
    "camd.client",
    "httpx",
]

PROBE = """
import json, sys
from camd.cli.camd_main import _SUBCOMMANDS, build_parser
args = build_parser("serve").parse_args(["serve", "--sim", "--port", "0"])
print(json.dumps(sorted(name for name in sys.argv[1:] if name in sys.modules)))
"""


def test_serve_parses_without_loading_the_other_commands() -> None:
    proc = subprocess.run(
        [sys.executable, "-c", PROBE, *NOT_FOR_SERVE],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout) == []


@pytest.mark.parametrize(
    "argv",
    [
        ["serve", "--sim", "--port", "0", "--data-dir", "/tmp/d", "--inject", "ber=1e-4"],
        ["serve", "--config", "camd.toml", "--record-dir", "/a", "--record-dir", "/b"],
        ["serve", "--hardware", "--serial", "/dev/ttyUSB0", "--host", "0.0.0.0"],
        ["conform", "--sim", "--out", "report"],
        ["demo", "--pings", "10", "--no-campaigns"],
        ["bench", "tdi"],
    ],
)
def test_one_commands_parser_reads_as_the_whole_parser(argv: list[str]) -> None:
    assert vars(build_parser(argv[0]).parse_args(argv)) == vars(build_parser().parse_args(argv))
