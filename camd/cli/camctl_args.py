"""What camctl's command groups share to read their command lines: the argument types of their
options (argparse's ``type``: each refuses a bad value with a message that says what to give) and
the ACTION subcommands of a command (``camctl reg read``, ``camctl sim scene``, ``camctl wheel
speed``)."""

from __future__ import annotations

import argparse
import math
import re
from collections.abc import Callable


def positive_float(text: str) -> float:
    """An argument type: a number > 0 (``--timeout``, ``--ttl-s``)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not value > 0:
        raise argparse.ArgumentTypeError(f"must be > 0, got {text}")
    return value


def int_range(lo: int, hi: int) -> Callable[[str], int]:
    """An argument type: an integer from ``lo`` to ``hi``, named ``integer`` in argparse's
    messages."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
        if not lo <= value <= hi:
            raise argparse.ArgumentTypeError(f"must be from {lo} to {hi}, got {value}")
        return value

    parse.__name__ = "integer"
    return parse


def number_within(lo: float, hi: float, refusal: str) -> Callable[[str], float]:
    """An argument type: a number from ``lo`` to ``hi``; anything else is refused with
    ``refusal``, a format of ``{text}`` (the value given), e.g. ``"{text!r} is not a speed in
    m/s between 0 and 10"``."""

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            value = math.nan
        if not lo <= value <= hi:
            raise argparse.ArgumentTypeError(refusal.format(text=text))
        return value

    return parse


def count_arg(text: str) -> int:
    """argparse type: a whole number >= 0 (decimal or 0x hex)."""
    try:
        value = int(text, 0)
    except ValueError:
        value = -1
    if value < 0:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number >= 0")
    return value


_WITH_UNIT = re.compile(r"\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*([a-zµ/]+)\s*")
_TO_SI = {"m": 1.0, "cm": 1e-2, "mm": 1e-3, "um": 1e-6, "µm": 1e-6, "m/s": 1.0,
          "cm/s": 1e-2, "mm/s": 1e-3, "um/s": 1e-6, "µm/s": 1e-6}  # fmt: skip


def si_number(text: str) -> float:
    """argparse type: a finite number in the SI unit the option names, written without one;
    ``100mm`` is refused with the number to give instead (0.1)."""
    match = _WITH_UNIT.fullmatch(text)
    if match is not None and match.group(2) in _TO_SI:
        value = float(match.group(1)) * _TO_SI[match.group(2)]
        what = "speed in m/s" if match.group(2).endswith("/s") else "distance in metres"
        raise argparse.ArgumentTypeError(
            f"{text!r} is not a number: give the {what}, without a unit, e.g. {value:g} for "
            f"{match.group(1)} {match.group(2)}"
        )
    return finite_number(text)


def finite_number(text: str) -> float:
    """argparse type: a finite number (nan and inf are refused here, not by the daemon)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be a finite number, got {text}")
    return value


def actions(
    command: argparse.ArgumentParser, dest: str, *, required: bool = True
) -> Callable[[str, str], argparse.ArgumentParser]:
    """The ACTION subcommands of ``command`` (the one given is in ``args.<dest>``): a factory
    ``action(name, help)`` of their parsers, each with its own ``--json`` (which leaves the one
    given before the action alone unless given again)."""
    sub = command.add_subparsers(dest=dest, metavar="ACTION", required=required)

    def action(name: str, help_text: str) -> argparse.ArgumentParser:
        sp = sub.add_parser(name, help=help_text, description=help_text)
        sp.add_argument("--json", action="store_true", default=argparse.SUPPRESS,
                        help="print exactly one JSON document on stdout")  # fmt: skip
        return sp

    return action
