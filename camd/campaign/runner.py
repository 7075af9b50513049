"""Run a campaign against a daemon through ``camd.client`` only (docs/campaigns.md).

``CampaignRunner(client, spec, out_dir).run()`` runs a YAML campaign, and
``CampaignRunner(client, None, out_dir, plan=load_plan(path)).run()`` a Python one: either way
a plan (``camd.campaign.plan``: a generator of steps and sweep markers; ``yaml_plan`` for the
YAML steps) says what to do, and this runner does it, step by step, sending each step's
outcome back to the plan. The steps themselves are carried out by a ``StepExecutor``
(``camd.campaign.steps``). Every executed step
instance (a step, or a step inside one iteration of a sweep: ``sweep_m[1]/stare``) is
recorded in ``out_dir/state.json`` (``camd.campaign.state``) as soon as it completes, with its
results, its check outcome or its raw file. Running again into the same directory resumes: recorded instances
are replayed from the state file, not executed, except ``configure`` steps, which are always
applied again (they are cheap and idempotent, and the device must be in the state the next
step expects, possibly after a daemon restart).

Determinism: on the simulated camera every acquisition is seeded from the campaign's seed and
the instance's key (``camd.campaign.steps``), so it sees the same noise whether the run was
interrupted before it or not. results.json is a pure function of the recorded instances.

Observers see the progress: before each step instance the runner, which holds control, says
what it does (PUT /api/v1/control/activity: ``campaign <name>: step <i>/<n> <kind> <key>`` with
i - 1 steps done of n); giving control back at the end clears it.

Ctrl-C (KeyboardInterrupt) stops the step in progress (the stream or scan is stopped) and
raises ``CampaignInterrupted``; everything completed before it is in the state file.

Pause and abort (a campaign job of the daemon): the runner asks its ``interrupt`` hook before
each step it executes, and again after an acquisition; ``"pause"`` raises ``CampaignPaused``,
``"abort"`` ``CampaignAborted``, both resumable as an interrupt is (``camd.campaign.state``).
The daemon's settings before the first step are kept until the run ends, so that a resumed run
puts back the settings the campaign found, not the ones it left.
"""

from __future__ import annotations

import contextlib
import json
import os
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

from camd.campaign.baseline import apply_baseline, restore
from camd.campaign.checks import check_campaign
from camd.campaign.measurements import Acquired
from camd.campaign.plan import (
    BeginIteration,
    BeginSweep,
    EndIteration,
    EndSweep,
    ExecutedStep,
    Plan,
    PlanCampaign,
    yaml_plan,
    yaml_steps_in_run,
)
from camd.campaign.spec import (
    AcquireStep,
    CampaignError,
    CampaignSpec,
    CheckStep,
    ConfigureStep,
    MeasureStep,
)
from camd.campaign.state import (
    CampaignAborted,
    CampaignInterrupted,
    CampaignPaused,
    CampaignState,
)
from camd.campaign.steps import Level, StepExecutor, check_camera, plain
from camd.client import CamdClient, CamdError

# The exceptions and check_camera live with their job (camd.campaign.state, .steps); they are
# re-exported here, where the runner's callers have always imported them from.
__all__ = [
    "CampaignAborted",
    "CampaignInterrupted",
    "CampaignOutcome",
    "CampaignPaused",
    "CampaignRunner",
    "Progress",
    "check_camera",
]


CONTROL_TTL_S = 60.0  # the campaign's control lease, renewed every 20 s while it runs
ACTIVITY_TEXT_MAX = 200  # the daemon's limit on an activity's text


class Progress(Protocol):
    """Told about each step instance as the run goes (camctl shows a rich progress bar);
    ``total`` is None when a Python plan does not say how many steps it takes."""

    def begin(self, total: int | None) -> None: ...

    def step(self, key: str, title: str, *, replayed: bool) -> None: ...

    def advance(self) -> None: ...


class _NoProgress:
    def begin(self, total: int | None) -> None:
        pass

    def step(self, key: str, title: str, *, replayed: bool) -> None:
        pass

    def advance(self) -> None:
        pass


@dataclass
class CampaignOutcome:
    """What a run produced: the results.json document and where the files are."""

    doc: dict[str, Any]
    results_path: Path
    report_path: Path | None = None

    @property
    def passed(self) -> bool:
        return bool(self.doc["passed"])


@dataclass
class _OpenSweep:
    """A sweep the plan has begun: its iterations' levels so far."""

    begin: BeginSweep
    key: str
    iterations: list[Level] = field(default_factory=list)


@dataclass
class _Scope:
    """Where the plan is: the key prefix, the names ``${...}`` sees, the results' level, and
    the sweep open at this level, if any."""

    prefix: str
    names: dict[str, Any]
    level: Level
    sweep: _OpenSweep | None = None


class CampaignRunner:
    """Runs ``spec`` through ``client`` into ``out_dir`` (see the module docstring).

    ``plan``, a Python campaign (``camd.campaign.plan.load_plan``), replaces ``spec`` (give
    None) by its header and its plan. ``sim`` says whether the daemon drives the simulated
    camera (None: ask the daemon); ``stop_after`` (a step instance key or step id) stops the
    run once that instance has completed, as an interrupt would (for tests and debugging).
    ``interrupt``, asked before each executed step and after each acquisition, returns None
    to go on, "pause" or "abort" (module docstring).
    """

    def __init__(
        self,
        client: CamdClient,
        spec: CampaignSpec | None,
        out_dir: str | os.PathLike[str],
        *,
        plan: PlanCampaign | None = None,
        quick: bool = False,
        progress: Progress | None = None,
        sim: bool | None = None,
        stop_after: str | None = None,
        interrupt: Callable[[], str | None] | None = None,
    ) -> None:
        if (spec is None) == (plan is None):
            raise ValueError("give a YAML campaign's spec or a Python campaign's plan (one)")
        if plan is not None:
            spec = plan.spec
        assert spec is not None
        self.client = client
        self.plan = plan
        self.spec: CampaignSpec = spec
        self.out_dir = Path(out_dir).resolve()
        self.quick = quick
        self.progress: Progress = progress if progress is not None else _NoProgress()
        self.stop_after = stop_after
        self.interrupt = interrupt
        self.parameters = self.spec.parameters_for(quick)
        self.raw_dir = self.out_dir / "raw"
        self.state = CampaignState(
            self.out_dir, self.spec, quick, None if plan is None else plan.source
        )
        self.steps = StepExecutor(client, self.spec.seed, self.out_dir, self.raw_dir, sim)
        self._checks: list[dict[str, Any]] = []
        self._files: dict[str, str] = {}
        self.restored: list[str] = []  # the daemon's settings put back after the run
        self._step_number = 0  # step instances begun so far in this run
        self._steps_total: int | None = 0

    # -- the run --------------------------------------------------------------------------------

    def run(self, *, report: bool = True) -> CampaignOutcome:
        """Run (or resume) the campaign; write results.json and, with ``report``, the report.

        Raises CampaignError when the daemon's camera is not the campaign's, a step cannot be
        done (the message names the step), CampaignInterrupted when stopped early. A step that
        its parameters make invalid is refused before the daemon is touched (``_preflight``).
        """
        self._preflight()
        try:
            self.raw_dir.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise CampaignError(
                f"cannot create the output directory {self.raw_dir}: {exc.strerror or exc}; "
                "choose another --out"
            ) from None
        self.state.load()
        check_camera(self.client, self.spec, self.steps.on_sim)
        if self.plan is None:
            self._steps_total = yaml_steps_in_run(self.spec.steps, self.parameters)
        else:
            self._steps_total = self.plan.steps_in_run(dict(self.parameters))
        self._step_number = 0
        self.progress.begin(self._steps_total)
        top = Level()
        try:
            # The campaign holds control for its whole run: no other client changes the
            # camera between its steps (they may watch). It starts from its baseline and puts
            # back the daemon's settings when it ends, passed or failed.
            with self.client.holding_control(CONTROL_TTL_S):
                before = self.state.settings_before(self.client)
                try:
                    apply_baseline(self.client, self.spec.baseline)
                    self._drive(self._plan(), top)
                except BaseException:
                    self._stop_device()
                    raise
                finally:
                    self._say("putting the daemon's settings back", self._step_number)
                    self.restored = restore(self.client, before)
        except KeyboardInterrupt:
            raise CampaignInterrupted(
                f"interrupted; {len(self.state.completed)} completed step(s) saved in "
                f"{self.state.path}: run again with the same --out to resume"
            ) from None
        doc = self._results_doc(top)
        results_path = self.out_dir / "results.json"
        results_path.write_text(json.dumps(doc, indent=2) + "\n", encoding="utf-8")
        self.state.settings_put_back()  # the run has ended: nothing to put back
        outcome = CampaignOutcome(doc, results_path)
        if report:
            from camd.campaign.report import write_report

            outcome.report_path = write_report(self.spec, doc, self.out_dir, restored=self.restored)
        return outcome

    def _results_doc(self, top: Level) -> dict[str, Any]:
        # Plain JSON in a fixed key order; nothing that differs between an interrupted and an
        # uninterrupted run (no times, no absolute paths).
        return {
            "campaign": self.spec.name,
            "profile": self.spec.profile,
            "seed": self.spec.seed,
            "quick": self.quick,
            "passed": all(c["passed"] for c in self._checks),
            "parameters": self.parameters,
            "results": plain(top.results),
            "checks": self._checks,
            "files": dict(sorted(self._files.items())),
            "assumptions": list(self.spec.assumptions),
        }

    def _plan(self) -> Plan:
        """The plan to run: the Python campaign's, or the YAML steps' front end."""
        parameters = dict(self.parameters)
        if self.plan is None:
            return yaml_plan(self.spec.steps, parameters)
        plan = self.plan.plan(parameters)
        if not hasattr(plan, "send"):
            raise CampaignError(
                f"{self.plan.path}: plan(parameters) must be a generator (a function that "
                f"yields steps), not {type(plan).__name__}"
            )
        return plan

    def _drive(self, plan: Plan, top: Level) -> None:
        """Carry out the plan: each step executed (or replayed), its outcome sent back."""
        scopes = [_Scope("", dict(self.parameters), top)]
        seen: set[str] = set()
        reply: Any = None
        try:
            while True:
                try:
                    instruction = plan.send(reply)
                except StopIteration:
                    break
                reply = self._instruction(instruction, scopes, seen)
        finally:
            plan.close()  # a plan's own ``finally`` blocks run when the run stops early
        if len(scopes) > 1 or scopes[0].sweep is not None:
            raise CampaignError(
                "the plan ended inside a sweep: every BeginSweep needs its iterations and an "
                "EndSweep (use camd.campaign.plan.sweep)"
            )

    def _instruction(self, instruction: Any, scopes: list[_Scope], seen: set[str]) -> Any:
        scope = scopes[-1]
        if isinstance(instruction, BeginSweep):
            key = self._new_key(scope, instruction.id, seen)
            if scope.sweep is not None:
                raise CampaignError(f"sweep {key}: begun inside sweep {scope.sweep.key}'s own "
                                    "level, outside an iteration")  # fmt: skip
            scope.sweep = _OpenSweep(instruction, key)
            return None
        if isinstance(instruction, BeginIteration):
            sweep = scope.sweep
            if sweep is None:
                raise CampaignError("an iteration begun outside a sweep (BeginSweep first)")
            i, values = len(sweep.iterations), sweep.begin.values
            if (
                instruction.index != i
                or i >= len(values)
                or not (instruction.value is values[i] or instruction.value == values[i])
            ):
                raise CampaignError(
                    f"sweep {sweep.key}: iteration {instruction.index} ({instruction.value!r}) "
                    f"out of order: expected iteration {i} of the {len(values)} values"
                )
            names = {**scope.names, sweep.begin.parameter: instruction.value}
            scopes.append(_Scope(f"{sweep.key}[{i}]/", names, Level(parent=scope.level)))
            return None
        if isinstance(instruction, EndIteration):
            if len(scopes) == 1 or scope.sweep is not None:
                raise CampaignError("EndIteration without an iteration in progress (or with a "
                                    "sweep still open inside it)")  # fmt: skip
            scopes.pop()
            parent = scopes[-1]
            assert parent.sweep is not None
            parent.sweep.iterations.append(scope.level)
            return None
        if isinstance(instruction, EndSweep):
            sweep = scope.sweep
            if sweep is None or len(sweep.iterations) != len(sweep.begin.values):
                raise CampaignError("EndSweep without a sweep whose iterations have all run")
            self._close_sweep(sweep, scope.level)
            scope.sweep = None
            return None
        if isinstance(instruction, ConfigureStep | AcquireStep | MeasureStep | CheckStep):
            if scope.sweep is not None:
                raise CampaignError(f"step {instruction.id}: inside sweep {scope.sweep.key} "
                                    "but outside its iterations")  # fmt: skip
            key = self._new_key(scope, instruction.id, seen)
            return self._step(instruction, key, scope)
        raise CampaignError(
            f"the plan yielded {type(instruction).__name__}: a plan yields steps (configure, "
            "acquire, measure, check) and sweep markers (camd.campaign.plan)"
        )

    @staticmethod
    def _new_key(scope: _Scope, step_id: str, seen: set[str]) -> str:
        key = f"{scope.prefix}{step_id}"
        if key in seen:
            raise CampaignError(
                f"step {key}: its id is used twice at one level; give each step its own id "
                "(state, files and results are named after it)"
            )
        seen.add(key)
        return key

    def _step(self, step: ExecutedStep, key: str, scope: _Scope) -> Any:
        """Execute one step instance (or replay it), make its outcome visible; the reply to
        the plan."""
        record = self.state.completed.get(key)
        replayed = record is not None and not isinstance(step, ConfigureStep)
        self.progress.step(key, step.title or step.id, replayed=replayed)
        self._step_number += 1
        of = "" if self._steps_total is None else f"/{self._steps_total}"
        self._say(
            f"step {self._step_number}{of} {step.kind} {key}" + (" (replayed)" if replayed else ""),
            self._step_number - 1,
        )
        if record is None or isinstance(step, ConfigureStep):
            self.state.checkpoint(self.interrupt)
            try:
                record = self.steps.execute(step, key, scope.names, scope.level)
            except (CamdError, CampaignError):
                # Stopped by a pause or an abort: not a failure of the step.
                self.state.checkpoint(self.interrupt)
                raise
            if isinstance(step, AcquireStep):
                # Possibly cut short by the pause: done again on resume.
                self.state.checkpoint(self.interrupt)
            self.state.record(key, record)
        self._apply(step, key, record, scope.level)
        self.progress.advance()
        if self.stop_after in (key, step.id) and not replayed:
            raise CampaignInterrupted(f"stopped after {key} (stop_after)")
        if isinstance(step, AcquireStep):
            return record["doc"]
        if isinstance(step, MeasureStep):
            return dict(record["results"])
        if isinstance(step, CheckStep):
            return dict(record["check"])
        return None

    def _apply(self, step: Any, key: str, record: dict[str, Any], level: Level) -> None:
        """Make a completed instance's outcome visible to the steps after it."""
        if isinstance(step, AcquireStep):
            path = self.out_dir / record["file"]
            level.files[step.id] = Acquired(record["how"], path, record["doc"])
            self._files[key] = record["file"]
        elif isinstance(step, MeasureStep):
            level.results.update(record["results"])
        elif isinstance(step, CheckStep):
            self._checks.append(record["check"])

    @staticmethod
    def _close_sweep(sweep: _OpenSweep, level: Level) -> None:
        # A result measured inside the sweep becomes a list over its values, in order.
        produced: list[str] = []
        for inner in sweep.iterations:
            produced += [n for n in inner.results if n not in produced]
        if sweep.begin.record:
            level.results[sweep.begin.parameter] = list(sweep.begin.values)
        for name in produced:
            level.results[name] = [inner.results.get(name) for inner in sweep.iterations]

    def _say(self, what: str, done: int) -> None:
        """Tell the daemon what the campaign is doing, for observers (GET /api/v1/control);
        informative only: a daemon that refuses it (an older one) does not stop the run."""
        text = "".join(
            ch if ch.isprintable() else " " for ch in f"campaign {self.spec.name}: {what}"
        )
        with contextlib.suppress(CamdError):
            self.client.set_activity(text[:ACTIVITY_TEXT_MAX], done, self._steps_total)

    def _preflight(self) -> None:
        """Substitute the parameters into every step (every sweep value too) and validate it,
        so that a bad parameter refuses the campaign before its baseline changes the camera
        (``check_campaign``; camctl has done it already, naming the file)."""
        check_campaign(self.spec, f"campaign {self.spec.name}", quick=self.quick)

    # -- the camera ------------------------------------------------------------------------------

    def _stop_device(self) -> None:
        # Best effort after Ctrl-C: leave no stream or scan running behind us.
        for stop in (self.client.stop_scan, self.client.stop_stream):
            with contextlib.suppress(CamdError):
                stop()
