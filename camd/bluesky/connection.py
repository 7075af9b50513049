"""The asynchronous connection of the bluesky devices to one daemon, and its control lease.

ophyd-async runs every device on bluesky's event loop, so the devices talk to the daemon with
``httpx.AsyncClient`` (never with ``camd.client``'s blocking client, which would stall the loop
and every other device with it). Errors are ``camd.client.CamdError`` with the daemon's own
words, built by the same functions as the blocking client's.

Control (docs/api.md, Control): a device takes the connection's lease when it is staged and
gives it back when unstaged; the connection holds one lease for all its devices (the first
stage takes it, the last unstage gives it back), renews it every third of its time to live while
any device holds it, and names itself in ``X-Camd-Client`` (``bluesky:user@host`` by default)
so that the daemon's refusals and events say who holds the camera.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
from collections.abc import Awaitable, Callable
from typing import Any, cast

import httpx

from camd.client.connection import (
    API,
    CLIENT_HEADER,
    DEFAULT_URL,
    CamdError,
    api_error,
    default_client_name,
    json_document,
    normalise_url,
    transport_error,
)
from camd.client_types import ControlInfo

log = logging.getLogger(__name__)

LEASE_TTL_S = 60.0  # the lease's time to live; renewed every third of it
CLIENT_PREFIX = "bluesky:"


class CamdConnection:
    """The daemon at ``url`` (default ``$CAMD_URL``, else http://127.0.0.1:8422) as the bluesky
    devices reach it: asynchronous HTTP, the token (``token``, default ``$CAMD_TOKEN``) and the
    client's name (``client``, default ``bluesky:user@host``), and the control lease its devices
    share. ``timeout_s`` bounds each request but an acquisition's, which the daemon bounds.

    One connection serves any number of devices of one daemon; create it anywhere, use it on
    bluesky's event loop (the HTTP client is made there, on first use).
    """

    def __init__(
        self,
        url: str | None = None,
        *,
        token: str | None = None,
        client: str | None = None,
        timeout_s: float = 30.0,
        lease_ttl_s: float = LEASE_TTL_S,
    ) -> None:
        if timeout_s <= 0:
            raise ValueError(f"timeout_s must be > 0 seconds, got {timeout_s}")
        if not 0 < lease_ttl_s <= 86400:
            raise ValueError(f"lease_ttl_s must be in (0, 86400] seconds, got {lease_ttl_s}")
        self.url = normalise_url(url or os.environ.get("CAMD_URL") or DEFAULT_URL)
        self.client = client or CLIENT_PREFIX + default_client_name()
        self.timeout_s = timeout_s
        self.lease_ttl_s = lease_ttl_s
        token = token if token is not None else os.environ.get("CAMD_TOKEN")
        self._headers = {"Accept": "application/json", CLIENT_HEADER: self.client}
        if token:
            self._headers["Authorization"] = f"Bearer {token}"
        self._http: httpx.AsyncClient | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._holders: set[str] = set()
        # bluesky stages a plan's devices at once: taking and giving back the lease must not
        # interleave (two takes would start two renewers, one of them never stopped).
        self._lease_lock: asyncio.Lock | None = None
        self._renewer: asyncio.Task[None] | None = None
        self.lease_error: CamdError | None = None  # why the last renewal failed, if it did

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.url!r}, client={self.client!r})"

    # -- requests --------------------------------------------------------------------------------

    def _client(self) -> httpx.AsyncClient:
        # An AsyncClient belongs to the loop it was first used on; bluesky's loop is the one.
        loop = asyncio.get_running_loop()
        if self._http is None or self._loop is not loop:
            self._http = httpx.AsyncClient(
                base_url=self.url, headers=self._headers, timeout=self.timeout_s
            )
            self._loop = loop
            self._lease_lock = asyncio.Lock()
        return self._http

    def _lock(self) -> asyncio.Lock:
        self._client()  # the lock belongs to the loop, as the HTTP client does
        assert self._lease_lock is not None
        return self._lease_lock

    async def request(
        self,
        method: str,
        path: str,
        body: dict[str, Any] | None = None,
        *,
        timeout: httpx.Timeout | float | None = None,
    ) -> dict[str, Any]:
        """``method`` ``/api/v1`` + ``path`` with the JSON ``body``; the answer's JSON object.
        CamdError with the daemon's message and code when it refuses or fails; ``timeout``
        (default ``timeout_s``) bounds the request."""
        full = f"{API}{path}"
        limit = self.timeout_s if timeout is None else timeout
        try:
            response = await self._client().request(method, full, json=body, timeout=limit)
        except httpx.TransportError as exc:
            raise transport_error(method, full, self.url, exc, limit) from None
        if not response.is_success:
            raise api_error(method, full, response)
        return json_document(method, full, self.url, response)

    async def get(self, path: str) -> dict[str, Any]:
        """GET ``/api/v1`` + ``path``."""
        return await self.request("GET", path)

    async def close(self) -> None:
        """Give back a lease still held and close the HTTP client."""
        if self._holders:
            self._holders.clear()
            await self._give_back()
        if self._http is not None:
            await self._http.aclose()
            self._http = None

    # -- control ---------------------------------------------------------------------------------

    @property
    def holders(self) -> frozenset[str]:
        """The devices that hold the lease now (staged)."""
        return frozenset(self._holders)

    async def hold_control(self, holder: str) -> None:
        """Hold control for ``holder`` (a device being staged): the first holder takes the lease
        (CamdError ``not_in_control`` naming who holds the camera when another client does),
        and the lease is renewed while anyone holds it."""
        async with self._lock():
            if not self._holders:
                await self._take()
                self._renewer = asyncio.get_running_loop().create_task(
                    self._renew(), name=f"camd-lease-{self.client}"
                )
            self._holders.add(holder)

    async def release_control(self, holder: str) -> None:
        """``holder`` (a device being unstaged) no longer needs control: the last one gives the
        lease back. Never raises: an unstage after an error must not hide that error (a lease
        that cannot be given back expires after ``lease_ttl_s``; a warning says so)."""
        async with self._lock():
            if holder not in self._holders:
                return
            self._holders.discard(holder)
            if not self._holders:
                await self._give_back()

    async def staged(self, holder: str, ready: Callable[[], Awaitable[None]]) -> None:
        """A device's stage: hold control for ``holder``, then ``ready()`` (the device's own
        staging); control given back if that fails."""
        await self.hold_control(holder)
        try:
            await ready()
        except BaseException:
            await self.release_control(holder)
            raise

    async def unstaged(self, holder: str, finish: Callable[[], Awaitable[None]]) -> None:
        """A device's unstage: ``finish()`` (the device's own unstaging), then control given
        back for ``holder`` whatever ``finish`` did."""
        try:
            await finish()
        finally:
            await self.release_control(holder)

    async def _take(self) -> ControlInfo:
        doc = await self.request("POST", "/control", {"ttl_s": self.lease_ttl_s})
        self.lease_error = None
        return cast(ControlInfo, doc)

    async def _give_back(self) -> None:
        if self._renewer is not None:
            self._renewer.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._renewer
            self._renewer = None
        try:
            await self.request("DELETE", "/control")
        except CamdError as exc:
            log.warning(
                "%s could not give control back (%s); the lease expires within %g s",
                self.client,
                exc.message,
                self.lease_ttl_s,
            )

    async def _renew(self) -> None:
        while True:
            await asyncio.sleep(self.lease_ttl_s / 3)
            try:
                await self._take()
            except CamdError as exc:
                # Taken over (force) or the daemon went away: the next request that needs
                # control is refused with the daemon's words; say it here as well.
                self.lease_error = exc
                log.warning("%s could not renew its control lease: %s", self.client, exc.message)


def holder_name(device: object) -> str:
    """A device's name as a holder of its connection's lease: unique among the devices."""
    name = getattr(device, "name", "") or type(device).__name__
    return f"{name}#{id(device):x}"
