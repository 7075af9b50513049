"""Push-broom scans with host TDI: start, follow, change the stage count, stop (docs/scan.md)."""

from __future__ import annotations

import time
from typing import Any, Unpack, cast

from camd.client.connection import API, CamdError, HttpClient
from camd.client_requests import ScanRequestOptions
from camd.client_types import ScanResponse


class ScanClient(HttpClient):
    """The client of the scan routes."""

    def scan(self) -> ScanResponse:
        """The current or last scan (``state`` "none" before the first)."""
        return cast(ScanResponse, self._json("GET", f"{API}/scan"))

    def start_scan(
        self, stages: int, lines: int, **options: Unpack[ScanRequestOptions]
    ) -> ScanResponse:
        """Start a push-broom scan of ``lines`` complete TDI lines at ``stages`` stages and
        return at once. ``options`` are ``ScanRequest``'s optional keys (camd/client_requests.py,
        with their defaults): only those given are sent, the daemon supplies the others.
        ``out`` is a path on the daemon's host (relative = in its data directory's scans;
        docs/api.md "Files"). The scan drives the stage at the synchronous speed
        (``drive_stage``), closed loop unless ``closed_loop`` is False (None: the config),
        offset by ``dv_over_v``."""
        body: dict[str, Any] = {"stages": stages, "lines": lines, **options}
        return cast(ScanResponse, self._json("POST", f"{API}/scan/start", json=body))

    def stop_scan(self) -> ScanResponse:
        """Stop the running scan; returns once its file is closed."""
        return cast(ScanResponse, self._json("POST", f"{API}/scan/stop"))

    def set_stages(self, stages: int) -> ScanResponse:
        """Change the running scan's TDI stage count from its next frame."""
        return cast(ScanResponse, self._json("PUT", f"{API}/scan/stages", json={"stages": stages}))

    def wait_scan(self, timeout_s: float | None = None, *, poll_s: float = 0.2) -> ScanResponse:
        """Poll until the current scan has ended; return its final document."""
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        while True:
            doc = self.scan()
            if doc["state"] not in ("starting", "running"):
                return doc
            if deadline is not None and time.monotonic() > deadline:
                raise CamdError(
                    f"the scan did not end within {timeout_s:g} s; see `camctl scan --status`",
                    "timeout",
                )
            time.sleep(poll_s)
