"""``camd bench motion``: what the live image motion measurement costs (issue 35, item 2).

The daemon's ``ImageMotionMonitor`` (camd.pipeline.image_motion) measures the image's motion
from blocks of the stream's TDI windows on its own thread, within a CPU budget
(``[motion] image_cpu_fraction`` of one core). Two parts:

- **cost**, in this process on one core: hr400 TDI windows of M rows x 2048 columns rendered
  by the simulated camera (``firmware_models.camera.CameraModel``: its own frame maker, so with
  its fixed pattern and temporal noise) on a textured, moving scene, at the frames the monitor
  takes (``_offsets(rows, frames_per_block)`` line periods after a block's first, the image
  moving one row per line period as at the synchronous speed), cut to the central
  ``columns_max`` columns as the monitor cuts them, and also whole. ``measure_tdi_motion`` is
  timed on each block with ``time.thread_time``, OpenCV and BLAS held to one thread. The
  baseline is the stream itself at hr400's fastest line period for M rows (``M x T_row``): the
  CPU per block over the time the block spans (``block_span_lines x M x T_row``, its first
  frame to the line after its last) is the fraction of one core measuring every block back to
  back would take. With the budget ``f`` the monitor starts a block no sooner than ``c / f``
  after the last one's frames were collected (a block of ``c`` CPU-seconds, measured on an idle
  core), so one block in every ``span + c / f`` seconds: the fraction of the stream's frames
  measured is ``frames_per_block x M x T_row / (span + c / f)``.
- **scan**, through the daemon: ``camd bench scan``'s scan (hr400, M = 96, the fastest line
  period, a frame bank of 512 frames: the stream's first 512 rendered frames, so the image
  moves within the bank and the blocks are measured on a moving scene) with the measurement
  off (A, ``[motion] image_measure = false``) and on (B), each run its own daemon, alternated
  A B, B A over ``--rounds``; the median of the rounds' B/A of lines/s and of the rate the
  stream's frames arrived at, with their ranges, against the goal (>= 0.95); never asserted.

bench/README.md says why each baseline is the fair one.
"""

from __future__ import annotations

import argparse
import importlib
import json
import statistics
import time
from collections.abc import Callable, Sequence
from typing import Any

from camd.bench.common import Alternation, alternate, int_list, machine
from camd.bench.scan import bench_scan

PROFILE = "hr400"
DEFAULT_STAGES = 96
DEFAULT_SCENE = "natural:photons=1e9,magnification_error=0.005,rotation_deg=0.3"
"""A textured scene whose image moves 1.005 rows and tan(0.3 deg) columns per line: what the
measurement is for (a flat scene would be 'not measurable' after the texture test, cheaper)."""
DEFAULT_BLOCKS = 2
DEFAULT_REPEAT = 3
DEFAULT_LINES = 5000
DEFAULT_ROUNDS = 3
DEFAULT_BANK = 512
GOAL_RATIO = 0.95
"""Scan ingest with the measurement on over off (issue 35, item 2)."""
T0_S = 0.05  # the first frame's row 0 ends its exposure here (the stage starts at 0)
PARTS = ("cost", "scan")


def add_options(p: argparse.ArgumentParser) -> None:
    """The options of ``camd bench motion`` but ``--json`` (camd.bench.command adds it). The
    monitor's settings default to the daemon's (``run`` reads them: importing the monitor here
    would load OpenCV for every ``camd bench``)."""
    p.add_argument(
        "--parts",
        type=_parts,
        default=PARTS,
        help="which parts: cost (in process, one core), scan (on vs off through the daemon)",
    )
    p.add_argument(
        "--stages", type=int, default=DEFAULT_STAGES, help=f"M = window rows ({DEFAULT_STAGES})"
    )
    p.add_argument(
        "--frames-per-block",
        type=int,
        default=None,
        help="[motion] image_frames_per_block, both parts (default: the daemon's, 16)",
    )
    p.add_argument(
        "--columns-max",
        type=int,
        default=None,
        help="[motion] image_columns_max, both parts (default: the daemon's, 512)",
    )
    p.add_argument(
        "--cpu-fraction",
        type=float,
        default=None,
        help="[motion] image_cpu_fraction: the budget, both parts (default: the daemon's, 0.25)",
    )
    p.add_argument(
        "--widths",
        type=lambda text: int_list(text, "widths"),
        default=None,
        help="cost: the columns to time, comma-separated (default: --columns-max and 2048)",
    )
    p.add_argument(
        "--blocks", type=int, default=DEFAULT_BLOCKS, help=f"cost: blocks ({DEFAULT_BLOCKS})"
    )
    p.add_argument(
        "--repeat",
        type=int,
        default=DEFAULT_REPEAT,
        help=f"cost: times each block is measured ({DEFAULT_REPEAT})",
    )
    p.add_argument("--scene", default=DEFAULT_SCENE, help=f"both parts ({DEFAULT_SCENE})")
    p.add_argument(
        "--lines", type=int, default=DEFAULT_LINES, help=f"scan: lines ({DEFAULT_LINES})"
    )
    p.add_argument(
        "--frame-bank",
        type=int,
        default=DEFAULT_BANK,
        help=f"scan: frames the simulator replays ({DEFAULT_BANK})",
    )
    p.add_argument(
        "--rounds", type=int, default=DEFAULT_ROUNDS, help=f"scan: rounds ({DEFAULT_ROUNDS})"
    )


def _parts(text: str) -> tuple[str, ...]:
    from camd.bench.common import choice_list

    return choice_list(text, PARTS, "part")


# -- cost, in process ------------------------------------------------------------------------


def one_thread() -> tuple[Callable[[], None], str]:
    """Hold OpenCV and BLAS to one thread, as the monitor's worker runs (OpenCV's remap would
    take every core; BLAS does the fit's small solves); a function that undoes it, and how
    BLAS was held."""
    import cv2

    before = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        # An optional dependency (blosc2 brings it); without it numpy is already imported and
        # the environment (OPENBLAS_NUM_THREADS) can no longer limit its BLAS.
        threadpoolctl: Any = importlib.import_module("threadpoolctl")
    except ImportError:
        limits = None
        how = "not limited (threadpoolctl is not installed)"
    else:
        limits = threadpoolctl.threadpool_limits(limits=1)
        how = "threadpoolctl.threadpool_limits(1)"

    def undo() -> None:
        cv2.setNumThreads(before)
        if limits is not None:
            limits.restore_original_limits()

    return undo, how


def _camera(stages: int, scene: str) -> Any:
    """The simulated hr400 with a window of ``stages`` rows on ``scene``, its stage at the
    synchronous speed (the image one row per TDI line period)."""
    from camd.sensor.profile import load_profile
    from camd.sensor.regmap import load_register_map
    from firmware_models.camera import CameraModel
    from firmware_models.sensor import SensorModel

    sensor = SensorModel(load_register_map(PROFILE))
    sensor.spi_write(sensor.regmap.register("WIN_ROWS").address, stages)
    camera = CameraModel(load_profile(PROFILE), sensor)
    camera.set_scene(scene)
    return camera


def block_figures(
    cpu_s_per_block: float,
    frames_per_block: int,
    span_lines: int,
    line_period_s: float,
    cpu_fraction: float,
) -> dict[str, float]:
    """What a block's CPU time means against the stream (module docstring, "cost"): per frame,
    the fraction of one core measuring every block back to back takes, and under the budget
    the blocks' period, the fraction of the stream's frames measured and the core used."""
    span_s = span_lines * line_period_s
    period_s = span_s + cpu_s_per_block / cpu_fraction
    return {
        "cpu_s_per_frame": cpu_s_per_block / frames_per_block,
        "block_span_s": span_s,
        "core_fraction_every_block": cpu_s_per_block / span_s,
        "budget_block_period_s": period_s,
        "budget_frames_measured_fraction": frames_per_block * line_period_s / period_s,
        "budget_core_fraction": cpu_s_per_block / period_s,
    }


def bench_cost(
    *,
    stages: int,
    frames_per_block: int,
    widths: Sequence[int],
    blocks: int,
    repeat: int,
    scene: str,
    cpu_fraction: float,
) -> dict[str, Any]:
    """The cost part (module docstring): figures per width."""
    import numpy as np

    from camd.analysis.image_motion import measure_tdi_motion
    from camd.pipeline.image_motion import _offsets  # the frames the monitor takes, its own

    camera = _camera(stages, scene)
    timing = camera.sensor.timing()
    row_s = float(timing.line_period_s)
    line_s = stages * row_s  # the fastest TDI line period M rows allow
    # The camera's stage keeps the image one row per its own frame period: render at it.
    render_s = float(timing.tdi_line_period_s)
    offsets = _offsets(stages, frames_per_block)
    span = offsets[-1] + 1
    counters = [b * span + k for b in range(blocks) for k in offsets]
    t0 = time.perf_counter()
    frames, _ = camera.render_block([T0_S + c * render_s for c in counters])
    render_wall_s = time.perf_counter() - t0
    rolling = camera.profile.shutter.value == "rolling"
    lag = row_s / render_s if rolling else 0.0  # as the monitor's, T_row / T_line
    n = len(offsets)
    columns = int(frames.shape[2])
    undo, blas = one_thread()
    cases = []
    try:
        for width in widths:
            w = min(width, columns)
            c0 = (columns - w) // 2
            # As the monitor hands a block over: one contiguous array, its frames as a list.
            cut = [
                np.ascontiguousarray(frames[b * n : (b + 1) * n, :, c0 : c0 + w])
                for b in range(blocks)
            ]
            cpu: list[float] = []
            motion = None
            for _ in range(repeat):
                for b, block in enumerate(cut):
                    c = time.thread_time()
                    motion = measure_tdi_motion(
                        list(block), counters[b * n : (b + 1) * n], row_lag_lines=lag
                    )
                    cpu.append(time.thread_time() - c)
            assert motion is not None
            per_block = statistics.median(cpu)
            cases.append(
                {
                    "columns": w,
                    "cpu_s_per_block": per_block,
                    "cpu_s_per_block_range": [min(cpu), max(cpu)],
                    **block_figures(per_block, n, span, line_s, cpu_fraction),
                    "measurable": motion.measurable,
                    "dv_over_v": motion.dv_over_v if motion.measurable else None,
                    "theta_deg": motion.theta_deg if motion.measurable else None,
                    "pairs": motion.pairs_used,
                }
            )
    finally:
        undo()
    return {
        "profile": PROFILE,
        "stages": stages,
        "frames_per_block": n,
        "offsets": list(offsets),
        "block_span_lines": span,
        "blocks": blocks,
        "repeat": repeat,
        "row_time_s": row_s,
        "line_period_s": line_s,
        "cpu_fraction": cpu_fraction,
        "scene": scene,
        "render_wall_s": render_wall_s,
        "threads": {"opencv": 1, "blas": blas},
        "widths": cases,
    }


# -- scan ingest, on against off ------------------------------------------------------------


def motion_config(measure: bool, frames_per_block: int, columns_max: int, cpu: float) -> str:
    """The daemon's ``[motion]`` section for a side: only ``image_measure`` differs."""
    return (
        "[motion]\n"
        f"image_measure = {'true' if measure else 'false'}\n"
        f"image_frames_per_block = {frames_per_block}\n"
        f"image_columns_max = {columns_max}\n"
        f"image_cpu_fraction = {cpu!r}\n"
    )


def bench_scan_on_off(
    *,
    stages: int,
    lines: int,
    frame_bank: int,
    rounds: int,
    scene: str,
    frames_per_block: int,
    columns_max: int,
    cpu_fraction: float,
) -> dict[str, Any]:
    """The scan part (module docstring): A = off, B = on, alternated."""
    runs: dict[bool, list[dict[str, Any]]] = {False: [], True: []}

    def side(measure: bool) -> Callable[[], float]:
        config = motion_config(measure, frames_per_block, columns_max, cpu_fraction)

        def one() -> float:
            doc = bench_scan(
                profile=PROFILE, stages=stages, lines=lines, frame_bank=frame_bank,
                scene=scene, extra_config=config,
            )  # fmt: skip
            runs[measure].append(doc)
            return float(doc["lines_per_s"])

        return one

    lines_alt = alternate(side(False), side(True), rounds)
    # The same runs' stream rates (the order of ``runs`` is the order of the rounds).
    stream_alt = Alternation(
        a=[float(d["stream_frames_per_s"]) for d in runs[False]],
        b=[float(d["stream_frames_per_s"]) for d in runs[True]],
    )

    def per_run(doc: dict[str, Any]) -> dict[str, Any]:
        motion = doc["image_motion"]
        elapsed = float(doc["elapsed_s"])
        blocks = int(motion["blocks_measured"])
        return {
            "lines_per_s": doc["lines_per_s"],
            "stream_frames_per_s": doc["stream_frames_per_s"],
            # Below 1 on both sides: the simulator (or the machine) set the pace, not the host.
            "stream_over_line_rate": doc["stream_rate_over_line_rate"],
            "lines": doc["lines"],
            "lost_frames": doc["lost_frames"],
            "overruns": doc["overruns"],
            "daemon_cpu_load": doc["daemon_cpu_load"],
            "sim_cpu_load": doc["sim_cpu_load"],
            "elapsed_s": elapsed,
            "blocks_measured": motion["blocks_measured"],
            "frames_measured": motion["frames_measured"],
            "tdi_frames_seen": motion["tdi_frames_seen"],
            "motion_cpu_s": motion["cpu_s"],
            # The monitor's own worker-thread CPU per block: against the cost part's one-core
            # figure it shows what the daemon's threads (BLAS's) add to each block.
            "motion_cpu_s_per_block": motion["cpu_s"] / blocks if blocks else None,
            "motion_cpu_load": motion["cpu_s"] / elapsed if elapsed else 0.0,
        }

    first = runs[False][0]
    return {
        "profile": PROFILE,
        "stages": stages,
        "lines": lines,
        "frame_bank": frame_bank,
        "rounds": rounds,
        "scene": scene,
        "line_rate_hz": first["line_rate_hz"],
        "goal_ratio": GOAL_RATIO,
        "lines_per_s": lines_alt.summary(),
        "stream_frames_per_s": stream_alt.summary(),
        "ratio": lines_alt.summary()["ratio"],
        "stream_ratio": stream_alt.summary()["ratio"],
        "meets_goal": lines_alt.ratio >= GOAL_RATIO,
        "off": [per_run(d) for d in runs[False]],
        "on": [per_run(d) for d in runs[True]],
    }


def run(args: argparse.Namespace) -> int:
    """``camd bench motion``: print the figures (one JSON document with --json)."""
    from camd.pipeline import image_motion

    if args.frames_per_block is None:
        args.frames_per_block = image_motion.FRAMES_PER_BLOCK
    if args.columns_max is None:
        args.columns_max = image_motion.COLUMNS_MAX
    if args.cpu_fraction is None:
        args.cpu_fraction = image_motion.CPU_FRACTION
    problems = []
    if args.stages < 1 or args.frames_per_block < 3 or args.columns_max < 16:
        problems.append("--stages >= 1, --frames-per-block >= 3, --columns-max >= 16")
    if not 0 < args.cpu_fraction <= 1:
        problems.append("0 < --cpu-fraction <= 1")
    if args.blocks < 1 or args.repeat < 1 or args.lines < 1 or args.rounds < 1:
        problems.append("--blocks, --repeat, --lines and --rounds >= 1")
    if args.frame_bank < 0:
        problems.append("--frame-bank >= 0")
    if problems:
        print(f"camd bench motion: give {'; '.join(problems)}")
        return 2
    doc: dict[str, Any] = {"machine": machine()}
    if "cost" in args.parts:
        widths = args.widths or (args.columns_max, 2048)
        doc["cost"] = bench_cost(
            stages=args.stages, frames_per_block=args.frames_per_block, widths=widths,
            blocks=args.blocks, repeat=args.repeat, scene=args.scene,
            cpu_fraction=args.cpu_fraction,
        )  # fmt: skip
    if "scan" in args.parts:
        doc["scan"] = bench_scan_on_off(
            stages=args.stages, lines=args.lines, frame_bank=args.frame_bank,
            rounds=args.rounds, scene=args.scene, frames_per_block=args.frames_per_block,
            columns_max=args.columns_max, cpu_fraction=args.cpu_fraction,
        )  # fmt: skip
    if args.json:
        print(json.dumps(doc))
    else:
        _print_human(doc)
    return 0


def _print_human(doc: dict[str, Any]) -> None:
    cost = doc.get("cost")
    if cost is not None:
        print(
            f"cost on one core (OpenCV 1 thread, BLAS {cost['threads']['blas']}): "
            f"{cost['profile']} M = {cost['stages']}, blocks of {cost['frames_per_block']} "
            f"frames spanning {cost['block_span_lines']} lines = "
            f"{cost['block_span_lines'] * cost['line_period_s'] * 1e3:.1f} ms at the fastest "
            f"line period {cost['line_period_s'] * 1e3:.3f} ms; {cost['blocks']} blocks x "
            f"{cost['repeat']}"
        )
        for c in cost["widths"]:
            dv = "-" if c["dv_over_v"] is None else f"{c['dv_over_v']:+.5f}"
            th = "-" if c["theta_deg"] is None else f"{c['theta_deg']:.3f}"
            print(
                f"  {c['columns']:>5} columns: {c['cpu_s_per_block'] * 1e3:.1f} ms per block "
                f"({c['cpu_s_per_block_range'][0] * 1e3:.1f}..."
                f"{c['cpu_s_per_block_range'][1] * 1e3:.1f}), "
                f"{c['cpu_s_per_frame'] * 1e3:.2f} ms per frame; every block back to back "
                f"{c['core_fraction_every_block']:.3f} of a core; at the budget "
                f"{cost['cpu_fraction']:g}: one block every "
                f"{c['budget_block_period_s'] * 1e3:.0f} ms, "
                f"{c['budget_frames_measured_fraction']:.3f} of the frames measured, "
                f"{c['budget_core_fraction']:.3f} of a core (dV/V {dv}, theta {th} deg)"
            )
    scan = doc.get("scan")
    if scan is not None:
        lines, stream = scan["lines_per_s"], scan["stream_frames_per_s"]
        verdict = "meets" if scan["meets_goal"] else "BELOW"
        print(
            f"scan {scan['profile']} M = {scan['stages']}, {scan['lines']} lines at "
            f"{scan['line_rate_hz']:.1f} Hz, bank {scan['frame_bank']}, {scan['rounds']} rounds: "
            f"lines/s on/off {scan['ratio']:.4f} (range {lines['ratio_range'][0]:.4f}.."
            f"{lines['ratio_range'][1]:.4f}; off {lines['a']:.1f}, on {lines['b']:.1f}) "
            f"{verdict} the goal >= {scan['goal_ratio']}; stream frames/s on/off "
            f"{scan['stream_ratio']:.4f} (range {stream['ratio_range'][0]:.4f}.."
            f"{stream['ratio_range'][1]:.4f})"
        )
        for name in ("off", "on"):
            for i, r in enumerate(scan[name]):
                print(
                    f"  {name:>3} run {i + 1}: {r['lines_per_s']:.1f} lines/s, stream "
                    f"{r['stream_frames_per_s']:.1f} frames/s ({r['stream_over_line_rate']:.3f} "
                    f"of the line rate), lost {r['lost_frames']}, "
                    f"overruns {r['overruns']}, daemon CPU {r['daemon_cpu_load']:.2f} core; "
                    f"{r['blocks_measured']} blocks, {r['frames_measured']} of "
                    f"{r['tdi_frames_seen']} frames measured, {r['motion_cpu_s']:.2f} CPU-s "
                    f"({r['motion_cpu_load']:.3f} core"
                    + (
                        f", {r['motion_cpu_s_per_block'] * 1e3:.1f} ms per block)"
                        if r["motion_cpu_s_per_block"] is not None
                        else ")"
                    )
                )
