"""The daemon's campaign jobs as ``<data_dir>/campaigns/jobs.json`` keeps them.

``JobStore`` holds every job the daemon knows (``Job``: the API's document and what only the
daemon needs), read from jobs.json when the daemon starts and rewritten atomically at each
change, so that a restarted daemon knows them all. An unreadable file is kept aside
(``jobs.json.unreadable``) and the daemon starts with no jobs; a file that cannot be written
(a full disk) refuses a start or resume (``save(strict=True)``), and otherwise keeps the jobs
in memory, says so once and tries again at the next change.

The store does no locking of its own: its callers hold the campaign jobs' lock
(``camd.daemon.campaign_jobs``).
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from camd.daemon.errors import BadRequest, NotFound, SessionError, StorageFull
from camd.daemon.models import CampaignJob

JOBS_FORMAT = "camd-campaign-jobs"
JOBS_VERSION = 1

# The states of a job; ACTIVE ones have (or are about to have) a worker.
ACTIVE = ("running", "pausing", "aborting")
RESUMABLE = ("paused", "error", "interrupted")

Events = Callable[[str, str, str], None]
"""``(level, source, message)``: the daemon's event log."""


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


class JobStore:
    """The jobs, by id, and their file (module docstring)."""

    def __init__(self, folder: Path, events: Events) -> None:
        self.folder = folder  # the campaigns folder: jobs.json, and the jobs' own directories
        self.path = folder / "jobs.json"
        self._events = events
        self.jobs: dict[int, Job] = {}
        self._save_failed = False  # jobs.json could not be written (said once)
        self._load()

    def get(self, job_id: int) -> Job:
        """The job ``job_id``; NotFound, listing the jobs there are, if there is none."""
        job = self.jobs.get(job_id)
        if job is None:
            known = ", ".join(str(i) for i in self.jobs) or "none"
            raise NotFound(f"no campaign job {job_id} (jobs: {known}); `camctl campaign status`")
        return job

    def _load(self) -> None:
        try:
            doc = json.loads(self.path.read_text(encoding="utf-8"))
        except FileNotFoundError:
            return
        except (OSError, ValueError) as exc:
            self._events("warning", "campaign", f"{self.path}: unreadable ({exc}); kept aside "
                         "and starting with no jobs")  # fmt: skip
            with contextlib.suppress(OSError):
                self.path.replace(self.path.with_suffix(".json.unreadable"))
            return
        if doc.get("format") != JOBS_FORMAT or doc.get("version") != JOBS_VERSION:
            return
        for entry in doc.get("jobs", []):
            with contextlib.suppress(ValidationError):
                job = Job.model_validate(entry)
                self.jobs[job.id] = job

    def save(self, *, strict: bool = False) -> None:
        """Rewrite jobs.json. A failure (a full disk) raises StorageFull or BadRequest with
        ``strict`` (a start or resume is then refused); otherwise the jobs stay in memory, the
        failure is said once and the next change tries again."""
        doc = {
            "format": JOBS_FORMAT,
            "version": JOBS_VERSION,
            "jobs": [job.model_dump() for job in self.jobs.values()],
        }
        tmp = self.path.with_suffix(".json.tmp")
        try:
            self.folder.mkdir(parents=True, exist_ok=True)
            tmp.write_text(json.dumps(doc, indent=1) + "\n", encoding="utf-8")
            os.replace(tmp, self.path)
        except OSError as exc:
            with contextlib.suppress(OSError):
                tmp.unlink(missing_ok=True)
            error = write_error(f"cannot write {self.path}", exc)
            if strict:
                raise error from None
            if not self._save_failed:
                self._events("warning", "campaign", f"{error}; the jobs are kept in memory")
            self._save_failed = True
            return
        if self._save_failed:
            self._events("info", "campaign", f"{self.path} written again")
        self._save_failed = False


def write_error(what: str, exc: OSError) -> SessionError:
    """A file the jobs need could not be written: StorageFull (507) for a full disk, else
    BadRequest saying why."""
    if exc.errno in (errno.ENOSPC, errno.EDQUOT):
        return StorageFull(
            f"{what}: the disk is full (No space left on device); free some space on the "
            "daemon's data disk, then try again"
        )
    return BadRequest(f"{what}: {exc.strerror or exc}")
