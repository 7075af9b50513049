"""``camd bench scan``: does a push-broom scan keep up with the sensor's line rate?

A daemon on the simulated camera runs a scan at the fastest TDI line period a window of M rows
allows (``M x T_row``: the sensor's own line rate), through the whole chain: simulated FX3 ->
pyusb -> FrameStream (CRCs, counters) -> batches -> TDI engine -> HDF5. The baseline is the
line rate itself: the bench prints lines/s against it, the frames lost and overrun, and the CPU
the daemon and the simulator used (from /proc).

The simulator replays a bank of rendered frames (``[sim] frame_bank``): the host's work does
not depend on the pixels. ``--frame-bank 0`` renders every frame from the moving scene instead.
``--drive-stage`` drives the scan stage at the synchronous speed, closed loop, as a scan does by
default (the simulator then follows the stage's trims while it streams); a line period the stage
cannot follow is refused, so ``--line-period-s`` sets a longer one than the fastest.
``--compression`` names the scan file's compression (docs/stream.md, "Compression"; default:
the daemon's, Bitshuffle + LZ4); the file's size is reported.
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path
from typing import Any

from camd.bench.common import choice_list, proc_status_int
from camd.store.compression import FILTERS

DEFAULT_LINES = 5000
DEFAULT_STAGES = 96
DEFAULT_BANK = 64
DEFAULT_SCENE = "bars:lux=3"


def add_options(p: argparse.ArgumentParser) -> None:
    """The options of ``camd bench scan`` but ``--json`` (camd.bench.command adds it)."""
    p.add_argument("--profile", default="hr400", help="simulated camera profile (default hr400)")
    p.add_argument(
        "--stages", type=int, default=DEFAULT_STAGES, help=f"M = window rows ({DEFAULT_STAGES})"
    )
    p.add_argument("--lines", type=int, default=DEFAULT_LINES, help=f"lines ({DEFAULT_LINES})")
    p.add_argument(
        "--frame-bank", type=int, default=DEFAULT_BANK, help=f"frames replayed ({DEFAULT_BANK})"
    )
    p.add_argument(
        "--drive-stage",
        action="store_true",
        help="drive the scan stage at the synchronous speed, closed loop (default: leave it)",
    )
    p.add_argument(
        "--line-period-s",
        type=float,
        default=None,
        help="TDI line period (default: the fastest the window allows, M x T_row)",
    )
    p.add_argument(
        "--compression",
        type=lambda text: choice_list(text, tuple(FILTERS), "compression")[0],
        default=None,
        help=f"the scan file's compression: {', '.join(FILTERS)} (default: the daemon's)",
    )
    p.add_argument(
        "--scene",
        default=DEFAULT_SCENE,
        help=f"the simulator's scene, as [sim] scene takes it (default {DEFAULT_SCENE})",
    )


def _cpu_s(pid: int) -> float | None:
    """User + system CPU seconds of a process (Linux /proc), or None where there is none."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return None
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _children(pid: int) -> list[int]:
    kids: list[int] = []
    for task in Path(f"/proc/{pid}/task").glob("*"):
        try:
            kids += [int(x) for x in (task / "children").read_text().split()]
        except OSError:
            continue
    return kids


RSS_MARK_LINES = 5000
"""Lines at which the daemon's memory is noted, to compare with the end of a long scan."""


def bench_scan(
    *,
    profile: str,
    stages: int,
    lines: int,
    frame_bank: int,
    drive_stage: bool = False,
    line_period_s: float | None = None,
    compression: str | None = None,
    scene: str = DEFAULT_SCENE,
    extra_config: str = "",
) -> dict[str, Any]:
    """Run the scan and return the figures (see the module docstring). ``scene``: the
    simulator's (``[sim] scene``); ``extra_config``: TOML appended to the daemon's config (other
    sections than ``[sim]`` and ``[sensor]``: ``camd bench motion`` sets ``[motion]``)."""
    from camd.cli._daemon_proc import DaemonProcess, write_sim_config
    from camd.client import CamdClient

    with tempfile.TemporaryDirectory(prefix="camd-bench-scan-") as tmp:
        config = write_sim_config(Path(tmp), profile, frame_bank=frame_bank, scene=scene)
        if extra_config:
            with config.open("a", encoding="utf-8") as f:
                f.write("\n" + extra_config.rstrip("\n") + "\n")
        with DaemonProcess(tmp, extra_args=["--config", str(config)]) as daemon:
            client = CamdClient(daemon.url)
            client.wait_ready(60)
            row_s = float(client.timing()["line_period_s"])
            period_s = stages * row_s if line_period_s is None else line_period_s
            sims = _children(daemon.pid)
            before = [_cpu_s(daemon.pid), *(_cpu_s(p) for p in sims)]
            started = time.monotonic()
            # By default the stage is left alone (a frame bank's replayed frames cannot show
            # it): the pipeline is measured.
            client.start_scan(
                stages, lines, out=str(Path(tmp) / "scan.h5"), line_period_s=period_s,
                quicklook=False, drive_stage=drive_stage, compression=compression,
            )  # fmt: skip
            # Poll (as wait_scan does) and note the daemon's memory on the way: at
            # RSS_MARK_LINES lines, and its largest over the scan.
            deadline = started + 60 + 4 * (lines + stages) * period_s
            rss_mark: int | None = None
            rss_max = 0
            while True:
                doc = client.scan()
                rss = proc_status_int(daemon.pid, "VmRSS") or 0
                rss_max = max(rss_max, rss)
                if rss_mark is None and int(doc.get("lines") or 0) >= RSS_MARK_LINES:
                    rss_mark = rss
                if doc["state"] not in ("starting", "running"):
                    break
                if time.monotonic() > deadline:
                    raise RuntimeError(f"the scan did not end in {deadline - started:.0f} s")
                time.sleep(0.5)
            wall_s = time.monotonic() - started
            rss_end = proc_status_int(daemon.pid, "VmRSS")
            rss_peak = proc_status_int(daemon.pid, "VmHWM")
            after = [_cpu_s(daemon.pid), *(_cpu_s(p) for p in sims)]
            sim_stats = client.sim_stream_stats()
            # The image motion monitor's counters (the daemon is this scan's alone, so they are
            # the scan's; 0 blocks with [motion] image_measure = false).
            motion = client.image_motion()
            client.close()
            file_bytes = (Path(tmp) / "scan.h5").stat().st_size

    def load(i: int) -> float | None:
        b, a = before[i], after[i]
        return None if a is None or b is None else (a - b) / wall_s

    rate_hz = 1.0 / float(doc["timing"]["tdi_line_period_s"]) if doc["timing"] else 0.0
    cols = int(doc["width"])
    stream = doc["stream"]
    stream_rate = (stream["frames"] - 1) / stream["elapsed_s"] if stream["elapsed_s"] else 0.0
    return {
        "profile": profile,
        "stages": stages,
        "width": cols,
        "lines": doc["lines"],
        "complete_lines": doc["complete_lines"],
        "lost_frames": doc["lost_frames"],
        "overruns": doc["stream"]["overruns"],
        "line_rate_hz": rate_hz,
        "lines_per_s": doc["lines_per_s"],
        "lines_per_s_over_line_rate": doc["lines_per_s"] / rate_hz if rate_hz else 0.0,
        # Frames as they arrived, first to last (the scan's own time adds start and finish).
        "stream_frames_per_s": stream_rate,
        "stream_rate_over_line_rate": stream_rate / rate_hz if rate_hz else 0.0,
        "input_mpix_per_s": doc["lines_per_s"] * stages * cols / 1e6,
        "daemon_cpu_load": doc["cpu_load"],
        "tdi_cpu_s": doc["tdi_cpu_s"],
        "tdi_cpu_load": doc["tdi_cpu_s"] / doc["elapsed_s"] if doc["elapsed_s"] else 0.0,
        "daemon_cpu_load_proc": load(0),
        "sim_cpu_load": load(1) if len(before) > 1 else None,
        "elapsed_s": doc["elapsed_s"],
        "frame_bank": frame_bank,
        "drive_stage": drive_stage,
        "sim": dict(sim_stats),
        "state": doc["state"],
        # The image motion monitor's counters (GET /api/v1/live/motion).
        "image_motion": {
            "enabled": motion["enabled"],
            "blocks_measured": motion["blocks_measured"],
            "tdi_frames_seen": motion["tdi_frames_seen"],
            "frames_measured": motion["frames_measured"],
            "cpu_s": motion["cpu_s"],
        },
        "image_motion_latest": motion["latest"],  # the newest block measured, or None
        "scene": scene,
        "compression": compression or "the daemon's",
        "file_bytes": file_bytes,
        # The daemon's resident memory (KiB): at RSS_MARK_LINES lines (None if the scan was
        # shorter), the largest seen while polling, at the end, and the kernel's peak.
        "daemon_rss_kib": {
            f"at_{RSS_MARK_LINES}_lines": rss_mark,
            "max_polled": rss_max,
            "end": rss_end,
            "peak": rss_peak,
        },
        "loadavg": list(os.getloadavg()),
    }


def run(args: argparse.Namespace) -> int:
    """``camd bench scan``: print the figures (one JSON document with --json)."""
    if args.stages < 1 or args.lines < 1 or args.frame_bank < 0:
        print("camd bench scan: --stages and --lines must be >= 1, --frame-bank >= 0")
        return 2
    if args.line_period_s is not None and not args.line_period_s > 0:
        print("camd bench scan: --line-period-s must be > 0 (seconds)")
        return 2
    result = bench_scan(
        profile=args.profile,
        stages=args.stages,
        lines=args.lines,
        frame_bank=args.frame_bank,
        drive_stage=args.drive_stage,
        line_period_s=args.line_period_s,
        compression=args.compression,
        scene=args.scene,
    )
    if args.json:
        print(json.dumps(result))
        return 0
    print(
        f"scan {result['profile']} M = {result['stages']} x {result['width']}: "
        f"{result['lines']} lines ({result['complete_lines']} complete) in "
        f"{result['elapsed_s']:.2f} s = {result['lines_per_s']:.1f} lines/s against a line rate "
        f"of {result['line_rate_hz']:.1f} Hz (ratio {result['lines_per_s_over_line_rate']:.3f}; "
        f"frames arrived at {result['stream_frames_per_s']:.1f} /s, ratio "
        f"{result['stream_rate_over_line_rate']:.3f}), {result['input_mpix_per_s']:.1f} Mpix/s in"
    )
    sim = result["sim_cpu_load"]
    print(
        f"lost {result['lost_frames']}, overruns {result['overruns']}; CPU: daemon "
        f"{result['daemon_cpu_load']:.2f} core (TDI worker {result['tdi_cpu_load']:.3f}), "
        f"simulator {'?' if sim is None else f'{sim:.2f}'} core; the file "
        f"{result['file_bytes'] / 1e6:.1f} MB (compression: {result['compression']})"
    )
    rss = result["daemon_rss_kib"]
    mark = rss[f"at_{RSS_MARK_LINES}_lines"]
    print(
        f"daemon memory: {'-' if mark is None else f'{mark / 1024:.1f} MiB'} at "
        f"{RSS_MARK_LINES} lines, {rss['max_polled'] / 1024:.1f} MiB the most seen, "
        f"{(rss['end'] or 0) / 1024:.1f} MiB at the end, peak {(rss['peak'] or 0) / 1024:.1f} MiB"
    )
    return 0
