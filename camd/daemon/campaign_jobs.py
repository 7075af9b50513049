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

Its parts, one job each: jobs.json (``campaign_job_store``), the worker processes
(``campaign_worker``: start, watch, stop), and what clients ask of jobs (``campaign_job_actions``:
start, pause, resume, abort, the emergency stop's pause, who may hold control). ``CampaignJobs``
composes them, takes a worker's exit into its job, and runs the daemon's start and stop.
"""

from __future__ import annotations

import sys
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from camd.daemon.campaign_dirs import CampaignDirs
from camd.daemon.campaign_job_actions import JobActions
from camd.daemon.campaign_job_store import ACTIVE, Events, Job, JobStore
from camd.daemon.campaign_worker import EXIT_STATES, CampaignWorkers, stop_leftover, worker_client
from camd.daemon.output_paths import CAMPAIGNS_FOLDER

__all__ = ["ACTIVE", "CampaignJobs", "Job", "worker_client"]


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
        self._events = events
        self._worker_ended = worker_ended
        self._estop_latched = estop_latched
        self.campaigns = CampaignDirs(campaign_dirs)
        self._lock = threading.RLock()
        self._store = JobStore(data_dir / CAMPAIGNS_FOLDER, events)
        self._workers = CampaignWorkers(python, self._lock, self._store, events, self._exited)
        self._actions = JobActions(
            self._lock,
            self._store,
            self._workers,
            events,
            stop_acquisition,
            estop_latched,
            self.campaigns,
            record_dirs,
        )

    # -- reading --------------------------------------------------------------------------------

    def jobs(self) -> list[dict[str, Any]]:
        with self._lock:
            return [job.public() for job in self._store.jobs.values()]

    def job(self, job_id: int) -> dict[str, Any]:
        with self._lock:
            return self._store.get(job_id).public()

    # -- starting -------------------------------------------------------------------------------

    def attach(self, url: str, token: str) -> None:
        """Where the workers find the API (known once the daemon has bound its socket)."""
        self._workers.attach(url, token)

    def check(self, file: str, quick: bool) -> dict[str, Any]:
        """Load and check the campaign file ``file`` (found by ``CampaignDirs.find``) in a worker, without
        running it: {"file", "campaign", "profile", "steps"}; BadRequest with the worker's
        reason when it is not a valid campaign. Once the API serves, the worker checks the
        camera too, as the runner does before its first step (the campaign's profile must be
        the daemon's sensor): a job for another camera is refused here, not 2 s after it was
        accepted, holding control."""
        return self._workers.check(file, quick)

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
        return self._actions.start(campaign, out_dir, quick, client, before_spawn)

    def refuse_control(self, client: str) -> None:
        """NotInControl if ``client`` is the worker of a job that no longer runs, or that an
        emergency stop paused: it may change nothing more, so it may not take control."""
        self._actions.refuse_control(client)

    def estop(self) -> int | None:
        """The emergency stop: the running job (if any) is to pause, its worker to change
        nothing more (module docstring). The id of the job, or None."""
        return self._actions.estop()

    def refuse_if_active(self) -> None:
        """Busy, naming the job, while one runs (one job runs at a time)."""
        self._actions.refuse_if_active()

    # -- pause, resume, abort ------------------------------------------------------------------

    def pause(self, job_id: int, client: str, *, force: bool = False) -> dict[str, Any]:
        """Ask the running job to pause (see the module docstring); WrongState unless it
        runs."""
        return self._actions.ask(job_id, "pause", client, force)

    def abort(self, job_id: int, client: str, *, force: bool = False) -> dict[str, Any]:
        """Abort the job: a running one is stopped as for a pause, then ends "aborted"; a
        paused one ends at once. WrongState once it has ended."""
        return self._actions.abort(job_id, client, force)

    def resume(
        self,
        job_id: int,
        client: str,
        before_spawn: Callable[[int], None] = lambda job_id: None,
    ) -> dict[str, Any]:
        """Run a paused (or failed with an error, or interrupted) job on from its state file.
        Busy while another job runs; WrongState for a job that runs or has ended."""
        return self._actions.resume(job_id, client, before_spawn)

    # -- the worker's exit ----------------------------------------------------------------------

    def _exited(self, job_id: int, code: int) -> None:
        """Job ``job_id``'s worker exited with status ``code`` (on its watcher thread): take
        its outcome into the job, then end the worker's control."""
        with self._lock:
            job = self._store.jobs[job_id]
            self._workers.forget(job_id)
            if job.started_t_s is not None:
                job.run_time_s += max(0.0, time.time() - job.started_t_s)
            job.pid, job.started_t_s = None, None
            outcome = self._workers.outcome(job)
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
                    f"the worker exited with status {code}: {self._workers.log_tail(job)}"
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
            self._store.save()
            self._events(
                "info" if job.state in ("passed", "paused", "interrupted") else "warning",
                "campaign",
                f"job {job_id}: {job.state}" + (f" ({job.message})" if job.message else ""),
            )
        # Outside the lock: the session ends the worker's control (and its acquisition).
        self._worker_ended(job_id, f"its worker exited with status {code}")

    # -- the daemon's start and stop -----------------------------------------------------------

    def resume_interrupted(self) -> list[int]:
        """At the daemon's start: stop any worker a killed daemon left, then resume the jobs
        the last daemon was running when it stopped. Returns their ids."""
        resumed: list[int] = []
        with self._lock:
            for job in self._store.jobs.values():
                if job.state in ACTIVE or job.resume_on_start:
                    if job.pid is not None:
                        stop_leftover(job.pid, job.id)
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
                        self._workers.spawn(job)
                        resumed.append(job.id)
                        self._events("info", "campaign", f"job {job.id}: resumed at start")
            self._store.save()
        return resumed

    def stopping(self) -> None:
        """The daemon's stop has begun (its API stops answering first, so the worker may fail
        before ``close``): the running job is to resume at the next start, whatever its
        worker says now."""
        with self._lock:
            self._workers.stopping = True
            changed = False
            for job_id in self._workers.running():
                job = self._store.jobs[job_id]
                if job.state == "running" and not job.resume_on_start:
                    job.resume_on_start = changed = True
            if changed:
                self._store.save()

    def close(self) -> None:
        """At the daemon's stop: stop the running worker (it leaves its state file as a Ctrl-C
        does); its job resumes at the next start (``stopping``)."""
        self.stopping()
        self._workers.close()
