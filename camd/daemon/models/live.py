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


ROI_HISTORY_MAX = 4096  # = camd.pipeline.roi.HISTORY_MAX: frames of ROI statistics kept


class RoiRequest(_Request):
    """POST /api/v1/live/roi: a named rectangle, in pixels from the frame's top left."""

    name: str = Field(
        description="1-32 letters, digits, '_', '.', '-' (not 'frame'); an ROI of that name is "
        "replaced"
    )
    x: int = Field(description="first column")
    y: int = Field(description="first row")
    width: int = Field(description="columns")
    height: int = Field(description="rows")


class RoiDefinition(BaseModel):
    """One ROI as the daemon measures it."""

    name: str
    x: int
    y: int
    width: int
    height: int


class RoiList(BaseModel):
    """GET /api/v1/live/roi, and the answer of POST and DELETE there."""

    rois: list[RoiDefinition] = Field(description="the ROIs measured on every frame")
    rows: int | None = Field(description="the frame height the ROIs were checked against")
    cols: int | None = Field(description="the frame width the ROIs were checked against")


class RoiFrameStats(BaseModel):
    """One ROI's statistics on one frame (DN; null where not defined)."""

    mean_dn: float
    std_dn: float
    min_dn: float
    max_dn: float
    sum_dn: float
    snr: float | None = Field(description="mean / std; null when std is 0")
    saturated: float = Field(description="pixels at or above full scale (2^bits - 1)")
    bg_mean_dn: float | None = Field(description="mean minus the background's; null without one")


class RoiLatest(BaseModel):
    """The newest measured frame's statistics of every ROI."""

    counter: int
    timestamp_ns: int
    rois: dict[str, RoiFrameStats]


class RoiHistorySeries(BaseModel):
    """One ROI's statistics over the newest frames, oldest first (one value per frame)."""

    counter: list[int]
    mean_dn: list[float]
    std_dn: list[float]
    min_dn: list[float]
    max_dn: list[float]
    sum_dn: list[float]
    snr: list[float | None]
    saturated: list[float]
    bg_mean_dn: list[float | None]


class RoiStatsResponse(BaseModel):
    """GET /api/v1/live/roi/stats."""

    rois_seq: int = Field(description="ROI sets so far: a change of the ROIs starts a new history")
    measured: int = Field(description="frames measured since the ROIs were last changed")
    unfit: int = Field(description="frames the ROIs did not fit (a smaller window): not measured")
    latest: RoiLatest | None
    history: dict[str, RoiHistorySeries] = Field(
        description="per ROI, the newest `history` frames (none unless asked)"
    )


FOCUS_HISTORY_MAX = 1200  # = camd.pipeline.focus.FOCUS_HISTORY_MAX: focus figures kept


class FocusLatest(BaseModel):
    """The newest frame's focus figures."""

    seq: int = Field(description="the live frame's seq (GET /api/v1/live/frame)")
    counter: int = Field(description="the device's frame counter")
    t_s: float = Field(description="when it was measured, s since the epoch")
    values: dict[str, float | None] = Field(
        description="grey-gradient sharpness G per target: 'frame' and each ROI's name; null "
        "where there is none (an ROI the frame does not hold, a frame of zeros)"
    )


class FocusBestModel(BaseModel):
    """A target's best focus figure since the last reset, and its frame."""

    value: float
    counter: int
    seq: int
    t_s: float


class FocusHistory(BaseModel):
    """The newest focus figures, oldest first (one entry per measured frame)."""

    seq: list[int]
    counter: list[int]
    t_s: list[float]
    values: dict[str, list[float | None]] = Field(
        description="per target, its figure at each entry (null where it had none)"
    )


class FocusResponse(BaseModel):
    """GET /api/v1/live/focus, and the answer of DELETE /api/v1/live/focus/best."""

    rate_hz: float = Field(description="figures a second at most (of the live view's frames)")
    watching: bool = Field(
        description="figures are being measured: someone asked within the last watch_s"
    )
    watch_s: float = Field(description="measuring goes on this long after the last GET")
    measured: int = Field(description="figures measured since the daemon started")
    latest: FocusLatest | None
    best: dict[str, FocusBestModel] = Field(description="per target, the best since the reset")
    history: FocusHistory


class SnapshotRequest(_Request):
    """POST /api/v1/live/snapshot: save a snapshot in the data directory's snapshots folder."""

    seq: int | None = Field(
        default=None,
        ge=1,
        description="the live frame's seq (as X-Camd-Frame gave it); null: the newest",
    )


class SnapshotSaved(BaseModel):
    """The answer of POST /api/v1/live/snapshot: what was written, on the daemon's computer."""

    seq: int = Field(description="the live frame saved")
    counter: int = Field(description="its device frame counter")
    files: list[str] = Field(
        description="the TIFF, and the ROI statistics' CSV when an ROI measured the frame"
    )


class LivePixel(BaseModel):
    """GET /api/v1/live/pixel: one pixel of a live frame, raw (a binned viewer's readout)."""

    seq: int = Field(description="the live frame")
    counter: int = Field(description="its device frame counter")
    row: int
    col: int
    raw_dn: int = Field(description="the pixel as the camera sent it, DN")


IMAGE_MOTION_HISTORY_MAX = 1024  # = camd.pipeline.image_motion.HISTORY_MAX


class ImageMotionBlock(BaseModel):
    """One block of consecutive TDI window frames and the image's motion measured from it
    (docs/physics.md §10; docs/motion.md, "The image's motion from the frames"). The figures
    are null when the block was not measurable (``why`` says what was missing)."""

    counter_first: int = Field(description="the block's first frame counter")
    counter_last: int = Field(description="... and its last (a gap inside is a lost frame)")
    frames: int
    pairs: int = Field(description="pairs of frames registered")
    stages: int = Field(description="M, as the frames' headers give it")
    columns: list[int] = Field(description="the columns [first, last) measured")
    measured_t_s: float = Field(description="Unix time the measurement ended")
    cpu_s: float = Field(description="CPU time the measurement took")
    measurable: bool
    why: str = Field(description="pairs registered, or why the block could not be measured")
    shift_along_px_per_line: float | None = Field(description="rows the image moved per line")
    shift_across_px_per_line: float | None = Field(description="columns per line")
    shift_along_stderr_px: float | None
    shift_across_stderr_px: float | None
    dv_over_v: float | None = Field(description="1 - shift along: > 0 when the image is slow")
    dv_over_v_stderr: float | None = Field(
        default=None,
        description="its standard error (the shift's, through the rolling shutter's lag; null "
        "with fewer than 3 pairs)",
    )
    m_dv_over_v: float | None = Field(description="M dV/V: the along-track smear, pixels")
    theta_deg: float | None = Field(description="the image's drift angle from the columns")
    row_lag_lines: float = Field(
        description="a rolling shutter's lag between two rows of the frames, in line periods "
        "(T_row / T; twice that for 2x2-binned frames; negative for a reverse scan; 0 for a "
        "global shutter): what turned the frames' step into the image's speed"
    )


class ImageMotionResponse(BaseModel):
    """GET /api/v1/live/motion: the image's motion measured from the streams' TDI windows."""

    enabled: bool = Field(description="motion.image_measure: measuring at all")
    frames_per_block: int
    columns_max: int
    cpu_fraction: float = Field(description="the most of one core the measurement takes")
    blocks_measured: int = Field(description="blocks measured since the daemon started")
    tdi_frames_seen: int = Field(description="TDI frames the streams delivered meanwhile")
    frames_measured: int = Field(description="... of which in a measured block")
    cpu_s: float = Field(description="CPU time of all the measurements")
    latest: ImageMotionBlock | None
    history: list[ImageMotionBlock] = Field(description="the newest blocks, oldest first")
