"""Campaign jobs: campaigns the daemon runs, pauses, resumes and aborts (docs/campaigns.md,
"Campaign jobs").

The daemon does not run a campaign in its own process (its threads stream and integrate in
real time, and a campaign's measurements are heavy numpy work): it starts a worker,
``python -m camd.campaign.worker run``, a client of this daemon's API like ``camctl campaign
run``, and supervises it. The worker holds control for the run under the client name
``campaign-job-<id>``, and asks its job before each step whether to go on (``requested``).

- pause: ``requested`` becomes "pause" and the running acquisition is stopped at once; the
  worker stops at its next step boundary (or as its stopped acquisition returns: a stopped
  acquisition is never recorded) and exits, having put the daemon's settings back and given
  control back. The job is "paused"; nothing runs while it is.
- resume: a new worker runs into the same output directory, which resumes from its state file
  (completed steps are replayed, not executed again).
- abort: as pause, then the job ends "aborted" (its files stay; it cannot be resumed).
- a daemon that stops while a job runs stops the worker (SIGTERM) and, when it starts again,
  resumes the job; a worker left from a daemon that was killed is stopped first.
- an emergency stop pauses the running job (``estop``): its acquisition is stopped, its
  worker's control ends and it may not take control again, so it changes nothing more (not
  even its closing "restore settings"); the job is "paused", and neither starts, resumes nor
  resumes at the daemon's start until the emergency stop is released. Pausing, not aborting:
  the steps done stay done, and the operator resumes it once the rig has been checked.
- whenever a worker exits, however it ended (killed too), ``worker_ended`` is told at once, so
  that its control ends with it.

Every job is in ``<data_dir>/campaigns/jobs.json`` (rewritten atomically at each change), so
a restarted daemon knows them all. One job runs at a time.

The daemon runs no code a client names: a job names its campaign by name, looked up in the
operator's campaign directories and then the shipped ones (``camd.daemon.campaign_dirs``); a
path is refused before anything is loaded or imported.
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, Literal

from pydantic import ValidationError

from camd.daemon.campaign_dirs import CampaignDirs
from camd.daemon.errors import (
    BadRequest,
    Busy,
    EstopLatched,
    NotFound,
    NotInControl,
    SessionError,
    StorageFull,
    WrongState,
)
from camd.daemon.estop import RELEASE_HINT
from camd.daemon.models import CampaignJob, CampaignJobState
from camd.daemon.output_paths import CAMPAIGNS_FOLDER, resolve_output

__all__ = ["ACTIVE", "CampaignJobs", "Job", "worker_client"]

JOBS_FORMAT = "camd-campaign-jobs"
JOBS_VERSION = 1
WORKER_MODULE = "camd.campaign.worker"
CHECK_TIMEOUT_S = 60.0  # loading a campaign: imports and the file's own checks
STOP_GRACE_S = 60.0  # a worker asked to stop gets this long before SIGKILL (a measure step
# runs to its end first: the shipped ones take seconds)
SHUTDOWN_WAIT_S = 5.0  # the daemon's stop waits this long for a worker after SIGTERM
LOG_TAIL_CHARS = 600

# The states of a job; ACTIVE ones have (or are about to have) a worker.
ACTIVE = ("running", "pausing", "aborting")
RESUMABLE = ("paused", "error", "interrupted")
# worker exit status -> the job's state (camd.campaign.worker's exit statuses)
EXIT_STATES: dict[int, CampaignJobState] = {
    0: "passed",
    1: "failed",
    3: "paused",
    4: "aborted",
    130: "interrupted",
}

Events = Callable[[str, str, str], None]


def worker_client(job_id: int) -> str:
    """The client name a job's worker holds control under."""
    return f"campaign-job-{job_id}"


class Job(CampaignJob):
    """One campaign job as jobs.json keeps it: the API's document (``public``) and what only
    the daemon needs, the worker's pid and start time and whether to resume at start."""

    pid: int | None = None
    resume_on_start: bool = False
    started_t_s: float | None = None  # the running worker's start
    estopped: bool = False  # paused by an emergency stop: its worker may not hold control

    def public(self) -> dict[str, Any]:
        doc = self.model_dump(exclude={"pid", "resume_on_start", "started_t_s", "estopped"})
        if self.started_t_s is not None:  # the running worker's time so far
            doc["run_time_s"] = self.run_time_s + max(0.0, time.time() - self.started_t_s)
        return doc


class CampaignJobs:
    """The daemon's campaign jobs (module docstring); thread-safe."""

    def __init__(
        self,
        data_dir: Path,
        events: Events,
        stop_acquisition: Callable[[], object],
        *,
        worker_ended: Callable[[int, str], None] = lambda job_id, why: None,
        estop_latched: Callable[[], bool] = lambda: False,
        campaign_dirs: Sequence[Path] = (),
        python: str = sys.executable,
        record_dirs: Sequence[Path] = (),
    ) -> None:
        self._dir = data_dir / CAMPAIGNS_FOLDER
        self._record_dirs = tuple(record_dirs)  # where else an out directory may be
        self._path = self._dir / "jobs.json"
        self._events = events
        self._stop_acquisition = stop_acquisition
        self._worker_ended = worker_ended
        self._estop_latched = estop_latched
        self.campaigns = CampaignDirs(campaign_dirs)
        self._python = python
        self._lock = threading.RLock()
        self._jobs: dict[int, Job] = {}
        self._procs: dict[int, subprocess.Popen[bytes]] = {}
        self._url: str | None = None
        self._token = ""
        self._stopping = False
        self._save_failed = False  # jobs.json could not be written (said once)
        self._load()

    # -- reading --------------------------------------------------------------------------------

    def jobs(self) -> list[dict[str, Any]]:
        with self._lock:
            return [job.public() for job in self._jobs.values()]

    def job(self, job_id: int) -> dict[str, Any]:
        with self._lock:
            return self._get(job_id).public()

    # -- starting -------------------------------------------------------------------------------

    def attach(self, url: str, token: str) -> None:
        """Where the workers find the API (known once the daemon has bound its socket)."""
        self._url, self._token = url, token

    def check(self, file: str, quick: bool) -> dict[str, Any]:
        """Load and check the campaign file ``file`` (found by ``CampaignDirs.find``) in a worker, without
        running it: {"file", "campaign", "profile", "steps"}; BadRequest with the worker's
        reason when it is not a valid campaign. Once the API serves, the worker checks the
        camera too, as the runner does before its first step (the campaign's profile must be
        the daemon's sensor): a job for another camera is refused here, not 2 s after it was
        accepted, holding control."""
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

    def start(
        self,
        campaign: str,
        out_dir: str | None,
        quick: bool,
        client: str,
        before_spawn: Callable[[int], None] = lambda job_id: None,
    ) -> dict[str, Any]:
        """Find the campaign by name (``find``), check it, then start a worker for it: the new
        job's document. Busy while another job runs; BadRequest for an unknown or invalid
        campaign or output directory (nothing is written then). ``before_spawn(job_id)`` (the
        session hands control to the worker) may refuse the start by raising."""
        with self._lock:
            self.refuse_if_active()
            self._refuse_if_latched("start a campaign job")
            if self._url is None:
                raise WrongState("campaign jobs start once the daemon serves its API; retry")
        campaign_path = self.campaigns.find(campaign)
        # A directory the client named is checked first: refused at once, no worker started.
        named_out = None if out_dir is None else self._check_out_dir(out_dir)
        checked = self.check(str(campaign_path), quick)
        with self._lock:
            self.refuse_if_active()
            job_id = max(self._jobs, default=0) + 1
            out = named_out or self._dir / f"{job_id}-{checked['campaign']}"
            job = Job(
                id=job_id,
                campaign=str(checked["campaign"]),
                profile=str(checked["profile"]),
                file=str(checked["file"]),
                out_dir=str(out.resolve()),
                quick=quick,
                started_by=client,
                state="running",
                steps=checked.get("steps"),
                created_t_s=time.time(),
                requested=None,
                run_time_s=0.0,
                runs=0,
                message=None,
                passed=None,
                report=None,
            )
            before_spawn(job_id)
            self._jobs[job_id] = job
            try:
                # jobs.json first: a job the next daemon would not know of is not started.
                self._save(strict=True)
                self._spawn(job)
            except BaseException:
                del self._jobs[job_id]  # refused: no job, nothing written
                self._save()
                raise
            self._events("info", "campaign", f"job {job_id}: campaign {job.campaign} started "
                         f"by {client} into {job.out_dir}")  # fmt: skip
            return job.public()

    def _refuse_if_latched(self, wanted: str) -> None:
        if self._estop_latched():
            raise EstopLatched(
                f"cannot {wanted}: the emergency stop is latched; nothing moves or acquires "
                f"until it is released: {RELEASE_HINT}"
            )

    def refuse_control(self, client: str) -> None:
        """NotInControl if ``client`` is the worker of a job that no longer runs, or that an
        emergency stop paused: it may change nothing more, so it may not take control."""
        with self._lock:
            for job in self._jobs.values():
                if client != worker_client(job.id):
                    continue
                if job.estopped or job.state not in ACTIVE:
                    why = "an emergency stop paused it" if job.estopped else f"it is {job.state}"
                    raise NotInControl(
                        f"campaign job {job.id}'s worker may not take control: {why}; "
                        f"`camctl campaign resume {job.id}` runs it on with a new worker"
                    )

    def estop(self) -> int | None:
        """The emergency stop: the running job (if any) is to pause, its worker to change
        nothing more (module docstring). The id of the job, or None."""
        with self._lock:
            active = [job for job in self._jobs.values() if job.state in ACTIVE]
            if not active:
                return None
            job = active[0]
            job.estopped = True
            if job.state != "aborting":
                job.requested, job.state = "pause", "pausing"
            job.message = "paused by an emergency stop"
            self._save()
            self._events("warning", "campaign", f"job {job.id}: paused by the emergency stop")
        threading.Thread(
            target=self._kill_if_stuck, args=(job.id,), name=f"camd-job-{job.id}-grace",
            daemon=True,
        ).start()  # fmt: skip
        return job.id

    def refuse_if_active(self) -> None:
        """Busy, naming the job, while one runs (one job runs at a time)."""
        for job in self._jobs.values():
            if job.state in ACTIVE:
                raise Busy(
                    f"campaign job {job.id} ({job.campaign}) is {job.state}; one job runs at a "
                    f"time: pause or abort it first (`camctl campaign pause {job.id}`)"
                )

    def _check_out_dir(self, out_dir: str) -> Path:
        """The job's output directory a client named, resolved and confined like a recording
        (``camd.daemon.output_paths``: relative to the campaigns folder); BadRequest if it
        is outside the allowed directories, a file, or not writable. Nothing is created."""
        out = resolve_output(
            out_dir,
            field="out",
            relative_to=self._dir,
            data_dir=self._dir.parent,
            record_dirs=self._record_dirs,
        )
        if out.exists() and not out.is_dir():
            raise BadRequest(f"out {out}: exists and is not a directory; give a directory")
        parent = out if out.exists() else out.parent
        while not parent.exists() and parent != parent.parent:
            parent = parent.parent
        if not os.access(parent, os.W_OK | os.X_OK):
            raise BadRequest(f"out {out}: {parent} is not writable; give another directory")
        return out

    # -- pause, resume, abort ------------------------------------------------------------------

    def pause(self, job_id: int, client: str, *, force: bool = False) -> dict[str, Any]:
        """Ask the running job to pause (see the module docstring); WrongState unless it
        runs."""
        return self._ask(job_id, "pause", client, force)

    def abort(self, job_id: int, client: str, *, force: bool = False) -> dict[str, Any]:
        """Abort the job: a running one is stopped as for a pause, then ends "aborted"; a
        paused one ends at once. WrongState once it has ended."""
        with self._lock:
            job = self._get(job_id)
            if job.state in RESUMABLE:
                self._allowed(job, client, "abort", force)
                job.state, job.message = "aborted", f"aborted by {client} while {job.state}"
                self._save()
                self._events("info", "campaign", f"job {job_id}: aborted by {client}")
                return job.public()
        return self._ask(job_id, "abort", client, force)

    def _ask(
        self, job_id: int, what: Literal["pause", "abort"], client: str, force: bool
    ) -> dict[str, Any]:
        with self._lock:
            job = self._get(job_id)
            if job.state == "aborting" or (job.state == "pausing" and what == "pause"):
                return job.public()  # asked already: the same answer again
            if job.state not in ("running", "pausing"):
                hint = f"; resume it with `camctl campaign resume {job_id}`"
                raise WrongState(
                    f"campaign job {job_id} is {job.state}, not running: nothing to {what}"
                    + (hint if job.state in RESUMABLE else "")
                )
            self._allowed(job, client, what, force)
            job.requested = what
            job.state = "pausing" if what == "pause" else "aborting"
            self._save()
            self._events("info", "campaign", f"job {job_id}: {what} asked by {client}")
        # Outside the lock: stopping a scan waits for its file to close.
        with contextlib.suppress(Exception):  # nothing running is fine; the worker still stops
            self._stop_acquisition()
        threading.Thread(
            target=self._kill_if_stuck, args=(job_id,), name=f"camd-job-{job_id}-grace",
            daemon=True,
        ).start()  # fmt: skip
        return self.job(job_id)

    def resume(
        self,
        job_id: int,
        client: str,
        before_spawn: Callable[[int], None] = lambda job_id: None,
    ) -> dict[str, Any]:
        """Run a paused (or failed with an error, or interrupted) job on from its state file.
        Busy while another job runs; WrongState for a job that runs or has ended."""
        with self._lock:
            job = self._get(job_id)
            if job.state not in RESUMABLE:
                raise WrongState(
                    f"campaign job {job_id} is {job.state}: only a paused, interrupted or "
                    "failed-with-an-error job can be resumed"
                    + ("" if job.state in ACTIVE else "; start the campaign again as a new job")
                )
            self.refuse_if_active()
            self._refuse_if_latched(f"resume campaign job {job_id}")
            before_spawn(job_id)
            was = job.state, job.message
            job.state, job.requested, job.message = "running", None, None
            try:
                self._save(strict=True)
                self._spawn(job)
            except BaseException:
                job.state, job.message = was  # refused: the job as it was
                self._save()
                raise
            self._events("info", "campaign", f"job {job_id}: resumed by {client}")
            return job.public()

    def _allowed(self, job: Job, client: str, what: str, force: bool) -> None:
        if client in (job.started_by, worker_client(job.id)):
            return
        if force:
            self._events("warning", "campaign",
                         f"job {job.id}: {what} forced by {client} (started by {job.started_by})")  # fmt: skip
            return
        raise NotInControl(
            f"cannot {what} campaign job {job.id}: {job.started_by} started it; ask them, or "
            f"{what} it anyway with `camctl campaign {what} {job.id} --force`"
        )

    # -- the worker -----------------------------------------------------------------------------

    def _spawn(self, job: Job) -> None:
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
            raise _write_error(f"cannot start job {job.id}'s worker in {out}", exc) from None
        self._procs[job.id] = proc
        job.pid, job.runs, job.started_t_s = proc.pid, job.runs + 1, time.time()
        job.resume_on_start, job.estopped = False, False
        self._save()
        threading.Thread(
            target=self._watch, args=(job.id, proc), name=f"camd-job-{job.id}", daemon=True
        ).start()

    def _watch(self, job_id: int, proc: subprocess.Popen[bytes]) -> None:
        """Wait for the worker to exit; take its outcome into the job."""
        code = proc.wait()
        with self._lock:
            job = self._jobs[job_id]
            self._procs.pop(job_id, None)
            if job.started_t_s is not None:
                job.run_time_s += max(0.0, time.time() - job.started_t_s)
            job.pid, job.started_t_s = None, None
            outcome = self._outcome(job)
            if job.resume_on_start and code not in (0, 1):
                job.state, job.resume_on_start = "interrupted", True
                job.message = "the daemon stopped during the run; it resumes when it starts"
            elif outcome is not None and code in EXIT_STATES:
                job.state = EXIT_STATES[code]
                job.message = outcome.get("message")
                job.passed = outcome.get("passed")
                job.report = outcome.get("report")
            else:
                job.state = "error"
                job.message = (outcome or {}).get("message") or (
                    f"the worker exited with status {code}: {self._log_tail(job)}"
                )
            if job.state == "aborted" or job.requested == "abort":
                job.state = "aborted"
            elif job.estopped and job.state != "passed":
                # Whatever the cut-off worker made of it (a refused request is an error to
                # it), the job is paused: resumable once the emergency stop is released.
                job.state = "paused"
                job.message = (
                    "paused by an emergency stop: release it (`camctl estop release`), then "
                    f"`camctl campaign resume {job_id}`"
                )
            job.requested = None
            self._save()
            self._events(
                "info" if job.state in ("passed", "paused", "interrupted") else "warning",
                "campaign",
                f"job {job_id}: {job.state}" + (f" ({job.message})" if job.message else ""),
            )
        # Outside the lock: the session ends the worker's control (and its acquisition).
        self._worker_ended(job_id, f"its worker exited with status {code}")

    @staticmethod
    def _outcome(job: Job) -> dict[str, Any] | None:
        path = Path(job.out_dir) / "outcome.json"
        try:
            doc = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return None
        return doc if isinstance(doc, dict) and doc.get("run") == job.runs else None

    @staticmethod
    def _log_tail(job: Job) -> str:
        try:
            text = (Path(job.out_dir) / "worker.log").read_text(errors="replace")
        except OSError:
            return "no log"
        tail = " ".join(text.strip().splitlines()[-3:])
        return tail[-LOG_TAIL_CHARS:] or "no output"

    def _kill_if_stuck(self, job_id: int) -> None:
        """A worker that has not stopped STOP_GRACE_S after a pause or abort is killed (a
        measurement step runs to its end first; none takes that long on the shipped ones)."""
        deadline = time.monotonic() + STOP_GRACE_S
        while time.monotonic() < deadline:
            with self._lock:
                proc = self._procs.get(job_id)
            if proc is None or self._stopping:
                return  # stopped, or the daemon's own stop takes it over
            time.sleep(0.2)
        with self._lock:
            proc = self._procs.get(job_id)
        if proc is not None:
            self._events("warning", "campaign",
                         f"job {job_id}: the worker did not stop within {STOP_GRACE_S:g} s; "
                         "killed")  # fmt: skip
            _terminate(proc, 5.0)

    # -- the daemon's start and stop -----------------------------------------------------------

    def resume_interrupted(self) -> list[int]:
        """At the daemon's start: stop any worker a killed daemon left, then resume the jobs
        the last daemon was running when it stopped. Returns their ids."""
        resumed: list[int] = []
        with self._lock:
            for job in self._jobs.values():
                if job.state in ACTIVE or job.resume_on_start:
                    if job.pid is not None:
                        _stop_leftover(job.pid, job.id)
                        job.pid = None
                    if job.started_t_s is not None:  # cut off by a killed daemon: no end time
                        job.started_t_s = None
                    if job.state == "pausing":
                        job.state, job.requested = "paused", None
                    elif job.state == "aborting":
                        job.state, job.requested = "aborted", None
                    elif self._estop_latched():
                        job.state, job.requested, job.resume_on_start = "interrupted", None, False
                        job.message = (
                            "not resumed at start: the emergency stop is latched; release it "
                            f"(`camctl estop release`), then `camctl campaign resume {job.id}`"
                        )
                        self._events("warning", "campaign", f"job {job.id}: {job.message}")
                    else:
                        job.state, job.requested, job.message = "running", None, None
                        self._spawn(job)
                        resumed.append(job.id)
                        self._events("info", "campaign", f"job {job.id}: resumed at start")
            self._save()
        return resumed

    def stopping(self) -> None:
        """The daemon's stop has begun (its API stops answering first, so the worker may fail
        before ``close``): the running job is to resume at the next start, whatever its
        worker says now."""
        with self._lock:
            self._stopping = True
            changed = False
            for job_id in self._procs:
                job = self._jobs[job_id]
                if job.state == "running" and not job.resume_on_start:
                    job.resume_on_start = changed = True
            if changed:
                self._save()

    def close(self) -> None:
        """At the daemon's stop: stop the running worker (it leaves its state file as a Ctrl-C
        does); its job resumes at the next start (``stopping``)."""
        self.stopping()
        with self._lock:
            procs = list(self._procs.values())
        for proc in procs:
            _terminate(proc, SHUTDOWN_WAIT_S)

    # -- jobs.json ------------------------------------------------------------------------------

    def _get(self, job_id: int) -> Job:
        job = self._jobs.get(job_id)
        if job is None:
            known = ", ".join(str(i) for i in self._jobs) or "none"
            raise NotFound(f"no campaign job {job_id} (jobs: {known}); `camctl campaign status`")
        return job

    def _load(self) -> None:
        try:
            doc = json.loads(self._path.read_text(encoding="utf-8"))
        except FileNotFoundError:
            return
        except (OSError, ValueError) as exc:
            self._events("warning", "campaign", f"{self._path}: unreadable ({exc}); kept aside "
                         "and starting with no jobs")  # fmt: skip
            with contextlib.suppress(OSError):
                self._path.replace(self._path.with_suffix(".json.unreadable"))
            return
        if doc.get("format") != JOBS_FORMAT or doc.get("version") != JOBS_VERSION:
            return
        for entry in doc.get("jobs", []):
            with contextlib.suppress(ValidationError):
                job = Job.model_validate(entry)
                self._jobs[job.id] = job

    def _save(self, *, strict: bool = False) -> None:
        """Rewrite jobs.json. A failure (a full disk) raises StorageFull or BadRequest with
        ``strict`` (a start or resume is then refused); otherwise the jobs stay in memory, the
        failure is said once and the next change tries again."""
        doc = {
            "format": JOBS_FORMAT,
            "version": JOBS_VERSION,
            "jobs": [job.model_dump() for job in self._jobs.values()],
        }
        tmp = self._path.with_suffix(".json.tmp")
        try:
            self._dir.mkdir(parents=True, exist_ok=True)
            tmp.write_text(json.dumps(doc, indent=1) + "\n", encoding="utf-8")
            os.replace(tmp, self._path)
        except OSError as exc:
            with contextlib.suppress(OSError):
                tmp.unlink(missing_ok=True)
            error = _write_error(f"cannot write {self._path}", exc)
            if strict:
                raise error from None
            if not self._save_failed:
                self._events("warning", "campaign", f"{error}; the jobs are kept in memory")
            self._save_failed = True
            return
        if self._save_failed:
            self._events("info", "campaign", f"{self._path} written again")
        self._save_failed = False


def _terminate(proc: subprocess.Popen[bytes], wait_s: float) -> None:
    with contextlib.suppress(ProcessLookupError):
        proc.send_signal(signal.SIGTERM)
    try:
        proc.wait(wait_s)
    except subprocess.TimeoutExpired:
        with contextlib.suppress(ProcessLookupError):
            proc.kill()
        proc.wait()


def _stop_leftover(pid: int, job_id: int) -> None:
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


def _write_error(what: str, exc: OSError) -> SessionError:
    """A file the jobs need could not be written: StorageFull (507) for a full disk, else
    BadRequest saying why."""
    if exc.errno in (errno.ENOSPC, errno.EDQUOT):
        return StorageFull(
            f"{what}: the disk is full (No space left on device); free some space on the "
            "daemon's data disk, then try again"
        )
    return BadRequest(f"{what}: {exc.strerror or exc}")
