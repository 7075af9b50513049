"""Campaign files: the YAML schema as pydantic models (docs/campaigns.md describes every key).

A campaign declares the camera profile it was written for, a seed, named parameters (with
``quick`` overrides for CI-sized runs), a list of steps and the report's outputs::

    name: example_stare
    profile: hr400
    seed: 7
    parameters: {frames: 8, stages: [1, 2, 4]}
    quick: {stages: [1, 2]}
    steps:
      - {id: light, kind: configure, scene: "flat:photons=2e4", mode: area}
      - id: sweep_stages
        kind: sweep
        parameter: m
        values: ${stages}
        steps:
          - {id: stare, kind: acquire, stare: {frames: ${frames}}}
          - {id: snr, kind: measure, function: stare_psnr, inputs: {frames: stare}}
          - {id: psnr_ok, kind: check, result: psnr_db, min: 20}
    outputs:
      tables: [{title: PSNR, columns: [m, psnr_db]}]
      plots: [{title: PSNR against M, x: m, y: [psnr_db]}]

Step kinds are few and data-driven: ``configure`` (registers, mode, simulated scene, stage,
wheel), ``sweep`` (a parameter over values, with nested steps), ``acquire`` (stare, scan,
wheel or polarization, recorded to HDF5), ``measure`` (a function of
camd.campaign.measurements by name, on acquired data and/or earlier results) and ``check`` (a
result against min/max). ``${name}`` anywhere in a step's values refers to a parameter, an
enclosing sweep's variable or a result an earlier measure step declared; ``${name.key}`` to a
key of a mapping value. A whole-string reference takes the value with its type, an embedded
one is formatted into the text. References are checked when the file is loaded, the values
they resolve to when the step runs.

This module is the schema and the references; reading a file and explaining its errors is
``camd.campaign.loading`` (with ``camd.campaign.explain``), the checks against the camera's
profile and register map ``camd.campaign.checks``.
"""

from __future__ import annotations

import re
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

__all__ = [
    "AcquireStep",
    "CampaignError",
    "CampaignSpec",
    "CheckStep",
    "ConfigureStep",
    "MeasureStep",
    "Outputs",
    "PlotSpec",
    "PolarizationAcquire",
    "Step",
    "SweepStep",
    "TableSpec",
    "resolve",
    "sweep_values",
    "text_of",
]

NAME = r"^[a-z][a-z0-9_]*$"
# ${name}, or ${name.key} for a key of a mapping value (a sweep over conditions).
REF_RE = re.compile(r"\$\{([a-z][a-z0-9_]*)((?:\.[A-Za-z0-9_]+)*)\}")
WHOLE_REF = r"^\$\{[a-z][a-z0-9_]*(\.[A-Za-z0-9_]+)*\}$"

RESULT_PATH = r"^[a-z][a-z0-9_]*(\.[A-Za-z0-9_]+)*$"
"""A result name, or a path into a result that is a mapping: ``model_db.tao12``."""

Ref = Annotated[str, Field(pattern=WHOLE_REF)]
"""A whole-string parameter reference, ``${name}``, where a number or list is expected."""

# Counts in the daemon's own ranges, so that a parameter out of them refuses the campaign
# before it starts (the runner checks every step with its parameters first), not at its step.
RANGES: dict[str, tuple[int, int]] = {
    "frames": (1, 0xFFFFFFFF),
    "stages": (1, 4096),
    "lines": (0, 10_000_000),
    "passes": (1, 1000),
    "seed": (0, 0xFFFFFFFF),
}
"""The valid range of each count, by key: the schema's bounds (its errors name them)."""

Frames = Annotated[int, Field(ge=RANGES["frames"][0], le=RANGES["frames"][1])]
Stages = Annotated[int, Field(ge=RANGES["stages"][0], le=RANGES["stages"][1])]
Lines = Annotated[int, Field(ge=RANGES["lines"][0], le=RANGES["lines"][1])]
Passes = Annotated[int, Field(ge=RANGES["passes"][0], le=RANGES["passes"][1])]


class CampaignError(ValueError):
    """A campaign file is invalid or cannot run; the message names the file, step and key."""


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, strict=True)


# -- steps ------------------------------------------------------------------------------------


class _Step(_Model):
    id: str = Field(pattern=NAME, description="unique step id (state, files and errors name it)")
    title: str = Field(default="", description="what the step does, for progress and reports")


class StageSetting(_Model):
    """The simulated stage: track the synchronous speed or run at a fixed speed."""

    track: bool | Ref = True
    speed_m_s: float | Ref = 0.0


class StageFaults(_Model):
    """The simulated stepper stage's imperfections (as ``--inject stage_*``)."""

    error: float | Ref = 0.0
    ripple: float | Ref = 0.0
    jitter: float | Ref = 0.0
    drift: float | Ref = 0.0
    load: float | Ref = 0.0


class ConfigureStep(_Step):
    """Set registers, mode, the simulated scene, stage and wheel (each optional)."""

    kind: Literal["configure"]
    registers: dict[str, int | str] = Field(
        default_factory=dict, description="REG, REG.field or GROUP -> value (written all at once)"
    )
    mode: Literal["area", "tdi"] | Ref | None = None
    scene: str | None = Field(default=None, description="simulator only: a scene spec")
    stage: StageSetting | None = Field(default=None, description="simulator only")
    stage_faults: StageFaults | None = Field(default=None, description="simulator only")
    stage_speed_m_s: float | Ref | None = Field(
        default=None, description="run the real stage at this signed speed (0 stops it)"
    )
    wheel_speed_deg_s: float | Ref | None = None
    wheel_compensation: bool | Ref | None = None
    polarizer_deg: float | Ref | None = Field(
        default=None, description="simulator only: the reference polariser's axis"
    )


class StareAcquire(_Model):
    """Stare: ``frames`` window frames recorded to HDF5 (camd.store.recording)."""

    frames: Frames | Ref = Field(default=10, description="frames to take (>= 1)")
    mode: Literal["area", "tdi"] | Ref | None = None
    stages: Stages | Ref | None = None
    binning: Literal["off", "2x2"] | Ref = "off"
    timeout_s: float | Ref | None = None


class ScanAcquire(_Model):
    """A push-broom TDI scan recorded to HDF5 (camd.store.tdi_recording)."""

    stages: Stages | Ref
    lines: Lines | Ref
    scene: str | None = None
    mode: Literal["sum", "mean"] | Ref = "sum"
    out_bits: int | Ref | None = None
    binning: Literal["off", "2x2"] | Ref = "off"
    dv_over_v: float | Ref = 0.0
    closed_loop: bool | Ref | None = None
    image_loop: bool | Ref | None = Field(
        default=None,
        description="close the loop on the image (line period and drift taps from the frames, "
        "docs/motion.md); null: the daemon's motion.image_loop",
    )
    drive_stage: bool | Ref = True
    timeout_s: float | Ref = 120.0


class WheelAcquire(_Model):
    """One frame per channel per pass through the turning filter wheel."""

    channels: list[int] | Ref
    passes: Passes | Ref = 1
    exposure_s: float | Ref | None = None
    compensated: bool | Ref | None = None
    timeout_s: float | Ref | None = None


class PolarizationAcquire(_Model):
    """A reference-polariser scan through the wheel's polarising channels (docs/physics.md §4):
    per compensation setting, exposure and reference angle one pass, the frame means recorded
    (camd.motion.polarization_run)."""

    channels: list[int] | Ref | None = None
    exposures_s: list[float] | Ref
    step_deg: float | Ref = 15.0
    compensated: bool | list[bool] | Ref = Field(
        default=[True, False], description="the settings to take: on, off or both"
    )


class CustomAcquire(_Model):
    """An acquisition kind registered in Python (``camd.campaign.acquisitions.acquisition``,
    e.g. by a Python campaign's module): its name and its keyword arguments."""

    kind: str = Field(pattern=NAME, description="a registered acquisition kind")
    args: dict[str, Any] = Field(default_factory=dict, description="its keyword arguments")


_ACQUIRE_KINDS = ("stare", "scan", "wheel", "polarization", "custom")


class AcquireStep(_Step):
    """Take data: exactly one of ``stare``, ``scan``, ``wheel``, ``polarization`` or
    ``custom`` (a registered kind); recorded under raw/."""

    kind: Literal["acquire"]
    stare: StareAcquire | None = None
    scan: ScanAcquire | None = None
    wheel: WheelAcquire | None = None
    polarization: PolarizationAcquire | None = None
    custom: CustomAcquire | None = None

    @model_validator(mode="after")
    def _exactly_one(self) -> AcquireStep:
        given = [k for k in _ACQUIRE_KINDS if getattr(self, k) is not None]
        if len(given) != 1:
            raise ValueError(
                "give exactly one of `stare`, `scan`, `wheel`, `polarization` or `custom`, got "
                + (", ".join(given) if given else "none")
            )
        return self

    @property
    def how(self) -> str:
        """``stare``, ``scan``, ``wheel``, ``polarization`` or the custom kind's name."""
        if self.custom is not None:
            return self.custom.kind
        return next(k for k in _ACQUIRE_KINDS if getattr(self, k) is not None)


class MeasureStep(_Step):
    """Apply a registered measurement function to acquired data; keep named results."""

    kind: Literal["measure"]
    function: str = Field(pattern=NAME, description="a name in camd.campaign.measurements")
    inputs: dict[str, str] = Field(
        default_factory=dict, description="argument name -> id of an acquire step"
    )
    args: dict[str, Any] = Field(default_factory=dict, description="keyword arguments")
    from_results: dict[str, str] = Field(
        default_factory=dict,
        description="argument name -> result name in scope (a sweep's results are lists)",
    )
    results: list[str] | None = Field(
        default=None, description="result names to keep (default: all the function returns)"
    )


class CheckStep(_Step):
    """A result against limits; a failure makes the campaign fail (after it has run)."""

    kind: Literal["check"]
    result: str = Field(
        pattern=RESULT_PATH, description="a result name in scope, or a path into it (a.b)"
    )
    min: float | Ref | None = None
    max: float | Ref | None = None


class SweepStep(_Step):
    """Run ``steps`` once per value of ``parameter`` (``${parameter}`` inside them)."""

    kind: Literal["sweep"]
    parameter: str = Field(pattern=NAME)
    values: list[Any] | Ref
    record: bool = Field(default=True, description="record the values as a result")
    steps: list[Step] = Field(min_length=1)


Step = Annotated[
    ConfigureStep | SweepStep | AcquireStep | MeasureStep | CheckStep,
    Field(discriminator="kind"),
]
SweepStep.model_rebuild()


# -- outputs ----------------------------------------------------------------------------------


class PlotSpec(_Model):
    """One PNG: results ``y`` (markers) and ``model`` (dashed lines) against result ``x``;
    check limits on ``y`` drawn dashed. A result that is a list of lists draws one line per
    inner list, labelled by the entries of the result ``labels`` if given."""

    title: str
    x: str = Field(pattern=RESULT_PATH)
    y: list[str] = Field(min_length=1)
    model: list[str] = Field(default_factory=list, description="model curves: dashed lines")
    labels: str | None = Field(default=None, description="a result labelling inner lists")
    xlabel: str = ""
    ylabel: str = ""
    logx: bool = False
    logy: bool = False


class TableSpec(_Model):
    """One table: columns are result names (lists side by side, scalars as one row)."""

    title: str
    columns: list[str] = Field(min_length=1, description="result names or paths (a.b)")


class Outputs(_Model):
    plots: list[PlotSpec] = Field(default_factory=list)
    tables: list[TableSpec] = Field(default_factory=list)


# -- the campaign -----------------------------------------------------------------------------


class BaselineSpec(_Model):
    """What the camera is brought to before the first step (camd.campaign.baseline)."""

    scene: str = Field(
        default="flat", description="simulator only: the scene before any configure step"
    )
    stage: Literal["stop", "home", "release"] = Field(
        default="stop",
        description="the scan stage: stopped where it stands (on the simulator the scene then "
        "moves with the ideal stage, whatever the stepper's position), enabled and homed, or "
        "stopped with its motor released",
    )


class CampaignSpec(_Model):
    """A whole campaign file."""

    name: str = Field(pattern=NAME)
    description: str = ""
    paper: str = Field(
        default="",
        max_length=40,
        description="the paper it reproduces, as docs/physics.md cites it (e.g. YUAN13 §4)",
    )
    profile: str = Field(pattern=NAME, description="camera profile (config/profiles/NAME.toml)")
    seed: int = Field(default=0, ge=RANGES["seed"][0], le=RANGES["seed"][1])
    parameters: dict[str, Any] = Field(default_factory=dict)
    quick: dict[str, Any] = Field(
        default_factory=dict, description="parameter overrides for --quick (CI-sized runs)"
    )
    assumptions: list[str] = Field(
        default_factory=list, description="what the report must say was assumed"
    )
    baseline: BaselineSpec = Field(default_factory=BaselineSpec)
    steps: list[Step] = Field(min_length=1)
    outputs: Outputs = Field(default_factory=Outputs)

    def parameters_for(self, quick: bool) -> dict[str, Any]:
        """The parameters, with the ``quick`` overrides applied when ``quick``."""
        return {**self.parameters, **(self.quick if quick else {})}


def resolve(value: Any, names: dict[str, Any]) -> Any:
    """``value`` with ``${name}`` references replaced: a whole-string reference by the value
    itself (its type kept), an embedded one by its text."""
    if isinstance(value, str):
        whole = re.fullmatch(REF_RE, value)
        if whole:
            return _lookup(names, whole)
        return REF_RE.sub(lambda m: text_of(_lookup(names, m)), value)
    if isinstance(value, dict):
        return {k: resolve(v, names) for k, v in value.items()}
    if isinstance(value, list):
        return [resolve(v, names) for v in value]
    return value


def _lookup(names: dict[str, Any], ref: re.Match[str]) -> Any:
    value = names[ref.group(1)]
    for key in filter(None, ref.group(2).split(".")):
        if not isinstance(value, dict) or key not in value:
            raise KeyError(f"${{{ref.group(1)}{ref.group(2)}}}: {ref.group(1)} has no key {key!r}")
        value = value[key]
    return value


def text_of(value: Any) -> str:
    """A value as it reads in a message or an embedded reference (floats as ``%g``)."""
    return format(value, "g") if isinstance(value, float) else str(value)


def sweep_values(step: SweepStep, names: dict[str, Any]) -> list[Any]:
    """The values a sweep runs over; KeyError if they are a result not measured yet."""
    values = resolve(step.values, names)
    if not isinstance(values, list) or not values:
        raise CampaignError(f"values: {step.values!r} must give a non-empty list, got {values!r}")
    return values
