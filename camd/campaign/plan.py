"""Campaigns as plans: a generator of steps that the runner carries out (docs/campaigns.md).

A plan is a Python generator. It yields the steps of a campaign, the same pydantic models a
YAML campaign is made of (``ConfigureStep``, ``AcquireStep``, ``MeasureStep``, ``CheckStep``),
and the markers of a sweep; the runner (``camd.campaign.runner``) executes each step, or
replays it from the state file when resuming, and sends back what it produced:

- configure: None;
- acquire: the acquisition's document (the API's answer: stream, scan or wheel statistics);
- measure: the results the step keeps, ``{name: value}``;
- check: the check's record, ``{"id", "result", "value", "min", "max", "passed"}``.

The plan never touches the device (as bluesky's plans do not): it says what to do, and may
look at what came back to choose what to do next. A resumed run replays the completed steps,
so the plan sees the same values and takes the same branches.

Sweeps keep the YAML campaigns' semantics (step instance keys ``light[1]/stare``, results
measured inside a sweep collected into lists over its values): ``sweep(id, parameter,
values, body)`` yields ``BeginSweep``, then per value ``BeginIteration``, the body's steps
and ``EndIteration``, then ``EndSweep``. Inside an iteration ``${parameter}`` is the value.

A Python campaign is a module with ``CAMPAIGN`` (the header of a YAML campaign as a dict:
name, profile, seed, parameters, quick, baseline, assumptions, outputs) and
``plan(parameters)``, the generator; it may also define ``count_steps(parameters)`` (steps
in a run, for the progress bar) and register its own acquisition kinds
(``camd.campaign.acquisitions.acquisition``) and measurements
(``camd.campaign.measurements.measurement``). ``load_plan(path)`` loads one. The YAML
campaigns are one front end of the same runner: ``yaml_plan`` yields their steps.
"""

from __future__ import annotations

import ast
import importlib.util
import sys
from collections.abc import Callable, Generator, Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pydantic import Field

from camd.campaign.loading import validate_header
from camd.campaign.spec import (
    AcquireStep,
    CampaignError,
    CampaignSpec,
    CheckStep,
    ConfigureStep,
    CustomAcquire,
    MeasureStep,
    Step,
    SweepStep,
    sweep_values,
)
from camd.datafile import Loc

__all__ = [
    "BeginIteration",
    "BeginSweep",
    "EndIteration",
    "EndSweep",
    "Instruction",
    "Plan",
    "PlanCampaign",
    "PlanSpec",
    "acquire",
    "check",
    "configure",
    "load_plan",
    "measure",
    "sweep",
    "yaml_plan",
    "yaml_steps_in_run",
]


@dataclass(frozen=True)
class BeginSweep:
    """A sweep over ``values`` of ``parameter`` starts (its iterations follow)."""

    id: str
    parameter: str
    values: tuple[Any, ...]
    record: bool = True
    title: str = ""


@dataclass(frozen=True)
class BeginIteration:
    """Iteration ``index`` of the open sweep starts, with its parameter at ``value``."""

    index: int
    value: Any


@dataclass(frozen=True)
class EndIteration:
    """The iteration in progress ends."""


@dataclass(frozen=True)
class EndSweep:
    """The open sweep ends: its results become lists over its values."""


ExecutedStep = ConfigureStep | AcquireStep | MeasureStep | CheckStep
Instruction = ExecutedStep | BeginSweep | BeginIteration | EndIteration | EndSweep
Plan = Generator[Instruction, Any, None]


# -- building steps in Python ------------------------------------------------------------------


def configure(id: str, **fields: Any) -> ConfigureStep:
    """A configure step: ``registers``, ``mode``, ``scene``, ``stage``, ... (as in YAML)."""
    return ConfigureStep.model_validate({"id": id, "kind": "configure", **fields})


def acquire(
    id: str, kind: str | None = None, args: Mapping[str, Any] | None = None, **fields: Any
) -> AcquireStep:
    """An acquire step: ``stare={...}``, ``scan={...}``, ``wheel={...}`` or
    ``polarization={...}`` as in YAML; or ``kind="name", args={...}`` for an acquisition kind
    registered with ``camd.campaign.acquisitions.acquisition``."""
    if kind is not None:
        fields["custom"] = CustomAcquire(kind=kind, args=dict(args or {}))
    elif args is not None:
        raise CampaignError(f"step {id!r}: args= goes with kind= (a registered acquisition kind)")
    return AcquireStep.model_validate({"id": id, "kind": "acquire", **fields})


def measure(id: str, function: str, **fields: Any) -> MeasureStep:
    """A measure step: ``function`` with ``inputs``, ``args``, ``from_results``, ``results``."""
    return MeasureStep.model_validate({"id": id, "kind": "measure", "function": function, **fields})


def check(id: str, result: str, **fields: Any) -> CheckStep:
    """A check step: ``result`` within ``min`` and/or ``max``."""
    return CheckStep.model_validate({"id": id, "kind": "check", "result": result, **fields})


def sweep(
    id: str,
    parameter: str,
    values: Iterable[Any],
    body: Callable[[Any], Plan],
    *,
    record: bool = True,
    title: str = "",
) -> Plan:
    """Run the plan ``body(value)`` once per value (``yield from sweep(...)``)."""
    values = tuple(values)
    yield BeginSweep(id, parameter, values, record, title)
    for index, value in enumerate(values):
        yield BeginIteration(index, value)
        yield from body(value)
        yield EndIteration()
    yield EndSweep()


# -- the YAML front end --------------------------------------------------------------------------


def yaml_plan(steps: list[Step], names: dict[str, Any]) -> Plan:
    """A YAML campaign's steps as a plan: its sweeps' values from ``names`` (the parameters
    and the enclosing sweeps' values); ``${...}`` references are left to the runner, which
    also knows the results measured so far."""
    for step in steps:
        if isinstance(step, SweepStep):
            values = _sweep_values(step, names)
            yield BeginSweep(step.id, step.parameter, tuple(values), step.record, step.title)
            for index, value in enumerate(values):
                yield BeginIteration(index, value)
                yield from yaml_plan(step.steps, {**names, step.parameter: value})
                yield EndIteration()
            yield EndSweep()
        else:
            yield step


def yaml_steps_in_run(steps: list[Step], names: dict[str, Any]) -> int:
    """The step instances ``yaml_plan(steps, names)`` yields (the runner's progress total)."""
    total = 0
    for step in steps:
        if isinstance(step, SweepStep):
            for value in _sweep_values(step, names):
                total += yaml_steps_in_run(step.steps, {**names, step.parameter: value})
        else:
            total += 1
    return total


def _sweep_values(step: SweepStep, names: dict[str, Any]) -> list[Any]:
    """A sweep's values, or CampaignError naming the step."""
    try:
        return sweep_values(step, names)
    except CampaignError as exc:
        raise CampaignError(f"step {step.id!r}: {exc}") from None


# -- Python campaigns ------------------------------------------------------------------------------


class PlanSpec(CampaignSpec):
    """A Python campaign's header: a YAML campaign without ``steps`` (the plan yields them)."""

    steps: list[Step] = Field(default_factory=list, max_length=0)


@dataclass(frozen=True)
class PlanCampaign:
    """A loaded Python campaign: its header, its plan and its source (for the state digest)."""

    spec: PlanSpec
    plan: Callable[[dict[str, Any]], Plan]
    source: str
    path: Path
    count_steps: Callable[[dict[str, Any]], int] | None = None

    def steps_in_run(self, parameters: dict[str, Any]) -> int | None:
        """Step instances a run takes, if the module says (None: not known in advance)."""
        return None if self.count_steps is None else int(self.count_steps(parameters))


def _header_lines(source: str) -> dict[Loc, int]:
    """The line of each place of the module's ``CAMPAIGN`` as the source writes it (a dict
    display or ``dict(...)``, with the dicts and lists in it), by its ``Loc``, as
    ``yaml_lines`` gives a YAML file's: its errors name their line. {} for a header built
    otherwise."""
    lines: dict[Loc, int] = {}

    def walk(node: ast.expr, loc: Loc) -> None:
        lines.setdefault(loc, node.lineno)
        if isinstance(node, ast.Dict):
            for key, value in zip(node.keys, node.values, strict=True):
                if isinstance(key, ast.Constant) and isinstance(key.value, str):
                    lines[(*loc, key.value)] = key.lineno
                    walk(value, (*loc, key.value))
        elif (
            isinstance(node, ast.Call)
            and isinstance(node.func, ast.Name)
            and node.func.id == "dict"
        ):
            for keyword in node.keywords:
                if keyword.arg is not None:
                    lines[(*loc, keyword.arg)] = keyword.lineno
                    walk(keyword.value, (*loc, keyword.arg))
        elif isinstance(node, ast.List | ast.Tuple):
            for index, item in enumerate(node.elts):
                lines[(*loc, index)] = item.lineno
                walk(item, (*loc, index))

    for statement in ast.parse(source).body:  # the module imported: its syntax is valid
        if isinstance(statement, ast.Assign):
            targets, value = statement.targets, statement.value
        elif isinstance(statement, ast.AnnAssign) and statement.value is not None:
            targets, value = [statement.target], statement.value
        else:
            continue
        if any(isinstance(target, ast.Name) and target.id == "CAMPAIGN" for target in targets):
            lines = {}  # the last assignment is the module's CAMPAIGN
            walk(value, ())
    return lines


def load_plan(path: str | Path) -> PlanCampaign:
    """Load a Python campaign (module docstring). CampaignError naming the file and what is
    wrong: no CAMPAIGN or plan, an invalid header, an error importing it."""
    path = Path(path)
    try:
        source = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise CampaignError(f"{path}: cannot read the campaign ({exc.strerror or exc})") from None
    name = f"camd_campaign_plan_{path.stem}"
    loader_spec = importlib.util.spec_from_file_location(name, path)
    if loader_spec is None or loader_spec.loader is None:
        raise CampaignError(f"{path}: not a Python module (a campaign plan is a .py file)")
    module = importlib.util.module_from_spec(loader_spec)
    sys.modules[name] = module  # dataclasses and pickling look modules up by name
    try:
        loader_spec.loader.exec_module(module)
    except Exception as exc:
        sys.modules.pop(name, None)
        raise CampaignError(
            f"{path}: importing the plan failed: {type(exc).__name__}: {exc}"
        ) from exc
    header = getattr(module, "CAMPAIGN", None)
    plan = getattr(module, "plan", None)
    if not isinstance(header, Mapping) or not callable(plan):
        raise CampaignError(
            f"{path}: a Python campaign defines CAMPAIGN (a dict: name, profile, seed, "
            "parameters, ...) and plan(parameters), a generator of steps (docs/campaigns.md)"
        )
    spec = validate_header(path, dict(header), PlanSpec, _header_lines(source), "CAMPAIGN")
    count = getattr(module, "count_steps", None)
    return PlanCampaign(
        spec=spec,
        plan=plan,
        source=source,
        path=path,
        count_steps=count if callable(count) else None,
    )
