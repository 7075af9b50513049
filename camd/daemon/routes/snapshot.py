"""The live view's snapshots (docs/live-view.md, "Snapshots"): the frame as a TIFF of raw DN
with its settings, as displayed (PNG), its ROI statistics (CSV), saved on the daemon on request;
and one raw pixel of a live frame (a binned viewer's readout). Frames are asked for by seq
among the newest the live view holds (``camd.pipeline.live.RECENT_FRAMES``)."""

from __future__ import annotations

import json
from typing import Any

from fastapi import APIRouter, Query, Response

from camd.analysis.roi_table import roi_csv
from camd.daemon.error_body import error_response
from camd.daemon.models import ErrorResponse, LivePixel, SnapshotRequest, SnapshotSaved
from camd.daemon.request_guard import API
from camd.daemon.routes.deps import Session, needs_control, no_frame
from camd.daemon.session import DeviceSession
from camd.daemon.snapshot import (
    SNAPSHOTS_FOLDER,
    colormaps,
    default_contrast,
    display_png,
    frame_roi_stats,
    read_or_why,
    save_snapshot,
    snapshot_metadata,
    snapshot_name,
    snapshot_tiff,
)
from camd.pipeline.live import RECENT_FRAMES, LiveFrame

router = APIRouter(prefix=f"{API}/live", tags=["live"])


# What asks for a live frame by seq may answer: none yet, or no longer held.
FRAME_SEQ_RESPONSES: dict[int | str, dict[str, Any]] = {
    404: {"model": ErrorResponse, "description": "no frame (or no ROI statistics) yet"},
    409: {"model": ErrorResponse, "description": "the live view no longer holds that seq"},
}
# A snapshot's files: the TIFF of raw DN, the display's PNG and the ROI statistics' CSV.
SNAPSHOT_RESPONSES: dict[int | str, dict[str, Any]] = {
    200: {"content": {"image/tiff": {}, "image/png": {}, "text/csv": {}}},
    **FRAME_SEQ_RESPONSES,
}


def _attachment(name: str) -> str:
    return f'attachment; filename="{name}"'


SEQ_QUERY = Query(
    default=None,
    ge=1,
    description="the live frame's seq (as X-Camd-Frame gave it; omitted: the newest); the "
    f"live view holds its newest {RECENT_FRAMES}",
)


def _snapshot_frame(session: DeviceSession, seq: int | None) -> LiveFrame | Response:
    """The live view's frame ``seq`` (None: the newest), or the 404 / 409 to answer instead."""
    frame = session.live.latest() if seq is None else session.live.frame(seq)
    if frame is not None:
        return frame
    held = session.live.held()
    if held is None:
        return no_frame()
    oldest, newest = held
    return error_response(
        409,
        "frame_gone",
        f"the live view holds seq {oldest}..{newest}, not {seq}: it keeps its newest "
        f"{RECENT_FRAMES} frames only; omit seq for the newest (its X-Camd-Frame says which)",
    )


def _snapshot_headers(frame: LiveFrame, suffix: str) -> dict[str, str]:
    return {
        "X-Camd-Frame": json.dumps(frame.meta()),
        "Content-Disposition": f'attachment; filename="{snapshot_name(frame, suffix)}"',
        "Cache-Control": "no-store",
    }


@router.get("/snapshot/frame.tiff", response_class=Response, responses=SNAPSHOT_RESPONSES)
def get_live_snapshot_tiff(session: Session, seq: int | None = SEQ_QUERY) -> Response:
    """The live view's newest frame as a TIFF of raw DN (uint16, one page) whose
    ImageDescription is JSON: the frame's description, the daemon's version and status, the
    camera's profile, registers and timing, the ROIs and their statistics on this frame
    (docs/live-view.md, "Snapshots"). The header ``X-Camd-Frame`` says which frame it is.
    404 no_frame before any; 409 frame_gone if the live view no longer holds ``seq`` (it
    keeps its newest few). Reading never needs control; the daemon writes no file."""
    frame = _snapshot_frame(session, seq)
    if isinstance(frame, Response):
        return frame
    content = snapshot_tiff(frame.pixels, snapshot_metadata(frame, _settings(session, frame)))
    return Response(
        content=content, media_type="image/tiff", headers=_snapshot_headers(frame, "tiff")
    )


def _settings(session: DeviceSession, frame: LiveFrame) -> dict[str, Any]:
    """What a snapshot's metadata says of the camera, read now (each part that cannot be read,
    e.g. without a camera, says why instead), and the ROIs' statistics on ``frame``."""
    sensor = session.sensor
    return {
        "status": session.status().model_dump(mode="json"),
        "stream": session.stream.status_info(),
        "profile": read_or_why(sensor.profile_metadata),
        "registers": read_or_why(sensor.register_values),
        "timing": read_or_why(lambda: sensor.timing().model_dump(mode="json")),
        "rois": session.roi.listing().model_dump(mode="json")["rois"],
        "roi_stats": frame_roi_stats(session.roi.monitor.history(), frame),
    }


@router.get("/snapshot/roi.csv", response_class=Response, responses=SNAPSHOT_RESPONSES)
def get_live_snapshot_roi_csv(session: Session, seq: int | None = SEQ_QUERY) -> Response:
    """Every ROI's statistics on the live view's frame (the frame the TIFF snapshot is of) as
    CSV, one ROI a row: roi, x, y, width, height, counter, timestamp_ns, mean_dn, std_dn,
    min_dn, max_dn, sum_dn, snr, saturated, bg_mean_dn (an empty cell: not defined). 404
    no_frame before any frame, no_roi_stats when that frame was not measured (no ROI, or the
    ROIs changed since); 409 frame_gone as for the TIFF."""
    frame = _snapshot_frame(session, seq)
    if isinstance(frame, Response):
        return frame
    stats = frame_roi_stats(session.roi.monitor.history(), frame)
    if stats is None:
        return error_response(
            404,
            "no_roi_stats",
            f"no ROI statistics of the live frame (seq {frame.seq}): define an ROI "
            "(POST /api/v1/live/roi, `camctl roi add`) and stream; every frame is measured "
            "from the next one on",
        )
    rois = session.roi.listing().model_dump(mode="json")["rois"]
    return Response(
        content=roi_csv(frame.counter, frame.timestamp_ns, stats, rois),
        media_type="text/csv",
        headers=_snapshot_headers(frame, "csv"),
    )


@router.get("/snapshot/display.png", response_class=Response, responses=SNAPSHOT_RESPONSES)
def get_live_snapshot_png(
    session: Session,
    seq: int | None = SEQ_QUERY,
    lo: float | None = Query(default=None, description="DN shown black (with hi)"),
    hi: float | None = Query(default=None, description="DN shown white (with lo)"),
    colormap: str = Query(default="gray", description="gray, viridis, inferno, cividis, turbo"),
) -> Response:
    """The live frame ``seq`` as the page displays it, an RGB PNG: DN ``lo``..``hi`` (both
    omitted: the page's default, the 0.1 and 99.9 % percentiles) onto ``colormap``'s 256
    colours, clipped at both ends; one image pixel a frame pixel. 404 no_frame, 409
    frame_gone as for the TIFF; 400 for a colour map not offered or lo not below hi."""
    maps = colormaps()
    if colormap not in maps:
        return error_response(
            400,
            "bad_request",
            f"colormap {colormap!r} is not offered: use {', '.join(maps)}",
        )
    if (lo is None) != (hi is None):
        return error_response(
            400,
            "bad_request",
            "give lo and hi together (the DN shown black and white), or neither",
        )
    if lo is not None and hi is not None and not lo < hi:
        return error_response(
            400,
            "bad_request",
            f"lo ({lo:g}) must be below hi ({hi:g}): the DN shown black and white",
        )
    frame = _snapshot_frame(session, seq)
    if isinstance(frame, Response):
        return frame
    if lo is None or hi is None:
        lo, hi = default_contrast(frame.pixels)
    content = display_png(frame.pixels, lo, hi, maps[colormap])
    return Response(
        content=content, media_type="image/png", headers=_snapshot_headers(frame, "png")
    )


@router.post(
    "/snapshot",
    response_model=SnapshotSaved,
    responses=FRAME_SEQ_RESPONSES,
    dependencies=[needs_control("save a snapshot on the daemon's disk")],
)
def post_live_snapshot(session: Session, body: SnapshotRequest | None = None) -> Any:
    """Save the snapshot of the live frame ``seq`` (null: the newest) in the data directory's
    ``snapshots`` folder: the TIFF of ``GET /snapshot/frame.tiff`` and, when an ROI measured
    the frame, the CSV of ``GET /snapshot/roi.csv``, named ``camd-snapshot-<UTC
    time>-seq<seq>``; never over a file. 404 no_frame, 409 frame_gone as for the GET, 507
    when the disk is full (nothing left). Writes the daemon's disk: needs control."""
    frame = _snapshot_frame(session, (body or SnapshotRequest()).seq)
    if isinstance(frame, Response):
        return frame
    files = {
        "tiff": snapshot_tiff(frame.pixels, snapshot_metadata(frame, _settings(session, frame)))
    }
    stats = frame_roi_stats(session.roi.monitor.history(), frame)
    if stats is not None:
        rois = session.roi.listing().model_dump(mode="json")["rois"]
        files["csv"] = roi_csv(frame.counter, frame.timestamp_ns, stats, rois).encode()
    folder = session.config.daemon.data_dir / SNAPSHOTS_FOLDER
    paths = save_snapshot(folder, frame, files)
    return SnapshotSaved(seq=frame.seq, counter=frame.counter, files=[str(p) for p in paths])


@router.get("/pixel", response_model=LivePixel, responses=FRAME_SEQ_RESPONSES)
def get_live_pixel(
    session: Session,
    row: int = Query(ge=0, description="the pixel's row in the camera's frame"),
    col: int = Query(ge=0, description="the pixel's column in the camera's frame"),
    seq: int | None = SEQ_QUERY,
) -> Any:
    """One pixel's raw DN in the live frame ``seq`` (omitted: the newest): what a viewer of a
    binned live view (``/live/ws?bin=4``) reads under its cursor. ``{"seq", "counter", "row",
    "col", "raw_dn"}``. 404 no_frame, 409 frame_gone as for a snapshot; 400 outside the
    frame."""
    frame = _snapshot_frame(session, seq)
    if isinstance(frame, Response):
        return frame
    if row >= frame.rows or col >= frame.cols:
        return error_response(
            400,
            "bad_request",
            f"pixel (row {row}, col {col}) is outside the {frame.rows} x {frame.cols} frame of "
            f"seq {frame.seq}: rows 0..{frame.rows - 1}, columns 0..{frame.cols - 1}",
        )
    return LivePixel(
        seq=frame.seq, counter=frame.counter, row=row, col=col, raw_dn=int(frame.pixels[row, col])
    )
