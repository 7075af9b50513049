"""Shared test configuration."""

from __future__ import annotations

import fcntl
import os
from collections.abc import Iterator

import pytest
from hypothesis import settings

# The browser fixtures (``browser``, ``page``) for the tests of the pages the daemon serves.
pytest_plugins = ["tests.browser"]

# No per-example deadline: CI machines are slow and shared; a slow example is not a failure.
settings.register_profile("camd", deadline=None)
settings.load_profile("camd")


@pytest.fixture(autouse=True)
def _cpu_share(
    request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory
) -> Iterator[None]:
    """Under pytest-xdist, a test marked ``exclusive`` runs while no other test does.

    Those tests stream or close a control loop in real time (lost frames, stream overruns,
    the stage loop's mismatch): another worker's test sharing the CPU makes them miss their
    deadlines, which is not what they test. Every test holds a lock shared; an exclusive one
    holds it alone (flock on a file in the session's base temp dir, which the workers share).
    Without xdist there is one process and nothing to share.
    """
    if "PYTEST_XDIST_WORKER" not in os.environ:
        yield
        return
    path = tmp_path_factory.getbasetemp().parent / "cpu-share.lock"
    exclusive = request.node.get_closest_marker("exclusive") is not None
    with open(path, "a") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX if exclusive else fcntl.LOCK_SH)
        try:
            yield
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)
