"""Run a campaign against a daemon through ``camd.client`` only (docs/campaigns.md).

``CampaignRunner(client, spec, out_dir).run()`` runs a YAML campaign, and
``CampaignRunner(client, None, out_dir, plan=load_plan(path)).run()`` a Python one: either way
a plan (``camd.campaign.plan``: a generator of steps and sweep markers; ``yaml_plan`` for the
YAML steps) says what to do, and this runner does it, step by step, sending each step's
outcome back to the plan. Every executed step
instance (a step, or a step inside one iteration of a sweep: ``sweep_m[1]/stare``) is
recorded in ``out_dir/state.json`` as soon as it completes, with its results, its check
outcome or its raw file. Running again into the same directory resumes: recorded instances
are replayed from the state file, not executed, except ``configure`` steps, which are always
applied again (they are cheap and idempotent, and the device must be in the state the next
step expects, possibly after a daemon restart).

Determinism: on the simulated camera the runner re-seeds the simulator's random streams
(PUT /api/v1/sim/seed) before every acquisition with a seed derived from the campaign's seed
and the instance's key, so an acquisition sees the same noise whether the run was interrupted
before it or not. results.json is a pure function of the recorded instances.

Observers see the progress: before each step instance the runner, which holds control, says
what it does (PUT /api/v1/control/activity: ``campaign <name>: step <i>/<n> <kind> <key>`` with
i - 1 steps done of n); giving control back at the end clears it.

Ctrl-C (KeyboardInterrupt) stops the step in progress (the stream or scan is stopped) and
raises ``CampaignInterrupted``; everything completed before it is in the state file.

Pause and abort (a campaign job of the daemon, ``camd.campaign.worker``): the runner asks its
``interrupt`` hook before each step it executes, and again after an acquisition (whether it
ended or failed: a pause stops the daemon's stream or scan, and a stopped acquisition is
never recorded). ``"pause"`` raises ``CampaignPaused``, ``"abort"`` ``CampaignAborted``; both
leave the state file as an interrupt does, so a resumed run executes the stopped step again.

The daemon's settings before the first step are kept in ``settings_before.json`` until the run
ends, so that a run resumed after a pause, a crash or a daemon restart puts back the settings
the campaign found, not the ones it left.
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import json
import math
import os
import zlib
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, Protocol, cast

from camd.campaign.acquisitions import run_acquisition
from camd.campaign.baseline import Settings, apply_baseline, capture, restore
from camd.campaign.checks import check_campaign
from camd.campaign.measurements import MEASUREMENTS, Acquired
from camd.campaign.plan import (
    BeginIteration,
    BeginSweep,
    EndIteration,
    EndSweep,
    ExecutedStep,
    Plan,
    PlanCampaign,
    yaml_plan,
)
from camd.campaign.spec import (
    AcquireStep,
    CampaignError,
    CampaignSpec,
    CheckStep,
    ConfigureStep,
    MeasureStep,
    PolarizationAcquire,
    ScanAcquire,
    StareAcquire,
    SweepStep,
    WheelAcquire,
    resolve,
    sweep_values,
)
from camd.client import CamdClient, CamdError

__all__ = [
    "CampaignAborted",
    "CampaignInterrupted",
    "CampaignOutcome",
    "CampaignPaused",
    "CampaignRunner",
    "Progress",
]

STATE_FORMAT = "camd-campaign-state"
STATE_VERSION = 1


CONTROL_TTL_S = 60.0  # the campaign's control lease, renewed every 20 s while it runs
ACTIVITY_TEXT_MAX = 200  # the daemon's limit on an activity's text


class CampaignInterrupted(Exception):
    """The run stopped before its end (Ctrl-C or ``stop_after``); the state file has every
    completed step, so running again into the same directory resumes."""


class CampaignPaused(CampaignInterrupted):
    """Paused on request (the ``interrupt`` hook said "pause"); resumable."""


class CampaignAborted(CampaignInterrupted):
    """Aborted on request (the ``interrupt`` hook said "abort")."""


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
class _Level:
    """Results and acquisitions visible at one nesting level (a sweep iteration)."""

    results: dict[str, Any] = field(default_factory=dict)
    files: dict[str, Acquired] = field(default_factory=dict)
    parent: _Level | None = None

    def result(self, path: str) -> Any:
        """A result in scope by name, or a path into a mapping result (``rms_db.tao12``)."""
        name, *keys = path.split(".")
        level: _Level | None = self
        while level is not None:
            if name in level.results:
                value = level.results[name]
                for key in keys:
                    if not isinstance(value, Mapping) or key not in value:
                        raise KeyError(path)
                    value = value[key]
                return value
            level = level.parent
        raise KeyError(path)

    def visible(self) -> dict[str, Any]:
        """Every result in scope, the innermost level's winning."""
        outer = self.parent.visible() if self.parent is not None else {}
        return {**outer, **self.results}

    def acquired(self, step_id: str) -> Acquired:
        level: _Level | None = self
        while level is not None:
            if step_id in level.files:
                return level.files[step_id]
            level = level.parent
        raise KeyError(step_id)


@dataclass
class _OpenSweep:
    """A sweep the plan has begun: its iterations' levels so far."""

    begin: BeginSweep
    key: str
    iterations: list[_Level] = field(default_factory=list)


@dataclass
class _Scope:
    """Where the plan is: the key prefix, the names ``${...}`` sees, the results' level, and
    the sweep open at this level, if any."""

    prefix: str
    names: dict[str, Any]
    level: _Level
    sweep: _OpenSweep | None = None


def instance_seed(seed: int, key: str) -> int:
    """The simulator seed of one step instance: the campaign's seed and the instance's key
    hashed to 32 bits (stable across runs and Python versions, unlike ``hash``)."""
    return zlib.crc32(f"{seed}/{key}".encode())


def spec_digest(spec: CampaignSpec, quick: bool, source: str | None = None) -> str:
    """What a state file must have been made by to be resumed: the campaign (a Python
    campaign's ``source`` too) and --quick."""
    doc: dict[str, Any] = {"spec": spec.model_dump(mode="json"), "quick": quick}
    if source is not None:
        doc["source"] = source
    text = json.dumps(doc, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()


def check_camera(
    client: CamdClient, spec: CampaignSpec, on_sim: Callable[[], bool] | None = None
) -> None:
    """CampaignError unless the daemon's sensor is the campaign's profile (physics differ per
    sensor). ``on_sim`` says whether the daemon drives the simulated camera (None: ask it).
    The runner checks this before its first step; a daemon's campaign job before it is
    accepted (``camd.campaign.worker check --url``)."""
    sensor = client.timing()["sensor"]
    if sensor == spec.profile:
        return
    simulated = on_sim() if on_sim is not None else client.status()["link"].get("sim_pid")
    if simulated:
        raise CampaignError(
            f"campaign {spec.name!r} is written for the {spec.profile} camera but the daemon "
            f"simulates {sensor}: run `camctl campaign run FILE --sim`, which starts a "
            f"simulator with the campaign's profile, or start the daemon with [sim] profile = "
            f'"{spec.profile}" and [sensor] name = "{spec.profile}"'
        )
    raise CampaignError(
        f"campaign {spec.name!r} is written for the {spec.profile} sensor; the camera on this "
        f"daemon has a {sensor}: refusing to run it on another sensor"
    )


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
        self.sim = sim
        self.stop_after = stop_after
        self.interrupt = interrupt
        self.parameters = self.spec.parameters_for(quick)
        self.state_path = self.out_dir / "state.json"
        self.settings_path = self.out_dir / "settings_before.json"
        self.raw_dir = self.out_dir / "raw"
        self._completed: dict[str, dict[str, Any]] = {}
        self._checks: list[dict[str, Any]] = []
        self._files: dict[str, str] = {}
        self.restored: list[str] = []  # the daemon's settings put back after the run
        self._step_number = 0  # step instances begun so far in this run
        self._steps_total: int | None = 0
        self._digest = spec_digest(self.spec, quick, None if plan is None else plan.source)

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
        self._load_state()
        self._check_camera()
        if self.plan is None:
            self._steps_total = self._count(self.spec.steps, self.parameters)
        else:
            self._steps_total = self.plan.steps_in_run(dict(self.parameters))
        self._step_number = 0
        self.progress.begin(self._steps_total)
        top = _Level()
        try:
            # The campaign holds control for its whole run: no other client changes the
            # camera between its steps (they may watch). It starts from its baseline and puts
            # back the daemon's settings when it ends, passed or failed.
            with self.client.holding_control(CONTROL_TTL_S):
                before = self._settings_before()
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
                f"interrupted; {len(self._completed)} completed step(s) saved in "
                f"{self.state_path}: run again with the same --out to resume"
            ) from None
        doc = self._results_doc(top)
        results_path = self.out_dir / "results.json"
        results_path.write_text(json.dumps(doc, indent=2) + "\n", encoding="utf-8")
        self.settings_path.unlink(missing_ok=True)  # the run has ended: nothing to put back
        outcome = CampaignOutcome(doc, results_path)
        if report:
            from camd.campaign.report import write_report

            outcome.report_path = write_report(self.spec, doc, self.out_dir, restored=self.restored)
        return outcome

    def _results_doc(self, top: _Level) -> dict[str, Any]:
        # Plain JSON in a fixed key order; nothing that differs between an interrupted and an
        # uninterrupted run (no times, no absolute paths).
        return {
            "campaign": self.spec.name,
            "profile": self.spec.profile,
            "seed": self.spec.seed,
            "quick": self.quick,
            "passed": all(c["passed"] for c in self._checks),
            "parameters": self.parameters,
            "results": _plain(top.results),
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

    def _drive(self, plan: Plan, top: _Level) -> None:
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
            scopes.append(_Scope(f"{sweep.key}[{i}]/", names, _Level(parent=scope.level)))
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
        record = self._completed.get(key)
        replayed = record is not None and not isinstance(step, ConfigureStep)
        self.progress.step(key, step.title or step.id, replayed=replayed)
        self._step_number += 1
        of = "" if self._steps_total is None else f"/{self._steps_total}"
        self._say(
            f"step {self._step_number}{of} {step.kind} {key}" + (" (replayed)" if replayed else ""),
            self._step_number - 1,
        )
        if record is None or isinstance(step, ConfigureStep):
            self._checkpoint()
            try:
                record = self._execute(step, key, scope.names, scope.level)
            except (CamdError, CampaignError):
                self._checkpoint()  # stopped by a pause or an abort: not a failure of the step
                raise
            if isinstance(step, AcquireStep):
                self._checkpoint()  # possibly cut short by the pause: done again on resume
            self._completed[key] = record
            self._save_state()
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

    def _checkpoint(self) -> None:
        """Raise CampaignPaused or CampaignAborted if the ``interrupt`` hook asks for it."""
        if self.interrupt is None:
            return
        asked = self.interrupt()
        if asked == "pause":
            raise CampaignPaused(
                f"paused; {len(self._completed)} completed step(s) saved in {self.state_path}"
            )
        if asked == "abort":
            raise CampaignAborted(
                f"aborted; {len(self._completed)} completed step(s) saved in {self.state_path}"
            )

    def _settings_before(self) -> Settings:
        """The settings to put back at the end: those this run (or the run it resumes) found
        before its first step, kept on disk until the run ends."""
        if self.settings_path.exists():
            try:
                return Settings(**json.loads(self.settings_path.read_text(encoding="utf-8")))
            except (OSError, ValueError, TypeError):
                pass  # unreadable: capture afresh (the settings now are the best guess left)
        before = capture(self.client)
        tmp = self.settings_path.with_suffix(".json.tmp")
        tmp.write_text(json.dumps(dataclasses.asdict(before), indent=1) + "\n", encoding="utf-8")
        os.replace(tmp, self.settings_path)
        return before

    @staticmethod
    def _close_sweep(sweep: _OpenSweep, level: _Level) -> None:
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

    def _sweep_values(self, step: SweepStep, names: dict[str, Any]) -> list[Any]:
        try:
            return sweep_values(step, names)
        except CampaignError as exc:
            raise CampaignError(f"step {step.id!r}: {exc}") from None

    def _preflight(self) -> None:
        """Substitute the parameters into every step (every sweep value too) and validate it,
        so that a bad parameter refuses the campaign before its baseline changes the camera
        (``check_campaign``; camctl has done it already, naming the file)."""
        check_campaign(self.spec, f"campaign {self.spec.name}", quick=self.quick)

    def _count(self, steps: list[Any], names: dict[str, Any]) -> int:
        total = 0
        for step in steps:
            if isinstance(step, SweepStep):
                for value in self._sweep_values(step, names):
                    total += self._count(step.steps, {**names, step.parameter: value})
            else:
                total += 1
        return total

    # -- one step instance ----------------------------------------------------------------------

    def _execute(self, step: Any, key: str, names: dict[str, Any], level: _Level) -> dict[str, Any]:
        # ${name} may name a result measured before this step, as well as a parameter.
        names = {**level.visible(), **names}
        try:
            if isinstance(step, ConfigureStep):
                return self._configure(_resolved(step, names))
            if isinstance(step, AcquireStep):
                return self._acquire(_resolved(step, names), key)
            if isinstance(step, MeasureStep):
                return self._measure(_resolved(step, names), level)
            if isinstance(step, CheckStep):
                return self._check(_resolved(step, names), key, level)
        except CamdError as exc:
            raise CampaignError(f"step {key}: the daemon refused: {exc.message}") from None
        except (ValueError, KeyError, TypeError) as exc:
            if isinstance(exc, CampaignError):
                raise
            raise CampaignError(f"step {key}: {exc}") from None
        raise CampaignError(f"step {key}: unknown kind {step.kind!r}")

    def _apply(self, step: Any, key: str, record: dict[str, Any], level: _Level) -> None:
        """Make a completed instance's outcome visible to the steps after it."""
        if isinstance(step, AcquireStep):
            path = self.out_dir / record["file"]
            level.files[step.id] = Acquired(record["how"], path, record["doc"])
            self._files[key] = record["file"]
        elif isinstance(step, MeasureStep):
            level.results.update(record["results"])
        elif isinstance(step, CheckStep):
            self._checks.append(record["check"])

    def _configure(self, step: ConfigureStep) -> dict[str, Any]:
        c = self.client
        if step.registers:
            c.write_registers(dict(step.registers))
        if step.mode is not None:
            c.set_mode(str(step.mode))
        if step.scene is not None:
            self._require_sim("scene")
            c.set_scene(step.scene)
        if step.stage is not None:
            self._require_sim("stage")
            c.set_stage(track=bool(step.stage.track), speed_m_s=float(step.stage.speed_m_s))
        if step.stage_faults is not None:
            self._require_sim("stage_faults")
            c.set_stage_faults(**{k: float(v) for k, v in step.stage_faults})
        if step.stage_speed_m_s is not None:
            c.run_stage(float(step.stage_speed_m_s))
        if step.wheel_speed_deg_s is not None:
            c.set_wheel_speed(float(step.wheel_speed_deg_s))
        if step.wheel_compensation is not None:
            c.set_wheel_compensation(bool(step.wheel_compensation))
        if step.polarizer_deg is not None:
            self._require_sim("polarizer_deg")
            c.set_polarizer(float(step.polarizer_deg))
        return {"configured": True}

    def _acquire(self, step: AcquireStep, key: str) -> dict[str, Any]:
        name = key.replace("/", "__").replace("[", "_").replace("]", "") + ".h5"
        path = self.raw_dir / name
        path.unlink(missing_ok=True)  # left by an interrupted attempt: the daemon makes it new
        if self._on_sim():
            self.client.set_sim_seed(instance_seed(self.spec.seed, key))
        doc: dict[str, Any]
        if isinstance(step.stare, StareAcquire):
            s = step.stare
            doc = dict(
                self.client.acquire(
                    int(s.frames),
                    mode=None if s.mode is None else str(s.mode),
                    stages=None if s.stages is None else int(s.stages),
                    binning=str(s.binning),
                    record=str(path),
                    timeout_s=None if s.timeout_s is None else float(s.timeout_s),
                )
            )
            stats = doc.get("stats", {})
            if int(stats.get("frames", 0)) != int(s.frames):
                raise CampaignError(
                    f"step {key}: {stats.get('frames')} of {s.frames} frames arrived "
                    f"({stats.get('lost')} lost, {stats.get('corrupt')} corrupt, "
                    f"{stats.get('short')} short, {stats.get('overruns')} overrun: the host "
                    "fell behind); run the step again (`--resume`)"
                )
        elif isinstance(step.scan, ScanAcquire):
            sc = step.scan
            # mode and binning may come from a reference, a str to the type checker; the daemon
            # refuses any other value (400).
            self.client.start_scan(
                int(sc.stages), int(sc.lines), out=str(path), scene=sc.scene,
                mode=cast(Literal["sum", "mean"], sc.mode),
                out_bits=None if sc.out_bits is None else int(sc.out_bits),
                binning=cast(Literal["off", "2x2"], sc.binning), quicklook=False,
                drive_stage=bool(sc.drive_stage),
                closed_loop=None if sc.closed_loop is None else bool(sc.closed_loop),
                dv_over_v=float(sc.dv_over_v),
            )  # fmt: skip
            doc = dict(self.client.wait_scan(float(sc.timeout_s)))
            if doc.get("error"):
                raise CampaignError(f"step {key}: the scan failed: {doc['error']}")
            if doc.get("state") != "done":
                raise CampaignError(
                    f"step {key}: the scan ended {doc.get('state')} after {doc.get('lines')} of "
                    f"{doc.get('lines_wanted')} lines (stopped by another client or an emergency stop); run "
                    "the step again (`--resume`)"
                )
        elif isinstance(step.polarization, PolarizationAcquire):
            doc = self._polarization(step.polarization, path)
        elif step.custom is not None:
            doc = run_acquisition(step.custom.kind, self.client, path, dict(step.custom.args))
        else:
            assert isinstance(step.wheel, WheelAcquire)
            w = step.wheel
            channels = w.channels if isinstance(w.channels, list) else []
            doc = dict(
                self.client.wheel_acquire(
                    [int(ch) for ch in channels],
                    passes=int(w.passes),
                    exposure_s=None if w.exposure_s is None else float(w.exposure_s),
                    compensated=None if w.compensated is None else bool(w.compensated),
                    record=str(path),
                    timeout_s=None if w.timeout_s is None else float(w.timeout_s),
                )
            )
        return {"how": step.how, "file": str(path.relative_to(self.out_dir)), "doc": _plain(doc)}

    def _polarization(self, p: PolarizationAcquire, path: Path) -> dict[str, Any]:
        """A reference-polariser scan (camd.motion.polarization_run), its frame means written
        to ``path``; the polariser is the simulated camera's."""
        from camd.motion.polarization_run import acquire_polarization, write_polarization_scan

        self._require_sim("polarization")
        compensated = p.compensated if isinstance(p.compensated, list) else [p.compensated]
        try:
            scan = acquire_polarization(
                self.client,
                channels=None if not isinstance(p.channels, list) else [int(c) for c in p.channels],
                exposures_s=[float(e) for e in p.exposures_s],
                step_deg=float(p.step_deg),
                settings=[bool(c) for c in compensated],
            )
        except RuntimeError as exc:  # a frame was lost: the message says what to do
            raise CampaignError(str(exc)) from None
        write_polarization_scan(path, scan)
        return scan.summary()

    def _measure(self, step: MeasureStep, level: _Level) -> dict[str, Any]:
        inputs = {}
        for arg, source in step.inputs.items():
            try:
                inputs[arg] = level.acquired(source)
            except KeyError:
                raise CampaignError(
                    f"step {step.id}: inputs.{arg}: step {source!r} has not acquired anything "
                    "before this step (inputs name an earlier acquire step in scope)"
                ) from None
        kwargs = dict(step.args)
        for arg, name in step.from_results.items():
            try:
                kwargs[arg] = level.result(name)
            except KeyError:
                raise CampaignError(
                    f"step {step.id}: from_results.{arg}: no result {name!r} measured before "
                    "this step"
                ) from None
        produced = MEASUREMENTS[step.function](inputs, **kwargs)
        wanted = step.results if step.results is not None else list(produced)
        missing = [n for n in wanted if n not in produced]
        if missing:
            raise CampaignError(
                f"step {step.id}: results: {step.function} gave no {', '.join(missing)} "
                f"(it gives {', '.join(produced)})"
            )
        return {"results": _plain({n: produced[n] for n in wanted})}

    def _check(self, step: CheckStep, key: str, level: _Level) -> dict[str, Any]:
        try:
            value = level.result(step.result)
        except KeyError:
            raise CampaignError(
                f"step {step.id}: result: no result {step.result!r} measured before this step"
            ) from None
        lo = None if step.min is None else float(step.min)
        hi = None if step.max is None else float(step.max)
        numbers = list(_numbers(value))

        def ok(x: float) -> bool:
            return math.isfinite(x) and (lo is None or x >= lo) and (hi is None or x <= hi)

        passed = bool(numbers) and all(ok(x) for x in numbers)
        check = {
            "id": key, "result": step.result, "value": _plain(value), "min": lo, "max": hi,
            "passed": passed,
        }  # fmt: skip
        return {"check": check}

    # -- the camera, the state file -------------------------------------------------------------

    def _on_sim(self) -> bool:
        if self.sim is None:
            link = self.client.status().get("link") or {}
            self.sim = link.get("sim_pid") is not None
        return self.sim

    def _require_sim(self, key: str) -> None:
        if not self._on_sim():
            raise CampaignError(
                f"`{key}` drives the simulated camera only; this daemon runs hardware"
            )

    def _check_camera(self) -> None:
        check_camera(self.client, self.spec, self._on_sim)

    def _stop_device(self) -> None:
        # Best effort after Ctrl-C: leave no stream or scan running behind us.
        for stop in (self.client.stop_scan, self.client.stop_stream):
            with contextlib.suppress(CamdError):
                stop()

    def _load_state(self) -> None:
        if not self.state_path.exists():
            return
        try:
            state = json.loads(self.state_path.read_text(encoding="utf-8"))
        except (OSError, ValueError) as exc:
            raise CampaignError(
                f"{self.state_path}: unreadable state file ({exc}); remove it to start over"
            ) from None
        if state.get("format") != STATE_FORMAT or state.get("version") != STATE_VERSION:
            raise CampaignError(f"{self.state_path} is not a campaign state file; remove it")
        if state.get("digest") != self._digest:
            raise CampaignError(
                f"{self.state_path} was written by another version of campaign "
                f"{state.get('campaign')!r} (or with{'out' if self.quick else ''} --quick): "
                "choose a new --out directory or remove the state file to start over"
            )
        self._completed = dict(state["completed"])

    def _save_state(self) -> None:
        state = {
            "format": STATE_FORMAT,
            "version": STATE_VERSION,
            "campaign": self.spec.name,
            "digest": self._digest,
            "completed": self._completed,
        }
        tmp = self.state_path.with_suffix(".json.tmp")
        tmp.write_text(json.dumps(state, indent=1) + "\n", encoding="utf-8")
        os.replace(tmp, self.state_path)  # atomic: an interrupt never leaves half a file


def _resolved(step: Any, names: dict[str, Any]) -> Any:
    """The step with its ``${...}`` references replaced, validated again with their values."""
    data = step.model_dump(exclude_none=False)
    try:
        return type(step).model_validate(resolve(data, names))
    except ValueError as exc:
        raise CampaignError(f"step {step.id!r}: after substituting parameters: {exc}") from None


def _numbers(value: Any) -> Iterator[float]:
    if isinstance(value, bool | int | float):
        yield float(value)
    elif isinstance(value, list):
        for v in value:
            yield from _numbers(v)
    elif isinstance(value, Mapping):
        for v in value.values():
            yield from _numbers(v)


def _plain(value: Any) -> Any:
    """JSON-safe: numpy scalars to Python, NaN/inf to None (JSON has neither)."""
    if isinstance(value, Mapping):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    if hasattr(value, "item") and callable(value.item):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value
