"""The common locator of data files: a ValidationError becomes ``file:line: where: message``."""

from __future__ import annotations

import re
import tomllib
from pathlib import Path
from typing import Annotated

import pytest
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from camd.datafile import DataFileError, DataFileKind, KeyedError, Sourced, located, read_toml

PATH = Path("demo.toml")


class DemoError(DataFileError):
    """A demo file is invalid."""


class Part(BaseModel):
    model_config = ConfigDict(extra="forbid")

    name: str
    bits: int = Field(ge=0)


class Item(BaseModel):
    model_config = ConfigDict(extra="forbid")

    name: str
    size: int = Field(ge=1)
    parts: list[Part] = Field(default_factory=list)


class Limits(BaseModel):
    model_config = ConfigDict(extra="forbid")

    low: float
    high: float = Field(gt=0)


class Demo(BaseModel):
    model_config = ConfigDict(extra="forbid")

    title: str
    gain: Sourced[Annotated[float, Field(gt=0)]]
    limits: Limits
    items: list[Item] = Field(default_factory=list)

    @model_validator(mode="after")
    def _check(self) -> Demo:
        if self.limits.low > self.limits.high:
            raise KeyedError(("limits", "low"), f"{self.limits.low:g} is above high; lower it")
        return self


TEXT = """\
title = "demo"
gain = { value = 2.0, source = "a test" }

[limits]
low = 1.0
high = 5.0

[[items]]
name = "a"
size = 1
parts = [
    { name = "x", bits = 1 },
    { name = "y", bits = 2 },
    { name = "y", bits = 3 },
]

[[items]]
name = "b"
size = 2
"""


def error_of(old: str, new: str, named: dict[str, str] | None = None) -> tuple[DataFileError, str]:
    """The located error of TEXT with ``old`` replaced by ``new``, and the changed text."""
    assert old in TEXT, old
    text = TEXT.replace(old, new, 1)
    data = tomllib.loads(text)
    with pytest.raises(ValidationError) as info:
        Demo.model_validate(data)
    error = located(
        info.value, path=PATH, text=text, data=data, model=Demo, error=DemoError, named=named
    )
    assert isinstance(error, DemoError)
    return error, text


def line_of(text: str, snippet: str, nth: int = 0) -> int:
    """The 1-based line of the ``nth`` line holding ``snippet``."""
    found = [n for n, line in enumerate(text.splitlines(), start=1) if snippet in line]
    return found[nth]


def test_the_demo_file_validates() -> None:
    Demo.model_validate(tomllib.loads(TEXT))


def test_a_missing_top_level_key_has_no_line() -> None:
    error, _ = error_of('title = "demo"\n', "")
    assert error.line is None
    assert str(error) == "demo.toml: title: missing key; add `title = ...`"

    error, _ = error_of('gain = { value = 2.0, source = "a test" }\n', "")
    assert error.line is None
    assert str(error) == (
        'demo.toml: gain: missing key; add `gain = { value = ..., source = "..." }` '
        '(or assumed = "...")'
    )

    error, _ = error_of("[limits]\nlow = 1.0\nhigh = 5.0\n", "")
    assert str(error) == "demo.toml: limits: missing key; add a [limits] table"


def test_a_wrong_value_inside_a_table_names_its_line() -> None:
    error, text = error_of("high = 5.0", "high = -5.0")
    assert error.line == line_of(text, "high = -5.0") == 6
    assert str(error) == "demo.toml:6: limits.high: -5.0 is out of range; allowed: 0 < high"

    error, text = error_of("gain = { value = 2.0,", "gain = { value = -2.0,")
    assert str(error) == "demo.toml:2: gain.value: -2.0 is out of range; allowed: 0 < value"


def test_an_unknown_key_lists_the_known_ones() -> None:
    error, text = error_of('title = "demo"\n', 'title = "demo"\ncolour = "red"\n')
    assert error.line == line_of(text, "colour") == 2
    assert str(error) == (
        "demo.toml:2: colour: unknown key; known keys: title, gain, limits, items"
    )

    error, _ = error_of("low = 1.0", "low = 1.0\nmiddle = 3.0")
    assert str(error) == ("demo.toml:6: limits.middle: unknown key; known keys: low, high")

    error, _ = error_of('source = "a test" }', 'source = "a test", unit = "1" }')
    assert str(error) == ("demo.toml:2: gain.unit: unknown key; known keys: value, source, assumed")


def test_a_value_where_a_table_belongs() -> None:
    error, _ = error_of('gain = { value = 2.0, source = "a test" }', "gain = 2.0")
    assert str(error) == (
        "demo.toml:2: gain: Input should be a valid dictionary or instance of Sourced; "
        'write `gain = { value = ..., source = "..." }`'
    )


def test_an_entry_of_an_array_of_tables_by_index() -> None:
    error, text = error_of("size = 2", "size = 0")
    assert error.line == line_of(text, "size = 0") == 19
    assert str(error) == "demo.toml:19: items.1.size: 0 is out of range; allowed: 1 <= size"

    # A key missing from the entry: the line of the entry's header.
    error, text = error_of("size = 2\n", "")
    assert error.line == line_of(text, "[[items]]", nth=1) == 17
    assert str(error) == "demo.toml:17: items.1.size: missing key; add `size = ...`"


def test_an_inline_table_of_an_array_by_its_name() -> None:
    # The second of two parts named "y": its own line, not the first one's.
    error, text = error_of('{ name = "y", bits = 3 }', '{ name = "y", bits = -3 }')
    assert error.line == line_of(text, "bits = -3") == 14
    assert str(error) == (
        "demo.toml:14: items.0.parts.2.bits: -3 is out of range; allowed: 0 <= bits"
    )

    # Named arrays call their entries by name.
    named = {"items": "item {}", "parts": "part {!r}"}
    error, _ = error_of('{ name = "x", bits = 1 }', '{ name = "x", bits = -1 }', named)
    assert str(error) == (
        "demo.toml:12: item a: part 'x': bits: -1 is out of range; allowed: 0 <= bits"
    )


def test_a_keyed_error_of_a_validator_and_of_a_later_check() -> None:
    error, text = error_of("low = 1.0", "low = 9.0")
    assert error.line == line_of(text, "low = 9.0") == 5
    assert str(error) == "demo.toml:5: limits: 9 is above high; lower it"

    # Raised after validation: no pydantic location in front; label="" shows the message alone.
    data = tomllib.loads(TEXT)
    for problem, expected in [
        (KeyedError("title", "no such camera"), "demo.toml:1: title: no such camera"),
        (KeyedError(("items", 1, "name"), "b is taken", label=""), "demo.toml:18: b is taken"),
    ]:
        error = located(problem, path=PATH, text=TEXT, data=data, model=Demo, error=DemoError)
        assert str(error) == expected


def test_a_toml_syntax_error_names_its_line(tmp_path: Path) -> None:
    path = tmp_path / "demo.toml"
    path.write_text(TEXT.replace("high = 5.0", "high = = 5.0"), encoding="utf-8")
    with pytest.raises(DemoError) as info:
        read_toml(path, DemoError)
    assert info.value.line == 6
    assert str(info.value).startswith(f"{path}:6: ")

    path.write_text(TEXT, encoding="utf-8")
    text, data = read_toml(path, DemoError)
    assert text == TEXT
    assert data["title"] == "demo"


def _no_untitled(demo: Demo) -> None:
    """A check after validation, as a profile's against its register map."""
    if demo.title == "untitled":
        raise KeyedError("title", "give the demo a title")


def test_one_loader_reads_validates_checks_and_finds_a_kind(tmp_path: Path) -> None:
    """issue 32: every kind of data file is read by DataFileKind (it was five _load functions):
    TOML syntax, the model, the check after it, all as file:line; shipped files by name."""
    folder = tmp_path / "demos"
    folder.mkdir()
    (folder / "good.toml").write_text(TEXT, encoding="utf-8")
    bad = folder / "bad.toml"
    bad.write_text(TEXT.replace("size = 2", "size = 0"), encoding="utf-8")
    demos = DataFileKind(Demo, DemoError, check=_no_untitled, folder=lambda: folder, noun="demo")

    assert demos.names() == ["bad", "good"]
    assert demos.find("good").title == "demo"
    assert demos.find("good") is demos.find("good")  # a shipped file is read once
    with pytest.raises(DemoError) as info:
        demos.find("bad")
    assert str(info.value) == f"{bad}:19: items.1.size: 0 is out of range; allowed: 1 <= size"
    assert info.value.line == 19

    given = tmp_path / "given.toml"  # a file given by path is read each time: it may change
    given.write_text(TEXT, encoding="utf-8")
    assert demos.find(given).title == "demo"
    given.write_text(TEXT.replace('"demo"', '"untitled"'), encoding="utf-8")
    with pytest.raises(DemoError) as info:
        demos.find(given)
    assert str(info.value) == f"{given}:1: title: give the demo a title"
    given.write_text(TEXT.replace("high = 5.0", "high = = 5.0"), encoding="utf-8")
    with pytest.raises(DemoError) as info:
        demos.load(given)
    assert info.value.line == 6

    with pytest.raises(FileNotFoundError, match=r"^no demo 'nosuch'; known: bad, good$"):
        demos.find("nosuch")
    with pytest.raises(DemoError, match=r"not a demo name or a \.toml file; known: bad, good$"):
        demos.find("Not A Name")
    maps = DataFileKind(Demo, DemoError, folder=lambda: folder, noun="map", name_of="sensor")
    with pytest.raises(FileNotFoundError, match=r"^no map for sensor 'nosuch'; known: bad"):
        maps.find("nosuch")
    with pytest.raises(DemoError, match=r"not a sensor name or a \.toml file; known: bad, good$"):
        maps.find("Not A Name")


# -- the same fault in the same words, whatever the file ---------------------------------------

SAME_WORDS = [
    # (file of config/, text replaced, by, what the error says after `file[:line]: `)
    ("profiles/hr400.toml", 'sensor = "hr400"\n', 'sensor = "hr400"\ncolums = 3\n',
     "colums: unknown key; did you mean `columns`?; known keys: profile, description, "),
    ("stages/linear_rail.toml", "error = 0.0", "eror = 0.0",
     "sim.eror: unknown key; did you mean `error`?; known keys: ripple_period_m, "),
    ("protocol.toml", "opcode = 0x01", "opcod = 0x01",
     "command PING: opcod: unknown key; did you mean `opcode`?; known keys: name, opcode, "),
    ("camd.toml", "port = 8422", "prot = 8422",
     "api.prot: unknown key; did you mean `port`?; known keys: host, port, token, "),
    ("campaigns/example_stare.yaml", "    mode: area", "    mod: area",
     "steps[0] (id 'window').mod: unknown key; did you mean `mode`?; known keys: id, title, "),
    ("profiles/hr400.toml", "\nmagnification = {", "\n# magnification = {",
     'magnification: missing key; add `magnification = { value = ..., source = "..." }`'),
    ("protocol.toml", 'name = "PING"\nopcode = 0x01\n', 'name = "PING"\n',
     "command PING: opcode: missing key; add `opcode = ...`"),
    ("camd.toml", "[telemetry.limits.fpga_temp_degc]\nyellow = [0.0, 70.0]\n",
     "[telemetry.limits.fpga_temp_degc]\n",
     "telemetry.limits.fpga_temp_degc.yellow: missing key; add `yellow = ...`"),
    ("campaigns/example_stare.yaml", "    function: dark_noise\n", "",
     "steps[3] (id 'dark_noise').function: missing key; add `function: ...`"),
    ("sensors/hr400.toml", "address_bits = 7", "address_bits = 17",
     "spi.address_bits: 17 is out of range; allowed: 1 <= address_bits <= 16"),
    ("stages/linear_rail.toml", "travel_m = { value = 1.2,", "travel_m = { value = -1.2,",
     "travel_m.value: -1.2 is out of range; allowed: 0 < value"),
    ("camd.toml", "port = 8422", "port = 70000",
     "api.port: 70000 is out of range; allowed: 0 <= port <= 65535"),
    ("campaigns/example_stare.yaml", "seed: 7", "seed: -7",
     "seed: -7 is out of range; allowed: 0 <= seed <= 4294967295"),
    ("profiles/hr400.toml", 'shutter = { value = "rolling"', 'shutter = { value = "rollin"',
     "shutter.value: 'rollin' is not allowed; use 'rolling', 'global', 'frame_transfer' or "
     "'full_frame'"),
    ("wheel.toml", 'centres = { value = "equal"', 'centres = { value = "equl"',
     "centres.value: 'equl' is not allowed; use 'equal'"),
    ("camd.toml", 'log_level = "info"', 'log_level = "loud"',
     "daemon.log_level: 'loud' is not allowed; use 'debug', 'info', 'warning', 'error' or "
     "'critical'"),
    ("campaigns/example_stare.yaml", "    mode: area", "    mode: aera",
     "steps[0] (id 'window').mode: 'aera' is not allowed; use 'area' or 'tdi'"),
    ("sensors/hr400.toml", "lanes = 8", 'lanes = "8"',
     "output.lanes: '8' is a string, the wrong type; write an integer, without quotes"),
    ("camd.toml", "port = 8422", 'port = "8422"',
     "api.port: '8422' is a string, the wrong type; write an integer, without quotes"),
    ("campaigns/example_stare.yaml", "seed: 7", "seed: seven",
     "seed: 'seven' is a string, the wrong type; write an integer, without quotes"),
]  # fmt: skip


def _load_any(path: Path) -> None:
    """``path`` loaded as the config file it is a copy of."""
    from camd.campaign.loading import load_campaign
    from camd.daemon.config import load_config
    from camd.motion.stage_profile import load_stage_profile
    from camd.motion.wheel_profile import load_wheel_profile
    from camd.protocol.dictionary import load_dictionary
    from camd.sensor.profile import load_profile
    from camd.sensor.regmap import load_register_map

    loaders = {"profiles": load_profile, "stages": load_stage_profile,
               "sensors": load_register_map, "campaigns": load_campaign}  # fmt: skip
    whole = {"protocol.toml": load_dictionary, "wheel.toml": load_wheel_profile,
             "camd.toml": lambda p: load_config(p, env={})}  # fmt: skip
    (whole.get(path.name) or loaders[path.parent.name])(path)


@pytest.mark.parametrize(("file", "old", "new", "says"), SAME_WORDS)
def test_the_same_fault_is_said_in_the_same_words_in_every_config_file(
    tmp_path: Path, file: str, old: str, new: str, says: str
) -> None:
    """issue 32: the data files, camd.toml and campaigns said an unknown key three ways
    ('Extra inputs are not permitted', 'unknown key (a typo?); allowed keys here', 'unknown
    key'), a value out of range three ways, a value not among a few two ways; now one."""
    from camd.paths import config_dir

    text = (config_dir() / file).read_text(encoding="utf-8")
    assert old in text, old
    path = tmp_path / Path(file).parent / Path(file).name
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text.replace(old, new, 1), encoding="utf-8")
    with pytest.raises(ValueError) as info:
        _load_any(path)
    first = str(info.value).splitlines()[0]
    assert re.match(rf"{re.escape(str(path))}(:\d+)?: {re.escape(says)}", first), first


def test_a_toml_syntax_error_is_said_the_same_way_in_every_config_file(tmp_path: Path) -> None:
    """issue 32: 'file:line: <parser>' (data files), 'file: not valid TOML: <parser>' (camd.toml,
    no line) and 'source: not valid TOML: <parser>' (a saved register configuration, no line);
    now 'file:line: not valid TOML: <parser>' in all, the last line at the end of the file."""
    from camd.daemon.config import ConfigError, load_config
    from camd.sensor.config_file import ConfigFileError, parse_configuration
    from camd.sensor.profile import ProfileError, load_profile

    profile = tmp_path / "profile.toml"
    profile.write_text('profile = "x"\ncolumns = = 3\n', encoding="utf-8")
    with pytest.raises(ProfileError) as info:
        load_profile(profile)
    assert str(info.value) == f"{profile}:2: not valid TOML: Invalid value (at line 2, column 11)"
    assert info.value.line == 2

    camd_toml = tmp_path / "camd.toml"
    camd_toml.write_text("[api]\nport = = 8422\n", encoding="utf-8")
    with pytest.raises(ConfigError) as info:
        load_config(camd_toml, env={})
    assert str(info.value) == f"{camd_toml}:2: not valid TOML: Invalid value (at line 2, column 8)"

    with pytest.raises(ConfigFileError) as info:
        parse_configuration('sensor = "hr400"\n[registers]\nGAIN == 3\n', source="saved.toml")
    assert str(info.value) == "saved.toml:3: not valid TOML: Invalid value (at line 3, column 7)"

    camd_toml.write_text("[api]\nport = 8422\nallowed_origins = [\n", encoding="utf-8")
    with pytest.raises(ConfigError) as info:
        load_config(camd_toml, env={})
    assert str(info.value) == f"{camd_toml}:3: not valid TOML: Invalid value (at end of document)"


def test_a_saved_register_configuration_names_the_line_too() -> None:
    """issue 32: a saved register configuration's errors began `file:` alone; now `file:line:`
    as every config file's, and an unknown key in the same words."""
    from camd.sensor.config_file import ConfigFileError, parse_configuration

    good = 'sensor = "hr400"\n\n[registers]\nOFFSET = 0x0010\nWIN_ROWS = 0x0216\n'
    for text, expected in [
        (good.replace("0x0216", "-1"),
         "saved.toml:5: registers.WIN_ROWS = -1 is not a raw register value; give a "
         "non-negative integer (e.g. 0x02F5)"),
        (good.replace("0x0216", "true"),
         "saved.toml:5: registers.WIN_ROWS = True is not a raw register value; give a "
         "non-negative integer (e.g. 0x02F5)"),
        (good.replace('sensor = "hr400"\n', 'sensor = "hr400"\ncolour = 1\n'),
         "saved.toml:2: colour: unknown key; known keys: sensor, registers"),
        (good.replace('sensor = "hr400"\n', ""),
         'saved.toml: a configuration needs sensor = "<name>" and a [registers] table; write '
         "one with `camctl reg save FILE`"),
    ]:  # fmt: skip
        with pytest.raises(ConfigFileError) as info:
            parse_configuration(text, source="saved.toml")
        assert str(info.value) == expected
