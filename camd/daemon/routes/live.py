"""The live view (docs/live-view.md): the newest frame (polled, or pushed over a WebSocket),
the background, and the TDI waterfall's lines. Pixels leave as raw bytes with a JSON header."""

from __future__ import annotations

import contextlib
import json
import time
from typing import Any

import anyio
import numpy.typing as npt
from fastapi import APIRouter, Query, Response, WebSocket, WebSocketDisconnect

from camd.analysis.roi_table import roi_csv
from camd.daemon.api_token import TOKEN_COOKIE, token_ok
from camd.daemon.error_body import WS_POLICY_VIOLATION, error_response
from camd.daemon.models import (
    LIVE_LINES_MAX,
    LIVE_WAIT_MAX_S,
    ROI_HISTORY_MAX,
    BackgroundRequest,
    BackgroundStatus,
    ErrorResponse,
    LivePixel,
    RoiList,
    RoiRequest,
    RoiStatsResponse,
    SnapshotRequest,
    SnapshotSaved,
)
from camd.daemon.request_guard import API
from camd.daemon.routes.deps import Session, needs_control
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
from camd.pipeline.live_transport import Transport, parse_transport

# LIVE_WAIT_MAX_S (models): longest a live-view request waits for something newer.
LIVE_POLL_S = 1.0  # a WebSocket viewer's wait for the next frame, between checks

# The live view's pixels: raw bytes, or 404 while there are none yet (no_frame, no_scan,
# no_background).
FRAME_RESPONSES: dict[int | str, dict[str, Any]] = {
    200: {"content": {"application/octet-stream": {}}},
    404: {"model": ErrorResponse, "description": "nothing to show yet: the message says why"},
}

router = APIRouter(prefix=f"{API}/live", tags=["live"])


@router.get("/frame", response_class=Response, responses=FRAME_RESPONSES)
def get_live_frame(
    session: Session,
    after: int = Query(
        default=0, ge=0, description="wait for a frame newer than this seq (0: the newest)"
    ),
    timeout_s: float = Query(
        default=LIVE_WAIT_MAX_S, gt=0, le=LIVE_WAIT_MAX_S, description="longest wait, s"
    ),
) -> Response:
    """The live view's newest frame (at most 20 a second are kept, whatever streams):
    raw pixels, little-endian uint16, row by row; the header ``X-Camd-Frame`` holds its
    JSON description (seq, counter, timestamp_ns, mode, stages, rows, cols, skipped,
    gap_before, dtype). Reading never needs control. 404 if no frame newer than ``after``
    came within ``timeout_s``."""
    frame = session.live.latest() if after == 0 else session.live.wait_newer(after, timeout_s)
    if frame is None:
        return _no_frame(after, timeout_s)
    return Response(
        content=frame.pixels.astype("<u2", copy=False).tobytes(),
        media_type="application/octet-stream",
        headers={"X-Camd-Frame": json.dumps(frame.meta()), "Cache-Control": "no-store"},
    )


def _no_frame(after: int = 0, timeout_s: float = 0.0) -> Response:
    """404 no_frame: nothing streamed yet (or nothing newer than ``after`` came in time)."""
    newer = f" newer than seq {after} within {timeout_s:g} s" if after else " yet"
    return error_response(
        404,
        "no_frame",
        f"no live frame{newer}: the live view shows frames while something streams; "
        "start a stream (`camctl stream --frames 100`), a stare or a scan",
    )


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
        return _no_frame()
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


@router.websocket("/ws")
async def live_ws(websocket: WebSocket) -> None:
    """The live view pushed: for each frame the tap keeps (at most 20 a second), a text
    message with its JSON description (as ``X-Camd-Frame``) then a binary one with its
    pixels. A slow viewer gets fewer frames (always the newest), never a backlog, and
    never slows the acquisition. With a token: ``?token=`` or the Authorization header.

    Each viewer sets its transport (docs/live-view.md, "Transport") with the query
    parameters ``bin`` (1, 2, 4, 8: block means), ``max_fps`` (at most that many frames a
    second) and ``compression`` (none, deflate), and changes it with a text message
    ``{"bin": 4, ...}`` (answered ``{"transport": {...}}``). Each frame's description says
    what was applied (rows and cols as sent, frame_rows, frame_cols, bin, compression,
    max_fps, bytes). Bad settings: a text message ``{"error", "code": "bad_request"}``; in
    the query, the socket is then closed (1008), in a message the settings are unchanged."""
    token: str = websocket.app.state.token
    if token and not token_ok(
        token,
        websocket.headers.get("authorization", ""),
        websocket.query_params.get("token"),
        websocket.cookies.get(TOKEN_COOKIE),
    ):
        await websocket.close(code=WS_POLICY_VIOLATION, reason="no or wrong token")
        return
    await websocket.accept()
    try:
        transport = parse_transport(dict(websocket.query_params))
    except ValueError as exc:
        await websocket.send_text(json.dumps({"error": str(exc), "code": "bad_request"}))
        await websocket.close(code=WS_POLICY_VIOLATION, reason="bad transport settings")
        return
    viewer = _Viewer(websocket, transport)
    async with anyio.create_task_group() as group:
        group.start_soon(viewer.listen, group.cancel_scope)
        try:
            await viewer.push()
        except (WebSocketDisconnect, RuntimeError):  # gone between two frames
            group.cancel_scope.cancel()


class _Viewer:
    """One WebSocket viewer: its transport settings, its messages and its frames."""

    def __init__(self, websocket: WebSocket, transport: Transport) -> None:
        self.websocket = websocket
        self.transport = transport
        session = websocket.app.state.session
        self.live = session.live
        self.encoder = session.live_transport
        # A frame's two messages go out together: a settings answer never comes between.
        self.sending = anyio.Lock()

    async def listen(self, scope: anyio.CancelScope) -> None:
        """The viewer's messages (settings); a viewer that goes away is noticed at once."""
        with contextlib.suppress(WebSocketDisconnect):
            while True:
                message = await self.websocket.receive()
                if message["type"] == "websocket.disconnect":
                    break
                if message.get("text") is not None:
                    await self._settings(message["text"])
        scope.cancel()

    async def _settings(self, text: str) -> None:
        answer: dict[str, Any]
        try:
            values = json.loads(text)
            if not isinstance(values, dict):
                raise ValueError(f"expected a JSON object of settings, got {text[:80]!r}")
            self.transport = parse_transport(values, self.transport)
            answer = {"transport": self.transport.as_dict()}
        except ValueError as exc:  # json.JSONDecodeError is one
            answer = {"error": f"settings unchanged: {exc}", "code": "bad_request"}
        async with self.sending:
            await self.websocket.send_text(json.dumps(answer))

    async def push(self) -> None:
        """Each newest frame, encoded for this viewer, no sooner than its rate allows."""
        seq = 0
        sent_at = -float("inf")
        while True:
            wait_s = sent_at + self.transport.min_interval_s - time.monotonic()
            if wait_s > 0:
                await anyio.sleep(wait_s)
            frame = await anyio.to_thread.run_sync(
                self.live.wait_newer, seq, LIVE_POLL_S, abandon_on_cancel=True
            )
            if frame is None:
                continue
            seq = frame.seq
            encoded = await anyio.to_thread.run_sync(self.encoder.encode, frame, self.transport)
            sent_at = time.monotonic()
            async with self.sending:
                await self.websocket.send_text(json.dumps(encoded.meta))
                await self.websocket.send_bytes(encoded.payload)


@router.get("/background", response_model=BackgroundStatus)
def get_live_background(session: Session) -> BackgroundStatus:
    """The live view's background: none, capturing (progress), ready (where it came from,
    its spatial mean and standard deviation, the recordings it was saved in) or failed
    (why). Reading never needs control."""
    return session.background.status()


@router.post(
    "/background",
    response_model=BackgroundStatus,
    dependencies=[needs_control("capture a background")],
)
def post_live_background(
    session: Session, body: BackgroundRequest | None = None
) -> BackgroundStatus:
    """Average the next ``frames`` frames of the running stream into the background, and
    return at once (poll GET). It replaces the background there was; every recording
    started while it is ready stores it as ``/background``. 409 when nothing streams
    (nothing changed then)."""
    body = body or BackgroundRequest()
    return session.background.start(body.frames)


@router.delete(
    "/background",
    response_model=BackgroundStatus,
    dependencies=[needs_control("clear the background")],
)
def delete_live_background(session: Session) -> BackgroundStatus:
    """Drop the background (and stop a capture); recordings no longer get one."""
    return session.background.clear()


@router.get("/roi", response_model=RoiList)
def get_live_roi(session: Session) -> RoiList:
    """The ROIs measured on every frame of every stream, and the frame geometry (the current
    or last stream's) they were checked against. Reading never needs control."""
    return session.roi.listing()


@router.post(
    "/roi", response_model=RoiList, dependencies=[needs_control("define a region of interest")]
)
def post_live_roi(session: Session, body: RoiRequest) -> RoiList:
    """Measure a named rectangle on every frame from the next one on (an ROI of that name is
    replaced; the ROIs' history starts again). 400 bad_request, nothing changed, if it does
    not fit the current or last stream's frame, its name is not valid or there would be more
    than 16."""
    return session.roi.add(body)


@router.delete(
    "/roi/{name}",
    response_model=RoiList,
    dependencies=[needs_control("delete a region of interest")],
)
def delete_live_roi(session: Session, name: str) -> RoiList:
    """Stop measuring ROI ``name``. 404 not_found (listing the ROIs) if there is none."""
    return session.roi.delete(name)


@router.get("/roi/stats", response_model=RoiStatsResponse)
def get_live_roi_stats(
    session: Session,
    history: int = Query(
        default=0,
        ge=0,
        le=ROI_HISTORY_MAX,
        description=f"frames of history per ROI, newest last (0..{ROI_HISTORY_MAX})",
    ),
) -> RoiStatsResponse:
    """Every ROI's statistics on the newest measured frame (mean, std, min, max, sum, SNR,
    saturated pixels, background-subtracted mean) and, per ROI, the newest ``history``
    frames' (every frame of the stream: none is skipped)."""
    return session.roi.stats(history)


@router.get("/background/frame", response_class=Response, responses=FRAME_RESPONSES)
def get_live_background_frame(session: Session) -> Response:
    """The background: raw little-endian float32, row by row (DN, the mean of its frames);
    the header ``X-Camd-Background`` holds its JSON description (seq, frames, rows, cols,
    mode, stages, first_counter, last_counter, captured_t_s, mean_dn, std_dn, dtype).
    404 when none is ready."""
    background = session.background.capture.ready()
    if background is None:
        state = session.background.status()
        why = {"capturing": "one is being captured", "failed": "the last capture failed"}
        return error_response(
            404,
            "no_background",
            f"no background is ready ({why.get(state.state, 'none was captured')}); "
            "capture one while something streams: POST /api/v1/live/background "
            '{"frames": 16}, then poll GET /api/v1/live/background',
        )
    return _float32(background.pixels, "X-Camd-Background", json.dumps(background.meta()))


@router.get("/lines", response_class=Response, responses=FRAME_RESPONSES)
def get_live_lines(
    session: Session,
    after: int = Query(
        default=-1, ge=-1, description="the last line index the viewer has (-1: none)"
    ),
    max_lines: int = Query(
        default=512, ge=1, le=LIVE_LINES_MAX, alias="max", description="most lines to send"
    ),
    timeout_s: float = Query(
        default=0.0,
        ge=0,
        le=LIVE_WAIT_MAX_S,
        description="with no line newer than after: longest wait for one, s",
    ),
) -> Response:
    """The live view's waterfall: the newest integrated lines of the running (or last)
    TDI scan with index > ``after``, at most ``max``, the newest ones. Raw little-endian
    float32, ``n`` x ``cols`` row by row; the header ``X-Camd-Lines`` holds their JSON
    description (scan, scan_seq, first_index, n, cols, index, complete, stages_used,
    skipped, lines_done, lines_planned, state, dtype). With none newer, waits up to
    ``timeout_s`` for one, then answers ``n`` = 0 with an empty body. 404 before the
    first scan. Reading never needs control."""
    lines = session.live_lines
    if timeout_s > 0:
        lines.wait_newer(after, timeout_s)
    chunk = lines.since(after, max_lines)
    if chunk is None:
        return error_response(
            404,
            "no_scan",
            "no scan has run since the daemon started: the live lines are those of the "
            "running or last TDI scan; start one (`camctl scan --stages 8 --lines 1000`)",
        )
    # Compact: with 2048 lines the flags and indices make a header of tens of kB.
    return _float32(chunk.data, "X-Camd-Lines", json.dumps(chunk.meta(), separators=(",", ":")))


def _float32(pixels: npt.NDArray[Any], header: str, description: str) -> Response:
    """``pixels`` as raw little-endian float32, row by row, with their JSON ``description`` in
    the header ``header``; never cached (the next answer differs)."""
    return Response(
        content=pixels.astype("<f4", copy=False).tobytes(),
        media_type="application/octet-stream",
        headers={header: description, "Cache-Control": "no-store"},
    )
