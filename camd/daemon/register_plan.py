"""A register burst, planned whole before the camera is touched.

A write of several registers, fields and groups at once (POST /registers) and the load of a
saved configuration (PUT /registers/config) are planned by pure code against the register file
read once (``RegisterSnapshot``): every value checked as the write itself checks it (names,
access, widths, field ranges and labels, a group's hold, the window inside the array), the
registers the burst changes named (also those a written register mirrors into: mt9m001's
GLOBAL_GAIN sets the four colour gains), and of them the settings that a failure writes back,
with their values in the snapshot. A refusal is a ``BadRequest`` raised here, so that a refused
burst sends nothing.

``SensorService`` then sends the burst through an ``Apply`` (``camd.daemon.transaction``): a
burst that fails after the camera may have taken it (unanswered, a read-back refused or
different) writes those registers back and says so. Scans and wheel acquisitions plan their
register writes against the same snapshot (``preview``, ``changed``).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

from camd.daemon.errors import BadRequest
from camd.daemon.models import RegisterConfig, TimingResponse
from camd.sensor.registers import SensorRegisters
from camd.sensor.regmap import RegisterAccessError, RegisterMap, RegisterValueError
from camd.sensor.timing_view import SensorTiming, sensor_timing

CONFIGURATION = "the configuration"  # what a configuration's refusals start with


class RegisterSnapshot:
    """The sensor's registers at one moment (raw values), and what writes would make of them.

    ``preview(writes)`` validates ``writes`` as a write would and returns the timing they would
    set, with nothing sent (pure); ``changed(writes)`` names the registers they would change.
    """

    def __init__(
        self, regmap: RegisterMap, registers: SensorRegisters, raw: dict[str, int]
    ) -> None:
        self.regmap = regmap
        self.raw = raw
        self._registers = registers

    def value(self, name: str) -> int | str:
        """A value name's value (``REG``, ``REG.field`` or ``GROUP``) in the snapshot."""
        return self.regmap.value_of(name, lambda reg: self.raw[reg.name])

    def timing(self) -> TimingResponse:
        """The timing the snapshot's registers set."""
        return TimingResponse.model_validate(sensor_timing(self.regmap, self.value).as_dict())

    def columns(self) -> int:
        """Columns per window row (the window-columns role, else the whole row)."""
        count = self.regmap.role_count("window_columns", self.value)
        return self.regmap.columns if count is None else count

    def _plan(self, writes: Mapping[str, int | str]) -> tuple[dict[str, int], SensorTiming]:
        try:
            return self._registers.preview(writes, self.raw)
        except (RegisterAccessError, RegisterValueError) as exc:
            raise BadRequest(str(exc)) from None

    def check(self, writes: Mapping[str, int | str]) -> None:
        """Validate ``writes`` whole, as the write would; BadRequest for any it would refuse
        (an empty one too)."""
        self._plan(writes)

    def preview(self, writes: Mapping[str, int | str]) -> TimingResponse:
        """The timing ``writes`` would set; BadRequest for a write that would be refused."""
        if not writes:
            return self.timing()
        _, timing = self._plan(writes)
        return TimingResponse.model_validate(timing.as_dict())

    def changed(self, writes: Mapping[str, int | str]) -> list[str]:
        """The registers ``writes`` would change, by name, in the order they are written: each
        register written, followed by those it mirrors into (a write of it sets them too)."""
        if not writes:
            return []
        values, _ = self._plan(writes)
        after = dict(self.raw)
        order: list[str] = []
        for name, raw in values.items():
            after[name] = raw
            order.append(name)
            for target in self.regmap.register(name).mirrors:
                after[target] = raw & self.regmap.register(target).kept_mask
                order.append(target)
        return [name for name in dict.fromkeys(order) if after[name] != self.raw[name]]


@dataclass(frozen=True, slots=True)
class RegisterPlan:
    """A burst checked whole: what to send, and what a failure puts back."""

    what: str  # the request as a noun, for its failure's event ("register write")
    writes: dict[str, int | str]  # the burst as asked: REG, REG.field or GROUP -> value
    restore: dict[str, int]  # the settings it changes -> their raw values in the snapshot

    @property
    def restore_label(self) -> str:
        """What writing ``restore`` back restores, in words ("registers GAIN, OFFSET")."""
        return "registers " + ", ".join(self.restore)


def restorable(regmap: RegisterMap, names: list[str]) -> list[str]:
    """The settings among ``names``: what a failed write puts back. Actions (a soft reset,
    flags cleared by writing 1) and volatile registers cannot be put back."""
    reset_reg = regmap.soft_reset_register()
    return [
        name
        for name in names
        if regmap.register(name).configurable and regmap.register(name) is not reset_reg
    ]


def plan_write(snapshot: RegisterSnapshot, values: Mapping[str, int | str]) -> RegisterPlan:
    """A write of registers, fields and groups at once (POST /registers), checked against
    ``snapshot``; BadRequest saying what to change if any value would be refused."""
    return _plan("register write", snapshot, values)


def check_configuration(registers: SensorRegisters, config: RegisterConfig) -> None:
    """Refuse, before the register file is read, a configuration saved from another sensor or
    naming registers that are not settings (BadRequest)."""
    try:
        registers.check_configuration(config.sensor, config.registers, source=CONFIGURATION)
    except (RegisterAccessError, RegisterValueError) as exc:
        raise BadRequest(str(exc)) from None


def plan_configuration(snapshot: RegisterSnapshot, config: RegisterConfig) -> RegisterPlan:
    """The load of a saved configuration (PUT /registers/config; ``check_configuration``
    first), checked against ``snapshot``: a refusal names the configuration and says that
    nothing was written."""
    try:
        return _plan("configuration load", snapshot, config.registers)
    except BadRequest as exc:
        raise BadRequest(f"{CONFIGURATION}: {exc}; nothing was written") from None


def _plan(what: str, snapshot: RegisterSnapshot, values: Mapping[str, int | str]) -> RegisterPlan:
    writes = dict(values)
    snapshot.check(writes)
    changed = restorable(snapshot.regmap, snapshot.changed(writes))
    return RegisterPlan(what, writes, {name: snapshot.raw[name] for name in changed})
