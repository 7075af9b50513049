"""A scan's status document (``GET /api/v1/scan``, docs/api.md) and its mismatch gauges.

``scan_response`` answers for the current or last scan (``camd.daemon.scan_run.ScanRun``), or
for none yet ("none"): its progress read from the pipeline, its times (until its end once it
has ended), its lost frames (once the stream has ended, by the device's own count) and the
stream's counters. ``mismatch_gauges`` gives the metrics their M |dV/V| figures.
"""

from __future__ import annotations

import time

from camd.daemon.models import ImageMotionBlock, ScanImageLoopInfo, ScanImageMotion, ScanResponse
from camd.daemon.scan_run import ScanRun
from camd.daemon.stream_service import StreamService


def scan_response(scan: ScanRun | None, stream: StreamService) -> ScanResponse:
    """The scan's status document, with the stream's counters."""
    stats = stream.stats()
    if scan is None:
        return ScanResponse(
            state="none", file=None, quicklook=None, stages=0, lines_wanted=0,
            frames_requested=0, lines=0, complete_lines=0, lost_frames=0, not_sent_frames=0,
            stage_changes=[],
            mode="sum", width=0, elapsed_s=0.0, lines_per_s=0.0, cpu_load=0.0,
            tdi_cpu_s=0.0, backlog_frames=0, timing=None, error=None, stream=stats,
            mismatch_max=None, mismatch_rms=None, mismatch_level="ok", motion=None,
        )  # fmt: skip
    progress = scan.pipeline.progress()
    end_mono = scan.ended_mono if scan.ended_mono is not None else time.monotonic()
    end_cpu = scan.ended_cpu if scan.ended_cpu is not None else time.process_time()
    elapsed = max(end_mono - scan.started_mono, 1e-9)
    return ScanResponse(
        state=scan.state,  # type: ignore[arg-type]
        file=str(scan.path),
        quicklook=None if scan.quicklook is None else str(scan.quicklook),
        stages=scan.pipeline.stages,
        lines_wanted=scan.request.lines,
        frames_requested=scan.frames_requested,
        lines=progress.lines,
        complete_lines=progress.complete_lines,
        lines_flushed=scan.pipeline.recorder.flushed_lines,
        lost_frames=_lost_frames(scan, stream, progress.frames_in, progress.gap_frames),
        not_sent_frames=scan.not_sent_frames,
        stage_changes=list(progress.stage_changes),
        mode=scan.request.mode,
        width=scan.pipeline.width,
        elapsed_s=elapsed,
        lines_per_s=progress.lines / elapsed,
        cpu_load=(end_cpu - scan.started_cpu) / elapsed,
        tdi_cpu_s=progress.tdi_cpu_s,
        backlog_frames=progress.backlog_frames,
        timing=scan.timing,
        error=scan.error,
        stream=stats,
        mismatch_max=progress.mismatch_max,
        mismatch_rms=progress.mismatch_rms,
        mismatch_last=progress.mismatch_last,
        mismatch_level=progress.mismatch_level,
        motion=scan.motion_info(),
        image_motion=_image_motion(scan),
    )


def _image_motion(scan: ScanRun) -> ScanImageMotion | None:
    """The image's motion over the scan's measured blocks (None: not measured)."""
    summary = scan.image_motion_summary()
    if summary is None:
        return None
    latest = summary.latest
    return ScanImageMotion(
        blocks=summary.blocks,
        measurable_blocks=summary.measurable_blocks,
        dv_over_v_mean=summary.dv_over_v_mean,
        m_dv_over_v_mean=summary.m_dv_over_v_mean,
        theta_deg_mean=summary.theta_deg_mean,
        dv_over_v_sem=summary.dv_over_v_sem,
        latest=None if latest is None else ImageMotionBlock(**latest.as_dict()),
        loop=None if scan.image_loop is None else _loop_info(scan),
    )


def _loop_info(scan: ScanRun) -> ScanImageLoopInfo:
    assert scan.image_loop is not None
    state = scan.image_loop.info()
    return ScanImageLoopInfo(
        updates=state.updates,
        line_period_s=state.line_period_s,
        cols_per_line=state.cols_per_line,
        limited=state.limited,
        error=state.error,
    )


def mismatch_gauges(scan: ScanRun | None) -> dict[str, float]:
    """The scan's M |dV/V| for the metrics: last batch, max, RMS (none before a scan)."""
    if scan is None:
        return {}
    progress = scan.pipeline.progress()
    values = {
        "last": progress.mismatch_last,
        "max": progress.mismatch_max,
        "rms": progress.mismatch_rms,
    }
    return {k: v for k, v in values.items() if v is not None}


def _lost_frames(scan: ScanRun, stream: StreamService, frames_in: int, gap_frames: int) -> int:
    """Frames of the scan that never reached the engine: lost, corrupt, overrun or cut
    short on the way; once the stream has ended, by the device's own count."""
    if scan.done.is_set() or scan.ended_mono is not None:
        sent = stream.status_info().get("frames_sent")
        if sent is not None:
            return max(0, int(sent) - frames_in)
    return gap_frames
