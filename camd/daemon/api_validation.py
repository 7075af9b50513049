"""The 400 message of an invalid request: for each invalid parameter, what was wrong and the
values it takes, read from the endpoint's own request model or query parameter (its type and
constraints), so that the message cannot drift from what is enforced. FastAPI's 422 validation
errors leave as these 400s (``camd.daemon.api_errors``).
"""

from __future__ import annotations

import types
from collections.abc import Callable
from typing import Annotated, Any, Literal, Union, get_args, get_origin

import annotated_types
from fastapi.exceptions import RequestValidationError
from fastapi.routing import APIRoute
from pydantic import BaseModel
from pydantic.fields import FieldInfo

from camd.daemon.error_body import ERROR_MESSAGE_MAX, cut
from camd.datafile import what_it_is

PROBLEMS_SHOWN_MAX = 10  # invalid parameters described in one 400; the rest are counted

# What a field's type and constraints do not say, for 400 messages: appended in parentheses to
# the valid values read from the field itself (valid_values). Keyed by field name, so each entry
# must hold for every request model and query parameter of that name.
ALLOWED: dict[str, str] = {
    "size": "bytes",
    "channel": "a telemetry channel name (GET /api/v1/telemetry lists them)",
    "since_s": "a Unix time in seconds, or a negative number of seconds before now",
    "speed_deg_s": "a wheel speed in deg/s, 0 stops the wheel",
    "channels": "wheel channel numbers, each 0..12",
    "angle_deg": "the polariser's axis in deg; null takes it out of the beam",
    "max": "lines",
    "text": "printable characters: no newlines or tabs",
    "done": "at most total",
    "total": "at least done",
    "values": "register name -> raw integer, or enum name for an enum field",
}


def _number(value: Any) -> str:
    return f"{value:g}" if isinstance(value, float) else str(value)


def _kind(annotation: Any) -> str:
    """What a value of this (non-null) type is, in words."""
    if get_origin(annotation) is Annotated:  # a type with its checks: the type says it
        return _kind(get_args(annotation)[0])
    if get_origin(annotation) is Literal:
        names = [str(v) for v in get_args(annotation)]
        return names[0] if len(names) == 1 else f"{', '.join(names[:-1])} or {names[-1]}"
    origin = get_origin(annotation) or annotation
    if origin in (Union, types.UnionType):
        return " or ".join(_kind(a) for a in get_args(annotation))
    words = {
        bool: "true or false",
        int: "an integer",
        float: "a number",
        str: "a string",
        list: "a list",
        dict: "an object",
    }
    if isinstance(origin, type) and issubclass(origin, BaseModel):
        return f"an object with keys {', '.join(origin.model_fields)}"
    return words.get(origin, "a value") if isinstance(origin, type) else "a value"


def valid_values(field: FieldInfo) -> str:
    """The values ``field`` takes, in words, from its own type and constraints (so that they
    cannot drift from what is enforced): e.g. "an integer in 1..4096", "a number more than 0
    and at most 10", "sum or mean", "null or a string of at most 240 characters"."""
    annotation: Any = field.annotation
    nullable = False
    if get_origin(annotation) in (Union, types.UnionType):
        args = [a for a in get_args(annotation) if a is not type(None)]
        nullable = len(args) < len(get_args(annotation))
        annotation = args[0] if len(args) == 1 else Union[tuple(args)]  # noqa: UP007
    words = _kind(annotation)
    low: Any = None
    high: Any = None
    low_incl = high_incl = True
    min_len = max_len = None
    for item in field.metadata:
        if isinstance(item, annotated_types.Ge):
            low = item.ge
        elif isinstance(item, annotated_types.Gt):
            low, low_incl = item.gt, False
        elif isinstance(item, annotated_types.Le):
            high = item.le
        elif isinstance(item, annotated_types.Lt):
            high, high_incl = item.lt, False
        elif isinstance(item, annotated_types.MinLen):
            min_len = item.min_length
        elif isinstance(item, annotated_types.MaxLen):
            max_len = item.max_length
    if low is not None and high is not None:
        if low_incl and high_incl:
            words += f" in {_number(low)}..{_number(high)}"
        else:
            words += (
                f" {'from' if low_incl else 'more than'} {_number(low)} "
                f"{'to' if low_incl else 'and'} {'at most' if high_incl else 'below'} "
                f"{_number(high)}"
            )
    elif low is not None:
        words += f" {'>=' if low_incl else '>'} {_number(low)}"
    elif high is not None:
        words += f" {'<=' if high_incl else '<'} {_number(high)}"
    if min_len is not None or max_len is not None:
        origin: Any = get_origin(annotation) or annotation
        unit = {str: "characters", dict: "entries"}.get(origin, "items")
        if min_len is not None and max_len is not None:
            words += f" of {min_len} to {max_len} {unit}"
        elif min_len == 1:
            words = f"a non-empty {words.removeprefix('a ').removeprefix('an ')}"
        elif min_len is not None:
            words += f" of at least {min_len} {unit}"
        else:
            words += f" of at most {max_len} {unit}"
    if not nullable:
        return words
    if " or " in words:  # a choice of values: true, false or null
        return f"{words.replace(' or ', ', ')} or null"
    return f"null or {words}"


_UNION_TAGS = {"int", "float", "str", "bool", "none"}  # pydantic's loc parts for union members


def _parameter(route: object, loc: list[str | int]) -> FieldInfo | None:
    """The field of ``route``'s own request model (or query parameter) that ``loc`` names, so
    that the valid values quoted are this endpoint's (several models share field names)."""
    if not isinstance(route, APIRoute) or len(loc) < 2:
        return None
    where, path = loc[0], loc[1:]
    if where == "query":
        params = {p.alias: p.field_info for p in route.dependant.query_params}
        return params.get(str(path[0])) if len(path) == 1 else None
    if where != "body" or len(route.dependant.body_params) != 1:
        return None
    model: Any = route.dependant.body_params[0].field_info.annotation
    field: FieldInfo | None = None
    for part in path:
        if get_origin(model) in (Union, types.UnionType):
            args = [a for a in get_args(model) if a is not type(None)]
            model = args[0] if len(args) == 1 else None
        if get_origin(model) in (dict, list):  # an entry: its type, unconstrained
            field = FieldInfo.from_annotation(get_args(model)[-1])
        elif isinstance(model, type) and issubclass(model, BaseModel):
            field = model.model_fields.get(str(part))
        else:
            return None
        if field is None:
            return None
        model = field.annotation
    return field


def _outside(field: FieldInfo | None, value: float) -> bool:
    """Whether ``value`` lies beyond the bounds ``field`` sets (unknown bounds: no)."""
    for item in field.metadata if field is not None else ():
        if isinstance(item, annotated_types.Ge | annotated_types.Gt):
            low = item.ge if isinstance(item, annotated_types.Ge) else item.gt
            if value < low:  # type: ignore[operator]
                return True
        elif isinstance(item, annotated_types.Le | annotated_types.Lt):
            high = item.le if isinstance(item, annotated_types.Le) else item.lt
            if value > high:  # type: ignore[operator]
                return True
    return False


def _shown(value: object, loc: list[str | int]) -> str:
    """A rejected value as the user wrote it: a query parameter's number arrives as the text
    of the URL ("0.0"), which quoted would read as a string given where a number was due."""
    return cut(value if loc[:1] == ["query"] and isinstance(value, str) else repr(value))


def validation_message(
    exc: RequestValidationError,
    route: object = None,
    limit_now: Callable[[str], str] = lambda name: "",
) -> str:
    """``"stages: 0 is out of range; use an integer in 1..4096"`` for each invalid parameter:
    the valid values read from the endpoint's own model (``valid_values``), with
    ``ALLOWED``'s explanation where the type and constraints do not say enough."""
    parts: list[str] = []
    seen = set()
    more = 0  # invalid parameters past PROBLEMS_SHOWN_MAX: counted, not described
    for err in exc.errors():
        loc: list[str | int] = list(err.get("loc", ()))
        while len(loc) > 2 and loc[-1] in _UNION_TAGS:
            loc.pop()  # values.GAIN.int -> values.GAIN
        shown_loc = [str(p) for p in loc if p not in ("body", "query", "path")]
        name = ".".join(shown_loc)
        if name in seen:
            continue  # one message per parameter (a union reports each member)
        seen.add(name)
        if len(parts) >= PROBLEMS_SHOWN_MAX:
            more += 1
            continue
        name = cut(name)  # a key of the client's own object may be part of it
        kind = str(err.get("type", ""))
        value = err.get("input")
        field = _parameter(route, loc)
        # ALLOWED's explanation of the parameter, or of the one an entry belongs to
        hint = next((ALLOWED[p] for p in reversed(shown_loc) if p in ALLOWED), "")
        if field is not None and not hint and loc[0] == "query":
            hint = field.description or ""  # its meaning on this endpoint
        if field is not None:
            allowed = valid_values(field) + (f" ({hint})" if hint else "")
        else:
            allowed = hint
        use = f"; use {allowed}" if allowed else ""
        if kind == "json_invalid":
            parts.append('the request body is not valid JSON; send e.g. {"count": 10}')
        elif kind == "missing":
            parts.append(f"{name}: is required{use}")
        elif kind == "extra_forbidden":
            parts.append(f"{name}: unknown parameter; remove it (check the spelling)")
        elif kind in ("model_attributes_type", "dict_type") and not name:
            shown = value.decode(errors="replace") if isinstance(value, bytes) else repr(value)
            parts.append(
                f"the request body must be a JSON object (Content-Type: application/json), "
                f"not {cut(shown)}"
            )
        elif kind in ("greater_than_equal", "less_than_equal", "greater_than", "less_than"):
            parts.append(f"{name}: {_shown(value, loc)} is out of range{use}{limit_now(name)}")
        elif kind == "finite_number":
            parts.append(f"{name}: {_shown(value, loc)} is not a finite number{use}")
        elif kind == "int_type" and isinstance(value, float) and value.is_integer():
            # 1e20 or 3.0: a whole number written as a float; out of range, or just its form
            if _outside(field, value):
                parts.append(f"{name}: {cut(repr(value))} is out of range{use}")
            else:
                parts.append(f"{name}: {cut(repr(value))} is a whole number written with a "
                             f"decimal point or an exponent; write it as an integer{use}")  # fmt: skip
        elif kind.endswith("_type"):
            what = what_it_is(value, array="a list", table="an object")
            parts.append(f"{name}: {cut(repr(value))} is {what}, the wrong type{use}")
        elif kind == "value_error":  # a validator of the model: its reason
            reason = cut(str(err.get("msg", "")).removeprefix("Value error, "), ERROR_MESSAGE_MAX)
            parts.append(f"{name}: {cut(repr(value))} is not valid ({reason}){use}")
        else:
            parts.append(f"{name}: {cut(repr(value))} is not valid{use}")
    if more:
        parts.append(f"and {more} more problem{'s' if more > 1 else ''}")
    return "; ".join(parts) or "invalid request"
