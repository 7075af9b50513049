"""What the routes share, as FastAPI dependencies: the session the app serves, the client a
request comes from, and the control check of every route that changes the camera.

``create_app`` puts the session in ``app.state.session``; a route asks for it with a parameter
of type ``Session``. A route that changes the camera declares ``needs_control("start a scan")``
among its dependencies: the client is checked once, before the body is read (423
not_in_control naming the holder), and the route then runs as that client, so that an
acquisition it starts is owned by it (``camd.daemon.acquisition.acting_as``).
"""

from __future__ import annotations

from collections.abc import AsyncIterator
from typing import Annotated, Any

import anyio
from fastapi import Depends, Header, Response
from starlette.requests import HTTPConnection

from camd.daemon.acquisition import acting_as
from camd.daemon.control import ANONYMOUS
from camd.daemon.error_body import error_response
from camd.daemon.session import DeviceSession

CLIENT_NAME_MAX = 100


async def session_of(connection: HTTPConnection) -> DeviceSession:
    """The session the app serves (async: a plain lookup, no worker thread needed)."""
    session: DeviceSession = connection.app.state.session
    return session


Session = Annotated[DeviceSession, Depends(session_of)]


def client_name(header: str | None) -> str:
    """The client a request comes from (the ``X-Camd-Client`` header, printable, at most 100
    characters), or "anonymous"."""
    if header is None:
        return ANONYMOUS
    name = "".join(ch for ch in header if ch.isprintable()).strip()[:CLIENT_NAME_MAX]
    return name or ANONYMOUS


async def requester(
    x_camd_client: str | None = Header(
        default=None, description="who asks (camctl sends user@host; --client NAME)"
    ),
) -> str:
    """The requesting client's name (the header, cleaned)."""
    return client_name(x_camd_client)


Client = Annotated[str, Depends(requester)]


class ControlCheck:
    """The dependency ``needs_control`` declares: a callable object, so that each route names
    what it wants to do in the 423's message."""

    def __init__(self, wanted: str) -> None:
        self.wanted = wanted

    async def __call__(self, session: Session, client: Client) -> AsyncIterator[str]:
        # Control.check takes a lock and may log an expired lease: a worker thread, as the
        # endpoints' own work, never the event loop.
        await anyio.to_thread.run_sync(session.control.check, client, self.wanted)
        # Set here, on the request's task, the client is in the context FastAPI copies into
        # the endpoint's worker thread; the "function" scope ends it when the endpoint returns.
        with acting_as(client):
            yield client


def needs_control(wanted: str) -> Any:
    """A route's dependency: the requesting client may change the camera (nobody holds
    control, or it does), else 423 not_in_control "cannot <wanted>: <holder> holds control
    ..."; the route then runs as that client."""
    return Depends(ControlCheck(wanted), scope="function")


def no_frame(after: int = 0, timeout_s: float = 0.0) -> Response:
    """404 no_frame: nothing streamed yet (or nothing newer than ``after`` came in time)."""
    newer = f" newer than seq {after} within {timeout_s:g} s" if after else " yet"
    return error_response(
        404,
        "no_frame",
        f"no live frame{newer}: the live view shows frames while something streams; "
        "start a stream (`camctl stream --frames 100`), a stare or a scan",
    )
