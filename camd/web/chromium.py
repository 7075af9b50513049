"""Where the system's chromium is, and how to start it for the daemon's pages.

Used by the browser tests (tests/browser.py) and by ``camd bench live``'s browser viewers, both
through Playwright with the system browser's executable (Playwright's own browser download
needs servers a test PC cannot reach).
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

CHROMIUM_ARGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    # Nothing that phones home: on a closed network those connections are refused (and they
    # would count as requests leaving loopback in the tests).
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]
"""Headless chromium's command-line switches (Playwright adds ``--headless``)."""


def chromium_path() -> str | None:
    """Debian's chromium: ``$CAMD_CHROMIUM`` (None if that is not a file), else ``chromium`` or
    ``chromium-browser`` on PATH, else None."""
    given = os.environ.get("CAMD_CHROMIUM")
    if given:
        return given if Path(given).is_file() else None
    return shutil.which("chromium") or shutil.which("chromium-browser")
