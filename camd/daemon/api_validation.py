"""What a 400 quotes as the values a parameter takes: read from the field's own type and
constraints (``valid_values``), so that the message cannot drift from what is enforced, with
``ALLOWED``'s explanation where they do not say enough.
"""

from __future__ import annotations

import types
from typing import Any, Literal, Union, get_args, get_origin

import annotated_types
from pydantic import BaseModel
from pydantic.fields import FieldInfo

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
