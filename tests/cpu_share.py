"""How the workers share the CPU with the ``exclusive`` tests (under pytest-xdist).

Those tests stream or close a control loop in real time (lost frames, stream overruns, the
stage loop's mismatch): another worker's test sharing the CPU makes them miss their deadlines,
which is not what they test. Every test holds a lock shared; an exclusive one holds it alone
(flock on a file named after the run, which the workers share). Without xdist there is one
process and nothing to share.

Every test passes a turnstile (a second lock) on its way in; an exclusive test holds the
turnstile while it waits and runs, so no test starts after it asked. Without it, flock would go
on granting the shared lock to the other workers' next tests, and the exclusive test's worker
could wait for as long as they kept one running.

An exclusive test waits for the tests then running on the other workers to end. Behind a long
one (a 32 s soak, a 20 s campaign job) the whole run stood still: in a timeline of a fresh-clone
run, 4 workers, the 9 exclusive tests ran 100 s and the workers stood 405 s in all between
tests, 201 s of it while no exclusive test ran (waiting behind other long tests). So the
exclusive tests go first: the modules that hold them are sent to the workers first
(tests/schedule.py), and a test of any other module that starts a process (marked ``daemon``,
tests/tiers.py: the long ones) starts only once every exclusive test of the run has ended; each
one that ends says so in a file the workers share. The tests that start no process (milliseconds
to a few seconds) run in between, in the time the other workers would stand idle, so an
exclusive test waits for short tests only. A worker's modules come in the order sent, so a
worker waiting there holds no exclusive test behind it; and if no exclusive test ends for
``GATE_STALL_S`` (a worker lost mid-test), the others go on.

While an exclusive test waits or runs, one test that starts no process may run beside it (one
at a time, on a lock of their own): that is at most one core's worth of numpy or parsing, less
than the two CPU hogs (``stress-ng --cpu 2``) beside which the whole suite, exclusive tests
included, must pass. In a fresh-clone run 114 tests (32 s of them) ran beside the exclusive
ones, in time three workers would otherwise have stood idle.

An exclusive test whose real-time part ends before the test does hands the lock back then with
the ``end_exclusive`` fixture, and counts as ended: for the rest it is the one test beside the
next exclusive test (the demo's campaigns, 18 s, no longer hold the other exclusive tests back).

A hook wrapping the whole test (setup, call, teardown) from outside, not a fixture: the waits
must not count against the test's timeout (pytest-timeout starts its clock inside this).
"""

from __future__ import annotations

import fcntl
import os
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TextIO

import pytest

MARK = "exclusive"
GATE_STALL_S = 300.0  # pytest-timeout's limit: an exclusive test that runs longer has failed
GATE_POLL_S = 0.25
STOPPING = "*"  # said by a worker whose session stops early (-x, --maxfail): the rest never run


def module_of(nodeid: str) -> str:
    return nodeid.split("::")[0]


def run_files(run: str) -> Path:
    """The base name of this run's shared files (``.lock``, ``.turnstile``, ``.beside``,
    ``.ended``)."""
    return Path(tempfile.gettempdir()) / f"camd-cpu-share-{run}"


class _Exclusive:
    """The run's exclusive tests, and the modules that hold them (the same in every worker:
    each collects the whole run)."""

    def __init__(self, items: list[pytest.Item]) -> None:
        self.tests = frozenset(i.nodeid for i in items if i.get_closest_marker(MARK))
        self.modules = frozenset(module_of(t) for t in self.tests)


_EXCLUSIVE = pytest.StashKey[_Exclusive]()
_END_EXCLUSIVE = pytest.StashKey[Callable[[], None]]()


def _exclusive(item: pytest.Item) -> _Exclusive:
    stash = item.config.stash
    if _EXCLUSIVE not in stash:
        stash[_EXCLUSIVE] = _Exclusive(item.session.items)
    return stash[_EXCLUSIVE]


def ended(base: Path) -> set[str]:
    try:
        return set(Path(f"{base}.ended").read_text(encoding="utf-8").split("\n")) - {""}
    except FileNotFoundError:
        return set()


def say_ended(base: Path, nodeid: str) -> None:
    # One short append (O_APPEND): the workers' lines do not mix.
    with open(f"{base}.ended", "a", encoding="utf-8") as f:
        f.write(nodeid + "\n")


def wait_for_the_exclusive_tests(base: Path, tests: frozenset[str]) -> None:
    seen = -1
    progress = time.monotonic()
    while True:
        done = ended(base)
        if tests <= done or STOPPING in done:
            return
        if len(done) != seen:
            seen, progress = len(done), time.monotonic()
        elif time.monotonic() - progress > GATE_STALL_S:
            return  # a worker lost mid-test: its test is failed; the run goes on
        time.sleep(GATE_POLL_S)


def _try(f: TextIO, how: int) -> bool:
    try:
        fcntl.flock(f, how | fcntl.LOCK_NB)
    except BlockingIOError:
        return False
    return True


@pytest.hookimpl(hookwrapper=True, tryfirst=True)
def pytest_runtest_protocol(item: pytest.Item) -> Iterator[None]:
    run = os.environ.get("PYTEST_XDIST_TESTRUNUID")
    if "PYTEST_XDIST_WORKER" not in os.environ or run is None:
        item.stash[_END_EXCLUSIVE] = lambda: None
        yield
        return
    base = run_files(run)
    runs = _exclusive(item)
    exclusive = item.nodeid in runs.tests
    starts_processes = item.get_closest_marker("daemon") is not None
    if starts_processes and not exclusive and module_of(item.nodeid) not in runs.modules:
        wait_for_the_exclusive_tests(base, runs.tests)
    beside = not starts_processes and not exclusive  # may run beside an exclusive test
    with (
        open(f"{base}.lock", "a") as lock,
        open(f"{base}.turnstile", "a") as turnstile,
        open(f"{base}.beside", "a") as one_beside,
    ):
        if beside and not _try(turnstile, fcntl.LOCK_EX):
            # An exclusive test waits or runs: one test that starts no process at a time runs
            # beside it, holding no lock but this one.
            fcntl.flock(one_beside, fcntl.LOCK_EX)
        else:
            if not beside:
                fcntl.flock(turnstile, fcntl.LOCK_EX)
            fcntl.flock(lock, fcntl.LOCK_EX if exclusive else fcntl.LOCK_SH)
            if not exclusive:
                fcntl.flock(turnstile, fcntl.LOCK_UN)
        said = False

        def end_exclusive() -> None:
            nonlocal said
            if not exclusive or said:
                return
            # The rest of it is the one test beside the next exclusive test (which may start
            # now, as may every other test).
            fcntl.flock(one_beside, fcntl.LOCK_EX)
            fcntl.flock(lock, fcntl.LOCK_UN)
            fcntl.flock(turnstile, fcntl.LOCK_UN)
            say_ended(base, item.nodeid)
            said = True

        item.stash[_END_EXCLUSIVE] = end_exclusive
        try:
            yield
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)
            fcntl.flock(turnstile, fcntl.LOCK_UN)  # held by an exclusive test still; else a no-op
            fcntl.flock(one_beside, fcntl.LOCK_UN)  # a no-op unless it ran beside one
            if exclusive and not said:
                say_ended(base, item.nodeid)
            if item.session.shouldfail or item.session.shouldstop:
                say_ended(base, STOPPING)  # the exclusive tests after this one will not run


@pytest.fixture
def end_exclusive(request: pytest.FixtureRequest) -> Callable[[], None]:
    """Call it where an ``exclusive`` test's real-time part ends: other tests may run beside
    the rest of it (tests/test_demo.py: the demo's campaigns, after its streams and scans)."""
    end: Callable[[], None] = request.node.stash[_END_EXCLUSIVE]
    return end


def pytest_configure(config: pytest.Config) -> None:
    # The controller names the run, so that it can remove the workers' shared files at its end.
    named = config.getoption("testrunuid", None) is not None
    if not hasattr(config, "workerinput") and not named and config.getoption("numprocesses", None):
        config.option.testrunuid = os.urandom(16).hex()


def pytest_unconfigure(config: pytest.Config) -> None:
    run = config.getoption("testrunuid", None)
    if run is None or hasattr(config, "workerinput"):
        return
    for suffix in (".lock", ".turnstile", ".beside", ".ended"):
        Path(f"{run_files(run)}{suffix}").unlink(missing_ok=True)
