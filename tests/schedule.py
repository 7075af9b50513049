"""How many workers the suite runs on, and the order in which its modules go to them.

``-n auto`` (pyproject.toml) starts two workers per core the process may use: the suite waits
on real time (a simulated camera's frame periods, a stage's moves, a link's timeouts, daemons
starting) more than it computes. Measured on the 2-core machine: with 2 workers the cores were
24-74 % idle through the run (vmstat every 10 s), with 3 workers the run used 1.03 cores on
average (766 s of CPU in 743 s), with 4 workers 1.35 (747 s in 554 s), and every test passed.
``PYTEST_XDIST_AUTO_NUM_WORKERS=N`` or ``-n N`` chooses another number.

pytest runs with ``--dist loadscope --no-loadscope-reorder`` (pyproject.toml): each module (or
test class) goes whole to one worker, so its tests share the module's daemon, and the workers
take the modules in the order sorted here:

1. The modules with ``exclusive`` tests first. An exclusive test waits until no other test runs
   and the other workers wait while it runs (tests/cpu_share.py): a test that starts a process
   (marked ``daemon``, tests/tiers.py) in any other module starts only once every exclusive
   test has ended.
2. Then the modules that start no process: their tests are short (milliseconds to a few
   seconds), so the workers run them while the exclusive tests go on, and an exclusive test
   that asks for the CPU waits only for the short tests then running.
3. Then the rest, the longest first, from tests/module_seconds.json (each module's seconds in a
   recent run; a module not in it counts 1 s): a run does not end waiting on a long module that
   one worker started last while the others stand idle. xdist's own order (most tests first)
   put a 37 s module of 2 tests at the very end.

``pytest --record-module-seconds`` rewrites the file from the run it ends. Stale figures only
make the order less good; they never change what a test does.
"""

from __future__ import annotations

import json
import os
from collections import defaultdict
from pathlib import Path

import pytest

SECONDS_FILE = Path(__file__).parent / "module_seconds.json"
UNKNOWN_MODULE_S = 1.0
WORKERS_PER_CORE = 2
_SECONDS: defaultdict[str, float] = defaultdict(float)  # this process's run, by module


def module_of(nodeid: str) -> str:
    return nodeid.split("::")[0]


def recorded_seconds(path: Path = SECONDS_FILE) -> dict[str, float]:
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        return {}
    return {str(k): float(v) for k, v in data.items()}


def module_order(items: list[pytest.Item], seconds: dict[str, float]) -> list[pytest.Item]:
    """``items`` with their modules in the order above; each module's own order kept."""
    exclusive = {module_of(i.nodeid) for i in items if i.get_closest_marker("exclusive")}
    processes = {module_of(i.nodeid) for i in items if i.get_closest_marker("daemon")}

    def key(item: pytest.Item) -> tuple[bool, bool, float]:
        module = module_of(item.nodeid)
        return module not in exclusive, module in processes, -seconds.get(module, UNKNOWN_MODULE_S)

    return sorted(items, key=key)  # stable: a module's tests keep their order


@pytest.hookimpl(tryfirst=True)
def pytest_xdist_auto_num_workers(config: pytest.Config) -> int | None:
    if os.environ.get("PYTEST_XDIST_AUTO_NUM_WORKERS"):
        return None  # xdist's own hook reads it
    return WORKERS_PER_CORE * len(os.sched_getaffinity(0))


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption(
        "--record-module-seconds",
        action="store_true",
        help="write each module's seconds in this run to tests/module_seconds.json "
        "(the order modules go to the workers; tests/schedule.py)",
    )


@pytest.hookimpl(trylast=True)  # after tests/tiers.py has marked the tests that start processes
def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    items[:] = module_order(items, recorded_seconds())


def pytest_runtest_logreport(report: pytest.TestReport) -> None:
    # In the controller this sees every worker's reports (setup, call and teardown).
    _SECONDS[module_of(report.nodeid)] += report.duration


def pytest_sessionfinish(session: pytest.Session, exitstatus: int) -> None:
    config = session.config
    if not config.getoption("--record-module-seconds") or hasattr(config, "workerinput"):
        return
    seconds = recorded_seconds() | dict(_SECONDS)
    text = json.dumps({k: round(v, 1) for k, v in sorted(seconds.items())}, indent=1)
    SECONDS_FILE.write_text(text + "\n", encoding="utf-8")
