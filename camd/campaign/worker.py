"""The worker of a daemon's campaign job (docs/campaigns.md, "Campaign jobs").

    python -m camd.campaign.worker check FILE [--quick] [--url URL]
    python -m camd.campaign.worker run --url URL --job N --run K --file FILE --out DIR [--quick]

The daemon (``camd.daemon.campaign_worker``, for its campaign jobs) starts it; nobody else needs to.

``check`` loads and checks a campaign without running it and prints ``{"file", "campaign",
"profile", "steps"}`` as JSON; a campaign that cannot be run exits 2 with the reason as the
last line on stderr. With ``--url`` it also checks the camera of the daemon there, as the
runner does before its first step (the sensor must be the campaign's profile).

``run`` runs the campaign into DIR through the daemon's API at URL (the token in
``$CAMD_TOKEN``, the client name in ``$CAMD_CLIENT``), resuming from DIR's state file if it
has one. Before each step, and after each acquisition, it asks its job
(GET /api/v1/campaigns/jobs/N) whether a pause or an abort is asked for. SIGTERM and SIGINT
stop it as a Ctrl-C stops ``camctl campaign run``. It writes DIR/outcome.json
(``{"run", "outcome", "passed", "message", "report"}``, ``run`` the daemon's count of
the job's runs, so that it never takes an older run's outcome for this one) and exits 0 passed, 1 a check
failed, 2 an error (the message says which step and why), 3 paused, 4 aborted,
130 interrupted.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import sys
import time
from pathlib import Path
from types import FrameType
from typing import Any

from camd.campaign.catalog import load_any
from camd.campaign.runner import (
    CampaignAborted,
    CampaignInterrupted,
    CampaignPaused,
    CampaignRunner,
    check_camera,
)
from camd.campaign.spec import CampaignError
from camd.client import CamdClient, CamdError, DaemonUnreachable

EXIT = {"passed": 0, "failed": 1, "error": 2, "paused": 3, "aborted": 4, "interrupted": 130}
READY_TIMEOUT_S = 120.0  # a daemon that has just started connects its camera first


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m camd.campaign.worker")
    sub = parser.add_subparsers(dest="command", required=True)
    check = sub.add_parser("check")
    check.add_argument("file")
    check.add_argument("--quick", action="store_true")
    check.add_argument("--url", help="also check the camera of the daemon there (its sensor)")
    run = sub.add_parser("run")
    run.add_argument("--url", required=True)
    run.add_argument("--job", type=int, required=True)
    run.add_argument("--run", type=int, default=1, help="the job's run: 1, then 1 per resume")
    run.add_argument("--file", required=True)
    run.add_argument("--out", required=True)
    run.add_argument("--quick", action="store_true")
    args = parser.parse_args(argv)
    if args.command == "check":
        return _check(args.file, args.quick, args.url)
    return _run(args)


def _check(file: str, quick: bool, url: str | None) -> int:
    try:
        loaded = load_any(file, quick=quick)
        steps = loaded.steps(quick)
        if url is not None:  # the job is checked whole: the camera it would run on too
            with CamdClient(url, timeout_s=30.0) as client:
                check_camera(client, loaded.spec)
    except (CampaignError, CamdError) as exc:
        print(str(exc).replace("\n", " "), file=sys.stderr)
        return 2
    doc = {
        "file": str(loaded.path),
        "campaign": loaded.spec.name,
        "profile": loaded.spec.profile,
        "steps": steps,
    }
    print(json.dumps(doc))
    return 0


def _interrupt_on_signals() -> None:
    def stop(sig: int, frame: FrameType | None) -> None:
        raise KeyboardInterrupt

    signal.signal(signal.SIGTERM, stop)
    signal.signal(signal.SIGINT, stop)


def _run(args: argparse.Namespace) -> int:
    _interrupt_on_signals()
    out = Path(args.out)
    run_number = int(args.run)
    started = time.time()
    print(f"{time.strftime('%Y-%m-%d %H:%M:%S')} worker {os.getpid()}: job {args.job} run "
          f"{run_number}: {args.file} into {out}", flush=True)  # fmt: skip
    doc: dict[str, Any] = {"run": run_number, "passed": None, "report": None}
    try:
        with CamdClient(args.url, timeout_s=30.0) as client:
            client.wait_ready(READY_TIMEOUT_S)
            loaded = load_any(args.file, quick=args.quick)

            def interrupt() -> str | None:
                return client.campaign_job(args.job)["requested"]

            runner = CampaignRunner(
                client, None if loaded.plan is not None else loaded.spec, out,
                plan=loaded.plan, quick=args.quick, interrupt=interrupt,
            )  # fmt: skip
            outcome = runner.run()
        doc.update(
            outcome="passed" if outcome.passed else "failed",
            passed=outcome.passed,
            report=None if outcome.report_path is None else str(outcome.report_path),
            message=None if outcome.passed else _failed_checks(outcome.doc),
        )
    except CampaignPaused as exc:
        doc.update(outcome="paused", message=str(exc))
    except CampaignAborted as exc:
        doc.update(outcome="aborted", message=str(exc))
    except (CampaignInterrupted, KeyboardInterrupt) as exc:
        doc.update(outcome="interrupted", message=str(exc) or "interrupted")
    except DaemonUnreachable as exc:  # the daemon stopped under us: it resumes the job
        doc.update(outcome="interrupted", message=str(exc))
    except (CampaignError, CamdError) as exc:
        doc.update(outcome="error", message=str(exc))
    print(f"{time.strftime('%Y-%m-%d %H:%M:%S')} worker {os.getpid()}: {doc['outcome']} after "
          f"{time.time() - started:.1f} s: {doc.get('message') or ''}", flush=True)  # fmt: skip
    tmp = out / "outcome.json.tmp"
    tmp.write_text(json.dumps(doc, indent=1) + "\n", encoding="utf-8")
    os.replace(tmp, out / "outcome.json")
    return EXIT[str(doc["outcome"])]


def _failed_checks(doc: dict[str, Any]) -> str:
    failed = [c["id"] for c in doc.get("checks", []) if not c.get("passed")]
    return f"check(s) failed: {', '.join(failed)}"


if __name__ == "__main__":
    sys.exit(main())
