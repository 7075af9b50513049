"""The instrument as a whole: status and readiness, imaging mode, reset, the command link (ping,
raw frames, counters), telemetry and events, emergency stop, metrics."""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any, Unpack, cast

from camd.client.connection import (
    API,
    UNSET,
    CamdError,
    DaemonUnreachable,
    HttpClient,
    Unset,
    given,
)
from camd.client_requests import LinkCommandRequestOptions, PingRequestOptions
from camd.client_types import (
    EstopResponse,
    EstopState,
    EventsResponse,
    HistoryResponse,
    LinkCommandResponse,
    LinkResponse,
    ModeResponse,
    PingResponse,
    StatusResponse,
    TelemetryResponse,
)

# Upper bound on one ping's wall time used to size the HTTP timeout of a ping run: the daemon
# pings strictly one at a time and a lost frame costs at most a few link timeouts of ~0.1 s, so
# a long run must not be cut off by the client's ordinary per-request timeout.
_PING_ALLOWANCE_S = 0.05


class DeviceClient(HttpClient):
    """The client of the instrument's routes: status, mode, reset, the command link, telemetry
    and events, emergency stop, metrics."""

    def status(self) -> StatusResponse:
        """The daemon's state, mode, link, device status and identity."""
        return cast(StatusResponse, self._json("GET", f"{API}/status"))

    def ping(
        self, count: int | Unset = UNSET, **options: Unpack[PingRequestOptions]
    ) -> PingResponse:
        """Have the daemon ping the device ``count`` times with ``size``-byte payloads (not
        given: the daemon's defaults, docs/api.md)."""
        # A run of the daemon's default count (a few pings) fits the ordinary timeout.
        pings = 0 if isinstance(count, Unset) else max(count, 0)
        timeout = self.timeout_s + _PING_ALLOWANCE_S * pings
        body = {**given(count=count), **options}
        return cast(PingResponse, self._json("POST", f"{API}/ping", json=body, timeout=timeout))

    def link_command(
        self,
        command: str | Unset | None = UNSET,
        *,
        payload: bytes | None = None,
        **options: Unpack[LinkCommandRequestOptions],
    ) -> LinkCommandResponse:
        """Send one COMMAND frame (POST /api/v1/link/command): ``command`` by name with
        ``fields`` (checked by the dictionary), or any ``opcode`` / ``payload`` unchecked; with
        ``repeat`` the identical frame goes twice. Returns the ACK or NAK (both with repeat);
        a NAK is an answer here, not an error. Needs control."""
        body: dict[str, Any] = {**given(command=command), **options}
        if payload is not None:
            body["payload_hex"] = payload.hex()
        return cast(LinkCommandResponse, self._json("POST", f"{API}/link/command", json=body))

    def link(self) -> LinkResponse:
        """Host and device counters of the command link."""
        return cast(LinkResponse, self._json("GET", f"{API}/link"))

    def telemetry(self) -> TelemetryResponse:
        """Latest value of every telemetry channel, sample count and archive path."""
        return cast(TelemetryResponse, self._json("GET", f"{API}/telemetry"))

    def history(
        self,
        channels: str | Sequence[str],
        since_s: float | None = None,
        limit: int | None = None,
        *,
        start: str | None = None,
        end: str | None = None,
        bucket_s: float | None = None,
        source: str | None = None,
    ) -> HistoryResponse:
        """Archived samples of telemetry channels over a range (``start``, ``end``: ISO 8601,
        Unix seconds, ``now`` or before now like ``-10m``; default the last hour), each with
        its source, or min/mean/max/count per ``bucket_s``. ``since_s``: the older form of
        ``start``; ``limit``: the newest N samples per channel."""
        params = _history_params(channels, since_s, limit, start, end, bucket_s, source)
        return cast(HistoryResponse, self._json("GET", f"{API}/telemetry/history", params=params))

    def history_csv(
        self,
        channels: str | Sequence[str],
        *,
        start: str | None = None,
        end: str | None = None,
        bucket_s: float | None = None,
        source: str | None = None,
        limit: int | None = None,
    ) -> str:
        """The same history as CSV text (docs/api.md gives its columns)."""
        params = _history_params(channels, None, limit, start, end, bucket_s, source)
        params["format"] = "csv"
        return self._request("GET", f"{API}/telemetry/history", params=params).text

    def events(
        self,
        limit: int | None = None,
        *,
        start: str | None = None,
        end: str | None = None,
        levels: Sequence[str] | None = None,
        sources: Sequence[str] | None = None,
    ) -> EventsResponse:
        """Recent events, newest last: the newest ``limit`` in [start, end) of the ``levels``
        (info, warning, error) and ``sources`` given (none: all)."""
        params: dict[str, Any] = {}
        for key, value in (
            ("limit", limit),
            ("start", start),
            ("end", end),
            ("level", levels),
            ("source", sources),
        ):
            if value is not None:
                params[key] = list(value) if isinstance(value, list | tuple) else value
        return cast(EventsResponse, self._json("GET", f"{API}/events", params=params))

    def set_mode(self, mode: str) -> ModeResponse:
        """Select the imaging mode, ``area`` or ``tdi`` (the daemon checks the value)."""
        return cast(ModeResponse, self._json("POST", f"{API}/mode", json={"mode": mode}))

    def reset(self) -> StatusResponse:
        """Soft-reset the device; returns the status afterwards."""
        return cast(StatusResponse, self._json("POST", f"{API}/reset"))

    def metrics(self) -> str:
        """The Prometheus text exposition."""
        return self._request("GET", "/metrics").text

    def estop(self) -> EstopResponse:
        """Emergency stop (stage, acquisition, wheel, campaign job): never refused; it latches
        until ``release_estop``."""
        return cast(EstopResponse, self._json("POST", f"{API}/estop"))

    def estop_state(self) -> EstopState:
        """The emergency-stop latch."""
        return cast(EstopState, self._json("GET", f"{API}/estop"))

    def release_estop(self) -> EstopState:
        """Release the emergency-stop latch (needs control, or free control)."""
        return cast(EstopState, self._json("POST", f"{API}/estop/release"))

    def wait_ready(self, timeout_s: float = 10.0, *, poll_s: float = 0.1) -> StatusResponse:
        """Wait until the daemon answers and its camera is connected (state not
        ``disconnected``); return that status.

        Raises DaemonUnreachable if nothing answered within ``timeout_s``, CamdError (code
        ``timeout``) if the daemon answered but stayed disconnected, with its reason.
        """
        deadline = time.monotonic() + timeout_s
        last: CamdError | StatusResponse | None = None
        while True:
            try:
                doc = self.status()
                if doc.get("state") != "disconnected":
                    return doc
                last = doc
            except DaemonUnreachable as exc:
                last = exc
            if time.monotonic() >= deadline:
                break
            time.sleep(poll_s)
        if isinstance(last, CamdError):
            raise last
        reason = last.get("reason") if last is not None else None
        raise CamdError(
            f"the daemon at {self.url} is up but no camera connected within {timeout_s:g} s"
            f" ({reason or 'no reason given'}); check the camera link or start it with --sim",
            code="timeout",
        )


def _history_params(
    channels: str | Sequence[str],
    since_s: float | None,
    limit: int | None,
    start: str | None,
    end: str | None,
    bucket_s: float | None,
    source: str | None,
) -> dict[str, Any]:
    """The query of GET /telemetry/history, leaving out what is not given."""
    params: dict[str, Any] = {
        "channel": [channels] if isinstance(channels, str) else list(channels)
    }
    for key, value in (
        ("since_s", since_s),
        ("limit", limit),
        ("start", start),
        ("end", end),
        ("bucket_s", bucket_s),
        ("source", source),
    ):
        if value is not None:
            params[key] = value
    return params
