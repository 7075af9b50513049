"""Real-time scheduling for the threads the hardware waits on (docs/config.md, ``[daemon]``).

A busy host PC must not starve the frame reader (the USB bulk reads), the command link's reader
(every stage reading and correction goes through it), a scan's closed loop or the service loop
(it pets systemd's watchdog). Each of them, once started, calls ``enter(role)`` from inside
its own thread: with ``daemon.realtime = "auto"`` or ``"required"`` the thread asks for
``SCHED_RR`` at ``daemon.rt_priority``; where that is not allowed (RLIMIT_RTPRIO 0 and no
CAP_SYS_NICE, a ``RestrictRealtime=yes`` unit) it asks for the raised priority
``daemon.fallback_nice`` instead; where that is not allowed either it keeps what it has. What
each thread got, and why it did not get more, is logged and shown in ``GET /api/v1/status``
(``daemon.scheduling``).

Only threads that block between short bursts of work (on a USB read, the serial port, a sleep,
an event) may ask: a real-time thread that spins would take its core from everything else. The
frame dispatcher (its consumers' work grows with the frame rate) and the TDI worker stay at
normal priority. ``SCHED_RR`` rather than ``SCHED_FIFO`` so that the real-time threads, all at
one priority, share a core in time slices should one of them run long. Each request carries
``SCHED_RESET_ON_FORK``: a thread or process started from a real-time thread (a stream's
finisher, the simulator) starts at normal priority (and nice 0) instead of inheriting it.

The scheduling is the process's, like its logging: one ``Realtime`` per process, set by
``configure`` when the daemon starts (until then ``enter`` changes nothing and only records).
``decide`` is the pure decision; ``enter`` and ``probe`` make the real system calls.
"""

from __future__ import annotations

import logging
import os
import resource
import threading
from dataclasses import dataclass

from camd.daemon.config_sections import RealtimeSetting

log = logging.getLogger(__name__)
CAP_SYS_NICE = 23  # linux/capability.h
REALTIME_ROLES = frozenset({"frame_reader", "command_link", "closed_loop", "service_loop"})
"""The threads that ask for real time; any other role passed to ``enter`` is only recorded."""
_POLICY_NAMES = {
    0: "SCHED_OTHER",
    1: "SCHED_FIFO",
    2: "SCHED_RR",
    3: "SCHED_BATCH",
    5: "SCHED_IDLE",
}


@dataclass(frozen=True)
class ThreadScheduling:
    """What one thread runs with: its policy, its real-time priority (0 for the normal
    policies) and its nice value (which counts for the normal policies only)."""

    policy: str
    priority: int
    nice: int

    @property
    def realtime(self) -> bool:
        return self.policy in ("SCHED_RR", "SCHED_FIFO")

    def describe(self) -> str:
        """``SCHED_RR 10`` for a real-time thread, ``SCHED_OTHER nice -5`` otherwise."""
        return (
            f"{self.policy} {self.priority}" if self.realtime else f"{self.policy} nice {self.nice}"
        )


@dataclass(frozen=True)
class Decision:
    """What a thread asks for: ``rt_priority`` (None: no real-time request) and ``nice`` (None:
    leave it), with ``why`` it asks for no more (None when it asks for real time as configured)."""

    rt_priority: int | None
    nice: int | None
    why: str | None


def decide(
    setting: RealtimeSetting,
    rt_priority: int,
    fallback_nice: int,
    *,
    rtprio_limit: int,
    nice_floor: int,
    cap_sys_nice: bool,
) -> Decision:
    """What a thread should ask for, from the configuration and what the process may do: the
    soft RLIMIT_RTPRIO ``rtprio_limit`` (RLIM_INFINITY as a large number), the lowest nice the
    soft RLIMIT_NICE allows ``nice_floor`` (20 - limit) and whether it has CAP_SYS_NICE."""
    if setting == "off":
        return Decision(None, None, 'daemon.realtime = "off"')
    if cap_sys_nice or rtprio_limit >= rt_priority:
        return Decision(rt_priority, None, None)
    if rtprio_limit > 0:
        return Decision(
            rtprio_limit,
            None,
            f"RLIMIT_RTPRIO {rtprio_limit} is below daemon.rt_priority {rt_priority}: priority "
            f"{rtprio_limit} (raise LimitRTPRIO= in the unit)",
        )
    why = (
        "real-time scheduling is not allowed: RLIMIT_RTPRIO is 0 and the process has no "
        "CAP_SYS_NICE (under systemd: LimitRTPRIO= in the unit, docs/config.md)"
    )
    if nice_floor <= fallback_nice:
        return Decision(None, fallback_nice, why)
    floor = "no nice below 20" if nice_floor >= 20 else f"nice {nice_floor} at the lowest"
    return Decision(
        None,
        None,
        f"{why}; nor nice {fallback_nice}: RLIMIT_NICE allows {floor} (Nice= or LimitNICE= "
        "in the unit)",
    )


def current() -> ThreadScheduling:
    """The calling thread's scheduling, as the kernel reports it."""
    if not hasattr(os, "sched_getscheduler"):
        return ThreadScheduling("SCHED_OTHER", 0, os.getpriority(os.PRIO_PROCESS, 0))
    policy = os.sched_getscheduler(0) & ~os.SCHED_RESET_ON_FORK
    return ThreadScheduling(
        _POLICY_NAMES.get(policy, f"policy {policy}"),
        os.sched_getparam(0).sched_priority,
        # On Linux the nice value is per thread: who=0 is the calling thread.
        os.getpriority(os.PRIO_PROCESS, 0),
    )


def _has_cap_sys_nice() -> bool:
    try:
        with open("/proc/self/status", encoding="ascii") as f:
            for line in f:
                if line.startswith("CapEff:"):
                    return bool(int(line.split()[1], 16) >> CAP_SYS_NICE & 1)
    except OSError:
        pass
    return False


def _soft_limit(which: int, infinite: int) -> int:
    soft = resource.getrlimit(which)[0]
    return infinite if soft == resource.RLIM_INFINITY else int(soft)


def process_decision(setting: RealtimeSetting, rt_priority: int, fallback_nice: int) -> Decision:
    """``decide`` for this process, from its real limits and capabilities."""
    if not hasattr(os, "sched_setscheduler"):
        return Decision(None, None, "this system has no sched_setscheduler (Linux only)")
    return decide(
        setting,
        rt_priority,
        fallback_nice,
        rtprio_limit=_soft_limit(resource.RLIMIT_RTPRIO, 99),
        nice_floor=20 - _soft_limit(resource.RLIMIT_NICE, 40),
        cap_sys_nice=_has_cap_sys_nice(),
    )


def apply(decision: Decision) -> tuple[ThreadScheduling, str | None]:
    """Ask the kernel for ``decision`` on the calling thread; what it got, and why not more
    (the decision's reason, or the system call's refusal: a seccomp filter such as systemd's
    ``RestrictRealtime=yes``, or a control group without real-time budget)."""
    why = decision.why
    if decision.rt_priority is not None:
        try:
            os.sched_setscheduler(
                0, os.SCHED_RR | os.SCHED_RESET_ON_FORK, os.sched_param(decision.rt_priority)
            )
            return current(), why
        except OSError as exc:
            why = (
                f"SCHED_RR {decision.rt_priority} refused: {exc.strerror or exc} (is "
                "RestrictRealtime=yes set in the unit, or has the control group no real-time "
                "budget?)"
            )
    if decision.nice is not None and decision.nice < current().nice:
        try:
            # Threads started from this one begin at nice 0 again, not at this raised value.
            os.sched_setscheduler(0, os.SCHED_OTHER | os.SCHED_RESET_ON_FORK, os.sched_param(0))
            os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), decision.nice)
        except OSError as exc:
            why = f"{why}; nice {decision.nice} refused: {exc.strerror or exc}"
    return current(), why


class Realtime:
    """The process's scheduling request and what each of its threads got."""

    def __init__(self) -> None:
        self.setting: RealtimeSetting = "off"
        self.rt_priority = 10
        self.fallback_nice = -5
        self._configured = False
        self._lock = threading.Lock()
        self._threads: dict[str, ThreadScheduling] = {}
        self._why: str | None = "not configured"

    def configure(
        self, setting: RealtimeSetting, rt_priority: int, fallback_nice: int
    ) -> str | None:
        """Set the request (``daemon.realtime``, ``rt_priority``, ``fallback_nice``), try it on
        a thread of its own and log the outcome. Returns the refusal to start with when
        ``setting`` is "required" and real time is not granted, else None."""
        self.setting, self.rt_priority, self.fallback_nice = setting, rt_priority, fallback_nice
        self._configured = True
        got, why = self.probe()
        with self._lock:
            self._why = why
        if setting == "off":
            log.info("real-time scheduling off (daemon.realtime); threads at %s", got.describe())
        elif got.realtime:
            log.info("real-time scheduling: the hardware's threads get %s", got.describe())
        else:
            log.warning(
                "real-time scheduling: the hardware's threads get %s: %s", got.describe(), why
            )
        if setting == "required" and not got.realtime:
            return (
                f'daemon.realtime = "required", but {why}; grant it (LimitRTPRIO= in the '
                'systemd unit, or run with CAP_SYS_NICE) or set daemon.realtime = "auto"'
            )
        return None

    def probe(self) -> tuple[ThreadScheduling, str | None]:
        """What a thread that calls ``enter`` would get, tried for real on a short-lived thread
        (so that the caller's own scheduling is left as it is)."""
        result: list[tuple[ThreadScheduling, str | None]] = []
        thread = threading.Thread(
            target=lambda: result.append(apply(self._decision())),
            name="camd-realtime-probe",
            daemon=True,
        )
        thread.start()
        thread.join()
        return result[0]

    def _decision(self) -> Decision:
        if not self._configured:
            return Decision(None, None, "not configured")
        return process_decision(self.setting, self.rt_priority, self.fallback_nice)

    def enter(self, role: str) -> ThreadScheduling:
        """Called by a thread when it starts, from inside it: one of ``REALTIME_ROLES`` asks
        for real-time scheduling as configured; any other role asks for nothing. Either way
        what ``role`` runs at is recorded (the first time, logged)."""
        if role in REALTIME_ROLES:
            got, why = apply(self._decision())
        else:
            got, why = current(), None
        with self._lock:
            first = role not in self._threads
            self._threads[role] = got
            if role in REALTIME_ROLES:
                self._why = why
        if first:
            name = threading.current_thread().name
            log.info("thread %s (%s) runs at %s", role, name, got.describe())
        return got

    def report(self) -> dict[str, str]:
        """``{role: "SCHED_RR 10", ..., "why": reason or None}`` for the status: each thread
        seen so far (the frame reader once a stream ran, the closed loop once a scan ran)."""
        with self._lock:
            shown: dict[str, str] = {
                role: got.describe() for role, got in sorted(self._threads.items())
            }
            if self._why is not None:
                shown["why"] = self._why
        return shown


REALTIME = Realtime()
"""The daemon's one ``Realtime``: threads call ``REALTIME.enter(role)`` when they start."""
