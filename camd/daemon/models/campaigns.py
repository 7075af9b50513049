"""Bodies of the campaign jobs' routes (docs/campaigns.md, "Campaign jobs")."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, Field

from camd.daemon.models.common import _Request

CampaignJobState = Literal[
    "running", "pausing", "paused", "aborting", "aborted", "passed", "failed", "error",
    "interrupted",
]  # fmt: skip


class CampaignStartRequest(_Request):
    """POST /api/v1/campaigns/jobs."""

    campaign: str = Field(
        min_length=1,
        max_length=100,
        description="the campaign's name (lowercase letters, digits, _): one of the daemon's "
        "campaign directories ([campaigns] dirs in camd.toml, then the shipped ones; "
        "`camctl campaign list`); never a path: the daemon runs no file a client names",
    )
    out: str | None = Field(
        default=None,
        # No max_length: the path rules (camd.daemon.output_paths) bound it, in bytes.
        description="output directory on the daemon's host: relative = in <data_dir>/campaigns; "
        "absolute = inside the data directory or daemon.record_dirs (docs/api.md, Files); "
        "null = <data_dir>/campaigns/<id>-<campaign>",
    )
    quick: bool = Field(default=False, description="the campaign's CI-sized overrides")


class CampaignActionRequest(_Request):
    """POST /api/v1/campaigns/jobs/{id}/pause and /abort."""

    force: bool = Field(
        default=False,
        description="pause or abort a job another client started (logged as a warning)",
    )


class CampaignJob(BaseModel):
    """One campaign job: what runs, where its files go, how far it is."""

    id: int
    campaign: str = Field(description="the campaign's name")
    profile: str = Field(description="the camera profile it is written for")
    file: str = Field(description="the campaign file it runs")
    out_dir: str = Field(description="its output directory: state, raw files, results, report")
    quick: bool
    started_by: str = Field(description="the client that started it (it may pause and abort)")
    state: CampaignJobState
    steps: int | None = Field(description="step instances in a run; null: not known ahead")
    done: int | None = Field(default=None, description="steps done, as its worker last said")
    activity: str | None = Field(default=None, description="what its worker last said it does")
    created_t_s: float = Field(description="Unix time it was started")
    requested: Literal["pause", "abort"] | None = Field(
        description="a pause or abort asked for and not yet done (the worker reads it)"
    )
    run_time_s: float = Field(description="its workers' wall time, summed over resumes")
    runs: int = Field(description="workers started: 1, plus 1 per resume")
    message: str | None = Field(description="why it paused, failed or ended")
    passed: bool | None = Field(description="every check passed (null until it has ended)")
    report: str | None = Field(description="its HTML report, once written")


class CampaignJobsResponse(BaseModel):
    """GET /api/v1/campaigns/jobs."""

    jobs: list[CampaignJob]
