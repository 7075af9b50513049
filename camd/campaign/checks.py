"""What can be checked of a campaign without the daemon: every count and register value with
the parameters (or their ``quick`` overrides) substituted into every step and sweep value,
against the ranges the daemon enforces and the profile's register map.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

from pydantic import ValidationError

from camd.campaign.explain import CampaignFile, explain, walk_steps
from camd.campaign.spec import (
    CampaignError,
    CampaignSpec,
    ConfigureStep,
    SweepStep,
    resolve,
    sweep_values,
    text_of,
)
from camd.datafile import Loc

if TYPE_CHECKING:
    from camd.sensor.regmap import FieldSpec, GroupSpec, RegisterMap, RegisterSpec

__all__ = ["check_campaign", "check_register_names", "register_map_of"]


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


def check_register_names(file: CampaignFile, spec: CampaignSpec) -> None:
    """Every register a configure step names is one of the profile's sensor's that can be
    written (``REG``, ``REG.field``, ``GROUP`` or an address)."""
    configures = [(label, loc, step) for label, loc, step in walk_steps(spec.steps, "steps")
                  if isinstance(step, ConfigureStep) and step.registers]  # fmt: skip
    if not configures:
        return
    regmap = register_map_of(file.at(("profile",)), spec)
    for label, loc, step in configures:
        for name in step.registers:
            if "${" not in name:
                _register_target(file, (*loc, "registers", name), label, regmap, name)


def _register_target(
    file: CampaignFile, loc: Loc, label: str, regmap: RegisterMap, name: str
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
    file: CampaignFile, at: Loc, label: str, regmap: RegisterMap, registers: dict[str, Any]
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

    file: CampaignFile | None = None  # read for its lines when there is an error to place

    def read() -> CampaignFile:
        nonlocal file
        file = file or CampaignFile.read(path)
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
                         f"{within} with {step.parameter} = {text_of(value)}")  # fmt: skip
                continue
            data = step.model_dump()
            try:
                resolved = type(step).model_validate(resolve(data, names))
            except KeyError:
                continue  # names a result measured before it
            except ValidationError as exc:
                lines = read().lines
                explained = explain(Path(path), data, exc, type(step), label, lines, loc)
                raise CampaignError(f"{explained}\n{fix}") from None
            if isinstance(resolved, ConfigureStep) and resolved.registers:
                regmap = regmap or register_map_of(read().at(("profile",)), spec)
                try:
                    _check_register_values(read(), loc, label, regmap, resolved.registers)
                except CampaignError as exc:
                    raise CampaignError(f"{exc}\nnothing was done") from None

    walk(spec.steps, "steps", ("steps",), dict(spec.parameters_for(quick)), "")
