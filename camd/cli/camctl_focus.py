"""camctl's focus command: the live view's focus aid (docs/live-view.md, "Focus aid").

    camctl focus [--history N]   the newest sharpness figures (frame and each ROI) and the best
                                 since the last reset (with --json, the newest N figures too)
    camctl focus --reset         forget the best (a new focusing starts)

Asking keeps the daemon measuring for ``watch_s`` (30 s); the first ask starts it, so the first
answer may have no figure yet: ask again a moment later (or watch the live page).
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from typing import Any

from rich.console import Console

from camd.cli.camctl_args import count_arg
from camd.client import CamdClient


def add_parsers(command: Callable[[str, str], argparse.ArgumentParser]) -> None:
    """Add ``focus`` through camctl's ``command(name, help)`` factory."""
    p = command("focus", "focus aid: the live frames' sharpness figure and the best so far")
    p.add_argument(
        "--history",
        type=count_arg,
        default=0,
        metavar="N",
        help="also the newest N figures (0..1200; shown with --json)",
    )
    p.add_argument("--reset", action="store_true", help="forget the best figures first")


def cmd_focus(client: CamdClient, args: argparse.Namespace) -> Any:
    if args.reset:
        client.reset_focus_best()
    return client.focus(args.history)


COMMANDS: dict[str, Callable[[CamdClient, argparse.Namespace], Any]] = {"focus": cmd_focus}


def _fmt(value: float | None) -> str:
    return "-" if value is None else f"{value:.6g}"


def render_focus(out: Console, doc: Any, args: argparse.Namespace) -> None:
    watching = "measuring" if doc["watching"] else "not measuring"
    out.print(
        f"focus: {doc['measured']} figures so far, {watching} (at most {doc['rate_hz']:g} a "
        f"second while asked within {doc['watch_s']:g} s)",
        markup=False,
    )
    latest = doc["latest"]
    if latest is None:
        out.print("no figure yet: stream, and ask again in a second", markup=False)
        return
    out.print(f"frame {latest['counter']}: sharpness G (best since reset)", markup=False)
    for target, value in latest["values"].items():
        best = doc["best"].get(target)
        best_text = "-" if best is None else f"{_fmt(best['value'])} at frame {best['counter']}"
        out.print(f"  {target}: {_fmt(value)} (best {best_text})", markup=False)


RENDER: dict[str, Callable[[Console, Any, argparse.Namespace], None]] = {"focus": render_focus}
