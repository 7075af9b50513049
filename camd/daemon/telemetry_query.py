"""What the telemetry queries ask: the history's and the events' parameters as the API took
them, and the SQL that selects a channel's samples over a range or the events wanted.

Apart from ``camd.daemon.telemetry`` (the archive) so that the archive's module stays one job.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Protocol


class _Event(Protocol):
    """What ``EventFilter.matches`` reads of an event."""

    @property
    def t_s(self) -> float: ...
    @property
    def level(self) -> str: ...
    @property
    def source(self) -> str: ...


@dataclass(frozen=True, slots=True)
class HistoryQuery:
    """What GET /telemetry/history asks (docs/api.md); times as ``parse_instant`` takes them."""

    channels: Sequence[str]
    start: str | None = None
    end: str | None = None
    bucket_s: float | None = None
    source: str | None = None
    limit: int | None = None
    since_s: float | None = None  # the older form of start: a Unix time, or < 0 seconds ago


@dataclass(frozen=True, slots=True)
class EventsQuery:
    """What GET /events asks: the newest ``limit`` in a range, of some levels and sources."""

    limit: int = 100
    start: str | None = None
    end: str | None = None
    levels: Sequence[str] | None = None
    sources: Sequence[str] | None = None


@dataclass(frozen=True, slots=True)
class EventFilter:
    """Which events a query wants: a time range [start_s, end_s) and levels and sources (None:
    any)."""

    start_s: float | None = None
    end_s: float | None = None
    levels: Sequence[str] | None = None
    sources: Sequence[str] | None = None

    def sql(self) -> tuple[str, list[Any]]:
        """The WHERE clause (empty for no filter) and its arguments."""
        terms: list[str] = []
        args: list[Any] = []
        if self.start_s is not None:
            terms.append("t_s >= ?")
            args.append(self.start_s)
        if self.end_s is not None:
            terms.append("t_s < ?")
            args.append(self.end_s)
        for column, values in (("level", self.levels), ("source", self.sources)):
            if values is not None:
                terms.append(f"{column} IN ({', '.join('?' * len(values))})")
                args.extend(values)
        return ("WHERE " + " AND ".join(terms) if terms else ""), args

    def matches(self, event: _Event) -> bool:
        """Whether ``event`` passes (for the events kept in memory)."""
        return (
            (self.start_s is None or event.t_s >= self.start_s)
            and (self.end_s is None or event.t_s < self.end_s)
            and (self.levels is None or event.level in self.levels)
            and (self.sources is None or event.source in self.sources)
        )


def range_where(
    channel: str, start_s: float, end_s: float, source: str | None
) -> tuple[str, tuple[Any, ...]]:
    """The WHERE clause of one channel's samples in [start_s, end_s), of one source or both;
    it walks the (channel, t_s) index."""
    if source is None:
        return "WHERE channel = ? AND t_s >= ? AND t_s < ?", (channel, start_s, end_s)
    return (
        "WHERE channel = ? AND t_s >= ? AND t_s < ? AND source = ?",
        (channel, start_s, end_s, source),
    )
