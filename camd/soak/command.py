"""``camd soak``: a long mixed workload on a lossy line (a benchmark, not a test).

It starts its own ``camd serve --sim`` on loopback with line faults (bit errors, dropped frames
on the RS-422 link, frame faults on the USB stream), runs pings, telemetry and status reads,
register writes verified by read-back, short streams, stares recorded to HDF5 and re-checked
against the device's CRCs, short TDI scans and a quick campaign for ``--minutes``, and prints:
commands sent, failed and executed twice (the last from the simulated device's own count),
frames lost against frames injected, and the daemon's RSS, open file descriptors and threads
at the start (after a warm-up: one item of each kind, then the mix for ``--warmup-minutes``) and
at the end, with a sample every
``--sample-s``. The exit status is 0 whenever the soak ran, whatever the figures; a verdict
line per criterion says how they compare with what is expected. The workload itself is
``camd.soak.workload``; docs/cli.md describes every option and the JSON document.
"""

from __future__ import annotations

import argparse
import json
import math
import shutil
import sys
import tempfile
from pathlib import Path
from typing import Any

DEFAULT_MINUTES = 60.0
DEFAULT_WARMUP_MINUTES = 5.0
DEFAULT_BER = 1e-4
DEFAULT_DROP = 0.01
DEFAULT_FRAME_FAULTS = 0.002
DEFAULT_SAMPLE_S = 60.0

VERDICTS = (
    ("failed_commands_0", "failed commands = 0"),
    ("executed_twice_0", "commands executed twice = 0"),
    ("lost_equals_injected", "frames lost = frames injected"),
    ("rss_growth_below_5pct", "daemon RSS growth < 5 %"),
    ("fds_flat", "daemon open file descriptors flat"),
    ("threads_flat", "daemon threads flat"),
)


def _positive_or_zero(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not (math.isfinite(value) and value >= 0):
        raise argparse.ArgumentTypeError(f"must be a number >= 0, got {text}")
    return value


def _positive(text: str) -> float:
    value = _positive_or_zero(text)
    if value == 0:
        raise argparse.ArgumentTypeError("must be > 0")
    return value


def add_parser(sub: Any) -> None:
    """Register ``camd soak`` (called by camd.cli.camd_main)."""
    p: argparse.ArgumentParser = sub.add_parser(
        "soak",
        help="long mixed workload on a lossy simulated line: failures, losses, resources",
        description="Start the daemon on the simulated camera with a lossy line and run a mixed "
        "workload (pings, telemetry, register writes, streams, stares, scans, a campaign) for "
        "--minutes; print commands sent/failed/executed twice, frames lost against injected, "
        "and the daemon's RSS, file descriptors and threads at the start and the end. A "
        "benchmark: exit status 0 whenever it ran.",
    )
    p.add_argument(
        "--minutes", type=_positive_or_zero, default=DEFAULT_MINUTES, metavar="N",
        help=f"how long the mixed workload runs after the warm-up (default {DEFAULT_MINUTES:g}; "
        "a fraction is fine, 0 = the warm-up only)",
    )  # fmt: skip
    p.add_argument(
        "--warmup-minutes", type=_positive_or_zero, default=DEFAULT_WARMUP_MINUTES, metavar="W",
        help="after one item of each kind, run the mix this long before the start sample "
        f"(default {DEFAULT_WARMUP_MINUTES:g}: the daemon's RSS levels off in the first minutes)",
    )  # fmt: skip
    p.add_argument("--seed", type=int, default=0, help="seed of the mix and of the simulator (0)")
    p.add_argument(
        "--ber", type=_positive_or_zero, default=DEFAULT_BER,
        help=f"bit error rate on the command link (default {DEFAULT_BER:g})",
    )  # fmt: skip
    p.add_argument(
        "--drop", type=_positive_or_zero, default=DEFAULT_DROP,
        help=f"probability a command-link frame is dropped (default {DEFAULT_DROP:g})",
    )  # fmt: skip
    p.add_argument(
        "--frame-faults", type=_positive_or_zero, default=DEFAULT_FRAME_FAULTS, metavar="P",
        help="USB stream: probability of each of frame_drop, frame_corrupt, frame_short per "
        f"frame, and P/4 of frame_stall (default {DEFAULT_FRAME_FAULTS:g}; 0 = none)",
    )  # fmt: skip
    p.add_argument(
        "--inject", default="", metavar="SPEC",
        help="more simulator faults, key=value,... (docs/simulator.md), added to or overriding "
        "the above, e.g. garbage=0.001,delay_ms=2",
    )  # fmt: skip
    p.add_argument(
        "--sample-s", type=_positive, default=DEFAULT_SAMPLE_S, metavar="S",
        help=f"sample the daemon's resources every S seconds (default {DEFAULT_SAMPLE_S:g})",
    )  # fmt: skip
    p.add_argument(
        "--timeout", type=_positive, default=60.0, metavar="S",
        help="seconds to wait for each API answer (default 60)",
    )  # fmt: skip
    p.add_argument(
        "--out", type=Path, metavar="DIR",
        help="work directory (new or empty; default a temporary one): the daemon's data and "
        "log, recordings until checked, campaigns",
    )  # fmt: skip
    p.add_argument(
        "--keep", action="store_true", help="keep the work directory (removed by default)"
    )
    p.add_argument("--json", action="store_true", help="print one JSON document on stdout")
    edges = p.add_argument_group(
        "--edges", "the soak at the edges (root only): a small data disk filled and emptied, "
        "campaign jobs and emergency stops (docs/cli.md, camd soak --edges)"
    )  # fmt: skip
    edges.add_argument(
        "--edges", action="store_true",
        help="run the edge soak instead of the mixed workload on a lossy line",
    )  # fmt: skip
    edges.add_argument(
        "--disk-mb", type=int, default=64, metavar="MB",
        help="size of the tmpfs mounted as the daemon's data disk (default 64)",
    )  # fmt: skip
    edges.add_argument(
        "--estop-every-s", type=_positive, default=180.0, metavar="S",
        help="an emergency stop about every S seconds, inside a job's acquisition (default 180)",
    )  # fmt: skip
    edges.add_argument(
        "--disk-fills", type=int, default=2, metavar="N",
        help="how many times the data disk is filled and emptied (default 2)",
    )  # fmt: skip
    edges.add_argument(
        "--fill-hold-s", type=_positive, default=120.0, metavar="S",
        help="how long the disk stays full each time (default 120)",
    )  # fmt: skip


def run(args: argparse.Namespace) -> int:
    """``camd soak``: 0 if the soak ran (whatever the figures), 1 if it could not, 2 for bad
    options, 130 when interrupted."""
    from camd.soak.workload import Soak, SoakAborted, SoakSettings, build_inject

    try:
        inject = build_inject(args.ber, args.drop, args.frame_faults, args.inject)
    except ValueError as exc:
        print(f"camd soak: error: {exc}", file=sys.stderr)
        return 2
    if args.out is not None:
        out: Path = args.out
        if out.exists() and (not out.is_dir() or any(out.iterdir())):
            print(
                f"camd soak: error: --out {out}: exists and is not an empty directory; give a "
                "new or empty directory (it is removed afterwards unless --keep)",
                file=sys.stderr,
            )
            return 2
        try:
            out.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            print(f"camd soak: error: --out {out}: {exc.strerror or exc}", file=sys.stderr)
            return 2
        work = out.resolve()
    else:
        work = Path(tempfile.mkdtemp(prefix="camd-soak-"))
    if args.edges:
        return _run_edges(args, work)
    settings = SoakSettings(
        minutes=args.minutes, seed=args.seed, inject=inject, work_dir=work,
        sample_s=args.sample_s, timeout_s=args.timeout, warmup_minutes=args.warmup_minutes,
    )  # fmt: skip

    def progress(line: str) -> None:
        print(line, file=sys.stderr, flush=True)

    try:
        doc = Soak(settings, progress).run()
    except SoakAborted as exc:
        print(f"camd soak: error: {exc}", file=sys.stderr)
        if not args.keep:
            print(f"camd soak: the work directory {work} is kept for the log", file=sys.stderr)
        return 1
    doc["work_dir"] = str(work)
    doc["kept"] = bool(args.keep or doc["error"] or doc["commands"]["failed_checks"])
    if not doc["kept"]:
        shutil.rmtree(work, ignore_errors=True)
    if args.json:
        print(json.dumps(doc))
    else:
        render(doc)
    if doc["interrupted"]:
        return 130
    return 1 if doc["error"] else 0


def _run_edges(args: argparse.Namespace, work: Path) -> int:
    """``camd soak --edges`` (camd.soak.edges)."""
    from camd.soak.edges import EdgeSettings, EdgeSoak
    from camd.soak.workload import SoakAborted

    if args.disk_mb < 16 or args.disk_fills < 0:
        print(
            "camd soak: error: --disk-mb takes 16 or more (the daemon's files need room), "
            "--disk-fills 0 or more",
            file=sys.stderr,
        )
        return 2
    settings = EdgeSettings(
        minutes=args.minutes, seed=args.seed, work_dir=work, disk_mb=args.disk_mb,
        estop_every_s=args.estop_every_s, disk_fills=args.disk_fills,
        fill_hold_s=args.fill_hold_s, timeout_s=args.timeout,
    )  # fmt: skip

    def progress(line: str) -> None:
        print(line, file=sys.stderr, flush=True)

    try:
        doc = EdgeSoak(settings, progress).run()
    except SoakAborted as exc:
        print(f"camd soak --edges: error: {exc}", file=sys.stderr)
        return 1
    doc["work_dir"] = str(work)
    doc["kept"] = bool(args.keep or doc["error"] or not all(doc["verdict"].values()))
    if not doc["kept"]:
        shutil.rmtree(work, ignore_errors=True)
    if args.json:
        print(json.dumps(doc))
    else:
        render_edges(doc)
    if doc["interrupted"]:
        return 130
    return 1 if doc["error"] else 0


def render_edges(doc: dict[str, Any]) -> None:
    """The edge soak's figures and verdicts, on stdout."""
    c = doc["counts"]
    f = doc["files"]
    r = doc["requests"]
    print(
        f"camd soak --edges: {doc['seconds'] / 60:.1f} min, seed {doc['seed']}, data disk "
        f"{doc['disk_mb']} MiB"
    )
    if doc["interrupted"]:
        print("INTERRUPTED: the figures cover the run up to Ctrl-C")
    if doc["error"]:
        print(f"ERROR: {doc['error']}")
    print(
        f"emergency stops {c.get('estops', 0)} (during campaign jobs; {c.get('estop_checks', 0)} "
        f"checks that nothing moved, {c.get('refused_while_latched', 0)} wheel starts refused "
        f"while latched); jobs started {c.get('jobs_started', 0)}, resumed "
        f"{c.get('jobs_resumed', 0)}"
    )
    print(
        f"data disk filled {c.get('disk_filled', 0)} times and emptied {c.get('disk_emptied', 0)}; "
        f"recordings {c.get('recordings', 0)} ({c.get('recordings_ok', 0)} ok); jobs and "
        f"recordings refused or cut by the full disk: {c.get('refused_disk_full', 0)}"
    )
    print(
        f"requests {r['sent']}: {r['2xx']} 2xx, {r['4xx']} 4xx, {r['5xx']} 5xx, "
        f"{r['no_answer']} unanswered; error answers by code: "
        + (", ".join(f"{k} {v}" for k, v in doc["error_codes"].items()) or "none")
        + "; other counts: "
        + ", ".join(f"{k} {v}" for k, v in c.items() if k.startswith(("refused_", "jobs_")))
    )
    print(
        f"files: {f.get('checked', 0)} HDF5 files opened, {len(f.get('unopenable', []))} could "
        f"not be; journal entries left {len(f.get('journal_left', []))}"
    )
    print(
        f"daemon: crashes {doc['crashes']}, exit status {doc['daemon']['exit_code']}, "
        f"tracebacks in its log {doc['daemon']['tracebacks_in_log']}"
    )
    for line in doc["violations"][:20]:
        print(f"  VIOLATION: {line}")
    for line in f.get("unopenable", [])[:20]:
        print(f"  UNOPENABLE: {line}")
    names = {
        "crashes_0": "no crash",
        "motion_after_estop_0": "no motion after an emergency stop without a release",
        "files_openable": "every file openable",
        "no_internal_error": "no internal error (500) and no request unanswered",
    }
    for key, ok in doc["verdict"].items():
        print(f"{'PASS' if ok else 'FAIL'}: {names.get(key, key)}")
    print(f"work directory: {doc['work_dir']}{' (kept)' if doc['kept'] else ' (removed)'}")


def render(doc: dict[str, Any]) -> None:
    """The final table and the verdicts, on stdout."""
    w = doc["workload"]
    c = doc["commands"]
    f = doc["frames"]
    r = doc["resources"]
    print(
        f"camd soak: {doc['seconds'] / 60:.1f} min ({doc['warmup_s']:.0f} s warm-up), seed "
        f"{doc['seed']}, line faults {doc['inject'] or 'none'}"
    )
    if doc["interrupted"]:
        print("INTERRUPTED: the figures cover the run up to Ctrl-C")
    if doc["error"]:
        print(f"ERROR: {doc['error']}")
    print()
    print(f"{'workload':12} {'runs':>6} {'failed':>6} {'seconds':>9}")
    for kind, k in w["kinds"].items():
        print(f"{kind:12} {k['runs']:6d} {k['failed']:6d} {k['seconds']:9.1f}")
    print(f"{'all':12} {w['items']:6d} {sum(k['failed'] for k in w['kinds'].values()):6d}")
    print()
    ans = c["answered"]
    host = c["link_host"]
    dev = c["link_device"]
    print(
        f"commands: {c['sent']} API requests sent ({ans['2xx']} 2xx, {ans['4xx']} 4xx, "
        f"{ans['5xx']} 5xx, {ans['no_answer']} unanswered)"
    )
    print(
        f"  failed {c['failed']} (requests {c['failed_requests']}, workload checks "
        f"{c['failed_checks']}, device commands unanswered {c['device_unanswered']})"
    )
    print(
        f"  executed twice {_text(c['executed_twice'])} (the simulated device's count); device "
        f"commands {_text(c['device_commands'])}: link frames sent {host.get('sent', '?')}, "
        f"retries {host.get('retries', '?')}, timeouts {host.get('timeouts', '?')}; device "
        f"executed {dev.get('executed', '?')}, replayed {dev.get('replayed', '?')} from its record"
    )
    if c["recoveries"]:
        print(
            "  recoveries after a failure: "
            + ", ".join(f"{k} x{v}" for k, v in sorted(c["recoveries"].items()))
            + " (train: the sensor's LVDS link was found untrained)"
        )
    for error in c["errors"]:
        print(f"  error: {error}")
    print()
    h = f["host"]
    d = f["device"]
    print(
        f"frames: {f['acquisitions']} acquisitions, {f['requested']} frames asked for, "
        f"{f['delivered']} delivered"
    )
    print(
        f"  lost {f['lost']} (host: lost {h['lost']}, corrupt {h['corrupt']}, short "
        f"{h['short']}, overruns {h['overruns']}; stalls {h['stalls']}, out of order "
        f"{h['out_of_order']})"
    )
    print(
        f"  injected {_text(f['injected'])} (device: "
        + ", ".join(f"{k} {v}" for k, v in d.items() if k not in ("bytes_sent",))
        + f"): {'equal' if f['equal'] else 'NOT equal'}"
    )
    print()
    print(f"{'daemon':10} {'t (min)':>8} {'RSS (MB)':>9} {'fds':>5} {'threads':>8} {'items':>6}")
    for s in r["series"]:
        p = s["daemon"] or {}
        print(
            f"{s['what']:10} {s['t_min']:8.1f} {p.get('rss_kb', 0) / 1024:9.1f} "
            f"{p.get('fds', '?'):>5} {p.get('threads', '?'):>8} {s['items']:6d}"
        )
    g = r["growth_pct"]
    med = r["rss_median_kb"]
    rss_text = (
        f"{_pct(g['rss_kb'])} ({med['start'] / 1024:.1f} -> {med['end'] / 1024:.1f} MB, medians "
        f"of the first and last {r['rss_samples']} samples)"
        if med["start"] and med["end"]
        else _pct(g["rss_kb"])
    )
    print(
        f"growth start -> end: RSS {rss_text}, fds {_pct(g['fds'])}, threads {_pct(g['threads'])}"
    )
    sims = [s["simulator"] for s in r["series"] if s["simulator"]]
    if sims:
        print(
            f"simulator (for information): RSS {sims[0]['rss_kb'] / 1024:.1f} -> "
            f"{sims[-1]['rss_kb'] / 1024:.1f} MB, threads {sims[0]['threads']} -> "
            f"{sims[-1]['threads']}"
        )
    print()
    for key, text in VERDICTS:
        print(f"verdict: {text}: {'yes' if doc['verdict'][key] else 'NO'}")
    if doc["kept"]:
        print(f"work directory kept: {doc['work_dir']}; daemon log {doc['daemon']['log']}")
    else:
        print(f"work directory {doc['work_dir']} removed (--keep keeps it)")


def _text(value: object) -> str:
    return "?" if value is None else str(value)


def _pct(value: float | None) -> str:
    return "?" if value is None else f"{value:+.2f} %"
