"""camctl's campaign commands (docs/campaigns.md).

    camctl campaign run FILE --out DIR [--quick] [--sim] [--json]
    camctl campaign list

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
import re
import sys
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

from camd.client import CamdClient

if TYPE_CHECKING:
    from camd.campaign.plan import PlanCampaign
    from camd.campaign.runner import CampaignOutcome
    from camd.campaign.runner import Progress as StepProgress
    from camd.campaign.spec import CampaignSpec

__all__ = ["COMMANDS", "RENDER", "add_parsers", "campaigns_dir", "run_on_own_sim"]


def campaigns_dir() -> Path:
    """The shipped campaigns: config/campaigns/ of the camd config dir."""
    from camd.paths import config_dir

    return config_dir() / "campaigns"


def add_parsers(command: Callable[[str, str], argparse.ArgumentParser]) -> None:
    """Add ``campaign`` through camctl's ``command(name, help)`` factory."""
    p = command("campaign", "run a scripted test campaign, or list the shipped ones")
    p.add_argument("action", choices=("run", "list"))
    p.add_argument(
        "file", nargs="?", metavar="FILE",
        help="run: the campaign (YAML, or a Python plan .py), or the name of a shipped one "
        "(camctl campaign list)",
    )  # fmt: skip
    p.add_argument("--out", metavar="DIR", help="run: output directory (resumes if it has state)")
    p.add_argument("--quick", action="store_true", help="run: the campaign's CI-sized overrides")
    p.add_argument(
        "--sim", action="store_true",
        help="run: start a simulated camera with the campaign's profile and seed for this run",
    )  # fmt: skip
    p.add_argument("--resume", action="store_true", help="run: require a state file to resume")
    p.add_argument("--stop-after", metavar="STEP", help=argparse.SUPPRESS)  # tests: interrupt


def _campaign_path(text: str) -> Path | None:
    """The campaign file ``text`` names: a file, or a shipped campaign's name (None: neither)."""
    from camd.campaign.spec import NAME

    path = Path(text)
    if path.is_file():
        return path
    if re.fullmatch(NAME, text):
        for suffix in CAMPAIGN_SUFFIXES:
            shipped = campaigns_dir() / f"{text}{suffix}"
            if shipped.is_file():
                return shipped
    return None


CAMPAIGN_SUFFIXES = (".yaml", ".py")  # a YAML campaign, a Python plan


def _shipped() -> list[Path]:
    return sorted(p for p in campaigns_dir().iterdir() if p.suffix in CAMPAIGN_SUFFIXES)


def _shipped_names() -> str:
    return ", ".join(p.stem for p in _shipped())


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
    from camd.campaign.spec import CampaignError, check_campaign, load_campaign
    from camd.cli.camctl_sensor import CommandFailed, UsageError

    if args.action == "list":
        return _list()
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
    plan = None
    spec: CampaignSpec
    try:
        if path.suffix == ".py":
            from camd.campaign.plan import load_plan

            plan = load_plan(path)
            spec = plan.spec
        else:
            spec = load_campaign(path)
            check_campaign(spec, path, quick=args.quick)
    except CampaignError as exc:
        raise UsageError(str(exc)) from None
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
    from camd.cli._daemon_proc import DaemonProcess, DaemonStartError

    data = out_dir.resolve() / "daemon"
    data.mkdir(parents=True, exist_ok=True)
    config = data / "camd.toml"
    config.write_text(
        f'[sim]\nprofile = "{spec.profile}"\nseed = {spec.seed}\n'
        f'[sensor]\nname = "{spec.profile}"\n',
        encoding="utf-8",
    )
    daemon = DaemonProcess(data, extra_args=["--config", str(config)], env={"CAMD_TOKEN": ""})
    try:
        daemon.start()
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
    from camd.campaign.plan import load_plan
    from camd.campaign.spec import CampaignError, load_campaign

    found: list[dict[str, Any]] = []
    for path in _shipped():
        try:
            spec = load_plan(path).spec if path.suffix == ".py" else load_campaign(path)
            found.append({"name": spec.name, "profile": spec.profile, "file": str(path),
                          "description": " ".join(spec.description.split())})  # fmt: skip
        except CampaignError as exc:
            found.append({"name": path.stem, "profile": None, "file": str(path),
                          "description": f"INVALID: {exc}"})  # fmt: skip
    return {"campaigns": found}


class RichProgress:
    """The runner's progress as a rich bar on stderr."""

    def __init__(self, console: Console, name: str) -> None:
        self._bar = Progress(
            TextColumn(f"[bold]{name}[/]"), BarColumn(), MofNCompleteColumn(),
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


def render_campaign(out: Console, doc: Any, args: argparse.Namespace) -> None:
    if "campaigns" in doc:
        for c in doc["campaigns"]:
            out.print(f"[bold]{c['name']}[/] ({c['profile']}): {c['description']}")
        if not doc["campaigns"]:
            out.print(f"no campaigns in {campaigns_dir()}")
        return
    if "error" in doc:
        return
    colour = "green" if doc["passed"] else "red"
    out.print(
        f"campaign {doc['campaign']}: [{colour}]{'PASSED' if doc['passed'] else 'FAILED'}[/]; "
        f"report {doc['report']}"
    )


RENDER: dict[str, Callable[[Console, Any, argparse.Namespace], None]] = {
    "campaign": render_campaign,
}
