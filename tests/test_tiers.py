"""The fast tier's mark (tests/tiers.py): a test whose code can start a process is marked
``daemon`` (through a fixture, a helper, a helper's helper, a local import), the others are not;
and a test outside the mark that starts a process anyway fails, naming it. Each case is a small
test file run by a pytest session inside this one (pytester, in process)."""

from __future__ import annotations

import pytest

pytest_plugins = ["pytester"]

# Collected only (never run): how tests reach a daemon or a command.
REACHING = """
import contextlib
import subprocess

import pytest

from camd.cli._daemon_proc import DaemonProcess, start_sim_daemon


@contextlib.contextmanager
def a_daemon(path):
    with DaemonProcess(path) as daemon:
        yield daemon.url


def two_levels_down(path):
    with a_daemon(path) as url:
        return url


def a_first():  # reaches a process through c_starts, after a loop through b_loops_back
    b_loops_back()
    c_starts()


def b_loops_back():
    a_first()


def c_starts():
    subprocess.run(["true"], check=True)


@pytest.fixture(scope="module")
def url(tmp_path_factory):
    with a_daemon(tmp_path_factory.mktemp("d")) as url:
        yield url


@pytest.fixture
def client(url):
    return url


def test_pure_arithmetic():
    assert sum(range(4)) == 6


def test_through_a_fixture_of_a_fixture(client):
    pass


def test_through_helpers(tmp_path):
    two_levels_down(tmp_path)


def test_a_campaign_daemon(tmp_path):
    start_sim_daemon(tmp_path, "hr400")


def test_through_a_loop():
    a_first()


def test_into_the_loop_from_its_other_end():
    b_loops_back()


def test_a_command():
    subprocess.run(["camctl", "status"], check=False)


def test_a_local_import():
    from playwright.sync_api import sync_playwright

    sync_playwright()


class TestInAClass:
    def test_a_method_through_a_fixture(self, url):
        pass

    def test_a_method_that_starts_nothing(self):
        assert "daemon" in "no daemon here"


@pytest.mark.daemon
def test_marked_by_hand():
    pass
"""

# Run: one test starts a process through a path the reading cannot follow.
HIDDEN = """
import pytest


def run_true():
    runner = getattr(__import__("sub" + "process"), "run")
    runner(["true", "--started-behind-the-marks-back"], check=True)


def test_starts_nothing():
    pass


def test_starts_a_process_unmarked():
    run_true()


@pytest.mark.daemon
def test_starts_a_process_marked():
    run_true()
"""


def selected(pytester: pytest.Pytester, expression: str) -> set[str]:
    result = pytester.runpytest_inprocess(
        "-p", "tests.tiers", "-p", "no:cacheprovider", "--collect-only", "-q", "-m", expression
    )
    return {line.split("::", 1)[1] for line in result.outlines if "::" in line}


def test_a_test_that_can_start_a_process_is_marked_daemon(pytester: pytest.Pytester) -> None:
    pytester.makepyfile(test_reaching=REACHING)
    fast = {"test_pure_arithmetic", "TestInAClass::test_a_method_that_starts_nothing"}
    daemon = {
        "test_through_a_fixture_of_a_fixture",
        "test_through_helpers",
        "test_a_campaign_daemon",
        "test_through_a_loop",
        "test_into_the_loop_from_its_other_end",
        "test_a_command",
        "test_a_local_import",
        "TestInAClass::test_a_method_through_a_fixture",
        "test_marked_by_hand",
    }
    assert selected(pytester, "not daemon") == fast
    assert selected(pytester, "daemon") == daemon


def test_a_process_started_outside_the_mark_fails_the_test(pytester: pytest.Pytester) -> None:
    pytester.makepyfile(test_hidden=HIDDEN)
    result = pytester.runpytest_inprocess("-p", "tests.tiers", "-p", "no:cacheprovider")
    # The unmarked test ran and passed; its teardown then fails, naming the process.
    result.assert_outcomes(passed=3, errors=1)
    failed = [r for r in result.reprec.getreports("pytest_runtest_logreport") if r.failed]
    assert [(r.nodeid, r.when) for r in failed] == [
        ("test_hidden.py::test_starts_a_process_unmarked", "teardown")
    ]
    message = str(failed[0].longrepr)
    assert "test_starts_a_process_unmarked started a process but is not marked `daemon`" in message
    assert "subprocess.Popen true --started-behind-the-marks-back" in message
    assert "mark the test @pytest.mark.daemon" in message
