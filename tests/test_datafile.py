"""The common locator of data files: a ValidationError becomes ``file:line: where: message``."""

from __future__ import annotations

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
    assert str(error) == "demo.toml: title: Field required; add `title = ...`"

    error, _ = error_of('gain = { value = 2.0, source = "a test" }\n', "")
    assert error.line is None
    assert str(error) == (
        'demo.toml: gain: Field required; add `gain = { value = ..., source = "..." }` '
        '(or assumed = "...")'
    )

    error, _ = error_of("[limits]\nlow = 1.0\nhigh = 5.0\n", "")
    assert str(error) == "demo.toml: limits: Field required; add a [limits] table"


def test_a_wrong_value_inside_a_table_names_its_line() -> None:
    error, text = error_of("high = 5.0", "high = -5.0")
    assert error.line == line_of(text, "high = -5.0") == 6
    assert str(error) == "demo.toml:6: limits.high: Input should be greater than 0"

    error, text = error_of("gain = { value = 2.0,", "gain = { value = -2.0,")
    assert str(error) == "demo.toml:2: gain.value: Input should be greater than 0"


def test_an_unknown_key_lists_the_known_ones() -> None:
    error, text = error_of('title = "demo"\n', 'title = "demo"\ncolour = "red"\n')
    assert error.line == line_of(text, "colour") == 2
    assert str(error) == (
        "demo.toml:2: colour: Extra inputs are not permitted; "
        "known keys: title, gain, limits, items"
    )

    error, _ = error_of("low = 1.0", "low = 1.0\nmiddle = 3.0")
    assert str(error) == (
        "demo.toml:6: limits.middle: Extra inputs are not permitted; known keys: low, high"
    )

    error, _ = error_of('source = "a test" }', 'source = "a test", unit = "1" }')
    assert str(error) == (
        "demo.toml:2: gain.unit: Extra inputs are not permitted; known keys: value, source, assumed"
    )


def test_a_value_where_a_table_belongs() -> None:
    error, _ = error_of('gain = { value = 2.0, source = "a test" }', "gain = 2.0")
    assert str(error) == (
        "demo.toml:2: gain: Input should be a valid dictionary or instance of Sourced; "
        'write `gain = { value = ..., source = "..." }`'
    )


def test_an_entry_of_an_array_of_tables_by_index() -> None:
    error, text = error_of("size = 2", "size = 0")
    assert error.line == line_of(text, "size = 0") == 19
    assert str(error) == "demo.toml:19: items.1.size: Input should be greater than or equal to 1"

    # A key missing from the entry: the line of the entry's header.
    error, text = error_of("size = 2\n", "")
    assert error.line == line_of(text, "[[items]]", nth=1) == 17
    assert str(error) == "demo.toml:17: items.1.size: Field required; add `size = ...`"


def test_an_inline_table_of_an_array_by_its_name() -> None:
    # The second of two parts named "y": its own line, not the first one's.
    error, text = error_of('{ name = "y", bits = 3 }', '{ name = "y", bits = -3 }')
    assert error.line == line_of(text, "bits = -3") == 14
    assert str(error) == (
        "demo.toml:14: items.0.parts.2.bits: Input should be greater than or equal to 0"
    )

    # Named arrays call their entries by name.
    named = {"items": "item {}", "parts": "part {!r}"}
    error, _ = error_of('{ name = "x", bits = 1 }', '{ name = "x", bits = -1 }', named)
    assert str(error) == (
        "demo.toml:12: item a: part 'x': bits: Input should be greater than or equal to 0"
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
    assert str(info.value) == f"{bad}:19: items.1.size: Input should be greater than or equal to 1"
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
