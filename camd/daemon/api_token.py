"""The API's token (docs/api.md, "Authentication"): with ``api.token`` set, every request
carries it, as ``Authorization: Bearer <token>`` or, from a browser, which cannot add that
header to a page, a script or a WebSocket, as the ``camd_token`` cookie or ``?token=<token>``.

``create_app`` keeps the token in ``app.state.token`` ("" for none).
"""

from __future__ import annotations

import hmac
from collections.abc import Awaitable, Callable

from fastapi import Request, Response

from camd.daemon.error_body import error_response

TOKEN_COOKIE = "camd_token"  # a browser's copy of the token (set by a page opened with ?token=)


def token_ok(
    token: str, header: str, query_token: str | None = None, cookie_token: str | None = None
) -> bool:
    """The request carries ``token``: in the ``Authorization`` header (``header``), or in
    ``?token=`` or the cookie."""
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


async def check_token(
    request: Request, call_next: Callable[[Request], Awaitable[Response]]
) -> Response:
    """HTTP middleware: 401 unauthorized without the app's token; a page opened with
    ``?token=`` gets it as a cookie."""
    token: str = request.app.state.token
    if not token:
        return await call_next(request)
    header = request.headers.get("authorization", "")
    query_token = request.query_params.get("token")
    if not token_ok(token, header, query_token, request.cookies.get(TOKEN_COOKIE)):
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
