"""camctl's motion commands: ``sync`` and ``stage`` (docs/motion.md).

    camctl sync [--line-period-s T | --speed-m-s V] [--stages M] [--binning]
    camctl stage [status]
    camctl stage enable | disable | stop | estop
    camctl stage run V                      hold a constant signed speed, m/s (0 stops)
    camctl stage move X [--speed-m-s V] [--no-wait]
    camctl stage home [--no-wait]

``sync --json`` prints one document whose first keys are the contract {"line_period_s",
"row_time_s", "n_lines", "back_path_s", "m0", "stages", "sync_speed", "step_rate_hz",
"dv_over_v", "m_dv_over_v"}.

``stage move`` and ``stage home`` start the motion (the request answers at once) and wait for
the stage to stand by polling its status (``CamdClient.wait_stage``), as long as the daemon's
estimate of the operation says, with a progress bar on stderr when it is a terminal. Ctrl-C
stops waiting, not the stage: it says so and how to stop it, and camctl exits with 130.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from typing import Any

from rich.console import Console
from rich.markup import escape
from rich.progress import BarColumn, Progress, TaskProgressColumn, TextColumn

from camd.cli.camctl_args import count_arg, finite_number, si_number
from camd.client import CamdClient
from camd.client_types import MotionStatus, StageOperationModel

SYNC_CONTRACT = (
    "line_period_s", "row_time_s", "n_lines", "back_path_s", "m0", "stages", "sync_speed",
    "step_rate_hz", "dv_over_v", "m_dv_over_v",
)  # fmt: skip
STAGE_ACTIONS = ("status", "enable", "disable", "run", "move", "stop", "home", "estop")


def add_parsers(command: Callable[[str, str], argparse.ArgumentParser]) -> None:
    """Add the motion commands through camctl's ``command(name, help)`` factory."""
    p = command(
        "sync", "open-loop scan synchronisation: line period, window, stage speed, step rate"
    )
    how = p.add_mutually_exclusive_group()
    how.add_argument("--line-period-s", type=finite_number, metavar="T", help="TDI line period")
    how.add_argument("--speed-m-s", type=finite_number, metavar="V", help="stage speed")
    p.add_argument(
        "--with-speed-m-s", type=finite_number, metavar="V", dest="with_speed",
        help="with --line-period-s: the stage speed actually set (its mismatch is reported)",
    )  # fmt: skip
    p.add_argument("--stages", type=count_arg, metavar="M", help="TDI stages (default M0)")
    p.add_argument("--binning", action="store_true", help="2x2 binning (pitch doubled)")

    p = command("stage", "the scan stage: status, enable, run, move, stop, home, estop")
    p.add_argument("action", nargs="?", default="status", choices=STAGE_ACTIONS)
    p.add_argument("value", nargs="?", type=si_number, metavar="X",
                   help="run: speed in m/s (signed); move: position in m from home")  # fmt: skip
    p.add_argument("--speed-m-s", type=si_number, metavar="V", help="move: cruise speed")
    p.add_argument("--no-wait", action="store_true", help="move/home: answer at once")


def cmd_sync(client: CamdClient, args: argparse.Namespace) -> Any:
    from camd.cli.camctl_sensor import UsageError

    speed = args.speed_m_s
    if args.with_speed is not None:
        if args.line_period_s is None:
            raise UsageError("--with-speed-m-s goes with --line-period-s")
        speed = args.with_speed
    doc = client.sync(
        line_period_s=args.line_period_s, speed_m_s=speed, stages=args.stages,
        binning=args.binning,
    )  # fmt: skip
    out: dict[str, Any] = {key: doc[key] for key in SYNC_CONTRACT}  # type: ignore[literal-required]
    out.update({k: v for k, v in doc.items() if k not in SYNC_CONTRACT})
    return out


def cmd_stage(client: CamdClient, args: argparse.Namespace) -> Any:
    from camd.cli.camctl_sensor import UsageError

    action = args.action
    if action in ("run", "move") and args.value is None:
        raise UsageError(f"stage {action} needs a value: " + (
            "the speed in m/s (signed)" if action == "run" else "the position in m from home"
        ))  # fmt: skip
    if action == "status":
        return client.motion()
    if action in ("enable", "disable"):
        return client.enable_stage(action == "enable")
    if action == "run":
        return client.run_stage(args.value)
    if action == "move":
        doc = client.move_stage(args.value, speed_m_s=args.speed_m_s, wait=False)
        return doc if args.no_wait else _follow(client, doc)
    if action == "stop":
        return client.stop_stage()
    if action == "home":
        doc = client.home_stage(wait=False)
        return doc if args.no_wait else _follow(client, doc)
    return client.estop_stage()


def _follow(client: CamdClient, doc: MotionStatus) -> MotionStatus:
    """Wait for the move or homing ``doc`` started, with a progress bar on stderr when it is
    a terminal; Ctrl-C stops the wait (the stage goes on) and says how to stop the stage."""
    err = Console(stderr=True)
    op = doc["operation"]
    columns = [
        TextColumn(f"stage {'home' if op is not None and op['kind'] == 'home' else 'move'}"),
        BarColumn(),
        TaskProgressColumn(),
        TextColumn("{task.fields[where]}"),
        TextColumn("{task.fields[left]}"),
    ]
    last = doc
    try:
        with Progress(*columns, console=err, transient=True, disable=not err.is_terminal) as bar:
            task = bar.add_task("stage", total=100.0, where="", left="")

            def progress(now: MotionStatus) -> None:
                nonlocal last
                last = now
                where, left, done = _progress_fields(now)
                bar.update(task, completed=100.0 * done, where=where, left=left)

            return client.wait_stage(doc, progress=progress)
    except KeyboardInterrupt:
        reading = last["reading"]
        err.print(
            f"stopped waiting; the stage keeps {reading['state']} (at "
            f"{reading['position_m'] * 1e3:.3f} mm when last seen): `camctl stage` shows it, "
            "`camctl stage stop` stops it",
            highlight=False,
        )
        raise


def _progress_fields(doc: MotionStatus) -> tuple[str, str, float]:
    """(position and target, time left, fraction done) of the operation in ``doc``."""
    reading, op = doc["reading"], doc["operation"]
    where = f"at {reading['position_m'] * 1e3:.3f} mm"
    if op is None:
        return where, "", 0.0
    if op["target_m"] is not None:
        where += f" -> {op['target_m'] * 1e3:.3f} mm"
    else:
        where += " -> home switch"
    left = f"{op['remaining_s']:.0f} s left" if op["active"] else "done"
    return where, left, op["fraction_done"]


COMMANDS: dict[str, Callable[[CamdClient, argparse.Namespace], Any]] = {
    "sync": cmd_sync,
    "stage": cmd_stage,
}


def render_sync(out: Console, doc: Any, args: argparse.Namespace) -> None:
    out.print(
        f"line period {doc['line_period_s'] * 1e3:.6g} ms = {doc['n_lines']} rows x "
        f"{doc['row_time_s'] * 1e6:.4g} us + back path {doc['back_path_s'] * 1e6:.4g} us; "
        f"M = {doc['stages']} of M0 = {doc['m0']}"
    )
    angular = doc.get("angular_velocity_rad_s")
    table = f" (table {angular:.6g} rad/s)" if angular is not None else ""
    out.print(
        f"synchronous stage speed {doc['sync_speed'] * 1e3:.6g} mm/s{table}, step rate "
        f"{doc['step_rate_hz']:.6g} Hz ({escape(doc['stage_profile'])}, image scale "
        f"{doc['image_scale']:g}, image {doc['image_speed_m_s'] * 1e3:.6g} mm/s)"
    )
    colour = "green" if doc["tolerance_ok"] else "red"
    out.print(
        f"stage at {doc['stage_speed_m_s'] * 1e3:.6g} mm/s: dV/V = {doc['dv_over_v']:+.4g}, "
        f"[{colour}]M dV/V = {doc['m_dv_over_v']:+.4g}[/] pixels of smear"
    )


def render_stage(out: Console, doc: Any, args: argparse.Namespace) -> None:
    r, lim = doc["reading"], doc["limits"]
    colour = "red" if r["state"] == "estop" else "green"
    out.print(
        f"stage {escape(doc['profile'])} ({doc['kind']}): [{colour}]{r['state']}[/]"
        f"{', homed' if r['homed'] else ', not homed'}"
        f"{'' if r['at_limit'] == 'none' else ', at the ' + r['at_limit'] + ' limit'}"
    )
    out.print(
        f"position {r['position_m'] * 1e3:.4f} mm (encoder {r['encoder_m'] * 1e3:.4f} mm), "
        f"speed {r['speed_m_s'] * 1e3:.5g} mm/s (encoder {r['encoder_speed_m_s'] * 1e3:.5g})"
    )
    out.print(
        f"limits {lim['low_m'] * 1e3:.1f} .. {lim['high_m'] * 1e3:.1f} mm, "
        f"{lim['max_speed_m_s'] * 1e3:.4g} mm/s, {lim['accel_m_s2']:.4g} m/s^2; closed loop "
        f"{doc['closed_loop']}, M |dV/V| limits {doc['yellow']:g} / {doc['red']:g}"
    )
    op = doc.get("operation")
    if op is not None and op["active"]:
        out.print(_operation_line(op))


def _operation_line(op: StageOperationModel) -> str:
    """``moving to 900.000 mm: 45 %, about 12 s left of 30 s`` for a running operation."""
    what = (
        "homing"
        if op["target_m"] is None
        else f"moving to {op['target_m'] * 1e3:.3f} mm at {op['speed_m_s'] * 1e3:.4g} mm/s"
    )
    return (
        f"{what}: {op['fraction_done'] * 100:.0f} %, about {op['remaining_s']:.0f} s left of "
        f"{op['expected_duration_s']:.3g} s (`camctl stage stop` stops it)"
    )


RENDER: dict[str, Callable[[Console, Any, argparse.Namespace], None]] = {
    "sync": render_sync,
    "stage": render_stage,
}
