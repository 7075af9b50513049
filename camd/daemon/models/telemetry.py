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


class ChannelLimitRanges(BaseModel):
    """One channel's limits (``telemetry.limits``), in its unit, bounds inclusive: ``ok`` inside
    ``yellow``, ``yellow`` outside it but inside ``red``, ``red`` outside ``red``."""

    yellow: tuple[float, float]
    red: tuple[float, float]


class TelemetryResponse(BaseModel):
    """GET /api/v1/telemetry."""

    latest: dict[str, ChannelLatest]
    limits: dict[str, ChannelLimitRanges] = Field(
        default_factory=dict,
        description="every channel's configured limits (the defaults and the config's), so that "
        "a client draws them as the daemon applies them",
    )
    samples: int = Field(description="samples in the archive")
    archive: str = Field(description="path of the SQLite archive")
    archive_error: str | None = Field(
        default=None,
        description="why the archive cannot be written now (a full disk, a read-only or corrupt "
        "file), null while it can: the limits are still checked and the events kept in memory",
    )


HISTORY_POINTS_MAX = 100_000

SampleSource = Literal["tlm", "poll"]


class ChannelHistory(BaseModel):
    """One channel's samples over the range, or its buckets when ``bucket_s`` is set."""

    channel: str
    unit: str
    t_s: list[float] = Field(
        description="each sample's Unix time, or each bucket's start, oldest first"
    )
    source: list[SampleSource] = Field(
        description="where each sample (or bucket) came from: tlm (the camera's unsolicited "
        "packet) or poll (the daemon's GET_HOUSEKEEPING)"
    )
    value: list[float] = Field(
        default_factory=list, description="each sample's value; empty with bucket_s"
    )
    min: list[float] = Field(
        default_factory=list, description="each bucket's minimum; empty without bucket_s"
    )
    mean: list[float] = Field(
        default_factory=list, description="each bucket's mean; empty without bucket_s"
    )
    max: list[float] = Field(
        default_factory=list, description="each bucket's maximum; empty without bucket_s"
    )
    count: list[int] = Field(
        default_factory=list, description="each bucket's number of samples; empty without bucket_s"
    )


class HistoryResponse(BaseModel):
    """GET /api/v1/telemetry/history."""

    start_s: float = Field(description="the range's start, Unix time (inclusive)")
    end_s: float = Field(description="the range's end, Unix time (exclusive)")
    bucket_s: float | None = Field(description="the bucket width, null for every sample")
    channels: list[ChannelHistory] = Field(description="in the order asked")


class EventItem(BaseModel):
    """One event."""

    t_s: float
    level: Literal["info", "warning", "error"]
    source: str
    message: str


class EventsResponse(BaseModel):
    """GET /api/v1/events."""

    events: list[EventItem] = Field(description="newest last")
