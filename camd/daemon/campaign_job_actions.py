"""What clients ask of campaign jobs: start, pause, resume, abort; who may ask, who holds control.

``JobActions`` is handed the campaign jobs' lock, their store and workers, the event log, the
daemon's way to stop the running acquisition now, the emergency-stop latch and where
campaigns are found. Each action checks first and changes nothing when it refuses:

- start: the campaign is found by name (never a path), the output directory a client names is
  confined like a recording, the campaign is checked in a worker; then the job is noted in
  jobs.json, the requester's control handed over (``before_spawn``, the campaign service's)
  and its worker started. Busy while another job runs;
- pause and abort: ``requested`` is set for the worker to see at its next step boundary, the
  running acquisition is stopped at once, and a worker that does not stop in time is killed;
  abort ends a paused job at once. Only the client that started the job (or its worker) may
  ask, unless it forces;
- resume: a new worker runs the job on from its state file, with control handed over as for
  a start;
- the emergency stop: the running job is to pause, and its worker may not take control again
  (``refuse_control``) until the job is resumed.

Nothing starts or resumes while the emergency stop is latched.
"""

from __future__ import annotations

import contextlib
import os
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from camd.daemon.campaign_dirs import CampaignDirs
from camd.daemon.campaign_job_store import ACTIVE, RESUMABLE, Events, Job, JobStore
from camd.daemon.campaign_worker import CampaignWorkers, worker_client
from camd.daemon.errors import BadRequest, Busy, EstopLatched, NotInControl, WrongState
from camd.daemon.estop import RELEASE_HINT
from camd.daemon.output_paths import resolve_output


@dataclass(eq=False)
class JobActions:
    """Start, pause, resume and abort campaign jobs (module docstring)."""

    _lock: threading.RLock
    _store: JobStore
    _workers: CampaignWorkers
    _events: Events
    _stop_acquisition: Callable[[], object]
    _estop_latched: Callable[[], bool]
    _campaigns: CampaignDirs
    _record_dirs: Sequence[Path]  # where else an out directory may be

    def __post_init__(self) -> None:
        self._record_dirs = tuple(self._record_dirs)  # the caller's list may change later

    # -- starting -------------------------------------------------------------------------------

    def start(
        self,
        campaign: str,
        out_dir: str | None,
        quick: bool,
        client: str,
        before_spawn: Callable[[int], None],
    ) -> dict[str, Any]:
        """See ``CampaignJobs.start``."""
        store = self._store
        with self._lock:
            self.refuse_if_active()
            self._refuse_if_latched("start a campaign job")
            if not self._workers.attached:
                raise WrongState("campaign jobs start once the daemon serves its API; retry")
        campaign_path = self._campaigns.find(campaign)
        # A directory the client named is checked first: refused at once, no worker started.
        named_out = None if out_dir is None else self._check_out_dir(out_dir)
        checked = self._workers.check(str(campaign_path), quick)
        with self._lock:
            self.refuse_if_active()
            job_id = max(store.jobs, default=0) + 1
            out = named_out or store.folder / f"{job_id}-{checked['campaign']}"
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
            store.jobs[job_id] = job
            try:
                # jobs.json first: a job the next daemon would not know of is not started.
                store.save(strict=True)
                self._workers.spawn(job)
            except BaseException:
                del store.jobs[job_id]  # refused: no job, nothing written
                store.save()
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

    def refuse_if_active(self) -> None:
        """Busy, naming the job, while one runs (one job runs at a time)."""
        for job in self._store.jobs.values():
            if job.state in ACTIVE:
                raise Busy(
                    f"campaign job {job.id} ({job.campaign}) is {job.state}; one job runs at a "
                    f"time: pause or abort it first (`camctl campaign pause {job.id}`)"
                )

    def _check_out_dir(self, out_dir: str) -> Path:
        """The job's output directory a client named, resolved and confined like a recording
        (``camd.daemon.output_paths``: relative to the campaigns folder); BadRequest if it
        is outside the allowed directories, a file, or not writable. Nothing is created."""
        folder = self._store.folder
        out = resolve_output(
            out_dir,
            field="out",
            relative_to=folder,
            data_dir=folder.parent,
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

    # -- control --------------------------------------------------------------------------------

    def refuse_control(self, client: str) -> None:
        """NotInControl if ``client`` is the worker of a job that no longer runs, or that an
        emergency stop paused: it may change nothing more, so it may not take control."""
        with self._lock:
            for job in self._store.jobs.values():
                if client != worker_client(job.id):
                    continue
                if job.estopped or job.state not in ACTIVE:
                    why = "an emergency stop paused it" if job.estopped else f"it is {job.state}"
                    raise NotInControl(
                        f"campaign job {job.id}'s worker may not take control: {why}; "
                        f"`camctl campaign resume {job.id}` runs it on with a new worker"
                    )

    def estop(self) -> int | None:
        """See ``CampaignJobs.estop``."""
        with self._lock:
            active = [job for job in self._store.jobs.values() if job.state in ACTIVE]
            if not active:
                return None
            job = active[0]
            job.estopped = True
            if job.state != "aborting":
                job.requested, job.state = "pause", "pausing"
            job.message = "paused by an emergency stop"
            self._store.save()
            self._events("warning", "campaign", f"job {job.id}: paused by the emergency stop")
        self._workers.kill_if_stuck(job.id)
        return job.id

    # -- pause, resume, abort ------------------------------------------------------------------

    def abort(self, job_id: int, client: str, force: bool) -> dict[str, Any]:
        """See ``CampaignJobs.abort``."""
        with self._lock:
            job = self._store.get(job_id)
            if job.state in RESUMABLE:
                self._allowed(job, client, "abort", force)
                job.state, job.message = "aborted", f"aborted by {client} while {job.state}"
                self._store.save()
                self._events("info", "campaign", f"job {job_id}: aborted by {client}")
                return job.public()
        return self.ask(job_id, "abort", client, force)

    def ask(
        self, job_id: int, what: Literal["pause", "abort"], client: str, force: bool
    ) -> dict[str, Any]:
        """Ask the running job to pause or abort: its worker stops at its next step boundary
        (its acquisition is stopped now). WrongState unless it runs."""
        with self._lock:
            job = self._store.get(job_id)
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
            self._store.save()
            self._events("info", "campaign", f"job {job_id}: {what} asked by {client}")
        # Outside the lock: stopping a scan waits for its file to close.
        with contextlib.suppress(Exception):  # nothing running is fine; the worker still stops
            self._stop_acquisition()
        self._workers.kill_if_stuck(job_id)
        with self._lock:
            return self._store.get(job_id).public()

    def resume(
        self, job_id: int, client: str, before_spawn: Callable[[int], None]
    ) -> dict[str, Any]:
        """See ``CampaignJobs.resume``."""
        with self._lock:
            job = self._store.get(job_id)
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
                self._store.save(strict=True)
                self._workers.spawn(job)
            except BaseException:
                job.state, job.message = was  # refused: the job as it was
                self._store.save()
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
