"""The filter wheel: its state, speed and exposure delay compensation, and acquisitions of one
frame per channel (docs/wheel.md)."""

from __future__ import annotations

from typing import Any, Unpack, cast

import httpx

from camd.client.connection import API, UNSET, HttpClient, Unset
from camd.client_requests import WheelAcquireRequestOptions
from camd.client_types import WheelAcquireResponse, WheelRegion, WheelStatus


class WheelClient(HttpClient):
    """The client of the wheel routes."""

    def wheel(self) -> WheelStatus:
        """The filter wheel, with camd's numbers for the exposure in the registers."""
        return cast(WheelStatus, self._json("GET", f"{API}/wheel"))

    def set_wheel_speed(self, speed_deg_s: float) -> WheelStatus:
        """Turn the wheel at ``speed_deg_s`` (0 stops it)."""
        body = {"speed_deg_s": speed_deg_s}
        return cast(WheelStatus, self._json("PUT", f"{API}/wheel/speed", json=body))

    def set_wheel_compensation(self, on: bool) -> WheelStatus:
        """Exposure delay compensation on or off (refused if the exposure cannot fit)."""
        return cast(WheelStatus, self._json("PUT", f"{API}/wheel/compensation", json={"on": on}))

    def wheel_acquire(
        self,
        channels: list[int],
        *,
        region: WheelRegion | Unset | None = UNSET,
        **options: Unpack[WheelAcquireRequestOptions],
    ) -> WheelAcquireResponse:
        """One frame per channel per pass; returns each frame's imaging-centre angle, its
        uncertainty and mean. ``exposure_s`` / ``compensated`` are set first when given;
        ``record`` is a new HDF5 file on the daemon's host (as for ``acquire``); ``region`` the
        region whose mean each frame reports (not given: the whole frame)."""
        body: dict[str, Any] = {"channels": list(channels), **options}
        # region is a parameter of its own: it holds a document (client_types.WheelRegion).
        if not isinstance(region, Unset):
            body["region"] = None if region is None else dict(region)
        # The daemon bounds the acquisition itself (timeout_s, or per frame a revolution).
        timeout_s = options.get("timeout_s")
        read_s = None if timeout_s is None else timeout_s + 30.0
        timeout = httpx.Timeout(self.timeout_s, read=read_s)
        return cast(
            WheelAcquireResponse,
            self._json("POST", f"{API}/wheel/acquire", json=body, timeout=timeout),
        )
