"""``camctl``: the command-line client of a running camd daemon.

    camctl [--url URL] [--token T] [--timeout S] <command> ... [--json]

With ``--json`` (before or after the command) every command prints exactly one JSON document on
stdout: the API's answer. Without it, readable tables. Errors go to stderr as
``camctl: error: <message>``; exit status 1 for an error reported by the daemon, 2 for a usage
error, 3 when no daemon answers at the URL. docs/cli.md describes every command.

This module holds the options every command takes, the parser that gathers the command groups,
and ``main``: one call, its document printed as JSON or as tables, errors to exit statuses. The
commands live in their groups, each with ``add_parsers``, ``COMMANDS`` and ``RENDER``:
``camctl_device`` (status, ping, link, telemetry, events, mode, reset, control, estop),
``camctl_sensor``, ``camctl_stream``, ``camctl_roi``, ``camctl_focus``, ``camctl_snapshot``,
``camctl_scan``, ``camctl_motion``, ``camctl_wheel``, ``camctl_campaign``, ``camctl_conform``; the
tables and value formats in ``camctl_format``.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from collections.abc import Callable, Sequence
from typing import Any

from rich.console import Console

import camd
from camd.cli import (
    camctl_campaign,
    camctl_conform,
    camctl_device,
    camctl_focus,
    camctl_motion,
    camctl_roi,
    camctl_scan,
    camctl_sensor,
    camctl_snapshot,
    camctl_stream,
    camctl_wheel,
)
from camd.cli.camctl_args import positive_float
from camd.cli.camctl_sensor import CommandFailed, NothingRunning, UsageError
from camd.client import DEFAULT_URL, CamdClient, CamdError, DaemonUnreachable
from camd.datafile import bounded

EXIT_OK = 0
EXIT_API_ERROR = 1
EXIT_USAGE = 2
EXIT_UNREACHABLE = 3


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
        type=positive_float,
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

    camctl_device.add_parsers(command)
    camctl_sensor.add_parsers(command)
    camctl_stream.add_parsers(command)
    camctl_roi.add_parsers(command)
    camctl_focus.add_parsers(command)
    camctl_snapshot.add_parsers(command)
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


_COMMANDS: dict[str, Callable[[CamdClient, argparse.Namespace], Any]] = {
    **camctl_device.COMMANDS,
    **camctl_sensor.COMMANDS,
    **camctl_stream.COMMANDS,
    **camctl_roi.COMMANDS,
    **camctl_focus.COMMANDS,
    **camctl_snapshot.COMMANDS,
    **camctl_scan.COMMANDS,
    **camctl_motion.COMMANDS,
    **camctl_wheel.COMMANDS,
    **camctl_campaign.COMMANDS,
    **camctl_conform.COMMANDS,
}

_RENDER: dict[str, Callable[[Console, Any, argparse.Namespace], None]] = {
    **camctl_device.RENDER,
    **camctl_sensor.RENDER,
    **camctl_stream.RENDER,
    **camctl_roi.RENDER,
    **camctl_focus.RENDER,
    **camctl_snapshot.RENDER,
    **camctl_scan.RENDER,
    **camctl_motion.RENDER,
    **camctl_wheel.RENDER,
    **camctl_campaign.RENDER,
    **camctl_conform.RENDER,
}


if __name__ == "__main__":
    sys.exit(main())
