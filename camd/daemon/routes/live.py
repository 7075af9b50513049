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

from camd.daemon.api_token import TOKEN_COOKIE, token_ok
from camd.daemon.error_body import WS_POLICY_VIOLATION, error_response
from camd.daemon.models import (
    FOCUS_HISTORY_MAX,
    IMAGE_MOTION_HISTORY_MAX,
    LIVE_LINES_MAX,
    LIVE_WAIT_MAX_S,
    ROI_HISTORY_MAX,
    BackgroundRequest,
    BackgroundStatus,
    ErrorResponse,
    FocusBestModel,
    FocusHistory,
    FocusLatest,
    FocusResponse,
    ImageMotionBlock,
    ImageMotionResponse,
    RoiList,
    RoiRequest,
    RoiStatsResponse,
)
from camd.daemon.request_guard import API
from camd.daemon.routes.deps import Session, needs_control, no_frame
from camd.pipeline.focus import FocusMonitor
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
    JSON description (seq, counter, timestamp_ns, mode, stages, bits, rows, cols, skipped,
    gap_before, dtype). Reading never needs control. 404 if no frame newer than ``after``
    came within ``timeout_s``."""
    frame = session.live.latest() if after == 0 else session.live.wait_newer(after, timeout_s)
    if frame is None:
        return no_frame(after, timeout_s)
    return Response(
        content=frame.pixels.astype("<u2", copy=False).tobytes(),
        media_type="application/octet-stream",
        headers={"X-Camd-Frame": json.dumps(frame.meta()), "Cache-Control": "no-store"},
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


@router.get("/focus", response_model=FocusResponse)
def get_live_focus(
    session: Session,
    history: int = Query(
        default=0,
        ge=0,
        le=FOCUS_HISTORY_MAX,
        description=f"figures of history, newest last (0..{FOCUS_HISTORY_MAX})",
    ),
) -> FocusResponse:
    """The focus aid: the grey-gradient sharpness of the live view's frames (the whole frame
    and each ROI), the best since the last reset, and the newest ``history`` figures. Asking
    keeps the figures measured (at most ``rate_hz`` a second, on the live view's frames, off
    the acquisition's path) for ``watch_s`` more seconds; the first ask starts them. Reading
    never needs control."""
    session.focus.watch()
    return _focus_response(session.focus, history)


@router.delete(
    "/focus/best",
    response_model=FocusResponse,
    dependencies=[needs_control("reset the best focus figure")],
)
def delete_live_focus_best(session: Session) -> FocusResponse:
    """Forget the best focus figures (a new focusing starts); the history stays."""
    session.focus.reset_best()
    return _focus_response(session.focus, 0)


@router.get("/motion", response_model=ImageMotionResponse)
def get_live_motion(
    session: Session,
    history: int = Query(
        default=0,
        ge=0,
        le=IMAGE_MOTION_HISTORY_MAX,
        description=f"blocks of history, newest last (0..{IMAGE_MOTION_HISTORY_MAX})",
    ),
) -> ImageMotionResponse:
    """The image's motion measured from blocks of consecutive TDI window frames of every
    stream and scan (dV/V, M dV/V, drift angle; docs/motion.md), off the acquisition's path:
    the newest block and the newest ``history`` blocks. Area-mode frames are not measured."""
    status = session.image_motion.status(history)
    blocks = [ImageMotionBlock(**b.as_dict()) for b in status.blocks]
    latest = session.image_motion.status(1).blocks
    return ImageMotionResponse(
        enabled=status.enabled,
        frames_per_block=status.frames_per_block,
        columns_max=status.columns_max,
        cpu_fraction=status.cpu_fraction,
        blocks_measured=status.blocks_measured,
        tdi_frames_seen=status.tdi_frames_seen,
        frames_measured=status.frames_measured,
        cpu_s=status.cpu_s,
        latest=ImageMotionBlock(**latest[0].as_dict()) if latest else None,
        history=blocks,
    )


def _focus_response(focus: FocusMonitor, history: int) -> FocusResponse:
    snap = focus.snapshot(history)
    points = snap.history if history > 0 else []
    targets = list(dict.fromkeys(t for p in points for t in p.values))
    newest = snap.history[-1] if snap.history else None
    return FocusResponse(
        rate_hz=snap.rate_hz,
        watching=snap.watching,
        watch_s=focus.watch_s,
        measured=snap.measured,
        latest=None
        if newest is None
        else FocusLatest(
            seq=newest.seq, counter=newest.counter, t_s=newest.t_s, values=newest.values
        ),
        best={
            k: FocusBestModel(value=b.value, counter=b.counter, seq=b.seq, t_s=b.t_s)
            for k, b in snap.best.items()
        },
        history=FocusHistory(
            seq=[p.seq for p in points],
            counter=[p.counter for p in points],
            t_s=[p.t_s for p in points],
            values={t: [p.values.get(t) for p in points] for t in targets},
        ),
    )


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
