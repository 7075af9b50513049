"""Generate camd/client_types.py, the client's TypedDicts, from the API's pydantic models.

The HTTP API's response bodies are the pydantic models of ``camd.daemon.models`` (FastAPI
publishes them in /openapi.json). ``camd.client`` returns the same documents as plain JSON dicts
and types them with TypedDicts; those are rendered here from the models, so that the shapes are
written once. ``tests/test_client_types.py`` fails when the committed file is stale.

One TypedDict per response model (every model of the package that is not a request body) and per
model nested in one, named after the model, in the order of the package's ``__all__`` with nested
models first. The
keys are those of the JSON the API emits: FastAPI serialises a ``response_model`` with
``by_alias=True`` and without excluding unset, default or None values, so the key of a field is
its serialisation alias (else its alias, else its name) and every key is present (``None``
values included). JSON has no tuples: ``tuple[...]`` becomes ``list[...]``; JSON object keys are
strings: ``dict[K, V]`` becomes ``dict[str, V]``.

    python -m camd.daemon.client_types_gen            write camd/client_types.py
    python -m camd.daemon.client_types_gen --check    exit 1 if the file differs from the render
"""

from __future__ import annotations

import argparse
import json
import keyword
import re
import sys
import textwrap
import types
import typing
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Annotated, Any, Literal, Union

from pydantic import BaseModel

from camd.daemon import models as api_models
from camd.daemon.models.common import _Request
from camd.markdown import write_or_check

COMMAND = "python -m camd.daemon.client_types_gen"
OUTPUT = Path(__file__).resolve().parents[1] / "client_types.py"
LINE_LENGTH = 100  # pyproject.toml [tool.ruff] line-length
INDENT = "    "


class ClientTypesError(ValueError):
    """A model uses a type this generator cannot express as a JSON TypedDict."""


# -- which models -----------------------------------------------------------------------------------


def module_models(module: types.ModuleType = api_models) -> list[type[BaseModel]]:
    """Every pydantic model ``module`` defines or, a package, defines in its modules and
    exports: in the order of its ``__all__`` (else of definition)."""
    names = getattr(module, "__all__", None) or list(vars(module))
    values = [getattr(module, name) for name in names]
    return [
        value
        for value in dict.fromkeys(values)
        if isinstance(value, type)
        and issubclass(value, BaseModel)
        and (
            value.__module__ == module.__name__
            or value.__module__.startswith(f"{module.__name__}.")
        )
        and not value.__name__.startswith("_")
    ]


def is_request(model: type[BaseModel]) -> bool:
    """A request body (a ``_Request``: unknown keys forbidden) rather than a response."""
    return issubclass(model, _Request)


def response_models(module: types.ModuleType = api_models) -> list[type[BaseModel]]:
    """The response models of ``module`` and every model nested in one, nested models before
    the models using them, otherwise in definition order."""
    order = module_models(module)
    rank = {model: i for i, model in enumerate(order)}
    done: list[type[BaseModel]] = []
    seen: set[type[BaseModel]] = set()

    def visit(model: type[BaseModel], path: tuple[str, ...]) -> None:
        if model in seen:
            return
        if model.__name__ in path:
            raise ClientTypesError("recursive models: " + " -> ".join((*path, model.__name__)))
        if model not in rank:
            raise ClientTypesError(
                f"{' -> '.join(path)} nests {model.__module__}.{model.__name__}, which is not "
                f"exported by {module.__name__}; define the API's models there (and list it in its "
                "__all__)"
            )
        nested = sorted(
            {m for _, annotation in json_fields(model) for m in nested_models(annotation)},
            key=rank.__getitem__,
        )
        for inner in nested:
            visit(inner, (*path, model.__name__))
        seen.add(model)
        done.append(model)

    for model in order:
        if not is_request(model):
            visit(model, ())
    return done


# -- fields and annotations -------------------------------------------------------------------------


def json_fields(model: type[BaseModel]) -> list[tuple[str, Any]]:
    """(JSON key, annotation) of every key the API emits for ``model``, in field order.

    The key is the serialisation alias, else the alias, else the field name (FastAPI answers
    with ``by_alias=True``); fields excluded from serialisation are left out; computed fields
    follow the fields, as pydantic emits them.
    """
    out: list[tuple[str, Any]] = []
    for name, info in model.model_fields.items():
        if info.exclude:
            continue
        if getattr(info, "exclude_if", None) is not None:
            raise ClientTypesError(
                f"{model.__name__}.{name} has exclude_if: its key may be absent, which the "
                "generated TypedDicts do not express"
            )
        out.append((info.serialization_alias or info.alias or name, info.annotation))
    for name, computed in model.model_computed_fields.items():
        out.append((computed.alias or name, computed.return_type))
    for key, _ in out:
        if not key.isidentifier() or keyword.iskeyword(key):
            raise ClientTypesError(
                f"{model.__name__}: JSON key {key!r} is not a Python identifier, which a "
                "class-syntax TypedDict cannot declare"
            )
    return out


def _strip(annotation: Any) -> Any:
    while typing.get_origin(annotation) is Annotated:
        annotation = typing.get_args(annotation)[0]
    return annotation


def nested_models(annotation: Any) -> Iterator[type[BaseModel]]:
    """The pydantic models an annotation refers to, at any depth."""
    annotation = _strip(annotation)
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        yield annotation
        return
    if typing.get_origin(annotation) is Literal:
        return
    for arg in typing.get_args(annotation):
        if arg is not Ellipsis:
            yield from nested_models(arg)


_SCALARS: dict[Any, str] = {
    int: "int",
    float: "float",
    str: "str",
    bool: "bool",
    type(None): "None",
    None: "None",
    Any: "Any",
}


def render_type(annotation: Any, where: str = "annotation") -> str:
    """The TypedDict annotation of the JSON a field of this type serialises to."""
    annotation = _strip(annotation)
    if annotation in _SCALARS:
        return _SCALARS[annotation]
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return annotation.__name__
    origin = typing.get_origin(annotation)
    args = typing.get_args(annotation)
    if origin is Literal:
        return "Literal[" + ", ".join(_literal(v, where) for v in args) + "]"
    if origin in (Union, types.UnionType):
        return _union([render_type(a, where) for a in args])
    if origin in (list, set, frozenset) or (origin is not None and origin is Sequence):
        (item,) = args or (Any,)
        return f"list[{render_type(item, where)}]"
    if origin is tuple:
        items = [a for a in args if a is not Ellipsis] or [Any]
        if items == [()]:  # tuple[()]
            items = [Any]
        return f"list[{_union([render_type(a, where) for a in items])}]"
    if origin is dict:
        _, value = args or (str, Any)
        return f"dict[str, {render_type(value, where)}]"
    raise ClientTypesError(
        f"{where}: cannot express {annotation!r} as JSON in a TypedDict; use int, float, str, "
        "bool, None, Literal, a model, list, tuple or dict (or teach camd.daemon.client_types_gen)"
    )


def _literal(value: object, where: str) -> str:
    if isinstance(value, bool) or value is None:
        return repr(value)
    if isinstance(value, str):
        return json.dumps(value, ensure_ascii=False)
    if isinstance(value, int):
        return str(value)
    raise ClientTypesError(f"{where}: Literal value {value!r} is not a JSON scalar")


def _union(parts: list[str]) -> str:
    """``a | b | None``: duplicates dropped, None last."""
    unique = list(dict.fromkeys(parts))
    if "None" in unique:
        unique = [p for p in unique if p != "None"] + ["None"]
    return " | ".join(unique)


# -- the module -------------------------------------------------------------------------------------

HEADER = f'''\
# Generated from camd/daemon/models/ by `{COMMAND}`: do not edit.
"""The JSON documents of the camd HTTP API as TypedDicts: the shapes ``camd.client`` returns.

Generated from the pydantic models of camd/daemon/models/ (the bodies the daemon publishes in
/openapi.json) by ``{COMMAND}``: to change a shape, change the
model and run that command (tests/test_client_types.py fails while this file is stale).

One TypedDict per response model and per model nested in one, named after the model. Its keys
are the JSON keys the API emits; every key is always present, with null where the model allows
None. JSON has no tuples, so a model's ``tuple[...]`` is a ``list`` here. The module imports
nothing of camd, so a script can type the client's answers without loading the daemon.
"""

from __future__ import annotations
'''


def summary(model: type[BaseModel]) -> str:
    """The model's summary: its docstring's first paragraph, on one line."""
    doc = model.__dict__.get("__doc__") or ""
    text = " ".join(doc.strip().split("\n\n")[0].split())
    return text or f"The ``{model.__name__}`` document (its model has no docstring)."


def docstring_lines(text: str) -> list[str]:
    """``text`` as a class docstring, wrapped to the line length."""
    text = text.replace("\\", "\\\\").replace('"""', '\\"\\"\\"')
    if text.endswith('"'):
        text += " "
    width = LINE_LENGTH - len(INDENT)
    lines = textwrap.wrap(text, width - 3, break_long_words=False, break_on_hyphens=False)
    lines[0] = '"""' + lines[0]
    lines[-1] += '"""'
    return [INDENT + line for line in lines]


def comment_lines(text: str) -> list[str]:
    """``text`` as comment lines of a class body, wrapped to the line length."""
    prefix = INDENT + "# "
    width = LINE_LENGTH - len(prefix)
    words = " ".join(text.split())
    return [prefix + line for line in textwrap.wrap(words, width, break_long_words=False)]


def render_class(model: type[BaseModel], annotations: list[str] | None = None) -> list[str]:
    """The TypedDict of ``model``; its annotations are appended to ``annotations``."""
    lines = [f"class {model.__name__}(TypedDict):", *docstring_lines(summary(model)), ""]
    fields = json_fields(model)
    if not fields:
        raise ClientTypesError(f"{model.__name__} has no fields to emit")
    descriptions = {
        (info.serialization_alias or info.alias or name): info.description
        for name, info in model.model_fields.items()
    }
    for name, computed in model.model_computed_fields.items():
        descriptions[computed.alias or name] = computed.description
    for key, annotation in fields:
        description = descriptions.get(key)
        if description:
            lines += comment_lines(description)
        rendered = render_type(annotation, f"{model.__name__}.{key}")
        if annotations is not None:
            annotations.append(rendered)
        lines += field_lines(key, rendered)
    return lines


def field_lines(key: str, rendered: str) -> list[str]:
    """``key: rendered``, a long ``Literal[...]`` split as ruff's formatter splits it (the
    file must pass ``ruff format`` unchanged): its values on one indented line if they fit,
    else one per line with a trailing comma."""
    line = f"{INDENT}{key}: {rendered}"
    inner = rendered.removeprefix("Literal[").removesuffix("]")
    if len(line) <= LINE_LENGTH or not rendered.startswith("Literal[") or "[" in inner:
        return [line]
    head, tail = f"{INDENT}{key}: Literal[", f"{INDENT}]"
    if len(INDENT * 2 + inner) <= LINE_LENGTH:
        return [head, INDENT * 2 + inner, tail]
    return [head, *(f"{INDENT * 2}{value}," for value in inner.split(", ")), tail]


def module_text(header: str, classes: Sequence[list[str]], annotations: Sequence[str]) -> str:
    """A generated module: ``header``, the typing names its ``annotations`` use, ``classes``."""
    body: list[str] = []
    for lines in classes:
        body += ["", "", *lines]
    used = {name for a in annotations for name in re.findall(r"\b(Any|Literal)\b", a)}
    imports = "from typing import " + ", ".join(sorted({"TypedDict", *used}))
    return header + "\n" + imports + "\n" + "\n".join(body) + "\n"


def render_client_types(models: Sequence[type[BaseModel]] | None = None) -> str:
    """The text of camd/client_types.py for ``models`` (default: the API's response models)."""
    models = response_models() if models is None else models
    annotations: list[str] = []
    classes = [render_class(model, annotations) for model in models]
    return module_text(HEADER, classes, annotations)


def generator_main(
    argv: Sequence[str] | None,
    *,
    command: str,
    description: str,
    output: Path,
    render: Callable[[], str],
) -> int:
    """The command line of a generator of this kind: write ``output`` with ``render()``, or
    with ``--check`` say whether it is current (exit 1 if not, 2 if a model cannot be
    rendered)."""
    parser = argparse.ArgumentParser(prog=command, description=description)
    parser.add_argument(
        "--check",
        action="store_true",
        help="do not write; exit 1 if the file differs from what would be generated",
    )
    parser.add_argument("--output", type=Path, default=output, help="file to write or check")
    args = parser.parse_args(argv)
    try:
        text = render()
    except ClientTypesError as exc:
        print(f"{command.rpartition('.')[2]}: {exc}", file=sys.stderr)
        return 2
    return write_or_check(args.output, text, check=args.check, command=command)


def main(argv: Sequence[str] | None = None) -> int:
    return generator_main(
        argv,
        command=COMMAND,
        description="Generate camd/client_types.py (the client's TypedDicts) from the API's "
        "pydantic models in camd/daemon/models/.",
        output=OUTPUT,
        render=render_client_types,
    )


if __name__ == "__main__":
    raise SystemExit(main())
