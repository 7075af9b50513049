"""How errors leave the API: every one as ``{"error", "code"}`` with the status docs/api.md
gives. The session's errors map to their status and code (``ERROR_MAP``, which OpenAPI lists per
status), FastAPI's 422 validation errors become 400s naming each parameter and its valid values
(``camd.daemon.api_validation``), Starlette's 404 and 405 say what to use instead, and anything
unexpected is a 500 that points at the log.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Coroutine
from functools import partial
from typing import Any

import anyio
from fastapi import Request, Response
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.routing import Match, Mount

from camd.daemon.api_validation import validation_message
from camd.daemon.error_body import cut, error_response
from camd.daemon.errors import (
    ArchiveUnreadable,
    BadRequest,
    Busy,
    DeviceRejected,
    DeviceTimeout,
    Disconnected,
    EndedEarly,
    EstopLatched,
    LinkUntrained,
    NoControl,
    NoFrameDevice,
    NotFound,
    NotInControl,
    SensorMismatch,
    SessionError,
    StorageFull,
    WrongState,
)
from camd.daemon.models import ErrorResponse
from camd.daemon.session import DeviceSession
from camd.daemon.state import IllegalState

log = logging.getLogger(__name__)

# exception type -> (HTTP status, error code), as docs/api.md lists them
ERROR_MAP: list[tuple[type[Exception], int, str]] = [
    (BadRequest, 400, "bad_request"),
    (NotFound, 404, "not_found"),
    (IllegalState, 409, "illegal_state"),
    (LinkUntrained, 409, "link_untrained"),
    (SensorMismatch, 409, "sensor_mismatch"),
    (Busy, 409, "busy"),
    (EstopLatched, 409, "estop_latched"),
    (WrongState, 409, "wrong_state"),
    (NoControl, 409, "no_control"),
    (NotInControl, 423, "not_in_control"),
    (DeviceRejected, 502, "device_nak"),
    (EndedEarly, 502, "ended_early"),
    (Disconnected, 503, "disconnected"),
    (NoFrameDevice, 503, "no_frame_device"),
    (ArchiveUnreadable, 503, "archive_unreadable"),
    (DeviceTimeout, 504, "timeout"),
    (StorageFull, 507, "insufficient_storage"),
]

ERROR_RESPONSES: dict[int | str, dict[str, Any]] = {
    401: {"model": ErrorResponse, "description": "unauthorized"},
    403: {
        "model": ErrorResponse,
        "description": "foreign_origin, foreign_host or client_header_required (docs/api.md, "
        "Browsers and untrusted clients)",
    },
    413: {
        "model": ErrorResponse,
        "description": "too_large: the body passes api.max_body_bytes or 1000 JSON values",
    },
}
# One status may carry several codes (409: illegal_state, busy, ...): OpenAPI lists them all.
for _status in dict.fromkeys(status for _, status, _ in ERROR_MAP):
    _codes = ", ".join(code for _, s, code in ERROR_MAP if s == _status)
    ERROR_RESPONSES[_status] = {"model": ErrorResponse, "description": _codes}


def map_error(exc: Exception) -> JSONResponse:
    """The error body of a session error, with its status and code from ERROR_MAP."""
    for kind, status, code in ERROR_MAP:
        if isinstance(exc, kind):
            return error_response(status, code, str(exc))
    return error_response(500, "internal", str(exc))


def limit_now(session: DeviceSession, name: str) -> str:
    """A limit tighter than the field's own that holds now: the stages the window holds
    (the field's 4096 is the largest window of any sensor)."""
    if name != "stages":
        return ""
    try:
        timing = session.sensor.timing()
    except (SessionError, IllegalState):
        return ""  # the camera cannot be asked: the field's own range stands
    return (
        f"; the sensor's window now has {timing.window_rows} rows, so at most "
        f"{timing.max_stages} stages (M <= the window's rows, docs/physics.md §2 eq 13); "
        "a scan sets the window from its line period"
    )


async def on_validation_error(request: Request, exc: RequestValidationError) -> JSONResponse:
    """400 bad_request naming each invalid parameter and the values it takes."""
    # In a worker thread: limit_now may ask the camera (never on the event loop).
    route = request.scope.get("route")
    limit = partial(limit_now, request.app.state.session)
    message = await anyio.to_thread.run_sync(validation_message, exc, route, limit)
    return error_response(400, "bad_request", message)


# The methods a 405's Allow header may name: those of RFC 9110 and PATCH, in sorted order.
HTTP_METHODS = ("DELETE", "GET", "HEAD", "OPTIONS", "PATCH", "POST", "PUT", "TRACE")


def allowed_methods(request: Request) -> list[str]:
    """The methods the routes of the request's path answer (for a 405 and its Allow header).

    Each method is asked of every route, as the app would route it: a router the app includes
    (FastAPI from 0.137 keeps it as one entry of the app's routes) answers for its own routes.
    The static files' mount, which takes any method, is left out.
    """
    routes = [r for r in request.app.router.routes if not isinstance(r, Mount)]
    return [
        method
        for method in HTTP_METHODS
        if any(r.matches({**request.scope, "method": method})[0] == Match.FULL for r in routes)
    ]


async def on_http_error(request: Request, exc: StarletteHTTPException) -> JSONResponse:
    """Starlette's own errors in the API's form: a 404 says where the endpoints are listed, a
    405 which methods the path answers."""
    code = {400: "bad_request", 404: "not_found", 405: "method_not_allowed"}.get(
        exc.status_code, "http_error"
    )
    message = str(exc.detail)
    path = cut(request.url.path)
    if exc.status_code == 404:
        message = f"no such endpoint {path}; see /docs or docs/api.md"
    elif exc.status_code == 405:
        allowed = allowed_methods(request)
        message = (
            f"{request.method} is not allowed on {path}; use {' or '.join(allowed)} (see /docs)"
        )
        response = error_response(exc.status_code, code, message)
        response.headers["Allow"] = ", ".join(allowed)  # RFC 9110 15.5.6: required
        return response
    elif exc.status_code == 400:  # FastAPI: a JSON body its parser gave up on
        message = (
            f"{message}: the request body is not JSON that can be read (nested too deeply?); "
            'send a JSON object, e.g. {"count": 10}'
        )
    return error_response(exc.status_code, code, message)


async def on_session_error(request: Request, exc: SessionError | IllegalState) -> JSONResponse:
    """A session error or a request the state machine refuses: its status and code."""
    return map_error(exc)


async def on_unexpected(request: Request, exc: Exception) -> JSONResponse:
    """A bug: 500 internal, logged with its traceback."""
    log.exception("unhandled error in %s %s", request.method, request.url.path)
    return error_response(
        500, "internal", f"internal error in camd: {type(exc).__name__}: {exc}; see its log"
    )


Handler = Callable[[Request, Any], Coroutine[Any, Any, Response]]

EXCEPTION_HANDLERS: dict[int | type[Exception], Handler] = {
    RequestValidationError: on_validation_error,
    StarletteHTTPException: on_http_error,
    SessionError: on_session_error,
    IllegalState: on_session_error,
    Exception: on_unexpected,
}
