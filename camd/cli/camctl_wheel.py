"""camctl's filter-wheel commands (docs/wheel.md, docs/physics.md §4).

    camctl wheel [status]                 speed, angle, compensation, camd's T_frame / T_delay
    camctl wheel speed DEG_S              turn at DEG_S deg/s (0 stops)
    camctl wheel compensation on|off      exposure delay compensation
    camctl wheel acquire --channels 0,4,8 [--passes N] [--exposure-ms X]
                         [--compensation on|off] [--out FILE] [--region ROW,ROWS,COL,COLS]
    camctl wheel azimuth [--channels 10,11,12] [--exposures-ms 3,15,60] [--step-deg 15]
    camctl wheel polarizer DEG|off        simulated camera: the reference polariser

Milliseconds are converted to seconds here, at the edge; the API and the JSON documents are SI
(angles in degrees). ``wheel azimuth`` is ``camd.motion.polarization_run``: it drives the
daemon through many acquisitions and shows a progress bar on stderr.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from pathlib import Path
from typing import Any

from rich import box
from rich.console import Console
from rich.markup import escape
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn
from rich.table import Table

from camd.cli.camctl_args import actions, number_within
from camd.cli.camctl_sensor import UsageError
from camd.cli.camctl_stream import daemon_file
from camd.client import CamdClient
from camd.client_types import WheelRegion
from camd.motion.polarization_run import (
    DEFAULT_EXPOSURES_S,
    DEFAULT_STEP_DEG,
    measure_polarization_azimuth,
)


def _number_list(kind: Callable[[str], Any], what: str) -> Callable[[str], list[Any]]:
    def parse(text: str) -> list[Any]:
        try:
            values = [kind(part) for part in text.split(",") if part.strip()]
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"{text!r} is not a comma-separated list of {what}"
            ) from None
        if not values:
            raise argparse.ArgumentTypeError(f"give at least one of {what}")
        return values

    parse.__name__ = "list"
    return parse


def _positive(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = -1.0
    if not value > 0 or value == float("inf"):
        raise argparse.ArgumentTypeError(f"{text!r} is not a number > 0")
    return value


_speed = number_within(0.0, 360.0, "{text!r} is not a speed in deg/s from 0 to 360")


def _on_off(text: str) -> bool:
    if text.lower() in ("on", "off"):
        return text.lower() == "on"
    raise argparse.ArgumentTypeError(f"{text!r} is not on or off")


def _region(text: str) -> WheelRegion:
    try:
        row, rows, col, cols = (int(part) for part in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"{text!r} is not ROW,ROWS,COL,COLS (four whole numbers, e.g. 4,8,512,1024)"
        ) from None
    if min(row, col) < 0 or min(rows, cols) < 1:
        raise argparse.ArgumentTypeError(f"{text!r}: ROW, COL >= 0 and ROWS, COLS >= 1")
    return {"row": row, "rows": rows, "col": col, "cols": cols}


def add_parsers(command: Callable[[str, str], argparse.ArgumentParser]) -> None:
    """Add ``wheel`` through camctl's ``command(name, help)`` factory."""
    p = command(
        "wheel",
        "the filter wheel: status, speed, delay compensation, acquisitions, azimuth measurement",
    )
    action = actions(p, "wheel_command", required=False)

    action("status", "speed, angle, compensation and camd's numbers for the exposure set now")
    sp = action("speed", "turn the wheel at a constant speed (0 stops it)")
    sp.add_argument("speed_deg_s", type=_speed, metavar="DEG_S", help="deg/s, 0 .. 360")
    sp = action("compensation", "exposure delay compensation (docs/physics.md §4 eq 5) on or off")
    sp.add_argument("on", type=_on_off, metavar="on|off")
    sp = action("acquire", "one frame through each channel per pass; imaging centre and mean")
    sp.add_argument(
        "--channels", type=_number_list(int, "channel numbers"), required=True,
        metavar="C,C,...", help="channels 0..12 in acquisition order, e.g. 0,4,8",
    )  # fmt: skip
    sp.add_argument("--passes", type=int, default=1, metavar="N", help="passes (default 1)")
    sp.add_argument("--exposure-ms", type=_positive, metavar="X",
                    help="set this exposure first (default: the registers')")  # fmt: skip
    sp.add_argument("--compensation", type=_on_off, metavar="on|off",
                    help="set delay compensation first (default: as it is)")  # fmt: skip
    sp.add_argument(
        "--out",
        type=Path,
        metavar="FILE",
        help="record the frames to a new HDF5 file on the daemon's host (relative: in its data "
        "directory's recordings)",
    )
    sp.add_argument("--region", type=_region, metavar="ROW,ROWS,COL,COLS",
                    help="report the mean of this region (default: the whole frame)")  # fmt: skip
    sp = action(
        "azimuth",
        "polarisation azimuth of the polarising channels with a rotating reference polariser, "
        "at several exposures, with and without delay compensation",
    )
    sp.add_argument("--channels", type=_number_list(int, "channel numbers"), metavar="C,C,...",
                    help="polarising channels (default: all of them)")  # fmt: skip
    sp.add_argument(
        "--exposures-ms", type=_number_list(_positive, "exposures in ms"), metavar="X,X,...",
        default=[e * 1e3 for e in DEFAULT_EXPOSURES_S],
        help="exposures in ms (default 3,15,60)",
    )  # fmt: skip
    sp.add_argument("--step-deg", type=_positive, default=DEFAULT_STEP_DEG, metavar="DEG",
                    help="reference polariser step (default 15: 0, 15, .. 345 deg)")  # fmt: skip
    sp = action("polarizer", "simulated camera: the reference polariser's axis, or off")
    sp.add_argument("angle", metavar="DEG|off", help="axis in deg (0 .. 360) or off")


def cmd_wheel(client: CamdClient, args: argparse.Namespace) -> Any:
    what = args.wheel_command or "status"
    if what == "status":
        return client.wheel()
    if what == "speed":
        return client.set_wheel_speed(args.speed_deg_s)
    if what == "compensation":
        return client.set_wheel_compensation(args.on)
    if what == "acquire":
        return _acquire(client, args)
    if what == "azimuth":
        return _azimuth(client, args)
    return _polarizer(client, args)


def _acquire(client: CamdClient, args: argparse.Namespace) -> Any:
    if not 1 <= args.passes <= 1000:
        raise UsageError(f"--passes must be from 1 to 1000, got {args.passes}")
    record = None if args.out is None else daemon_file(args.out)
    return client.wheel_acquire(
        args.channels,
        passes=args.passes,
        exposure_s=None if args.exposure_ms is None else args.exposure_ms * 1e-3,
        compensated=args.compensation,
        record=record,
        region=args.region,
    )


def _azimuth(client: CamdClient, args: argparse.Namespace) -> Any:
    err = Console(stderr=True)
    columns = [
        TextColumn("azimuth"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn("{task.fields[what]}"),
        TimeRemainingColumn(),
    ]
    with Progress(*columns, console=err, transient=True, disable=not err.is_terminal) as bar:
        task = bar.add_task("azimuth", total=None, what="")

        def progress(done: int, total: int, what: str) -> None:
            bar.update(task, completed=done, total=total, what=what)

        try:
            return measure_polarization_azimuth(
                client,
                channels=args.channels,
                exposures_s=[ms * 1e-3 for ms in args.exposures_ms],
                step_deg=args.step_deg,
                progress=progress,
            )
        except ValueError as exc:
            raise UsageError(str(exc)) from None


def _polarizer(client: CamdClient, args: argparse.Namespace) -> Any:
    if args.angle.lower() == "off":
        client.set_polarizer(None)
        return {"polarizer_deg": None}
    try:
        angle = float(args.angle)
    except ValueError:
        angle = -1.0
    if not 0.0 <= angle <= 360.0:
        raise UsageError(f"the polariser angle must be off or 0 .. 360 deg, got {args.angle!r}")
    client.set_polarizer(angle)
    return {"polarizer_deg": angle}


COMMANDS: dict[str, Callable[[CamdClient, argparse.Namespace], Any]] = {"wheel": cmd_wheel}


# -- rendering -----------------------------------------------------------------------------------


def _exposure_lines(out: Console, e: dict[str, Any]) -> None:
    out.print(
        f"exposure {e['exposure_lines']} lines = {e['exposure_s'] * 1e3:.6g} ms, window "
        f"{e['window_rows']} rows: T_frame = (n + k + 1) T_line = {e['frame_time_s'] * 1e3:.6g} "
        f"ms, T_delay = {e['delay_s'] * 1e3:.6g} ms"
    )
    if not e["fits"]:
        out.print(f"[red]does not fit:[/] {escape(e['refusal'])}")
        return
    out.print(
        f"compensation {'on' if e['compensated'] else 'off'}: delay after the entry pulse "
        f"{e['applied_delay_s'] * 1e3:.6g} ms, imaging centre {e['centre_offset_deg']:+.6f} deg "
        f"from the channel centre, +- {e['centre_error_deg']:.5f} deg (eq 8)"
    )


def render_wheel(out: Console, doc: Any, args: argparse.Namespace) -> None:
    what = args.wheel_command or "status"
    if what == "acquire":
        _render_acquire(out, doc)
    elif what == "azimuth":
        _render_azimuth(out, doc)
    elif what == "polarizer":
        angle = doc["polarizer_deg"]
        out.print(
            "reference polariser out" if angle is None else f"reference polariser {angle:g} deg"
        )
    else:
        _render_status(out, doc)


def _render_status(out: Console, doc: dict[str, Any]) -> None:
    speed = doc["speed_deg_s"]
    turning = (
        f"{speed:g} deg/s (one turn in {doc['period_s']:.4g} s)" if speed > 0 else "[red]stopped[/]"
    )
    channel = doc["channel"]
    at = "between channels" if channel is None else f"channel {channel}"
    out.print(
        f"wheel {escape(doc['wheel'])}: {turning}, angle {doc['angle_deg']:.4f} deg ({at}); "
        f"compensation [bold]{'on' if doc['compensation'] else 'off'}[/]"
    )
    out.print(
        f"T_center {doc['t_center_s'] * 1e3:g} ms, light window {doc['window_s'] * 1e3:g} ms; "
        f"FPGA: T_frame {doc['device_frame_time_s'] * 1e3:.6g} ms, "
        f"T_delay {doc['device_delay_s'] * 1e3:.6g} ms"
    )
    _exposure_lines(out, doc["exposure"])
    table = Table(box=box.SIMPLE_HEAVY, show_edge=False)
    table.add_column("ch", justify="right")
    table.add_column("name")
    table.add_column("band", no_wrap=True, overflow="ellipsis", max_width=24)
    table.add_column("centre (deg)", justify="right")
    table.add_column("polariser (deg)", justify="right")
    for c in doc["channels"]:
        axis = c["polarizer_deg"]
        table.add_row(
            str(c["channel"]), c["name"], c["band"], f"{c['centre_deg']:.4f}",
            "-" if axis is None else f"{axis:g}",
        )  # fmt: skip
    out.print(table)


def _render_acquire(out: Console, doc: dict[str, Any]) -> None:
    _exposure_lines(out, doc["exposure"])
    table = Table(
        title="frames (angles in deg, mean in DN)", title_justify="left",
        box=box.SIMPLE_HEAVY, show_edge=False,
    )  # fmt: skip
    for name in ("frame", "ch", "name", "start", "imaging centre", "offset", "header", "mean"):
        table.add_column(name, justify="right", no_wrap=True)
    for f in doc["frames"]:
        table.add_row(
            str(f["counter"]), str(f["channel"]), f["name"], f"{f['start_angle_deg']:.4f}",
            f"{f['centre_deg']:.4f} +- {f['centre_error_deg']:.4f}",
            f"{f['centre_offset_deg']:+.4f}", f"{f['header_centre_deg']:.4f}", f"{f['mean']:.3f}",
        )  # fmt: skip
    out.print(table)
    stats = doc["stream"]["stats"]
    colour = "red" if stats["lost"] + stats["corrupt"] + stats["overruns"] else "green"
    recording = doc["stream"]["recording"]
    out.print(
        f"[{colour}]{len(doc['frames'])} of {doc['stream']['frames_requested']} frames, "
        f"{stats['lost']} lost[/]" + (f"; recorded to {escape(recording)}" if recording else "")
    )


def _render_azimuth(out: Console, doc: dict[str, Any]) -> None:
    exposures = doc["exposure_ms"]
    table = Table(box=box.SIMPLE_HEAVY, show_edge=False, title_justify="left",
                  title="polarisation azimuth (deg) by exposure")  # fmt: skip
    table.add_column("compensation")
    table.add_column("ch", justify="right")
    for ms in exposures:
        table.add_column(f"{ms:g} ms", justify="right")
    table.add_column("spread", justify="right")
    for name in ("compensated", "uncompensated"):
        for channel, values in doc["azimuth_deg"][name].items():
            table.add_row(
                "on" if name == "compensated" else "off", channel,
                *(f"{v:.4f}" for v in values),
                f"{doc['spread_by_channel_deg'][name][channel]:.4f}",
            )  # fmt: skip
    out.print(table)
    for name in ("compensated", "uncompensated"):
        out.print(
            f"spread across exposures, {name}: {doc['spread_deg'][name]:.4f} deg "
            f"(predicted {doc['predicted_spread_deg'][name]:.4f} deg)"
        )


RENDER: dict[str, Callable[[Console, Any, argparse.Namespace], None]] = {"wheel": render_wheel}
