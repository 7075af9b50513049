"""Bodies of the telemetry routes: latest values, the archive's history, the event log."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, Field

LimitLevel = Literal["ok", "yellow", "red"]


HISTORY_LIMIT_MAX = 1_000_000


EVENTS_LIMIT_MAX = 100_000


class ChannelLatest(BaseModel):
    """The newest sample of one channel."""

    value: float
    unit: str
    t_s: float = Field(description="Unix time of the sample, seconds")
    limit: LimitLevel


class TelemetryResponse(BaseModel):
    """GET /api/v1/telemetry."""

    latest: dict[str, ChannelLatest]
    samples: int = Field(description="samples in the archive")
    archive: str = Field(description="path of the SQLite archive")
    archive_error: str | None = Field(
        default=None,
        description="why the archive cannot be written now (a full disk, a read-only or corrupt "
        "file), null while it can: the limits are still checked and the events kept in memory",
    )


class HistoryResponse(BaseModel):
    """GET /api/v1/telemetry/history."""

    channel: str
    unit: str
    t_s: list[float]
    value: list[float]


class EventItem(BaseModel):
    """One event."""

    t_s: float
    level: Literal["info", "warning", "error"]
    source: str
    message: str


class EventsResponse(BaseModel):
    """GET /api/v1/events."""

    events: list[EventItem] = Field(description="newest last")
