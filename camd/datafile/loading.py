"""Reading a data file: the TOML parsed, a syntax error at its line (``parse_toml``), every kind
of data file loaded the one way (``DataFileKind``)."""

from __future__ import annotations

import functools
import re
import tomllib
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, Generic, TypeVar

from pydantic import BaseModel, ValidationError

from camd.datafile.places import DataFileError, KeyedError
from camd.datafile.words import located

Model = TypeVar("Model", bound=BaseModel)


def read_toml(path: Path, error: type[DataFileError]) -> tuple[str, dict[str, Any]]:
    """The text of a TOML data file and what it holds (see ``parse_toml``)."""
    text = path.read_text(encoding="utf-8")
    return text, parse_toml(text, path, error)


def parse_toml(
    text: str, path: Path | str, error: type[DataFileError] = DataFileError
) -> dict[str, Any]:
    """What the TOML text ``text`` of the file ``path`` holds; a syntax error is ``error``,
    ``file:line: not valid TOML: <the parser's words>``, at the line the parser names (the
    last line when it names the end of the text), as every config file says it."""
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        match = re.search(r"line (\d+)", str(exc))
        line = int(match.group(1)) if match else len(text.splitlines()) or None
        raise error(path, line, f"not valid TOML: {exc}") from None


class DataFileKind(Generic[Model]):
    """One kind of TOML data file (camera profiles, stage profiles, the wheel, register maps,
    the command dictionary), read the one way every kind is read: the TOML parsed (a syntax
    error names the line the parser gives), validated as ``model``, then by ``check`` (which
    raises ``KeyedError``); any error is ``error`` as ``located`` words it, ``file:line: key:
    what to write``, without a traceback. ``named`` calls the entries of arrays of tables by
    their names (see ``located``).

    A kind shipped as ``config/<folder>/<name>.toml`` files (``folder``, called when asked: the
    config directory is found then) is also found by name (``find``): the ``noun`` says what a
    name stands for in the refusal of an unknown one (``no camera profile 'x'; known: ...``),
    ``name_of`` what the name names when that is not the noun (a register map is named by its
    ``sensor``).
    """

    def __init__(
        self,
        model: type[Model],
        error: type[DataFileError],
        *,
        named: Mapping[str, str] | None = None,
        check: Callable[[Model], None] | None = None,
        folder: Callable[[], Path] | None = None,
        noun: str = "data file",
        name_of: str | None = None,
    ) -> None:
        self.model = model
        self.error = error
        self.named = dict(named or {})
        self.check = check
        self.folder = folder
        self.noun = noun
        self.name_of = name_of
        # A shipped file is read once per process; one given by path is read each time it is
        # asked for, since it may have been edited in between.
        self.shipped: Callable[[Path], Model] = functools.cache(self.load)

    def load(self, path: Path) -> Model:
        """The file at ``path``, validated; ``error`` (``file:line: ...``) if it is not valid.
        OSError as reading raises it (a missing file is FileNotFoundError)."""
        text, data = read_toml(path, self.error)
        try:
            loaded = self.model.model_validate(data)
            if self.check is not None:
                self.check(loaded)
        except (ValidationError, KeyedError) as exc:
            raise located(
                exc,
                path=path,
                text=text,
                data=data,
                model=self.model,
                error=self.error,
                named=self.named,
            ) from None
        return loaded

    def names(self) -> list[str]:
        """The names of the shipped files, sorted."""
        if self.folder is None:
            return []
        return sorted(p.stem for p in self.folder().glob("*.toml"))

    def find(self, name_or_path: str | Path) -> Model:
        """A shipped file by name (``<folder>/<name>.toml``, read once) or a ``.toml`` file by
        path (read each time)."""
        path = Path(name_or_path)
        if path.suffix == ".toml":
            return self.load(path)
        known = f"known: {', '.join(self.names())}"
        if self.folder is None or not re.fullmatch(r"[a-z0-9_]+", str(name_or_path)):
            what = f"not a {self.name_of or self.noun} name or a .toml file"
            raise self.error(path, None, f"{what}; {known}")
        path = self.folder() / f"{name_or_path}.toml"
        if not path.is_file():
            named = f"{self.noun} for {self.name_of}" if self.name_of else self.noun
            raise FileNotFoundError(f"no {named} {name_or_path!r}; {known}")
        return self.shipped(path)
