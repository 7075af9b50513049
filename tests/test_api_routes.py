"""The API's shape: routers per resource assembled by a short ``create_app``, and the control
check declared once per route that changes the camera (``needs_control``), never wrapped by hand.

In-process: the app ``camd serve`` builds, its session never started (no camera, no server).
"""

from __future__ import annotations

import inspect
import re
from pathlib import Path

import fastapi.routing
import pytest
from fastapi.routing import APIRoute

from camd.daemon import api
from camd.daemon.config import Config
from camd.daemon.routes.deps import ControlCheck
from camd.daemon.session import DeviceSession

ROUTES_DIR = Path(api.__file__).parent / "routes"

# Routes that change something and yet take no control, with why (docs/api.md, "Control").
NO_CONTROL = {
    "POST /api/v1/control": "taking control is how one gets it (423 while another holds it)",
    "DELETE /api/v1/control": "giving it back is harmless when one holds none",
    "PUT /api/v1/control/activity": "only the holder may; the session checks (423, 409)",
    "POST /api/v1/estop": "an emergency stop is never refused",
    "POST /api/v1/motion/stop": "stopping is never refused",
    "POST /api/v1/motion/estop": "an emergency stop is never refused",
    "POST /api/v1/ping": "a PING changes nothing",
    "POST /api/v1/registers/diff": "a comparison changes nothing",
    "POST /api/v1/campaigns/jobs": "control passes to the job's worker: the session checks",
    "POST /api/v1/campaigns/jobs/{job_id}/pause": "its starter or force: the session checks",
    "POST /api/v1/campaigns/jobs/{job_id}/resume": "control passes to the worker: the session checks",
    "POST /api/v1/campaigns/jobs/{job_id}/abort": "its starter or force: the session checks",
}


@pytest.fixture(scope="module")
def routes(tmp_path_factory: pytest.TempPathFactory) -> dict[str, APIRoute]:
    """``"METHOD /path"`` -> route, for every route of the app."""
    data_dir = tmp_path_factory.mktemp("camd-app")
    session = DeviceSession(Config.model_validate({"daemon": {"data_dir": str(data_dir)}}))
    app = api.create_app(session)
    # FastAPI from 0.137 keeps an included router as one entry of app.routes; its
    # iter_route_contexts (0.137.2) lists the routes inside.
    flatten = getattr(fastapi.routing, "iter_route_contexts", None)
    found = [c.original_route for c in flatten(app.routes)] if flatten else app.routes
    return {
        f"{method} {route.path}": route
        for route in found
        if isinstance(route, APIRoute)
        for method in sorted(route.methods)
    }


def control_checks(route: APIRoute) -> list[ControlCheck]:
    return [d.call for d in route.dependant.dependencies if isinstance(d.call, ControlCheck)]


def test_create_app_only_assembles() -> None:
    lines = inspect.getsource(api.create_app).splitlines()
    assert len(lines) < 80, f"create_app has {len(lines)} lines; it assembles routers only"


def test_the_app_has_its_routes(routes: dict[str, APIRoute]) -> None:
    assert len(routes) == 84  # 80 under /api/v1, /metrics, /live, /docs and /
    assert set(NO_CONTROL) <= set(routes)


def test_each_route_that_changes_the_camera_checks_control_once(
    routes: dict[str, APIRoute],
) -> None:
    unchecked = []
    for name, route in routes.items():
        checks = control_checks(route)
        if name.startswith("GET "):
            assert not checks, f"{name} reads, and reading never needs control"
        elif name in NO_CONTROL:
            assert not checks, f"{name} takes no control: {NO_CONTROL[name]}"
        elif len(checks) != 1:
            unchecked.append(f"{name}: {len(checks)} control checks")
        else:
            assert re.fullmatch(r"[a-z][a-z' -]+", checks[0].wanted), (name, checks[0].wanted)
    assert not unchecked, "declare dependencies=[needs_control('...')] once: " + "; ".join(
        unchecked
    )


def test_no_route_wraps_its_body_in_the_acting_client() -> None:
    # The client a route acts as is set by its control check (routes/deps.py), not by hand.
    wrapped = [
        path.name
        for path in sorted(ROUTES_DIR.glob("*.py"))
        if path.name != "deps.py" and "acting_as" in path.read_text(encoding="utf-8")
    ]
    assert not wrapped, f"routes that set the acting client themselves: {wrapped}"
