"""Bodies of the push-broom scan's routes (docs/scan.md)."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, Field

from camd.daemon.models.common import _Compressed, _Request
from camd.daemon.models.live import ImageMotionBlock
from camd.daemon.models.stream import Binning, StreamStats

SCAN_LINE_PERIOD_MAX_S = 10.0  # the longest TDI line period a scan takes, given or implied


TdiMode = Literal["sum", "mean"]


ScanState = Literal["none", "starting", "running", "done", "stopped", "ended_early", "failed"]


class ScanRequest(_Compressed):
    """POST /api/v1/scan/start: a push-broom scan with host TDI (docs/scan.md)."""

    stages: int = Field(ge=1, le=4096, description="TDI stages M (1..window rows)")
    lines: int = Field(
        ge=0,
        le=10_000_000,
        description="complete TDI lines wanted; the scan takes lines + M - 1 frames because the "
        "first M - 1 lines lack stages; 0 = until /scan/stop",
    )
    out: str | None = Field(
        default=None,
        description="the new HDF5 file, on the daemon's host: relative = in <data_dir>/scans; "
        "absolute = inside the data directory or daemon.record_dirs (docs/api.md, Files); "
        "null = <data_dir>/scans/scan-<UTC time>.h5",
    )
    scene: str | None = Field(
        default=None, max_length=240, description="simulated camera only: set this scene first"
    )
    speed_m_s: float | None = Field(
        default=None,
        gt=0.0,
        le=10.0,
        description="stage speed: the TDI line period follows from it (docs/physics.md §2); null = "
        "keep the registers' line period and run the stage at the synchronous speed",
    )
    line_period_s: float | None = Field(
        default=None,
        gt=0.0,
        le=SCAN_LINE_PERIOD_MAX_S,
        description="TDI line period to set (docs/physics.md §2 eqs 6-9); exclusive with speed_m_s",
    )
    drive_stage: bool = Field(
        default=True,
        description="drive the scan stage at the synchronous speed (docs/motion.md); false = "
        "leave it alone (an external stage; on the simulator, an ideal one)",
    )
    closed_loop: bool | None = Field(
        default=None, description="correct from the encoder while scanning; null = config"
    )
    image_loop: bool | None = Field(
        default=None,
        description="trim the line period and the drift taps from the image's motion measured "
        "in the frames (docs/motion.md); null = config motion.image_loop",
    )
    dv_over_v: float = Field(
        default=0.0,
        ge=-2.0,
        lt=1.0,
        description="deliberate velocity mismatch (V - V_m)/V: the stage runs at "
        "(1 - dv_over_v) x the synchronous speed (MTF against mismatch, docs/physics.md §6); "
        "a driven stage takes -0.5 .. 0.5, the simulator's ideal stage (drive_stage false, "
        "forwards only) -2 .. below 1",
    )
    mode: TdiMode = Field(default="sum", description="sum (uint32, eq 12) or mean (float32)")
    out_bits: int | None = Field(
        default=None, ge=1, le=32, description="clip sums to 2^out_bits - 1 (eq 12); null = none"
    )
    rows_per_line: float = Field(
        default=1.0, ge=0.0, le=64.0, description="rows the image moves per line (docs/tdi.md)"
    )
    cols_per_line: float = Field(
        default=0.0, ge=-64.0, le=64.0, description="columns of drift per line (docs/tdi.md)"
    )
    reverse: bool = Field(default=False, description="the scene moves from row 1 towards row M")
    binning: Binning = Field(default="off", description="FPGA-side 2x2 binning")
    quicklook: bool = Field(default=True, description="write a PNG quicklook beside the file")


class StagesRequest(_Request):
    """PUT /api/v1/scan/stages."""

    stages: int = Field(ge=1, le=4096, description="new TDI stage count, from the next frame")


class ScanTiming(BaseModel):
    """The timing a scan runs at (docs/physics.md §2 eqs 5-9, 13)."""

    tdi_line_period_s: float = Field(description="T_line,TDI: the frame period the registers set")
    row_period_s: float = Field(description="T_line,roll: the sensor's row time")
    n_lines: int = Field(description="window rows, eq 8")
    back_path_s: float = Field(description="T_back, eq 9")
    max_stages: int = Field(description="M0 = n_lines, eq 13")
    exposure_s: float
    sync_speed_m_s: float = Field(description="stage speed that moves the image one row a period")
    stage_speed_m_s: float | None = Field(
        description="the stage speed the scan runs at (null: not known to camd)"
    )
    dv_over_v: float | None = Field(
        description="(V - V_m) / V, docs/physics.md §6; null if unknown"
    )


class ScanMotionInfo(BaseModel):
    """How a scan drove the stage (docs/motion.md)."""

    closed_loop: str = Field(description="off, step_rate or line_period")
    stage_speed_m_s: float = Field(
        description="signed speed the stage was commanded: sync x (1 - dv_over_v)"
    )
    target_speed_m_s: float = Field(description="the speed the closed loop held")
    loop_samples: int = Field(description="closed-loop polls recorded")
    loop_error: str | None = Field(description="why the loop stopped early, if it did")
    line_period_limited: bool = Field(
        description="line-period correction hit n_lines = M (it could not shorten further)"
    )


class ScanImageLoopInfo(BaseModel):
    """A scan's image loop (docs/motion.md, "Closing the loop on the image")."""

    updates: int = Field(description="blocks it has acted on")
    line_period_s: float = Field(description="the line period it set last")
    cols_per_line: float = Field(description="the drift taps' columns per line it set last")
    limited: bool = Field(description="a limit (motion.max_trim, the drift's) held it back")
    error: str | None = Field(description="why it stopped, if it did (the scan goes on)")


class ScanImageMotion(BaseModel):
    """The image's motion measured from blocks of a scan's frames (docs/motion.md, "The
    image's motion from the frames"): the newest block and the means over the measurable ones
    (null before the first)."""

    blocks: int = Field(description="blocks of the scan's frames measured")
    measurable_blocks: int = Field(description="... of which measurable")
    dv_over_v_mean: float | None = Field(description="mean dV/V (> 0: the image is slow)")
    m_dv_over_v_mean: float | None = Field(description="mean M dV/V, pixels of smear")
    theta_deg_mean: float | None = Field(description="mean drift angle, degrees")
    dv_over_v_sem: float | None = Field(
        description="standard error of the mean dV/V from the blocks' scatter (2 blocks or more)"
    )
    latest: ImageMotionBlock | None
    loop: ScanImageLoopInfo | None = Field(
        default=None, description="the image loop's state (null: the scan does not run one)"
    )


class ScanResponse(BaseModel):
    """GET /api/v1/scan, and the answer of /scan/start, /stop and /stages."""

    state: ScanState
    file: str | None = Field(description="the HDF5 file of the current or last scan")
    quicklook: str | None = Field(description="its PNG quicklook, once written")
    stages: int = Field(description="M now")
    lines_wanted: int = Field(description="complete lines asked for; 0 = until stopped")
    frames_requested: int
    lines: int = Field(description="TDI lines recorded so far")
    complete_lines: int = Field(description="lines with all M stages from consecutive frames")
    lines_flushed: int = Field(
        default=0,
        description="lines on disk: what the file keeps if the daemon dies now (flushed at "
        'least once a second; docs/stream.md "Crash safety")',
    )
    lost_frames: int = Field(description="frames the stream never delivered")
    not_sent_frames: int = Field(
        default=0,
        description="once ended: frames the scan asked for that the camera never sent (the "
        "scan was stopped, failed or ended early: state and error say why), by its own count or, "
        "if it could not say (it died), those the host never accounted for",
    )
    stage_changes: list[tuple[int, int]] = Field(
        description="[line index, stages] for the start and every change"
    )
    mode: TdiMode
    width: int
    elapsed_s: float
    lines_per_s: float
    cpu_load: float = Field(
        description="the daemon's CPU time over the scan's wall time (1.0 = one core busy)"
    )
    tdi_cpu_s: float = Field(description="CPU time of the TDI worker thread")
    backlog_frames: int = Field(description="frames received but not yet through the engine")
    timing: ScanTiming | None
    error: str | None = Field(description="why the scan failed, if it did")
    stream: StreamStats
    mismatch_max: float | None = Field(
        description="largest M |dV/V| of a line (pixels of smear; docs/physics.md §6), from the "
        "encoder counts in the frame headers; null without encoder data"
    )
    mismatch_rms: float | None = Field(description="RMS of M dV/V over the scan's lines")
    mismatch_last: float | None = Field(
        default=None,
        description="the last graded batch's largest M |dV/V| (pixels): the figure now, beside "
        "the scan's max and RMS; null without encoder data",
    )
    mismatch_level: str = Field(description="ok, yellow or red: the worst level reached")
    motion: ScanMotionInfo | None = Field(description="the stage's part of the scan, if driven")
    image_motion: ScanImageMotion | None = Field(
        default=None,
        description="the image's motion measured from the scan's frames (null: not measured, "
        "motion.image_measure = false)",
    )
