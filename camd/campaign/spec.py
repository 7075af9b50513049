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

Errors (``CampaignError``) begin ``file:line:`` (the line of the key, found in the YAML's node
graph: ``camd.datafile.yaml_lines``), then name the step (``steps[2] (id 'sweep')``) and the
key and say what to write, in the words of the TOML data files' errors (camd.datafile).
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Literal, TypeVar, get_args

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from camd.datafile import Loc, place, what_to_write, wrong_type, yaml_line, yaml_lines, yaml_problem

if TYPE_CHECKING:
    from camd.sensor.regmap import FieldSpec, GroupSpec, RegisterMap, RegisterSpec

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
    "check_campaign",
    "load_campaign",
    "register_map_of",
    "resolve",
    "sweep_values",
    "validate_header",
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
"""The valid range of each count, by key: the schema's bounds and its error messages."""

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
    _check_semantics(_File(path, lines), spec)
    _check_register_names(_File(path, lines), spec)
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
        raise CampaignError(_explain(path, doc, exc, model, name, lines)) from None
    unknown_quick = sorted(set(spec.quick) - set(spec.parameters))
    if unknown_quick:
        where = _File(path, lines).at(("quick", unknown_quick[0]))
        raise CampaignError(
            f"{where}: {name}{': ' if name else ''}quick: {', '.join(unknown_quick)} not in "
            "`parameters` (quick overrides parameters; declare them there)"
        )
    return spec


@dataclass(frozen=True)
class _File:
    """A campaign file and the lines its places are written on (``yaml_lines``): where each
    error begins, ``file:line:`` (``file:`` when the place is not known)."""

    path: str | Path
    lines: Mapping[Loc, int]

    @classmethod
    def read(cls, path: str | Path) -> _File:
        """The file at ``path``, with its lines if it can be read (the runner names a campaign
        by its name instead: no lines)."""
        try:
            return cls(path, yaml_lines(Path(path).read_text(encoding="utf-8")))
        except (OSError, ValueError, yaml.YAMLError):
            return cls(path, {})

    def at(self, loc: Loc) -> str:
        """``file:line`` of the place ``loc`` (the nearest written place above it)."""
        return place(self.path, yaml_line(self.lines, loc))


def _explain(
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
        leaf = ""
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
                leaf = str(part)
            elif part in _STEP_KINDS:
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
        rank, message = _message(err, leaf, model, loc)
        line = yaml_line(lines, (*at, *loc)) if lines is not None else None
        if key not in found or rank < found[key][0]:
            found[key] = (rank, line, message)
    shown = []
    for key, (_, line, message) in found.items():
        if key in references and " the wrong type;" in message:
            message += " (or a ${name} reference)"
        shown.append(f"{place(path, line)}: {prefix}{': ' if prefix else ''}{key}: {message}")
    return "\n".join(shown)


_STEP_KINDS: tuple[str, ...] = tuple(
    get_args(member.model_fields["kind"].annotation)[0] for member in get_args(get_args(Step)[0])
)
"""The kinds of step, the tags of ``Step``: configure, sweep, acquire, measure, check."""


def _message(err: Any, leaf: str, model: type[BaseModel], loc: Loc) -> tuple[int, str]:
    """(rank, text) of one pydantic error: range errors first, then others, type mismatches of
    a union's alternatives last (a count given as -5 is out of range, not "not a ${ref}")."""
    kind = err["type"]
    if kind in ("extra_forbidden", "missing"):
        hint = what_to_write(model, loc, kind)
        if kind == "missing":
            return 0, f"missing key{hint}"
        return 0, f"unknown key{hint or '; docs/campaigns.md lists the keys'}"
    if kind == "union_tag_not_found":
        return 0, f"missing key; add `kind: ...`, one of {', '.join(_STEP_KINDS)}"
    if kind == "union_tag_invalid":
        tag = err["ctx"]["tag"]
        return 0, f"{tag!r} is not a step kind; give one of {', '.join(_STEP_KINDS)}"
    if kind in ("greater_than_equal", "less_than_equal", "greater_than", "less_than"):
        if leaf in RANGES:
            lo, hi = RANGES[leaf]
            return 0, f"{err['input']!r} is out of range; give {lo} .. {hi}"
        return 0, f"{err['input']!r}: {err['msg']}"
    if kind.endswith("_type") or kind.endswith("_parsing") or kind == "string_pattern_mismatch":
        return 2, wrong_type(kind, err["input"]) or f"{err['input']!r}: {err['msg']}"
    return 1, f"{err['msg']}"


def _walk(steps: list[Any], where: str, at: Loc = ("steps",)) -> list[tuple[str, Loc, Any]]:
    """Every step, nested ones after their sweep: its label in messages, its place in the
    file, the step."""
    out: list[tuple[str, Loc, Any]] = []
    for i, step in enumerate(steps):
        label = f"{where}[{i}] (id {step.id!r})"
        out.append((label, (*at, i), step))
        if isinstance(step, SweepStep):
            out += _walk(step.steps, f"{label}.steps", (*at, i, "steps"))
    return out


def _check_semantics(file: _File, spec: CampaignSpec) -> None:
    """What the schema cannot say: unique ids, known references, known functions."""
    from camd.campaign.measurements import MEASUREMENTS

    seen: dict[str, str] = {}
    acquires: set[str] = set()
    for label, loc, step in _walk(spec.steps, "steps"):
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


def resolve(value: Any, names: dict[str, Any]) -> Any:
    """``value`` with ``${name}`` references replaced: a whole-string reference by the value
    itself (its type kept), an embedded one by its text."""
    if isinstance(value, str):
        whole = re.fullmatch(REF_RE, value)
        if whole:
            return _lookup(names, whole)
        return REF_RE.sub(lambda m: _text(_lookup(names, m)), value)
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


def _text(value: Any) -> str:
    return format(value, "g") if isinstance(value, float) else str(value)


# -- what can be checked without the daemon ------------------------------------------------------


def register_map_of(path: str | Path, spec: CampaignSpec) -> RegisterMap:
    """The register map of the campaign's profile's sensor; CampaignError if there is none
    (``path``: the file, or ``file:line`` of its profile)."""
    from camd.sensor.profile import load_profile
    from camd.sensor.regmap import load_register_map

    try:
        return load_register_map(load_profile(spec.profile).sensor)
    except (OSError, ValueError) as exc:
        raise CampaignError(
            f"{path}: profile: {exc}; name a camera profile of config/profiles/"
        ) from None


def _check_register_names(file: _File, spec: CampaignSpec) -> None:
    """Every register a configure step names is one of the profile's sensor's that can be
    written (``REG``, ``REG.field``, ``GROUP`` or an address)."""
    configures = [(label, loc, step) for label, loc, step in _walk(spec.steps, "steps")
                  if isinstance(step, ConfigureStep) and step.registers]  # fmt: skip
    if not configures:
        return
    regmap = register_map_of(file.at(("profile",)), spec)
    for label, loc, step in configures:
        for name in step.registers:
            if "${" not in name:
                _register_target(file, (*loc, "registers", name), label, regmap, name)


def _register_target(
    file: _File, loc: Loc, label: str, regmap: RegisterMap, name: str
) -> tuple[RegisterSpec | GroupSpec, FieldSpec | None]:
    from camd.sensor.regmap import GroupSpec

    where = f"{file.at(loc)}: {label}: registers.{name}"
    try:
        try:
            target: RegisterSpec | GroupSpec = regmap.register(int(name.strip(), 0))
            field_spec: FieldSpec | None = None
        except ValueError:
            target, field_spec = regmap.resolve(name)
    except ValueError as exc:  # RegisterAccessError
        raise CampaignError(f"{where}: {exc}") from None
    if not isinstance(target, GroupSpec) and not target.writable:
        raise CampaignError(
            f"{where}: {target.name} is read-only on the {regmap.sensor}; remove it from the "
            "step (docs/sensors.md lists the writable registers)"
        )
    return target, field_spec


def _check_register_values(
    file: _File, at: Loc, label: str, regmap: RegisterMap, registers: dict[str, Any]
) -> None:
    """Each value against its register's, field's or group's range (what the daemon checks
    first; combinations such as the window are checked by the daemon when the step runs)."""
    from camd.sensor.regmap import GroupSpec

    for name, given in registers.items():
        loc = (*at, "registers", name)
        target, field_spec = _register_target(file, loc, label, regmap, name)
        value = given
        if isinstance(value, str):
            try:
                value = int(value.strip(), 0)
            except ValueError:
                value = value.strip()
        try:
            if isinstance(target, GroupSpec):
                regmap.split_group(target, value)
            elif field_spec is not None:
                field_spec.to_raw(value, f"{target.name}.{field_spec.name}")
            elif isinstance(value, str):
                fields = ", ".join(f"{target.name}.{f.name}" for f in target.all_fields())
                raise CampaignError(
                    f"{file.at(loc)}: {label}: registers.{name}: {value!r} is not a number; "
                    f"give an integer or set a field by name ({fields})"
                )
            else:
                target.check_value(value)
        except ValueError as exc:  # RegisterValueError
            if isinstance(exc, CampaignError):
                raise
            raise CampaignError(f"{file.at(loc)}: {label}: registers.{name}: {exc}") from None


def check_campaign(spec: CampaignSpec, path: str | Path, *, quick: bool) -> None:
    """Everything that can be checked without the daemon, with the parameters (with ``quick``,
    their overrides) substituted into every step and every sweep value: counts in their
    ranges, register values in theirs. CampaignError names the file, the step (and the sweep
    value) and what to give. A step that refers to a result measured before it is checked
    when it runs."""
    regmap: RegisterMap | None = None
    fix = (
        "nothing was done: correct the campaign's parameters (or their quick overrides) that "
        "this step uses"
    )

    file: _File | None = None  # read for its lines when there is an error to place

    def read() -> _File:
        nonlocal file
        file = file or _File.read(path)
        return file

    def walk(steps: list[Any], where: str, at: Loc, names: dict[str, Any], within: str) -> None:
        nonlocal regmap
        for i, step in enumerate(steps):
            label = f"{where}[{i}] (id {step.id!r}){within}"
            loc = (*at, i)
            if isinstance(step, SweepStep):
                try:
                    values = sweep_values(step, names)
                except KeyError:
                    continue  # swept over a measured result
                except CampaignError as exc:
                    raise CampaignError(
                        f"{read().at((*loc, 'values'))}: {label}: {exc}\n{fix}"
                    ) from None
                for value in values:
                    walk(step.steps, f"{where}[{i}] (id {step.id!r}).steps", (*loc, "steps"),
                         {**names, step.parameter: value},
                         f"{within} with {step.parameter} = {_text(value)}")  # fmt: skip
                continue
            data = step.model_dump()
            try:
                resolved = type(step).model_validate(resolve(data, names))
            except KeyError:
                continue  # names a result measured before it
            except ValidationError as exc:
                lines = read().lines
                explained = _explain(Path(path), data, exc, type(step), label, lines, loc)
                raise CampaignError(f"{explained}\n{fix}") from None
            if isinstance(resolved, ConfigureStep) and resolved.registers:
                regmap = regmap or register_map_of(read().at(("profile",)), spec)
                try:
                    _check_register_values(read(), loc, label, regmap, resolved.registers)
                except CampaignError as exc:
                    raise CampaignError(f"{exc}\nnothing was done") from None

    walk(spec.steps, "steps", ("steps",), dict(spec.parameters_for(quick)), "")


def sweep_values(step: SweepStep, names: dict[str, Any]) -> list[Any]:
    """The values a sweep runs over; KeyError if they are a result not measured yet."""
    values = resolve(step.values, names)
    if not isinstance(values, list) or not values:
        raise CampaignError(f"values: {step.values!r} must give a non-empty list, got {values!r}")
    return values
