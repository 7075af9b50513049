"""Supervision of the simulated camera (``link.device = "sim"``): restarted when it dies.

``SimSupervisor.check()`` runs on the session's service loop. When the simulator child exits
on its own (not by the daemon's ``stop``), it logs an error event naming the pid, how it died
and how long it ran, waits out a backoff and starts the same command again (the same profile,
scene, inject spec, seed, pty link and sockets: ``SimulatorProcess.start``) on a thread of its
own, so that the loop keeps polling and petting the watchdog while the new child imports.

``RestartPolicy`` is the arithmetic, pure and clock-free: the wait before restart n of a run of
failures in a row is ``backoff_min_s * 2**(n-1)``, at most ``backoff_max_s``; a child that
stayed up ``stable_s`` before it died starts the run afresh; the failure after ``limit``
restarts in a row is final (an error event says what to do). A start that fails counts as a
failure too.

The links come back by themselves once the new child runs: ``CommandLink`` reopens the pty
link, which the new child points at its own pty, and the probe after that reconnect (GET_STATUS,
the sensor's identity and LVDS training) reopens the register bridge and the USB frame stream
(``SensorService.on_connect``, ``StreamService.on_connect``).
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, Protocol

from camd.daemon.errors import SimulatorError
from camd.daemon.simulator import describe_exit

log = logging.getLogger(__name__)

SimState = Literal["running", "restarting", "exited", "gave_up"]
EventSink = Callable[[str, str, str], None]
"""``(level, source, message)``: log and archive one event."""


class SupervisedProcess(Protocol):
    """What the supervisor needs of ``SimulatorProcess`` (tests pass a fake)."""

    @property
    def link_path(self) -> Path: ...

    @property
    def last_pid(self) -> int | None: ...

    @property
    def stopped(self) -> bool: ...

    def returncode(self) -> int | None: ...

    def start(self) -> dict[str, Any]: ...

    def stop_child(self) -> None: ...

    def refuses_link(self) -> str | None: ...

    def forget_link(self) -> None: ...


@dataclass(slots=True)
class RestartPolicy:
    """Exponential backoff with a stability reset and a limit on restarts in a row."""

    backoff_min_s: float = 0.5
    backoff_max_s: float = 30.0
    stable_s: float = 60.0
    limit: int = 5
    failures: int = 0  # in the current run of failures in a row

    def on_failure(self, up_s: float) -> float | None:
        """A child died (or failed to start) after ``up_s`` seconds: the wait before the next
        start, or None to give up."""
        if up_s >= self.stable_s:
            self.failures = 0  # it had been stable: a fresh run
        self.failures += 1
        if self.failures > self.limit:
            return None
        return float(min(self.backoff_min_s * 2 ** (self.failures - 1), self.backoff_max_s))


class _Restarter:
    """One long-lived thread that runs the restarts, started on first use.

    Not a thread per restart: the child's parent-death signal (``PR_SET_PDEATHSIG``, which
    stops the simulator when the daemon dies) fires when the *thread* that forked it ends, so
    a child forked by a short-lived thread would be terminated as soon as that thread returned.
    """

    def __init__(self) -> None:
        self._jobs: queue.SimpleQueue[Callable[[], None] | None] = queue.SimpleQueue()
        self._thread: threading.Thread | None = None
        self._lock = threading.Lock()

    def __call__(self, job: Callable[[], None]) -> None:
        with self._lock:
            if self._thread is None:
                self._thread = threading.Thread(
                    target=self._run, name="camd-sim-restart", daemon=True
                )
                self._thread.start()
        self._jobs.put(job)

    def close(self, timeout_s: float) -> None:
        """End the thread (after the job it runs, if any): the daemon's shutdown, once the
        child it may have started is stopped."""
        with self._lock:
            thread = self._thread
        if thread is not None:
            self._jobs.put(None)
            thread.join(timeout_s)

    def _run(self) -> None:
        while True:  # until the daemon stops: see the class docstring
            job = self._jobs.get()
            if job is None:
                return
            try:
                job()
            except Exception:
                log.exception("restarting the simulated camera failed")


class SimSupervisor:
    """Restart the simulated camera when it dies; see the module docstring.

    ``restart``: False only reports the death (``sim.restart = false``). ``event`` logs and
    archives an event. ``clock`` and ``spawn`` (how a restart is run: by default on the
    supervisor's own long-lived thread) are seams for tests.
    """

    def __init__(
        self,
        process: SupervisedProcess,
        policy: RestartPolicy,
        event: EventSink,
        *,
        restart: bool = True,
        clock: Callable[[], float] = time.monotonic,
        spawn: Callable[[Callable[[], None]], None] | None = None,
    ) -> None:
        self.process = process
        self.policy = policy
        self.restart = restart
        self._event = event
        self._clock = clock
        self._restarter: _Restarter | None = None
        if spawn is None:
            spawn = self._restarter = _Restarter()
        self._spawn: Callable[[Callable[[], None]], None] = spawn
        self._lock = threading.Lock()
        self._state: SimState = "running"
        self._started_at = clock()  # the current child's start
        self._due = 0.0  # when the next start is due, while restarting
        self._starting = False  # a start runs on its thread
        self.restarts = 0  # children started again since the daemon started

    def close(self, timeout_s: float = 5.0) -> None:
        """The daemon's shutdown, after the simulator was stopped: end the restart thread
        (waiting for a start in progress, which then stops the child it started)."""
        if self._restarter is not None:
            self._restarter.close(timeout_s)

    @property
    def state(self) -> SimState:
        """``running``, ``restarting`` (waiting out the backoff, or starting), ``exited`` (dead,
        not restarted: ``sim.restart = false``) or ``gave_up``."""
        return self._state

    def check(self) -> None:
        """From the service loop: notice the child's exit, start it again when due."""
        with self._lock:
            if self.process.stopped:
                return  # the daemon's own stop: nothing to restart
            now = self._clock()
            if self._state == "running":
                code = self.process.returncode()
                if code is None:
                    return
                up_s = now - self._started_at
                what = (
                    f"the simulated camera (pid {self.process.last_pid}) {describe_exit(code)} "
                    f"after running {up_s:.1f} s"
                )
                level, message = self._failed(what, up_s, now)
            elif self._state == "restarting" and not self._starting and now >= self._due:
                self._starting = True
                level = message = ""
            else:
                return
        if message:
            self._event(level, "daemon", message)
        else:
            self._spawn(self._start)

    def refuses_link(self) -> str | None:
        """Why the command link must not open the simulator's link now (None: it may). While
        the daemon runs or restarts its simulator the link leads to that child only
        (``SimulatorProcess.refuses_link``); once it has stopped restarting it (``exited``,
        ``gave_up``) the link is the operator's, for a simulator started by hand (``camd sim
        --link``), and the dead child's stale link was removed when its death was noticed."""
        if self._state in ("exited", "gave_up"):
            return None
        return self.process.refuses_link()

    def _failed(self, what: str, up_s: float, now: float) -> tuple[str, str]:
        """Book a failure (lock held): the event to log."""
        link = self.process.link_path
        self.process.forget_link()
        if not self.restart:
            self._state = "exited"
            return (
                "error",
                f"{what}; it is not restarted (sim.restart = false): run "
                f"`camd sim --link {link}` to reconnect one",
            )
        delay = self.policy.on_failure(up_s)
        if delay is None:
            self._state = "gave_up"
            return (
                "error",
                f"{what}; giving up after {self.policy.limit} restarts in a row, each dying "
                f"within {self.policy.stable_s:g} s (sim.restart_limit, sim.restart_stable_s): "
                "its messages in the daemon's log (stderr, or `journalctl -u camd`) say why. "
                "Fix the cause and restart camd, or run "
                f"`camd sim --link {link}` to attach one by hand",
            )
        self._state = "restarting"
        self._due = now + delay
        return (
            "error",
            f"{what}; restarting it in {delay:g} s (restart {self.restarts + 1}, failure "
            f"{self.policy.failures} in a row of at most {self.policy.limit})",
        )

    def _start(self) -> None:
        """On the restart thread: start the same simulator again."""
        try:
            info = self.process.start()
        except SimulatorError as exc:
            with self._lock:
                self._starting = False
                if self.process.stopped:
                    return
                event = self._failed(
                    f"the simulated camera did not start again: {exc}", 0.0, self._clock()
                )
            self._event(event[0], "daemon", event[1])
            return
        except Exception:  # a bug: say so, and try again like any failed start
            log.exception("restarting the simulated camera failed")
            with self._lock:
                self._starting = False
                event = self._failed(
                    "the simulated camera could not be started again (see the daemon's log)",
                    0.0,
                    self._clock(),
                )
            self._event(event[0], "daemon", event[1])
            return
        with self._lock:
            self._starting = False
            if self.process.stopped:
                self.process.stop_child()  # the daemon began stopping meanwhile
                return
            self.restarts += 1
            self._started_at = self._clock()
            self._state = "running"
            n = self.restarts
        self._event(
            "warning",
            "daemon",
            f"simulated camera restarted (restart {n}): pid {info.get('pid')}, tty "
            f"{info.get('tty')}, link {self.process.link_path}. It starts at power-on with the "
            "config's [sim] options: the sensor's registers are at their power-on defaults, and "
            "scene, faults and stage changed at run time are back at the config's; the daemon "
            "reconnects the command link, the USB stream and the register bridge",
        )
