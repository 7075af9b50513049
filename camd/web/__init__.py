"""What the daemon serves to a browser: static files shipped in the package.

``static/`` is mounted at ``/static`` by the daemon's HTTP app (``camd.daemon.api``), under the
same token rule as the API. ``static/vendor/`` holds third-party front-end files exactly as
published (each folder with its licence and a README saying where it came from), so that every
page works with no internet: the test PC of a clean room has none.
"""

from __future__ import annotations

from pathlib import Path

STATIC_DIR = Path(__file__).resolve().parent / "static"
"""Served at ``/static``."""

SWAGGER_UI_VERSION = "5.35.0"
"""The Swagger UI shipped in ``static/vendor/swagger-ui`` (its README says how to update it)."""

SWAGGER_UI_URL = "/static/vendor/swagger-ui"
"""Where the daemon serves it."""

UPLOT_VERSION = "1.6.32"
"""The uPlot shipped in ``static/vendor/uplot`` (the live view's plots; its README says how to
update it)."""

LIVE_PAGE = STATIC_DIR / "live" / "index.html"
"""The live view, served at ``/live``; its scripts and styles sit beside it in ``static/live``."""
