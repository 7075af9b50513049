"""What is wrong and what to write, the same fault in the same words in every config file:
``problem`` words one of pydantic's errors, ``located`` the first of a data file's (``file:line:
where: ...``), ``every_error`` each of camd.toml's; a campaign's explanation uses ``problem``
too (camd.campaign.explain)."""

from __future__ import annotations

import difflib
import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ValidationError
from pydantic_core import ErrorDetails

from camd.datafile.places import (
    DataFileError,
    KeyedError,
    Loc,
    TomlLayout,
    child,
    clean_loc,
    place,
)
from camd.datafile.quoting import cut, what_it_is
from camd.datafile.schema import constraints, is_model, is_tables, type_at
from camd.datafile.sourced import Sourced

_SOURCED_SHAPE = '{ value = ..., source = "..." }'


def located(
    exc: ValidationError | KeyedError,
    *,
    path: Path,
    text: str,
    data: Mapping[str, Any],
    model: type[BaseModel],
    error: type[DataFileError],
    named: Mapping[str, str] | None = None,
) -> DataFileError:
    """A validation error of the data file ``path`` (``text``, parsed into ``data``, validated
    as ``model``) as ``error``: ``file:line: where: what is wrong[; what to write]``.

    The first of pydantic's errors is reported (an unknown key before the others: a misspelt
    key is also missing), in the words of ``problem``. ``where`` is its location, dotted
    (``channels.2.band``); an entry of an array listed in ``named`` is called by its ``name``
    key instead, through the format given (``{"registers": "register {}"}`` gives
    ``register GAIN: width: ...``). A ``KeyedError`` shows its own message after its label.
    The line is that of the key: at the top level, in a ``[table]``, in the n-th ``[[array]]``
    entry, or of an inline table in an array found by its ``name``; else the line of the
    table's header; none for a missing top-level key.
    """
    named = named or {}
    layout = TomlLayout.of(text)
    if isinstance(exc, KeyedError):
        line, message = _keyed(exc, (), layout, data, model, named)
        return error(path, line, message)
    errors = exc.errors()
    # A misspelt key is also a missing one: the unknown key is the cause, and says what to fix.
    first = next((e for e in errors if e["type"] == "extra_forbidden"), errors[0])
    line, message = _explained(first, model, data, named, layout)
    return error(path, line, message)


def every_error(
    exc: ValidationError,
    source: str,
    *,
    model: type[BaseModel],
    text: str | None = None,
    data: Mapping[str, Any] | None = None,
) -> str:
    """Every one of pydantic's errors (``data`` validated as ``model``), a line each, as
    ``located`` words the first: ``source:line: where: what is wrong; what to write``. For a
    file whose reader wants every mistake at once (camd.toml); without the ``text`` (values
    given on the command line, say), no line."""
    layout = None if text is None else TomlLayout.of(text)
    lines = []
    for err in exc.errors():
        line, message = _explained(err, model, data or {}, {}, layout)
        lines.append(f"{place(source, line)}: {message}")
    return "\n".join(lines)


def _explained(
    err: ErrorDetails,
    model: type[BaseModel],
    data: Mapping[str, Any],
    named: Mapping[str, str],
    layout: TomlLayout | None,
) -> tuple[int | None, str]:
    """The line (None without a ``layout``) and the ``where: message`` of one error."""
    loc = clean_loc(err["loc"])
    cause = err.get("ctx", {}).get("error")
    if isinstance(cause, KeyedError):
        return _keyed(cause, loc, layout, data, model, named)
    message = problem(err, model)
    if not loc:
        return None, message
    segments = _segments(loc, data, model, named)
    if message.startswith(f"{segments[-1]}:"):  # a nested model's validator named itself
        segments.pop()
    where = "".join(f"{segment}: " for segment in segments)
    return None if layout is None else layout.line(loc, data), f"{where}{message}"


_BOUND_ERRORS = frozenset({"greater_than", "greater_than_equal", "less_than", "less_than_equal"})


def problem(err: ErrorDetails, model: type[BaseModel], *, yaml: bool = False) -> str:
    """What is wrong in one of pydantic's errors (validating ``model``) and what to write
    instead, in the words every config file's errors use (the data files of config/, camd.toml
    and, with ``yaml``, a campaign's YAML):

    - an unknown key: ``unknown key; did you mean `frames`?; known keys: frames, mode, ...``;
    - a missing key: ``missing key; add `title = ...``` (``title: ...`` in YAML; a physical
      value's inline table, a ``[table]``, ``[[tables]]``);
    - a strict type: ``'8423' is a string, the wrong type; write an integer, without quotes``;
    - a value out of its bounds: ``70000 is out of range; allowed: 0 <= port <= 65535``;
    - a value not among a few: ``'loud' is not allowed; use 'debug', 'info', ...``;
    - a validator's own message as it is; other errors with the value given, ``String should
      have at most 240 characters (got 'zz...')``.
    """
    kind = str(err["type"])
    loc = clean_loc(err["loc"])
    value = err.get("input")
    ctx = err.get("ctx", {})
    if kind == "extra_forbidden":
        return f"unknown key{_hint(model, loc, kind)}"
    if kind == "missing":
        return f"missing key{_hint(model, loc, kind, yaml=yaml)}"
    strict = wrong_type(kind, value)
    if strict is not None:
        return strict
    shown = cut(repr(value))
    if kind == "literal_error" and "expected" in ctx:
        return f"{shown} is not allowed; use {ctx['expected']}"
    if kind in _BOUND_ERRORS:
        return f"{shown} is out of range; allowed: {_allowed(model, loc, ctx)}"
    message = str(err["msg"]).removeprefix("Value error, ")
    if kind == "model_type":  # "... instance of Sourced[Annotated[float, FieldInfo(...)]]"
        message = re.sub(r"(instance of \w+)\[.*\]$", r"\1", message)
        return message + ("" if yaml else _hint(model, loc, kind))
    if kind in ("value_error", "assertion_error"):
        return message  # a validator's: it says what it checked
    return f"{message} (got {shown})"


_TYPE_WORDS = {
    "int_type": "an integer, without quotes",
    "float_type": "a number, without quotes",
    "string_type": "a string, in quotes",
    "bool_type": "true or false, without quotes",
    "list_type": "an array, [...]",
    "tuple_type": "an array, [...]",
    "dict_type": "a table, { ... }",
}
"""What a value of each strict type is written as, by pydantic's error type."""


def wrong_type(kind: str, value: object) -> str | None:
    """A strict type's refusal (pydantic's error ``kind``) that says what was written and what
    to write instead, e.g. ``'8423' is a string, the wrong type; write an integer, without
    quotes``; None for other errors."""
    if kind not in _TYPE_WORDS:
        return None
    return f"{cut(repr(value))} is {what_it_is(value)}, the wrong type; write {_TYPE_WORDS[kind]}"


def _allowed(model: type[BaseModel], loc: Loc, ctx: Mapping[str, Any]) -> str:
    """``0 <= port <= 65535``: the bounds of the value at ``loc``, both of them when its
    constraints hold the one the error's ``ctx`` names, else that one."""
    key = next((part for part in reversed(loc) if isinstance(part, str)), "value")
    bounds = {name: ctx[name] for name in ("ge", "gt", "le", "lt") if name in ctx}
    for group in constraints(model, loc):
        found = {
            name: getattr(meta, name)
            for meta in group
            for name in ("ge", "gt", "le", "lt")
            if getattr(meta, name, None) is not None
        }
        if all(found.get(name) == bound for name, bound in bounds.items()):
            bounds = found
            break
    lo = f"{bounds['ge']} <= " if "ge" in bounds else f"{bounds['gt']} < " if "gt" in bounds else ""
    hi = f" <= {bounds['le']}" if "le" in bounds else f" < {bounds['lt']}" if "lt" in bounds else ""
    return f"{lo}{key}{hi}"


def _keyed(
    exc: KeyedError,
    outer: Loc,
    layout: TomlLayout | None,
    data: Mapping[str, Any],
    model: type[BaseModel],
    named: Mapping[str, str],
) -> tuple[int | None, str]:
    """The line and message of a ``KeyedError`` raised at ``outer`` (see ``located``)."""
    loc = outer + exc.loc
    label = exc.label
    if label is None and loc:  # the place's first key, or its named entry
        head = 2 if len(loc) > 1 and _entry_of(model, loc[:1], named) else 1
        label = _segments(loc[:head], data, model, named)[0]
    message = f"{label}: {exc.message}" if label else exc.message
    return None if layout is None else layout.line(loc, data), message


def _segments(
    loc: Loc, data: Mapping[str, Any], model: type[BaseModel], named: Mapping[str, str]
) -> list[str]:
    """How a message names a place: dotted keys, an entry of a named array of tables by its
    name."""
    segments: list[str] = []
    keys: list[str] = []
    node: object = data
    i = 0
    while i < len(loc):
        part = loc[i]
        index = loc[i + 1] if i + 1 < len(loc) else None
        if isinstance(index, int) and _entry_of(model, loc[: i + 1], named):
            if keys:
                segments.append(".".join(keys))
                keys = []
            node = child(child(node, part), index)
            name = child(node, "name")
            call = named[str(part)]
            segments.append(call.format(name if isinstance(name, str) else f"#{index + 1}"))
            i += 2
        else:
            keys.append(str(part))
            node = child(node, part)
            i += 1
    if keys:
        segments.append(".".join(keys))
    return segments


def _entry_of(model: type[BaseModel], loc: Loc, named: Mapping[str, str]) -> bool:
    """Whether ``loc`` is one of the ``named`` arrays of tables."""
    if not loc or loc[-1] not in named:
        return False
    return is_tables(type_at(model, loc))


def _hint(model: type[BaseModel], loc: Loc, kind: str, *, yaml: bool = False) -> str:
    """What to write, for a missing key, an unknown key or a value that should be a table
    (in TOML, or with ``yaml`` in YAML, where a missing key is added as ``key: ...``)."""
    key = loc[-1] if loc else None
    if not isinstance(key, str):
        return ""
    if yaml and kind == "missing":
        return f"; add `{key}: ...`"
    if kind == "extra_forbidden":
        parent = type_at(model, loc[:-1])
        if isinstance(parent, type) and issubclass(parent, BaseModel):
            close = difflib.get_close_matches(key, list(parent.model_fields), n=1)
            meant = f"; did you mean `{close[0]}`?" if close else ""
            return f"{meant}; known keys: {', '.join(parent.model_fields)}"
        return ""
    if kind not in ("missing", "model_type"):
        return ""
    # A key to add, or a value written where a table belongs: what to write there.
    verb = "add" if kind == "missing" else "write"
    tables = all(isinstance(part, str) for part in loc)
    dotted = ".".join(str(part) for part in loc)
    expected = type_at(model, loc)
    if is_model(expected, Sourced):
        either = ' (or assumed = "...")' if kind == "missing" else ""
        return f"; {verb} `{key} = {_SOURCED_SHAPE}`{either}"
    if is_model(expected) and tables:
        return f"; {verb} a [{dotted}] table"
    if kind == "model_type":
        return ""
    if is_tables(expected) and tables:
        return f"; add [[{dotted}]] tables"
    return f"; add `{key} = ...`"
