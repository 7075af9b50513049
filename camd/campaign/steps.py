"""The step executors of a campaign run: configure, acquire, measure and check, one step
instance at a time, through ``camd.client`` only (docs/campaigns.md).

``CampaignRunner`` (``camd.campaign.runner``) drives the plan and holds a ``StepExecutor``,
which carries out one step instance with its ``${...}`` references substituted
(``StepExecutor.execute``) and returns the instance's record, the plain JSON the state file
keeps: an acquisition's file and document, a measurement's results, a check's outcome.

Determinism: on the simulated camera the executor re-seeds the simulator's random streams
(PUT /api/v1/sim/seed) before every acquisition with a seed derived from the campaign's seed
and the instance's key (``camd.campaign.state.instance_seed``), so an acquisition sees the same
noise whether the run was interrupted before it or not.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, TypeVar, cast

from camd.campaign.acquisitions import run_acquisition
from camd.campaign.measurements import MEASUREMENTS, Acquired
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
    WheelAcquire,
    resolve,
)
from camd.campaign.state import instance_seed
from camd.client import CamdClient, CamdError

__all__ = ["Level", "StepExecutor", "check_camera", "plain"]

T = TypeVar("T")


@dataclass
class Level:
    """Results and acquisitions visible at one nesting level (a sweep iteration)."""

    results: dict[str, Any] = field(default_factory=dict)
    files: dict[str, Acquired] = field(default_factory=dict)
    parent: Level | None = None

    def result(self, path: str) -> Any:
        """A result in scope by name, or a path into a mapping result (``rms_db.tao12``)."""
        name, *keys = path.split(".")
        level: Level | None = self
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
        level: Level | None = self
        while level is not None:
            if step_id in level.files:
                return level.files[step_id]
            level = level.parent
        raise KeyError(step_id)


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


@dataclass(eq=False)
class StepExecutor:
    """Executes step instances for a run into ``out_dir`` (acquisitions into ``raw_dir``)
    through ``client``. ``seed`` is the campaign's seed; ``sim`` says whether the daemon drives
    the simulated camera (None: ask the daemon, once).
    """

    client: CamdClient
    seed: int
    out_dir: Path
    raw_dir: Path
    sim: bool | None

    def execute(self, step: Any, key: str, names: dict[str, Any], level: Level) -> dict[str, Any]:
        """Carry out one step instance (``key``) with ``names`` (the parameters, the sweep's
        values) and the results in scope at ``level``; its record, or CampaignError naming it."""
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

    def _configure(self, step: ConfigureStep) -> dict[str, Any]:
        c = self.client
        if step.registers:
            c.write_registers(dict(step.registers))
        if step.mode is not None:
            c.set_mode(str(step.mode))
        if step.scene is not None:
            self.require_sim("scene")
            c.set_scene(step.scene)
        if step.stage is not None:
            self.require_sim("stage")
            c.set_stage(track=bool(step.stage.track), speed_m_s=float(step.stage.speed_m_s))
        if step.stage_faults is not None:
            self.require_sim("stage_faults")
            c.set_stage_faults(**{k: float(v) for k, v in step.stage_faults})
        if step.stage_speed_m_s is not None:
            c.run_stage(float(step.stage_speed_m_s))
        if step.wheel_speed_deg_s is not None:
            c.set_wheel_speed(float(step.wheel_speed_deg_s))
        if step.wheel_compensation is not None:
            c.set_wheel_compensation(bool(step.wheel_compensation))
        if step.polarizer_deg is not None:
            self.require_sim("polarizer_deg")
            c.set_polarizer(float(step.polarizer_deg))
        return {"configured": True}

    def _acquire(self, step: AcquireStep, key: str) -> dict[str, Any]:
        name = key.replace("/", "__").replace("[", "_").replace("]", "") + ".h5"
        path = self.raw_dir / name
        path.unlink(missing_ok=True)  # left by an interrupted attempt: the daemon makes it new
        if self.on_sim():
            self.client.set_sim_seed(instance_seed(self.seed, key))
        doc: dict[str, Any]
        if isinstance(step.stare, StareAcquire):
            s = step.stare
            doc = dict(
                self.client.acquire(
                    int(s.frames),
                    mode=None if s.mode is None else cast(Literal["area", "tdi"], str(s.mode)),
                    stages=None if s.stages is None else int(s.stages),
                    binning=cast(Literal["off", "2x2"], str(s.binning)),
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
            self.client.start_scan(
                int(sc.stages), int(sc.lines), out=str(path), scene=sc.scene,
                mode=cast(Literal["sum", "mean"], sc.mode),
                out_bits=None if sc.out_bits is None else int(sc.out_bits),
                binning=cast(Literal["off", "2x2"], sc.binning), quicklook=False,
                drive_stage=bool(sc.drive_stage),
                closed_loop=None if sc.closed_loop is None else bool(sc.closed_loop),
                image_loop=None if sc.image_loop is None else bool(sc.image_loop),
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
        return {"how": step.how, "file": str(path.relative_to(self.out_dir)), "doc": plain(doc)}

    def _polarization(self, p: PolarizationAcquire, path: Path) -> dict[str, Any]:
        """A reference-polariser scan (camd.motion.polarization_run), its frame means written
        to ``path``; the polariser is the simulated camera's."""
        from camd.motion.polarization_run import acquire_polarization, write_polarization_scan

        self.require_sim("polarization")
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

    def _measure(self, step: MeasureStep, level: Level) -> dict[str, Any]:
        inputs = {
            arg: _earlier(
                level.acquired,
                source,
                f"step {step.id}: inputs.{arg}: step {source!r} has not acquired anything "
                "before this step (inputs name an earlier acquire step in scope)",
            )
            for arg, source in step.inputs.items()
        }
        kwargs = dict(step.args)
        for arg, name in step.from_results.items():
            kwargs[arg] = _earlier(
                level.result,
                name,
                f"step {step.id}: from_results.{arg}: no result {name!r} measured before this step",
            )
        produced = MEASUREMENTS[step.function](inputs, **kwargs)
        wanted = step.results if step.results is not None else list(produced)
        missing = [n for n in wanted if n not in produced]
        if missing:
            raise CampaignError(
                f"step {step.id}: results: {step.function} gave no {', '.join(missing)} "
                f"(it gives {', '.join(produced)})"
            )
        return {"results": plain({n: produced[n] for n in wanted})}

    def _check(self, step: CheckStep, key: str, level: Level) -> dict[str, Any]:
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
            "id": key, "result": step.result, "value": plain(value), "min": lo, "max": hi,
            "passed": passed,
        }  # fmt: skip
        return {"check": check}

    def on_sim(self) -> bool:
        """Whether the daemon drives the simulated camera (asked once, then remembered)."""
        if self.sim is None:
            link = self.client.status().get("link") or {}
            self.sim = link.get("sim_pid") is not None
        return self.sim

    def require_sim(self, key: str) -> None:
        """CampaignError unless the daemon drives the simulated camera (``key`` needs it)."""
        if not self.on_sim():
            raise CampaignError(
                f"`{key}` drives the simulated camera only; this daemon runs hardware"
            )


def _earlier(find: Callable[[str], T], name: str, refusal: str) -> T:
    """What an earlier step left under ``name`` (``find`` raises KeyError where there is none);
    CampaignError with ``refusal`` where there is none."""
    try:
        return find(name)
    except KeyError:
        raise CampaignError(refusal) from None


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


def plain(value: Any) -> Any:
    """JSON-safe: numpy scalars to Python, NaN/inf to None (JSON has neither)."""
    if isinstance(value, Mapping):
        return {str(k): plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [plain(v) for v in value]
    if hasattr(value, "item") and callable(value.item):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value
