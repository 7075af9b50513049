"""Argument checks shared by the timing equations: one clear ``ValueError`` per bad input."""

from __future__ import annotations

import math


def positive(name: str, value: float) -> float:
    """``value`` as a float if it is finite and > 0, else a ValueError naming ``name``."""
    number = real(name, value)
    if number <= 0.0:
        raise ValueError(f"{name} must be > 0, got {value!r}")
    return number


def non_negative(name: str, value: float) -> float:
    """``value`` as a float if it is finite and >= 0, else a ValueError naming ``name``."""
    number = real(name, value)
    if number < 0.0:
        raise ValueError(f"{name} must be >= 0, got {value!r}")
    return number


def real(name: str, value: float) -> float:
    """``value`` as a finite float (bool is refused: it is almost always a caller's mistake)."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ValueError(f"{name} must be a number, got {value!r}")
    number = float(value)
    if not math.isfinite(number):
        raise ValueError(f"{name} must be finite, got {value!r}")
    return number


def count(name: str, value: int, minimum: int) -> int:
    """``value`` if it is an integer >= ``minimum``, else a ValueError naming ``name``."""
    if isinstance(value, bool) or not isinstance(value, int):
        raise ValueError(f"{name} must be an integer, got {value!r}")
    if value < minimum:
        raise ValueError(f"{name} must be >= {minimum}, got {value}")
    return value
