"""``camctl``: the command-line client of a running camd daemon.

    camctl [--url URL] [--token T] [--timeout S] <command> ... [--json]

With ``--json`` (before or after the command) every command prints exactly one JSON document on
stdout: the API's answer. Without it, readable tables. Errors go to stderr as
``camctl: error: <message>``; exit status 1 for an error reported by the daemon, 2 for a usage
error, 3 when no daemon answers at the URL. docs/cli.md describes every command.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from collections.abc import Callable, Sequence
from itertools import zip_longest
from typing import Any

from rich import box
from rich.console import Console
from rich.table import Table
from rich.text import Text

import camd
from camd.cli import (
    camctl_campaign,
    camctl_conform,
    camctl_motion,
    camctl_scan,
    camctl_sensor,
    camctl_stream,
    camctl_wheel,
)
from camd.cli.camctl_sensor import CommandFailed, NothingRunning, UsageError
from camd.client import DEFAULT_URL, CamdClient, CamdError, DaemonUnreachable
from camd.datafile import bounded

EXIT_OK = 0
EXIT_API_ERROR = 1
EXIT_USAGE = 2
EXIT_UNREACHABLE = 3

MODES = ("area", "tdi")

STATE_STYLE = {
    "idle": "bold green",
    "staring": "bold cyan",
    "scanning": "bold cyan",
    "imaging": "bold cyan",
    "disconnected": "bold yellow",
    "fault": "bold red",
}
LIMIT_STYLE = {"ok": "green", "yellow": "bold yellow", "red": "bold red"}
LEVEL_STYLE = {"info": "", "warning": "yellow", "warn": "yellow", "error": "red", "critical": "red"}


# -- argument parsing -----------------------------------------------------------------------------


def _common_options(parser: argparse.ArgumentParser, *, suppress: bool) -> None:
    """Options accepted both before and after the command.

    The subcommands' copies default to SUPPRESS so that they only set a value when given there
    (otherwise argparse would overwrite the value given before the command with the default).
    """

    def default(value: Any) -> Any:
        return argparse.SUPPRESS if suppress else value

    parser.add_argument(
        "--json",
        action="store_true",
        default=default(False),
        help="print exactly one JSON document (the API's answer) on stdout",
    )
    parser.add_argument(
        "--url",
        default=default(None),
        help=f"daemon URL (default: $CAMD_URL or {DEFAULT_URL})",
    )
    parser.add_argument(
        "--token",
        default=default(None),
        help="API token, required when the daemon is not on loopback (default: $CAMD_TOKEN)",
    )
    parser.add_argument(
        "--timeout",
        type=_positive_float,
        default=default(30.0),
        metavar="S",
        help="seconds to wait for each answer (default 30; ping adds time per ping)",
    )
    parser.add_argument(
        "--client",
        default=default(None),
        metavar="NAME",
        help="the name the daemon knows you by for control (default: $CAMD_CLIENT or user@host)",
    )


def _positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not value > 0:
        raise argparse.ArgumentTypeError(f"must be > 0, got {text}")
    return value


def _int_range(lo: int, hi: int) -> Callable[[str], int]:
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
        if not lo <= value <= hi:
            raise argparse.ArgumentTypeError(f"must be from {lo} to {hi}, got {value}")
        return value

    parse.__name__ = "integer"
    return parse


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of ``camctl`` (also used by docs and tests)."""
    parser = argparse.ArgumentParser(
        prog="camctl",
        description="Client of a running camd daemon. Every command takes --json to print "
        "exactly one JSON document on stdout. Exit status: 0 ok, 1 error reported by the "
        "daemon, 2 usage error, 3 no daemon at the URL.",
    )
    parser.add_argument("--version", action="version", version=f"camctl {camd.__version__}")
    _common_options(parser, suppress=False)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)

    def command(name: str, help_text: str) -> argparse.ArgumentParser:
        p = sub.add_parser(name, help=help_text, description=help_text)
        _common_options(p, suppress=True)
        return p

    command("status", "show the daemon's state, mode, link and device status")

    p = command("ping", "ping the device through the daemon and show round-trip times")
    p.add_argument(
        "--count",
        type=_int_range(1, 100_000),
        default=10,
        metavar="N",
        help="number of pings, 1..100000 (default 10)",
    )
    p.add_argument(
        "--size",
        type=_int_range(0, 256),
        default=16,
        metavar="B",
        help="payload bytes per ping, 0..256 (default 16)",
    )

    command("link", "show the command link's counters, host and device side by side")

    p = command("telemetry", "show the latest housekeeping telemetry, or one channel's history")
    p.add_argument(
        "--history",
        metavar="CHANNEL",
        help="show the archived samples of CHANNEL instead (e.g. fpga_temp_degc)",
    )
    p.add_argument(
        "--since-s",
        type=camctl_stream.finite_number,
        metavar="T",
        help="with --history: only samples from Unix time T on; a negative T means T seconds "
        "before now (e.g. --since-s -60)",
    )
    p.add_argument(
        "--limit",
        type=_int_range(1, 1_000_000),
        metavar="N",
        help="with --history: at most N samples",
    )

    p = command("events", "show recent events, newest last")
    p.add_argument(
        "--limit", type=_int_range(1, 100_000), metavar="N", help="at most N events (newest)"
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
        type=_positive_float,
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
    camctl_sensor.add_parsers(command)
    camctl_stream.add_parsers(command)
    camctl_scan.add_parsers(command)
    camctl_motion.add_parsers(command)
    camctl_wheel.add_parsers(command)
    camctl_campaign.add_parsers(command)
    camctl_conform.add_parsers(command)
    return parser


# -- main -----------------------------------------------------------------------------------------


def main(argv: Sequence[str] | None = None) -> int:
    """Run camctl; returns the exit status (0 ok, 1 API error, 2 usage, 3 unreachable)."""
    parser = build_parser()
    args = parser.parse_args(argv)  # exits 2 with argparse's message on a usage error
    if (
        args.command == "telemetry"
        and args.history is None
        and (args.since_s is not None or args.limit is not None)
    ):
        parser.error("telemetry: --since-s and --limit go with --history CHANNEL")

    try:
        client = CamdClient(args.url, token=args.token, timeout_s=args.timeout, client=args.client)
    except ValueError as exc:
        parser.error(str(exc))

    out = Console(highlight=False, soft_wrap=False)
    try:
        with client:
            try:
                doc = _COMMANDS[args.command](client, args)
            except CommandFailed as failed:
                _show(out, failed.doc, args)
                _error(failed.message)
                return failed.status
            _show(out, doc, args)
    except UsageError as exc:
        _error(str(exc))
        return EXIT_USAGE
    except NothingRunning as exc:
        _error(str(exc))
        return EXIT_API_ERROR
    except DaemonUnreachable as exc:
        _error(exc.message)
        return EXIT_UNREACHABLE
    except CamdError as exc:
        _error(exc.message)
        return EXIT_API_ERROR
    except KeyboardInterrupt:
        _error("interrupted")
        return 130
    except BrokenPipeError:
        # `camctl ... | head`: the reader left; not an error worth a traceback.
        _silence_stdout()
        return EXIT_OK
    return EXIT_OK


def _show(out: Console, doc: Any, args: argparse.Namespace) -> None:
    if args.json:
        # One document, plain print: no rich markup or wrapping may touch it.
        sys.stdout.write(json.dumps(doc, indent=2, sort_keys=False) + "\n")
    else:
        _RENDER[args.command](out, doc, args)


def _error(message: str) -> None:
    # Bounded: a message quotes what it refuses (a value of a file, an argument), cut short.
    print(f"camctl: error: {bounded(message)}", file=sys.stderr)


def _silence_stdout() -> None:
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())


# -- commands: one API call each; the returned document is what --json prints ------------------


def _cmd_status(client: CamdClient, args: argparse.Namespace) -> Any:
    return client.status()


def _cmd_ping(client: CamdClient, args: argparse.Namespace) -> Any:
    return client.ping(count=args.count, size=args.size)


def _cmd_link(client: CamdClient, args: argparse.Namespace) -> Any:
    return client.link()


def _cmd_telemetry(client: CamdClient, args: argparse.Namespace) -> Any:
    if args.history is not None:
        return client.history(args.history, since_s=args.since_s, limit=args.limit)
    return client.telemetry()


def _cmd_events(client: CamdClient, args: argparse.Namespace) -> Any:
    return client.events(limit=args.limit)


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


_COMMANDS: dict[str, Callable[[CamdClient, argparse.Namespace], Any]] = {
    "status": _cmd_status,
    "ping": _cmd_ping,
    "link": _cmd_link,
    "telemetry": _cmd_telemetry,
    "events": _cmd_events,
    "mode": _cmd_mode,
    "reset": _cmd_reset,
    "control": _cmd_control,
    "estop": _cmd_estop,
    **camctl_sensor.COMMANDS,
    **camctl_stream.COMMANDS,
    **camctl_scan.COMMANDS,
    **camctl_motion.COMMANDS,
    **camctl_wheel.COMMANDS,
    **camctl_campaign.COMMANDS,
    **camctl_conform.COMMANDS,
}


# -- human output ---------------------------------------------------------------------------------


def cell(value: Any) -> Text:
    """A table cell holding a value the daemon sent: text, never read as rich markup (a reason
    or an event that says "[sim] profile = ..." keeps its brackets)."""
    return Text(fmt_value(value))


def fmt_value(value: Any) -> str:
    """A compact human form of a JSON value (6 significant digits for floats)."""
    if value is None:
        return "-"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return format(value, ".6g")
    if isinstance(value, dict | list):
        return json.dumps(value)
    return str(value)


def fmt_time(t_s: Any) -> str:
    """Wall-clock seconds as local HH:MM:SS.mmm; other numbers (relative times) as seconds."""
    if not isinstance(t_s, int | float):
        return fmt_value(t_s)
    if t_s > 1e9:  # seconds since the epoch
        return time.strftime("%H:%M:%S", time.localtime(t_s)) + f".{int(t_s * 1000) % 1000:03d}"
    return f"{t_s:.3f} s"


def fmt_firmware(version: Any) -> str:
    """GET_STATUS fw_version (major * 256 + minor) as ``major.minor``."""
    if isinstance(version, int) and not isinstance(version, bool):
        return f"{version >> 8}.{version & 0xFF}"
    return fmt_value(version)


def state_text(state: Any) -> Text:
    """The daemon state, coloured."""
    return Text(str(state), style=STATE_STYLE.get(str(state), "bold"))


def limit_text(limit: Any) -> Text:
    """A telemetry limit state (ok / yellow / red), coloured."""
    return Text(str(limit), style=LIMIT_STYLE.get(str(limit), ""))


def _kv_table(title: str | None = None) -> Table:
    table = Table(
        title=title, box=box.SIMPLE_HEAVY, show_edge=False, show_header=False, title_justify="left"
    )
    table.add_column("key", style="dim")
    table.add_column("value")
    return table


def backends_text(backends: dict[str, Any]) -> Text:
    """``hardware: link serial /dev/ttyUSB0, stream libusb USB 04b4:00f1, registers fpga (...)``;
    a mix of simulated and real interfaces in yellow."""
    parts = [
        f"{name} {part.get('backend')} {part.get('detail')}"
        if name != "registers"
        else f"{name} {part.get('backend')} ({part.get('detail')})"
        for name in ("link", "stream", "registers")
        if isinstance(part := backends.get(name), dict)
    ]
    camera = str(backends.get("camera"))
    return Text(f"{camera}: " + ", ".join(parts), style="yellow" if camera == "mixed" else "")


def status_table(doc: dict[str, Any], title: str | None = "camd status") -> Table:
    """The status document as a two-column table, state coloured."""
    table = _kv_table(title)
    table.add_row("state", state_text(doc.get("state")))
    if doc.get("reason"):
        table.add_row("reason", cell(doc.get("reason")))
    table.add_row("mode", fmt_value(doc.get("mode")))
    link = doc.get("link") or {}
    connected = link.get("connected")
    table.add_row(
        "link",
        Text.assemble(
            f"{link.get('port', '-')} ",
            ("connected", "green") if connected else ("not connected", "yellow"),
        ),
    )
    if link.get("last_error"):
        table.add_row("link error", Text(str(link["last_error"]), style="yellow"))
    if link.get("sim_state") is not None:  # the simulated camera this daemon spawned
        sim_state = str(link["sim_state"])
        table.add_row(
            "simulator",
            Text(
                f"{sim_state}, pid {link.get('sim_pid') or '-'}, "
                f"restarts {link.get('sim_restarts') or 0}",
                style="green" if sim_state == "running" else "yellow",
            ),
        )
    if isinstance(doc.get("backends"), dict):
        table.add_row("camera", backends_text(doc["backends"]))
    device = doc.get("device")
    if isinstance(device, dict):
        for key, value in device.items():
            shown = fmt_firmware(value) if key == "fw_version" else fmt_value(value)
            table.add_row(f"device.{key}", shown)
    else:
        table.add_row("device", "-")
    daemon = doc.get("daemon") or {}
    for key, value in daemon.items():
        table.add_row(f"daemon.{key}", cell(value))
    if isinstance(doc.get("estop"), dict) and doc["estop"].get("latched"):
        table.add_row("EMERGENCY STOP", estop_text(doc["estop"]))
    if isinstance(doc.get("control"), dict):
        table.add_row("control", control_text(doc["control"]))
    acquisition = doc.get("acquisition")
    if isinstance(acquisition, dict):
        running = "running" if acquisition.get("running") else "ended"
        by = f" by {acquisition['client']}" if acquisition.get("client") else ""
        table.add_row(
            "acquisition",
            f"{acquisition.get('kind')} {running}: {acquisition.get('description')}{by}, "
            f"since {fmt_time(acquisition.get('started_t_s'))}",
        )
    listed = {
        "state", "reason", "mode", "link", "device", "daemon", "control", "acquisition", "estop",
    }  # fmt: skip
    for key, value in doc.items():
        if key not in listed:
            table.add_row(key, cell(value))
    return table


def ping_table(doc: dict[str, Any], title: str | None = "ping") -> Table:
    """A ping result: counts and RTT percentiles."""
    table = _kv_table(title)
    failed = doc.get("failed", 0)
    table.add_row("count", fmt_value(doc.get("count")))
    table.add_row("ok", Text(fmt_value(doc.get("ok")), style="green"))
    table.add_row("failed", Text(fmt_value(failed), style="bold red" if failed else "green"))
    table.add_row("retries", fmt_value(doc.get("retries")))
    rtt = doc.get("rtt_ms") or {}
    for key in ("p50", "p99", "max"):
        value = rtt.get(key)
        shown = f"{value:.3f} ms" if isinstance(value, int | float) else fmt_value(value)
        table.add_row(f"rtt {key}", shown)
    for key, value in doc.items():
        if key not in {"count", "ok", "failed", "retries", "rtt_ms", "errors"}:
            table.add_row(key, cell(value))
    return table


def _flatten(doc: dict[str, Any], prefix: str = "") -> list[tuple[str, Any]]:
    rows: list[tuple[str, Any]] = []
    for key, value in doc.items():
        if isinstance(value, dict):
            rows += _flatten(value, f"{prefix}{key}.")
        else:
            rows.append((f"{prefix}{key}", value))
    return rows


def link_table(doc: dict[str, Any], title: str | None = "command link counters") -> Table:
    """Host and device counters side by side."""
    table = Table(title=title, box=box.SIMPLE_HEAVY, show_edge=False, title_justify="left")
    table.add_column("host", style="dim")
    table.add_column("", justify="right")
    table.add_column("device", style="dim")
    table.add_column("", justify="right")
    host = _flatten(doc.get("host") or {})
    device_doc = doc.get("device")
    device = _flatten(device_doc) if isinstance(device_doc, dict) else [("(disconnected)", None)]
    for (hk, hv), (dk, dv) in zip_longest(host, device, fillvalue=("", "")):
        table.add_row(hk, cell(hv) if hk else "", dk, cell(dv) if dk else "")
    return table


def telemetry_table(doc: dict[str, Any], title: str | None = "telemetry") -> Table:
    """Latest value of every channel with its unit and limit state."""
    table = Table(title=title, box=box.SIMPLE_HEAVY, show_edge=False, title_justify="left")
    table.add_column("channel")
    table.add_column("value", justify="right")
    table.add_column("unit")
    table.add_column("limit")
    table.add_column("time")
    latest = doc.get("latest") or {}
    for name, sample in latest.items():
        table.add_row(
            name,
            fmt_value(sample.get("value")),
            fmt_value(sample.get("unit")) if sample.get("unit") else "",
            limit_text(sample.get("limit")),
            fmt_time(sample.get("t_s")),
        )
    table.caption = f"{fmt_value(doc.get('samples'))} samples archived in {doc.get('archive')}"
    table.caption_justify = "left"
    return table


def history_table(doc: dict[str, Any]) -> Table:
    """One channel's archived samples."""
    unit = doc.get("unit") or ""
    table = Table(
        title=f"{doc.get('channel')} history",
        box=box.SIMPLE_HEAVY,
        show_edge=False,
        title_justify="left",
    )
    table.add_column("time")
    table.add_column(f"value ({unit})" if unit else "value", justify="right")
    times = doc.get("t_s") or []
    values = doc.get("value") or []
    for t_s, value in zip(times, values, strict=False):
        table.add_row(fmt_time(t_s), fmt_value(value))
    table.caption = f"{len(values)} samples"
    table.caption_justify = "left"
    return table


def events_table(doc: dict[str, Any], title: str | None = "events") -> Table:
    """Events, newest last, level coloured."""
    table = Table(title=title, box=box.SIMPLE_HEAVY, show_edge=False, title_justify="left")
    table.add_column("time")
    table.add_column("level")
    table.add_column("source")
    table.add_column("message")
    for event in doc.get("events") or []:
        level = str(event.get("level", ""))
        table.add_row(
            fmt_time(event.get("t_s")),
            Text(level, style=LEVEL_STYLE.get(level.lower(), "")),
            cell(event.get("source")),
            cell(event.get("message")),
        )
    if not doc.get("events"):
        table.caption = "no events"
    return table


def _render_status(out: Console, doc: Any, args: argparse.Namespace) -> None:
    out.print(status_table(doc))


def _render_ping(out: Console, doc: Any, args: argparse.Namespace) -> None:
    out.print(ping_table(doc, title=f"ping: {args.count} x {args.size} B"))
    for reason in doc.get("errors") or []:
        out.print(Text(f"  error: {reason}", style="red"))


def _render_link(out: Console, doc: Any, args: argparse.Namespace) -> None:
    out.print(link_table(doc))


def _render_telemetry(out: Console, doc: Any, args: argparse.Namespace) -> None:
    out.print(history_table(doc) if args.history is not None else telemetry_table(doc))


def _render_events(out: Console, doc: Any, args: argparse.Namespace) -> None:
    out.print(events_table(doc))


def _render_mode(out: Console, doc: Any, args: argparse.Namespace) -> None:
    out.print(Text.assemble("mode: ", (str(doc.get("mode")), "bold")))


def _render_reset(out: Console, doc: Any, args: argparse.Namespace) -> None:
    out.print("device reset")
    out.print(status_table(doc))


def control_text(doc: dict[str, Any]) -> Text:
    """``nobody`` or ``alice@pc1 since 12:03:04 (lease until 12:04:04)``, then what the holder
    says it is doing (``; doing: campaign x: step 3/12 ... (2/12)``); "you" marked."""
    holder = doc.get("holder")
    if holder is None:
        return Text("nobody (any client may change the camera)", style="green")
    until = doc.get("expires_t_s")
    why = f"{doc.get('why')}, until {fmt_time(until)}" if until else str(doc.get("why"))
    mine = holder == doc.get("you")
    activity = doc.get("activity")
    doing = ""
    if activity:
        done, total = activity.get("done"), activity.get("total")
        steps = f" ({done if done is not None else '?'}/{total})" if total is not None else ""
        doing = f"; doing: {activity.get('text')}{steps}"
    return Text.assemble(
        (str(holder), "bold green" if mine else "bold yellow"),
        " (you)" if mine else "",
        f" since {fmt_time(doc.get('since_t_s'))} ({why}){doing}",
    )


def _render_control(out: Console, doc: Any, args: argparse.Namespace) -> None:
    out.print(Text.assemble("control: ", control_text(doc)))


def estop_text(latch: dict[str, Any]) -> Text:
    """``LATCHED since 12:03:04 by alice@pc1 (stopped stage, wheel); release: ...`` in red, or
    ``released ...`` / ``not latched``."""
    if latch.get("latched"):
        stopped = ", ".join(latch.get("stopped") or []) or "nothing"
        failed = "; ".join(latch.get("failed") or [])
        return Text(
            f"LATCHED since {fmt_time(latch.get('since_t_s'))} by {latch.get('by')} (stopped "
            f"{stopped}" + (f"; could not stop {failed}" if failed else "") + "): nothing "
            f"moves or acquires; {latch.get('how_to_release')}",
            style="bold red",
        )
    if latch.get("released_t_s") is not None:
        return Text(
            f"not latched (released at {fmt_time(latch.get('released_t_s'))} by "
            f"{latch.get('released_by')})",
            style="green",
        )
    return Text("not latched", style="green")


def _render_estop(out: Console, doc: Any, args: argparse.Namespace) -> None:
    if args.action == "stop":
        out.print(
            Text(f"EMERGENCY STOP: stopped {', '.join(doc['stopped']) or 'nothing'}", "bold red")
        )
        doc = doc["latch"]
    out.print(Text.assemble("emergency stop: ", estop_text(doc)))


_RENDER: dict[str, Callable[[Console, Any, argparse.Namespace], None]] = {
    "status": _render_status,
    "ping": _render_ping,
    "link": _render_link,
    "telemetry": _render_telemetry,
    "events": _render_events,
    "mode": _render_mode,
    "reset": _render_reset,
    "control": _render_control,
    "estop": _render_estop,
    **camctl_sensor.RENDER,
    **camctl_stream.RENDER,
    **camctl_scan.RENDER,
    **camctl_motion.RENDER,
    **camctl_wheel.RENDER,
    **camctl_campaign.RENDER,
    **camctl_conform.RENDER,
}


if __name__ == "__main__":
    sys.exit(main())
