"""Campaign jobs as the API shows them, with the hand-over of control to their workers.

``CampaignService`` is handed the device access (the acquisition slot, the emergency-stop
latch, the event log), the control of the camera (``Control``: a job's worker holds the
requester's control while it runs) and the session's way to stop the running acquisition
now. It builds the ``CampaignJobs`` that start and supervise the workers (``jobs``: jobs.json,
pause, resume, abort, the shutdown) and serves ``/api/v1/campaigns`` (docs/api.md,
docs/campaigns.md "Campaign jobs"): each job's document carries what its worker last said it
is doing; a start or resume that fails puts control back as it was; a worker that exits,
however it ended, loses its control, and an acquisition it left running is stopped.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator
from typing import Any

from camd.daemon.acquisition import STOP_COMMANDS
from camd.daemon.campaign_jobs import CampaignJobs, worker_client
from camd.daemon.control import Control
from camd.daemon.device import DeviceAccess
from camd.daemon.errors import Busy
from camd.daemon.models import CampaignJob, CampaignJobsResponse, CampaignStartRequest

# A campaign's worker takes the requester's control for this long, renewing it as it runs
# (camd.campaign.runner's lease).
CAMPAIGN_CONTROL_TTL_S = 60.0


class CampaignService:
    """Campaign jobs of one device session (module docstring)."""

    def __init__(
        self, device: DeviceAccess, control: Control, stop_acquisition: Callable[[], bool]
    ) -> None:
        self.device = device
        self.control = control
        self._stop_acquisition = stop_acquisition
        config = device.config
        self.jobs = CampaignJobs(
            config.daemon.data_dir,
            lambda level, source, message: device.log_event(level, source, message),
            stop_acquisition,
            worker_ended=self._worker_ended,
            estop_latched=lambda: device.estop.latched,
            campaign_dirs=config.campaigns.dirs,
            record_dirs=config.daemon.record_dirs,
        )

    def list_jobs(self) -> CampaignJobsResponse:
        return CampaignJobsResponse(jobs=[self._job_doc(doc) for doc in self.jobs.jobs()])

    def job(self, job_id: int) -> CampaignJob:
        return self._job_doc(self.jobs.job(job_id))

    def _job_doc(self, doc: dict[str, Any]) -> CampaignJob:
        """The job with what its worker, holding control, last said it is doing."""
        activity = self.control.activity()
        if activity is not None and activity.client == worker_client(int(doc["id"])):
            doc = {**doc, "activity": activity.text, "done": activity.done}
        return CampaignJob.model_validate(doc)

    def start(self, body: CampaignStartRequest, client: str) -> CampaignJob:
        """Start a campaign job; the requester's control (or free control) goes to its worker.
        Busy while an acquisition or another job runs."""
        self.jobs.refuse_if_active()  # before control: it names the job that runs
        self.control.check(client, "start a campaign")
        running = self.device.acquisition.active
        if running is not None:
            raise Busy(
                f"a {running.kind} is running: a campaign starts from its own baseline; stop it "
                f"first with {STOP_COMMANDS[running.kind]}"
            )

        with self._handing_over(client) as hand_over:
            doc = self.jobs.start(body.campaign, body.out, body.quick, client, hand_over)
        return self._job_doc(doc)

    def resume(self, job_id: int, client: str) -> CampaignJob:
        self.jobs.refuse_if_active()
        self.control.check(client, "resume a campaign")

        with self._handing_over(client) as hand_over:
            return self._job_doc(self.jobs.resume(job_id, client, hand_over))

    @contextlib.contextmanager
    def _handing_over(self, client: str) -> Iterator[Callable[[int], None]]:
        """The hand-over of ``client``'s control (or free control) to a job's worker, put back
        as it was if the start or resume then fails (a refused request changes nothing)."""
        before = self.control.holder()
        handed: list[str] = []

        def hand_over(job_id: int) -> None:
            self.control.hand_over(client, worker_client(job_id), CAMPAIGN_CONTROL_TTL_S)
            handed.append(worker_client(job_id))

        try:
            yield hand_over
        except BaseException:
            for worker in handed:
                self.control.hand_back(worker, before)
            raise

    def pause(self, job_id: int, client: str, force: bool) -> CampaignJob:
        return self._job_doc(self.jobs.pause(job_id, client, force=force))

    def abort(self, job_id: int, client: str, force: bool) -> CampaignJob:
        return self._job_doc(self.jobs.abort(job_id, client, force=force))

    def pause_for_estop(self) -> bool:
        """The emergency stop pauses the running job; True if there was one."""
        job_id = self.jobs.estop()
        if job_id is None:
            return False
        # Its worker changes nothing more (not even its closing "restore settings"): its
        # control ends here, and it may not take control again (take_control).
        self.control.revoke(worker_client(job_id), "the emergency stop paused its job")
        return True

    def _worker_ended(self, job_id: int, why: str) -> None:
        """A job's worker has exited, however it ended: its control ends with it, and an
        acquisition it left running (a killed worker) is stopped: nobody will read it."""
        client = worker_client(job_id)
        running = self.device.acquisition.active
        if running is not None and running.client == client:
            with contextlib.suppress(Exception):
                self._stop_acquisition()
        self.control.revoke(client, why)
