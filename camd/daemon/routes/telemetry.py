"""Housekeeping telemetry (docs/api.md): latest values, the archive's history, the events."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Header, Query, Response

from camd.daemon.errors import BadRequest
from camd.daemon.models import (
    EVENTS_LIMIT_MAX,
    HISTORY_LIMIT_MAX,
    EventsResponse,
    HistoryResponse,
    TelemetryResponse,
)
from camd.daemon.request_guard import API
from camd.daemon.routes.deps import Session
from camd.daemon.telemetry_query import EventsQuery, HistoryQuery
from camd.daemon.telemetry_service import history_csv

router = APIRouter(prefix=API, tags=["telemetry"])

CSV_MEDIA_TYPE = "text/csv"


@router.get("/telemetry", response_model=TelemetryResponse)
def get_telemetry(session: Session) -> TelemetryResponse:
    """Latest value of every housekeeping channel, with its limit level."""
    return session.telemetry.latest()


@router.get(
    "/telemetry/history",
    response_model=HistoryResponse,
    responses={200: {"content": {CSV_MEDIA_TYPE: {}}}},
)
def get_history(
    session: Session,
    channel: Annotated[
        list[str],
        Query(description="telemetry channel(s): repeat it or separate names by commas"),
    ],
    start: str | None = Query(
        default=None,
        description="ISO 8601 (UTC without a zone), Unix seconds, now, or before now like "
        "-10m, -2h (default -1h)",
    ),
    end: str | None = Query(default=None, description="as start (default now); exclusive"),
    bucket_s: float | None = Query(
        default=None, description="bucket width, seconds: min, mean, max and count per bucket"
    ),
    source: str | None = Query(default=None, description="tlm, poll or all (default all)"),
    format: str | None = Query(default=None, description="json (default) or csv"),
    limit: int | None = Query(
        default=None, ge=1, le=HISTORY_LIMIT_MAX, description="the newest N samples per channel"
    ),
    since_s: float | None = Query(
        default=None, description="older form of start: Unix time, or < 0 seconds before now"
    ),
    accept: Annotated[str | None, Header()] = None,
) -> HistoryResponse | Response:
    """Archived samples of some channels over a time range, each with its source, or their
    min/mean/max/count per bucket; JSON or CSV."""
    if format not in (None, "json", "csv"):
        raise BadRequest(f"format: {format!r} is not a format; use json or csv")
    as_csv = format == "csv" or (format is None and CSV_MEDIA_TYPE in (accept or ""))
    doc = session.telemetry.history(
        HistoryQuery(
            channels=channel,
            start=start,
            end=end,
            bucket_s=bucket_s,
            source=source,
            limit=limit,
            since_s=since_s,
        )
    )
    if as_csv:
        return Response(history_csv(doc), media_type=CSV_MEDIA_TYPE)
    return doc


@router.get("/events", response_model=EventsResponse)
def get_events(
    session: Session,
    limit: int = Query(default=100, ge=1, le=EVENTS_LIMIT_MAX, description="newest N"),
    start: str | None = Query(default=None, description="as in /telemetry/history"),
    end: str | None = Query(default=None, description="as in /telemetry/history; exclusive"),
    level: Annotated[
        list[str] | None, Query(description="info, warning, error: repeat or use commas")
    ] = None,
    source: Annotated[
        list[str] | None, Query(description="link, device, limits, daemon, api, ...")
    ] = None,
) -> EventsResponse:
    """Recent events (link, device, limits, state changes), newest last; filtered by time range,
    level and source."""
    return session.telemetry.events(
        EventsQuery(limit=limit, start=start, end=end, levels=level, sources=source)
    )
