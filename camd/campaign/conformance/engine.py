"""The conformance engine: a plan of checks, carried out through the client (bluesky style).

A suite is a plan: a generator that yields ``CheckStep`` objects (what to check, with which
arguments, against which clause of the spec) and receives each check's ``CheckRecord`` back.
The plan never touches the unit; the engine looks the step's check function up in the registry
(``@check_function``), calls it with a ``Unit`` (the client and what was learnt about the unit
before the plan started) and records pass or fail with the evidence it returned. A check
function raises ``CheckFailed`` with its evidence to fail; any other error fails the check too,
with the error as evidence, and the suite goes on: every check is independent of the others.

A step marked ``destructive`` changes something the unit cannot get back (e.g. homing redefines
the stage's zero); it is skipped, and recorded as such, unless the run allows it.
"""

from __future__ import annotations

import time
import traceback
from collections.abc import Callable, Generator, Mapping
from dataclasses import dataclass, field
from typing import Any, Literal

from camd.client import CamdClient, CamdError
from camd.protocol import Dictionary, load_dictionary
from camd.sensor.regmap import RegisterMap, load_register_map

Evidence = dict[str, Any]
Outcome = Literal["pass", "fail", "skipped"]


class CheckFailed(Exception):
    """A check found the unit not conforming: ``reason`` in words, ``evidence`` the values."""

    def __init__(self, reason: str, evidence: Evidence) -> None:
        super().__init__(reason)
        self.reason = reason
        self.evidence = evidence


@dataclass(frozen=True, slots=True)
class CheckStep:
    """One check of a plan: ``function`` (registered) called with ``args``."""

    id: str
    function: str
    clause: str  # the spec section it tests, e.g. 'docs/protocol.md §4 "Exchanges"'
    title: str
    args: Mapping[str, Any] = field(default_factory=dict)
    destructive: bool = False


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

    def as_dict(self) -> dict[str, Any]:
        return {
            "id": self.id,
            "clause": self.clause,
            "title": self.title,
            "outcome": self.outcome,
            "passed": self.outcome == "pass",
            "reason": self.reason,
            "destructive": self.destructive,
            "duration_s": round(self.duration_s, 3),
            "evidence": self.evidence,
        }


Plan = Generator[CheckStep, CheckRecord, None]


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

    def register(fn: CheckFunction) -> CheckFunction:
        if name in _REGISTRY:
            raise ValueError(f"check function {name!r} is registered twice")
        _REGISTRY[name] = fn
        return fn

    return register


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
    checks to run (the others are not recorded)."""
    records: list[CheckRecord] = []
    seen: set[str] = set()
    try:
        step = next(plan)
        while True:
            if not isinstance(step, CheckStep):
                raise TypeError(f"a conformance plan yields CheckStep objects, not {step!r}")
            if step.id in seen:
                raise ValueError(f"check id {step.id!r} is used twice in the plan")
            seen.add(step.id)
            record = _run_step(unit, step, destructive) if only is None or only(step.id) else None
            if record is not None:
                records.append(record)
                if progress is not None:
                    progress(record)
            step = plan.send(record) if record is not None else next(plan)
    except StopIteration:
        pass
    return records


def _run_step(unit: Unit, step: CheckStep, destructive: bool) -> CheckRecord:
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
    fn = _REGISTRY.get(step.function)
    if fn is None:
        known = ", ".join(sorted(_REGISTRY))
        return record("fail", f"no check function {step.function!r} (known: {known})", {}, t0)
    try:
        evidence = fn(unit, **step.args)
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
