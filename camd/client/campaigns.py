"""Campaign jobs in the daemon: start, follow, pause, resume, abort (docs/campaigns.md,
"Campaign jobs")."""

from __future__ import annotations

from typing import Any, Unpack, cast

import httpx

from camd.client.connection import API, HttpClient
from camd.client_requests import CampaignActionRequestOptions, CampaignStartRequestOptions
from camd.client_types import CampaignJob, CampaignJobsResponse


class CampaignsClient(HttpClient):
    """The client of the campaign job routes."""

    def campaign_jobs(self) -> CampaignJobsResponse:
        """Every campaign job the daemon knows, running or ended."""
        return cast(CampaignJobsResponse, self._json("GET", f"{API}/campaigns/jobs"))

    def campaign_job(self, job_id: int) -> CampaignJob:
        """One campaign job (CamdError ``not_found`` if there is none)."""
        return cast(CampaignJob, self._json("GET", f"{API}/campaigns/jobs/{job_id}"))

    def start_campaign(
        self, campaign: str, **options: Unpack[CampaignStartRequestOptions]
    ) -> CampaignJob:
        """Start a campaign job on the daemon (``campaign``: a campaign's name in the daemon's
        campaign directories, never a path; ``out``: its output directory there, relative = in
        the data directory's campaigns; ``quick``: the campaign's CI-sized overrides); returns
        at once with the job, which runs in the daemon's worker. Needs control (or free
        control), which passes to the job's worker."""
        body: dict[str, Any] = {"campaign": campaign, **options}
        # The daemon checks the campaign in a process of its own first: allow it some time.
        timeout = httpx.Timeout(self.timeout_s, read=max(self.timeout_s, 90.0))
        return cast(
            CampaignJob, self._json("POST", f"{API}/campaigns/jobs", json=body, timeout=timeout)
        )

    def pause_campaign(
        self, job_id: int, **options: Unpack[CampaignActionRequestOptions]
    ) -> CampaignJob:
        """Pause a running job (its acquisition is stopped and done again on resume); ``force``
        pauses another client's job."""
        return self._job_action(job_id, "pause", options)

    def resume_campaign(self, job_id: int) -> CampaignJob:
        """Run a paused (or interrupted, or failed-with-an-error) job on from its state."""
        return cast(CampaignJob, self._json("POST", f"{API}/campaigns/jobs/{job_id}/resume"))

    def abort_campaign(
        self, job_id: int, **options: Unpack[CampaignActionRequestOptions]
    ) -> CampaignJob:
        """Abort a job (running: stopped as for a pause; paused: ended at once); ``force``
        aborts another client's job."""
        return self._job_action(job_id, "abort", options)

    def _job_action(
        self, job_id: int, action: str, options: CampaignActionRequestOptions
    ) -> CampaignJob:
        path = f"{API}/campaigns/jobs/{job_id}/{action}"
        return cast(CampaignJob, self._json("POST", path, json=options))
