"""Housekeeping telemetry (docs/api.md): latest values, the archive's history, the events."""

from __future__ import annotations

from fastapi import APIRouter, Query

from camd.daemon.models import (
    EVENTS_LIMIT_MAX,
    HISTORY_LIMIT_MAX,
    EventsResponse,
    HistoryResponse,
    TelemetryResponse,
)
from camd.daemon.request_guard import API
from camd.daemon.routes.deps import Session

router = APIRouter(prefix=API, tags=["telemetry"])


@router.get("/telemetry", response_model=TelemetryResponse)
def get_telemetry(session: Session) -> TelemetryResponse:
    """Latest value of every housekeeping channel, with its limit level."""
    return session.telemetry.latest()


@router.get("/telemetry/history", response_model=HistoryResponse)
def get_history(
    session: Session,
    channel: str = Query(description="telemetry channel, e.g. fpga_temp_degc"),
    since_s: float = Query(
        default=0.0,
        description="Unix time in seconds (the t_s clock); negative = seconds before now",
    ),
    limit: int = Query(default=1000, ge=1, le=HISTORY_LIMIT_MAX, description="newest N"),
) -> HistoryResponse:
    """Archived samples of one channel, oldest first."""
    return session.telemetry.history(channel, since_s, limit)


@router.get("/events", response_model=EventsResponse)
def get_events(
    session: Session,
    limit: int = Query(default=100, ge=1, le=EVENTS_LIMIT_MAX, description="newest N"),
) -> EventsResponse:
    """Recent events (link, device, limits, state changes), newest last."""
    return session.telemetry.events(limit)
