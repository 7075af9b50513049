"""Generate docs/sensors.md from the register-map schema and the shipped maps.

The document is rendered from the pydantic models of ``camd.sensor.regmap`` (every key, its type,
default and meaning) and from every ``config/sensors/*.toml`` (registers, fields, roles, timing),
so it cannot drift from them; ``tests/test_sensor_docs.py`` fails when the committed file is stale.

    python -m camd.sensor.docgen            write docs/sensors.md
    python -m camd.sensor.docgen --check    exit 1 if docs/sensors.md differs from the render
"""

from __future__ import annotations

import sys
import types
import typing
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from pydantic import BaseModel
from pydantic_core import PydanticUndefined

from camd.markdown import docgen_parser, table, write_or_check
from camd.sensor.regmap import (
    ROLE_DOCS,
    ROLES,
    FieldSpec,
    GroupSpec,
    OutputSpec,
    RegisterMap,
    RegisterMapError,
    RegisterSpec,
    SoftResetSpec,
    SpiLayout,
    TimingSpec,
    list_sensors,
    load_register_map,
)
from camd.sensor.timing_view import SensorTiming, reset_timing

# -- formatting -------------------------------------------------------------------------------------


def _num(x: float) -> str:
    return f"{x:.10g}"


def _duration(seconds: float) -> str:
    """A time in the unit that reads best (s, ms, µs), 7 significant digits."""
    for scale, unit in ((1.0, "s"), (1e-3, "ms"), (1e-6, "µs")):
        if abs(seconds) >= scale:
            return f"{seconds / scale:.7g} {unit}"
    return "0 s" if seconds == 0 else f"{seconds / 1e-9:.7g} ns"


def _hex(value: int, width: int) -> str:
    return f"0x{value:0{(width + 3) // 4}X}"


# -- schema -----------------------------------------------------------------------------------------


def _type_name(annotation: Any) -> str:
    origin = typing.get_origin(annotation)
    args = typing.get_args(annotation)
    if origin is typing.Annotated:  # a strict type: the type it constrains is what a file holds
        return _type_name(args[0])
    if origin is typing.Literal:
        return " | ".join(f'"{a}"' for a in args)
    if origin in (typing.Union, types.UnionType):
        return " or ".join(_type_name(a) for a in args)
    if origin is list:
        return f"array of {_type_name(args[0])}"
    if origin is tuple:
        return f"[{', '.join(_type_name(a) for a in args)}]"
    if origin is dict:
        return f"table of {_type_name(args[1])}"
    if annotation is type(None):
        return "absent"
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return "table"
    names = {int: "integer", float: "number", str: "string", bool: "boolean"}
    return names.get(annotation, getattr(annotation, "__name__", str(annotation)))


def _default(info: Any) -> str:
    if info.is_required():
        return "required"
    if info.default_factory is not None:
        value = info.default_factory()
        return "[]" if value == [] else "{}" if value == {} else str(value)
    default = info.default
    if default is PydanticUndefined or default is None:
        return "absent"
    if isinstance(default, str):
        return f'"{default}"'
    if isinstance(default, bool):
        return str(default).lower()
    return _num(default) if isinstance(default, float) else str(default)


def _schematable(model: type[BaseModel]) -> list[str]:
    rows = []
    for name, info in model.model_fields.items():
        constraints = []
        for meta in info.metadata:
            for attr, sign in (("ge", ">="), ("gt", ">"), ("le", "<="), ("lt", "<")):
                bound = getattr(meta, attr, None)
                if bound is not None:
                    constraints.append(f"{sign} {bound}")
            pattern = getattr(meta, "pattern", None)
            if pattern:
                constraints.append(f"matches `{pattern}`")
        kind = _type_name(info.annotation)
        if constraints:
            kind += f" ({', '.join(constraints)})"
        rows.append([f"`{name}`", kind, _default(info), info.description or ""])
    return table(["Key", "Type", "Default", "Meaning"], rows)


def _schema() -> list[str]:
    roles = table(["Role", "Meaning"], [[f"`{r}`", ROLE_DOCS.get(r, "")] for r in ROLES])
    return [
        "## 1. Register map schema",
        "",
        "A sensor's register map is one TOML file, `config/sensors/<sensor>.toml`, loaded and "
        "validated by `camd.sensor.regmap.load_register_map` (pydantic). The host "
        "(`camd.sensor.SensorRegisters`), the simulated sensor (`firmware_models.sensor`) and "
        "this document read the same file. Unknown keys are errors.",
        "",
        "### Top level",
        "",
        *_schematable(RegisterMap),
        "",
        "### `[spi]`: the SPI frame",
        "",
        "One register access is one chip-select-low frame of `rw_bits` of command, "
        "`address_bits` of address and `data_bits` of data, most significant bit first; the "
        "total must be whole bytes. A read sends zeros in the data slot and the sensor drives "
        "the value on MISO during it.",
        "",
        *_schematable(SpiLayout),
        "",
        "### `[timing]`: the line period",
        "",
        "- `sequencer`: `T_line = clocks_per_line / clock_hz` (docs/physics.md §3).",
        "- `row_blanking`: `T_line = t_rb + n_pixels / f_s` (docs/physics.md §2 eq 4) with "
        "`t_rb = (fixed_row_overhead_clocks + max(row_blanking, row_blanking_min_clocks)) / "
        "clock_hz`, `f_s = clock_hz * pixels_per_clock` and `n_pixels` the `window_columns` "
        "role (or `columns`).",
        "",
        *_schematable(TimingSpec),
        "",
        "### `[output]`: the pixel output",
        "",
        *_schematable(OutputSpec),
        "",
        "### `[soft_reset]`",
        "",
        "Writing `value` to `field` returns every register to its reset value.",
        "",
        *_schematable(SoftResetSpec),
        "",
        "### `[roles]`",
        "",
        "Each role names the value (`REGISTER`, `REGISTER.field` or a group) that plays it, so "
        "that the timing, the simulator and `camctl timing` need no per-sensor code. Counted "
        "roles take `raw + bias` of their field; clock roles count clocks of `timing.clock_hz` "
        "(a field in seconds must then have `scale = 1 / clock_hz`).",
        "",
        *roles,
        "",
        "### `[[registers]]`",
        "",
        *_schematable(RegisterSpec),
        "",
        "### Fields: `fields = [ { ... }, ... ]` of a register",
        "",
        "A register without fields behaves as one field named `value` covering all its bits. "
        "The physical value of a field is `raw * scale` in `unit`; a counted quantity is "
        "`raw + bias`.",
        "",
        *_schematable(FieldSpec),
        "",
        "### `[[groups]]`",
        "",
        "A value spread over several registers, most significant first, e.g. a 20-bit exposure "
        "in two 16-bit registers. The host writes a group as hold = 1, the parts, hold = 0 in "
        "one burst; the sensor applies latched parts together when hold is cleared.",
        "",
        *_schematable(GroupSpec),
        "",
        "### Load errors",
        "",
        "A map that breaks a rule is refused at load with `RegisterMapError`, whose message "
        "starts with `file:line:` (the offending key's line, the field's inline table or the "
        "role's line) and names the register, group or role, e.g. "
        "`config/sensors/hr400.toml:176: register GAIN: field 'digital' bits 8..0 overlap field "
        "'analog' bits 9..8`. Checked:",
        "",
        "- TOML syntax; unknown keys; types and bounds of every key above;",
        "- fields: bits within the register, no overlaps, unique names, enum values and "
        "`min`/`max` within the field's bits, `min <= max`;",
        "- registers: unique names and addresses, addresses within `spi.address_bits`, widths "
        "within `spi.data_bits`, reset values within the width, no reset bits outside the "
        "fields, every field's reset value valid for its range or enum, pulse fields reset to 0 "
        "and not in RO registers, `mirrors` targets existing RW/WO registers of the same width "
        "(the mirroring register volatile);",
        "- groups: members exist, are non-volatile RW/WO registers in one group only, the "
        "members' reset values make a value within `min`/`max`, the hold bit exists in a "
        "non-volatile RW register outside the group;",
        "- roles: known roles, targets exist (register, field or group), counted roles are not "
        "enums, clock roles in seconds scale by `1 / clock_hz`, `spi_error_flag` is a W1C bit; "
        "the reset window lies within the pixel array;",
        "- the `sequencer` model has `clocks_per_line` or a `line_clocks` role; an `lvds` output "
        "has `training_word` and a `test_pattern` with `training` and `prbs`; `[soft_reset]` "
        "names a writable field and a value that fits it.",
        "",
    ]


def _behaviour() -> list[str]:
    return [
        "## 2. Access rules and host behaviour",
        "",
        "| Access | Host read | Host write | Verified after write | In a saved configuration |",
        "|---|---|---|---|---|",
        "| `ro` | yes | refused | no | no |",
        "| `rw` | yes | yes | yes, unless volatile | yes, unless volatile |",
        "| `wo` | refused (the shadow copy is shown) | yes | no | yes, from the shadow copy |",
        "| `w1c` | yes | each 1 clears that flag | no | no |",
        "",
        "- **Validation first.** `camctl reg write` / `SensorRegisters.write` check every "
        "assignment (width, each field's range or enum, bits outside the fields, access, the "
        "window against the pixel array) before sending anything; a refusal names the "
        "register, the value and the valid range, and nothing is written.",
        "- **Field writes** are read-modify-write from a fresh read (from the shadow copy for "
        "WO registers); W1C fields are written alone.",
        "- **One burst.** All registers of one write go out in one `write_burst`; a group, or "
        "any write to its registers, is wrapped in hold = 1 ... hold = 0.",
        "- **Verify.** RW non-volatile registers are read back; a mismatch is a `VerifyError` "
        "naming the register, the written and the read value. Pulse bits are not compared.",
        "- **Volatile** registers change by themselves (status, counters, mirrors); they are "
        "never verified, saved or diffed against reset values.",
        "- **Shadow copy.** The host's copy starts at the reset values (`sync()` reads the "
        "device); `stage()` changes it and marks registers dirty; `flush()` writes every dirty "
        "register in one burst. Actions (soft reset, pulse bits, W1C) cannot be staged.",
        "- **Diff** against `reset` compares every non-volatile register except W1C flags (RO "
        "ones too, so a wrong chip ID shows); against a file or values, just the names given. "
        "WO registers are compared through the shadow copy.",
        "- **Configurations** (`camctl reg save FILE`) are TOML: a header comment, `sensor = "
        '"<name>"` and a `[registers]` table of raw values, e.g. `WIN_START = 0x02F5  # 757`. '
        "They hold the RW and WO non-volatile registers except the soft-reset register, and "
        "round-trip bit-exactly. `camctl reg load FILE` refuses a file for another sensor, "
        "unknown or non-configurable names and invalid values before writing anything.",
        "",
    ]


# -- per sensor -------------------------------------------------------------------------------------


def _field_values(f: FieldSpec) -> str:
    if f.enum is not None:
        return ", ".join(f"`{name}` = {raw}" for name, raw in f.enum.items())
    text = f"{f.lo} .. {f.hi}"
    if f.bias:
        text += f" (count = raw {'+' if f.bias > 0 else '-'} {abs(f.bias)})"
    return text


def _field_rows(reg: RegisterSpec) -> list[list[str]]:
    rows = []
    for f in reg.fields:
        bits = f"{f.msb}" if f.msb == f.lsb else f"{f.msb}..{f.lsb}"
        doc = f.doc + (" (self-clearing)" if f.pulse and "self-clearing" not in f.doc else "")
        scale = _num(f.scale) if f.scale != 1.0 else ""
        rows.append([f"`{reg.name}`", f"`{f.name}`", bits, _field_values(f), f.unit, scale, doc])
    return rows


def _timing_lines(regmap: RegisterMap, timing: SensorTiming) -> list[str]:
    spec = regmap.timing
    if spec.model == "sequencer":
        clocks = regmap.role("line_clocks") or f"{spec.clocks_per_line}"
        formula = (
            f"`sequencer`: T_line = {clocks} clocks / {_num(spec.clock_hz / 1e6)} MHz "
            "(docs/physics.md §3)"
        )
    else:
        blanking = regmap.role("row_blanking") or "0"
        if spec.row_blanking_min_clocks:
            blanking = f"max({blanking}, {spec.row_blanking_min_clocks})"
        if spec.fixed_row_overhead_clocks:
            blanking = f"{spec.fixed_row_overhead_clocks} + {blanking}"
        pixels = regmap.role("window_columns") or f"{regmap.columns}"
        if regmap.role("window_columns") is not None:
            _, field_spec = regmap.resolve(pixels)
            if field_spec is not None and field_spec.bias:
                pixels = f"({pixels} + {field_spec.bias})"
        rate = spec.clock_hz * spec.pixels_per_clock
        formula = (
            f"`row_blanking`: T_line = ({blanking}) clocks / {_num(spec.clock_hz / 1e6)} MHz + "
            f"{pixels} pixels / {_num(rate / 1e6)} MHz (docs/physics.md §2 eq 4)"
        )
    rows = [
        ["line period T_line", _duration(timing.line_period_s)],
        ["window", f"rows {timing.window_start_row} .. "
         f"{timing.window_start_row + timing.window_rows - 1} (k = {timing.window_rows})"],
        ["exposure", f"n = {timing.exposure_lines} lines = {_duration(timing.exposure_s)}"],
        ["first frame (n + k + 1) T_line", _duration(timing.frame_time_s)],
        ["frame period max(k, n + 1) T_line + back path", _duration(timing.frame_period_s)],
        ["back path", _duration(timing.back_path_s)],
        ["TDI line period", _duration(timing.tdi_line_period_s)],
        ["max TDI stages M0", str(timing.max_stages)],
    ]  # fmt: skip
    for role in ("gain", "offset", "readout_mode", "test_pattern"):
        value = getattr(timing, role)
        if value is not None:
            rows.append([role.replace("_", " "), f"`{value}`"])
    extra = [spec.doc] if spec.doc else []
    if spec.dummy_row is not None:
        extra.append(f"Dummy row address: {spec.dummy_row}.")
    if spec.exposure_remainder_s:
        extra.append(f"T_RES = {_duration(spec.exposure_remainder_s)}.")
    return [
        f"Model {formula}.",
        *(["", " ".join(extra)] if extra else []),
        "",
        "At the reset values:",
        "",
        *table(["Quantity", "Value"], rows),
        "",
    ]


def _sensor(number: int, regmap: RegisterMap) -> list[str]:
    spi = regmap.spi
    what = (
        "**A model**: no public register map exists; addresses, widths and reset values are camd's."
        if regmap.modelled
        else "**From the public datasheet** (assumptions are marked in the map file)."
    )
    facts = [
        f"- Pixel array: {regmap.rows} rows x {regmap.columns} columns"
        + (
            f" (first active row {regmap.first_row}, column {regmap.first_column})"
            if regmap.first_row or regmap.first_column
            else ""
        )
        + ".",
        f"- SPI frame: {spi.frame_bits} bits = {spi.rw_bits}-bit command (read {spi.read_code}, "
        f"write {spi.write_code}) + {spi.address_bits}-bit address + {spi.data_bits}-bit data; "
        f"mode {spi.mode} (CPOL {spi.cpol}, CPHA {spi.cpha}); up to "
        f"{_num(spi.max_clock_hz / 1e6)} MHz." + (f" {spi.doc}" if spi.doc else ""),
        f"- Output: {regmap.output.interface}, {regmap.output.lanes} lane(s), "
        f"{regmap.output.word_bits}-bit words"
        + ("; trained by the FPGA before imaging." if regmap.output.needs_training else "."),
    ]
    if regmap.soft_reset is not None:
        facts.append(
            f"- Soft reset: write {regmap.soft_reset.value} (0x{regmap.soft_reset.value:X}) to "
            f"`{regmap.soft_reset.field}`."
        )
    if regmap.source:
        facts.append(f"- Source: {regmap.source}.")
    registers = table(
        ["Address", "Name", "Width", "Access", "Volatile", "Reset", "Description"],
        [
            [
                f"0x{reg.address:02X}",
                f"`{reg.name}`",
                str(reg.width),
                reg.access.upper(),
                "yes" if reg.volatile else "",
                _hex(reg.reset, reg.width),
                reg.doc + (f" Mirrors {', '.join(reg.mirrors)}." if reg.mirrors else ""),
            ]
            for reg in regmap.by_address()
        ],
    )
    field_rows = [row for reg in regmap.by_address() for row in _field_rows(reg)]
    roles = table(
        ["Role", "Value"],
        [[f"`{role}`", f"`{regmap.roles[role]}`"] for role in ROLES if role in regmap.roles],
    )
    lines = [
        f"## {number}. {regmap.sensor}",
        "",
        f"{regmap.description}. {what} File: `config/sensors/{regmap.sensor}.toml`.",
        "",
        *facts,
        "",
        "### Timing",
        "",
        *_timing_lines(regmap, reset_timing(regmap)),
        "### Roles",
        "",
        *roles,
        "",
        "### Registers",
        "",
        *registers,
        "",
        "### Fields",
        "",
        *(
            table(
                ["Register", "Field", "Bits", "Values", "Unit", "Scale", "Description"], field_rows
            )
            if field_rows
            else ["None."]
        ),
        "",
    ]
    if regmap.groups:
        lines += [
            "### Groups",
            "",
            *table(
                ["Group", "Registers (MSB first)", "Hold", "Range", "Unit", "Description"],
                [
                    [
                        f"`{g.name}`",
                        ", ".join(f"`{r}`" for r in g.registers),
                        f"`{g.hold}`" if g.hold else "",
                        "{} .. {}".format(*regmap.group_range(g)),
                        g.unit,
                        g.doc,
                    ]
                    for g in regmap.groups
                ],
            ),
            "",
        ]
    return lines


def render_sensors_doc(regmaps: Sequence[RegisterMap]) -> str:
    """Return the full text of docs/sensors.md for ``regmaps``."""
    contents = ["1. Register map schema", "2. Access rules and host behaviour"]
    contents += [f"{i}. {m.sensor}" for i, m in enumerate(regmaps, start=3)]
    lines = [
        "# Sensor register maps",
        "",
        "<!-- Generated by `python -m camd.sensor.docgen`; do not edit by hand. -->",
        "",
        "This document is generated from the register-map schema (`camd/sensor/regmap.py`) and "
        "the shipped maps (`config/sensors/*.toml`) by `python -m camd.sensor.docgen`. "
        "`tests/test_sensor_docs.py` fails when it differs from the generated text, so edit the "
        "maps and regenerate rather than editing this file.",
        "",
        *contents,
        "",
        *_schema(),
        *_behaviour(),
    ]
    for number, regmap in enumerate(regmaps, start=3):
        lines += _sensor(number, regmap)
    return "\n".join(lines).rstrip("\n") + "\n"


def shipped_maps() -> list[RegisterMap]:
    """Every map in config/sensors/, by sensor name."""
    return [load_register_map(name) for name in list_sensors()]


def main(argv: Sequence[str] | None = None) -> int:
    parser = docgen_parser(
        "python -m camd.sensor.docgen",
        "Generate docs/sensors.md from the register-map schema and the shipped maps.",
        "sensors.md",
    )
    parser.add_argument(
        "--map",
        dest="maps",
        type=Path,
        action="append",
        default=None,
        help="render these map files instead of the shipped ones (repeatable)",
    )
    args = parser.parse_args(argv)
    output: Path = args.output
    try:
        maps = [load_register_map(p) for p in args.maps] if args.maps else shipped_maps()
        text = render_sensors_doc(maps)
    except (RegisterMapError, FileNotFoundError) as exc:
        print(f"docgen: {exc}", file=sys.stderr)
        return 2
    return write_or_check(output, text, check=args.check, command="python -m camd.sensor.docgen")


if __name__ == "__main__":
    raise SystemExit(main())
