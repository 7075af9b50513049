"""``camd bench live``: is acquisition slowed by live viewers?

One daemon on the simulated hr400 streams continuously (area mode, exposure 1 line: the
shortest frame period the window allows, ``rows`` line periods, so that its 2048 columns
come at the sensor's full pixel rate; the simulator replaying a bank of rendered
frames so that the host, not the renderer, is the limit). Rounds A (no viewer) and B (N viewers
on the live view) alternate on that one stream (A B, then B A, ...); in each the daemon's own
stream counters (GET /api/v1/stream) give the frames and bytes it received per second, and the
frames lost and overrun. The figure is the median over the rounds of B / A, with its spread.

Viewers:

- ``ws``: threads with the ``websockets`` client, each consuming the live WebSocket as a page
  does: JSON description, then the pixels, decoded to uint16, min and max for the contrast.
  They offer permessage-deflate as browsers do (``--no-deflate``: they do not).
- ``browser``: N pages of ``/live`` in Debian's chromium, driven by Playwright (a test extra:
  imported only then). Each page counts the frames it receives (``window.camdLive``); the
  bench reads the counts and does not listen to the pages' WebSocket (which would have the
  browser copy every frame to Playwright).

  With ``--transport QUERY`` (e.g. ``bin=4&compression=deflate``) they ask the daemon for
  that transport (docs/live-view.md, "Transport") and inflate what comes deflated.
- ``roi``: no viewer; B defines N regions of interest in the daemon (each 1/N of the window's
  columns and all its rows), which it measures on every frame (``camd.pipeline.roi``): the
  cost of ROI statistics at the stream's full rate (issue 34: four ROIs, B / A >= 0.95).

``--per-setting``: instead of A/B, the bytes a viewer is sent: one ``ws`` viewer at each
transport setting in turn (bin 1, 2, 4, 8 x compression none, deflate), on one stream, each for
``--seconds``: its frames and bytes (descriptions and pixels, as they leave the daemon) per
second, and the daemon's CPU. The issue's figure is at 534 x 2048 (``--rows 534``, hr400's full
window), where the live view keeps 20 frames a second.

A frame's cost to the stream does not depend on its pixels, and a viewer's only through their
number, so the frame bank's repeats change nothing measured.

CPUs (``--pin``, the default on a machine with two or more): the simulated camera is a process
on the host here, but the real one is not, so it gets CPU 0 to itself, as if it were outside
the PC, and the daemon and the viewers share the others, as they would on a test PC. Without
pinning, on two cores, a viewer's CPU is taken from the simulator, and B / A measures how
the simulator slows down, not the host's acquisition (``--no-pin`` shows it).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import statistics
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any
from urllib.parse import quote

from camd.bench.live_viewers import (
    LIVE_PAGE,
    LIVE_WS,
    BenchError,
    BrowserViewers,
    RoiViewers,
    Viewers,
    WsViewers,
    default_kind,
)

PROFILE = "hr400"  # the register names below are hr400's
DEFAULT_ROUNDS = 5
DEFAULT_SECONDS = 3.0
DEFAULT_VIEWERS = 3
DEFAULT_ROWS = 16
DEFAULT_BANK = 16
EXPOSURE_LINES = 1  # below the window's rows: frames follow each other every `rows` lines
SETTLE_S = 0.5  # before each measurement, after the viewers are up
GOAL = 0.95
PER_SETTING = [
    f"bin={b}&compression={c}" for b in (1, 2, 4, 8) for c in ("none", "deflate")
]  # --per-setting's transports, in the order of the table


def add_options(p: argparse.ArgumentParser) -> None:
    """The options of ``camd bench live`` but ``--json`` (camd.bench.command adds it)."""
    p.add_argument(
        "--rounds", type=int, default=DEFAULT_ROUNDS, help=f"A/B rounds ({DEFAULT_ROUNDS})"
    )
    p.add_argument(
        "--seconds",
        type=float,
        default=DEFAULT_SECONDS,
        help=f"measured time of each A and each B (default {DEFAULT_SECONDS:g})",
    )
    p.add_argument(
        "--viewers", type=int, default=DEFAULT_VIEWERS, help=f"viewers in B ({DEFAULT_VIEWERS})"
    )
    p.add_argument(
        "--viewer-kind",
        choices=("ws", "browser", "roi"),
        default=None,
        help="ws: WebSocket clients consuming frames as a page does; browser: pages of /live in "
        "chromium (Playwright); roi: no viewer, but --viewers ROIs measured by the daemon on "
        "every frame (each 1/N of the columns, all rows). Default: browser when chromium and "
        "playwright are found, else ws",
    )
    p.add_argument(
        "--rows",
        type=int,
        default=DEFAULT_ROWS,
        help=f"window rows x 2048 columns (default {DEFAULT_ROWS}: a frame rate above what the "
        "host can take)",
    )
    p.add_argument(
        "--frame-bank",
        type=int,
        default=DEFAULT_BANK,
        help=f"frames the simulator renders and replays ({DEFAULT_BANK})",
    )
    p.add_argument("--page", default=LIVE_PAGE, help=f"the page browser viewers open ({LIVE_PAGE})")
    p.add_argument(
        "--no-deflate",
        action="store_true",
        help="ws viewers do not offer permessage-deflate (browsers do)",
    )
    p.add_argument(
        "--transport",
        default="",
        metavar="QUERY",
        help="ws viewers ask for this transport, e.g. 'bin=4&compression=deflate&max_fps=10' "
        "(default: none asked: full frames, uncompressed)",
    )
    p.add_argument(
        "--per-setting",
        action="store_true",
        help="instead of A/B: one ws viewer at each transport setting (bin 1/2/4/8 x "
        "none/deflate) in turn, its frames and bytes per second (use --rows 534)",
    )
    p.add_argument(
        "--pin",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="the simulated camera on CPU 0 alone, the daemon and the viewers on the others, "
        "as on a test PC with the camera outside it (default: on with 2 CPUs or more)",
    )


def _descendants(pid: int) -> list[int]:
    from camd.bench.scan import _children

    out: list[int] = []
    for child in _children(pid):
        out += [child, *_descendants(child)]
    return out


def _pin(pid: int, cpus: set[int]) -> None:
    """Every thread of ``pid`` onto ``cpus`` (threads started later inherit it)."""
    for task in Path(f"/proc/{pid}/task").iterdir():
        with contextlib.suppress(ProcessLookupError, FileNotFoundError):
            os.sched_setaffinity(int(task.name), cpus)


def pin_cpus(daemon_pid: int) -> dict[str, list[int]]:
    """The simulated camera (the daemon's child processes) on CPU 0, the daemon and this
    process (the viewers, and the browser it starts later) on the others (module docstring)."""
    cpus = sorted(os.sched_getaffinity(0))
    if len(cpus) < 2:
        raise BenchError(f"--pin needs two CPUs or more, this process may use {cpus}; use --no-pin")
    camera, host = {cpus[0]}, set(cpus[1:])
    for pid in _descendants(daemon_pid):
        _pin(pid, camera)
    _pin(daemon_pid, host)
    _pin(os.getpid(), host)
    return {"camera": sorted(camera), "host": sorted(host)}


class _Cpu:
    """CPU seconds of the daemon, its simulator and the viewers (this process and, for browser
    viewers, the driver and chromium it started), read from /proc."""

    def __init__(self, daemon_pid: int) -> None:
        self.daemon_pid = daemon_pid

    def sample(self) -> dict[str, dict[int, float]]:
        from camd.bench.scan import _cpu_s

        daemon_tree = [self.daemon_pid, *_descendants(self.daemon_pid)]
        viewers = [p for p in _descendants(os.getpid()) if p not in daemon_tree]
        groups = {
            "daemon": [self.daemon_pid],
            "sim": daemon_tree[1:],
            "viewers": viewers,
        }
        sample: dict[str, dict[int, float]] = {}
        for name, pids in groups.items():
            sample[name] = {}
            for pid in pids:
                cpu = _cpu_s(pid)
                if cpu is not None:
                    sample[name][pid] = cpu
        own = os.times()
        sample["viewers"][os.getpid()] = own.user + own.system
        return sample

    @staticmethod
    def load(before: dict[str, dict[int, float]], after: dict[str, dict[int, float]],
             wall_s: float) -> dict[str, float]:  # fmt: skip
        """Cores used per group between two samples (processes present in both)."""
        return {
            name: round(
                sum(after[name][p] - before[name][p] for p in after[name] if p in before[name])
                / wall_s,
                3,
            )
            for name in before
        }


def _phase(client: Any, cpu: _Cpu, viewers: Viewers | None, seconds: float) -> dict[str, Any]:
    """One A (viewers None) or B phase: the daemon's ingest over ``seconds``."""
    if viewers is not None:
        viewers.attach()
    try:
        (viewers.pause if viewers is not None else time.sleep)(SETTLE_S)
        s0 = client.stream()
        c0 = cpu.sample()
        v0 = viewers.counts() if viewers is not None else []
        b0 = viewers.bytes() if isinstance(viewers, WsViewers) else []
        t0 = time.monotonic()
        (viewers.pause if viewers is not None else time.sleep)(seconds)
        s1 = client.stream()
        c1 = cpu.sample()
        v1 = viewers.counts() if viewers is not None else []
        b1 = viewers.bytes() if isinstance(viewers, WsViewers) else []
        wall_s = time.monotonic() - t0
    finally:
        if viewers is not None:
            viewers.detach()
    if not s1["streaming"]:
        raise BenchError("the stream stopped during the bench; see the daemon's log")
    a, b = s0["stats"], s1["stats"]
    span_s = b["elapsed_s"] - a["elapsed_s"]  # the daemon's clock, first to last frame
    frames = b["frames"] - a["frames"]
    if frames <= 0 or span_s <= 0:
        raise BenchError(f"the daemon received no frame in {seconds:g} s")
    return {
        "frames": frames,
        "frames_per_s": frames / span_s,
        "mbyte_per_s": (b["bytes"] - a["bytes"]) / span_s / 1e6,
        "lost": b["lost"] - a["lost"],
        "overruns": b["overruns"] - a["overruns"],
        "corrupt": b["corrupt"] - a["corrupt"],
        "short": b["short"] - a["short"],
        "seconds": span_s,
        "cpu_cores": _Cpu.load(c0, c1, wall_s),
        "viewer_frames_per_s": [
            round((n1 - n0) / wall_s, 2) for n0, n1 in zip(v0, v1, strict=True)
        ],
        # What each ws viewer was sent (descriptions and pixels, as they left the daemon).
        "viewer_bytes_per_s": [round((n1 - n0) / wall_s) for n0, n1 in zip(b0, b1, strict=True)],
    }


@contextlib.contextmanager
def _streaming(
    rows: int, frame_bank: int, pin: bool
) -> Iterator[tuple[Any, Any, dict[str, Any], dict[str, Any], dict[str, list[int]] | None]]:
    """A daemon on the simulated hr400 streaming ``rows`` x 2048 at the shortest frame period
    (module docstring), past the frame bank's rendering: (daemon, client, the stream's start
    document, the timing, the CPUs pinned or None). The stream is stopped on the way out."""
    from camd.cli._daemon_proc import DaemonProcess, write_sim_config
    from camd.client import CamdClient

    with tempfile.TemporaryDirectory(prefix="camd-bench-live-") as tmp:
        config = write_sim_config(Path(tmp), PROFILE, frame_bank=frame_bank, scene="bars")
        with DaemonProcess(tmp, extra_args=["--config", str(config)]) as daemon:
            client = CamdClient(daemon.url, timeout_s=60, client="camd bench live")
            try:
                client.wait_ready(60)
                pinned = pin_cpus(daemon.pid) if pin else None
                client.write_registers(
                    {"WIN_START": 0, "WIN_ROWS": rows, "EXPOSURE": EXPOSURE_LINES}
                )
                timing = client.timing()
                start = client.start_stream(0, mode="area")
                deadline = time.monotonic() + 60
                while client.stream()["stats"]["frames"] == 0:
                    if time.monotonic() > deadline:
                        raise BenchError("the stream delivered no frame within 60 s")
                    time.sleep(0.1)
                time.sleep(1.0)  # past the frame bank's rendering
                yield daemon, client, dict(start), dict(timing), pinned
                client.stop_stream()
            finally:
                client.close()


def _ws_url(daemon_url: str, transport: str) -> str:
    """The live WebSocket's URL with the token ($CAMD_TOKEN, which the daemon takes too) and
    ``transport`` (a query, e.g. ``bin=4&compression=deflate``)."""
    token = os.environ.get("CAMD_TOKEN", "")
    params = [f"token={quote(token, safe='')}"] if token else []
    params += [transport] if transport else []
    return (
        daemon_url.replace("http", "ws", 1) + LIVE_WS + ("?" + "&".join(params) if params else "")
    )


def bench_live(
    *,
    rounds: int = DEFAULT_ROUNDS,
    seconds: float = DEFAULT_SECONDS,
    viewers: int = DEFAULT_VIEWERS,
    viewer_kind: str | None = None,
    rows: int = DEFAULT_ROWS,
    frame_bank: int = DEFAULT_BANK,
    page: str = LIVE_PAGE,
    deflate: bool = True,
    transport: str = "",
    pin: bool | None = None,
    progress: Any = None,
) -> dict[str, Any]:
    """Run the bench and return its figures (module docstring). ``progress(text)``, if given,
    is called with a line per phase."""
    if pin is None:
        pin = len(os.sched_getaffinity(0)) >= 2
    why = "--viewer-kind " + viewer_kind if viewer_kind else ""
    if viewer_kind is None:
        viewer_kind, why = default_kind()
    token = os.environ.get("CAMD_TOKEN", "")  # the daemon takes it too (docs/config.md)
    query = f"?token={quote(token, safe='')}" if token else ""
    say = progress or (lambda text: None)
    load_before = os.getloadavg()[0]
    with _streaming(rows, frame_bank, pin) as (daemon, client, start, timing, pinned):
        group: Viewers | None = None
        try:
            if viewer_kind == "browser":
                # The page's own query (e.g. /live?bin=4: its transport) keeps the token's.
                joined = page + ("&" + query[1:] if query and "?" in page else query)
                group = BrowserViewers(daemon.url + joined, viewers)
            elif viewer_kind == "roi":
                group = RoiViewers(client, viewers, rows)
            else:
                group = WsViewers(_ws_url(daemon.url, transport), viewers, deflate=deflate)
            results = []
            for r in range(rounds):
                order = "AB" if r % 2 == 0 else "BA"
                phases: dict[str, dict[str, Any]] = {}
                for name in order:
                    say(f"round {r + 1}/{rounds}: {name}")
                    viewing = group if name == "B" else None
                    phases[name] = _phase(client, _Cpu(daemon.pid), viewing, seconds)
                results.append({
                    "round": r + 1, "order": order, "A": phases["A"], "B": phases["B"],
                    "ratio": phases["B"]["frames_per_s"] / phases["A"]["frames_per_s"],
                    "ratio_mbyte_s": phases["B"]["mbyte_per_s"] / phases["A"]["mbyte_per_s"],
                })  # fmt: skip
        finally:
            if group is not None:
                group.close()
    summary = _summary(
        results, start=start, timing=timing, kind=viewer_kind, why=why,
        viewers=viewers, seconds=seconds, frame_bank=frame_bank, deflate=deflate,
        loadavg=[load_before, os.getloadavg()[0]], pinned=pinned,
    )  # fmt: skip
    summary["transport"] = transport if viewer_kind == "ws" else None
    return summary


def bench_per_setting(
    *,
    seconds: float = DEFAULT_SECONDS,
    rows: int = DEFAULT_ROWS,
    frame_bank: int = DEFAULT_BANK,
    pin: bool | None = None,
    settings: list[str] | None = None,
    progress: Any = None,
) -> dict[str, Any]:
    """``--per-setting`` (module docstring): one ws viewer at each transport in turn."""
    if pin is None:
        pin = len(os.sched_getaffinity(0)) >= 2
    say = progress or (lambda text: None)
    rows_out = []
    with _streaming(rows, frame_bank, pin) as (daemon, client, start, timing, pinned):
        for transport in settings or PER_SETTING:
            say(f"transport {transport}")
            viewer = WsViewers(_ws_url(daemon.url, transport), 1, deflate=False)
            try:
                phase = _phase(client, _Cpu(daemon.pid), viewer, seconds)
            finally:
                viewer.close()
            rows_out.append(
                {
                    "transport": transport,
                    "viewer_frames_per_s": phase["viewer_frames_per_s"][0],
                    "viewer_bytes_per_s": phase["viewer_bytes_per_s"][0],
                    "ingest_frames_per_s": phase["frames_per_s"],
                    "lost": phase["lost"],
                    "daemon_cpu_cores": phase["cpu_cores"]["daemon"],
                }
            )
    rows_n, cols = int(start["rows"]), int(start["cols"])
    return {
        "per_setting": rows_out,
        "seconds": seconds,
        "stream": {
            "profile": PROFILE,
            "rows": rows_n,
            "cols": cols,
            "frame_period_s": float(start["frame_period_s"]),
            "line_period_s": float(timing["line_period_s"]),
        },
        "pinned": pinned,
        "cpus": os.cpu_count(),
    }


def render_per_setting(result: dict[str, Any]) -> str:
    """The table ``camd bench live --per-setting`` prints."""
    s = result["stream"]
    lines = [
        f"bytes a live viewer is sent: one ws viewer at each transport for {result['seconds']:g} "
        f"s; stream {s['profile']} {s['rows']} x {s['cols']}, "
        f"{1 / s['frame_period_s']:.0f} frames/s from the camera, the live view keeping 20",
        "",
        f"{'transport':<28} {'viewer fr/s':>11} {'MB/s':>8} {'kB/frame':>9} "
        f"{'MB/s at 20/s':>12} {'ingest fr/s':>12} {'daemon CPU':>10}",
    ]
    for r in result["per_setting"]:
        fps = r["viewer_frames_per_s"]
        per_frame = r["viewer_bytes_per_s"] / fps / 1e3 if fps else 0.0
        lines.append(
            f"{r['transport']:<28} {fps:>11.1f} {r['viewer_bytes_per_s'] / 1e6:>8.3f} "
            f"{per_frame:>9.1f} {per_frame * 20 / 1e3:>12.3f} {r['ingest_frames_per_s']:>12.1f} "
            f"{r['daemon_cpu_cores']:>10.2f}"
        )
    return "\n".join(lines)


def _summary(results: list[dict[str, Any]], *, start: dict[str, Any], timing: dict[str, Any],
             kind: str, why: str, viewers: int, seconds: float, frame_bank: int,
             deflate: bool, loadavg: list[float],
             pinned: dict[str, list[int]] | None) -> dict[str, Any]:  # fmt: skip
    ratios = [r["ratio"] for r in results]
    a_fps = statistics.median(r["A"]["frames_per_s"] for r in results)
    paced = 1.0 / float(start["frame_period_s"])
    rows, cols = int(start["rows"]), int(start["cols"])

    def median_of(phase: str, key: str) -> float:
        return statistics.median(float(r[phase][key]) for r in results)

    def median_cpu(phase: str, group: str) -> float:
        return round(statistics.median(float(r[phase]["cpu_cores"][group]) for r in results), 3)

    ratio = statistics.median(ratios)
    return {
        "viewer_kind": kind,
        "viewer_kind_why": why,
        "viewers": viewers,
        "deflate_offered": deflate if kind == "ws" else None,
        "rounds": len(results),
        "seconds": seconds,
        "stream": {
            "profile": PROFILE,
            "mode": start["mode"],
            "rows": rows,
            "cols": cols,
            "frame_bytes": 2 * rows * cols + 64,
            "exposure_lines": EXPOSURE_LINES,
            "line_period_s": float(timing["line_period_s"]),
            "frame_period_s": float(start["frame_period_s"]),
            "paced_frames_per_s": paced,
            "frame_bank": frame_bank,
        },
        # The host took less than the camera sent: its ingest, not the camera, is the limit.
        "host_bound": a_fps < 0.95 * paced,
        "a_frames_per_s": a_fps,
        "b_frames_per_s": median_of("B", "frames_per_s"),
        "a_mbyte_per_s": median_of("A", "mbyte_per_s"),
        "b_mbyte_per_s": median_of("B", "mbyte_per_s"),
        "ratio": ratio,
        "ratio_min": min(ratios),
        "ratio_max": max(ratios),
        "ratio_mbyte_s": statistics.median(r["ratio_mbyte_s"] for r in results),
        "goal": GOAL,
        "met": ratio >= GOAL,
        "lost": {p: sum(r[p]["lost"] for r in results) for p in "AB"},
        "overruns": {p: sum(r[p]["overruns"] for r in results) for p in "AB"},
        "viewer_frames_per_s": statistics.median(
            f for r in results for f in r["B"]["viewer_frames_per_s"]
        ),
        "cpu_cores": {p: {g: median_cpu(p, g) for g in ("daemon", "sim", "viewers")} for p in "AB"},
        "per_round": results,
        "loadavg": loadavg,  # 1-minute load average before and after the run
        "pinned": pinned,  # CPUs of the simulated camera and of the host's side, or None
        "cpus": os.cpu_count(),
    }


# -- the command ----------------------------------------------------------------------------


def render(result: dict[str, Any]) -> str:
    """The table ``camd bench live`` prints."""
    s = result["stream"]
    kind = result["viewer_kind"]
    what = (
        "WebSocket clients (websockets; permessage-deflate "
        + ("offered, as browsers do" if result["deflate_offered"] else "not offered")
        + ")"
        if kind == "ws"
        else "ROIs measured by the daemon on every frame (no viewer; 'viewer fr/s': frames "
        "measured)"
        if kind == "roi"
        else "chromium pages of the live page (Playwright)"
    )
    lines = [
        f"live viewers: {result['viewers']} {kind} viewers, {what}; {result['viewer_kind_why']}",
        f"stream: {s['profile']} {s['mode']} {s['rows']} x {s['cols']} "
        f"({s['frame_bytes'] / 1e3:.1f} kB frames), exposure {s['exposure_lines']} line, "
        f"frame period {s['frame_period_s'] * 1e6:.1f} us = {s['paced_frames_per_s']:.0f} "
        f"frames/s from the simulated camera (frame bank {s['frame_bank']}); "
        f"{result['rounds']} rounds of {result['seconds']:g} s, A/B alternated",
        (
            f"CPUs: the simulated camera on {result['pinned']['camera']}, the daemon and the "
            f"viewers on {result['pinned']['host']} (--pin)"
            if result["pinned"]
            else "CPUs: not pinned (--no-pin): the simulated camera shares them with the host"
        ),
        "",
        f"{'round':>5} {'order':>5} {'A fr/s':>8} {'A MB/s':>7} {'B fr/s':>8} {'B MB/s':>7} "
        f"{'B/A':>6} {'lost A/B':>9} {'ovr A/B':>8} {'viewer fr/s':>12} {'daemon CPU A/B':>15}",
    ]
    for r in result["per_round"]:
        a, b = r["A"], r["B"]
        views = b["viewer_frames_per_s"]
        lines.append(
            f"{r['round']:>5} {r['order']:>5} {a['frames_per_s']:>8.1f} {a['mbyte_per_s']:>7.1f} "
            f"{b['frames_per_s']:>8.1f} {b['mbyte_per_s']:>7.1f} {r['ratio']:>6.3f} "
            f"{a['lost']:>4}/{b['lost']:<4} {a['overruns']:>3}/{b['overruns']:<4} "
            f"{statistics.median(views) if views else 0:>12.1f} "
            f"{a['cpu_cores']['daemon']:>7.2f}/{b['cpu_cores']['daemon']:<7.2f}"
        )
    cpu = result["cpu_cores"]
    bound = (
        f"host-bound: A took {result['a_frames_per_s'] / s['paced_frames_per_s']:.0%} of the "
        "camera's rate"
        if result["host_bound"]
        else "not host-bound: the host kept up with the camera in A, so B/A shows only a "
        "slowdown below the camera's rate (fewer --rows make it host-bound)"
    )
    lines += [
        "",
        f"median A {result['a_frames_per_s']:.1f} frames/s {result['a_mbyte_per_s']:.1f} MB/s, "
        f"B {result['b_frames_per_s']:.1f} frames/s {result['b_mbyte_per_s']:.1f} MB/s; "
        f"lost A/B {result['lost']['A']}/{result['lost']['B']}, overruns "
        f"{result['overruns']['A']}/{result['overruns']['B']}; {bound}",
        f"CPU cores A -> B: daemon {cpu['A']['daemon']:.2f} -> {cpu['B']['daemon']:.2f}, "
        f"simulator {cpu['A']['sim']:.2f} -> {cpu['B']['sim']:.2f}, viewers "
        f"{cpu['B']['viewers']:.2f}; each viewer got {result['viewer_frames_per_s']:.1f} "
        "frames/s (median)",
        f"load average {result['loadavg'][0]:.2f} before, {result['loadavg'][1]:.2f} after "
        f"({result['cpus']} CPUs)",
        f"ratio B/A (frames/s): median {result['ratio']:.3f}, rounds {result['ratio_min']:.3f} "
        f".. {result['ratio_max']:.3f}; goal >= {result['goal']:g}: "
        + ("met" if result["met"] else "NOT met"),
    ]
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    """``camd bench live``: the table, or one JSON document with --json."""
    if args.rounds < 1 or args.viewers < 1 or not args.seconds > 0:
        print(
            "camd bench live: --rounds and --viewers must be >= 1, --seconds > 0", file=sys.stderr
        )
        return 2
    if not 1 <= args.rows <= 2048 or args.frame_bank < 0:
        print("camd bench live: --rows must be 1..2048, --frame-bank >= 0", file=sys.stderr)
        return 2
    if getattr(args, "transport", "") and (args.viewer_kind or "ws") != "ws":
        print("camd bench live: --transport goes with --viewer-kind ws", file=sys.stderr)
        return 2
    if not args.page.startswith("/"):
        print(f"camd bench live: --page must be a path such as {LIVE_PAGE}", file=sys.stderr)
        return 2

    from camd.cli._daemon_proc import DaemonStartError
    from camd.client import CamdError

    def progress(text: str) -> None:
        if not args.json:
            print(f"  {text}", file=sys.stderr, flush=True)

    per_setting = getattr(args, "per_setting", False)
    transport = getattr(args, "transport", "")
    try:
        if per_setting:
            result = bench_per_setting(
                seconds=args.seconds, rows=args.rows, frame_bank=args.frame_bank, pin=args.pin,
                progress=progress,
            )  # fmt: skip
        else:
            result = bench_live(
                rounds=args.rounds, seconds=args.seconds, viewers=args.viewers,
                viewer_kind=args.viewer_kind, rows=args.rows, frame_bank=args.frame_bank,
                page=args.page, deflate=not args.no_deflate, transport=transport,
                pin=args.pin, progress=progress,
            )  # fmt: skip
    except (BenchError, DaemonStartError, CamdError) as exc:
        print(f"camd bench live: {exc}", file=sys.stderr)
        return 1
    if args.json:
        print(json.dumps(result))
    else:
        print(render_per_setting(result) if per_setting else render(result))
    return 0
