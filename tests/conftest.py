"""Shared test configuration."""

from __future__ import annotations

import os

import pytest
from hypothesis import settings

from camd.daemon.config import RECORD_DIRS_ENV

# The browser fixtures (``browser``, ``page``) for the tests of the pages the daemon serves; the
# ``daemon`` mark of the tests that start a process, and its check (the fast tier: -m "not daemon");
# the order the modules go to the workers (tests/schedule.py); the run's bytecode cache, warmed
# before the workers collect (tests/bytecode.py); how the workers share the CPU with the tests
# that must run alone (tests/cpu_share.py); the logs of the running daemons in a failed test's
# report (tests/daemon_logs.py).
pytest_plugins = [
    "tests.browser",
    "tests.tiers",
    "tests.schedule",
    "tests.bytecode",
    "tests.cpu_share",
    "tests.daemon_logs",
]

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


# No per-example deadline: CI machines are slow and shared; a slow example is not a failure.
settings.register_profile("camd", deadline=None)
settings.load_profile("camd")
