"""Start the daemon with the scheduling its systemd unit gives it (systemd/camd.service).

The unit runs camd as an unprivileged user without capabilities, with ``Nice=`` and
``LimitRTPRIO=``; the suite runs as root. ``as_the_unit()`` is the command prefix (for
``DaemonProcess(wrapper=...)``) that gives a daemon the same: the unit's nice value, the unit's
RLIMIT_RTPRIO, and CAP_SYS_NICE dropped from the bounding set, so that the limit, not root's
capability, is what allows real time. A host that will not raise RLIMIT_RTPRIO (a container
whose hard limit is 0, without CAP_SYS_RESOURCE) gets the unit's nice value and keeps
CAP_SYS_NICE instead, which allows what the limit would: the daemon's threads get the same
policy and priority either way (``UNIT_GRANT`` says which applies).

``without_realtime()`` starts a process that may have neither real time nor a lower nice value:
RLIMIT_RTPRIO 0 and no CAP_SYS_NICE, what a unit without ``LimitRTPRIO=`` gives.
"""

from __future__ import annotations

import configparser
import os
import resource
import shutil
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parent.parent
UNIT = REPO_ROOT / "systemd" / "camd.service"
CAP_SYS_RESOURCE = 24  # linux/capability.h
# The daemon's and its simulator's first-scan work done when they start, as shipped
# (daemon.tdi_warm_up, docs/config.md; docs/simulator.md), which the suite turns off for its
# other daemons (tests/conftest.py). A closed-loop scan's stage runs from its first frame's
# request: a first scan that waits a second or more for compiled kernels, the fixed pattern and
# the noise bank lets the stage run on (a loaded run's first scan took 9 s and 1.1 m of rail,
# and the next scan rewound it for 11 s), and makes the first scan's loop a warm-up's.
WARM_UP_AS_SHIPPED = {"CAMD_TDI_WARM_UP": "1", "CAMD_SIM_WARM_UP": "1"}
POLICIES = {0: "SCHED_OTHER", 1: "SCHED_FIFO", 2: "SCHED_RR"}


def unit_service() -> configparser.SectionProxy:
    """The unit's [Service] section (its last value of a repeated key)."""
    parser = configparser.ConfigParser(strict=False, interpolation=None)
    parser.optionxform = str  # type: ignore[assignment,method-assign]  # keys keep their case
    parser.read_string(UNIT.read_text(encoding="utf-8"))
    return parser["Service"]


def _capable(cap: int) -> bool:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("CapEff:"):
            return bool(int(line.split()[1], 16) >> cap & 1)
    return False


def _can_raise_rtprio(limit: int) -> bool:
    hard = resource.getrlimit(resource.RLIMIT_RTPRIO)[1]
    return hard == resource.RLIM_INFINITY or hard >= limit or _capable(CAP_SYS_RESOURCE)


def _unit_grant() -> str:
    limit = int(unit_service()["LimitRTPRIO"])
    if _can_raise_rtprio(limit):
        return f"RLIMIT_RTPRIO {limit}, no CAP_SYS_NICE"
    return "CAP_SYS_NICE (this host keeps RLIMIT_RTPRIO at 0)"


UNIT_GRANT = _unit_grant()
"""How ``as_the_unit()`` allows real time on this host: the unit's limit, or root's capability."""


def as_the_unit() -> list[str]:
    """The command prefix that runs a command with the unit's nice value and real-time limit."""
    service = unit_service()
    wrapper = ["nice", "-n", service["Nice"]]
    limit = int(service["LimitRTPRIO"])
    if _can_raise_rtprio(limit):
        wrapper += ["prlimit", f"--rtprio={limit}:{limit}", "setpriv", "--bounding-set=-sys_nice"]
    return wrapper


def without_realtime() -> list[str]:
    """The command prefix that runs a command with RLIMIT_RTPRIO 0 and RLIMIT_NICE 0 and without
    CAP_SYS_NICE: no real time, no nice below the current."""
    return ["prlimit", "--rtprio=0:0", "--nice=0:0", "setpriv", "--bounding-set=-sys_nice"]


def thread_scheduling(pid: int) -> dict[int, tuple[str, int, int]]:
    """{thread id: (policy, real-time priority, nice)} of process ``pid``, from /proc: what the
    kernel says, to hold the daemon's own report against."""
    threads: dict[int, tuple[str, int, int]] = {}
    for task in Path(f"/proc/{pid}/task").iterdir():
        try:
            stat = (task / "stat").read_text()
        except OSError:  # the thread ended meanwhile
            continue
        # Fields after "(comm)": state is field 3; nice 19, rt_priority 40, policy 41.
        fields = stat[stat.rindex(")") + 2 :].split()
        nice, rt_priority, policy = int(fields[16]), int(fields[37]), int(fields[38])
        threads[int(task.name)] = (POLICIES.get(policy, str(policy)), rt_priority, nice)
    return threads


def running_in_group(pgid: int) -> int:
    """How many processes of process group ``pgid`` are running (state R) now."""
    running = 0
    for stat_path in Path("/proc").glob("[0-9]*/stat"):
        try:
            stat = stat_path.read_text()
        except OSError:
            continue  # gone meanwhile
        # Fields after "(comm)": state, ppid, pgrp.
        state, _, pgrp = stat[stat.rindex(")") + 2 :].split()[:3]
        running += state == "R" and int(pgrp) == pgid
    return running


def wait_hog_running(pgid: int, workers: int, timeout_s: float = 30.0) -> None:
    """Until ``workers`` processes of the hog's process group ``pgid`` run at once: its
    workers have started spinning (a poll instead of a fixed wait; a busy machine may take
    longer to start them)."""
    deadline = time.monotonic() + timeout_s
    while running_in_group(pgid) < workers:
        if time.monotonic() > deadline:
            raise AssertionError(
                f"the CPU hog's {workers} workers did not run within {timeout_s} s"
            )
        time.sleep(0.05)


@contextmanager
def cpu_hog(workers: int = 4) -> Iterator[str]:
    """A CPU hog of normal priority while the block runs: ``stress-ng --cpu N`` if installed,
    else N Python processes spinning. Yields what it runs."""
    if shutil.which("stress-ng"):
        command = ["stress-ng", "--cpu", str(workers), "--timeout", "900s", "--quiet"]
        procs = [subprocess.Popen(command, start_new_session=True)]
        what = " ".join(command[:3])
    else:
        spin = [sys.executable, "-c", "while True: pass"]
        procs = [subprocess.Popen(spin, start_new_session=True) for _ in range(workers)]
        what = f"{workers} spinning Python processes"
    try:
        # Spinning before the block starts (each spinner is its own group's only process).
        if len(procs) == 1:
            wait_hog_running(procs[0].pid, workers)
        else:
            for proc in procs:
                wait_hog_running(proc.pid, 1)
        yield what
    finally:
        for proc in procs:
            # Its own process group: stress-ng's workers are its children.
            os.killpg(proc.pid, 15)
        for proc in procs:
            proc.wait(timeout=30)
