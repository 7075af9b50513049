"""Reading a campaign file: YAML parsed with the line of every key, validated against the
schema (``camd.campaign.spec``), then what the schema cannot say (unique ids, known references
and measurement functions, writable register names).

Errors (``CampaignError``) begin ``file:line:`` (the line of the key), then name the step
(``steps[2] (id 'sweep')``) and the key and say what to write (``camd.campaign.explain``).
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any, TypeVar

import yaml
from pydantic import ValidationError

from camd.campaign.checks import check_register_names
from camd.campaign.explain import CampaignFile, explain, walk_steps
from camd.campaign.spec import (
    REF_RE,
    AcquireStep,
    CampaignError,
    CampaignSpec,
    CheckStep,
    MeasureStep,
    SweepStep,
)
from camd.datafile import Loc, place, yaml_lines, yaml_problem

__all__ = ["load_campaign", "validate_header"]


def load_campaign(path: str | Path) -> CampaignSpec:
    """Read and validate a campaign file; CampaignError naming the file, step and key."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise CampaignError(f"{path}: cannot read the campaign file ({exc})") from None
    try:
        doc = yaml.safe_load(text)
        lines = yaml_lines(text)
    except yaml.YAMLError as exc:
        line, problem = yaml_problem(exc)
        raise CampaignError(f"{place(path, line)}: not valid YAML: {problem}") from None
    if not isinstance(doc, dict):
        raise CampaignError(
            f"{place(path, lines.get(()))}: a campaign is a mapping (name, profile, steps, ...)"
        )
    spec = validate_header(path, doc, CampaignSpec, lines)
    _check_semantics(CampaignFile(path, lines), spec)
    check_register_names(CampaignFile(path, lines), spec)
    return spec


Spec = TypeVar("Spec", bound=CampaignSpec)


def validate_header(
    path: Path, doc: Mapping[str, Any], model: type[Spec], lines: Mapping[Loc, int], name: str = ""
) -> Spec:
    """``doc`` validated as ``model`` (a campaign, or a Python campaign's header, called
    ``name``), its ``quick`` overrides among its parameters; CampaignError whose lines begin
    ``file:line:`` (the places' ``lines``, as ``yaml_lines`` gives them) otherwise."""
    try:
        spec = model.model_validate(doc)
    except ValidationError as exc:
        raise CampaignError(explain(path, doc, exc, model, name, lines)) from None
    unknown_quick = sorted(set(spec.quick) - set(spec.parameters))
    if unknown_quick:
        where = CampaignFile(path, lines).at(("quick", unknown_quick[0]))
        raise CampaignError(
            f"{where}: {name}{': ' if name else ''}quick: {', '.join(unknown_quick)} not in "
            "`parameters` (quick overrides parameters; declare them there)"
        )
    return spec


def _check_semantics(file: CampaignFile, spec: CampaignSpec) -> None:
    """What the schema cannot say: unique ids, known references, known functions."""
    from camd.campaign.measurements import MEASUREMENTS

    seen: dict[str, str] = {}
    acquires: set[str] = set()
    for label, loc, step in walk_steps(spec.steps, "steps"):
        if step.id in seen:
            raise CampaignError(
                f"{file.at((*loc, 'id'))}: {label}: id {step.id!r} already used by {seen[step.id]}"
            )
        seen[step.id] = label
        if isinstance(step, AcquireStep):
            acquires.add(step.id)

    # Results a measure step declares (`results: [...]`) can be referred to by the steps after
    # it, as ${name} or in `from_results`; what a step without the list gives is known only
    # when it runs, so those are checked then.
    declared: set[str] = set()

    def check(steps: list[Any], where: str, at: Loc, names: set[str]) -> None:
        for i, step in enumerate(steps):
            label = f"{where}[{i}] (id {step.id!r})"
            loc = (*at, i)
            known = names | declared
            for key, value in step.model_dump(exclude={"steps", "from_results"}).items():
                for ref, inside in _refs(value):
                    if ref not in known:
                        raise CampaignError(
                            f"{file.at((*loc, key, *inside))}: {label}: {key}: ${{{ref}}} is "
                            "neither a parameter, an "
                            "enclosing sweep's parameter nor a result declared before it "
                            f"(known: {', '.join(sorted(known))})"
                        )
            if isinstance(step, MeasureStep):
                if step.function not in MEASUREMENTS:
                    raise CampaignError(
                        f"{file.at((*loc, 'function'))}: {label}: function: unknown "
                        f"measurement {step.function!r}; known: {', '.join(sorted(MEASUREMENTS))}"
                    )
                for arg, source in step.inputs.items():
                    if source not in acquires:
                        raise CampaignError(
                            f"{file.at((*loc, 'inputs', arg))}: {label}: inputs.{arg}: "
                            f"{source!r} is not the id of an acquire step"
                        )
                declared.update(step.results or ())
            if isinstance(step, CheckStep) and step.min is None and step.max is None:
                raise CampaignError(f"{file.at(loc)}: {label}: give `min`, `max` or both")
            if isinstance(step, SweepStep):
                check(step.steps, f"{label}.steps", (*loc, "steps"), names | {step.parameter})

    # Result names in `outputs` are only known after a run: the report says which are missing.
    check(spec.steps, "steps", ("steps",), set(spec.parameters))


def _refs(value: Any) -> list[tuple[str, Loc]]:
    """The names ``value`` refers to (``${name}``), each with its place inside ``value``."""
    if isinstance(value, str):
        return [(m.group(1), ()) for m in REF_RE.finditer(value)]
    if isinstance(value, dict):
        return [(r, (k, *at)) for k, v in value.items() for r, at in _refs(v)]
    if isinstance(value, list):
        return [(r, (i, *at)) for i, v in enumerate(value) for r, at in _refs(v)]
    return []
