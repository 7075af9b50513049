"""How a value given is quoted back in an error: cut when long (``cut``), the whole message
bounded (``bounded``), its type in words (``what_it_is``). The API's errors, camctl's, camd's and
the simulator's use them too."""

from __future__ import annotations

import re

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
