"""Shared test configuration."""

from __future__ import annotations

import fcntl
import os
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from hypothesis import settings

from camd.daemon.config import RECORD_DIRS_ENV

# The browser fixtures (``browser``, ``page``) for the tests of the pages the daemon serves; the
# ``daemon`` mark of the tests that start a process, and its check (the fast tier: -m "not daemon");
# the order the modules go to the workers (tests/schedule.py).
pytest_plugins = ["tests.browser", "tests.tiers", "tests.schedule"]

# The suite's daemons do not load the TDI kernels at start (daemon.tdi_warm_up, docs/config.md):
# most never scan, and a scan loads them itself; about a second of a core per daemon saved.
# tests/test_config.py starts one daemon with the warm-up, as shipped.
os.environ.setdefault("CAMD_TDI_WARM_UP", "0")
# Nor do their simulated cameras do their first frame's work when they start (compiled kernels,
# fixed pattern, noise bank; docs/simulator.md): the first stream does it, if there is one.
os.environ.setdefault("CAMD_SIM_WARM_UP", "0")


@pytest.fixture(scope="session", autouse=True)
def daemons_record_into_the_test_directories(tmp_path_factory: pytest.TempPathFactory) -> None:
    """The suite's daemons may write into this run's temporary directories (``tmp_path`` and
    the rest: a test records beside its own files, outside the daemon's data directory),
    allowed as an operator would, through ``daemon.record_dirs`` (``$CAMD_RECORD_DIRS``, which
    the daemons inherit; docs/config.md); nowhere else. tests/test_record_paths.py starts its
    daemon without it."""
    os.environ[RECORD_DIRS_ENV] = str(tmp_path_factory.getbasetemp())


@pytest.fixture(scope="session", autouse=True)
def started_processes_keep_their_bytecode(tmp_path_factory: pytest.TempPathFactory) -> None:
    """Where the environment says PYTHONDONTWRITEBYTECODE (keep the checkout free of
    __pycache__), every daemon, simulated camera and camctl the tests start compiled camd's
    modules anew: 0.2-0.3 s of a core at each of about 200 starts. They keep it in this run's
    temporary directory instead (PYTHONPYCACHEPREFIX), still outside the checkout."""
    if os.environ.get("PYTHONDONTWRITEBYTECODE") and not os.environ.get("PYTHONPYCACHEPREFIX"):
        del os.environ["PYTHONDONTWRITEBYTECODE"]
        os.environ["PYTHONPYCACHEPREFIX"] = str(tmp_path_factory.getbasetemp() / "bytecode")


# No per-example deadline: CI machines are slow and shared; a slow example is not a failure.
settings.register_profile("camd", deadline=None)
settings.load_profile("camd")


@pytest.hookimpl(hookwrapper=True, tryfirst=True)
def pytest_runtest_protocol(item: pytest.Item) -> Iterator[None]:
    """Under pytest-xdist, a test marked ``exclusive`` runs while no other test does.

    Those tests stream or close a control loop in real time (lost frames, stream overruns,
    the stage loop's mismatch): another worker's test sharing the CPU makes them miss their
    deadlines, which is not what they test. Every test holds a lock shared; an exclusive one
    holds it alone (flock on a file named after the run, which the workers share). Without
    xdist there is one process and nothing to share.

    Every test passes a turnstile (a second lock) on its way in; an exclusive test holds the
    turnstile while it waits and runs, so no test starts after it asked. Without it, flock
    would go on granting the shared lock to the other workers' next tests, and the exclusive
    test's worker could wait for as long as they kept one running.

    An exclusive test whose real-time part ends before the test does hands the lock back
    then with the ``end_exclusive`` fixture: it holds it shared, like any other test, for the
    rest.

    A hook wrapping the whole test (setup, call, teardown) from outside, not a fixture: the
    wait for the lock must not count against the test's timeout (pytest-timeout starts its
    clock inside this), since a test may wait minutes behind an exclusive one.
    """
    run = os.environ.get("PYTEST_XDIST_TESTRUNUID")
    if "PYTEST_XDIST_WORKER" not in os.environ or run is None:
        item.stash[_END_EXCLUSIVE] = lambda: None
        yield
        return
    base = Path(tempfile.gettempdir()) / f"camd-cpu-share-{run}"
    exclusive = item.get_closest_marker("exclusive") is not None
    with open(f"{base}.lock", "a") as lock, open(f"{base}.turnstile", "a") as turnstile:
        fcntl.flock(turnstile, fcntl.LOCK_EX)
        fcntl.flock(lock, fcntl.LOCK_EX if exclusive else fcntl.LOCK_SH)
        if not exclusive:
            fcntl.flock(turnstile, fcntl.LOCK_UN)

        def end_exclusive() -> None:
            fcntl.flock(lock, fcntl.LOCK_SH)  # the other workers' tests may start again
            fcntl.flock(turnstile, fcntl.LOCK_UN)

        item.stash[_END_EXCLUSIVE] = end_exclusive
        try:
            yield
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)
            fcntl.flock(turnstile, fcntl.LOCK_UN)  # held by an exclusive test still; else a no-op


_END_EXCLUSIVE = pytest.StashKey[Callable[[], None]]()


@pytest.fixture
def end_exclusive(request: pytest.FixtureRequest) -> Callable[[], None]:
    """Call it where an ``exclusive`` test's real-time part ends: other tests may run beside
    the rest of it (tests/test_demo.py: the demo's campaigns, after its streams and scans)."""
    return request.node.stash[_END_EXCLUSIVE]
