"""What a pydantic model expects at a place of a file: the type (``type_at``, through lists,
tables and discriminated unions) and the constraints (``constraints``: a field's bounds, a union
member's), for the words of an error."""

from __future__ import annotations

import types
from typing import Annotated, Literal, Union, get_args, get_origin

from pydantic import BaseModel
from pydantic.fields import FieldInfo

from camd.datafile.places import Loc


def type_at(model: type[BaseModel], loc: Loc) -> object:
    """The type the model expects at ``loc`` (None when the location leaves the models)."""
    expected: object = model
    for part in loc:
        expected = member_at(expected, part)
        if expected is None:
            return None
    return unwrap(expected)


def member_at(outer: object, part: str | int) -> object:
    """The type, as annotated, at the step ``part`` of a location into the type ``outer``: a
    model's field, a list's or tuple's item, a table's value, a discriminated union's member
    (pydantic names the member it tried by its tag); None when there is none."""
    outer = unwrap(outer)
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


def unwrap(annotation: object) -> object:
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


def is_model(annotation: object, base: type[BaseModel] = BaseModel) -> bool:
    return isinstance(annotation, type) and issubclass(annotation, base)


def is_tables(annotation: object) -> bool:
    """Whether a type is a list of models (an array of tables)."""
    args = get_args(annotation)
    return get_origin(annotation) is list and bool(args) and is_model(unwrap(args[0]))


def constraints(model: type[BaseModel], loc: Loc) -> list[list[object]]:
    """The constraints (``annotated_types.Ge`` etc.) on the value at ``loc``: a list for each
    type it may have (a field's own, each member of a union)."""
    if not loc:
        return []
    parent = type_at(model, loc[:-1])
    key = loc[-1]
    groups: list[list[object]] = []
    annotation: object
    if isinstance(parent, type) and issubclass(parent, BaseModel) and key in parent.model_fields:
        info = parent.model_fields[key]
        groups.append(list(info.metadata))
        annotation = info.annotation
    else:
        annotation = member_at(parent, key)

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
