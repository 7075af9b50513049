"""The conformance engine: a plan of checks, carried out through the client (bluesky style).

A suite is a plan: a generator that yields ``CheckStep`` objects (what to check, with which
arguments, against which clause of the spec), read whole before anything runs. The plan never
touches the unit; the engine looks the step's check function up in the registry
(``@check_function``), calls it with a ``Unit`` (the client and what was learnt about the unit
before the plan started) and records the outcome with the evidence it returned. A check
function raises ``CheckFailed`` with its evidence to fail; any other error fails the check too,
with the error as evidence, and the suite goes on.

Four outcomes (``OUTCOMES``): ``pass``, ``fail``, ``skipped`` (a destructive step the run did
not allow) and ``not_run`` ("not run" in words): the check could not show what it tests, so it
neither passes nor fails. That happens three ways:

- ``needs``: a resource the unit may lack (``"stream"``: the USB frame stream). A check that
  finds it missing raises ``CheckNotRun`` naming it; every later step that needs it is then
  recorded not run with that reason, without being tried.
- a check that cannot send what it would have to (a valid case that would change what the
  unit cannot report back) raises ``CheckNotRun`` with no resource and says why.
- ``depends_on``: checks that exercise part of what this one reports (a command whose valid
  case only an acquisition check sends). The step runs after them, whatever the plan's order,
  and passes only if each of them passed; otherwise it is not run, with the reason ("its valid
  case is exercised by stream.headers, which failed: ..."). Its own failure stays a failure.

A step marked ``destructive`` changes something the unit cannot get back (e.g. homing redefines
the stage's zero); it is skipped, and recorded as such, unless the run allows it.
"""

from __future__ import annotations

import time
import traceback
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any, Literal

from camd.campaign.registry import register_in
from camd.client import CamdClient, CamdError
from camd.protocol import Dictionary, load_dictionary
from camd.sensor.regmap import RegisterMap, load_register_map

Evidence = dict[str, Any]
Outcome = Literal["pass", "fail", "skipped", "not_run"]
OUTCOMES: tuple[Outcome, ...] = ("pass", "fail", "not_run", "skipped")
OUTCOME_WORDS: dict[Outcome, str] = {
    "pass": "pass",
    "fail": "fail",
    "not_run": "not run",
    "skipped": "skipped",
}
"""Each outcome as the human report and the progress lines write it (JSON: the key)."""
RESOURCES = {"stream": "frame stream"}
"""What a step may ``need`` that a unit may lack, in words."""


class CheckNotRun(Exception):
    """A check could not show what it tests: ``resource`` (a key of RESOURCES) is missing,
    ``reason`` says how the unit or daemon said so; or (``resource`` None) ``reason`` says
    what the check could not do (a valid case it cannot send without changing the unit)."""

    def __init__(self, resource: str | None, reason: str, evidence: Evidence | None = None) -> None:
        super().__init__(reason)
        if resource is not None and resource not in RESOURCES:
            raise ValueError(f"unknown resource {resource!r}; known: {', '.join(RESOURCES)}")
        self.resource = resource
        self.reason = reason
        self.evidence = evidence or {}


class CheckFailed(Exception):
    """A check found the unit not conforming: ``reason`` in words, ``evidence`` the values."""

    def __init__(self, reason: str, evidence: Evidence) -> None:
        super().__init__(reason)
        self.reason = reason
        self.evidence = evidence


def conclude(problems: Sequence[str], evidence: Evidence) -> Evidence:
    """A check's end: its ``evidence`` when it found no problem, else CheckFailed with every
    problem in one reason (``; `` between them) and the same evidence."""
    if problems:
        raise CheckFailed("; ".join(problems), evidence)
    return evidence


@dataclass(frozen=True, slots=True)
class CheckStep:
    """One check of a plan: ``function`` (registered) called with ``args``."""

    id: str
    function: str
    clause: str  # the spec section it tests, e.g. 'docs/protocol.md §4 "Exchanges"'
    title: str
    args: Mapping[str, Any] = field(default_factory=dict)
    destructive: bool = False
    # Resources of RESOURCES the check needs: without one it is not run.
    needs: tuple[str, ...] = ()
    # Check id -> what of this check it exercises ("its valid case"): this check runs after
    # them and passes only if they passed.
    depends_on: Mapping[str, str] = field(default_factory=dict)


@dataclass(frozen=True, slots=True)
class CheckRecord:
    """What a check found: its outcome, why (in words) and the evidence (values seen)."""

    id: str
    clause: str
    title: str
    outcome: Outcome
    reason: str
    evidence: Evidence
    destructive: bool
    duration_s: float
    depends_on: tuple[str, ...] = ()

    def as_dict(self) -> dict[str, Any]:
        return {
            "id": self.id,
            "clause": self.clause,
            "title": self.title,
            "outcome": self.outcome,
            "passed": self.outcome == "pass",
            "reason": self.reason,
            "destructive": self.destructive,
            "depends_on": list(self.depends_on),
            "duration_s": round(self.duration_s, 3),
            "evidence": self.evidence,
        }


Plan = Iterable[CheckStep]


@dataclass
class Unit:
    """The unit under test as the checks see it: the client and what it said about itself."""

    client: CamdClient
    sensor: str
    regmap: RegisterMap
    dictionary: Dictionary
    simulated: bool
    status: dict[str, Any]

    @classmethod
    def probe(cls, client: CamdClient) -> Unit:
        """Ask the daemon what it drives (read-only requests)."""
        status = dict(client.status())
        sensor = str(client.timing()["sensor"])
        simulated = bool(client.sim_settings().get("available"))
        return cls(client, sensor, load_register_map(sensor), load_dictionary(), simulated, status)


CheckFunction = Callable[..., Evidence]
_REGISTRY: dict[str, CheckFunction] = {}


def check_function(name: str) -> Callable[[CheckFunction], CheckFunction]:
    """Register ``fn(unit, **args) -> evidence`` as the check function ``name``."""
    return register_in(_REGISTRY, "check function", name)


def registered() -> dict[str, CheckFunction]:
    """The check functions by name."""
    return dict(_REGISTRY)


ProgressFn = Callable[[CheckRecord], None]


def run_plan(
    unit: Unit,
    plan: Plan,
    *,
    destructive: bool = False,
    only: Callable[[str], bool] | None = None,
    progress: ProgressFn | None = None,
) -> list[CheckRecord]:
    """Carry out ``plan`` on ``unit``; the records in plan order. ``only(id)`` selects the
    checks to run (the others are not recorded), with the checks they depend on. Each step
    runs after the steps it depends on (``execution_order``); ``progress`` sees each record
    as its check finishes, in that order."""
    steps = _collect(plan)
    by_id = {step.id: step for step in steps}
    chosen = {step.id for step in steps if only is None or only(step.id)}
    pending = list(chosen)
    while pending:  # what a chosen check depends on is run too: its verdict needs them
        for dep in by_id[pending.pop()].depends_on:
            if dep in by_id and dep not in chosen:
                chosen.add(dep)
                pending.append(dep)
    missing: dict[str, str] = {}  # resource -> why the unit lacks it
    done: dict[str, CheckRecord] = {}
    for step in execution_order([s for s in steps if s.id in chosen]):
        record = _settle(step, _run_step(unit, step, destructive, missing), done)
        done[step.id] = record
        if progress is not None:
            progress(record)
    return [done[step.id] for step in steps if step.id in done]


def _collect(plan: Plan) -> list[CheckStep]:
    steps: list[CheckStep] = []
    seen: set[str] = set()
    for step in plan:
        if not isinstance(step, CheckStep):
            raise TypeError(f"a conformance plan yields CheckStep objects, not {step!r}")
        if step.id in seen:
            raise ValueError(f"check id {step.id!r} is used twice in the plan")
        seen.add(step.id)
        steps.append(step)
    return steps


def execution_order(steps: list[CheckStep]) -> list[CheckStep]:
    """``steps`` in plan order, except that a step comes after every step of ``steps`` it
    depends on (a dependency outside ``steps`` is not waited for: ``_settle`` reports it).
    ValueError for a cycle."""
    ids = {step.id for step in steps}
    placed: set[str] = set()
    order: list[CheckStep] = []
    waiting = list(steps)
    while waiting:
        ready = next(
            (s for s in waiting if all(d in placed or d not in ids for d in s.depends_on)), None
        )
        if ready is None:
            cycle = ", ".join(s.id for s in waiting)
            raise ValueError(f"the checks {cycle} depend on each other in a cycle")
        waiting.remove(ready)
        placed.add(ready.id)
        order.append(ready)
    return order


_DEPENDENCY_WENT = {"fail": "failed", "not_run": "did not run", "skipped": "was skipped"}


def _settle(step: CheckStep, record: CheckRecord, done: dict[str, CheckRecord]) -> CheckRecord:
    """A passed check whose dependencies did not all pass is not run: what they exercise of
    it was not shown (its own failure, or its own reason not to run, stands)."""
    record = replace(record, depends_on=tuple(step.depends_on))
    if record.outcome != "pass":
        return record
    for dep, what in step.depends_on.items():
        got = done.get(dep)
        if got is not None and got.outcome == "pass":
            continue
        if got is None:
            why = f"{what} is exercised by {dep}, which is not in the suite"
        else:
            why = f"{what} is exercised by {dep}, which {_DEPENDENCY_WENT[got.outcome]}"
            why += f": {got.reason}" if got.reason else ""
        evidence = record.evidence | {
            "dependency": {"check": dep, "outcome": None if got is None else got.outcome}
        }
        return replace(record, outcome="not_run", reason=why, evidence=evidence)
    return record


def _run_step(
    unit: Unit, step: CheckStep, destructive: bool, missing: dict[str, str]
) -> CheckRecord:
    def record(outcome: Outcome, reason: str, evidence: Evidence, t0: float) -> CheckRecord:
        return CheckRecord(
            step.id,
            step.clause,
            step.title,
            outcome,
            reason,
            evidence,
            step.destructive,
            time.monotonic() - t0,
        )

    t0 = time.monotonic()
    if step.destructive and not destructive:
        return record(
            "skipped",
            "destructive: it changes what the unit cannot get back; run with --destructive",
            {},
            t0,
        )
    lacking = [r for r in step.needs if r in missing]
    if lacking:
        return record("not_run", missing[lacking[0]], {"needs": list(step.needs)}, t0)
    fn = _REGISTRY.get(step.function)
    if fn is None:
        known = ", ".join(sorted(_REGISTRY))
        return record("fail", f"no check function {step.function!r} (known: {known})", {}, t0)
    try:
        evidence = fn(unit, **step.args)
    except CheckNotRun as exc:
        if exc.resource is None:
            return record("not_run", exc.reason, exc.evidence, t0)
        why = f"no {RESOURCES[exc.resource]}: {exc.reason}"
        missing.setdefault(exc.resource, f"{why} (found by {step.id})")
        return record("not_run", why, exc.evidence | {"needs": list(step.needs)}, t0)
    except CheckFailed as exc:
        return record("fail", exc.reason, exc.evidence, t0)
    except CamdError as exc:
        return record(
            "fail", f"the daemon refused a request: {exc.message}", {"code": exc.code}, t0
        )
    except Exception as exc:  # a check that breaks is a failed check, not a failed suite
        tb = traceback.format_exception_only(type(exc), exc)
        return record("fail", f"the check raised {type(exc).__name__}: {exc}", {"error": tb}, t0)
    return record("pass", "", evidence, t0)
