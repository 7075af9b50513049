"""Where an error of a config file is: ``file:line`` (``place``), the error that begins so
(``DataFileError``), a problem a check finds at a place (``KeyedError``), and the line of a
place in a TOML text (``line_of``, ``TomlLayout``) or a YAML one (``yaml_lines``: PyYAML's node
graph keeps the marks its parsed values lose)."""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

Loc = tuple[str | int, ...]
"""A place in a data file: the keys and ``[[array]]`` indices down to it (pydantic's ``loc``)."""


class DataFileError(ValueError):
    """A data file is invalid; the message starts with ``file:line:`` (or ``file:``)."""

    def __init__(self, path: Path | str, line: int | None, message: str) -> None:
        super().__init__(f"{place(path, line)}: {message}")
        self.path = Path(path)
        self.line = line


def place(path: Path | str, line: int | None) -> str:
    """``file:line`` (``file`` when the line is not known): how the error of every data file
    (TOML or a campaign's YAML) begins."""
    return f"{path}:{line}" if line is not None else f"{path}"


class KeyedError(ValueError):
    """A problem a check finds at one place of a data file, for ``located`` to place.

    Raised by a model validator (pydantic keeps it as the error's context; the location of the
    model that raised it goes in front of ``key``) or by a check after validation. ``key`` is
    a key, or the ``Loc`` of the place. The message is shown after ``label``: by default the
    place's first key (or its named entry, see ``located``); ``label=""`` shows it alone.
    """

    def __init__(self, key: str | Loc, message: str, *, label: str | None = None) -> None:
        super().__init__(message)
        self.loc: Loc = (key,) if isinstance(key, str) else tuple(key)
        self.message = message
        self.label = label


def clean_loc(loc: Sequence[str | int]) -> Loc:
    """pydantic's location of an error without its internal parts (validator functions,
    literal and constrained types, the ``Sourced`` wrapper's name): the keys and indices as
    the file writes them."""
    internal = ("function-", "literal[", "constrained-", "Sourced[")
    return tuple(
        part
        for part in loc
        if isinstance(part, int) or not (part.startswith(internal) or part == "Sourced")
    )


def child(node: object, part: str | int) -> object:
    """``node[part]`` of parsed TOML, None when it is not there."""
    if isinstance(node, dict) and isinstance(part, str):
        return node.get(part)
    if isinstance(node, list) and isinstance(part, int) and 0 <= part < len(node):
        return node[part]
    return None


def line_of(text: str, data: Mapping[str, Any], loc: Sequence[str | int]) -> int | None:
    """The line of the TOML text ``text`` (parsed into ``data``) where the place pydantic's
    ``loc`` names is written (see ``located``)."""
    return TomlLayout.of(text).line(clean_loc(loc), data)


_HEADER = re.compile(r"^\s*(\[\[?)\s*([A-Za-z0-9_.]+)\s*\]\]?")


Span = tuple[int, int]  # first and last 1-based line; the first is a header but for the top level


@dataclass(frozen=True)
class TomlLayout:
    """Where things are in a TOML text: line spans of the ``[tables]`` (``""``: the top level,
    up to the first header) and of the entries of each ``[[array]]``."""

    lines: list[str]
    tables: dict[str, Span]
    entries: dict[str, list[Span]]

    @classmethod
    def of(cls, text: str) -> TomlLayout:
        lines = text.splitlines()
        headers = [("[", "", 1)]  # the top level, up to the first header
        for number, line in enumerate(lines, start=1):
            match = _HEADER.match(line)
            if match:
                headers.append((match.group(1), match.group(2), number))
        ends = [start - 1 for _, _, start in headers[1:]] + [len(lines)]
        tables: dict[str, Span] = {}
        entries: dict[str, list[Span]] = {}
        for (brackets, name, start), end in zip(headers, ends, strict=True):
            if brackets == "[[":
                entries.setdefault(name, []).append((start, end))
            else:
                tables.setdefault(name, (start, end))
        return cls(lines, tables, entries)

    def line(self, loc: Loc, data: Mapping[str, Any]) -> int | None:
        """The line of the place ``loc`` names (see ``located``)."""
        head = loc[0] if loc else None
        if not isinstance(head, str):
            return None
        if head in self.entries:
            spans = self.entries[head]
            if len(loc) == 1 or not isinstance(loc[1], int):
                return spans[0][0]
            if loc[1] >= len(spans):
                return None
            entry = child(child(data, head), loc[1])
            return self._within(spans[loc[1]], loc[2:], entry, spans[loc[1]][0])
        node: object = data
        for n in range(len(loc), 0, -1):
            keys = loc[:n]
            name = ".".join(str(part) for part in keys)
            if all(isinstance(part, str) for part in keys) and name in self.tables:
                for part in keys:
                    node = child(node, part)
                return self._within(self.tables[name], loc[n:], node, self.tables[name][0])
        return self._within(self.tables.get("", (1, 0)), loc, data, None)

    def _within(self, span: Span, rest: Loc, node: object, otherwise: int | None) -> int | None:
        """The line of ``rest[0] = ...`` in the span (of the inline table ``rest[1]`` of its
        array, when there is one), else ``otherwise``."""
        key = rest[0] if rest else None
        if not isinstance(key, str):
            return otherwise
        pattern = re.compile(rf"^\s*[\"']?{re.escape(key)}[\"']?\s*=")
        start = next(
            (n for n in range(span[0], span[1] + 1) if pattern.match(self.lines[n - 1])), None
        )
        if start is None:
            return otherwise
        if len(rest) > 1 and isinstance(rest[1], int):
            return self._item(span, start, child(node, key), rest[1]) or start
        return start

    def _item(self, span: Span, start: int, items: object, index: int) -> int | None:
        """The line of the ``index``-th inline table of an array, by its ``name = "..."``."""
        if not isinstance(items, list) or not 0 <= index < len(items):
            return None
        name = child(items[index], "name")
        if not isinstance(name, str):
            return None
        before = sum(1 for item in items[:index] if child(item, "name") == name)
        pattern = re.compile(rf"\bname\s*=\s*[\"']{re.escape(name)}[\"']")
        found = [n for n in range(start, span[1] + 1) if pattern.search(self.lines[n - 1])]
        return found[before] if before < len(found) else None


def yaml_lines(text: str) -> dict[Loc, int]:
    """The 1-based line of every place of the YAML text ``text``, by its ``Loc``: of each
    mapping's key (``()``: where the document begins) and of each sequence's item. PyYAML's
    node graph keeps the marks that its parsed values lose. yaml.YAMLError if it is not YAML
    (``yaml_problem`` says where)."""
    import yaml

    root = yaml.compose(text, Loader=yaml.SafeLoader)
    lines: dict[Loc, int] = {}
    if root is None:
        return lines
    lines[()] = root.start_mark.line + 1

    def walk(node: yaml.Node, loc: Loc, above: frozenset[int]) -> None:
        if id(node) in above:  # an alias of a node that holds it: the same places again
            return
        above = above | {id(node)}
        if isinstance(node, yaml.MappingNode):
            for key, value in node.value:
                if isinstance(key, yaml.ScalarNode):
                    here = (*loc, key.value)
                    if here in lines and key.value != "<<":  # `<<` merges: not a key
                        # YAML's parsers keep the last silently; TOML refuses it, as here.
                        raise yaml.MarkedYAMLError(
                            problem=f"the key {key.value!r} is given twice (first on line "
                            f"{lines[here]}); keep one",
                            problem_mark=key.start_mark,
                        )
                    lines[here] = key.start_mark.line + 1
                    walk(value, here, above)
        elif isinstance(node, yaml.SequenceNode):
            for index, item in enumerate(node.value):
                lines[(*loc, index)] = item.start_mark.line + 1
                walk(item, (*loc, index), above)

    walk(root, (), frozenset())
    return lines


def yaml_line(lines: Mapping[Loc, int], loc: Sequence[str | int]) -> int | None:
    """The line (of ``yaml_lines``) of the deepest place of pydantic's ``loc`` written in the
    file. Parts the file does not write are passed over (a union's member, a discriminated
    union's tag), so a missing key gives the line of the mapping it belongs in."""
    here: Loc = ()
    for part in loc:
        if (*here, part) in lines:
            here = (*here, part)
    return lines.get(here)


def yaml_problem(exc: Exception) -> tuple[int | None, str]:
    """The line and a one-line account of a YAML syntax error (PyYAML's spans several lines,
    with the text quoted): ``expected ',' or '}', but got ':' (while parsing a flow mapping
    begun on line 15)``."""
    import yaml

    if not isinstance(exc, yaml.MarkedYAMLError):
        return None, " ".join(str(exc).split())
    mark = exc.problem_mark or exc.context_mark
    line = mark.line + 1 if mark is not None else None
    message = exc.problem or exc.context or "not YAML"
    if exc.problem and exc.context:
        begun = exc.context_mark
        at = f" begun on line {begun.line + 1}" if begun is not None and begun is not mark else ""
        message = f"{exc.problem} ({exc.context}{at})"
    return line, " ".join(message.split())
