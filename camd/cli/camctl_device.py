"""camctl's commands on the instrument as a whole: status, ping, link, telemetry (and a channel's
history), events, mode, reset, control and the emergency stop.

Like every command group (``camctl_sensor``, ``camctl_stream``, ...): ``add_parsers`` adds the
commands to camctl's parser, ``COMMANDS`` makes one API call each and returns the document
``--json`` prints, ``RENDER`` prints it as tables (``camctl_format``); the argument types of
their options are in ``camctl_args``.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from typing import Any

from rich.console import Console
from rich.text import Text

from camd.cli.camctl_args import finite_number, int_range, positive_float
from camd.cli.camctl_format import (
    control_text,
    estop_text,
    events_table,
    history_tables,
    link_table,
    ping_table,
    status_table,
    telemetry_table,
)
from camd.cli.camctl_sensor import CommandFailed, UsageError
from camd.client import CamdClient

MODES = ("area", "tdi")


def add_parsers(command: Callable[[str, str], argparse.ArgumentParser]) -> None:
    """The commands of this group, added through camctl's ``command(name, help)``."""
    command("status", "show the daemon's state, mode, link and device status")

    p = command("ping", "ping the device through the daemon and show round-trip times")
    p.add_argument(
        "--count",
        type=int_range(1, 100_000),
        default=10,
        metavar="N",
        help="number of pings, 1..100000 (default 10)",
    )
    p.add_argument(
        "--size",
        type=int_range(0, 256),
        default=16,
        metavar="B",
        help="payload bytes per ping, 0..256 (default 16)",
    )

    command("link", "show the command link's counters, host and device side by side")

    p = command("telemetry", "show the latest housekeeping telemetry, or channels' history")
    p.add_argument(
        "--history",
        metavar="CHANNELS",
        help="show the archived samples of CHANNELS instead (comma-separated, e.g. "
        "fpga_temp_degc,vcc_io_v)",
    )
    _range_arguments(p, "with --history: ", "the last hour")
    p.add_argument(
        "--bucket-s",
        type=positive_float,
        metavar="S",
        help="with --history: min, mean, max and count per S-second bucket instead of samples",
    )
    p.add_argument(
        "--source",
        choices=("tlm", "poll", "all"),
        help="with --history: only the camera's packets (tlm) or the daemon's polls (poll)",
    )
    p.add_argument(
        "--csv",
        action="store_true",
        help="with --history: print CSV (channel, unit, source, t_s, time_utc, then value or "
        "count, min, mean, max)",
    )
    p.add_argument(
        "--since-s",
        type=finite_number,
        metavar="T",
        help="with --history: the older form of --start: from Unix time T on; a negative T "
        "means T seconds before now (e.g. --since-s -60)",
    )
    p.add_argument(
        "--limit",
        type=int_range(1, 1_000_000),
        metavar="N",
        help="with --history: the newest N samples per channel",
    )

    p = command("events", "show recent events, newest last")
    p.add_argument(
        "--limit", type=int_range(1, 100_000), metavar="N", help="at most N events (newest)"
    )
    _range_arguments(p, "", "all")
    p.add_argument(
        "--level",
        metavar="LEVELS",
        help="only these levels, comma-separated: info, warning, error",
    )
    p.add_argument(
        "--source",
        metavar="SOURCES",
        help="only these sources, comma-separated (link, device, limits, daemon, api, ...)",
    )

    p = command("mode", "select the imaging mode: area (staring) or tdi (push-broom)")
    p.add_argument("mode", choices=MODES, help="area or tdi")

    command(
        "reset",
        "soft-reset the device (mode back to area, fault cleared, the sensor's registers back "
        "at their power-up values); refused while an acquisition runs",
    )
    p = command(
        "control",
        "show who holds control of the camera, or take or give it back (reading never needs it)",
    )
    p.add_argument(
        "action",
        nargs="?",
        choices=("status", "take", "release"),
        default="status",
        help="status (default), take (or renew) a lease, or release it",
    )
    p.add_argument(
        "--ttl-s",
        type=positive_float,
        default=60.0,
        metavar="S",
        help="with take: the lease's length in seconds (default 60; take again to renew)",
    )
    p.add_argument(
        "--force",
        action="store_true",
        help="with take: take control from the client that holds it (logged as an event)",
    )
    p = command(
        "estop",
        "EMERGENCY STOP: the stage (no ramp, current cut), the running acquisition, the filter "
        "wheel and a running campaign job (paused); never refused, whoever holds control. It "
        "latches: nothing moves or acquires until released (`camctl estop release`)",
    )
    p.add_argument(
        "action",
        nargs="?",
        choices=("stop", "status", "release"),
        default="stop",
        help="stop (default): the emergency stop; status: the latch; release: lift the latch "
        "once the rig is checked (needs control; the stage stays disabled and the wheel stopped "
        "until you start them)",
    )


# -- commands: one API call each; the returned document is what --json prints ------------------


def _cmd_status(client: CamdClient, args: argparse.Namespace) -> Any:
    return client.status()


def _cmd_ping(client: CamdClient, args: argparse.Namespace) -> Any:
    return client.ping(count=args.count, size=args.size)


def _cmd_link(client: CamdClient, args: argparse.Namespace) -> Any:
    return client.link()


def _range_arguments(p: argparse.ArgumentParser, prefix: str, default: str) -> None:
    """--start and --end, as the API takes them (docs/api.md)."""
    p.add_argument(
        "--start",
        metavar="TIME",
        help=f"{prefix}from TIME: ISO 8601 (UTC without a zone), Unix seconds, now, or before "
        f"now like --start=-10m, -2h, -1d (with '=': a bare -10m reads as an option; default "
        f"{default})",
    )
    p.add_argument(
        "--end", metavar="TIME", help=f"{prefix}up to TIME (exclusive), as --start (default now)"
    )


def _cmd_telemetry(client: CamdClient, args: argparse.Namespace) -> Any:
    if args.history is None:
        used = [
            flag
            for flag, value in (
                ("--start", args.start),
                ("--end", args.end),
                ("--bucket-s", args.bucket_s),
                ("--source", args.source),
                ("--since-s", args.since_s),
                ("--limit", args.limit),
                ("--csv", args.csv or None),
            )
            if value is not None
        ]
        if used:
            raise UsageError(f"{', '.join(used)} go(es) with --history CHANNELS")
        return client.telemetry()
    if args.csv and args.json:
        raise UsageError("--csv and --json are two formats: give one")
    channels = [c for c in args.history.split(",") if c.strip()]
    asked = {
        "start": args.start,
        "end": args.end,
        "bucket_s": args.bucket_s,
        "source": args.source,
        "limit": args.limit,
    }
    if args.csv:
        if args.since_s is not None:
            raise UsageError("with --csv give --start instead of --since-s")
        return client.history_csv(channels, **asked)
    return client.history(channels, since_s=args.since_s, **asked)


def _cmd_events(client: CamdClient, args: argparse.Namespace) -> Any:
    return client.events(
        limit=args.limit,
        start=args.start,
        end=args.end,
        levels=args.level.split(",") if args.level else None,
        sources=args.source.split(",") if args.source else None,
    )


def _cmd_mode(client: CamdClient, args: argparse.Namespace) -> Any:
    return client.set_mode(args.mode)


def _cmd_reset(client: CamdClient, args: argparse.Namespace) -> Any:
    return client.reset()


def _cmd_control(client: CamdClient, args: argparse.Namespace) -> Any:
    if args.action == "take":
        return client.take_control(args.ttl_s, force=args.force)
    if args.action == "release":
        return client.release_control()
    if args.force:
        raise UsageError("--force goes with `camctl control take`")
    return client.control()


def _cmd_estop(client: CamdClient, args: argparse.Namespace) -> Any:
    if args.action == "status":
        return client.estop_state()
    if args.action == "release":
        return client.release_estop()
    doc = client.estop()
    if doc["failed"]:
        raise CommandFailed(doc, "could not stop " + "; ".join(doc["failed"]))
    return doc


COMMANDS: dict[str, Callable[[CamdClient, argparse.Namespace], Any]] = {
    "status": _cmd_status,
    "ping": _cmd_ping,
    "link": _cmd_link,
    "telemetry": _cmd_telemetry,
    "events": _cmd_events,
    "mode": _cmd_mode,
    "reset": _cmd_reset,
    "control": _cmd_control,
    "estop": _cmd_estop,
}


# -- human output ---------------------------------------------------------------------------------


def _render_status(out: Console, doc: Any, args: argparse.Namespace) -> None:
    out.print(status_table(doc))


def _render_ping(out: Console, doc: Any, args: argparse.Namespace) -> None:
    out.print(ping_table(doc, title=f"ping: {args.count} x {args.size} B"))
    for reason in doc.get("errors") or []:
        out.print(Text(f"  error: {reason}", style="red"))


def _render_link(out: Console, doc: Any, args: argparse.Namespace) -> None:
    out.print(link_table(doc))


def _render_telemetry(out: Console, doc: Any, args: argparse.Namespace) -> None:
    if isinstance(doc, str):  # --csv: the daemon's CSV as it is, no rich markup or wrapping
        sys.stdout.write(doc)
    elif args.history is not None:
        for table in history_tables(doc):
            out.print(table)
    else:
        out.print(telemetry_table(doc))


def _render_events(out: Console, doc: Any, args: argparse.Namespace) -> None:
    out.print(events_table(doc))


def _render_mode(out: Console, doc: Any, args: argparse.Namespace) -> None:
    out.print(Text.assemble("mode: ", (str(doc.get("mode")), "bold")))


def _render_reset(out: Console, doc: Any, args: argparse.Namespace) -> None:
    out.print("device reset")
    out.print(status_table(doc))


def _render_control(out: Console, doc: Any, args: argparse.Namespace) -> None:
    out.print(Text.assemble("control: ", control_text(doc)))


def _render_estop(out: Console, doc: Any, args: argparse.Namespace) -> None:
    if args.action == "stop":
        out.print(
            Text(f"EMERGENCY STOP: stopped {', '.join(doc['stopped']) or 'nothing'}", "bold red")
        )
        doc = doc["latch"]
    out.print(Text.assemble("emergency stop: ", estop_text(doc)))


RENDER: dict[str, Callable[[Console, Any, argparse.Namespace], None]] = {
    "status": _render_status,
    "ping": _render_ping,
    "link": _render_link,
    "telemetry": _render_telemetry,
    "events": _render_events,
    "mode": _render_mode,
    "reset": _render_reset,
    "control": _render_control,
    "estop": _render_estop,
}
