"""``camd conform`` and ``camctl conform``: the conformance suite (docs/conformance.md).

    camd conform [--sim [--profile NAME] [--defect NAME ...]] [--url URL] [--out DIR]
                 [--only ID ...] [--destructive] [--json]
    camctl conform [--out DIR] [--only ID ...] [--destructive] [--sim ...] [--json]

Runs every check of ``camd.campaign.conformance`` on the unit behind the daemon at --url, or
with ``--sim`` on a simulated camera of its own (``camd serve --sim``, data and log in
DIR/daemon), with the simulator's deliberate ``--defect``s if asked. Each check's line goes to
stderr as it finishes; the report is DIR/conformance.json and DIR/conformance.html. Exit status
(EXIT_*): 0 when the unit conforms (every check ran and passed), 1 when a check failed (after
the report was written) or the run broke, 2 for bad options, 3 when no daemon answers, 4 when
no check failed but some were not run or skipped (the unit was not shown to conform).
"""

from __future__ import annotations

import argparse
import fnmatch
import json
import sys
from pathlib import Path
from typing import Any

from camd.client import DEFAULT_URL, CamdClient, CamdError, DaemonUnreachable
from firmware_models.defects import DEFECTS

DEFAULT_OUT = "conformance"
START_TIMEOUT_S = 60.0

EXIT_CONFORMS = 0
EXIT_FAILED = 1  # a check failed, or the run broke
EXIT_USAGE = 2
EXIT_NO_DAEMON = 3
EXIT_INCOMPLETE = 4  # none failed, but some were not run or skipped: conformance not shown
EXIT_FOR_VERDICT = {
    "conforms": EXIT_CONFORMS,
    "does_not_conform": EXIT_FAILED,
    "incomplete": EXIT_INCOMPLETE,
}
# The progress line's mark for each outcome (docs/conformance.md).
MARKS = {"pass": "PASS", "fail": "FAIL", "not_run": "NOT RUN", "skipped": "SKIP"}


def add_options(p: argparse.ArgumentParser, *, url: bool) -> None:
    """The suite's options (camd conform and camctl conform share them)."""
    p.add_argument("--out", default=DEFAULT_OUT, metavar="DIR",
                   help=f"report directory (default ./{DEFAULT_OUT})")  # fmt: skip
    p.add_argument(
        "--sim", action="store_true",
        help="start a simulated camera (camd serve --sim) for this run instead of using --url",
    )  # fmt: skip
    p.add_argument("--profile", default="hr400", metavar="NAME",
                   help="--sim: the camera profile to simulate (default hr400)")  # fmt: skip
    p.add_argument(
        "--defect", action="append", default=[], choices=sorted(DEFECTS), metavar="NAME",
        help="--sim: turn on a deliberate defect of the simulated camera (repeatable): "
        + ", ".join(DEFECTS),
    )  # fmt: skip
    p.add_argument("--only", action="append", default=[], metavar="ID",
                   help="run only these checks (ids or patterns such as 'stream.*'; repeatable)")  # fmt: skip
    p.add_argument("--destructive", action="store_true",
                   help="also run the checks that change what the unit cannot get back")  # fmt: skip
    if url:
        p.add_argument("--url", default=None,
                       help=f"daemon URL without --sim (default: $CAMD_URL or {DEFAULT_URL})")  # fmt: skip
        p.add_argument("--json", action="store_true",
                       help="print the report's summary as one JSON document on stdout")  # fmt: skip


def add_parser(sub: Any) -> None:
    """Register ``camd conform`` (called by camd.cli.camd_main)."""
    p: argparse.ArgumentParser = sub.add_parser(
        "conform",
        help="run the conformance suite on the camera (or a simulated one) and report",
        description="Check the unit the daemon drives against docs/protocol.md, "
        "docs/stream.md and docs/sensors.md: every command with valid and invalid arguments, "
        "at-most-once execution, registers, LVDS training, stream headers, counters, CRCs and "
        "frame period, stage and wheel. Writes DIR/conformance.json and DIR/conformance.html. "
        "Exit status 0 conforms (every check ran and passed), 1 a check failed, 2 bad options, "
        "3 no daemon, 4 none failed but some were not run or skipped.",
    )
    add_options(p, url=True)


def usage_problem(args: argparse.Namespace) -> str | None:
    """Options that do not go together, in words (None: fine)."""
    if args.defect and not args.sim:
        return "--defect goes with --sim (defects are switches of the simulated camera)"
    if args.sim and getattr(args, "url", None):
        return "--sim starts its own daemon: give --sim or --url, not both"
    from camd.campaign.conformance import check_ids

    ids = check_ids()
    unknown = [o for o in args.only if not any(fnmatch.fnmatchcase(i, o) for i in ids)]
    if unknown:
        return f"--only {', '.join(unknown)}: no such check; the checks are {', '.join(ids)}"
    return None


def conform(client: CamdClient | None, args: argparse.Namespace) -> dict[str, Any]:
    """Run the suite on ``client``'s daemon, or (None) on a simulated camera started for it;
    the summary document. DaemonUnreachable / CamdError pass through; RuntimeError if the
    simulated camera did not start."""
    from camd.campaign.conformance import run_conformance

    out_dir = Path(args.out)

    def progress(record: Any) -> None:
        why = f": {record.reason}" if record.reason else ""
        print(f"{MARKS[record.outcome]:4} {record.id}{why}", file=sys.stderr, flush=True)

    def run(c: CamdClient) -> dict[str, Any]:
        result = run_conformance(c, out_dir, destructive=args.destructive, only=args.only,
                                 progress=progress, defects=args.defect)  # fmt: skip
        summary = result.doc["summary"]
        assert isinstance(summary, dict)
        return {
            "conforms": summary["conforms"],
            "verdict": summary["verdict"],
            "summary": {k: summary[k] for k in ("checks", "pass", "fail", "not_run", "skipped")},
            "failed": result.failed,
            "not_run": result.not_run,
            "duration_s": result.doc["duration_s"],
            "report": {"json": str(result.json_path), "html": str(result.html_path)},
        }

    if client is not None:
        return run(client)
    from camd.cli._daemon_proc import DaemonStartError, start_sim_daemon

    try:
        daemon = start_sim_daemon(
            out_dir.resolve() / "daemon",
            args.profile,
            defects=list(args.defect or ()),
            record_dirs=[out_dir],
        )
    except DaemonStartError as exc:
        raise RuntimeError(f"the simulated camera did not start: {exc}") from None
    try:
        with CamdClient(daemon.url, timeout_s=60.0) as c:
            c.wait_ready(START_TIMEOUT_S)
            return run(c)
    finally:
        daemon.stop()


def show(doc: dict[str, Any], *, as_json: bool) -> None:
    """The summary on stdout: one JSON document, or a line for a person."""
    if as_json:
        sys.stdout.write(json.dumps(doc, indent=2) + "\n")
        return
    print(f"conformance: {summary_text(doc)}; report {doc['report']['html']}")


def summary_text(doc: dict[str, Any]) -> str:
    """'NOT SHOWN TO CONFORM: 54 passed, 0 failed, 1 not run, 1 skipped of 56 in 7.1 s; not
    run: cmd.MOTOR_HOME' (camd conform's and camctl conform's line)."""
    from camd.campaign.conformance.report import VERDICTS, counts_text

    listed = "".join(f"; {what}: {', '.join(doc[key])}"
                     for key, what in (("failed", "failed"), ("not_run", "not run")) if doc[key])  # fmt: skip
    return (
        f"{VERDICTS[doc['verdict']]}: {counts_text(doc['summary'])} in {doc['duration_s']:.1f} s"
        f"{listed}"
    )


def run(args: argparse.Namespace) -> int:
    """``camd conform``: 0 conforms, 1 a check failed (or the run broke), 2 bad options,
    3 no daemon, 4 not shown to conform (checks not run or skipped), 130 interrupted."""
    problem = usage_problem(args)
    if problem is not None:
        print(f"camd conform: error: {problem}", file=sys.stderr)
        return EXIT_USAGE
    try:
        if args.sim:
            doc = conform(None, args)
        else:
            with CamdClient(args.url) as client:
                doc = conform(client, args)
    except DaemonUnreachable as exc:
        print(f"camd conform: error: {exc.message}", file=sys.stderr)
        return EXIT_NO_DAEMON
    except (CamdError, RuntimeError, OSError) as exc:
        print(f"camd conform: error: {getattr(exc, 'message', exc)}", file=sys.stderr)
        return EXIT_FAILED
    show(doc, as_json=args.json)
    return EXIT_FOR_VERDICT[doc["verdict"]]
