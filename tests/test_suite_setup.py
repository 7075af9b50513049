"""What the suite sets up for the processes its tests start (tests/conftest.py)."""

from __future__ import annotations

import fcntl
import os
import subprocess
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path

import pytest

import camd


def test_the_processes_the_tests_start_keep_their_bytecode() -> None:
    # About 100 daemons and their simulated cameras start in a run; where the environment says
    # PYTHONDONTWRITEBYTECODE, each compiled camd's modules anew (0.2-0.3 s of a core apiece).
    # The suite gives them a bytecode cache outside the checkout instead: a process that
    # imported a camd module leaves its compiled form for the next.
    source = Path(camd.__file__).resolve().parent / "paths.py"
    where = subprocess.run(
        [sys.executable, "-c", "import importlib.util as u, camd.paths as m; "
         "print(u.cache_from_source(m.__file__))"],
        capture_output=True, text=True, check=True, timeout=60,
    ).stdout.strip()  # fmt: skip
    assert Path(where).is_file(), f"no bytecode kept for {source} (looked for {where})"


@pytest.mark.exclusive
def test_an_exclusive_test_hands_the_cpu_back_where_it_says(
    end_exclusive: Callable[[], None],
) -> None:
    # Under xdist an exclusive test holds the run's lock alone and the turnstile with it
    # (tests/conftest.py); end_exclusive() leaves it the lock shared, as every test holds it,
    # so the other workers' tests start again. Without xdist there is no lock: a no-op.
    run = os.environ.get("PYTEST_XDIST_TESTRUNUID")
    if "PYTEST_XDIST_WORKER" not in os.environ or run is None:
        end_exclusive()
        return
    base = Path(tempfile.gettempdir()) / f"camd-cpu-share-{run}"

    def could(name: str, how: int) -> bool:
        with open(f"{base}.{name}", "a") as other:  # another open file: another holder
            try:
                fcntl.flock(other, how | fcntl.LOCK_NB)
            except BlockingIOError:
                return False
            fcntl.flock(other, fcntl.LOCK_UN)
            return True

    assert not could("lock", fcntl.LOCK_SH) and not could("turnstile", fcntl.LOCK_EX)
    end_exclusive()
    # Not whether the turnstile is free now: another worker's test may take it at once.
    assert could("lock", fcntl.LOCK_SH)
    assert not could("lock", fcntl.LOCK_EX)  # still held shared until the test ends
