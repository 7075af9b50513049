"""camctl's ROI commands: the live view's regions of interest, measured on every frame.

    camctl roi add NAME X Y WIDTH HEIGHT   measure a rectangle (pixels from the top left)
    camctl roi list                        the ROIs and the frame they were checked against
    camctl roi rm NAME                     stop measuring one
    camctl roi stats [--history N]         the newest frame's statistics of every ROI (and,
                                           with --json, the newest N frames' per ROI)

A script or campaign reads through these what the operator sees on the live page
(docs/live-view.md, "Regions of interest").
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from typing import Any

from rich.console import Console

from camd.cli.camctl_args import actions, count_arg
from camd.client import CamdClient


def _int(text: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number of pixels") from None


def add_parsers(command: Callable[[str, str], argparse.ArgumentParser]) -> None:
    """Add ``roi`` through camctl's ``command(name, help)`` factory."""
    p = command("roi", "regions of interest: statistics on every frame of every stream")
    action = actions(p, "roi_command")
    add = action("add", "measure a named rectangle (replaces one of that name)")
    add.add_argument("name", help="1-32 letters, digits, '_', '.', '-'")
    for name, what in (
        ("x", "first column"),
        ("y", "first row"),
        ("width", "columns"),
        ("height", "rows"),
    ):
        add.add_argument(name, type=_int, help=what)
    action("list", "the ROIs and the frame geometry they were checked against")
    rm = action("rm", "stop measuring an ROI")
    rm.add_argument("name")
    stats = action("stats", "the newest frame's statistics of every ROI")
    stats.add_argument(
        "--history",
        type=count_arg,
        default=0,
        metavar="N",
        help="also the newest N frames' statistics per ROI (0..4096; shown with --json)",
    )


def cmd_roi(client: CamdClient, args: argparse.Namespace) -> Any:
    if args.roi_command == "add":
        return client.add_roi(args.name, args.x, args.y, args.width, args.height)
    if args.roi_command == "rm":
        return client.delete_roi(args.name)
    if args.roi_command == "stats":
        return client.roi_stats(args.history)
    return client.rois()


COMMANDS: dict[str, Callable[[CamdClient, argparse.Namespace], Any]] = {"roi": cmd_roi}


def _fmt(value: float | None) -> str:
    return "-" if value is None else f"{value:.6g}"


def render_roi(out: Console, doc: Any, args: argparse.Namespace) -> None:
    if args.roi_command != "stats":
        geometry = f"{doc['cols']} x {doc['rows']} frame" if doc["rows"] else "no stream yet"
        n = len(doc["rois"])
        out.print(f"{n} ROI{'' if n == 1 else 's'} (checked against: {geometry})", markup=False)
        for r in doc["rois"]:
            out.print(
                f"  {r['name']}: x={r['x']} y={r['y']} {r['width']} x {r['height']}",
                markup=False,
            )
        return
    latest = doc["latest"]
    out.print(
        f"{doc['measured']} frames measured, {doc['unfit']} not fitting the ROIs", markup=False
    )
    if latest is None:
        out.print("no frame measured yet: define an ROI and stream", markup=False)
        return
    out.print(f"frame {latest['counter']}:", markup=False)
    for name, s in latest["rois"].items():
        out.print(
            f"  {name}: mean {_fmt(s['mean_dn'])} std {_fmt(s['std_dn'])} min "
            f"{_fmt(s['min_dn'])} max {_fmt(s['max_dn'])} sum {_fmt(s['sum_dn'])} SNR "
            f"{_fmt(s['snr'])} saturated {int(s['saturated'])} bg-subtracted mean "
            f"{_fmt(s['bg_mean_dn'])} DN",
            markup=False,
        )


RENDER: dict[str, Callable[[Console, Any, argparse.Namespace], None]] = {"roi": render_roi}
