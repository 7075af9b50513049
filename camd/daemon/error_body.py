"""The API's error body, ``{"error", "code"}`` (docs/api.md, "Errors"), with what a client sent
quoted back cut short: an error must never be as large as the request that caused it.
"""

from __future__ import annotations

from fastapi.responses import JSONResponse

from camd.datafile import ERROR_MESSAGE_MAX, bounded, cut

__all__ = ["ERROR_MESSAGE_MAX", "WS_POLICY_VIOLATION", "cut", "error_response"]

WS_POLICY_VIOLATION = 1008  # the WebSocket close code for a refused token or origin


def error_response(status: int, code: str, message: str) -> JSONResponse:
    """The documented error body."""
    return JSONResponse(status_code=status, content={"error": bounded(message), "code": code})
