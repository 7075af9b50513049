"""What the config files have in common: the data files of config/ (camera, stage and wheel
profiles, register maps, the command dictionary), camd.toml and the campaigns.

``Sourced`` holds a physical value with its provenance (a paper's section, or why it was
assumed); ``DataFileKind`` reads every kind of TOML data file the one way (parse, validate,
check; shipped files found by name); ``DataFileError`` is a file that does not validate, its
message starting with ``file:line:``; ``located`` turns a pydantic ValidationError (or a
``KeyedError`` a check raised) into that message, with the line of the key in the TOML text.
``problem`` words each of pydantic's errors, the same fault in the same words in every config
file: ``located`` and ``every_error`` (camd.toml, all its errors at once) with it, and the
campaign files (YAML, camd.campaign.explain), which begin their errors the same way (``place``)
with the lines ``yaml_lines`` finds. Pure: the simulated camera reads the same files.
"""

from __future__ import annotations

import difflib
import functools
import re
import tomllib
import types
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Generic, Literal, TypeVar, Union, get_args, get_origin

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator
from pydantic.fields import FieldInfo
from pydantic_core import ErrorDetails

T = TypeVar("T")
Model = TypeVar("Model", bound=BaseModel)

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


class Sourced(BaseModel, Generic[T]):
    """A value with its provenance: exactly one of ``source`` or ``assumed``."""

    model_config = ConfigDict(extra="forbid", frozen=True, strict=True)

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


# -- where a validation error is -------------------------------------------------------------

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
    layout = _Layout.of(text)
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
    file its reader wants every mistake of at once (camd.toml); without the ``text`` (values
    given on the command line, say), no line."""
    layout = None if text is None else _Layout.of(text)
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
    layout: _Layout | None,
) -> tuple[int | None, str]:
    """The line (None without a ``layout``) and the ``where: message`` of one error."""
    loc = _clean_loc(err["loc"])
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
    loc = _clean_loc(err["loc"])
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
    for group in _constraints(model, loc):
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


def _constraints(model: type[BaseModel], loc: Loc) -> list[list[object]]:
    """The constraints (``annotated_types.Ge`` etc.) on the value at ``loc``: a list for each
    type it may have (a field's own, each member of a union)."""
    if not loc:
        return []
    parent = _type_at(model, loc[:-1])
    key = loc[-1]
    groups: list[list[object]] = []
    annotation: object
    if isinstance(parent, type) and issubclass(parent, BaseModel) and key in parent.model_fields:
        info = parent.model_fields[key]
        groups.append(list(info.metadata))
        annotation = info.annotation
    else:
        annotation = _member_at(parent, key)

    def walk(annotation: object) -> None:
        if get_origin(annotation) is Annotated:
            inner, *metadata = get_args(annotation)
            group: list[object] = []
            for meta in metadata:
                group += meta.metadata if isinstance(meta, FieldInfo) else [meta]
            groups.append(group)
            walk(inner)
        elif get_origin(annotation) in (Union, types.UnionType):
            for member in get_args(annotation):
                walk(member)

    walk(annotation)
    return groups


def line_of(text: str, data: Mapping[str, Any], loc: Sequence[str | int]) -> int | None:
    """The line of the TOML text ``text`` (parsed into ``data``) where the place pydantic's
    ``loc`` names is written (see ``located``)."""
    return _Layout.of(text).line(_clean_loc(loc), data)


SHOWN_MAX = 80  # characters of a value quoted back in an error message
ERROR_MESSAGE_MAX = 2000  # characters: longer messages carry an echoed value (below)
WORD_MAX = 100  # ... whose words longer than this are cut


def cut(text: str, limit: int = SHOWN_MAX) -> str:
    """``text``, or its first ``limit`` characters and how long it was: a value quoted in an
    error (from a request, a file, an argument) must not make the error as large as itself."""
    return text if len(text) <= limit else f"{text[:limit]}... ({len(text)} characters)"


def bounded(message: str) -> str:
    """An error message at most about ERROR_MESSAGE_MAX characters long. Messages quote names,
    paths and values given (a register, a file, a campaign's value); a message this long holds
    such a value, and its long words are cut; a message still too long keeps its head and its
    tail (what to do). The API's errors, camctl's, camd's and the simulator's pass through it."""
    if len(message) <= ERROR_MESSAGE_MAX:
        return message
    message = re.sub(rf"\S{{{WORD_MAX + 1},}}", lambda m: cut(m.group(), WORD_MAX), message)
    if len(message) <= ERROR_MESSAGE_MAX:
        return message
    head, tail = ERROR_MESSAGE_MAX * 3 // 4, ERROR_MESSAGE_MAX // 5
    dropped = len(message) - head - tail
    return f"{message[:head]} ... ({dropped} characters cut) ... {message[-tail:]}"


def what_it_is(value: object, *, array: str = "an array", table: str = "a table") -> str:
    """A parsed value's type, in words: TOML's (or YAML's) names for arrays and tables by
    default; the API calls them a list and an object."""
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "a boolean"
    if isinstance(value, int):
        return "an integer"
    if isinstance(value, float):
        return "a number with a fraction"
    if isinstance(value, str):
        return "a string"
    if isinstance(value, list):
        return array
    return table if isinstance(value, dict) else "a value"


def _clean_loc(loc: Sequence[str | int]) -> Loc:
    """pydantic's location of an error without its internal parts (validator functions,
    literal and constrained types, the ``Sourced`` wrapper's name): the keys and indices as
    the file writes them."""
    internal = ("function-", "literal[", "constrained-", "Sourced[")
    return tuple(
        part
        for part in loc
        if isinstance(part, int) or not (part.startswith(internal) or part == "Sourced")
    )


def _keyed(
    exc: KeyedError,
    outer: Loc,
    layout: _Layout | None,
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
            node = _child(_child(node, part), index)
            name = _child(node, "name")
            call = named[str(part)]
            segments.append(call.format(name if isinstance(name, str) else f"#{index + 1}"))
            i += 2
        else:
            keys.append(str(part))
            node = _child(node, part)
            i += 1
    if keys:
        segments.append(".".join(keys))
    return segments


def _entry_of(model: type[BaseModel], loc: Loc, named: Mapping[str, str]) -> bool:
    """Whether ``loc`` is one of the ``named`` arrays of tables."""
    if not loc or loc[-1] not in named:
        return False
    return _is_tables(_type_at(model, loc))


def _hint(model: type[BaseModel], loc: Loc, kind: str, *, yaml: bool = False) -> str:
    """What to write, for a missing key, an unknown key or a value that should be a table
    (in TOML, or with ``yaml`` in YAML, where a missing key is added as ``key: ...``)."""
    key = loc[-1] if loc else None
    if not isinstance(key, str):
        return ""
    if yaml and kind == "missing":
        return f"; add `{key}: ...`"
    tables = all(isinstance(part, str) for part in loc)
    dotted = ".".join(str(part) for part in loc)
    if kind == "missing":
        expected = _type_at(model, loc)
        if _is_model(expected, Sourced):
            return f'; add `{key} = {_SOURCED_SHAPE}` (or assumed = "...")'
        if _is_model(expected) and tables:
            return f"; add a [{dotted}] table"
        if _is_tables(expected) and tables:
            return f"; add [[{dotted}]] tables"
        return f"; add `{key} = ...`"
    if kind == "extra_forbidden":
        parent = _type_at(model, loc[:-1])
        if isinstance(parent, type) and issubclass(parent, BaseModel):
            close = difflib.get_close_matches(key, list(parent.model_fields), n=1)
            meant = f"; did you mean `{close[0]}`?" if close else ""
            return f"{meant}; known keys: {', '.join(parent.model_fields)}"
    if kind == "model_type":
        expected = _type_at(model, loc)
        if _is_model(expected, Sourced):
            return f"; write `{key} = {_SOURCED_SHAPE}`"
        if _is_model(expected) and tables:
            return f"; write a [{dotted}] table"
    return ""


def _type_at(model: type[BaseModel], loc: Loc) -> object:
    """The type the model expects at ``loc`` (None when the location leaves the models)."""
    expected: object = model
    for part in loc:
        expected = _member_at(expected, part)
        if expected is None:
            return None
    return _unwrap(expected)


def _member_at(outer: object, part: str | int) -> object:
    """The type, as annotated, at the step ``part`` of a location into the type ``outer``: a
    model's field, a list's or tuple's item, a table's value, a discriminated union's member
    (pydantic names the member it tried by its tag); None when there is none."""
    outer = _unwrap(outer)
    origin, args = get_origin(outer), get_args(outer)
    if isinstance(outer, type) and issubclass(outer, BaseModel):
        field_info = outer.model_fields.get(str(part))
        return field_info.annotation if field_info is not None else None
    if origin is list and args and isinstance(part, int):
        return args[0]
    if origin is tuple and args and isinstance(part, int):
        if len(args) == 2 and args[1] is Ellipsis:
            return args[0]
        return args[part] if 0 <= part < len(args) else None
    if origin is dict and len(args) == 2 and isinstance(part, str):
        return args[1]
    if origin in (Union, types.UnionType) and isinstance(part, str):
        return next((m for m in args if part in _tags(m)), None)
    return None


def _unwrap(annotation: object) -> object:
    """``X`` of ``Annotated[X, ...]`` and of ``X | None``."""
    while True:
        origin = get_origin(annotation)
        if origin is Annotated:
            annotation = get_args(annotation)[0]
            continue
        if origin in (Union, types.UnionType):
            members = [a for a in get_args(annotation) if a is not type(None)]
            if len(members) == 1:
                annotation = members[0]
                continue
        return annotation


def _tags(member: object) -> tuple[object, ...]:
    """The values of a model's ``Literal`` fields: its tags as a discriminated union's member."""
    if not (isinstance(member, type) and issubclass(member, BaseModel)):
        return ()
    fields = member.model_fields.values()
    return tuple(
        tag for f in fields if get_origin(f.annotation) is Literal for tag in get_args(f.annotation)
    )


def _is_model(annotation: object, base: type[BaseModel] = BaseModel) -> bool:
    return isinstance(annotation, type) and issubclass(annotation, base)


def _is_tables(annotation: object) -> bool:
    """Whether a type is a list of models (an array of tables)."""
    args = get_args(annotation)
    return get_origin(annotation) is list and bool(args) and _is_model(_unwrap(args[0]))


def _child(node: object, part: str | int) -> object:
    """``node[part]`` of parsed TOML, None when it is not there."""
    if isinstance(node, dict) and isinstance(part, str):
        return node.get(part)
    if isinstance(node, list) and isinstance(part, int) and 0 <= part < len(node):
        return node[part]
    return None


# -- where a place of a YAML file is -----------------------------------------------------------


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


# -- where a place of a TOML file is -----------------------------------------------------------

_HEADER = re.compile(r"^\s*(\[\[?)\s*([A-Za-z0-9_.]+)\s*\]\]?")

Span = tuple[int, int]  # first and last 1-based line; the first is a header but for the top level


@dataclass(frozen=True)
class _Layout:
    """Where things are in a TOML text: line spans of the ``[tables]`` (``""``: the top level,
    up to the first header) and of the entries of each ``[[array]]``."""

    lines: list[str]
    tables: dict[str, Span]
    entries: dict[str, list[Span]]

    @classmethod
    def of(cls, text: str) -> _Layout:
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
            entry = _child(_child(data, head), loc[1])
            return self._within(spans[loc[1]], loc[2:], entry, spans[loc[1]][0])
        node: object = data
        for n in range(len(loc), 0, -1):
            keys = loc[:n]
            name = ".".join(str(part) for part in keys)
            if all(isinstance(part, str) for part in keys) and name in self.tables:
                for part in keys:
                    node = _child(node, part)
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
            return self._item(span, start, _child(node, key), rest[1]) or start
        return start

    def _item(self, span: Span, start: int, items: object, index: int) -> int | None:
        """The line of the ``index``-th inline table of an array, by its ``name = "..."``."""
        if not isinstance(items, list) or not 0 <= index < len(items):
            return None
        name = _child(items[index], "name")
        if not isinstance(name, str):
            return None
        before = sum(1 for item in items[:index] if _child(item, "name") == name)
        pattern = re.compile(rf"\bname\s*=\s*[\"']{re.escape(name)}[\"']")
        found = [n for n in range(start, span[1] + 1) if pattern.search(self.lines[n - 1])]
        return found[before] if before < len(found) else None
