"""Campaign errors in the words of the data files' errors: ``file:line: steps[1] (id 'x'): key:
what to write`` (the line found in the YAML's node graph, ``camd.datafile.yaml_lines``).

Shared by loading a campaign (``camd.campaign.loading``), a Python campaign's header
(``camd.campaign.plan``) and the checks with parameters substituted (``camd.campaign.checks``).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, get_args

import yaml
from pydantic import BaseModel, ValidationError

from camd.campaign.spec import Step, SweepStep
from camd.datafile import Loc, place, problem, yaml_line, yaml_lines

__all__ = ["STEP_KINDS", "CampaignFile", "explain", "walk_steps"]


@dataclass(frozen=True)
class CampaignFile:
    """A campaign file and the lines its places are written on (``yaml_lines``): where each
    error begins, ``file:line:`` (``file:`` when the place is not known)."""

    path: str | Path
    lines: Mapping[Loc, int]

    @classmethod
    def read(cls, path: str | Path) -> CampaignFile:
        """The file at ``path``, with its lines if it can be read (the runner names a campaign
        by its name instead: no lines)."""
        try:
            return cls(path, yaml_lines(Path(path).read_text(encoding="utf-8")))
        except (OSError, ValueError, yaml.YAMLError):
            return cls(path, {})

    def at(self, loc: Loc) -> str:
        """``file:line`` of the place ``loc`` (the nearest written place above it)."""
        return place(self.path, yaml_line(self.lines, loc))


def explain(
    path: Path,
    doc: Any,
    exc: ValidationError,
    model: type[BaseModel],
    prefix: str = "",
    lines: Mapping[Loc, int] | None = None,
    at: Loc = (),
) -> str:
    """pydantic's errors (``doc`` validated as ``model``) as ``file:line: steps[1] (id 'x'):
    key: message`` lines, one per key (the most telling of a union's alternatives), each
    saying what to give instead. ``lines`` (``yaml_lines`` of the file) give the line of the
    key, or of the mapping a missing key belongs in; without them (a step checked with its
    parameters substituted, when the file cannot be read again) the message has no line.
    ``prefix`` names the step when ``doc`` is one step, the step at ``at`` of the file."""
    found: dict[str, tuple[int, int | None, str]] = {}
    references: set[str] = set()  # keys whose value may also be a ${name} reference
    for err in exc.errors():
        loc = tuple(err["loc"])
        if err["type"] in ("union_tag_not_found", "union_tag_invalid"):
            loc = (*loc, "kind")  # the step's `kind` is what is wrong or missing
        where: list[str] = []
        node: Any = doc
        for part in loc:
            if isinstance(part, int) and isinstance(node, list):
                node = node[part] if part < len(node) else None
                step_id = node.get("id") if isinstance(node, dict) else None
                label = f"[{part}]" + (f" (id {step_id!r})" if step_id else "")
                if where:
                    where[-1] += label
                else:
                    where.append(label)
            elif isinstance(node, dict) and part in node:
                node = node[part]
                where.append(str(part))
            elif part in STEP_KINDS:
                pass  # the discriminated union's tag: not a key of the file
            elif isinstance(node, dict) and (
                err["type"] in ("missing", "extra_forbidden") or part == "kind"
            ):
                where.append(str(part))
                node = None
            # else: a union's alternative, not a key
        key = ".".join(where) or "(top level)"
        if loc[-1] == "constrained-str" and err["type"] == "string_pattern_mismatch":
            references.add(key)
        rank, message = _message(err, model)
        line = yaml_line(lines, (*at, *loc)) if lines is not None else None
        if key not in found or rank < found[key][0]:
            found[key] = (rank, line, message)
    shown = []
    for key, (_, line, message) in found.items():
        if key in references and " the wrong type;" in message:
            message += " (or a ${name} reference)"
        shown.append(f"{place(path, line)}: {prefix}{': ' if prefix else ''}{key}: {message}")
    return "\n".join(shown)


STEP_KINDS: tuple[str, ...] = tuple(
    get_args(member.model_fields["kind"].annotation)[0] for member in get_args(get_args(Step)[0])
)
"""The kinds of step, the tags of ``Step``: configure, sweep, acquire, measure, check."""


_BOUNDS = ("greater_than_equal", "less_than_equal", "greater_than", "less_than")


def _message(err: Any, model: type[BaseModel]) -> tuple[int, str]:
    """(rank, text) of one pydantic error, in the words of every config file's errors
    (``camd.datafile.problem``): range errors first, then others, type mismatches of a union's
    alternatives last (a count given as -5 is out of range, not "not a ${ref}")."""
    kind = err["type"]
    if kind == "union_tag_not_found":
        return 0, f"missing key; add `kind: ...`, one of {', '.join(STEP_KINDS)}"
    if kind == "union_tag_invalid":
        tag = err["ctx"]["tag"]
        return 0, f"{tag!r} is not a step kind; give one of {', '.join(STEP_KINDS)}"
    message = problem(err, model, yaml=True)
    if message == "unknown key":  # inside a union: the known keys depend on its member
        message += "; docs/campaigns.md lists the keys"
    if kind.endswith("_type") or kind.endswith("_parsing") or kind == "string_pattern_mismatch":
        return 2, message
    if kind in ("extra_forbidden", "missing", *_BOUNDS):
        return 0, message
    return 1, message


def walk_steps(steps: list[Any], where: str, at: Loc = ("steps",)) -> list[tuple[str, Loc, Any]]:
    """Every step, nested ones after their sweep: its label in messages, its place in the
    file, the step."""
    out: list[tuple[str, Loc, Any]] = []
    for i, step in enumerate(steps):
        label = f"{where}[{i}] (id {step.id!r})"
        out.append((label, (*at, i), step))
        if isinstance(step, SweepStep):
            out += walk_steps(step.steps, f"{label}.steps", (*at, i, "steps"))
    return out
