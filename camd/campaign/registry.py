"""Functions registered by name, for the campaign's tables of them (``camd.campaign.measurements``'
measurements, ``camd.campaign.conformance.engine``'s check functions): a decorator that puts a
function in its table and refuses a name registered twice."""

from __future__ import annotations

from collections.abc import Callable
from typing import TypeVar

Fn = TypeVar("Fn", bound=Callable[..., object])


def register_in(table: dict[str, Fn], what: str, name: str) -> Callable[[Fn], Fn]:
    """A decorator that registers its function in ``table`` as ``name``; ValueError ("<what>
    'name' is registered twice") if ``table`` has the name already."""

    def register(fn: Fn) -> Fn:
        if name in table:
            raise ValueError(f"{what} {name!r} is registered twice")
        table[name] = fn
        return fn

    return register
