"""/docs works on a test PC with no internet: the daemon serves Swagger UI from camd.web.

Over a real daemon on loopback (simulated camera): the page names only the daemon's own paths,
each is served, and the script and style sheet are the files shipped in the package.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest

from camd import web
from tests.browser import PageLog, artifacts_dir
from tests.test_sensor_stack import serve

SHIPPED = web.STATIC_DIR / "vendor" / "swagger-ui"


@pytest.fixture(scope="module")
def url(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    with serve(tmp_path_factory.mktemp("camd-docs"), "fpga") as daemon:
        yield daemon.url


def test_docs_page_loads_only_from_the_daemon(url: str) -> None:
    with httpx.Client(base_url=url, timeout=30) as http:
        page = http.get("/docs")
        assert page.status_code == 200 and page.headers["content-type"].startswith("text/html")
        refs = re.findall(r'(?:src|href)="([^"]+)"', page.text)
        assert refs, page.text
        assert "http://" not in page.text.replace(url, "") and "https://" not in page.text
        assert all(r.startswith("/") and not r.startswith("//") for r in refs), refs
        for ref in refs:
            answer = http.get(ref)
            assert answer.status_code == 200, ref
            shipped = SHIPPED / Path(ref).name
            assert answer.content == shipped.read_bytes(), ref
        assert {Path(r).name for r in refs} == {
            "swagger-ui-bundle.js",
            "swagger-ui.css",
            "favicon-32x32.png",
        }
        # The page's schema is the daemon's own.
        assert "'/openapi.json'" in page.text or '"/openapi.json"' in page.text
        assert http.get("/openapi.json").json()["info"]["title"] == "camd"


def test_the_cdn_pages_are_gone(url: str) -> None:
    with httpx.Client(base_url=url, timeout=30) as http:
        answer = http.get("/redoc")
    assert answer.status_code == 404
    assert answer.json()["error"] == "no such endpoint /redoc; see /docs or docs/api.md"


def test_the_shipped_swagger_ui_carries_its_licence_and_version() -> None:
    assert "Apache License" in (SHIPPED / "LICENSE").read_text()
    readme = (SHIPPED / "README.md").read_text()
    assert f"Swagger UI {web.SWAGGER_UI_VERSION}" in readme
    # The bundle announces its own version; it must be the one we say we ship.
    bundle = (SHIPPED / "swagger-ui-bundle.js").read_text(encoding="utf-8")
    assert f'"{web.SWAGGER_UI_VERSION}"' in bundle


def test_docs_render_in_a_real_browser_with_nothing_from_outside(
    url: str, page: tuple[Any, PageLog]
) -> None:
    """Swagger UI renders every operation of the schema, offline (OpenAPI 3.1 needs UI 5)."""
    tab, log = page
    tab.goto(f"{url}/docs")
    tab.wait_for_selector(".opblock", timeout=30_000)
    with httpx.Client(base_url=url, timeout=30) as http:
        schema = http.get("/openapi.json").json()
    operations = sum(len(methods) for methods in schema["paths"].values())
    assert len(tab.query_selector_all(".opblock")) == operations
    tab.screenshot(path=str(artifacts_dir() / "docs-swagger-ui.png"))
    assert log.errors == []
    assert log.off_loopback() == []
    assert f"{url}/static/vendor/swagger-ui/swagger-ui-bundle.js" in log.requests
