"""Saved sensor configurations: a TOML file of register values, written and read exactly.

    # camd sensor configuration
    sensor = "hr400"

    [registers]
    WIN_START = 0x02F5  # 757
    WIN_ROWS = 0x0216  # 534

Values are raw register values (hex, with the decimal in a comment); the file round-trips
bit-exactly. Checking the names and values against the register map is the job of the code that
writes them to the sensor (all before anything is written).
"""

from __future__ import annotations

import re
from collections.abc import Mapping

from camd.datafile import DataFileError, line_of, parse_toml, place

_NAME = re.compile(r"^[A-Z][A-Z0-9_]*$")


class ConfigFileError(ValueError):
    """A configuration file cannot be read; the message names the file and what is wrong."""


def format_configuration(sensor: str, registers: Mapping[str, int], *, note: str = "") -> str:
    """The TOML text of a configuration (registers in the order given)."""
    lines = [
        "# camd sensor configuration: raw register values (`camctl reg load FILE` writes them back)",
    ]
    if note:
        lines.append(f"# {note}")
    lines += [f'sensor = "{sensor}"', "", "[registers]"]
    for name, value in registers.items():
        if not _NAME.match(name):
            raise ValueError(f"{name!r} is not a register name")
        lines.append(f"{name} = 0x{value:04X}  # {value}")
    return "\n".join(lines) + "\n"


def parse_configuration(text: str, *, source: str = "configuration") -> tuple[str, dict[str, int]]:
    """(sensor, {register name: raw value}) from a configuration's text; ConfigFileError
    ``source:line: ...`` (the line of the key) otherwise, as every config file's errors."""
    try:
        data = parse_toml(text, source)
    except DataFileError as exc:
        raise ConfigFileError(str(exc)) from None

    def at(*loc: str) -> str:
        return place(source, line_of(text, data, loc))

    sensor = data.get("sensor")
    registers = data.get("registers")
    if not isinstance(sensor, str) or not isinstance(registers, dict):
        raise ConfigFileError(
            f'{source}: a configuration needs sensor = "<name>" and a [registers] table; '
            "write one with `camctl reg save FILE`"
        )
    unknown = sorted(set(data) - {"sensor", "registers"})
    if unknown:
        key = unknown[0]
        raise ConfigFileError(f"{at(key)}: {key}: unknown key; known keys: sensor, registers")
    values: dict[str, int] = {}
    for name, value in registers.items():
        if isinstance(value, bool) or not isinstance(value, int) or value < 0:
            raise ConfigFileError(
                f"{at('registers', name)}: registers.{name} = {value!r} is not a raw register "
                "value; give a non-negative integer (e.g. 0x02F5)"
            )
        values[name.upper()] = value
    return sensor, values
