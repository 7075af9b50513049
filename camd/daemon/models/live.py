"""Bodies and limits of the live view's routes: the background and its bounds (the frame and
the waterfall answer raw bytes)."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, Field

from camd.daemon.models.common import _Request

LIVE_LINES_MAX = 2048  # lines the live view's waterfall keeps, and the most one request gets


LIVE_WAIT_MAX_S = 5.0  # longest a live-view request waits for something newer


BACKGROUND_FRAMES_MAX = 1000  # = camd.pipeline.background.FRAMES_MAX


BACKGROUND_FRAMES_DEFAULT = 16


class BackgroundRequest(_Request):
    """POST /api/v1/live/background."""

    frames: int = Field(
        default=BACKGROUND_FRAMES_DEFAULT,
        ge=1,
        le=BACKGROUND_FRAMES_MAX,
        description=f"frames to average, 1..{BACKGROUND_FRAMES_MAX}",
    )


class BackgroundStatus(BaseModel):
    """GET /api/v1/live/background, and the answer of POST and DELETE there. While capturing
    (and after a failure) the geometry and counters are those of the frames taken so far; a
    field that does not apply is null."""

    state: Literal["none", "capturing", "ready", "failed"] = Field(
        description="none: no background; capturing: averaging frames; ready: the mean is "
        "there (GET /api/v1/live/background/frame); failed: see error"
    )
    frames_wanted: int | None = Field(description="frames the capture averages")
    frames_done: int | None = Field(description="frames averaged so far")
    rows: int | None
    cols: int | None
    mode: str | None = Field(description="the frames' mode (area, tdi)")
    stages: int | None = Field(description="TDI stages in the frame headers (0 in area mode)")
    first_counter: int | None = Field(description="the device's counter of the first frame")
    last_counter: int | None = Field(description="... and of the last frame averaged so far")
    captured_t_s: float | None = Field(description="Unix time the capture completed")
    seq: int | None = Field(description="completed captures since the daemon started")
    mean_dn: float | None = Field(description="spatial mean of the background, DN")
    std_dn: float | None = Field(description="spatial standard deviation of the background, DN")
    saved_to: list[str] = Field(
        description="recordings started since it was captured, which hold it as /background "
        "(newest last, the last 20)"
    )
    error: str | None = Field(description="why the capture failed, and what to do")
