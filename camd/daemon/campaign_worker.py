"""The campaign jobs' worker processes: started, watched, stopped (docs/campaigns.md).

A job's worker is ``python -m camd.campaign.worker run``, a client of this daemon's API (like
``camctl campaign run``) holding control under the client name ``worker_client(job_id)``.
``CampaignWorkers`` is handed the campaign jobs' lock, their store and the event log, and
told where the API is (``attach``). It

- checks a campaign file in a worker without running it (``check``);
- starts a job's worker in its own session, its output into the job's ``worker.log``
  (``spawn``), and watches it: whenever it exits, however it ended (killed too), ``exited(job_id,
  status)`` is told at once (``camd.daemon.campaign_jobs`` takes the outcome into the job);
- kills a worker that has not stopped ``STOP_GRACE_S`` after a pause, an abort or an emergency
  stop (``kill_if_stuck``);
- at the daemon's stop, stops the running worker (SIGTERM, then SIGKILL; ``close``), and at its
  start, a worker a killed daemon left (``stop_leftover``);
- reads what a worker left: its outcome file and the end of its log.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from camd.daemon.campaign_job_store import Events, Job, JobStore, write_error
from camd.daemon.errors import BadRequest, WrongState
from camd.daemon.models import CampaignJobState

WORKER_MODULE = "camd.campaign.worker"
CHECK_TIMEOUT_S = 60.0  # loading a campaign: imports and the file's own checks
STOP_GRACE_S = 60.0  # a worker asked to stop gets this long before SIGKILL (a measure step
# runs to its end first: the shipped ones take seconds)
SHUTDOWN_WAIT_S = 5.0  # the daemon's stop waits this long for a worker after SIGTERM
LOG_TAIL_CHARS = 600

# worker exit status -> the job's state (camd.campaign.worker's exit statuses)
EXIT_STATES: dict[int, CampaignJobState] = {
    0: "passed",
    1: "failed",
    3: "paused",
    4: "aborted",
    130: "interrupted",
}


def worker_client(job_id: int) -> str:
    """The client name a job's worker holds control under."""
    return f"campaign-job-{job_id}"


@dataclass(eq=False)
class CampaignWorkers:
    """The running workers, by job id (module docstring)."""

    _python: str
    _lock: threading.RLock  # the campaign jobs': guards the workers with the jobs
    _store: JobStore
    _events: Events
    _exited: Callable[[int, int], None]
    _procs: dict[int, subprocess.Popen[bytes]] = field(default_factory=dict, init=False)
    _url: str | None = field(default=None, init=False)
    _token: str = field(default="", init=False)
    # The daemon's stop has begun: it stops the workers itself.
    stopping: bool = field(default=False, init=False)

    def attach(self, url: str, token: str) -> None:
        """Where the workers find the API (known once the daemon has bound its socket)."""
        self._url, self._token = url, token

    @property
    def attached(self) -> bool:
        """Whether the workers know where the API is (``attach``)."""
        return self._url is not None

    def running(self) -> list[int]:
        """The jobs whose worker runs (call with the lock held)."""
        return list(self._procs)

    def forget(self, job_id: int) -> None:
        """Job ``job_id``'s worker has exited (call with the lock held)."""
        self._procs.pop(job_id, None)

    def check(self, file: str, quick: bool) -> dict[str, Any]:
        """Load and check the campaign file ``file`` in a worker, without running it; see
        ``CampaignJobs.check``."""
        argv = [self._python, "-m", WORKER_MODULE, "check", file] + (["--quick"] if quick else [])
        if self._url is not None:
            argv += ["--url", self._url]
        env = {**os.environ, "CAMD_TOKEN": self._token, "CAMD_CLIENT": "campaign-check"}
        try:
            done = subprocess.run(
                argv, capture_output=True, timeout=CHECK_TIMEOUT_S, check=False, env=env
            )
        except subprocess.TimeoutExpired:
            raise BadRequest(
                f"checking campaign {file!r} took over {CHECK_TIMEOUT_S:g} s; check it with "
                f"`camctl campaign run {file} --sim --quick` first"
            ) from None
        if done.returncode != 0:
            reason = done.stderr.decode(errors="replace").strip().splitlines()
            raise BadRequest(reason[-1] if reason else f"campaign {file!r} cannot be loaded")
        doc: dict[str, Any] = json.loads(done.stdout)
        return doc

    def spawn(self, job: Job) -> None:
        """Start ``job``'s next run's worker and watch it; the job notes it (saved). Call with
        the lock held."""
        if self._url is None:
            raise WrongState("campaign jobs start once the daemon serves its API; retry")
        argv = [
            self._python, "-m", WORKER_MODULE, "run", "--url", self._url, "--job", str(job.id),
            "--run", str(job.runs + 1), "--file", job.file, "--out", job.out_dir,
        ] + (["--quick"] if job.quick else [])  # fmt: skip
        out = Path(job.out_dir)
        env = {**os.environ, "CAMD_TOKEN": self._token, "CAMD_CLIENT": worker_client(job.id)}
        try:
            out.mkdir(parents=True, exist_ok=True)
            with open(out / "worker.log", "ab") as log:
                # Its own session: a Ctrl-C meant for the daemon's terminal is not the
                # worker's; the daemon stops it itself (close).
                proc = subprocess.Popen(
                    argv, stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT,
                    env=env, start_new_session=True,
                )  # fmt: skip
        except OSError as exc:
            raise write_error(f"cannot start job {job.id}'s worker in {out}", exc) from None
        self._procs[job.id] = proc
        job.pid, job.runs, job.started_t_s = proc.pid, job.runs + 1, time.time()
        job.resume_on_start, job.estopped = False, False
        self._store.save()
        threading.Thread(
            target=self._watch, args=(job.id, proc), name=f"camd-job-{job.id}", daemon=True
        ).start()

    def _watch(self, job_id: int, proc: subprocess.Popen[bytes]) -> None:
        """Wait for the worker to exit; hand its exit status on."""
        code = proc.wait()
        self._exited(job_id, code)

    def kill_if_stuck(self, job_id: int) -> None:
        """Watch, on a thread of its own, that job ``job_id``'s worker stops within
        STOP_GRACE_S; kill it if it does not."""
        threading.Thread(
            target=self._kill_if_stuck, args=(job_id,), name=f"camd-job-{job_id}-grace",
            daemon=True,
        ).start()  # fmt: skip

    def _kill_if_stuck(self, job_id: int) -> None:
        """A worker that has not stopped STOP_GRACE_S after a pause or abort is killed (a
        measurement step runs to its end first; none takes that long on the shipped ones)."""
        deadline = time.monotonic() + STOP_GRACE_S
        while time.monotonic() < deadline:
            with self._lock:
                proc = self._procs.get(job_id)
            if proc is None or self.stopping:
                return  # stopped, or the daemon's own stop takes it over
            time.sleep(0.2)
        with self._lock:
            proc = self._procs.get(job_id)
        if proc is not None:
            self._events("warning", "campaign",
                         f"job {job_id}: the worker did not stop within {STOP_GRACE_S:g} s; "
                         "killed")  # fmt: skip
            _terminate(proc, 5.0)

    def close(self) -> None:
        """At the daemon's stop: stop the running workers (SIGTERM, then SIGKILL)."""
        with self._lock:
            procs = list(self._procs.values())
        for proc in procs:
            _terminate(proc, SHUTDOWN_WAIT_S)

    # -- what a worker left ---------------------------------------------------------------------

    @staticmethod
    def outcome(job: Job) -> dict[str, Any] | None:
        """What the job's last run's worker wrote in outcome.json, None if it wrote nothing."""
        path = Path(job.out_dir) / "outcome.json"
        try:
            doc = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return None
        return doc if isinstance(doc, dict) and doc.get("run") == job.runs else None

    @staticmethod
    def log_tail(job: Job) -> str:
        """The last lines of the job's worker.log, for an error that says why."""
        try:
            text = (Path(job.out_dir) / "worker.log").read_text(errors="replace")
        except OSError:
            return "no log"
        tail = " ".join(text.strip().splitlines()[-3:])
        return tail[-LOG_TAIL_CHARS:] or "no output"


def _terminate(proc: subprocess.Popen[bytes], wait_s: float) -> None:
    with contextlib.suppress(ProcessLookupError):
        proc.send_signal(signal.SIGTERM)
    try:
        proc.wait(wait_s)
    except subprocess.TimeoutExpired:
        with contextlib.suppress(ProcessLookupError):
            proc.kill()
        proc.wait()


def stop_leftover(pid: int, job_id: int) -> None:
    """Stop the worker of job ``job_id`` that a killed daemon left running, if ``pid`` still
    is that worker (a pid is reused: the command line must name the module and the job)."""
    try:
        cmdline = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
    except OSError:
        return
    try:
        ours = WORKER_MODULE.encode() in cmdline and cmdline[cmdline.index(b"--job") + 1] == (
            str(job_id).encode()
        )
    except (ValueError, IndexError):
        ours = False
    if not ours:
        return
    with contextlib.suppress(ProcessLookupError):
        os.kill(pid, signal.SIGTERM)
    deadline = time.monotonic() + SHUTDOWN_WAIT_S
    while Path(f"/proc/{pid}").exists() and time.monotonic() < deadline:
        time.sleep(0.05)
    with contextlib.suppress(ProcessLookupError):
        os.kill(pid, signal.SIGKILL)
