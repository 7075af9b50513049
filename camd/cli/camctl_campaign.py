"""camctl's campaign commands (docs/campaigns.md).

    camctl campaign run FILE --out DIR [--quick] [--sim] [--json]
    camctl campaign list
    camctl campaign start FILE [--out DIR] [--quick] [--wait]
    camctl campaign status [JOB]
    camctl campaign pause|abort [JOB] [--force]
    camctl campaign resume [JOB] [--wait]

``start`` .. ``resume`` drive the daemon's campaign jobs ("Campaign jobs" in
docs/campaigns.md): the campaign runs in the daemon's worker, not in camctl, so it outlives
camctl, and a job paused, or cut off by a daemon restart, runs on from its state file. JOB
defaults to the newest job. ``--wait`` follows the job with a progress bar until it ends or
pauses (Ctrl-C leaves it running).

FILE is a YAML campaign or a Python one (a ``.py`` module with CAMPAIGN and plan: see
``camd.campaign.plan``), or the name of a shipped campaign.
``run`` runs (or, into a DIR holding a state file, resumes) a campaign against the daemon at
--url, or with ``--sim`` against a simulated camera of the campaign's profile that it starts
itself (data and log in DIR/daemon). Progress goes to stderr. ``--json`` prints one document,
``{"campaign", "passed", "results", "report"}``. Exit status 1 when a check failed (after
everything was written), 2 for an unknown campaign, an invalid file (checked whole first:
``check_campaign``) or an unusable --out, with nothing done; 130 when interrupted (resume by
running again).
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from rich.console import Console
from rich.markup import escape
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

from camd.client import CamdClient

if TYPE_CHECKING:
    from camd.campaign.plan import PlanCampaign
    from camd.campaign.runner import CampaignOutcome
    from camd.campaign.runner import Progress as StepProgress
    from camd.campaign.spec import CampaignSpec

__all__ = ["COMMANDS", "RENDER", "add_parsers", "campaigns_dir", "run_on_own_sim"]


JOB_ACTIONS = ("start", "status", "pause", "resume", "abort")
JOB_ENDED = ("paused", "aborted", "passed", "failed", "error", "interrupted")


def campaigns_dir() -> Path:
    """The shipped campaigns: config/campaigns/ of the camd config dir."""
    from camd.campaign.catalog import campaigns_dir as shipped_dir

    return shipped_dir()


def add_parsers(command: Callable[[str, str], argparse.ArgumentParser]) -> None:
    """Add ``campaign`` through camctl's ``command(name, help)`` factory."""
    p = command(
        "campaign",
        "run a scripted test campaign (here, or as a daemon job you can pause and resume), or "
        "list the shipped ones",
    )
    p.add_argument("action", choices=(*JOB_ACTIONS, "run", "list"))
    p.add_argument(
        "file", nargs="?", metavar="FILE|NAME|JOB",
        help="run: the campaign (YAML, or a Python plan .py), or the name of a shipped one "
        "(camctl campaign list); start: the campaign's name in the daemon's campaign "
        "directories ([campaigns] dirs, then the shipped ones), never a path; status, pause, "
        "resume, abort: the job's number (default: the newest job)",
    )  # fmt: skip
    p.add_argument(
        "--out", metavar="DIR",
        help="run: output directory (resumes if it has state); start: output directory on the "
        "daemon's host (relative: in its data directory's campaigns; default: "
        "campaigns/<job>-<name> there)",
    )  # fmt: skip
    p.add_argument(
        "--quick", action="store_true", help="run, start: the campaign's CI-sized overrides"
    )
    p.add_argument(
        "--sim", action="store_true",
        help="run: start a simulated camera with the campaign's profile and seed for this run",
    )  # fmt: skip
    p.add_argument("--resume", action="store_true", help="run: require a state file to resume")
    p.add_argument(
        "--wait", action="store_true",
        help="start, resume: follow the job until it ends or pauses (Ctrl-C leaves it running)",
    )  # fmt: skip
    p.add_argument(
        "--force", action="store_true",
        help="pause, abort: a job another client started (logged)",
    )  # fmt: skip
    p.add_argument("--stop-after", metavar="STEP", help=argparse.SUPPRESS)  # tests: interrupt


def _campaign_path(text: str) -> Path | None:
    """The campaign file ``text`` names: a file, or a shipped campaign's name (None: neither)."""
    from camd.campaign.catalog import find_campaign

    return find_campaign(text)


def _shipped() -> list[Path]:
    from camd.campaign.catalog import shipped

    return shipped()


def _shipped_names() -> str:
    from camd.campaign.catalog import shipped_names

    return shipped_names()


def check_out_dir(out_dir: Path) -> None:
    """Make the output directory, or UsageError saying why it cannot be used and what to do."""
    from camd.cli.camctl_sensor import UsageError

    if out_dir.exists() and not out_dir.is_dir():
        raise UsageError(
            f"--out {out_dir}: exists and is not a directory; give a directory (a new one is made)"
        )
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UsageError(
            f"--out {out_dir}: cannot create the directory ({exc.strerror or exc}); give a "
            "directory you may write to"
        ) from None
    if not os.access(out_dir, os.W_OK | os.X_OK):
        raise UsageError(
            f"--out {out_dir}: the directory is not writable; give a directory you may write to"
        )


def cmd_campaign(client: CamdClient, args: argparse.Namespace) -> Any:
    from camd.campaign.catalog import load_any
    from camd.campaign.spec import CampaignError
    from camd.cli.camctl_sensor import CommandFailed, UsageError

    if args.action == "list":
        return _list()
    if args.action in JOB_ACTIONS:
        return _job_action(client, args)
    if not args.file or not args.out:
        raise UsageError("campaign run needs FILE and --out DIR")
    path = _campaign_path(args.file)
    if path is None:
        raise UsageError(
            f"no campaign {args.file!r}: give a campaign YAML file, or one of the shipped "
            f"campaigns (`camctl campaign list`): {_shipped_names()}"
        )
    # The whole file, with the parameters substituted, before anything is done (a Python
    # plan's steps are checked as it yields them).
    try:
        loaded = load_any(str(path), quick=args.quick)
    except CampaignError as exc:
        raise UsageError(str(exc)) from None
    spec, plan = loaded.spec, loaded.plan
    out_dir = Path(args.out)
    if args.resume and not (out_dir / "state.json").exists():
        raise UsageError(f"--resume: {out_dir / 'state.json'} does not exist; nothing to resume")
    check_out_dir(out_dir)
    try:
        doc = _run(None if args.sim else client, spec, plan, out_dir, args)
    except CampaignError as exc:
        raise CommandFailed({"campaign": spec.name, "error": str(exc)}, str(exc)) from None
    if not doc["passed"]:
        failed = [c for c in doc["results_doc"]["checks"] if not c["passed"]]
        names = ", ".join(c["id"] for c in failed)
        raise CommandFailed(_public(doc), f"campaign {spec.name}: check(s) failed: {names}")
    return _public(doc)


def _public(doc: dict[str, Any]) -> dict[str, Any]:
    return {k: doc[k] for k in ("campaign", "passed", "results", "report")}


def _run(
    client: CamdClient | None, spec: Any, plan: Any, out_dir: Path, args: argparse.Namespace
) -> dict[str, Any]:
    """Run on ``client``'s daemon, or (None) on a simulated camera of the campaign's own."""
    from camd.campaign.runner import CampaignInterrupted, CampaignRunner

    err = Console(stderr=True, highlight=False)
    with RichProgress(err, spec.name) as progress:
        try:
            if client is None:
                outcome = run_on_own_sim(
                    spec, out_dir, quick=args.quick, progress=progress, timeout_s=args.timeout,
                    stop_after=args.stop_after, plan=plan,
                )  # fmt: skip
            else:
                outcome = CampaignRunner(
                    client, None if plan is not None else spec, out_dir, plan=plan,
                    quick=args.quick, progress=progress, stop_after=args.stop_after,
                ).run()  # fmt: skip
        except CampaignInterrupted as exc:
            print(f"camctl: {exc}", file=sys.stderr)
            raise KeyboardInterrupt from None  # camctl: "interrupted", exit 130
    return {
        "campaign": spec.name,
        "passed": outcome.passed,
        "results": outcome.doc["results"],
        "report": str(outcome.report_path),
        "results_doc": outcome.doc,
    }


def run_on_own_sim(
    spec: CampaignSpec,
    out_dir: Path,
    *,
    quick: bool = False,
    progress: StepProgress | None = None,
    timeout_s: float = 30.0,
    stop_after: str | None = None,
    plan: PlanCampaign | None = None,
) -> CampaignOutcome:
    """Start ``camd serve --sim`` with the campaign's profile and seed (data and log in
    ``out_dir/daemon``), run the campaign (or the Python campaign ``plan``, whose header is
    ``spec``) on it, stop it. CampaignError if it does not start;
    the runner's errors otherwise (``camd demo`` runs its campaigns this way too)."""
    from camd.campaign.runner import CampaignRunner
    from camd.campaign.spec import CampaignError
    from camd.cli._daemon_proc import DaemonStartError, start_sim_daemon

    try:
        # Its data directory is inside out_dir; the raw files go beside it, into out_dir/raw.
        daemon = start_sim_daemon(
            out_dir.resolve() / "daemon", spec.profile, seed=spec.seed, record_dirs=[out_dir]
        )
    except DaemonStartError as exc:
        raise CampaignError(f"the simulated camera did not start: {exc}") from None
    try:
        with CamdClient(daemon.url, timeout_s=timeout_s) as client:
            client.wait_ready(60.0)
            runner = CampaignRunner(
                client, None if plan is not None else spec, out_dir, plan=plan, quick=quick,
                progress=progress, sim=True, stop_after=stop_after,
            )  # fmt: skip
            return runner.run()
    finally:
        daemon.stop()


def _list() -> dict[str, Any]:
    """The shipped campaigns: name, paper, camera, steps (full and --quick) and the measured
    run times of both forms (config/campaigns/run_times.toml)."""
    from camd.campaign.catalog import load_any, run_times
    from camd.campaign.spec import CampaignError

    times = run_times()
    found: list[dict[str, Any]] = []
    for path in _shipped():
        entry: dict[str, Any] = {"name": path.stem, "file": str(path)}
        try:
            loaded = load_any(str(path))
            spec = loaded.spec
            entry.update(
                name=spec.name, paper=spec.paper or None, profile=spec.profile,
                steps=loaded.steps(False), steps_quick=loaded.steps(True),
                description=" ".join(spec.description.split()),
            )  # fmt: skip
        except CampaignError as exc:
            entry.update(paper=None, profile=None, steps=None, steps_quick=None,
                         description=f"INVALID: {exc}")  # fmt: skip
        measured = times.get(str(entry["name"]), {})
        entry["run_time_s"] = measured.get("full_s")
        entry["run_time_quick_s"] = measured.get("quick_s")
        found.append(entry)
    return {"campaigns": found}


def _job_action(client: CamdClient, args: argparse.Namespace) -> Any:
    """start, status, pause, resume, abort: the daemon's campaign jobs."""
    from camd.cli.camctl_sensor import UsageError

    if args.action == "start":
        if not args.file:
            raise UsageError("campaign start needs NAME (a campaign in the daemon's directories)")
        if "/" in args.file or Path(args.file).suffix in (".yaml", ".py"):
            # The daemon runs no file a client names (it would run it with its own rights).
            raise UsageError(
                f"campaign start takes a campaign's name, not a file ({args.file}): the daemon "
                "runs only the campaigns in its campaign directories; put the file in one of "
                "them ([campaigns] dirs in the daemon's camd.toml) and start it by name, or run "
                f"it here, in camctl's own process: `camctl campaign run {args.file}`"
            )
        # DIR is the daemon's to resolve: a relative one goes into its campaigns folder.
        out = None if args.out is None else str(Path(args.out).expanduser())
        job = client.start_campaign(args.file, out=out, quick=args.quick)
        return _follow(client, job) if args.wait else job
    if args.action == "status":
        if args.file is None:
            return client.campaign_jobs()
        return client.campaign_job(_job_id(client, args.file))
    job_id = _job_id(client, args.file)
    if args.action == "pause":
        return client.pause_campaign(job_id, force=args.force)
    if args.action == "abort":
        return client.abort_campaign(job_id, force=args.force)
    job = client.resume_campaign(job_id)
    return _follow(client, job) if args.wait else job


def _job_id(client: CamdClient, text: str | None) -> int:
    from camd.cli.camctl_sensor import UsageError

    if text is None:
        jobs = client.campaign_jobs()["jobs"]
        if not jobs:
            raise UsageError("the daemon has no campaign jobs; start one with "
                             "`camctl campaign start NAME`")  # fmt: skip
        return max(int(job["id"]) for job in jobs)
    try:
        return int(text)
    except ValueError:
        raise UsageError(f"JOB {text!r}: give a job's number (`camctl campaign status`)") from None


def _follow(client: CamdClient, job: Any) -> Any:
    """Poll the job until it ends or pauses, with a progress bar on stderr."""
    import time

    err = Console(stderr=True, highlight=False)
    with Progress(
        TextColumn(f"[bold]job {job['id']} {escape(job['campaign'])}[/]"), BarColumn(),
        MofNCompleteColumn(), TextColumn("{task.description}"), TimeElapsedColumn(),
        console=err,
    ) as bar:  # fmt: skip
        task = bar.add_task("", total=job["steps"])
        while job["state"] not in JOB_ENDED:
            bar.update(task, completed=job.get("done") or 0, description=job["state"])
            time.sleep(0.5)
            job = client.campaign_job(int(job["id"]))
        bar.update(task, completed=job.get("done") or 0, description=job["state"])
    return job


class RichProgress:
    """The runner's progress as a rich bar on stderr."""

    def __init__(self, console: Console, name: str) -> None:
        self._bar = Progress(
            TextColumn(f"[bold]{escape(name)}[/]"), BarColumn(), MofNCompleteColumn(),
            TextColumn("{task.description}"), TimeElapsedColumn(), console=console,
            transient=False,
        )  # fmt: skip
        self._task = self._bar.add_task("", total=None)

    def __enter__(self) -> RichProgress:
        self._bar.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._bar.stop()

    def begin(self, total: int | None) -> None:
        self._bar.update(self._task, total=total, completed=0)

    def step(self, key: str, title: str, *, replayed: bool) -> None:
        how = " (done before: replayed)" if replayed else ""
        self._bar.update(self._task, description=f"{key}{how}")

    def advance(self) -> None:
        self._bar.advance(self._task)


COMMANDS: dict[str, Callable[[CamdClient, argparse.Namespace], Any]] = {
    "campaign": cmd_campaign,
}


def _seconds(value: float | None) -> str:
    if value is None:
        return "-"
    minutes, seconds = divmod(round(value), 60)
    return f"{minutes} min {seconds:02d} s" if minutes else f"{seconds} s"


def render_campaign(out: Console, doc: Any, args: argparse.Namespace) -> None:
    from rich.table import Table

    if "campaigns" in doc:
        if not doc["campaigns"]:
            out.print(f"no campaigns in {campaigns_dir()}", markup=False)
            return
        table = Table(
            title="shipped campaigns: steps and measured run times (simulated camera), full "
            "and --quick"
        )
        for column in ("name", "paper", "camera", "steps", "run", "quick"):
            table.add_column(
                column, justify="right" if column[0] in "sqr" else "left", no_wrap=True
            )
        for c in doc["campaigns"]:
            steps = "-" if c["steps"] is None else f"{c['steps']} ({c['steps_quick']})"
            table.add_row(
                c["name"], c["paper"] or "-", c["profile"] or "INVALID", steps,
                _seconds(c["run_time_s"]), _seconds(c["run_time_quick_s"]),
            )  # fmt: skip
        out.print(table)
        return
    if "jobs" in doc:
        if not doc["jobs"]:
            out.print("no campaign jobs; start one with `camctl campaign start NAME`")
        for job in doc["jobs"]:
            _render_job(out, job)
        return
    if "state" in doc and "out_dir" in doc:
        _render_job(out, doc)
        return
    if "error" in doc:
        return
    colour = "green" if doc["passed"] else "red"
    out.print(
        f"campaign {escape(doc['campaign'])}: [{colour}]{'PASSED' if doc['passed'] else 'FAILED'}"
        f"[/]; report {escape(str(doc['report']))}"
    )


def _render_job(out: Console, job: Any) -> None:
    colour = {"passed": "green", "failed": "red", "error": "red", "aborted": "yellow",
              "paused": "yellow"}.get(job["state"], "cyan")  # fmt: skip
    steps = "" if job["steps"] is None else f" of {job['steps']}"
    done = "" if job.get("done") is None else f", step {job['done']}{steps} done"
    out.print(
        f"job {job['id']} [bold]{escape(job['campaign'])}[/]{' (quick)' if job['quick'] else ''}: "
        f"[{colour}]{job['state']}[/]{done}, {_seconds(job['run_time_s'])} run "
        f"({job['runs']} run(s)), started by {escape(job['started_by'])}; "
        f"{escape(job['out_dir'])}"
    )
    if job.get("message"):
        out.print(f"  {job['message']}", markup=False)  # "[sim] profile = ...": not markup
    if job.get("report"):
        out.print(f"  report {job['report']}", markup=False)


RENDER: dict[str, Callable[[Console, Any, argparse.Namespace], None]] = {
    "campaign": render_campaign,
}
