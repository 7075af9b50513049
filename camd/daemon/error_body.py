"""The API's error body, ``{"error", "code"}`` (docs/api.md, "Errors"), with what a client sent
quoted back cut short: an error must never be as large as the request that caused it.
"""

from __future__ import annotations

import re

from fastapi.responses import JSONResponse

__all__ = ["ERROR_MESSAGE_MAX", "WS_POLICY_VIOLATION", "cut", "error_response"]

WS_POLICY_VIOLATION = 1008  # the WebSocket close code for a refused token or origin
SHOWN_MAX = 80  # characters of a client's value quoted back in an error message
ERROR_MESSAGE_MAX = 2000  # characters: longer messages carry an echoed value (below)
WORD_MAX = 100  # ... whose words longer than this are cut


def cut(text: str, limit: int = SHOWN_MAX) -> str:
    """``text``, or its first ``limit`` characters and how long it was: a value a client sent,
    quoted in an error, must not make the answer as large as the request."""
    return text if len(text) <= limit else f"{text[:limit]}... ({len(text)} characters)"


def _bounded(message: str) -> str:
    """An error message at most about ERROR_MESSAGE_MAX characters long. The services quote
    names and paths a client gave (a register, a file); a message this long holds such a value,
    and its long words are cut; a message still too long keeps its head and its tail (what to
    do)."""
    if len(message) <= ERROR_MESSAGE_MAX:
        return message
    message = re.sub(rf"\S{{{WORD_MAX + 1},}}", lambda m: cut(m.group(), WORD_MAX), message)
    if len(message) <= ERROR_MESSAGE_MAX:
        return message
    head, tail = ERROR_MESSAGE_MAX * 3 // 4, ERROR_MESSAGE_MAX // 5
    dropped = len(message) - head - tail
    return f"{message[:head]} ... ({dropped} characters cut) ... {message[-tail:]}"


def error_response(status: int, code: str, message: str) -> JSONResponse:
    """The documented error body."""
    return JSONResponse(status_code=status, content={"error": _bounded(message), "code": code})
