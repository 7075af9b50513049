"""Control of the camera: who holds it, taking and giving it back, saying what the holder does,
and holding it for a ``with`` block (docs/api.md, Control)."""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Iterator
from typing import Unpack, cast

from camd.client.connection import API, UNSET, CamdError, HttpClient, Unset, given
from camd.client_requests import ControlRequestOptions
from camd.client_types import ControlInfo


class ControlClient(HttpClient):
    """The client of the control routes."""

    def control(self) -> ControlInfo:
        """Who holds control (reading needs none)."""
        return cast(ControlInfo, self._json("GET", f"{API}/control"))

    def take_control(
        self, ttl_s: float | Unset = UNSET, **options: Unpack[ControlRequestOptions]
    ) -> ControlInfo:
        """Take (or renew) control for ``ttl_s`` seconds (not given: the daemon's lease);
        CamdError ``not_in_control`` while another client holds it, unless ``force`` (a
        takeover the daemon logs)."""
        body = {**given(ttl_s=ttl_s), **options}
        return cast(ControlInfo, self._json("POST", f"{API}/control", json=body))

    def release_control(self) -> ControlInfo:
        """Give control back (harmless when this client holds none)."""
        return cast(ControlInfo, self._json("DELETE", f"{API}/control"))

    def set_activity(
        self, text: str, done: int | Unset | None = UNSET, total: int | Unset | None = UNSET
    ) -> ControlInfo:
        """Say what this client, holding control, is doing (``done`` of ``total`` steps), for
        observers to see in the control document until control is given back or taken over.
        CamdError ``not_in_control`` while another client holds control, ``no_control`` while
        nobody does."""
        body = {"text": text, **given(done=done, total=total)}
        return cast(ControlInfo, self._json("PUT", f"{API}/control/activity", json=body))

    @contextlib.contextmanager
    def holding_control(self, ttl_s: float = 60.0, *, force: bool = False) -> Iterator[ControlInfo]:
        """Hold control for a ``with`` block (a campaign, a script): taken at the start,
        renewed in the background every ``ttl_s / 3``, given back at the end."""
        # ttl_s is the client's as well as the daemon's: it sets how often to renew, which the
        # client must know before the daemon's first answer.
        doc = self.take_control(ttl_s, force=force)
        stop = threading.Event()
        renewer = ControlClient(self.url, timeout_s=self.timeout_s, client=self.client)
        renewer._http.headers.update(self._http.headers)

        def renew() -> None:
            while not stop.wait(ttl_s / 3):
                with contextlib.suppress(CamdError):
                    renewer.take_control(ttl_s)

        thread = threading.Thread(target=renew, name="camd-control-renew", daemon=True)
        thread.start()
        try:
            yield doc
        finally:
            stop.set()
            thread.join(5.0)
            renewer.close()
            with contextlib.suppress(CamdError):
                self.release_control()
