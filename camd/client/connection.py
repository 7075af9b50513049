"""What every part of the client shares: the connection to one daemon, its URL and name, the
errors, and ``UNSET``, the default of a request key the caller did not give.

``HttpClient`` holds the connection pool and turns every answer into a JSON dict or a
``CamdError``; each resource's client (``camd.client.stream.StreamClient``, ...) is an
``HttpClient`` with that resource's methods, and ``camd.client.CamdClient`` has them all.
"""

from __future__ import annotations

import enum
import getpass
import json
import os
import socket
from typing import Any, Final, Self

import httpx

DEFAULT_URL = "http://127.0.0.1:8422"
API = "/api/v1"
CLIENT_HEADER = "X-Camd-Client"


def default_client_name() -> str:
    """``user@host``: the name a client is known by for control unless told otherwise."""
    try:
        user = getpass.getuser()
    except (KeyError, OSError):
        user = str(os.getuid())
    return f"{user}@{socket.gethostname()}"


class Unset(enum.Enum):
    """The type of ``UNSET``."""

    UNSET = "UNSET"

    def __repr__(self) -> str:
        return "UNSET"


UNSET: Final = Unset.UNSET
"""The default of a method's parameter that is a request key (``ping``'s count): not given, so
not sent, and the daemon's request model supplies its default (each default is written once, in
the model; camd/client_requests.py)."""


def given(**values: object) -> dict[str, Any]:
    """``values`` but those left ``UNSET``: the request keys a caller gave."""
    return {key: value for key, value in values.items() if value is not UNSET}


# -- errors ---------------------------------------------------------------------------------------


class CamdError(Exception):
    """The daemon refused or failed a request.

    ``message`` is the API's ``error`` text (it says what to change), ``code`` its ``code``
    (``bad_request``, ``illegal_state``, ``device_nak``, ...; see docs/api.md) and
    ``http_status`` the HTTP status, or None when no HTTP answer was received.
    """

    def __init__(self, message: str, code: str = "error", http_status: int | None = None) -> None:
        super().__init__(message)
        self.message = message
        self.code = code
        self.http_status = http_status

    def __repr__(self) -> str:
        return (
            f"{type(self).__name__}({self.message!r}, code={self.code!r}, "
            f"http_status={self.http_status!r})"
        )


class DaemonUnreachable(CamdError):
    """Nothing answers at the daemon's URL (not running, wrong URL or port)."""

    def __init__(self, url: str, detail: str) -> None:
        super().__init__(
            f"no camd daemon answers at {url} ({detail}); is `camd serve` running? "
            "start it with `camd serve --sim`, or point --url / $CAMD_URL at it",
            code="unreachable",
            http_status=None,
        )
        self.url = url


# -- the connection -------------------------------------------------------------------------------


def normalise_url(url: str) -> str:
    """Return ``url`` with a scheme (``localhost:8422`` -> ``http://localhost:8422``), no trailing
    slash. Raises ValueError naming the URL if it cannot be an HTTP URL."""
    text = url.strip()
    if "://" not in text:
        text = "http://" + text
    try:
        parsed = httpx.URL(text)
    except httpx.InvalidURL as exc:
        raise ValueError(f"bad daemon URL {url!r} ({exc}); write e.g. {DEFAULT_URL}") from None
    if parsed.scheme not in ("http", "https") or not parsed.host:
        raise ValueError(f"bad daemon URL {url!r}; write e.g. {DEFAULT_URL}")
    return text.rstrip("/")


class HttpClient:
    """The connection to one camd daemon, which every resource's client shares.

    ``url`` defaults to ``$CAMD_URL``, else ``http://127.0.0.1:8422``; ``token`` to
    ``$CAMD_TOKEN`` (sent as ``Authorization: Bearer``). ``timeout_s`` bounds each request,
    except where a method says otherwise. ``client`` is the name the daemon knows this client by
    for control (``X-Camd-Client``): ``$CAMD_CLIENT``, else ``user@host``.
    """

    def __init__(
        self,
        url: str | None = None,
        *,
        token: str | None = None,
        timeout_s: float = 30.0,
        client: str | None = None,
    ) -> None:
        if timeout_s <= 0:
            raise ValueError(f"timeout_s must be > 0 seconds, got {timeout_s}")
        self.url = normalise_url(url or os.environ.get("CAMD_URL") or DEFAULT_URL)
        self.timeout_s = timeout_s
        self.client = client or os.environ.get("CAMD_CLIENT") or default_client_name()
        token = token if token is not None else os.environ.get("CAMD_TOKEN")
        headers = {"Accept": "application/json", CLIENT_HEADER: self.client}
        if token:
            headers["Authorization"] = f"Bearer {token}"
        self._http = httpx.Client(base_url=self.url, headers=headers, timeout=timeout_s)

    def close(self) -> None:
        """Close the connection pool."""
        self._http.close()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.url!r})"

    def _json(self, method: str, path: str, **kwargs: Any) -> dict[str, Any]:
        return json_document(method, path, self.url, self._request(method, path, **kwargs))

    def _request(self, method: str, path: str, **kwargs: Any) -> httpx.Response:
        try:
            response = self._http.request(method, path, **kwargs)
        except httpx.TransportError as exc:
            timeout = kwargs.get("timeout", self.timeout_s)
            raise transport_error(method, path, self.url, exc, timeout) from None
        if response.is_success:
            return response
        raise api_error(method, path, response)


def json_document(method: str, path: str, url: str, response: httpx.Response) -> dict[str, Any]:
    """The JSON object a successful answer from ``url`` carries; CamdError ``bad_response`` if
    it is not one. Shared with the asynchronous client of ``camd.bluesky``."""
    try:
        doc = response.json()
    except ValueError:
        raise CamdError(
            f"{method} {path}: the answer from {url} is not JSON "
            f"({_snippet(response.text)}); is this URL a camd daemon?",
            code="bad_response",
            http_status=response.status_code,
        ) from None
    if not isinstance(doc, dict):
        raise CamdError(
            f"{method} {path}: expected a JSON object from {url}, got {_snippet(doc)}",
            code="bad_response",
            http_status=response.status_code,
        )
    return doc


def transport_error(
    method: str, path: str, url: str, exc: httpx.TransportError, timeout: object
) -> CamdError:
    """The CamdError of a request that got no HTTP answer (``exc``, httpx's): nothing answers
    at ``url``, no answer within ``timeout`` (seconds, or an ``httpx.Timeout``), or a broken
    exchange. Shared with the asynchronous client of ``camd.bluesky``."""
    if isinstance(exc, httpx.ConnectError | httpx.ConnectTimeout):
        return DaemonUnreachable(url, _reason(exc))
    if isinstance(exc, httpx.TimeoutException):
        if isinstance(timeout, httpx.Timeout):  # a request that waits for an acquisition
            timeout = timeout.read
        within = f"{timeout:g} s" if isinstance(timeout, int | float) else "its timeout"
        return CamdError(
            f"{method} {path}: the daemon at {url} did not answer within "
            f"{within}; raise the timeout (camctl --timeout) or check the daemon's log",
            code="timeout",
        )
    # Connected but the exchange broke (daemon died mid-request, not an HTTP server).
    return CamdError(
        f"{method} {path}: the connection to {url} failed ({_reason(exc)}); "
        "check that the daemon is still running and that the URL is camd's",
        code="transport",
    )


def api_error(method: str, path: str, response: httpx.Response) -> CamdError:
    """Build the CamdError of a non-2xx answer from its {"error", "code"} body (shared with the
    asynchronous client of ``camd.bluesky``)."""
    try:
        body = response.json()
    except ValueError:
        body = None
    if isinstance(body, dict) and isinstance(body.get("error"), str):
        return CamdError(body["error"], str(body.get("code", "error")), response.status_code)
    if isinstance(body, dict) and "detail" in body:
        # A framework answer that bypassed camd's error handler (e.g. 404 for an unknown path).
        detail = body["detail"]
        text = detail if isinstance(detail, str) else json.dumps(detail)
        return CamdError(
            f"{method} {path}: HTTP {response.status_code}: {text}; is the daemon at "
            f"{response.url.copy_with(path='/')} a compatible camd version?",
            code="http_error",
            http_status=response.status_code,
        )
    return CamdError(
        f"{method} {path}: unexpected HTTP {response.status_code} "
        f"({_snippet(response.text) or 'empty body'}); is this URL a camd daemon?",
        code="http_error",
        http_status=response.status_code,
    )


def _reason(exc: Exception) -> str:
    text = str(exc).strip()
    return text or type(exc).__name__


def _snippet(value: object, limit: int = 120) -> str:
    text = value if isinstance(value, str) else repr(value)
    text = " ".join(text.split())
    return text if len(text) <= limit else text[: limit - 3] + "..."
