"""The checks of a register map across its entries (camd.sensor.regmap_entries), run when a
``RegisterMap`` is built: unique names and addresses that fit the SPI frame, mirrors, groups
(members, bounds, reset value, hold bit), roles, the soft reset and what LVDS training needs.

Each raises ``_Located`` naming the entry and key at fault, so that the loader's message gives
the file's line (camd.sensor.regmap).
"""

from __future__ import annotations

import math

from camd.sensor.regmap_entries import (
    CLOCK_ROLES,
    COUNT_ROLES,
    ROLES,
    GroupSpec,
    OutputSpec,
    RegisterSpec,
    SoftResetSpec,
    SpiLayout,
    TimingSpec,
    _Located,
)


def check_registers(registers: list[RegisterSpec], spi: SpiLayout) -> dict[str, int]:
    names: dict[str, int] = {}
    addresses: dict[int, str] = {}
    for i, reg in enumerate(registers):
        if reg.name in names:
            raise _Located(
                f"duplicate register name (also entry #{names[reg.name] + 1} of [[registers]])",
                table="registers",
                index=i,
                key="name",
            )
        names[reg.name] = i
        if reg.address in addresses:
            raise _Located(
                f"address 0x{reg.address:02X} is already register {addresses[reg.address]}",
                table="registers",
                index=i,
                key="address",
            )
        addresses[reg.address] = reg.name
        if reg.address >= 1 << spi.address_bits:
            raise _Located(
                f"address 0x{reg.address:X} does not fit the SPI frame's "
                f"{spi.address_bits} address bits",
                table="registers",
                index=i,
                key="address",
            )
        if reg.width > spi.data_bits:
            raise _Located(
                f"width {reg.width} exceeds the SPI frame's {spi.data_bits} data bits",
                table="registers",
                index=i,
                key="width",
            )
    for i, reg in enumerate(registers):
        for target in reg.mirrors:
            other = registers[names[target]] if target in names else None
            if other is None:
                raise _Located(
                    f"mirrors {target}, which is not a register",
                    table="registers",
                    index=i,
                    key="mirrors",
                )
            if other.width != reg.width or other.mirrors or other.access not in ("rw", "wo"):
                raise _Located(
                    f"mirrors {target}, which must be a RW/WO register of the same width "
                    "that mirrors nothing",
                    table="registers",
                    index=i,
                    key="mirrors",
                )
    return names


def check_groups(
    groups: list[GroupSpec], registers: list[RegisterSpec], names: dict[str, int]
) -> set[str]:
    seen: set[str] = set()
    member_of: dict[str, str] = {}
    for i, group in enumerate(groups):
        if group.name in names or group.name in seen:
            raise _Located("name already used", table="groups", index=i, key="name")
        seen.add(group.name)
        for member in group.registers:
            if member not in names:
                raise _Located(f"no register {member}", table="groups", index=i, key="registers")
            reg = registers[names[member]]
            if not reg.writable or reg.access == "w1c" or reg.volatile:
                raise _Located(
                    f"member {member} must be a non-volatile RW or WO register",
                    table="groups",
                    index=i,
                    key="registers",
                )
            if member in member_of:
                raise _Located(
                    f"register {member} is already in group {member_of[member]}",
                    table="groups",
                    index=i,
                    key="registers",
                )
            member_of[member] = group.name
        width = sum(registers[names[m]].width for m in group.registers)
        top = (1 << width) - 1
        for bound in (group.min, group.max):
            if bound is not None and bound > top:
                raise _Located(
                    f"bound {bound} does not fit the group's {width} bits",
                    table="groups",
                    index=i,
                )
        reset = 0
        for member in group.registers:
            reg = registers[names[member]]
            reset = (reset << reg.width) | reg.reset
        lo = group.min if group.min is not None else 0
        hi = group.max if group.max is not None else top
        if not lo <= reset <= hi:
            raise _Located(
                f"the members' reset values make {reset}, out of range (valid: {lo} .. {hi})",
                table="groups",
                index=i,
            )
        if group.hold is not None:
            hold_reg, _, hold_field = group.hold.partition(".")
            if hold_reg not in names:
                raise _Located(f"no hold register {hold_reg}", table="groups", index=i, key="hold")
            reg = registers[names[hold_reg]]
            if hold_field and hold_field not in {f.name for f in reg.all_fields()}:
                raise _Located(
                    f"register {hold_reg} has no field {hold_field}",
                    table="groups",
                    index=i,
                    key="hold",
                )
            if hold_reg in group.registers or reg.access != "rw" or reg.volatile:
                raise _Located(
                    f"hold register {hold_reg} must be a non-volatile RW register outside "
                    "the group",
                    table="groups",
                    index=i,
                    key="hold",
                )
    return seen


def check_roles(
    roles: dict[str, str],
    registers: list[RegisterSpec],
    timing: TimingSpec,
    names: dict[str, int],
    groups: set[str],
) -> None:
    for role, target in roles.items():
        if role not in ROLES:
            raise _Located(
                f"unknown role {role!r}; roles are {', '.join(ROLES)}", table="roles", key=role
            )
        reg_name, _, field_name = target.partition(".")
        if reg_name in groups and not field_name:
            if role not in COUNT_ROLES:
                raise _Located(
                    f"role {role}: group {reg_name} cannot play this role",
                    table="roles",
                    key=role,
                )
            continue
        if reg_name not in names:
            raise _Located(f"role {role}: no register or group {reg_name}", table="roles", key=role)
        reg = registers[names[reg_name]]
        fields = {f.name: f for f in reg.all_fields()}
        if field_name and field_name not in fields:
            raise _Located(
                f"role {role}: register {reg_name} has no field {field_name}",
                table="roles",
                key=role,
            )
        field_spec = fields[field_name] if field_name else None
        if role in COUNT_ROLES and field_spec is not None and field_spec.enum is not None:
            raise _Located(
                f"role {role}: field {target} is an enum; the role needs a number",
                table="roles",
                key=role,
            )
        if role == "spi_error_flag" and reg.access != "w1c":
            raise _Located(
                f"role {role}: {reg_name} must be a write-1-to-clear register",
                table="roles",
                key=role,
            )
        if role in CLOCK_ROLES and field_spec is not None and field_spec.unit == "s":
            clock_s = 1.0 / timing.clock_hz
            if not math.isclose(field_spec.scale, clock_s, rel_tol=1e-9):
                raise _Located(
                    f"field {field_spec.name!r} plays the {role} role, which counts clocks "
                    f"of timing.clock_hz = {timing.clock_hz:g} Hz, so its scale must be "
                    f"{clock_s:g} s, not {field_spec.scale:g}",
                    table="registers",
                    index=names[reg_name],
                    field=reg.fields.index(field_spec),
                )
    sequencer = timing.model == "sequencer"
    if sequencer and timing.clocks_per_line is None and "line_clocks" not in roles:
        raise _Located(
            "the sequencer model needs clocks_per_line or a line_clocks role",
            table="timing",
        )


def check_soft_reset(
    soft_reset: SoftResetSpec | None, registers: list[RegisterSpec], names: dict[str, int]
) -> None:
    if soft_reset is None:
        return
    reg_name, _, field_name = soft_reset.field.partition(".")
    if reg_name not in names:
        raise _Located(f"no register {reg_name}", table="soft_reset", key="field")
    reg = registers[names[reg_name]]
    fields = {f.name: f for f in reg.all_fields()}
    if field_name and field_name not in fields:
        raise _Located(
            f"register {reg_name} has no field {field_name}", table="soft_reset", key="field"
        )
    if not reg.writable or reg.access == "w1c":
        raise _Located(f"register {reg_name} cannot be written", table="soft_reset", key="field")
    field_spec = fields[field_name] if field_name else reg.all_fields()[0]
    if soft_reset.value > field_spec.raw_max:
        raise _Located(
            f"value {soft_reset.value} does not fit {soft_reset.field}",
            table="soft_reset",
            key="value",
        )


def check_output(output: OutputSpec, roles: dict[str, str], registers: list[RegisterSpec]) -> None:
    if not output.needs_training:
        return
    word = roles.get("training_word")
    pattern = roles.get("test_pattern")
    if word is None or pattern is None:
        raise _Located(
            "an lvds output needs the training_word and test_pattern roles "
            "(the FPGA trains the lanes on the training word)",
            table="output",
            key="interface",
        )
    reg_name, _, field_name = pattern.partition(".")
    reg = next((r for r in registers if r.name == reg_name), None)
    field_spec = None
    if reg is not None:
        field_spec = next((f for f in reg.all_fields() if f.name == field_name), None)
    labels = set((field_spec.enum or {}) if field_spec is not None else {})
    if not {"training", "prbs"} <= labels:
        raise _Located(
            f"role test_pattern: {pattern} needs enum values 'training' and 'prbs' for "
            "LVDS training",
            table="roles",
            key="test_pattern",
        )
