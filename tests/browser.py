"""A real browser for the tests of the pages the daemon serves: Debian's chromium, driven by
Playwright for Python through the system browser's executable (Playwright's own browser download
is not used).

Without a chromium (``$CAMD_CHROMIUM``, else ``chromium`` or ``chromium-browser`` on PATH) or
without the playwright package, browser tests skip and say why; with ``CAMD_REQUIRE_BROWSER=1``
(set by .ci/run) that skip is a failure instead. Screenshots go to ``$CAMD_TEST_ARTIFACTS``
(default ``test-artifacts/`` in the checkout, ignored by git).
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

import pytest

from camd.web.chromium import CHROMIUM_ARGS, chromium_path

ROOT = Path(__file__).resolve().parents[1]


def artifacts_dir() -> Path:
    path = Path(os.environ.get("CAMD_TEST_ARTIFACTS") or ROOT / "test-artifacts")
    path.mkdir(parents=True, exist_ok=True)
    return path


def _unavailable(reason: str) -> None:
    if os.environ.get("CAMD_REQUIRE_BROWSER") == "1":
        pytest.fail(f"{reason}; CAMD_REQUIRE_BROWSER=1 makes this a failure, not a skip")
    pytest.skip(reason)


@dataclass
class PageLog:
    """What a page did: console errors and uncaught exceptions, and every URL it asked for."""

    errors: list[str] = field(default_factory=list)
    requests: list[str] = field(default_factory=list)

    def off_loopback(self) -> list[str]:
        """Requests to anything but the loopback address (data: and blob: URLs are local)."""
        return [
            url
            for url in self.requests
            if urlsplit(url).scheme not in ("data", "blob")
            and urlsplit(url).hostname not in ("127.0.0.1", "localhost", "::1")
        ]


@pytest.fixture(scope="module")
def browser() -> Iterator[Any]:
    """A headless chromium for the module (skips, or fails under CI, if there is none)."""
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        _unavailable("the playwright package is not installed: pip install -e '.[test]'")
    path = chromium_path()
    if path is None:
        _unavailable(
            "no chromium found: install Debian's chromium (apt-get install chromium) or set "
            "CAMD_CHROMIUM to its executable"
        )
    with sync_playwright() as playwright:
        launched = playwright.chromium.launch(executable_path=path, args=CHROMIUM_ARGS)
        try:
            yield launched
        finally:
            launched.close()


@pytest.fixture
def page(browser: Any) -> Iterator[tuple[Any, PageLog]]:
    """A new page and its log (console errors, page errors, requests)."""
    context = browser.new_context(viewport={"width": 1280, "height": 900})
    new = context.new_page()
    log = PageLog()
    new.on("console", lambda m: log.errors.append(m.text) if m.type == "error" else None)
    new.on("pageerror", lambda e: log.errors.append(str(e)))
    new.on("request", lambda r: log.requests.append(r.url))
    try:
        yield new, log
    finally:
        context.close()
