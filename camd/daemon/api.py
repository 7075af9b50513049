"""The HTTP API (docs/api.md) as a FastAPI app over a DeviceSession: the routers of
camd/daemon/routes (one per resource) behind the request guard and the token check, every error
leaving as ``{"error", "code"}`` (camd.daemon.api_errors).

Endpoints are plain ``def``: they block on the serial link, so FastAPI runs them on its worker
threads and the event loop stays free. They reach the session through ``app.state`` (the
dependencies of camd.daemon.routes.deps).
"""

from __future__ import annotations

from fastapi import FastAPI
from fastapi.staticfiles import StaticFiles
from starlette.middleware import Middleware
from starlette.middleware.base import BaseHTTPMiddleware

import camd
from camd import web
from camd.daemon.api_errors import ERROR_RESPONSES, EXCEPTION_HANDLERS
from camd.daemon.api_token import check_token
from camd.daemon.request_guard import RequestGuard
from camd.daemon.routes import (
    campaigns,
    control,
    link,
    live,
    metrics,
    motion,
    pages,
    scan,
    sensor,
    sim,
    snapshot,
    stream,
    telemetry,
    wheel,
)
from camd.daemon.session import DeviceSession

# In the order the app matches them (and OpenAPI lists them).
RESOURCES = [
    pages,
    control,
    campaigns,
    link,
    telemetry,
    live,
    snapshot,
    sensor,
    stream,
    scan,
    motion,
    wheel,
    sim,
    metrics,
]


def create_app(session: DeviceSession, *, token: str = "") -> FastAPI:
    """The FastAPI app serving ``session``; with ``token``, every request needs it."""
    app = FastAPI(
        title="camd",
        version=camd.__version__,
        description="Control daemon of a digital-TDI push-broom camera (docs/api.md).",
        responses=ERROR_RESPONSES,
        # FastAPI's own /docs and /redoc load their scripts from a CDN: blank on an offline
        # test PC. /docs is served from the Swagger UI shipped in camd.web (routes/pages.py).
        docs_url=None,
        redoc_url=None,
        exception_handlers=EXCEPTION_HANDLERS,
        middleware=[
            # Outermost first: nothing reads a request before the guard has checked it.
            Middleware(
                RequestGuard,
                token=token,
                allowed_origins=session.config.api.allowed_origins,
                max_body_bytes=session.config.api.max_body_bytes,
            ),
            Middleware(BaseHTTPMiddleware, dispatch=check_token),
        ],
    )
    app.state.session = session
    app.state.token = token
    app.mount("/static", StaticFiles(directory=web.STATIC_DIR), name="static")
    for module in RESOURCES:
        app.include_router(module.router)
    return app
