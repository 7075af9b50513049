"""camctl's scan commands: ``scan`` and ``stages``.

    camctl scan --stages M --lines L [--scene SPEC] [--out FILE] [--speed-m-s V | --line-period-s T]
                [--mode sum|mean] [--out-bits n] [--rows-per-line r] [--cols-per-line c]
                [--reverse] [--binning] [--no-quicklook] [--detach]
                [--open-loop | --closed-loop] [--image-loop | --no-image-loop] [--dv-over-v X]
                [--no-stage]
    camctl scan --status | --stop
    camctl stages M                      change M of the running scan from its next frame

``scan`` waits for the scan to end, with a progress bar on stderr, and prints one document whose
first keys are the contract {"file", "lines", "complete_lines", "lost_frames", "stages"}, then
"mismatch_max" and "mismatch_rms" (M |dV/V| over the scan from the encoder, docs/motion.md); the
rest is the daemon's scan document, whose "image_motion" is the image's own dV/V, M dV/V and drift
angle measured from blocks of the scan's frames. It exits 1, saying why, when the scan did not end ``done``: failed,
ended early (the camera ended its stream before the scan's frames were all sent), or stopped
before its lines by someone else (a scan until stopped ends ``stopped`` as asked). The scan drives the stage at the synchronous speed (closed loop unless
--open-loop, or config motion.closed_loop = "off"); --no-stage leaves it alone. --image-loop trims
the line period and the drift taps from the image's own motion (docs/motion.md). Ctrl-C stops the scan (the file keeps what was taken).
FILE is written by the daemon, on its host: a relative FILE goes into its data directory's
``scans`` folder, an absolute one must be inside a directory it may write (docs/api.md, "Files");
``file`` is the absolute path the daemon answers.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from rich.console import Console
from rich.markup import escape
from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn

from camd.cli.camctl_args import count_arg, finite_number
from camd.cli.camctl_sensor import CommandFailed, UsageError
from camd.cli.camctl_stream import daemon_file, refuse_a_stop_of_nothing
from camd.client import CamdClient
from camd.client_types import ScanResponse

CONTRACT = (
    "file", "lines", "complete_lines", "lost_frames", "stages", "mismatch_max", "mismatch_rms",
)  # fmt: skip
POLL_S = 0.25


def add_parsers(command: Callable[[str, str], argparse.ArgumentParser]) -> None:
    """Add the scan commands through camctl's ``command(name, help)`` factory."""
    p = command("scan", "push-broom scan: stream in TDI mode, host TDI, lines to HDF5 + PNG")
    what = p.add_mutually_exclusive_group()
    what.add_argument("--status", action="store_true", help="show the current or last scan")
    what.add_argument("--stop", action="store_true", help="stop the running scan")
    p.add_argument("--stages", type=count_arg, metavar="M", help="TDI stages (1..window rows)")
    p.add_argument(
        "--lines", type=count_arg, metavar="L", help="complete TDI lines wanted (0 = until --stop)"
    )
    p.add_argument("--scene", metavar="SPEC", help="simulated camera: set this scene first")
    p.add_argument(
        "--out",
        type=Path,
        metavar="FILE",
        help="new HDF5 file on the daemon's host (relative: in its data directory's scans; "
        "default: scans/scan-<UTC>.h5 there)",
    )
    how = p.add_mutually_exclusive_group()
    how.add_argument(
        "--speed-m-s", type=finite_number, metavar="V", help="stage speed; sets the line period"
    )
    how.add_argument(
        "--line-period-s", type=finite_number, metavar="T", help="TDI line period to set"
    )
    p.add_argument("--mode", choices=("sum", "mean"), default="sum", help="sum (eq 12) or mean")
    p.add_argument("--out-bits", type=count_arg, metavar="N", help="clip sums to 2^N - 1 (eq 12)")
    p.add_argument(
        "--rows-per-line", type=finite_number, default=1.0, metavar="R",
        help="rows the image moves per line: 2 = every other row, 1.02 = 2%% mismatch",
    )  # fmt: skip
    p.add_argument(
        "--cols-per-line", type=finite_number, default=0.0, metavar="C",
        help="columns of drift per line (tan of the drift angle)",
    )  # fmt: skip
    p.add_argument("--reverse", action="store_true", help="the scene moves from row 1 to row M")
    p.add_argument("--binning", action="store_true", help="FPGA-side 2x2 binning")
    p.add_argument("--no-quicklook", action="store_true", help="write no PNG quicklook")
    p.add_argument("--detach", action="store_true", help="start the scan and return at once")
    loop = p.add_mutually_exclusive_group()
    loop.add_argument("--open-loop", action="store_true", help="no closed-loop correction")
    loop.add_argument(
        "--closed-loop", action="store_true", help="closed loop even if off in config"
    )
    image = p.add_mutually_exclusive_group()
    image.add_argument(
        "--image-loop",
        action="store_true",
        help="trim the line period and the drift taps from the image's motion in the frames",
    )
    image.add_argument(
        "--no-image-loop", action="store_true", help="no image loop even if on in config"
    )
    p.add_argument(
        "--dv-over-v", type=finite_number, default=0.0, metavar="X",
        help="deliberate mismatch: the stage runs at (1 - X) x synchronous (e.g. 0.01)",
    )  # fmt: skip
    p.add_argument(
        "--no-stage", action="store_true",
        help="do not drive the scan stage (external stage; on the simulator an ideal one)",
    )  # fmt: skip

    p = command("stages", "change the TDI stage count of the running scan from its next frame")
    p.add_argument("stages", type=count_arg, metavar="M", help="new stage count")


def flat(doc: ScanResponse) -> dict[str, Any]:
    """The contract keys first, then the rest of the scan document."""
    out: dict[str, Any] = {key: doc[key] for key in CONTRACT}  # type: ignore[literal-required]
    out.update({k: v for k, v in doc.items() if k not in CONTRACT})
    return out


def cmd_scan(client: CamdClient, args: argparse.Namespace) -> Any:
    if args.stop:
        refuse_a_stop_of_nothing(client, ("scan",), "camctl scan --status")
        return flat(client.stop_scan())
    if args.status:
        return flat(client.scan())
    if args.stages is None or args.lines is None:
        raise UsageError("scan needs --stages M and --lines L (or --status / --stop)")
    if args.stages < 1:
        raise UsageError("--stages must be at least 1")
    out = None if args.out is None else daemon_file(args.out)
    doc = client.start_scan(
        args.stages,
        args.lines,
        out=out,
        scene=args.scene,
        speed_m_s=args.speed_m_s,
        line_period_s=args.line_period_s,
        mode=args.mode,
        out_bits=args.out_bits,
        rows_per_line=args.rows_per_line,
        cols_per_line=args.cols_per_line,
        reverse=args.reverse,
        binning="2x2" if args.binning else "off",
        quicklook=not args.no_quicklook,
        drive_stage=not args.no_stage,
        closed_loop=False if args.open_loop else True if args.closed_loop else None,
        image_loop=True if args.image_loop else False if args.no_image_loop else None,
        dv_over_v=args.dv_over_v,
    )
    if not args.detach:
        doc = _follow(client, doc)
    result = flat(doc)
    if args.detach:
        return result
    why = short_of(result)
    if why is not None:
        raise CommandFailed(result, why)
    return result


def short_of(doc: dict[str, Any]) -> str | None:
    """Why an ended scan is not what was asked for, None if it is: failed, ended early (the
    camera ended its stream), or stopped before its lines (by another client, an emergency
    stop); a scan until stopped ends stopped as asked."""
    state = doc["state"]
    if state == "done" or (state == "stopped" and not doc["lines_wanted"]):
        return None
    of = f" of {doc['lines_wanted']}" if doc["lines_wanted"] else ""
    counts = (
        f"{doc['lines']}{of} lines, {doc['not_sent_frames']} frames not sent, "
        f"{doc['lost_frames']} lost; {doc['file']} holds the lines that came"
    )
    if state == "failed":
        return f"the scan failed: {doc['error']}; {counts}"
    if state == "ended_early":
        return f"the scan ended early: {doc['error']}; {counts}"
    return f"the scan was stopped (by another client or an emergency stop): {counts}"


def _follow(client: CamdClient, doc: ScanResponse) -> ScanResponse:
    """Poll the scan until it ends, with a progress bar on stderr; Ctrl-C stops it."""
    err = Console(stderr=True)
    total = doc["frames_requested"] or None
    columns = [
        TextColumn("scan"),
        BarColumn(),
        TextColumn(
            "{task.completed:.0f}/{task.total} lines" if total else "{task.completed} lines"
        ),
        TextColumn("{task.fields[rate]}"),
        TimeRemainingColumn(),
    ]
    try:
        with Progress(*columns, console=err, transient=True, disable=not err.is_terminal) as bar:
            task = bar.add_task("scan", total=total, rate="")
            while doc["state"] in ("starting", "running"):
                time.sleep(POLL_S)
                doc = client.scan()
                rate = f"{doc['lines_per_s']:.0f} lines/s, {doc['lost_frames']} lost"
                bar.update(task, completed=doc["lines"], rate=rate)
    except KeyboardInterrupt:
        doc = client.stop_scan()
        err.print(f"scan stopped: {doc['lines']} lines in {doc['file']}", markup=False)
        raise
    return doc


def cmd_stages(client: CamdClient, args: argparse.Namespace) -> Any:
    if args.stages < 1:
        raise UsageError("stages must be at least 1")
    return flat(client.set_stages(args.stages))


COMMANDS: dict[str, Callable[[CamdClient, argparse.Namespace], Any]] = {
    "scan": cmd_scan,
    "stages": cmd_stages,
}


def render_scan(out: Console, doc: Any, args: argparse.Namespace) -> None:
    if doc["state"] == "none":
        out.print("no scan yet; start one with `camctl scan --stages M --lines L`")
        return
    bad = doc["lost_frames"] + doc["stream"]["overruns"] + doc.get("not_sent_frames", 0)
    colour = "red" if bad else "green"
    not_sent = f", {doc['not_sent_frames']} not sent" if doc.get("not_sent_frames") else ""
    out.print(
        f"scan {doc['state']}: [{colour}]{doc['lines']} lines, {doc['complete_lines']} complete, "
        f"{doc['lost_frames']} frames lost{not_sent}[/], M = {doc['stages']} ({doc['mode']}), "
        f"{doc['width']} columns"
    )
    timing = doc.get("timing")
    if timing:
        speed = timing["stage_speed_m_s"]
        stage = "unknown" if speed is None else f"{speed * 1e3:.6g} mm/s"
        out.print(
            f"line period {timing['tdi_line_period_s'] * 1e3:.6g} ms = {timing['n_lines']} rows "
            f"x {timing['row_period_s'] * 1e6:.4g} us + back path "
            f"{timing['back_path_s'] * 1e6:.4g} us; stage {stage} "
            f"(synchronous {timing['sync_speed_m_s'] * 1e3:.6g} mm/s)"
        )
    out.print(
        f"{doc['lines_per_s']:.0f} lines/s over {doc['elapsed_s']:.2f} s, CPU load "
        f"{doc['cpu_load']:.2f} core (TDI {doc['tdi_cpu_s']:.2f} s)"
    )
    motion = doc.get("motion")
    if motion:
        level = doc["mismatch_level"]
        colour = {"ok": "green", "yellow": "yellow", "red": "red"}.get(level, "white")
        worst = doc["mismatch_max"]
        rms = doc["mismatch_rms"]
        numbers = "no encoder data" if worst is None else f"max {worst:.3g}, rms {rms:.3g}"
        out.print(
            f"stage {motion['stage_speed_m_s'] * 1e3:.6g} mm/s, closed loop "
            f"{motion['closed_loop']} ({motion['loop_samples']} polls); "
            f"[{colour}]M |dV/V| {numbers} pixels ({level})[/]"
        )
        if motion["loop_error"]:
            out.print(f"[yellow]{escape(motion['loop_error'])}[/]")
    image = doc.get("image_motion")
    if image:
        out.print(image_motion_line(image), markup=False)
        if image.get("loop"):
            out.print(image_loop_line(image["loop"]), markup=False)
    if len(doc["stage_changes"]) > 1:
        changes = ", ".join(f"line {i}: M = {m}" for i, m in doc["stage_changes"])
        out.print(f"stage changes: {changes}", markup=False)
    if doc["file"]:
        out.print(
            f"file {doc['file']}" + (f", quicklook {doc['quicklook']}" if doc["quicklook"] else ""),
            markup=False,
        )
    if doc.get("error"):
        out.print(f"[red]error: {escape(doc['error'])}[/]")


def image_loop_line(loop: dict[str, Any]) -> str:
    """The scan's image loop, in one line."""
    text = (
        f"image loop: {loop['updates']} updates, line period {loop['line_period_s'] * 1e3:.6g} ms, "
        f"drift {loop['cols_per_line']:+.4g} columns/line"
    )
    if loop["limited"]:
        text += " (at its limit)"
    if loop["error"]:
        text += f"; {loop['error']}"
    return text


def image_motion_line(image: dict[str, Any]) -> str:
    """The scan's image motion from its frames (docs/motion.md), in one line."""
    head = f"image motion ({image['measurable_blocks']} of {image['blocks']} blocks measurable)"
    if image["dv_over_v_mean"] is None:
        latest = image["latest"]
        why = "no block measured yet" if latest is None else latest["why"]
        return f"{head}: {why}"
    sem = image["dv_over_v_sem"]
    spread = "" if sem is None else f" +- {sem:.2g}"
    return (
        f"{head}: dV/V {image['dv_over_v_mean']:+.4g}{spread}, "
        f"M dV/V {image['m_dv_over_v_mean']:+.3g} pixels, theta {image['theta_deg_mean']:+.3g} deg"
    )


RENDER: dict[str, Callable[[Console, Any, argparse.Namespace], None]] = {
    "scan": render_scan,
    "stages": render_scan,
}
