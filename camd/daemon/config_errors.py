"""The config's validation errors explained: one line per error, naming the file (and the key's
line), the dotted key path, what is wrong and what is allowed (the keys of the table, the range,
the literal values).
"""

from __future__ import annotations

from collections.abc import Callable

from pydantic import BaseModel, ValidationError

from camd.daemon.config_camera import ChannelLimits, TelemetrySection
from camd.datafile import cut, wrong_type


def _model_at(root: type[BaseModel], loc: tuple[int | str, ...]) -> type[BaseModel] | None:
    """The model class that validates the table at ``loc`` of ``root`` (None if it is not a
    table)."""
    model = root
    parts = [str(p) for p in loc]
    while parts:
        part = parts.pop(0)
        if model is TelemetrySection and part == "limits":
            if not parts:
                return None  # the limits table itself takes channel names, not fixed keys
            parts.pop(0)  # the channel name
            model = ChannelLimits
            continue
        field = model.model_fields.get(part)
        annotation = None if field is None else field.annotation
        if not (isinstance(annotation, type) and issubclass(annotation, BaseModel)):
            return None
        model = annotation
    return model


_BOUND_ERRORS = frozenset({"greater_than", "greater_than_equal", "less_than", "less_than_equal"})


def _allowed_range(root: type[BaseModel], loc: tuple[int | str, ...]) -> str:
    """``"0 <= x <= 65535"``-style text from the field's constraints at ``loc`` of ``root``."""
    parent = _model_at(root, loc[:-1])
    field = None if parent is None else parent.model_fields.get(str(loc[-1]))
    if field is None:
        return ""
    lo = hi = ""
    for meta in field.metadata:
        if getattr(meta, "ge", None) is not None:
            lo = f"{meta.ge} <= "
        if getattr(meta, "gt", None) is not None:
            lo = f"{meta.gt} < "
        if getattr(meta, "le", None) is not None:
            hi = f" <= {meta.le}"
        if getattr(meta, "lt", None) is not None:
            hi = f" < {meta.lt}"
    return f"{lo}{loc[-1]}{hi}" if lo or hi else ""


def format_errors(
    exc: ValidationError,
    source: str,
    line: Callable[[tuple[int | str, ...]], int | None] | None = None,
    *,
    root: type[BaseModel],
) -> str:
    """One line per error of validating ``root``: ``source[:line]: key.path: what is wrong;
    what is allowed`` (the line of the key, when ``line`` finds it in the file)."""
    lines = []
    for err in exc.errors():
        loc = tuple(err["loc"])
        number = None if line is None or not loc else line(loc)
        where = source if number is None else f"{source}:{number}"
        key = ".".join(str(p) for p in loc) or "(top level)"
        kind = err["type"]
        if kind == "extra_forbidden":
            parent = _model_at(root, loc[:-1])
            allowed = list(parent.model_fields) if parent is not None else []
            hint = f"; allowed keys here: {', '.join(allowed)}" if allowed else ""
            lines.append(f"{where}: {key}: unknown key (a typo?){hint}")
            continue
        msg = str(err["msg"]).removeprefix("Value error, ")
        ctx = err.get("ctx", {})
        strict = wrong_type(kind, err["input"])
        if strict is not None:
            msg = strict
        elif kind == "literal_error" and "expected" in ctx:
            msg = f"{cut(repr(err['input']))} is not allowed; use {ctx['expected']}"
        elif kind in _BOUND_ERRORS:
            bounds = _allowed_range(root, loc)
            msg = f"{cut(repr(err['input']))} is out of range; allowed: {bounds or msg}"
        elif kind not in ("value_error", "missing"):
            msg = f"{msg} (got {cut(repr(err['input']))})"
        lines.append(f"{where}: {key}: {msg}")
    return "\n".join(lines)
