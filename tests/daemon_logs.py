"""A failed test's report carries the end of the log of every daemon it had running.

A test that fails on a daemon's behaviour (a stare that never finished, a refusal not expected)
is diagnosed from what the daemon logged at that moment; the log file lives in a temporary
directory that a later run may delete, and a CI run keeps only its output. So the report of a
failed test (setup, call or teardown) gets a section per daemon still running: its log file's
last 16 KiB.
"""

from __future__ import annotations

from collections.abc import Generator
from typing import Any

import pytest

from camd.cli._daemon_proc import running_daemons


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(
    item: pytest.Item, call: pytest.CallInfo[None]
) -> Generator[None, Any, None]:
    outcome = yield
    report = outcome.get_result()
    if report.failed:
        for daemon in running_daemons():
            report.sections.append((f"daemon log {daemon.log_path} (its end)", daemon.log_tail()))
