"""camctl's sensor commands: ``reg``, ``timing`` and ``train``.

    camctl reg read NAME|ADDR          one register and its fields
    camctl reg write NAME=VALUE ...    validate all, write in one burst, verify
    camctl reg dump                    every register
    camctl reg diff [FILE]             registers differing from reset (or from a saved FILE)
    camctl reg save FILE               save the configuration (TOML)
    camctl reg load FILE               write a saved configuration
    camctl timing                      line period, exposure, frame time from the registers
    camctl train                       train the LVDS link (exit 1 if it does not lock, or if
                                       the camera reports another sensor)

Saved configurations are files on the client's machine: the daemon sends and receives the
register values, camctl reads and writes the file.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from pathlib import Path
from typing import Any

from rich import box
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from camd.cli.camctl_args import actions
from camd.client import CamdClient
from camd.client_types import RegisterConfig
from camd.sensor.config_file import ConfigFileError, format_configuration, parse_configuration


class CommandFailed(Exception):
    """The daemon answered, but the outcome is a failure: show ``doc``, then exit ``status``
    (1 unless the command documents another, e.g. conform's 4)."""

    def __init__(self, doc: Any, message: str, status: int = 1) -> None:
        super().__init__(message)
        self.doc = doc
        self.message = message
        self.status = status


class UsageError(Exception):
    """A bad argument found after parsing (e.g. an unreadable FILE): exit 2."""


class NothingRunning(Exception):
    """A stop with nothing to stop: said so (not the last one shown as if just stopped), exit 1."""


def _assignment(text: str) -> tuple[str, int | str]:
    name, sep, value = text.partition("=")
    if not sep or not name or not value:
        raise argparse.ArgumentTypeError(
            f"{text!r} is not NAME=VALUE; e.g. WIN_ROWS=534, GAIN.analog=x2 or EXPOSURE=0x100"
        )
    try:
        return name.strip(), int(value.strip(), 0)
    except ValueError:
        return name.strip(), value.strip()  # an enum name; the daemon checks it


def add_parsers(command: Callable[[str, str], argparse.ArgumentParser]) -> None:
    """Add the sensor commands through camctl's ``command(name, help)`` factory."""
    p = command("reg", "read, write, dump, diff, save and load sensor registers")
    action = actions(p, "reg_command")

    sp = action("read", "read one register by name or address (e.g. WIN_ROWS, 0x11)")
    sp.add_argument("key", metavar="NAME|ADDR")
    sp = action("write", "write registers: all validated first, one burst, read back")
    sp.add_argument(
        "assignments",
        nargs="+",
        type=_assignment,
        metavar="NAME=VALUE",
        help="REG=VALUE, REG.field=VALUE or GROUP=VALUE (e.g. EXPOSURE=1000); integers in "
        "decimal or 0x hex, enum fields by name",
    )
    action("dump", "read every register")
    sp = action("diff", "registers that differ from their reset values, or from a saved FILE")
    sp.add_argument("file", nargs="?", type=Path, metavar="FILE")
    sp = action("save", "save the sensor configuration (RW and WO registers) to a TOML FILE")
    sp.add_argument("file", type=Path, metavar="FILE")
    sp = action("load", "write a configuration saved with `reg save` (all or nothing)")
    sp.add_argument("file", type=Path, metavar="FILE")

    command("timing", "line period, exposure and frame time set by the sensor's registers")
    command("train", "train the sensor's LVDS link now and show each lane")


# -- commands --------------------------------------------------------------------------------------


def _read_file(path: Path) -> RegisterConfig:
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise UsageError(
            f"cannot read {path}: {exc.strerror}; give a file saved by `camctl reg save`"
        ) from None
    try:
        sensor, registers = parse_configuration(text, source=str(path))
    except ConfigFileError as exc:
        raise UsageError(str(exc)) from None
    return {"sensor": sensor, "registers": registers}


def cmd_reg(client: CamdClient, args: argparse.Namespace) -> Any:
    action = args.reg_command
    if action == "read":
        return client.read_register(args.key)
    if action == "write":
        return client.write_registers(dict(args.assignments))
    if action == "dump":
        return client.registers()
    if action == "diff":
        if args.file is None:
            return client.diff_registers()
        saved = _read_file(args.file)
        doc = client.diff_registers(saved["registers"])
        if saved["sensor"] != doc["sensor"]:
            raise UsageError(
                f"{args.file} is for sensor {saved['sensor']!r}, the camera's is {doc['sensor']!r}"
            )
        return doc
    if action == "save":
        config = client.register_config()
        text = format_configuration(config["sensor"], config["registers"])
        try:
            args.file.write_text(text, encoding="utf-8")
        except OSError as exc:
            raise UsageError(f"cannot write {args.file}: {exc.strerror}") from None
        return {**config, "file": str(args.file)}
    if action == "load":
        return client.load_register_config(_read_file(args.file))
    raise AssertionError(action)


def cmd_timing(client: CamdClient, args: argparse.Namespace) -> Any:
    return client.timing()


def cmd_train(client: CamdClient, args: argparse.Namespace) -> Any:
    doc = client.train()
    if not doc["trained"]:
        unlocked = [str(lane["lane"]) for lane in doc["lane_results"] if not lane["locked"]]
        why = (
            f"lane(s) {', '.join(unlocked)} did not lock"
            if unlocked
            else f"{doc['bit_errors']} bit errors in the PRBS check"
        )
        raise CommandFailed(
            doc, f"LVDS training failed: {why}; check the sensor's supply and cabling, then retry"
        )
    return doc


COMMANDS: dict[str, Callable[[CamdClient, argparse.Namespace], Any]] = {
    "reg": cmd_reg,
    "timing": cmd_timing,
    "train": cmd_train,
}


# -- rendering ---------------------------------------------------------------------------------------


def _fields(fields: dict[str, Any]) -> str:
    return ", ".join(f"{k}={v}" for k, v in fields.items())


def register_table(title: str, registers: list[dict[str, Any]]) -> Table:
    table = Table(title=title, box=box.SIMPLE_HEAD)
    for column in ("address", "name", "value", "fields"):
        table.add_column(column, justify="right" if column in ("address", "value") else "left")
    for r in registers:
        table.add_row(
            f"0x{r['address']:02X}", r["name"], f"0x{r['value']:04X} ({r['value']})",
            _fields(r["fields"]),
        )  # fmt: skip
    return table


def render_reg(out: Console, doc: Any, args: argparse.Namespace) -> None:
    action = args.reg_command
    if action == "read":
        out.print(register_table(doc["name"], [doc]))
    elif action == "write":
        out.print(register_table(f"written to {doc['sensor']} (read back)", doc["written"]))
    elif action == "dump":
        out.print(
            register_table(f"{doc['sensor']} registers (via {doc['bridge']})", doc["registers"])
        )
    elif action == "diff":
        if not doc["differences"]:
            out.print(f"no differences from {doc['against']}", markup=False)
            return
        table = Table(title=f"differences from {doc['against']}", box=box.SIMPLE_HEAD)
        for column in ("address", "name", "expected", "actual"):
            table.add_column(column)
        for d in doc["differences"]:
            table.add_row(f"0x{d['address']:02X}", d["name"], f"0x{d['expected']:04X}",
                          f"0x{d['actual']:04X}")  # fmt: skip
        out.print(table)
    elif action == "save":
        out.print(
            f"saved {len(doc['registers'])} {doc['sensor']} registers to {doc['file']}",
            markup=False,
        )
    elif action == "load":
        out.print(register_table(f"loaded into {doc['sensor']} (read back)", doc["written"]))


def render_timing(out: Console, doc: Any, args: argparse.Namespace) -> None:
    table = Table(title=f"{doc['sensor']} timing", box=box.SIMPLE_HEAD, show_header=False)
    table.add_column("key")
    table.add_column("value", justify="right")
    rows = [
        ("line period", f"{doc['line_period_s'] * 1e6:.4f} us"),
        ("window", f"rows {doc['window_start_row']}..{doc['window_start_row'] + doc['window_rows'] - 1}"
                   f" ({doc['window_rows']} rows)"),
        ("exposure", f"{doc['exposure_lines']} lines = {doc['exposure_s'] * 1e3:.6g} ms"),
        ("frame time (n+k+1)", f"{doc['frame_time_s'] * 1e3:.6g} ms"),
        ("frame period", f"{doc['frame_period_s'] * 1e3:.6g} ms"),
        ("back path", f"{doc['back_path_s'] * 1e6:.4g} us"),
        ("TDI line period", f"{doc['tdi_line_period_s'] * 1e3:.6g} ms"),
        ("max stages M0", str(doc["max_stages"])),
    ]  # fmt: skip
    for key in ("gain", "offset", "readout_mode", "test_pattern"):
        if doc.get(key) is not None:
            rows.append((key.replace("_", " "), str(doc[key])))
    for key, value in rows:
        table.add_row(key, value)
    out.print(table)


def render_train(out: Console, doc: Any, args: argparse.Namespace) -> None:
    if doc["interface"] != "lvds":  # no lanes: "0/0 lanes locked" would say nothing
        out.print(doc["summary"], markup=False)
        return
    verdict = "[bold green]trained[/]" if doc["trained"] else "[bold red]NOT trained[/]"
    out.print(
        f"{escape(doc['sensor'])} {doc['interface']} link: {verdict}; "
        f"{doc['locked_lanes']}/{doc['lanes']}"
        f" lanes locked, {doc['bit_errors']} bit errors in {doc['verified_bits']} PRBS bits"
    )
    if doc["lane_results"]:
        table = Table(box=box.SIMPLE_HEAD)
        for column in ("lane", "tap", "eye (taps)", "slips", "shift", "locked"):
            table.add_column(column, justify="right")
        for lane in doc["lane_results"]:
            table.add_row(*(str(lane[k]) for k in ("lane", "tap", "eye_width", "slips", "shift")),
                          "yes" if lane["locked"] else "[red]no[/]")  # fmt: skip
        out.print(table)


RENDER: dict[str, Callable[[Console, Any, argparse.Namespace], None]] = {
    "reg": render_reg,
    "timing": render_timing,
    "train": render_train,
}
