"""The viewers of ``camd bench live`` (camd/bench/live.py): WebSocket clients consuming the live
view as a page does, chromium pages of ``/live``, or regions of interest the daemon measures;
each attached for a B round and detached after it (``Viewers``).
"""

from __future__ import annotations

import contextlib
import json
import threading
import time
import zlib
from typing import Any, Protocol

from camd.web.chromium import CHROMIUM_ARGS, chromium_path

VIEWER_START_TIMEOUT_S = 60.0
LIVE_WS = "/api/v1/live/ws"
LIVE_PAGE = "/live"
INSTALL_BROWSER = (
    "install the test extra (pip install -e '.[test]') and Debian's chromium "
    "(apt-get install chromium; or set CAMD_CHROMIUM to its executable)"
)


class BenchError(RuntimeError):
    """The bench cannot run or a viewer failed; the message says what to change."""


# -- which viewers --------------------------------------------------------------------------


def browser_missing() -> str | None:
    """Why browser viewers cannot run here (None: they can)."""
    try:
        import playwright.sync_api  # noqa: F401
    except ImportError:
        return "the playwright package is not installed"
    if chromium_path() is None:
        return "no chromium found"
    return None


def default_kind() -> tuple[str, str]:
    """The viewer kind to use without ``--viewer-kind``, and why."""
    missing = browser_missing()
    if missing is None:
        return "browser", "chromium and playwright found"
    return "ws", f"{missing}: WebSocket viewers instead; for browser viewers, {INSTALL_BROWSER}"


# -- viewers --------------------------------------------------------------------------------


class Viewers(Protocol):
    """N viewers of one daemon's live view, attached for a B round and detached after it."""

    def attach(self) -> None:
        """Attach them all; return once each has received a frame (BenchError otherwise)."""

    def counts(self) -> list[int]:
        """Frames each viewer has received since it was attached."""

    def pause(self, seconds: float) -> None:
        """Wait ``seconds`` while the viewers run."""

    def detach(self) -> None:
        """Close them (BenchError if one failed while attached)."""

    def close(self) -> None:
        """Release everything (after the last round)."""


class _WsViewer:
    """One thread consuming the live WebSocket as a page does."""

    def __init__(self, url: str, deflate: bool, name: str) -> None:
        self.url = url
        self.deflate = deflate
        self.frames = 0
        self.bytes = 0  # descriptions and payloads, as the daemon sent them
        self.error: str | None = None
        self.contrast = (0, 0)  # the last frame's min and max
        self.first = threading.Event()
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, name=name, daemon=True)

    def _run(self) -> None:
        import numpy as np
        from websockets.sync.client import connect

        try:
            with connect(
                self.url,
                open_timeout=VIEWER_START_TIMEOUT_S,
                max_size=None,  # a frame may be several MB
                compression="deflate" if self.deflate else None,
            ) as ws:
                meta: dict[str, Any] | None = None
                while not self.stop.is_set():
                    try:
                        message = ws.recv(timeout=0.25)
                    except TimeoutError:
                        continue
                    if isinstance(message, str):
                        self.bytes += len(message)
                        meta = json.loads(message)
                        if "error" in meta:
                            raise BenchError(f"the daemon refused the transport: {meta['error']}")
                        continue
                    if meta is None:
                        raise BenchError("the live WebSocket sent pixels before their description")
                    raw = (
                        zlib.decompress(message)
                        if meta.get("compression") == "deflate"
                        else message
                    )
                    pixels = np.frombuffer(raw, dtype="<u2").reshape(meta["rows"], meta["cols"])
                    self.contrast = (int(pixels.min()), int(pixels.max()))
                    self.frames += 1
                    self.bytes += len(message)
                    self.first.set()
        except Exception as exc:
            self.error = f"{type(exc).__name__}: {exc}"
            self.first.set()


class WsViewers:
    """``ws`` viewers: one thread each (module docstring)."""

    def __init__(self, ws_url: str, n: int, *, deflate: bool) -> None:
        self.ws_url = ws_url
        self.n = n
        self.deflate = deflate
        self._viewers: list[_WsViewer] = []

    def attach(self) -> None:
        self._viewers = [
            _WsViewer(self.ws_url, self.deflate, f"camd-bench-viewer-{i}") for i in range(self.n)
        ]
        for viewer in self._viewers:
            viewer.thread.start()
        deadline = time.monotonic() + VIEWER_START_TIMEOUT_S
        for i, viewer in enumerate(self._viewers):
            if not viewer.first.wait(max(0.0, deadline - time.monotonic())):
                self.detach()
                raise BenchError(
                    f"viewer {i + 1} received no frame from {self.ws_url} within "
                    f"{VIEWER_START_TIMEOUT_S:g} s"
                )
            if viewer.error is not None:
                self.detach()
                raise BenchError(f"viewer {i + 1} of {self.ws_url}: {viewer.error}")

    def counts(self) -> list[int]:
        return [v.frames for v in self._viewers]

    def bytes(self) -> list[int]:
        """Bytes each viewer has been sent since it was attached."""
        return [v.bytes for v in self._viewers]

    def pause(self, seconds: float) -> None:
        time.sleep(seconds)

    def detach(self) -> None:
        for viewer in self._viewers:
            viewer.stop.set()
        for viewer in self._viewers:
            viewer.thread.join(10.0)
        errors = [f"viewer {i + 1}: {v.error}" for i, v in enumerate(self._viewers) if v.error]
        self._viewers = []
        if errors:
            raise BenchError("; ".join(errors))

    def close(self) -> None:
        if self._viewers:
            self.detach()


class RoiViewers:
    """``roi``: B defines ``n`` ROIs in the daemon (each 1/n of the window's columns, all its
    rows: the whole frame measured once) and deletes them after; a "viewer's" count is the
    frames the daemon measured, which must be every frame it received."""

    def __init__(self, client: Any, n: int, rows: int, cols: int = 2048) -> None:
        self.client = client
        self.n = n
        self.rows = rows
        self.width = max(1, cols // n)

    def attach(self) -> None:
        for i in range(self.n):
            self.client.add_roi(f"bench{i}", i * self.width, 0, self.width, self.rows)
        deadline = time.monotonic() + VIEWER_START_TIMEOUT_S
        while self.client.roi_stats()["measured"] == 0:
            if time.monotonic() > deadline:
                self.detach()
                raise BenchError(
                    f"the daemon measured no frame with {self.n} ROIs within "
                    f"{VIEWER_START_TIMEOUT_S:g} s"
                )
            time.sleep(0.05)

    def counts(self) -> list[int]:
        return [int(self.client.roi_stats()["measured"])]

    def pause(self, seconds: float) -> None:
        time.sleep(seconds)

    def detach(self) -> None:
        for roi in self.client.rois()["rois"]:
            self.client.delete_roi(roi["name"])

    def close(self) -> None:
        self.detach()


class BrowserViewers:
    """``browser`` viewers: pages of the live page in one headless chromium (Playwright)."""

    def __init__(self, page_url: str, n: int) -> None:
        try:
            from playwright.sync_api import sync_playwright
        except ImportError:
            raise BenchError(
                f"browser viewers need the playwright package: {INSTALL_BROWSER}; "
                "or use --viewer-kind ws"
            ) from None
        path = chromium_path()
        if path is None:
            raise BenchError(f"no chromium found for browser viewers: {INSTALL_BROWSER}")
        self.page_url = page_url
        self.n = n
        self._playwright = sync_playwright().start()
        try:
            self._browser = self._playwright.chromium.launch(
                executable_path=path, args=CHROMIUM_ARGS
            )
        except Exception:
            self._playwright.stop()
            raise
        self._contexts: list[Any] = []
        self._pages: list[Any] = []
        self._frames: list[int] = []
        self._errors: list[str] = []

    def _watch(self, i: int, page: Any) -> None:
        # Only errors and crashes: listening to the page's WebSocket would have the browser
        # copy every frame to Playwright over the DevTools protocol, a cost no user's browser
        # has. The page counts its own frames (window.camdLive.framesReceived).
        page.on("pageerror", lambda exc: self._errors.append(f"page {i + 1}: {exc}"))
        page.on("crash", lambda _page: self._errors.append(f"page {i + 1} crashed"))

    def attach(self) -> None:
        self._frames = [0] * self.n
        self._errors = []
        for i in range(self.n):
            context = self._browser.new_context(viewport={"width": 1280, "height": 900})
            self._contexts.append(context)
            page = context.new_page()
            self._pages.append(page)
            self._watch(i, page)
            response = page.goto(self.page_url, timeout=VIEWER_START_TIMEOUT_S * 1e3)
            if response is None or not response.ok:
                status = "no answer" if response is None else f"HTTP {response.status}"
                self.detach_quietly()
                raise BenchError(
                    f"the live page {self.page_url} answered {status}: does this daemon serve "
                    "it? (--page names another; --viewer-kind ws needs no page)"
                )
        deadline = time.monotonic() + VIEWER_START_TIMEOUT_S
        while min(self.counts()) == 0:
            if time.monotonic() > deadline:
                silent = [str(i + 1) for i, n in enumerate(self._frames) if n == 0]
                errors = f" (page errors: {'; '.join(self._errors)})" if self._errors else ""
                self.detach_quietly()
                raise BenchError(
                    f"page(s) {', '.join(silent)} of {self.page_url} received no frame on "
                    f"{LIVE_WS} within {VIEWER_START_TIMEOUT_S:g} s{errors}"
                )
            self._pages[0].wait_for_timeout(100)  # runs Playwright's event loop

    def counts(self) -> list[int]:
        self._frames = [
            int(page.evaluate("window.camdLive?.framesReceived ?? 0")) for page in self._pages
        ]
        return list(self._frames)

    def pause(self, seconds: float) -> None:
        self._pages[0].wait_for_timeout(seconds * 1e3)

    def detach_quietly(self) -> None:
        for context in self._contexts:
            with contextlib.suppress(Exception):  # already gone with its page
                context.close()
        self._contexts, self._pages = [], []

    def detach(self) -> None:
        errors = list(self._errors)
        self.detach_quietly()
        if errors:
            raise BenchError("; ".join(errors))

    def close(self) -> None:
        self.detach_quietly()
        try:
            self._browser.close()
        finally:
            self._playwright.stop()


# -- measuring ------------------------------------------------------------------------------
