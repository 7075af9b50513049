"""What the data files of config/ (camera, stage and wheel profiles) have in common.

``Sourced`` holds a physical value with its provenance (a paper's section, or why it was
assumed); ``DataFileError`` is a file that does not validate, its message starting with
``file:line:``. Pure: the simulated camera reads the same files.
"""

from __future__ import annotations

import re
import tomllib
from pathlib import Path
from typing import Generic, TypeVar

from pydantic import BaseModel, ConfigDict, Field, model_validator

T = TypeVar("T")


class DataFileError(ValueError):
    """A data file is invalid; the message starts with ``file:line:`` (or ``file:``)."""

    def __init__(self, path: Path | str, line: int | None, message: str) -> None:
        where = f"{path}:{line}" if line is not None else f"{path}"
        super().__init__(f"{where}: {message}")
        self.path = Path(path)
        self.line = line


class Sourced(BaseModel, Generic[T]):
    """A value with its provenance: exactly one of ``source`` or ``assumed``."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    value: T = Field(description="the value, in the unit the key's name gives")
    source: str | None = Field(default=None, description="where the value comes from")
    assumed: str | None = Field(default=None, description="why the value was chosen")

    @model_validator(mode="after")
    def _one_provenance(self) -> Sourced[T]:
        given = [k for k in ("source", "assumed") if (getattr(self, k) or "").strip()]
        if len(given) != 1:
            what = "both" if len(given) == 2 else "neither"
            raise ValueError(
                "give exactly one of `source` (where the value comes from) or `assumed` "
                f"(why it was chosen), not {what}"
            )
        return self

    @property
    def provenance(self) -> str:
        """``source: ...`` or ``assumed: ...``, for docs and reports."""
        if self.source:
            return f"source: {self.source}"
        return f"assumed: {self.assumed}"

    @property
    def is_assumed(self) -> bool:
        return bool(self.assumed)


def read_toml(path: Path, error: type[DataFileError]) -> tuple[str, dict[str, object]]:
    """The text of a TOML data file and what it holds; a syntax error becomes ``error`` with
    the line the parser names."""
    text = path.read_text(encoding="utf-8")
    try:
        return text, tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        match = re.search(r"line (\d+)", str(exc))
        raise error(path, int(match.group(1)) if match else None, str(exc)) from None


def named_file(
    name_or_path: str | Path,
    folder: Path,
    *,
    kind: str,
    known: list[str],
    error: type[DataFileError],
) -> Path:
    """The file a name (``folder/<name>.toml``) or a ``.toml`` path stands for."""
    path = Path(name_or_path)
    if path.suffix == ".toml":
        return path
    if not re.fullmatch(r"[a-z0-9_]+", str(name_or_path)):
        raise error(path, None, f"not a {kind} name or a .toml file; known: {', '.join(known)}")
    path = folder / f"{name_or_path}.toml"
    if not path.is_file():
        raise FileNotFoundError(f"no {kind} {name_or_path!r}; known: {', '.join(known)}")
    return path


def key_line(text: str, key: str, table: str | None = None) -> int | None:
    """The 1-based line of ``key = ...`` in a TOML text: at the top level (or a ``[key]`` /
    ``[[key]]`` header), or inside ``[table]`` (falling back to the table's header); None if
    the key is not written (a missing key)."""
    assign = re.compile(rf"^\s*{re.escape(key)}\s*=")
    header = re.compile(r"^\s*\[+\s*([A-Za-z0-9_.]+)\s*\]+")
    current: str | None = None
    table_line: int | None = None
    for number, line in enumerate(text.splitlines(), start=1):
        match = header.match(line)
        if match:
            current = match.group(1)
            if table is None and current == key:
                return number
            if table is not None and current == table and table_line is None:
                table_line = number
            continue
        if current == table and assign.match(line):
            return number
    return table_line
