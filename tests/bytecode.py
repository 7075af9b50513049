"""The run's bytecode: one cache for every process of the run, warmed before the workers collect.

Collecting the suite costs a process about 12 s of a core when nothing is compiled yet: Python
compiles camd's modules, and pytest rewrites the assertions of every test module (about half of
it). Measured on the 2-core machine: 12.4 s cold, 3.8 s with every module's bytecode already
kept. Each xdist worker collects the whole suite, so four workers compiled the same modules four
times at once (21-41 s before their first test).

So, before the workers start, the controller compiles once: a few ``pytest --collect-only``
processes, one per core, each on a share of the test files (collection compiles what it imports
and rewrites what it collects; nothing runs). The workers then find every module compiled.
A warm cache makes this a few seconds of stat calls and imports.

Where the environment says PYTHONDONTWRITEBYTECODE (keep the checkout free of __pycache__), the
bytecode goes to the pytest cache directory instead (PYTHONPYCACHEPREFIX, inherited by the
workers and by every daemon, simulated camera and camctl the tests start: about 200 starts
would otherwise each compile camd anew, 0.2-0.3 s of a core apiece). Python checks each cached
file against its source's time and size, so a stale cache only costs a compile.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

PREWARM_TIMEOUT_S = 300.0  # a cold collection takes about 15 s; a stuck one must not hold the run


def bytecode_dir(config: pytest.Config) -> Path:
    """The pytest cache's directory for it, kept between runs; without the cache (``-p
    no:cacheprovider``) one directory of this user's under the temporary directory, also kept
    (a new one per run would be left behind by every run)."""
    cache = getattr(config, "cache", None)
    if cache is not None:
        return Path(cache.mkdir("camd-bytecode"))
    where = Path(tempfile.gettempdir()) / f"camd-test-bytecode-{os.getuid()}"
    where.mkdir(mode=0o700, exist_ok=True)
    return where


def keep_bytecode(config: pytest.Config) -> None:
    if os.environ.get("PYTHONDONTWRITEBYTECODE") and not os.environ.get("PYTHONPYCACHEPREFIX"):
        where = str(bytecode_dir(config))
        del os.environ["PYTHONDONTWRITEBYTECODE"]
        os.environ["PYTHONPYCACHEPREFIX"] = where
        # This process too (a run without workers collects here).
        sys.pycache_prefix = where
        sys.dont_write_bytecode = False


def test_files(config: pytest.Config) -> list[Path]:
    """The test modules under the paths the run was given (its arguments, else testpaths)."""
    files: set[Path] = set()
    for arg in config.args:
        path = (config.invocation_params.dir / arg.split("::")[0]).resolve()
        if path.is_dir():
            files.update(path.rglob("test_*.py"))
        elif path.suffix == ".py" and path.is_file():
            files.add(path)
    return sorted(files)


def shares(files: list[Path], n: int) -> list[list[Path]]:
    """``files`` in ``n`` shares of about equal size, largest first."""
    groups: list[list[Path]] = [[] for _ in range(n)]
    sizes = [0] * n
    for size, f in sorted(((f.stat().st_size, f) for f in files), reverse=True):
        i = sizes.index(min(sizes))
        groups[i].append(f)
        sizes[i] += size
    return [g for g in groups if g]


def prewarm(config: pytest.Config, processes: int) -> None:
    files = test_files(config)
    if not files:
        return
    env = {k: v for k, v in os.environ.items() if k != "PYTEST_ADDOPTS"}
    command = [sys.executable, "-m", "pytest", "--collect-only", "-q", "-n", "0"]
    command += ["-p", "no:cacheprovider", "--rootdir", str(config.rootpath)]
    running = [
        subprocess.Popen(
            [*command, *map(str, share)],
            cwd=config.rootpath,
            env=env,
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        for share in shares(files, processes)
    ]
    for process in running:
        # Its errors are the run's own collection's to report: this only compiles.
        try:
            process.wait(timeout=PREWARM_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()


@pytest.hookimpl(trylast=True)
def pytest_configure(config: pytest.Config) -> None:
    if hasattr(config, "workerinput"):
        return  # a worker inherits the controller's environment, and finds the cache warm
    keep_bytecode(config)
    workers = config.getoption("numprocesses", None)
    if isinstance(workers, int) and workers >= 2 and not config.getoption("collectonly"):
        prewarm(config, processes=len(os.sched_getaffinity(0)))
