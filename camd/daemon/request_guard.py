"""Who may ask, and how much: the ASGI middleware in front of the whole API (docs/api.md,
"Browsers and untrusted clients"). ``RequestGuard`` refuses pages of other sites (Origin, and
Host without a token), bodyless changes without the client header, and bodies too large or
with too many JSON values, before the app sees the request.
"""

from __future__ import annotations

import ipaddress
import json
from collections.abc import Iterable
from urllib.parse import urlsplit

import anyio
from fastapi.responses import JSONResponse
from starlette.datastructures import Headers
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from camd.daemon.config_sections import normal_origin
from camd.daemon.error_body import WS_POLICY_VIOLATION, cut, error_response

__all__ = ["API", "EMERGENCY_STOPS", "JSON_VALUES_MAX", "RequestGuard", "json_values"]

API = "/api/v1"  # the API's prefix (camd.daemon.api serves under it)

SAFE_METHODS = frozenset({"GET", "HEAD", "OPTIONS"})
# Refused to a page of a foreign origin, but never for want of the client header or a JSON
# body: `curl -X POST .../api/v1/estop` from a shell must stop the camera.
EMERGENCY_STOPS = frozenset({f"{API}/estop", f"{API}/motion/estop", f"{API}/motion/stop"})

FOREIGN_ORIGIN = (
    "refused: this request comes from a page at {origin}, not one of this daemon's own pages; "
    "a page of another site may not use the camera, not even to stop it (`camctl estop`, the "
    "live view at /live and `curl -X POST .../api/v1/estop` always can). If the page is yours, "
    "add its origin to api.allowed_origins (docs/config.md)"
)
FOREIGN_HOST = (
    "refused: this request is addressed to {host}, a name that this daemon without a token "
    "does not answer to (a web page could point such a name at 127.0.0.1 to reach it); "
    "address it by IP (127.0.0.1) or as localhost, add the origin http://NAME:PORT to "
    "api.allowed_origins, or set api.token"
)
CLIENT_HEADER_REQUIRED = (
    "{method} {path} changes the camera, and this request has neither a JSON body "
    "(Content-Type: application/json) nor the X-Camd-Client header: send one of them (camctl, "
    "CamdClient and the live view always send X-Camd-Client). A web page of another site "
    "cannot send either without the daemon's leave, which it never gives"
)


JSON_VALUES_MAX = 1000  # values in one request body: no request of this API takes a hundred
PARSE_INLINE_MAX = 4096  # bytes: a JSON body this small is counted on the event loop


def json_values(body: bytes) -> int | None:
    """How many JSON values (objects, lists, scalars) ``body`` holds; None if it is not JSON
    (FastAPI's parser then says why)."""
    try:
        document = json.loads(body)
    except (ValueError, RecursionError):
        return None
    count, stack = 0, [document]
    while stack:
        value = stack.pop()
        count += 1
        if isinstance(value, dict):
            stack.extend(value.values())
        elif isinstance(value, list):
            stack.extend(value)
    return count


def _is_json(content_type: str | None) -> bool:
    """The media type is JSON: a type a browser sends cross-origin only after a preflight."""
    media = (content_type or "").partition(";")[0].strip().lower()
    return media == "application/json" or (
        media.startswith("application/") and media.endswith("+json")
    )


class RequestGuard:
    """ASGI middleware in front of the whole app: who may ask, and how much.

    A web page the user has open can make the browser send requests to 127.0.0.1; the daemon
    without a token would do what they say. So, before anything else runs:

    - without a token, a request addressed to a DNS name (Host) that is neither localhost nor
      a host of ``api.allowed_origins`` is refused (403 ``foreign_host``): a page that points
      its own name at 127.0.0.1 (DNS rebinding) is same-origin to the browser and would pass
      every check below;
    - a request with an Origin that is neither the daemon's own (the Origin matching the
      request's Host, on whatever address the daemon is reached by) nor listed in
      ``api.allowed_origins`` is refused (403 ``foreign_origin``), the live WebSocket's
      handshake included: a browser always names the page's origin on a cross-origin request
      and on a WebSocket;
    - a request that may change something (any method but GET, HEAD, OPTIONS) without Origin
      must carry a JSON body or the X-Camd-Client header (403 ``client_header_required``):
      both make a browser ask the daemon's leave first (a CORS preflight, never granted), so a
      browser that leaves Origin out cannot slip a bodyless POST through; the emergency stops
      are exempt;
    - a body longer than ``max_body_bytes`` is refused (413 ``too_large``): on its declared
      Content-Length before a byte of it is read, or, sent chunked, as soon as it passes the
      limit. The rest is read and dropped by the server, never kept; ``api.request_timeout_s``
      bounds how long (camd/daemon/serve.py). Bodies within the limit are read here whole and
      handed on;
    - a JSON body of more than JSON_VALUES_MAX values is refused (413 ``too_large``), counted
      on a worker thread when the body is large: FastAPI parses and validates a body on the
      event loop, and 64 KiB of invalid entries (4,700 of them) cost it 140 ms there, each
      (docs/api.md). What FastAPI then gets parses in a few ms and fails in a few at worst.

    Starlette's own body-limit middleware answers in plain text and lets the app run until it
    reads the body; this refuses before the app sees the request, with the API's error body.
    """

    def __init__(
        self,
        app: ASGIApp,
        *,
        token: str,
        allowed_origins: Iterable[str],
        max_body_bytes: int,
    ) -> None:
        self.app = app
        self.token = token
        self.allowed_origins = frozenset(normal_origin(o) for o in allowed_origins)
        self.allowed_hosts = frozenset(urlsplit(o).hostname for o in self.allowed_origins)
        self.max_body_bytes = max_body_bytes

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] not in ("http", "websocket"):
            await self.app(scope, receive, send)
            return
        headers = Headers(scope=scope)
        refusal = self._refusal(scope, headers)
        if refusal is not None:
            status, code, message = refusal
            if scope["type"] == "websocket":
                await _refuse_handshake(scope, send, status, code, message)
            else:
                await error_response(status, code, message)(scope, receive, send)
            return
        if scope["type"] == "websocket":
            await self.app(scope, receive, send)
        else:
            await self._with_bounded_body(scope, receive, send, headers)

    def _refusal(self, scope: Scope, headers: Headers) -> tuple[int, str, str] | None:
        """(status, code, message) when the request is refused here, else None."""
        host = headers.get("host")
        if not self.token and host is not None and not self._host_answered(host):
            return 403, "foreign_host", FOREIGN_HOST.format(host=cut(host))
        origin = headers.get("origin")
        if origin is not None and not self._origin_allowed(origin, scope, host):
            return 403, "foreign_origin", FOREIGN_ORIGIN.format(origin=cut(origin))
        if (
            scope["type"] == "http"
            and scope["method"] not in SAFE_METHODS
            and origin is None
            and scope["path"] not in EMERGENCY_STOPS
            and "x-camd-client" not in headers
            and not _is_json(headers.get("content-type"))
        ):
            message = CLIENT_HEADER_REQUIRED.format(method=scope["method"], path=cut(scope["path"]))
            return 403, "client_header_required", message
        return None

    def _host_answered(self, host: str) -> bool:
        """A Host a web page cannot have pointed at this daemon by DNS: an IP address,
        localhost (browsers resolve it, and *.localhost, to loopback themselves), or a host of
        an allowed origin."""
        try:
            name = urlsplit(f"//{host}").hostname
        except ValueError:
            return False
        if name is None:
            return False
        if name == "localhost" or name.endswith(".localhost") or name in self.allowed_hosts:
            return True
        try:
            ipaddress.ip_address(name)
        except ValueError:
            return False
        return True

    def _origin_allowed(self, origin: str, scope: Scope, host: str | None) -> bool:
        """``origin`` is the daemon's own (the page came from the address this request is
        addressed to) or listed in api.allowed_origins. "null" (a sandboxed or local file
        page) is neither."""
        try:
            given = normal_origin(origin)
        except ValueError:
            return False
        if given in self.allowed_origins:
            return True
        if host is None:
            return False
        scheme = {"ws": "http", "wss": "https"}.get(scope["scheme"], scope["scheme"])
        try:
            return given == normal_origin(f"{scheme}://{host}")
        except ValueError:
            return False

    async def _with_bounded_body(
        self, scope: Scope, receive: Receive, send: Send, headers: Headers
    ) -> None:
        """Read the body (at most max_body_bytes) and hand the request on; 413 past that."""
        declared = headers.get("content-length")
        chunked = "chunked" in headers.get("transfer-encoding", "").lower()
        if (declared is None or declared.strip() == "0") and not chunked:
            await self.app(scope, receive, send)  # no body
            return
        limit = self.max_body_bytes
        if declared is not None and int(declared) > limit:  # the server checked it is a number
            refusal = _too_large(
                f"{int(declared)} bytes, more than the {limit} this daemon takes "
                "(api.max_body_bytes)"
            )
            await refusal(scope, receive, send)
            return
        body = bytearray()
        more = True
        while more:
            event = await receive()
            if event["type"] == "http.disconnect":
                return  # the client went away: nobody to answer
            body += event.get("body", b"")
            more = event.get("more_body", False)
            if len(body) > limit:
                refusal = _too_large(
                    f"more than the {limit} bytes this daemon takes (api.max_body_bytes): it "
                    "was sent chunked and refused once it passed them"
                )
                await refusal(scope, receive, send)
                return
        if _is_json(headers.get("content-type")):
            if len(body) <= PARSE_INLINE_MAX:
                values = json_values(bytes(body))
            else:
                values = await anyio.to_thread.run_sync(json_values, bytes(body))
            if values is not None and values > JSON_VALUES_MAX:
                refusal = _too_large(
                    f"{values} JSON values (objects, lists, numbers, strings...), more than the "
                    f"{JSON_VALUES_MAX} this daemon takes"
                )
                await refusal(scope, receive, send)
                return
        await self.app(scope, _replay(bytes(body), receive), send)


def _too_large(what: str) -> JSONResponse:
    """413: the body is ``what``."""
    return error_response(
        413,
        "too_large",
        f"the request body is {what}; no request of this API needs that much: check what is "
        "being sent",
    )


def _replay(body: bytes, receive: Receive) -> Receive:
    """A receive that gives the body read already, then what the server says (a disconnect)."""
    given = False

    async def replayed() -> Message:
        nonlocal given
        if not given:
            given = True
            return {"type": "http.request", "body": body, "more_body": False}
        return await receive()

    return replayed


async def _refuse_handshake(scope: Scope, send: Send, status: int, code: str, text: str) -> None:
    """Refuse a WebSocket before it opens: an HTTP answer with the error body where the server
    can send one (the ASGI denial response), else a close (HTTP 403 on the wire)."""
    if "websocket.http.response" in scope.get("extensions", {}):
        body = json.dumps({"error": text, "code": code}).encode()
        await send(
            {
                "type": "websocket.http.response.start",
                "status": status,
                "headers": [
                    (b"content-type", b"application/json"),
                    (b"content-length", str(len(body)).encode()),
                ],
            }
        )
        await send({"type": "websocket.http.response.body", "body": body})
    else:
        await send({"type": "websocket.close", "code": WS_POLICY_VIOLATION, "reason": code})
