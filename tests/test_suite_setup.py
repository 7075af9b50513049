"""What the suite sets up for its processes: their bytecode (tests/bytecode.py) and their share of
the CPU (tests/cpu_share.py)."""

from __future__ import annotations

import fcntl
import os
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pytest

import camd
from tests import bytecode, cpu_share, schedule


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
    # (tests/cpu_share.py); end_exclusive() gives both back, so the other workers' tests start
    # again, and holds the lock of the one test beside an exclusive one instead. Without
    # xdist there is no lock: a no-op.
    run = os.environ.get("PYTEST_XDIST_TESTRUNUID")
    if "PYTEST_XDIST_WORKER" not in os.environ or run is None:
        end_exclusive()
        return
    base = cpu_share.run_files(run)

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
    # Not whether the lock or the turnstile is free now: another worker's test may take them
    # at once. The rest of this test is the one test beside the next exclusive one.
    assert not could("beside", fcntl.LOCK_EX)
    assert os.environ["PYTEST_CURRENT_TEST"].split(" ")[0] in cpu_share.ended(base)


def test_the_gate_opens_once_every_exclusive_test_has_ended(tmp_path: Path) -> None:
    base = tmp_path / "run"
    tests = frozenset({"tests/test_a.py::test_x", "tests/test_b.py::test_y"})
    cpu_share.say_ended(base, "tests/test_a.py::test_x")
    assert cpu_share.ended(base) == {"tests/test_a.py::test_x"}
    cpu_share.say_ended(base, "tests/test_b.py::test_y")
    cpu_share.wait_for_the_exclusive_tests(base, tests)  # returns: both have ended
    assert cpu_share.ended(base) == tests


def test_the_gate_opens_when_no_exclusive_test_ends_for_the_stall_limit(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # A worker lost in the middle of an exclusive test never says it ended: the run goes on.
    monkeypatch.setattr(cpu_share, "GATE_STALL_S", 0.3)
    monkeypatch.setattr(cpu_share, "GATE_POLL_S", 0.05)
    cpu_share.wait_for_the_exclusive_tests(tmp_path / "run", frozenset({"tests/t.py::lost"}))


GATED_RUN = {
    "pytest.ini": "[pytest]\nmarkers =\n    exclusive: runs alone\n    daemon: starts one\n",
    "conftest.py": 'pytest_plugins = ["tests.schedule", "tests.cpu_share"]\n',
    "test_a_mixed.py": (
        "import os, time, pytest\n"
        "def log(what):\n"
        "    with open(os.environ['GATE_LOG'], 'a') as f:\n"
        "        f.write(f'{what} {time.time()!r}\\n')\n"
        "def test_first():\n"
        "    log('first_start'); time.sleep(1.5)\n"
        "@pytest.mark.exclusive\n"
        "def test_alone(tmp_path_factory):\n"
        "    log('alone_start')\n"
        "    flags = tmp_path_factory.getbasetemp().parent\n"
        "    (flags / 'alone.flag').touch()\n"
        "    deadline = time.monotonic() + 20\n"
        "    while not (flags / 'pure.flag').exists() and time.monotonic() < deadline:\n"
        "        time.sleep(0.05)\n"
        "    log('alone_end')\n"
        "    assert (flags / 'pure.flag').exists(), 'no test ran beside the exclusive one'\n"
    ),
    "test_c_pure.py": (
        "import time, pytest\n"
        "@pytest.mark.parametrize('n', range(60))\n"
        "def test_short(n, tmp_path_factory):\n"
        "    flags = tmp_path_factory.getbasetemp().parent\n"
        "    if (flags / 'alone.flag').exists():\n"
        "        (flags / 'pure.flag').touch()\n"
        "    time.sleep(0.1)\n"
    ),
    "test_b_other.py": (
        "import pytest\n"
        "from test_a_mixed import log\n"
        "@pytest.mark.daemon\n"
        "def test_one():\n    log('other_start')\n"
        "@pytest.mark.daemon\n"
        "def test_two():\n    log('other_start')\n"
    ),
}


def gated_run(
    tmp_path: Path, files: dict[str, str] = GATED_RUN, *options: str
) -> tuple[subprocess.CompletedProcess[str], Path]:
    """A pytest run on two workers of ``files`` with this suite's scheduling and CPU sharing;
    its result and the log its tests write."""
    for name, text in files.items():
        (tmp_path / name).write_text(text, encoding="utf-8")
    log = tmp_path / "log"
    repo = Path(__file__).resolve().parents[1]
    env = {**os.environ, "GATE_LOG": str(log), "PYTHONPATH": f"{repo}:{tmp_path}"}
    env.pop("PYTEST_ADDOPTS", None)
    env.pop("PYTEST_XDIST_WORKER", None)
    env.pop("PYTEST_XDIST_TESTRUNUID", None)
    done = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-n", "2", "--dist", "loadscope",
         "--no-loadscope-reorder", "-p", "no:cacheprovider", "--rootdir", str(tmp_path),
         "-c", str(tmp_path / "pytest.ini"), *options, str(tmp_path)],
        cwd=tmp_path, env=env, capture_output=True, text=True, timeout=240,
    )  # fmt: skip
    return done, log


@pytest.mark.daemon
def test_no_test_that_starts_a_process_in_another_module_starts_before_the_exclusive_tests_end(
    tmp_path: Path,
) -> None:
    # Two workers: one takes the module with the exclusive test (sent first), the other the
    # module without, whose tests start processes (marked daemon: the long ones). Without the
    # gate, they ran during test_first, before the exclusive test had even asked for the CPU,
    # and an exclusive test then waited for whatever long test the other workers had started.
    # A third module's tests start no process: one of them runs beside the exclusive test
    # (test_alone waits for it, and fails without it).
    done, log = gated_run(tmp_path)
    assert done.returncode == 0, done.stdout + done.stderr
    events: dict[str, list[float]] = {}
    for line in log.read_text(encoding="utf-8").splitlines():
        what, when = line.split()
        events.setdefault(what, []).append(float(when))
    assert len(events["other_start"]) == 2, events
    assert min(events["other_start"]) >= events["alone_end"][0], events


class _Item:
    """What the module order reads of a collected test: its node id and its marks."""

    def __init__(self, nodeid: str, *marks: str) -> None:
        self.nodeid = nodeid
        self.marks = marks

    def get_closest_marker(self, name: str) -> str | None:
        return name if name in self.marks else None


def test_modules_go_exclusive_first_then_those_that_start_no_process_then_longest_first() -> None:
    items = [
        _Item("tests/test_long.py::a", "daemon"),
        _Item("tests/test_pure_short.py::a"),
        _Item("tests/test_mixed.py::b", "daemon"),
        _Item("tests/test_mixed.py::a"),
        _Item("tests/test_rt.py::second"),
        _Item("tests/test_rt.py::first", "daemon", "exclusive"),
        _Item("tests/test_pure_long.py::a"),
        _Item("tests/test_short.py::a", "daemon"),
    ]
    seconds = {
        "tests/test_long.py": 60.0,
        "tests/test_mixed.py": 30.0,
        "tests/test_pure_long.py": 8.0,
        "tests/test_pure_short.py": 0.5,
        "tests/test_short.py": 2.0,
    }
    ordered = schedule.module_order(items, seconds)  # type: ignore[arg-type]
    assert [i.nodeid for i in ordered] == [
        "tests/test_rt.py::second",  # a module's own order is kept
        "tests/test_rt.py::first",
        "tests/test_pure_long.py::a",
        "tests/test_pure_short.py::a",
        "tests/test_long.py::a",
        "tests/test_mixed.py::b",
        "tests/test_mixed.py::a",
        "tests/test_short.py::a",
    ]


@pytest.mark.daemon
def test_a_run_that_stops_at_its_first_failure_does_not_wait_at_the_gate(tmp_path: Path) -> None:
    # -x: test_first fails, so the exclusive test after it never runs. Its worker says the run
    # is stopping, and the other worker's tests stop waiting at the gate: the run ends now, not
    # when the gate's stall limit (300 s) has passed (the subprocess is given 240 s).
    # No module without processes: the other worker's first tests are the gated ones.
    files = {k: v for k, v in GATED_RUN.items() if k != "test_c_pure.py"}
    files["test_a_mixed.py"] = files["test_a_mixed.py"].replace(
        "log('first_start'); time.sleep(1.5)", "log('first_start'); time.sleep(1.5); assert 0"
    )
    done, log = gated_run(tmp_path, files, "-x")
    shown = done.stdout + done.stderr
    assert "FAILED test_a_mixed.py::test_first" in shown and "stopping after 1 failures" in shown
    assert "alone_start" not in log.read_text(encoding="utf-8")


def test_the_compile_shares_are_balanced_by_size(tmp_path: Path) -> None:
    files = []
    for name, size in (("a", 5), ("b", 4), ("c", 3), ("d", 2)):
        (tmp_path / name).write_bytes(b"x" * size)
        files.append(tmp_path / name)
    # Largest first, each to the lighter share: a+d = 7 and b+c = 7 bytes.
    assert bytecode.shares(files, 2) == [[tmp_path / "a", tmp_path / "d"],
                                          [tmp_path / "b", tmp_path / "c"]]  # fmt: skip
    assert bytecode.shares(files[:1], 2) == [[tmp_path / "a"]]  # no empty share
