"""camctl's ``conform``: the conformance suite against the daemon at --url, or with ``--sim``
against a simulated camera it starts (``camd.cli.conform`` does the work; docs/conformance.md).

    camctl conform [--out DIR] [--only ID ...] [--destructive] [--sim [--profile P]
                   [--defect NAME ...]] [--json]

Exit status 0 when the unit conforms, 1 when a check failed (the report is written), 2 for bad
options, 3 when no daemon answers.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from typing import Any

from rich.console import Console
from rich.markup import escape

from camd.client import CamdClient

__all__ = ["COMMANDS", "RENDER", "add_parsers"]


def add_parsers(command: Callable[[str, str], argparse.ArgumentParser]) -> None:
    """Add ``conform`` through camctl's ``command(name, help)`` factory."""
    from camd.cli.conform import add_options

    p = command("conform", "run the conformance suite on the camera and write its report")
    add_options(p, url=False)


def cmd_conform(client: CamdClient, args: argparse.Namespace) -> Any:
    from camd.cli.camctl_sensor import CommandFailed, UsageError
    from camd.cli.conform import conform, usage_problem

    problem = usage_problem(args)
    if problem is not None:
        raise UsageError(problem)
    try:
        doc = conform(None if args.sim else client, args)
    except RuntimeError as exc:
        raise CommandFailed({"error": str(exc)}, str(exc)) from None
    if not doc["conforms"]:
        raise CommandFailed(doc, f"conformance: check(s) failed: {', '.join(doc['failed'])}")
    return doc


def render_conform(out: Console, doc: Any, args: argparse.Namespace) -> None:
    if "error" in doc:
        return
    s = doc["summary"]
    colour = "green" if doc["conforms"] else "red"
    verdict = "CONFORMS" if doc["conforms"] else "DOES NOT CONFORM"
    out.print(
        f"conformance: [{colour}]{verdict}[/]: {s['pass']} passed, {s['fail']} failed, "
        f"{s['skipped']} skipped of {s['checks']}; report {escape(doc['report']['html'])}"
    )


COMMANDS: dict[str, Callable[[CamdClient, argparse.Namespace], Any]] = {"conform": cmd_conform}
RENDER: dict[str, Callable[[Console, Any, argparse.Namespace], None]] = {"conform": render_conform}
