"""Finding and loading campaigns: a file, or a shipped campaign by name (docs/campaigns.md).

The shipped campaigns are the YAML files and Python plans in config/campaigns/; beside them,
``run_times.toml`` keeps each one's measured run time on the simulated camera, full and
``--quick`` (``camctl campaign list`` shows them).
"""

from __future__ import annotations

import re
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from camd.campaign.checks import check_campaign
from camd.campaign.loading import load_campaign
from camd.campaign.plan import PlanCampaign, load_plan
from camd.campaign.spec import (
    NAME,
    CampaignError,
    CampaignSpec,
    SweepStep,
    sweep_values,
)

__all__ = [
    "CAMPAIGN_SUFFIXES",
    "Loaded",
    "campaigns_dir",
    "find_campaign",
    "load_any",
    "run_times",
    "shipped",
    "shipped_names",
]

CAMPAIGN_SUFFIXES = (".yaml", ".py")  # a YAML campaign, a Python plan
RUN_TIMES = "run_times.toml"


def campaigns_dir() -> Path:
    """The shipped campaigns: config/campaigns/ of the camd config dir."""
    from camd.paths import config_dir

    return config_dir() / "campaigns"


def shipped() -> list[Path]:
    """The shipped campaign files, by name."""
    return sorted(p for p in campaigns_dir().iterdir() if p.suffix in CAMPAIGN_SUFFIXES)


def shipped_names() -> str:
    return ", ".join(p.stem for p in shipped())


def find_campaign(text: str) -> Path | None:
    """The campaign file ``text`` names: a file, or a shipped campaign's name (None: neither)."""
    path = Path(text)
    if path.is_file():
        return path
    if re.fullmatch(NAME, text):
        for suffix in CAMPAIGN_SUFFIXES:
            candidate = campaigns_dir() / f"{text}{suffix}"
            if candidate.is_file():
                return candidate
    return None


@dataclass(frozen=True)
class Loaded:
    """A campaign loaded and checked whole: its header, its plan (Python campaigns) or None
    (YAML: the steps are in ``spec``), where it came from."""

    spec: CampaignSpec
    plan: PlanCampaign | None
    path: Path

    def steps(self, quick: bool) -> int | None:
        """Step instances a run takes (None: a Python plan that does not say)."""
        parameters = self.spec.parameters_for(quick)
        if self.plan is not None:
            return self.plan.steps_in_run(dict(parameters))
        return _count(list(self.spec.steps), parameters)


def load_any(text: str, *, quick: bool = False) -> Loaded:
    """Find (``find_campaign``), load and check the campaign ``text``: CampaignError saying
    what is wrong and what to do (a YAML campaign is checked whole, its parameters
    substituted; a Python plan's steps are checked as it yields them)."""
    path = find_campaign(text)
    if path is None:
        raise CampaignError(
            f"no campaign {text!r}: give a campaign file (YAML, or a Python plan .py), or one "
            f"of the shipped campaigns (`camctl campaign list`): {shipped_names()}"
        )
    if path.suffix == ".py":
        plan = load_plan(path)
        return Loaded(plan.spec, plan, path.resolve())
    spec = load_campaign(path)
    check_campaign(spec, path, quick=quick)
    return Loaded(spec, None, path.resolve())


def _count(steps: list[Any], names: dict[str, Any]) -> int | None:
    total = 0
    for step in steps:
        if isinstance(step, SweepStep):
            try:
                values = sweep_values(step, names)
            except (CampaignError, KeyError):
                return None  # swept over a result measured during the run
            for value in values:
                inner = _count(list(step.steps), {**names, step.parameter: value})
                if inner is None:
                    return None
                total += inner
        else:
            total += 1
    return total


def run_times() -> dict[str, dict[str, float]]:
    """The shipped campaigns' measured run times, ``{name: {"full_s", "quick_s"}}`` (from
    config/campaigns/run_times.toml; empty if it is missing)."""
    path = campaigns_dir() / RUN_TIMES
    try:
        doc = tomllib.loads(path.read_text(encoding="utf-8"))
    except (OSError, tomllib.TOMLDecodeError):
        return {}
    return {
        str(name): {k: float(v) for k, v in entry.items() if k in ("full_s", "quick_s")}
        for name, entry in doc.items()
        if isinstance(entry, dict)
    }
