"""Sensor register maps as data: ``config/sensors/<sensor>.toml``, validated by pydantic.

A map declares the sensor's SPI frame layout, its registers (address, width, access, reset value,
named bit fields with enums, units, scales and valid ranges), multi-register groups that must
change atomically (group hold), and the roles that say which register holds the window, the
exposure, the gain and so on. The host (``camd.sensor``), the simulated sensor
(``firmware_models``) and the docs all load the same file through ``load_register_map``.

Pure: no I/O beyond reading the file. Raw register values are unsigned integers; a field's
physical value is ``raw * scale`` in its ``unit``; a counted quantity (rows, columns, lines) is
``raw + bias`` (the MT9M001's row size register holds rows - 1: bias 1).

A map that does not validate raises ``RegisterMapError`` naming the file, the line of the
offending key (the register's ``reset`` line, the field's inline table, the role's line; the
``[[registers]]`` header when nothing narrower applies) and the register, e.g.::

    config/sensors/hr400.toml:176: register GAIN: field 'digital' bits 8..0 overlap field 'analog' bits 9..8

The entries, each validated alone, are in ``camd.sensor.regmap_entries`` and the checks across
them in ``camd.sensor.regmap_checks``; this module holds the whole map (look-up by name and
address, groups, roles, values) and loads it. Import the names from here.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, PrivateAttr, model_validator

from camd.datafile import DataFileKind
from camd.paths import config_dir
from camd.sensor.regmap_checks import (
    check_groups,
    check_output,
    check_registers,
    check_roles,
    check_soft_reset,
)
from camd.sensor.regmap_entries import (
    CLOCK_ROLES,
    COUNT_ROLES,
    MAX_ADDRESS_BITS,
    MAX_DATA_BITS,
    ROLE_DOCS,
    ROLES,
    Access,
    FieldSpec,
    GroupSpec,
    OutputSpec,
    RegisterAccessError,
    RegisterMapError,
    RegisterSpec,
    RegisterValueError,
    SoftResetSpec,
    SpiLayout,
    TimingSpec,
    _Located,
)

__all__ = [
    "CLOCK_ROLES",
    "COUNT_ROLES",
    "MAX_ADDRESS_BITS",
    "MAX_DATA_BITS",
    "ROLES",
    "ROLE_DOCS",
    "Access",
    "FieldSpec",
    "GroupSpec",
    "OutputSpec",
    "RegisterAccessError",
    "RegisterMap",
    "RegisterMapError",
    "RegisterSpec",
    "RegisterValueError",
    "SoftResetSpec",
    "SpiLayout",
    "TimingSpec",
    "list_sensors",
    "load_register_map",
    "sensors_dir",
]


class RegisterMap(BaseModel):
    """A sensor's whole register map, as loaded from ``config/sensors/<sensor>.toml``."""

    model_config = ConfigDict(extra="forbid", frozen=True, strict=True)

    sensor: str = Field(pattern=r"^[a-z0-9][a-z0-9_]*$", description="sensor name (file stem)")
    description: str = Field(default="", description="one line on the sensor")
    modelled: bool = Field(
        description="true when no public register map exists and this one is a model"
    )
    source: str = Field(default="", description="where the facts come from")
    rows: int = Field(ge=1, description="active rows of the pixel array")
    columns: int = Field(ge=1, description="active columns of the pixel array")
    first_row: int = Field(
        default=0, ge=0, description="row address of the first active row (window start minimum)"
    )
    first_column: int = Field(
        default=0, ge=0, description="column address of the first active column"
    )
    spi: SpiLayout = Field(description="SPI frame layout (table [spi])")
    timing: TimingSpec = Field(description="line-period model (table [timing])")
    output: OutputSpec = Field(description="pixel output interface (table [output])")
    soft_reset: SoftResetSpec | None = Field(
        default=None, description="the write that resets every register (table [soft_reset])"
    )
    roles: dict[str, str] = Field(
        default_factory=dict, description="role -> REGISTER, REGISTER.field or GROUP"
    )
    registers: list[RegisterSpec] = Field(description="the registers ([[registers]] entries)")
    groups: list[GroupSpec] = Field(
        default_factory=list, description="multi-register values ([[groups]] entries)"
    )

    _by_name: dict[str, RegisterSpec] = PrivateAttr(default_factory=dict)
    _by_address: dict[int, RegisterSpec] = PrivateAttr(default_factory=dict)
    _groups: dict[str, GroupSpec] = PrivateAttr(default_factory=dict)
    _group_of: dict[str, GroupSpec] = PrivateAttr(default_factory=dict)

    def model_post_init(self, __context: Any) -> None:
        for reg in self.registers:
            self._by_name[reg.name] = reg
            self._by_address[reg.address] = reg
        for group in self.groups:
            self._groups[group.name] = group
            for name in group.registers:
                self._group_of[name] = group

    # -- look-up ----------------------------------------------------------------------------

    def register(self, key: str | int) -> RegisterSpec:
        """A register by name (case-insensitive) or address."""
        if isinstance(key, int):
            reg = self._by_address.get(key)
            if reg is None:
                raise RegisterAccessError(
                    f"{self.sensor} has no register at address 0x{key:02X}; "
                    "`camctl reg dump` lists them"
                )
            return reg
        reg = self._by_name.get(key.upper())
        if reg is None:
            raise RegisterAccessError(
                f"{self.sensor} has no register named {key!r}; `camctl reg dump` lists them"
            )
        return reg

    def has_register(self, key: str | int) -> bool:
        return (key in self._by_address) if isinstance(key, int) else key.upper() in self._by_name

    def group(self, name: str) -> GroupSpec:
        group = self._groups.get(name.upper())
        if group is None:
            raise RegisterAccessError(f"{self.sensor} has no register group named {name!r}")
        return group

    def has_group(self, name: str) -> bool:
        return name.upper() in self._groups

    def group_of(self, register: str) -> GroupSpec | None:
        """The group a register belongs to, if any."""
        return self._group_of.get(register.upper())

    def group_registers(self, group: GroupSpec) -> list[RegisterSpec]:
        return [self._by_name[name] for name in group.registers]

    def group_width(self, group: GroupSpec) -> int:
        return sum(reg.width for reg in self.group_registers(group))

    def group_range(self, group: GroupSpec) -> tuple[int, int]:
        """The smallest and largest valid group value."""
        top = (1 << self.group_width(group)) - 1
        lo = group.min if group.min is not None else 0
        hi = group.max if group.max is not None else top
        return lo, hi

    def split_group(self, group: GroupSpec, value: int) -> list[tuple[RegisterSpec, int]]:
        """A group value as (register, value) pairs, most significant register first."""
        regs = self.group_registers(group)
        lo, hi = self.group_range(group)
        if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
            unit = f" {group.unit}" if group.unit else ""
            raise RegisterValueError(
                f"{group.name}: {value!r} is out of range (valid: {lo} .. {hi}{unit})"
            )
        pairs: list[tuple[RegisterSpec, int]] = []
        shift = self.group_width(group)
        for reg in regs:
            shift -= reg.width
            pairs.append((reg, (value >> shift) & reg.mask))
        return pairs

    def join_group(self, group: GroupSpec, values: dict[str, int]) -> int:
        """The group value from its registers' values (by register name)."""
        total = 0
        for reg in self.group_registers(group):
            total = (total << reg.width) | (values[reg.name] & reg.mask)
        return total

    def hold_of(self, group: GroupSpec) -> tuple[RegisterSpec, FieldSpec] | None:
        """The group-hold register and bit field of a group, if it has one."""
        if group.hold is None:
            return None
        reg_name, _, field_name = group.hold.partition(".")
        reg = self.register(reg_name)
        return reg, reg.field(field_name) if field_name else reg.all_fields()[0]

    def resolve(self, name: str) -> tuple[RegisterSpec | GroupSpec, FieldSpec | None]:
        """A value name -> (register, field) for ``REG`` / ``REG.field``, or (group, None)."""
        reg_name, _, field_name = name.strip().partition(".")
        if not field_name and self.has_group(reg_name):
            return self.group(reg_name), None
        reg = self.register(reg_name)
        return reg, (reg.field(field_name) if field_name else None)

    def canonical(self, name: str) -> str:
        """A value name as the map spells it (``win_start`` -> ``WIN_START``)."""
        target, field_spec = self.resolve(name)
        return f"{target.name}.{field_spec.name}" if field_spec is not None else target.name

    def value_of(self, name: str, raw: Callable[[RegisterSpec], int]) -> int | str:
        """The value of ``REG`` (raw), ``REG.field`` (enum label or raw) or ``GROUP`` (joined).

        ``raw`` gives a register's raw value (read from a device, a shadow copy or a model).
        """
        target, field_spec = self.resolve(name)
        if isinstance(target, GroupSpec):
            regs = self.group_registers(target)
            return self.join_group(target, {reg.name: raw(reg) for reg in regs})
        value = raw(target)
        if field_spec is None:
            return value
        part = field_spec.extract(value)
        label = field_spec.label(part)
        return label if label is not None else part

    def role(self, role: str) -> str | None:
        """The value name that plays ``role`` (see ROLES), or None if the sensor has none."""
        return self.roles.get(role)

    def role_count(self, role: str, value: Callable[[str], int | str]) -> int | None:
        """The counted quantity of a numeric role (raw + the field's bias); None if absent.

        ``value`` gives a value name's value (``value_of`` over some source of raw values).
        """
        name = self.role(role)
        if name is None:
            return None
        raw = value(name)
        if isinstance(raw, str):
            raise RegisterValueError(
                f"role {role} ({name}) has the enum value {raw!r}; it must be a number"
            )
        _, field_spec = self.resolve(name)
        return field_spec.count(raw) if field_spec is not None else raw

    def role_write(self, role: str, count: int) -> tuple[str, int] | None:
        """(value name, raw value) that sets a numeric role to the counted quantity ``count``
        (raw = count - the field's bias: ``role_count``'s inverse); None if absent."""
        name = self.role(role)
        if name is None:
            return None
        _, field_spec = self.resolve(name)
        return name, count - (field_spec.bias if field_spec is not None else 0)

    def is_soft_reset(self, reg: RegisterSpec, value: int) -> bool:
        """Whether writing ``value`` to ``reg`` resets every register (``soft_reset``)."""
        if self.soft_reset is None:
            return False
        target, field_spec = self.resolve(self.soft_reset.field)
        if target is not reg:
            return False
        assert field_spec is not None
        return field_spec.extract(value) == self.soft_reset.value

    def soft_reset_register(self) -> RegisterSpec | None:
        """The register whose write resets the sensor, if the map declares one."""
        if self.soft_reset is None:
            return None
        target, _ = self.resolve(self.soft_reset.field)
        assert isinstance(target, RegisterSpec)
        return target

    def check_window(self, value: Callable[[str], int | str]) -> None:
        """Raise RegisterValueError if the window runs off the pixel array.

        Checks ``window_start_row`` + ``window_rows`` against ``first_row`` and ``rows`` (and
        the same for columns when the map has column roles); ``value`` gives value names'
        values as they would be after the write.
        """
        axes = (
            ("window_start_row", "window_rows", self.first_row, self.rows, "row"),
            ("window_start_column", "window_columns", self.first_column, self.columns, "column"),
        )
        for start_role, size_role, first, total, what in axes:
            start_name, size_name = self.role(start_role), self.role(size_role)
            if start_name is None or size_name is None:
                continue
            start = self.role_count(start_role, value)
            size = self.role_count(size_role, value)
            assert start is not None and size is not None
            last_valid = first + total - 1
            if start < first:
                raise RegisterValueError(
                    f"{start_name} = {value(start_name)}: the window starts at {what} {start}, "
                    f"before the first active {what} {first} (valid: {first} .. {last_valid})"
                )
            last = start + size - 1
            if last > last_valid:
                raise RegisterValueError(
                    f"{start_name} = {value(start_name)} and {size_name} = {value(size_name)}: "
                    f"the window's last {what} would be {last}, beyond the sensor's last {what} "
                    f"{last_valid}; lower {start_name} or {size_name} (the window must fit "
                    f"{what}s {first} .. {last_valid})"
                )

    def by_address(self) -> Iterator[RegisterSpec]:
        """The registers in address order."""
        return iter(sorted(self.registers, key=lambda r: r.address))

    @model_validator(mode="after")
    def _check(self) -> RegisterMap:
        names = check_registers(self.registers, self.spi)
        groups = check_groups(self.groups, self.registers, names)
        check_roles(self.roles, self.registers, self.timing, names, groups)
        check_soft_reset(self.soft_reset, self.registers, names)
        check_output(self.output, self.roles, self.registers)
        by_name = {reg.name: reg for reg in self.registers}

        def reset_value(name: str) -> int | str:
            return self.value_of(name, lambda reg: by_name[reg.name].reset)

        try:
            self.check_window(reset_value)
        except RegisterValueError as exc:
            start = self.roles.get("window_start_row", "").partition(".")[0]
            index = names.get(start)
            if index is None:
                raise _Located(f"reset values: {exc}", table="roles") from None
            raise _Located(
                f"reset values: {exc}", table="registers", index=index, key="reset"
            ) from None
        return self


# -- loading --------------------------------------------------------------------------------


def sensors_dir() -> Path:
    return config_dir() / "sensors"


def list_sensors() -> list[str]:
    """Names of the shipped register maps."""
    return _MAPS.names()


def load_register_map(sensor_or_path: str | Path) -> RegisterMap:
    """Load and validate a register map by sensor name (``hr400``) or by file path."""
    return _MAPS.find(sensor_or_path)


_MAPS = DataFileKind(
    RegisterMap,
    RegisterMapError,
    # A message calls an entry by its name: "register GAIN: field 'digital': ...".
    named={"registers": "register {}", "groups": "group {}", "fields": "field {!r}"},
    folder=sensors_dir,
    noun="register map",
    name_of="sensor",
)
