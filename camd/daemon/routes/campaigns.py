"""Campaign jobs (docs/campaigns.md, "Campaign jobs"): start, follow, pause, resume, abort.

A job's worker process takes the requester's control for the run, so these routes check
control themselves (``DeviceSession``), not through ``needs_control``.
"""

from __future__ import annotations

from fastapi import APIRouter

from camd.daemon.models import (
    CampaignActionRequest,
    CampaignJob,
    CampaignJobsResponse,
    CampaignStartRequest,
)
from camd.daemon.request_guard import API
from camd.daemon.routes.deps import Client, Session

router = APIRouter(prefix=f"{API}/campaigns/jobs", tags=["campaigns"])


@router.get("", response_model=CampaignJobsResponse)
def get_campaign_jobs(session: Session) -> CampaignJobsResponse:
    """Every campaign job this daemon knows (jobs.json in its data directory), running or
    ended. Reading never needs control."""
    return session.campaigns.list_jobs()


@router.post("", response_model=CampaignJob)
def post_campaign_job(session: Session, client: Client, body: CampaignStartRequest) -> CampaignJob:
    """Start a campaign job: the campaign is loaded and checked whole in a worker process
    first (400 with the reason if it cannot run; nothing is started), then its worker
    starts and this returns at once. The requester's control (or free control) passes to
    the worker, ``campaign-job-<id>``, for the run. 409 while an acquisition or another
    job runs."""
    return session.campaigns.start(body, client)


@router.get("/{job_id}", response_model=CampaignJob)
def get_campaign_job(session: Session, job_id: int) -> CampaignJob:
    """One campaign job; 404 if there is none."""
    return session.campaigns.job(job_id)


@router.post("/{job_id}/pause", response_model=CampaignJob)
def post_campaign_pause(
    session: Session, client: Client, job_id: int, body: CampaignActionRequest
) -> CampaignJob:
    """Pause a running job: its acquisition is stopped at once (and done again on
    resume), its worker stops at the step boundary, puts the daemon's settings back and
    gives control back; the job is then ``paused``. Only its starter may, or anyone with
    ``force``. 409 unless it runs."""
    return session.campaigns.pause(job_id, client, body.force)


@router.post("/{job_id}/resume", response_model=CampaignJob)
def post_campaign_resume(session: Session, client: Client, job_id: int) -> CampaignJob:
    """Resume a paused, interrupted or failed-with-an-error job from its state file: the
    completed steps are replayed, the rest executed. Needs control, which passes to the
    worker as at the start."""
    return session.campaigns.resume(job_id, client)


@router.post("/{job_id}/abort", response_model=CampaignJob)
def post_campaign_abort(
    session: Session, client: Client, job_id: int, body: CampaignActionRequest
) -> CampaignJob:
    """Abort a job: a running one is stopped as for a pause, then ends ``aborted``; a
    paused one ends at once. Its files stay. Only its starter may, or anyone with
    ``force``."""
    return session.campaigns.abort(job_id, client, body.force)
