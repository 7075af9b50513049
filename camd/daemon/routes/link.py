"""The command link (docs/api.md, docs/conformance.md): PING, raw COMMAND frames, counters."""

from __future__ import annotations

from fastapi import APIRouter

from camd.daemon.models import (
    LinkCommandRequest,
    LinkCommandResponse,
    LinkResponse,
    PingRequest,
    PingResponse,
)
from camd.daemon.request_guard import API
from camd.daemon.routes.deps import Session, needs_control

router = APIRouter(prefix=API, tags=["link"])


@router.post("/ping", response_model=PingResponse)
def post_ping(session: Session, body: PingRequest | None = None) -> PingResponse:
    """PING the device ``count`` times with ``size`` random bytes; round-trip statistics."""
    body = body or PingRequest()
    return session.link_commands.ping(body.count, body.size)


@router.post(
    "/link/command",
    response_model=LinkCommandResponse,
    dependencies=[needs_control("send a raw command")],
)
def post_link_command(session: Session, body: LinkCommandRequest) -> LinkCommandResponse:
    """Send one COMMAND frame: a dictionary command with ``fields`` (checked by the
    dictionary) or any ``opcode`` with any ``payload_hex`` (unchecked), and return the
    device's ACK or NAK; ``repeat`` sends the identical frame again (same sequence number)
    to test at-most-once execution. For conformance tests (docs/conformance.md): the
    daemon's view of the camera is not updated, so put back what you change. Idle or in
    fault only."""
    return session.link_commands.command(body)


@router.get("/link", response_model=LinkResponse)
def get_link(session: Session) -> LinkResponse:
    """Host and device counters of the command link."""
    return session.link_commands.stats()
