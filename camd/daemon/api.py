"""The HTTP API (docs/api.md) as a FastAPI app over a DeviceSession.

Endpoints are plain ``def``: they block on the serial link, so FastAPI runs them on its worker
threads and the event loop stays free. Every error leaves as ``{"error", "code"}`` with the status
docs/api.md gives; FastAPI's 422 validation errors are reshaped into 400s whose message names the
parameter and its allowed values.
"""

from __future__ import annotations

import contextlib
import hmac
import json
import logging
import types
from collections.abc import Awaitable, Callable, Iterable
from typing import Any, Union, get_args, get_origin
from urllib.parse import urlencode

import annotated_types
import anyio
from fastapi import Depends, FastAPI, Header, Query, Request, WebSocket, WebSocketDisconnect
from fastapi.exceptions import RequestValidationError
from fastapi.openapi.docs import get_swagger_ui_html
from fastapi.responses import (
    FileResponse,
    HTMLResponse,
    JSONResponse,
    RedirectResponse,
    Response,
)
from fastapi.routing import APIRoute
from fastapi.staticfiles import StaticFiles
from prometheus_client import CONTENT_TYPE_LATEST, generate_latest
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily, Metric
from prometheus_client.registry import Collector, CollectorRegistry
from pydantic import BaseModel
from pydantic.fields import FieldInfo
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.routing import Match

import camd
from camd import web
from camd.daemon.acquisition import acting_as
from camd.daemon.api_validation import ALLOWED, valid_values
from camd.daemon.control import ANONYMOUS
from camd.daemon.error_body import ERROR_MESSAGE_MAX, WS_POLICY_VIOLATION, cut, error_response
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
from camd.daemon.models import (
    EVENTS_LIMIT_MAX,
    HISTORY_LIMIT_MAX,
    LIVE_LINES_MAX,
    LIVE_WAIT_MAX_S,
    ActivityRequest,
    BackgroundRequest,
    BackgroundStatus,
    CampaignActionRequest,
    CampaignJob,
    CampaignJobsResponse,
    CampaignStartRequest,
    ControlInfo,
    ControlRequest,
    ErrorResponse,
    EstopResponse,
    EstopState,
    EventsResponse,
    HistoryResponse,
    LinkCommandRequest,
    LinkCommandResponse,
    LinkResponse,
    ModeRequest,
    ModeResponse,
    MotionEnableRequest,
    MotionHomeRequest,
    MotionMoveRequest,
    MotionRunRequest,
    MotionStatus,
    PingRequest,
    PingResponse,
    PolarizerRequest,
    RegisterConfig,
    RegisterDiffRequest,
    RegisterDiffResponse,
    RegisterReading,
    RegistersResponse,
    RegisterWriteRequest,
    RegisterWriteResponse,
    ScanRequest,
    ScanResponse,
    SceneRequest,
    SeedRequest,
    SimFailNextRequest,
    SimSettings,
    SimStageFaultsRequest,
    SimStageTruth,
    SimStreamStats,
    StageRequest,
    StageResponse,
    StagesRequest,
    StatusResponse,
    StreamHeadersResponse,
    StreamResponse,
    StreamStartRequest,
    SyncResponse,
    TelemetryResponse,
    TimingResponse,
    TrainResponse,
    WheelAcquireRequest,
    WheelAcquireResponse,
    WheelCompensationRequest,
    WheelSpeedRequest,
    WheelStatus,
)
from camd.daemon.request_guard import API, RequestGuard
from camd.daemon.session import DeviceSession
from camd.daemon.state import IllegalState, State
from camd.daemon.telemetry import Level, classify
from camd.datafile import what_it_is

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

_ERROR_RESPONSES: dict[int | str, dict[str, Any]] = {
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
    _ERROR_RESPONSES[_status] = {"model": ErrorResponse, "description": _codes}

# The live view's pixels: raw bytes, or 404 while there are none yet (no_frame, no_scan,
# no_background).
_FRAME_RESPONSES: dict[int | str, dict[str, Any]] = {
    200: {"content": {"application/octet-stream": {}}},
    404: {"model": ErrorResponse, "description": "nothing to show yet: the message says why"},
}

CLIENT_NAME_MAX = 100


def client_name(header: str | None) -> str:
    """The client a request comes from (the ``X-Camd-Client`` header, printable, at most 100
    characters), or "anonymous"."""
    if header is None:
        return ANONYMOUS
    name = "".join(ch for ch in header if ch.isprintable()).strip()[:CLIENT_NAME_MAX]
    return name or ANONYMOUS


# LIVE_WAIT_MAX_S (models): longest a live-view request waits for something newer.
LIVE_POLL_S = 1.0  # a WebSocket viewer's wait for the next frame, between checks
PROBLEMS_SHOWN_MAX = 10  # invalid parameters described in one 400; the rest are counted
TOKEN_COOKIE = "camd_token"  # a browser's copy of the token (set by a page opened with ?token=)


_UNION_TAGS = {"int", "float", "str", "bool", "none"}  # pydantic's loc parts for union members


def _parameter(route: object, loc: list[str | int]) -> FieldInfo | None:
    """The field of ``route``'s own request model (or query parameter) that ``loc`` names, so
    that the valid values quoted are this endpoint's (several models share field names)."""
    if not isinstance(route, APIRoute) or len(loc) < 2:
        return None
    where, path = loc[0], loc[1:]
    if where == "query":
        params = {p.alias: p.field_info for p in route.dependant.query_params}
        return params.get(str(path[0])) if len(path) == 1 else None
    if where != "body" or len(route.dependant.body_params) != 1:
        return None
    model: Any = route.dependant.body_params[0].field_info.annotation
    field: FieldInfo | None = None
    for part in path:
        if get_origin(model) in (Union, types.UnionType):
            args = [a for a in get_args(model) if a is not type(None)]
            model = args[0] if len(args) == 1 else None
        if get_origin(model) in (dict, list):  # an entry: its type, unconstrained
            field = FieldInfo.from_annotation(get_args(model)[-1])
        elif isinstance(model, type) and issubclass(model, BaseModel):
            field = model.model_fields.get(str(part))
        else:
            return None
        if field is None:
            return None
        model = field.annotation
    return field


def _outside(field: FieldInfo | None, value: float) -> bool:
    """Whether ``value`` lies beyond the bounds ``field`` sets (unknown bounds: no)."""
    for item in field.metadata if field is not None else ():
        if isinstance(item, annotated_types.Ge | annotated_types.Gt):
            low = item.ge if isinstance(item, annotated_types.Ge) else item.gt
            if value < low:  # type: ignore[operator]
                return True
        elif isinstance(item, annotated_types.Le | annotated_types.Lt):
            high = item.le if isinstance(item, annotated_types.Le) else item.lt
            if value > high:  # type: ignore[operator]
                return True
    return False


def _allowed_methods(app: FastAPI, request: Request) -> list[str]:
    """The methods the routes of the request's path answer (for a 405 and its Allow header)."""
    methods: set[str] = set()
    for route in app.router.routes:
        match, _ = route.matches({**request.scope, "method": "GET"})
        route_methods = getattr(route, "methods", None)
        if match != Match.NONE and route_methods:
            methods.update(route_methods)
    return sorted(methods)


def _shown(value: object, loc: list[str | int]) -> str:
    """A rejected value as the user wrote it: a query parameter's number arrives as the text
    of the URL ("0.0"), which quoted would read as a string given where a number was due."""
    return cut(value if loc[:1] == ["query"] and isinstance(value, str) else repr(value))


def _validation_message(
    exc: RequestValidationError,
    route: object = None,
    limit_now: Callable[[str], str] = lambda name: "",
) -> str:
    """``"stages: 0 is out of range; use an integer in 1..4096"`` for each invalid parameter:
    the valid values read from the endpoint's own model (``valid_values``), with
    ``ALLOWED``'s explanation where the type and constraints do not say enough."""
    parts: list[str] = []
    seen = set()
    more = 0  # invalid parameters past PROBLEMS_SHOWN_MAX: counted, not described
    for err in exc.errors():
        loc: list[str | int] = list(err.get("loc", ()))
        while len(loc) > 2 and loc[-1] in _UNION_TAGS:
            loc.pop()  # values.GAIN.int -> values.GAIN
        shown_loc = [str(p) for p in loc if p not in ("body", "query", "path")]
        name = ".".join(shown_loc)
        if name in seen:
            continue  # one message per parameter (a union reports each member)
        seen.add(name)
        if len(parts) >= PROBLEMS_SHOWN_MAX:
            more += 1
            continue
        name = cut(name)  # a key of the client's own object may be part of it
        kind = str(err.get("type", ""))
        value = err.get("input")
        field = _parameter(route, loc)
        # ALLOWED's explanation of the parameter, or of the one an entry belongs to
        hint = next((ALLOWED[p] for p in reversed(shown_loc) if p in ALLOWED), "")
        if field is not None and not hint and loc[0] == "query":
            hint = field.description or ""  # its meaning on this endpoint
        if field is not None:
            allowed = valid_values(field) + (f" ({hint})" if hint else "")
        else:
            allowed = hint
        use = f"; use {allowed}" if allowed else ""
        if kind == "json_invalid":
            parts.append('the request body is not valid JSON; send e.g. {"count": 10}')
        elif kind == "missing":
            parts.append(f"{name}: is required{use}")
        elif kind == "extra_forbidden":
            parts.append(f"{name}: unknown parameter; remove it (check the spelling)")
        elif kind in ("model_attributes_type", "dict_type") and not name:
            shown = value.decode(errors="replace") if isinstance(value, bytes) else repr(value)
            parts.append(
                f"the request body must be a JSON object (Content-Type: application/json), "
                f"not {cut(shown)}"
            )
        elif kind in ("greater_than_equal", "less_than_equal", "greater_than", "less_than"):
            parts.append(f"{name}: {_shown(value, loc)} is out of range{use}{limit_now(name)}")
        elif kind == "finite_number":
            parts.append(f"{name}: {_shown(value, loc)} is not a finite number{use}")
        elif kind == "int_type" and isinstance(value, float) and value.is_integer():
            # 1e20 or 3.0: a whole number written as a float; out of range, or just its form
            if _outside(field, value):
                parts.append(f"{name}: {cut(repr(value))} is out of range{use}")
            else:
                parts.append(f"{name}: {cut(repr(value))} is a whole number written with a "
                             f"decimal point or an exponent; write it as an integer{use}")  # fmt: skip
        elif kind.endswith("_type"):
            what = what_it_is(value, array="a list", table="an object")
            parts.append(f"{name}: {cut(repr(value))} is {what}, the wrong type{use}")
        elif kind == "value_error":  # a validator of the model: its reason
            reason = cut(str(err.get("msg", "")).removeprefix("Value error, "), ERROR_MESSAGE_MAX)
            parts.append(f"{name}: {cut(repr(value))} is not valid ({reason}){use}")
        else:
            parts.append(f"{name}: {cut(repr(value))} is not valid{use}")
    if more:
        parts.append(f"and {more} more problem{'s' if more > 1 else ''}")
    return "; ".join(parts) or "invalid request"


class _SessionCollector(Collector):
    """Prometheus metrics read from the session at scrape time (no device traffic)."""

    def __init__(self, session: DeviceSession) -> None:
        self.session = session

    def collect(self) -> Iterable[Metric]:
        """The metric families, built fresh at each scrape."""
        session = self.session
        state = GaugeMetricFamily(
            "camd_state", "1 for the daemon's current state, 0 for the others", labels=["state"]
        )
        current = session.state
        for s in State:
            state.add_metric([s.value], 1.0 if s == current else 0.0)
        yield state
        link = session.link
        yield GaugeMetricFamily(
            "camd_link_connected",
            "1 while the command link's port is open",
            value=1.0 if link is not None and link.connected else 0.0,
        )
        for name, count in session.host_counters().items():
            yield CounterMetricFamily(
                f"camd_link_{name}", f"command link host counter: {name}", value=count
            )
        yield GaugeMetricFamily(
            "camd_stream_active", "1 while frames stream", value=float(session.stream.streaming)
        )
        mismatch = GaugeMetricFamily(
            "camd_scan_m_dv_over_v",
            "current or last scan: M |dV/V| (pixels of smear) of the last batch, max and RMS",
            labels=["stat"],
        )
        for stat, number in session.scan.mismatch_gauges().items():
            mismatch.add_metric([stat], number)
        yield mismatch
        for name, number in session.stream.stats().model_dump().items():
            # Per stream (reset when one starts), so gauges rather than counters.
            yield GaugeMetricFamily(
                f"camd_stream_{name}", f"frame stream ingest, current or last stream: {name}",
                value=float(number),
            )  # fmt: skip
        values = GaugeMetricFamily(
            "camd_telemetry_value",
            "latest housekeeping value per channel, in the channel's unit",
            labels=["channel", "unit"],
        )
        levels = GaugeMetricFamily(
            "camd_telemetry_limit_level",
            "limit level of the latest value: 0 ok, 1 yellow, 2 red",
            labels=["channel"],
        )
        level_number = {Level.OK: 0.0, Level.YELLOW: 1.0, Level.RED: 2.0}
        for channel, value in sorted(session.latest_values().items()):
            values.add_metric([channel, session.channels.get(channel, "")], value)
            limits = session.config.telemetry.limits.get(channel)
            if limits is not None:
                levels.add_metric([channel], level_number[classify(value, limits)])
        yield values
        yield levels
        archive = session.archive
        if archive is not None:
            yield GaugeMetricFamily(
                "camd_telemetry_archived_samples",
                "samples in the SQLite archive",
                value=archive.count(),
            )
        yield GaugeMetricFamily(
            "camd_uptime_seconds", "time since the daemon started", value=session.uptime_s
        )
        info = GaugeMetricFamily("camd_info", "daemon version", labels=["version"])
        info.add_metric([camd.__version__], 1.0)
        yield info


def create_app(session: DeviceSession, *, token: str = "") -> FastAPI:
    """The FastAPI app serving ``session``; with ``token``, every request needs it."""
    app = FastAPI(
        title="camd",
        version=camd.__version__,
        description="Control daemon of a digital-TDI push-broom camera (docs/api.md).",
        responses=_ERROR_RESPONSES,
        # FastAPI's own /docs and /redoc load their scripts from a CDN: blank on an offline
        # test PC. /docs is served below from the Swagger UI shipped in camd.web.
        docs_url=None,
        redoc_url=None,
    )
    app.mount("/static", StaticFiles(directory=web.STATIC_DIR), name="static")

    @app.get("/docs", include_in_schema=False)
    def swagger_ui() -> HTMLResponse:
        return get_swagger_ui_html(
            openapi_url=app.openapi_url or "/openapi.json",
            title="camd API",
            swagger_js_url=f"{web.SWAGGER_UI_URL}/swagger-ui-bundle.js",
            swagger_css_url=f"{web.SWAGGER_UI_URL}/swagger-ui.css",
            swagger_favicon_url=f"{web.SWAGGER_UI_URL}/favicon-32x32.png",
        )

    @app.get("/live", include_in_schema=False, response_model=None)
    def live_page(request: Request) -> FileResponse | RedirectResponse:
        """The live view (docs/live-view.md). Opened with ``?token=``, it answers with the
        token cookie and sends the browser to the plain address (the token leaves the
        address bar and the history)."""
        if "token" in request.query_params:
            rest = [(k, v) for k, v in request.query_params.multi_items() if k != "token"]
            query = urlencode(rest)
            return RedirectResponse(f"/live?{query}" if query else "/live", status_code=303)
        return FileResponse(web.LIVE_PAGE, headers={"Cache-Control": "no-cache"})

    @app.get("/", include_in_schema=False)
    def root() -> RedirectResponse:
        return RedirectResponse("/live", status_code=307)

    registry = CollectorRegistry(auto_describe=False)
    registry.register(_SessionCollector(session))

    def requester(
        x_camd_client: str | None = Header(
            default=None, description="who asks (camctl sends user@host; --client NAME)"
        ),
    ) -> str:
        return client_name(x_camd_client)

    def controlled(wanted: str) -> Callable[[str], str]:
        """A dependency: the requesting client, once it is allowed to change the camera
        (nobody holds control, or it does); 423 not_in_control naming the holder if not."""

        def check(client: str = Depends(requester)) -> str:
            session.control.check(client, wanted)
            return client

        return check

    def token_ok(
        header: str, query_token: str | None = None, cookie_token: str | None = None
    ) -> bool:
        """The request carries the daemon's token: ``Authorization: Bearer <token>``; or, from
        a browser, which cannot add that header to a page, a script or a WebSocket, the
        ``camd_token`` cookie or ``?token=<token>``."""
        scheme, _, given = header.partition(" ")
        if scheme.lower() == "bearer":
            candidate = given.strip()
        elif query_token is not None:  # asked for now, so it wins over an older cookie
            candidate = query_token
        elif cookie_token is not None:
            candidate = cookie_token
        else:
            return False
        # compare_digest: the time taken must not reveal how much of a guess was right.
        return hmac.compare_digest(candidate.encode(), token.encode())

    @app.middleware("http")
    async def check_token(
        request: Request, call_next: Callable[[Request], Awaitable[Response]]
    ) -> Response:
        if not token:
            return await call_next(request)
        header = request.headers.get("authorization", "")
        query_token = request.query_params.get("token")
        if not token_ok(header, query_token, request.cookies.get(TOKEN_COOKIE)):
            given = header or query_token is not None or TOKEN_COOKIE in request.cookies
            refusal = error_response(
                401,
                "unauthorized",
                f"{'wrong token' if given else 'no token'}: send 'Authorization: Bearer "
                "<token>' with the daemon's api.token (camctl --token or $CAMD_TOKEN); in a "
                "browser, open /live?token=<token> once",
            )
            refusal.headers["WWW-Authenticate"] = "Bearer"
            return refusal
        response = await call_next(request)
        if query_token is not None and request.cookies.get(TOKEN_COOKIE) != token:
            # A page opened with ?token= keeps it in a cookie, so that its scripts, its API
            # calls and its WebSocket carry it (SameSite=Strict: never sent by another site).
            response.set_cookie(TOKEN_COOKIE, token, httponly=True, samesite="strict", path="/")
        return response

    # Outermost (added last): nothing reads a request before it is checked.
    app.add_middleware(
        RequestGuard,
        token=token,
        allowed_origins=session.config.api.allowed_origins,
        max_body_bytes=session.config.api.max_body_bytes,
    )

    @app.exception_handler(RequestValidationError)
    async def on_validation_error(request: Request, exc: RequestValidationError) -> JSONResponse:
        # In a worker thread: limit_now may ask the camera (never on the event loop).
        route = request.scope.get("route")
        message = await anyio.to_thread.run_sync(_validation_message, exc, route, limit_now)
        return error_response(400, "bad_request", message)

    def limit_now(name: str) -> str:
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

    @app.exception_handler(StarletteHTTPException)
    async def on_http_error(request: Request, exc: StarletteHTTPException) -> JSONResponse:
        code = {400: "bad_request", 404: "not_found", 405: "method_not_allowed"}.get(
            exc.status_code, "http_error"
        )
        message = str(exc.detail)
        path = cut(request.url.path)
        if exc.status_code == 404:
            message = f"no such endpoint {path}; see /docs or docs/api.md"
        elif exc.status_code == 405:
            allowed = _allowed_methods(app, request)
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

    @app.exception_handler(SessionError)
    async def on_session_error(request: Request, exc: SessionError) -> JSONResponse:
        return _map_error(exc)

    @app.exception_handler(IllegalState)
    async def on_illegal_state(request: Request, exc: IllegalState) -> JSONResponse:
        return _map_error(exc)

    @app.exception_handler(Exception)
    async def on_unexpected(request: Request, exc: Exception) -> JSONResponse:
        log.exception("unhandled error in %s %s", request.method, request.url.path)
        return error_response(
            500, "internal", f"internal error in camd: {type(exc).__name__}: {exc}; see its log"
        )

    @app.get(f"{API}/status", response_model=StatusResponse, tags=["status"])
    def get_status(client: str = Depends(requester)) -> StatusResponse:
        """State, reason, mode, link, the device's status, the daemon's identity, who holds
        control and the current or last acquisition."""
        return session.status(client)

    @app.get(f"{API}/control", response_model=ControlInfo, tags=["control"])
    def get_control(client: str = Depends(requester)) -> ControlInfo:
        """Who holds control (no device traffic); reading never needs control."""
        return session.control_info(client)

    @app.post(f"{API}/control", response_model=ControlInfo, tags=["control"])
    def post_control(
        body: ControlRequest | None = None, client: str = Depends(requester)
    ) -> ControlInfo:
        """Take control for ``ttl_s`` seconds, or renew it; 423 while another client holds
        it, unless ``force`` (a takeover, logged as an event)."""
        body = body or ControlRequest()
        session.take_control(client, body.ttl_s, force=body.force)
        return session.control_info(client)

    @app.delete(f"{API}/control", response_model=ControlInfo, tags=["control"])
    def delete_control(client: str = Depends(requester)) -> ControlInfo:
        """Give control back (harmless when this client holds none)."""
        session.control.release(client)
        return session.control_info(client)

    @app.put(f"{API}/control/activity", response_model=ControlInfo, tags=["control"])
    def put_control_activity(
        body: ActivityRequest, client: str = Depends(requester)
    ) -> ControlInfo:
        """Say what the controlling client is doing (a campaign's step, with steps done and
        in all), for observers: it shows in the control document until control is given back,
        expires or is taken over. Only the holder may: 423 while another client holds
        control, 409 ``no_control`` while nobody does."""
        session.control.set_activity(client, body.text, body.done, body.total)
        return session.control_info(client)

    @app.post(f"{API}/estop", response_model=EstopResponse, tags=["control"])
    def post_estop(client: str = Depends(requester)) -> EstopResponse:
        """Emergency stop of the stage (no ramp, current cut), the running acquisition, the
        filter wheel and a running campaign job (paused). Never refused, whoever asks and
        whatever holds control; it latches: nothing moves or acquires until a client with
        control releases it (``POST /api/v1/estop/release``)."""
        return session.estop(client)

    @app.get(f"{API}/estop", response_model=EstopState, tags=["control"])
    def get_estop() -> EstopState:
        """The emergency-stop latch: whether it holds, since when, who asked, what was stopped."""
        return session.estop_state()

    @app.post(f"{API}/estop/release", response_model=EstopState, tags=["control"])
    def post_estop_release(
        client: str = Depends(controlled("release the emergency stop")),
    ) -> EstopState:
        """Release the latch (needs control, or free control); the stage stays disabled and the
        wheel stopped until someone starts them. Harmless when not latched."""
        return session.release_estop(client)

    @app.get(f"{API}/campaigns/jobs", response_model=CampaignJobsResponse, tags=["campaigns"])
    def get_campaign_jobs() -> CampaignJobsResponse:
        """Every campaign job this daemon knows (jobs.json in its data directory), running or
        ended. Reading never needs control."""
        return session.campaign_jobs()

    @app.post(f"{API}/campaigns/jobs", response_model=CampaignJob, tags=["campaigns"])
    def post_campaign_job(
        body: CampaignStartRequest, client: str = Depends(requester)
    ) -> CampaignJob:
        """Start a campaign job: the campaign is loaded and checked whole in a worker process
        first (400 with the reason if it cannot run; nothing is started), then its worker
        starts and this returns at once. The requester's control (or free control) passes to
        the worker, ``campaign-job-<id>``, for the run. 409 while an acquisition or another
        job runs."""
        return session.start_campaign(body, client)

    @app.get(f"{API}/campaigns/jobs/{{job_id}}", response_model=CampaignJob, tags=["campaigns"])
    def get_campaign_job(job_id: int) -> CampaignJob:
        """One campaign job; 404 if there is none."""
        return session.campaign_job(job_id)

    @app.post(
        f"{API}/campaigns/jobs/{{job_id}}/pause", response_model=CampaignJob, tags=["campaigns"]
    )
    def post_campaign_pause(
        job_id: int, body: CampaignActionRequest, client: str = Depends(requester)
    ) -> CampaignJob:
        """Pause a running job: its acquisition is stopped at once (and done again on
        resume), its worker stops at the step boundary, puts the daemon's settings back and
        gives control back; the job is then ``paused``. Only its starter may, or anyone with
        ``force``. 409 unless it runs."""
        return session.pause_campaign(job_id, client, body.force)

    @app.post(
        f"{API}/campaigns/jobs/{{job_id}}/resume", response_model=CampaignJob, tags=["campaigns"]
    )
    def post_campaign_resume(job_id: int, client: str = Depends(requester)) -> CampaignJob:
        """Resume a paused, interrupted or failed-with-an-error job from its state file: the
        completed steps are replayed, the rest executed. Needs control, which passes to the
        worker as at the start."""
        return session.resume_campaign(job_id, client)

    @app.post(
        f"{API}/campaigns/jobs/{{job_id}}/abort", response_model=CampaignJob, tags=["campaigns"]
    )
    def post_campaign_abort(
        job_id: int, body: CampaignActionRequest, client: str = Depends(requester)
    ) -> CampaignJob:
        """Abort a job: a running one is stopped as for a pause, then ends ``aborted``; a
        paused one ends at once. Its files stay. Only its starter may, or anyone with
        ``force``."""
        return session.abort_campaign(job_id, client, body.force)

    @app.post(f"{API}/ping", response_model=PingResponse, tags=["link"])
    def post_ping(body: PingRequest | None = None) -> PingResponse:
        """PING the device ``count`` times with ``size`` random bytes; round-trip statistics."""
        body = body or PingRequest()
        return session.ping(body.count, body.size)

    @app.post(f"{API}/link/command", response_model=LinkCommandResponse, tags=["link"])
    def post_link_command(
        body: LinkCommandRequest, client: str = Depends(controlled("send a raw command"))
    ) -> LinkCommandResponse:
        """Send one COMMAND frame: a dictionary command with ``fields`` (checked by the
        dictionary) or any ``opcode`` with any ``payload_hex`` (unchecked), and return the
        device's ACK or NAK; ``repeat`` sends the identical frame again (same sequence number)
        to test at-most-once execution. For conformance tests (docs/conformance.md): the
        daemon's view of the camera is not updated, so put back what you change. Idle or in
        fault only."""
        with acting_as(client):
            return session.link_command(body)

    @app.get(f"{API}/link", response_model=LinkResponse, tags=["link"])
    def get_link() -> LinkResponse:
        """Host and device counters of the command link."""
        return session.link_stats()

    @app.get(f"{API}/telemetry", response_model=TelemetryResponse, tags=["telemetry"])
    def get_telemetry() -> TelemetryResponse:
        """Latest value of every housekeeping channel, with its limit level."""
        return session.telemetry()

    @app.get(f"{API}/telemetry/history", response_model=HistoryResponse, tags=["telemetry"])
    def get_history(
        channel: str = Query(description="telemetry channel, e.g. fpga_temp_degc"),
        since_s: float = Query(
            default=0.0,
            description="Unix time in seconds (the t_s clock); negative = seconds before now",
        ),
        limit: int = Query(default=1000, ge=1, le=HISTORY_LIMIT_MAX, description="newest N"),
    ) -> HistoryResponse:
        """Archived samples of one channel, oldest first."""
        return session.history(channel, since_s, limit)

    @app.get(f"{API}/events", response_model=EventsResponse, tags=["telemetry"])
    def get_events(
        limit: int = Query(default=100, ge=1, le=EVENTS_LIMIT_MAX, description="newest N"),
    ) -> EventsResponse:
        """Recent events (link, device, limits, state changes), newest last."""
        return session.events(limit)

    @app.get(
        f"{API}/live/frame",
        tags=["live"],
        response_class=Response,
        responses=_FRAME_RESPONSES,
    )
    def get_live_frame(
        after: int = Query(
            default=0, ge=0, description="wait for a frame newer than this seq (0: the newest)"
        ),
        timeout_s: float = Query(
            default=LIVE_WAIT_MAX_S, gt=0, le=LIVE_WAIT_MAX_S, description="longest wait, s"
        ),
    ) -> Response:
        """The live view's newest frame (at most 20 a second are kept, whatever streams):
        raw pixels, little-endian uint16, row by row; the header ``X-Camd-Frame`` holds its
        JSON description (seq, counter, timestamp_ns, mode, stages, rows, cols, skipped,
        gap_before, dtype). Reading never needs control. 404 if no frame newer than ``after``
        came within ``timeout_s``."""
        frame = session.live.latest() if after == 0 else session.live.wait_newer(after, timeout_s)
        if frame is None:
            newer = f" newer than seq {after} within {timeout_s:g} s" if after else " yet"
            return error_response(
                404,
                "no_frame",
                f"no live frame{newer}: the live view shows frames while something streams; "
                "start a stream (`camctl stream --frames 100`), a stare or a scan",
            )
        return Response(
            content=frame.pixels.astype("<u2", copy=False).tobytes(),
            media_type="application/octet-stream",
            headers={"X-Camd-Frame": json.dumps(frame.meta()), "Cache-Control": "no-store"},
        )

    @app.websocket(f"{API}/live/ws")
    async def live_ws(websocket: WebSocket) -> None:
        """The live view pushed: for each frame the tap keeps (at most 20 a second), a text
        message with its JSON description (as ``X-Camd-Frame``) then a binary one with its
        pixels. A slow viewer gets fewer frames (always the newest), never a backlog, and
        never slows the acquisition. With a token: ``?token=`` or the Authorization header."""
        if token and not token_ok(
            websocket.headers.get("authorization", ""),
            websocket.query_params.get("token"),
            websocket.cookies.get(TOKEN_COOKIE),
        ):
            await websocket.close(code=WS_POLICY_VIOLATION, reason="no or wrong token")
            return
        await websocket.accept()
        live = session.live

        async def watch_for_close(scope: anyio.CancelScope) -> None:
            # A viewer that goes away is noticed at once, not at the next frame.
            with contextlib.suppress(WebSocketDisconnect):
                while (await websocket.receive())["type"] != "websocket.disconnect":
                    pass
            scope.cancel()

        async with anyio.create_task_group() as group:
            group.start_soon(watch_for_close, group.cancel_scope)
            seq = 0
            try:
                while True:
                    frame = await anyio.to_thread.run_sync(
                        live.wait_newer, seq, LIVE_POLL_S, abandon_on_cancel=True
                    )
                    if frame is None:
                        continue
                    seq = frame.seq
                    await websocket.send_text(json.dumps(frame.meta()))
                    await websocket.send_bytes(frame.pixels.astype("<u2", copy=False).tobytes())
            except (WebSocketDisconnect, RuntimeError):  # gone between two frames
                group.cancel_scope.cancel()

    @app.get(f"{API}/live/background", response_model=BackgroundStatus, tags=["live"])
    def get_live_background() -> BackgroundStatus:
        """The live view's background: none, capturing (progress), ready (where it came from,
        its spatial mean and standard deviation, the recordings it was saved in) or failed
        (why). Reading never needs control."""
        return session.background_status()

    @app.post(f"{API}/live/background", response_model=BackgroundStatus, tags=["live"])
    def post_live_background(
        body: BackgroundRequest | None = None,
        client: str = Depends(controlled("capture a background")),
    ) -> BackgroundStatus:
        """Average the next ``frames`` frames of the running stream into the background, and
        return at once (poll GET). It replaces the background there was; every recording
        started while it is ready stores it as ``/background``. 409 when nothing streams
        (nothing changed then)."""
        body = body or BackgroundRequest()
        with acting_as(client):
            return session.capture_background(body.frames)

    @app.delete(f"{API}/live/background", response_model=BackgroundStatus, tags=["live"])
    def delete_live_background(
        client: str = Depends(controlled("clear the background")),
    ) -> BackgroundStatus:
        """Drop the background (and stop a capture); recordings no longer get one."""
        with acting_as(client):
            return session.clear_background()

    @app.get(
        f"{API}/live/background/frame",
        tags=["live"],
        response_class=Response,
        responses=_FRAME_RESPONSES,
    )
    def get_live_background_frame() -> Response:
        """The background: raw little-endian float32, row by row (DN, the mean of its frames);
        the header ``X-Camd-Background`` holds its JSON description (seq, frames, rows, cols,
        mode, stages, first_counter, last_counter, captured_t_s, mean_dn, std_dn, dtype).
        404 when none is ready."""
        background = session.background.ready()
        if background is None:
            state = session.background_status()
            why = {"capturing": "one is being captured", "failed": "the last capture failed"}
            return error_response(
                404,
                "no_background",
                f"no background is ready ({why.get(state.state, 'none was captured')}); "
                "capture one while something streams: POST /api/v1/live/background "
                '{"frames": 16}, then poll GET /api/v1/live/background',
            )
        return Response(
            content=background.pixels.astype("<f4", copy=False).tobytes(),
            media_type="application/octet-stream",
            headers={
                "X-Camd-Background": json.dumps(background.meta()),
                "Cache-Control": "no-store",
            },
        )

    @app.get(
        f"{API}/live/lines",
        tags=["live"],
        response_class=Response,
        responses=_FRAME_RESPONSES,
    )
    def get_live_lines(
        after: int = Query(
            default=-1, ge=-1, description="the last line index the viewer has (-1: none)"
        ),
        max_lines: int = Query(
            default=512, ge=1, le=LIVE_LINES_MAX, alias="max", description="most lines to send"
        ),
        timeout_s: float = Query(
            default=0.0,
            ge=0,
            le=LIVE_WAIT_MAX_S,
            description="with no line newer than after: longest wait for one, s",
        ),
    ) -> Response:
        """The live view's waterfall: the newest integrated lines of the running (or last)
        TDI scan with index > ``after``, at most ``max``, the newest ones. Raw little-endian
        float32, ``n`` x ``cols`` row by row; the header ``X-Camd-Lines`` holds their JSON
        description (scan, scan_seq, first_index, n, cols, index, complete, stages_used,
        skipped, lines_done, lines_planned, state, dtype). With none newer, waits up to
        ``timeout_s`` for one, then answers ``n`` = 0 with an empty body. 404 before the
        first scan. Reading never needs control."""
        lines = session.live_lines
        if timeout_s > 0:
            lines.wait_newer(after, timeout_s)
        chunk = lines.since(after, max_lines)
        if chunk is None:
            return error_response(
                404,
                "no_scan",
                "no scan has run since the daemon started: the live lines are those of the "
                "running or last TDI scan; start one (`camctl scan --stages 8 --lines 1000`)",
            )
        return Response(
            content=chunk.data.astype("<f4", copy=False).tobytes(),
            media_type="application/octet-stream",
            # Compact: with 2048 lines the flags and indices make a header of tens of kB.
            headers={
                "X-Camd-Lines": json.dumps(chunk.meta(), separators=(",", ":")),
                "Cache-Control": "no-store",
            },
        )

    @app.post(f"{API}/mode", response_model=ModeResponse, tags=["control"])
    def post_mode(
        body: ModeRequest, client: str = Depends(controlled("change the imaging mode"))
    ) -> ModeResponse:
        """Select area (staring) or tdi (push-broom) imaging mode; legal only when idle."""
        with acting_as(client):
            return session.set_mode(body.mode)

    @app.post(f"{API}/reset", response_model=StatusResponse, tags=["control"])
    def post_reset(client: str = Depends(controlled("reset the camera"))) -> StatusResponse:
        """Soft-reset the camera; clears a fault. Returns the status afterwards."""
        with acting_as(client):
            return session.reset()

    @app.get(f"{API}/registers", response_model=RegistersResponse, tags=["sensor"])
    def get_registers() -> RegistersResponse:
        """Every sensor register, read from the device (write-only ones from the host's copy)."""
        return session.sensor.dump()

    @app.post(f"{API}/registers", response_model=RegisterWriteResponse, tags=["sensor"])
    def post_registers(
        body: RegisterWriteRequest, client: str = Depends(controlled("write sensor registers"))
    ) -> RegisterWriteResponse:
        """Write registers by name: all validated first (nothing written if one is invalid),
        sent in one burst, read back and verified."""
        with acting_as(client):
            return session.sensor.write(dict(body.values))

    @app.post(f"{API}/registers/diff", response_model=RegisterDiffResponse, tags=["sensor"])
    def post_registers_diff(body: RegisterDiffRequest | None = None) -> RegisterDiffResponse:
        """Registers that differ from their reset values or from the given values."""
        body = body or RegisterDiffRequest()
        return session.sensor.diff(body.against, body.values)

    @app.get(f"{API}/registers/config", response_model=RegisterConfig, tags=["sensor"])
    def get_register_config() -> RegisterConfig:
        """The whole configuration (RW and WO non-volatile registers), for `camctl reg save`."""
        return session.sensor.configuration()

    @app.put(f"{API}/registers/config", response_model=RegisterWriteResponse, tags=["sensor"])
    def put_register_config(
        body: RegisterConfig, client: str = Depends(controlled("load a register configuration"))
    ) -> RegisterWriteResponse:
        """Load a whole configuration: refused whole if invalid or for another sensor."""
        with acting_as(client):
            return session.sensor.load_configuration(body)

    @app.get(f"{API}/registers/{{key}}", response_model=RegisterReading, tags=["sensor"])
    def get_register(key: str) -> RegisterReading:
        """One register by name (case-insensitive) or address (0x10 or 16)."""
        return session.sensor.read(key)

    @app.get(f"{API}/timing", response_model=TimingResponse, tags=["sensor"])
    def get_timing() -> TimingResponse:
        """Line period, exposure, frame time and window, from the sensor's registers."""
        return session.sensor.timing()

    @app.post(f"{API}/train", response_model=TrainResponse, tags=["sensor"])
    def post_train(client: str = Depends(controlled("train the sensor link"))) -> TrainResponse:
        """Train the sensor's LVDS link now; ``trained`` says whether it locked error-free."""
        with acting_as(client):
            return session.sensor.train()

    @app.get(f"{API}/train", response_model=TrainResponse, tags=["sensor"])
    def get_train() -> TrainResponse:
        """The last training result (no device traffic)."""
        return session.sensor.last_training()

    @app.get(f"{API}/stream", response_model=StreamResponse, tags=["stream"])
    def get_stream() -> StreamResponse:
        """The current or last stream: geometry, mode and the host's ingest counters."""
        return session.stream.status()

    @app.get(f"{API}/stream/headers", response_model=StreamHeadersResponse, tags=["stream"])
    def get_stream_headers() -> StreamHeadersResponse:
        """The headers of the first frames of the current or last stream, each with the
        payload CRC the host computed, including frames the payload CRC rejected."""
        return session.stream.headers()

    @app.post(f"{API}/stream/start", response_model=StreamResponse, tags=["stream"])
    def post_stream_start(
        body: StreamStartRequest | None = None, client: str = Depends(controlled("start a stream"))
    ) -> StreamResponse:
        """Start streaming and return at once; refused (409 link_untrained) on an untrained
        link. ``frames = 0`` streams until /stream/stop."""
        with acting_as(client):
            return session.stream.start(body or StreamStartRequest())

    @app.post(f"{API}/stream/acquire", response_model=StreamResponse, tags=["stream"])
    def post_stream_acquire(
        body: StreamStartRequest, client: str = Depends(controlled("start a stare"))
    ) -> StreamResponse:
        """Take ``frames`` frames (optionally recording them to HDF5) and return when done."""
        with acting_as(client):
            return session.stream.acquire(body)

    @app.post(f"{API}/stream/stop", response_model=StreamResponse, tags=["stream"])
    def post_stream_stop(client: str = Depends(controlled("stop the stream"))) -> StreamResponse:
        """Stop the stream; frames the device sent are drained first. Harmless when idle."""
        with acting_as(client):
            return session.stream.stop()

    @app.get(f"{API}/scan", response_model=ScanResponse, tags=["scan"])
    def get_scan() -> ScanResponse:
        """The current or last scan: progress, counters, timing (state "none" before one)."""
        return session.scan.status()

    @app.post(f"{API}/scan/start", response_model=ScanResponse, tags=["scan"])
    def post_scan_start(
        body: ScanRequest, client: str = Depends(controlled("start a scan"))
    ) -> ScanResponse:
        """Start a push-broom scan with host TDI and return at once (docs/scan.md)."""
        with acting_as(client):
            return session.scan.start(body)

    @app.post(f"{API}/scan/stop", response_model=ScanResponse, tags=["scan"])
    def post_scan_stop(client: str = Depends(controlled("stop the scan"))) -> ScanResponse:
        """Stop the running scan and return once its file is closed. Harmless when idle."""
        with acting_as(client):
            return session.scan.stop()

    @app.put(f"{API}/scan/stages", response_model=ScanResponse, tags=["scan"])
    def put_scan_stages(
        body: StagesRequest, client: str = Depends(controlled("change the scan's stages"))
    ) -> ScanResponse:
        """Change the TDI stage count of the running scan from its next frame."""
        with acting_as(client):
            return session.scan.set_stages(body.stages)

    @app.get(f"{API}/motion", response_model=MotionStatus, tags=["motion"])
    def get_motion() -> MotionStatus:
        """The scan stage: state, positions, speeds, limits, synchronisation settings."""
        return session.motion.status()

    @app.post(f"{API}/motion/enable", response_model=MotionStatus, tags=["motion"])
    def post_motion_enable(
        body: MotionEnableRequest, client: str = Depends(controlled("enable or release the stage"))
    ) -> MotionStatus:
        """Energise the motor (programs the configured limits first; clears an estop) or
        release it."""
        with acting_as(client):
            return session.motion.enable(body.on)

    @app.post(f"{API}/motion/run", response_model=MotionStatus, tags=["motion"])
    def post_motion_run(
        body: MotionRunRequest, client: str = Depends(controlled("run the stage"))
    ) -> MotionStatus:
        """Ramp to a constant signed speed and hold it (0 stops)."""
        with acting_as(client):
            return session.motion.run(body.speed_m_s)

    @app.post(f"{API}/motion/move", response_model=MotionStatus, tags=["motion"])
    def post_motion_move(
        body: MotionMoveRequest, client: str = Depends(controlled("move the stage"))
    ) -> MotionStatus:
        """Move to a position (metres from home) and stop; waits unless ``wait`` is false."""
        with acting_as(client):
            return session.motion.move(body)

    @app.post(f"{API}/motion/stop", response_model=MotionStatus, tags=["motion"])
    def post_motion_stop() -> MotionStatus:
        """Decelerate to a stop. Legal while streaming."""
        return session.motion.stop()

    @app.post(f"{API}/motion/home", response_model=MotionStatus, tags=["motion"])
    def post_motion_home(
        body: MotionHomeRequest | None = None, client: str = Depends(controlled("home the stage"))
    ) -> MotionStatus:
        """Find the home switch and zero the position there."""
        with acting_as(client):
            return session.motion.home((body or MotionHomeRequest()).wait)

    @app.post(f"{API}/motion/estop", response_model=MotionStatus, tags=["motion"])
    def post_motion_estop() -> MotionStatus:
        """Emergency stop: no ramp, motor current cut, until /motion/enable."""
        return session.motion.emergency_stop()

    @app.get(f"{API}/motion/sync", response_model=SyncResponse, tags=["motion"])
    def get_motion_sync(
        line_period_s: float | None = Query(default=None, gt=0.0, le=10.0),
        speed_m_s: float | None = Query(default=None, gt=0.0, le=10.0),
        stages: int | None = Query(default=None, ge=1, le=4096),
        binning: bool = False,
    ) -> SyncResponse:
        """Open-loop synchronisation (docs/physics.md §2 eqs 5-9, 13; §6 eq 9) for a line period, a
        stage speed, both (their mismatch), or neither (the registers' line period)."""
        return session.motion.sync(
            line_period_s=line_period_s, speed_m_s=speed_m_s, stages=stages, binning=binning
        )

    @app.get(f"{API}/wheel", response_model=WheelStatus, tags=["wheel"])
    def get_wheel() -> WheelStatus:
        """The filter wheel: speed, angle, compensation, and camd's T_frame / T_delay / fit /
        imaging-centre offset and eq-8 uncertainty for the exposure in the registers."""
        return session.wheel.status()

    @app.put(f"{API}/wheel/speed", response_model=WheelStatus, tags=["wheel"])
    def put_wheel_speed(
        body: WheelSpeedRequest,
        client: str = Depends(controlled("change the filter wheel's speed")),
    ) -> WheelStatus:
        """Turn the wheel at a constant speed (0 stops it); legal only when idle."""
        with acting_as(client):
            return session.wheel.set_speed(body.speed_deg_s)

    @app.put(f"{API}/wheel/compensation", response_model=WheelStatus, tags=["wheel"])
    def put_wheel_compensation(
        body: WheelCompensationRequest,
        client: str = Depends(controlled("change the wheel's delay compensation")),
    ) -> WheelStatus:
        """Exposure delay compensation on or off (docs/physics.md §4 eq 5); switching on is
        refused (400, with the numbers) when the exposure in the registers cannot fit."""
        with acting_as(client):
            return session.wheel.set_compensation(body.on)

    @app.post(f"{API}/wheel/acquire", response_model=WheelAcquireResponse, tags=["wheel"])
    def post_wheel_acquire(
        body: WheelAcquireRequest, client: str = Depends(controlled("start a wheel acquisition"))
    ) -> WheelAcquireResponse:
        """One frame per channel per pass, each started by its channel's entry pulse (plus
        T_delay with compensation); returns when done, with each frame's imaging-centre angle,
        its uncertainty (eq 8) and mean signal. Out-of-window exposures are refused (400)
        before anything is written."""
        with acting_as(client):
            return session.wheel.acquire(body)

    @app.put(f"{API}/sim/polarizer", status_code=204, tags=["simulator"])
    def put_sim_polarizer(
        body: PolarizerRequest, client: str = Depends(controlled("change the simulated polariser"))
    ) -> Response:
        """Simulated camera only: the reference polariser in front of the scene (docs/wheel.md);
        ``angle_deg`` null takes it out."""
        with acting_as(client):
            session.sim.set_polarizer(body.angle_deg)
            return Response(status_code=204)

    @app.put(f"{API}/sim/stage/faults", status_code=204, tags=["simulator"])
    def put_sim_stage_faults(
        body: SimStageFaultsRequest,
        client: str = Depends(controlled("change the simulated stage's faults")),
    ) -> Response:
        """Simulated camera only: the stepper stage's imperfections (as --inject stage_*)."""
        with acting_as(client):
            session.sim.set_stage_faults(body)
            return Response(status_code=204)

    @app.get(f"{API}/sim/stage/truth", response_model=SimStageTruth, tags=["simulator"])
    def get_sim_stage_truth() -> SimStageTruth:
        """Simulated camera only: the stage's true position, velocity and missed steps."""
        return session.sim.stage_truth()

    @app.put(f"{API}/sim/scene", status_code=204, tags=["simulator"])
    def put_sim_scene(
        body: SceneRequest, client: str = Depends(controlled("change the simulated scene"))
    ) -> Response:
        """Simulated camera only: the scene in front of it (docs/simulator.md)."""
        with acting_as(client):
            session.sim.set_scene(body.spec)
            return Response(status_code=204)

    @app.put(f"{API}/sim/seed", status_code=204, tags=["simulator"])
    def put_sim_seed(
        body: SeedRequest, client: str = Depends(controlled("re-seed the simulator"))
    ) -> Response:
        """Simulated camera only: restart the temporal noise and frame-fault random streams
        from ``seed`` (the fixed pattern is kept), so a repeated step sees the same noise."""
        with acting_as(client):
            session.sim.set_seed(body.seed)
            return Response(status_code=204)

    @app.put(f"{API}/sim/stage", response_model=StageResponse, tags=["simulator"])
    def put_sim_stage(
        body: StageRequest, client: str = Depends(controlled("change the simulator's ideal stage"))
    ) -> StageResponse:
        """Simulated camera only: the scan stage tracks the synchronous speed or runs at a set
        speed (any difference from synchronous is velocity mismatch)."""
        with acting_as(client):
            return session.sim.set_ideal_stage(track=body.track, speed_m_s=body.speed_m_s)

    @app.post(f"{API}/sim/fail-next", status_code=204, tags=["simulator"])
    def post_sim_fail_next(
        body: SimFailNextRequest,
        client: str = Depends(controlled("make a simulated command fail")),
    ) -> Response:
        """Simulated camera only: make the (skip + 1)-th next ``command`` fail, refused with a
        NAK of ``error`` or lost to a dropped line for ``duration_s`` (to test recovery)."""
        with acting_as(client):
            session.sim.fail_next(body)
            return Response(status_code=204)

    @app.delete(f"{API}/sim/fail-next", status_code=204, tags=["simulator"])
    def delete_sim_fail_next(
        client: str = Depends(controlled("make a simulated command fail")),
    ) -> Response:
        """Simulated camera only: disarm a failure armed with POST (harmless when none is)."""
        with acting_as(client):
            session.sim.clear_fail_next()
            return Response(status_code=204)

    @app.get(f"{API}/sim", response_model=SimSettings, tags=["simulator"])
    def get_sim() -> SimSettings:
        """What this daemon last set on the simulated camera: scene, ideal stage, polariser,
        stage faults (``available`` false on hardware)."""
        return session.sim.settings()

    @app.get(f"{API}/sim/stream", response_model=SimStreamStats, tags=["simulator"])
    def get_sim_stream() -> SimStreamStats:
        """Simulated camera only: frames its stream engine made, sent and damaged on purpose."""
        return session.sim.stream_stats()

    @app.get("/metrics", tags=["status"], response_class=Response)
    def get_metrics() -> Response:
        """Prometheus text exposition: link counters, telemetry, state."""
        return Response(generate_latest(registry), media_type=CONTENT_TYPE_LATEST)

    return app


def _map_error(exc: Exception) -> JSONResponse:
    for kind, status, code in ERROR_MAP:
        if isinstance(exc, kind):
            return error_response(status, code, str(exc))
    return error_response(500, "internal", str(exc))
