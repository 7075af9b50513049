"""The frame stream (docs/stream.md): start, stare (acquire), stop, its counters and headers."""

from __future__ import annotations

from fastapi import APIRouter

from camd.daemon.models import StreamHeadersResponse, StreamResponse, StreamStartRequest
from camd.daemon.request_guard import API
from camd.daemon.routes.deps import Session, needs_control

router = APIRouter(prefix=f"{API}/stream", tags=["stream"])


@router.get("", response_model=StreamResponse)
def get_stream(session: Session) -> StreamResponse:
    """The current or last stream: geometry, mode and the host's ingest counters."""
    return session.stream.status()


@router.get("/headers", response_model=StreamHeadersResponse)
def get_stream_headers(session: Session) -> StreamHeadersResponse:
    """The headers of the first frames of the current or last stream, each with the
    payload CRC the host computed, including frames the payload CRC rejected."""
    return session.stream.headers()


@router.post(
    "/start", response_model=StreamResponse, dependencies=[needs_control("start a stream")]
)
def post_stream_start(session: Session, body: StreamStartRequest | None = None) -> StreamResponse:
    """Start streaming and return at once; refused (409 link_untrained) on an untrained
    link. ``frames = 0`` streams until /stream/stop."""
    return session.stream.start(body or StreamStartRequest())


@router.post(
    "/acquire", response_model=StreamResponse, dependencies=[needs_control("start a stare")]
)
def post_stream_acquire(session: Session, body: StreamStartRequest) -> StreamResponse:
    """Take ``frames`` frames (optionally recording them to HDF5) and return when done."""
    return session.stream.acquire(body)


@router.post(
    "/stop", response_model=StreamResponse, dependencies=[needs_control("stop the stream")]
)
def post_stream_stop(session: Session) -> StreamResponse:
    """Stop the stream; frames the device sent are drained first. Harmless when idle."""
    return session.stream.stop()
