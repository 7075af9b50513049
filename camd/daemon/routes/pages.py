"""The daemon's own pages, outside the API's schema: the live view (docs/live-view.md) and the
API's interactive documentation, both served from camd.web (nothing from the internet)."""

from __future__ import annotations

from urllib.parse import urlencode

from fastapi import APIRouter, Request
from fastapi.openapi.docs import get_swagger_ui_html
from fastapi.responses import FileResponse, HTMLResponse, RedirectResponse

from camd import web

router = APIRouter(include_in_schema=False)


@router.get("/docs")
def swagger_ui(request: Request) -> HTMLResponse:
    """The Swagger UI shipped in camd.web: FastAPI's own /docs and /redoc load their scripts
    from a CDN, blank on an offline test PC."""
    return get_swagger_ui_html(
        openapi_url=request.app.openapi_url or "/openapi.json",
        title="camd API",
        swagger_js_url=f"{web.SWAGGER_UI_URL}/swagger-ui-bundle.js",
        swagger_css_url=f"{web.SWAGGER_UI_URL}/swagger-ui.css",
        swagger_favicon_url=f"{web.SWAGGER_UI_URL}/favicon-32x32.png",
    )


@router.get("/live", response_model=None)
def live_page(request: Request) -> FileResponse | RedirectResponse:
    """The live view (docs/live-view.md). Opened with ``?token=``, it answers with the
    token cookie and sends the browser to the plain address (the token leaves the
    address bar and the history)."""
    if "token" in request.query_params:
        rest = [(k, v) for k, v in request.query_params.multi_items() if k != "token"]
        query = urlencode(rest)
        return RedirectResponse(f"/live?{query}" if query else "/live", status_code=303)
    return FileResponse(web.LIVE_PAGE, headers={"Cache-Control": "no-cache"})


@router.get("/")
def root() -> RedirectResponse:
    """The live view is the daemon's front page."""
    return RedirectResponse("/live", status_code=307)
