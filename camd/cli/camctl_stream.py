"""camctl's stream commands: ``stream``, ``stare`` and ``sim``.

    camctl stream [--frames N] [--mode area|tdi] [--stages M] [--binning]
                                        take N frames, print the ingest counters
    camctl stream --start [--frames N] | --stop | --status
    camctl stare --frames N --out FILE  record N area-mode frames to HDF5
    camctl sim scene SPEC               the simulated camera's scene (e.g. bars:lux=3)
    camctl sim stage --track | --speed-m-s V
    camctl sim stream                   what the simulator's stream engine did and injected
    camctl sim stage-faults [--error X] [--ripple X] [--jitter X] [--drift X] [--load X]
    camctl sim stage-truth              the stepper stage's true position, speed, missed steps

``stream`` and ``stare`` print one flat document: the counters (frames, lost, corrupt,
overruns, mpix_per_s, mbyte_per_s, ...) and the stream's geometry. A stream or stare that ends
before its frames all came (the camera ended it early or went away, its recording filled the
disk) is an error from the daemon: camctl says what happened and exits 1. A recording is written
by the daemon, on its host: a relative FILE goes into its data directory's ``recordings`` folder,
an absolute one must be inside a directory it may write (docs/api.md, "Files"); ``out`` is the
absolute path the daemon answers.
"""

from __future__ import annotations

import argparse
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

from rich.console import Console
from rich.markup import escape

from camd.cli.camctl_args import actions, count_arg, finite_number, number_within
from camd.cli.camctl_sensor import CommandFailed, NothingRunning, UsageError
from camd.client import CamdClient
from camd.client_types import StreamResponse

DEFAULT_FRAMES = 100
_HEADLINE = ("frames", "lost", "corrupt", "overruns", "mpix_per_s", "mbyte_per_s")


_speed = number_within(0.0, 10.0, "{text!r} is not a speed in m/s between 0 and 10")


def add_parsers(command: Callable[[str, str], argparse.ArgumentParser]) -> None:
    """Add the stream commands through camctl's ``command(name, help)`` factory."""
    p = command("stream", "take frames over the USB stream and show the ingest counters")
    what = p.add_mutually_exclusive_group()
    what.add_argument("--start", action="store_true", help="start streaming and return at once")
    what.add_argument("--stop", action="store_true", help="stop the stream")
    what.add_argument("--status", action="store_true", help="show the current or last stream")
    p.add_argument(
        "--frames",
        type=count_arg,
        default=None,
        metavar="N",
        help=f"frames to take (default {DEFAULT_FRAMES}; with --start, 0 = until --stop)",
    )
    _stream_options(p)
    p.add_argument(
        "--strict",
        action="store_true",
        help="exit 1 if any frame was lost, corrupt or overrun",
    )

    p = command("stare", "record area-mode (staring) frames to an HDF5 file")
    p.add_argument("--frames", type=count_arg, required=True, metavar="N", help="frames, >= 1")
    p.add_argument(
        "--out",
        type=Path,
        required=True,
        metavar="FILE",
        help="new HDF5 file on the daemon's host (relative: in its data directory's recordings)",
    )
    p.add_argument("--binning", action="store_true", help="FPGA-side 2x2 binning")

    p = command("sim", "the simulated camera's world: scene, stage, stream faults")
    action = actions(p, "sim_command")

    sp = action("scene", "set the scene, e.g. 'flat:photons=2e4', 'bars:lux=3', 'edge:angle_deg=5'")
    sp.add_argument("spec", metavar="SPEC")
    sp = action("stage", "the scan stage: track the synchronous speed or run at a set speed")
    how = sp.add_mutually_exclusive_group(required=True)
    how.add_argument("--track", action="store_true", help="follow the synchronous speed")
    how.add_argument("--speed-m-s", type=_speed, metavar="V", help="run at V m/s (0..10)")
    action("stream", "frames the simulator made, sent, and damaged on purpose (--inject)")
    sp = action("stage-faults", "the stepper stage's imperfections (as --inject stage_*)")
    for key, meaning in (
        ("error", "relative step-rate error, e.g. 0.005 (a clock 5000 ppm off)"),
        ("ripple", "relative amplitude of the periodic speed ripple, e.g. 0.01"),
        ("jitter", "relative RMS random speed jitter"),
        ("drift", "relative speed drift per second of running"),
        ("load", "load torque / pull-out torque (above 1 the motor misses steps)"),
    ):
        sp.add_argument(f"--{key}", type=finite_number, default=0.0, metavar="X", help=meaning)
    action("stage-truth", "the stepper stage's true position, speed and missed steps")


def _stream_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--mode", choices=("area", "tdi"), help="set this mode first")
    p.add_argument(
        "--stages",
        type=count_arg,
        metavar="M",
        help="TDI stages recorded with the frames (tdi mode; default: all window rows)",
    )
    p.add_argument("--binning", action="store_true", help="FPGA-side 2x2 binning")


def flat(doc: StreamResponse) -> dict[str, Any]:
    """The headline counters first, then the rest of the stream's counters and geometry."""
    stats = dict(doc["stats"])
    out: dict[str, Any] = {key: stats.pop(key) for key in _HEADLINE}
    out.update(stats)
    out.update({k: v for k, v in doc.items() if k != "stats"})
    return out


def refuse_a_stop_of_nothing(client: CamdClient, kinds: tuple[str, ...], show: str) -> None:
    """NothingRunning unless an acquisition of one of ``kinds`` runs: the daemon's stop answers
    the last one, which would read as if it had just been stopped."""
    running = client.status().get("acquisition")
    if running is None or not running["running"] or running["kind"] not in kinds:
        raise NothingRunning(f"nothing was running: no {kinds[0]} to stop (`{show}` shows the "
                             "last one)")  # fmt: skip


def cmd_stream(client: CamdClient, args: argparse.Namespace) -> Any:
    if args.stop:
        # What `stream --stop` stops: any acquisition but a scan (`camctl scan --stop`).
        refuse_a_stop_of_nothing(client, ("stream", "stare", "wheel"), "camctl stream --status")
        return flat(client.stop_stream())
    if args.status:
        return flat(client.stream())
    options = {
        "mode": args.mode,
        "stages": args.stages,
        "binning": "2x2" if args.binning else "off",
    }
    if args.start:
        return flat(client.start_stream(args.frames or 0, **options))
    frames = DEFAULT_FRAMES if args.frames is None else args.frames
    if frames < 1:
        raise UsageError("--frames must be at least 1 (use --start --frames 0 to stream on)")
    doc = flat(client.acquire(frames, **options))
    bad = doc["lost"] + doc["corrupt"] + doc["overruns"]
    if args.strict and bad:
        raise CommandFailed(
            doc,
            f"{doc['lost']} lost, {doc['corrupt']} corrupt, {doc['overruns']} overrun frames; "
            "check `camctl events` and the USB cabling, or raise [stream] queue_mb",
        )
    return doc


def daemon_file(path: Path) -> str:
    """A file for the daemon to write, as camctl sends it: ``~`` expanded; a relative path as
    given (the daemon takes it inside its data directory, whatever camctl's working directory
    is); an absolute one refused here already if it exists (UsageError)."""
    path = path.expanduser()
    # os.path.exists, not Path.exists: a name too long to stat is the daemon's to refuse.
    if path.is_absolute() and os.path.exists(path):
        raise UsageError(f"{path} already exists; choose another --out or remove it")
    return str(path)


def cmd_stare(client: CamdClient, args: argparse.Namespace) -> Any:
    if args.frames < 1:
        raise UsageError("--frames must be at least 1")
    record = daemon_file(args.out)
    doc = flat(
        client.acquire(
            args.frames, mode="area", binning="2x2" if args.binning else "off", record=record
        )
    )
    doc["out"] = doc["recording"]  # the absolute path the daemon wrote
    return doc


def cmd_sim(client: CamdClient, args: argparse.Namespace) -> Any:
    if args.sim_command == "scene":
        client.set_scene(args.spec)
        return {"scene": args.spec}
    if args.sim_command == "stage":
        if args.track:
            return client.set_stage(track=True)
        return client.set_stage(track=False, speed_m_s=args.speed_m_s)
    if args.sim_command == "stage-faults":
        faults = {k: getattr(args, k) for k in ("error", "ripple", "jitter", "drift", "load")}
        client.set_stage_faults(**faults)
        return {"stage_faults": faults}
    if args.sim_command == "stage-truth":
        return client.stage_truth()
    return client.sim_stream_stats()


COMMANDS: dict[str, Callable[[CamdClient, argparse.Namespace], Any]] = {
    "stream": cmd_stream,
    "stare": cmd_stare,
    "sim": cmd_sim,
}


# -- rendering ---------------------------------------------------------------------------------


def render_stream(out: Console, doc: Any, args: argparse.Namespace) -> None:
    state = "running" if doc["streaming"] else "ended"
    binned = ", 2x2 binned" if doc["binning"] == "2x2" else ""
    stages = f", M = {doc['stages']}" if doc["stages"] else ""
    geometry = (
        f"{doc['mode'] or '-'} mode, {doc['rows']} x {doc['cols']} x {doc['bits']} bit"
        f"{binned}{stages}, frame period {doc['frame_period_s'] * 1e3:.4g} ms"
    )
    out.print(f"stream {state}: {geometry}", markup=False)
    bad = doc["lost"] + doc["corrupt"] + doc["overruns"] + doc.get("frames_not_sent", 0)
    colour = "red" if bad else "green"
    not_sent = f", {doc['frames_not_sent']} not sent" if doc.get("frames_not_sent") else ""
    out.print(
        f"[{colour}]{doc['frames']} frames delivered[/], {doc['lost']} lost, "
        f"{doc['corrupt']} corrupt, {doc['short']} short, {doc['overruns']} overruns, "
        f"{doc['stalls']} stalls{not_sent}; {doc['mpix_per_s']:.1f} Mpix/s, "
        f"{doc['mbyte_per_s']:.1f} MB/s"
    )
    if doc.get("ended_early"):
        out.print(f"[red]ended early: {escape(doc['ended_early'])}[/]")
    if doc.get("out") or doc.get("recording"):
        out.print(f"recorded to {doc.get('out') or doc.get('recording')}", markup=False)


def render_sim(out: Console, doc: Any, args: argparse.Namespace) -> None:
    if args.sim_command == "scene":
        out.print(f"scene set: {doc['scene']}", markup=False)
    elif args.sim_command == "stage":
        sync = doc["sync_speed_m_s"]
        dv = (doc["speed_m_s"] - sync) / sync if sync else 0.0
        out.print(
            f"stage {'tracking' if doc['track'] else 'fixed'}: {doc['speed_m_s'] * 1e3:.6g} mm/s "
            f"(synchronous {sync * 1e3:.6g} mm/s, speed/sync - 1 = {dv:+.4g})"
        )
    elif args.sim_command == "stage-faults":
        out.print(
            "stage faults: " + ", ".join(f"{k} {v:g}" for k, v in doc["stage_faults"].items())
        )
    else:
        out.print(", ".join(f"{k} {v}" for k, v in doc.items()), markup=False)


RENDER: dict[str, Callable[[Console, Any, argparse.Namespace], None]] = {
    "stream": render_stream,
    "stare": render_stream,
    "sim": render_sim,
}
