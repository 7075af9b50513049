"""Housekeeping telemetry in the daemon: samples, limits, the archive, history and the event log.

``TelemetryService`` keeps the latest value of every housekeeping channel (this run's, in
memory), checks each sample against its yellow and red limits (``camd.daemon.telemetry``'s
``LimitChecker``, each change an event), writes samples and events to the SQLite archive
(``GuardedArchive``: a full disk never stops the daemon) and reads them back for
``GET /api/v1/telemetry``, ``/telemetry/history`` and ``/events`` (docs/api.md).

It is handed the event log (``EventSink``: log and archive one event) and what to do when a
channel is red and the operator has not acknowledged it (``on_red``: the session trips the
state machine to fault); it is built before the device access, whose event log writes into
its archive.
"""

from __future__ import annotations

import contextlib
import csv
import io
import logging
import math
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, cast

from camd.daemon.config import Config, telemetry_channels
from camd.daemon.device import EventSink
from camd.daemon.errors import BadRequest, SessionError
from camd.daemon.models import (
    HISTORY_POINTS_MAX,
    ChannelHistory,
    ChannelLatest,
    ChannelLimitRanges,
    EventItem,
    EventsResponse,
    HistoryResponse,
    TelemetryResponse,
)
from camd.daemon.telemetry import GuardedArchive, LimitChecker, TelemetryArchive, classify
from camd.daemon.telemetry_query import EventsQuery, HistoryQuery
from camd.daemon.time_range import iso_utc, parse_instant, parse_range
from camd.protocol.dictionary import FieldValue

# The session's logger: these lines kept the name they had before telemetry was a service of
# its own (log filters select the daemon's lines by it).
log = logging.getLogger("camd.daemon.session")


class TelemetryService:
    """Samples, limits, archive, history and events of one device session (module docstring)."""

    def __init__(self, config: Config, events: EventSink, on_red: Callable[[str], None]) -> None:
        self.config = config
        self.channels: dict[str, str] = telemetry_channels()  # name -> unit
        self.checker = LimitChecker(config.telemetry.limits)
        self.archive: GuardedArchive | None = None
        self._events = events
        self._on_red = on_red
        self._last_values: dict[str, float] = {}
        self._last_t_s: dict[str, float] = {}  # when each channel's last value was taken
        self._red_lock = threading.Lock()
        self._red_acknowledged: set[str] = set()

    # -- the archive ---------------------------------------------------------------------------

    def open(self) -> None:
        """Open the archive (OSError or sqlite3.Error if it cannot be written)."""
        self.archive = GuardedArchive(
            TelemetryArchive(self.config.archive_path),
            lambda level, message: self._events(level, "telemetry", message, None),
        )

    def close(self) -> None:
        """Close the archive; events are then only logged."""
        if self.archive is not None:
            self.archive.close()
            self.archive = None

    def archive_event(self, level: str, source: str, message: str, t_s: float | None) -> None:
        """Keep an event in the archive, once it is open."""
        archive = self.archive
        if archive is not None:
            archive.add_event(level, source, message, t_s)  # never raises (GuardedArchive)

    def prune(self) -> None:
        """Delete the samples older than ``telemetry.retention_days``."""
        days = self.config.telemetry.retention_days
        if days <= 0 or self.archive is None:
            return
        removed = self.archive.prune(time.time() - days * 86400.0)
        if removed:
            log.info("telemetry archive: deleted %d samples older than %g days", removed, days)

    def _archive(self) -> GuardedArchive:
        if self.archive is None:
            raise RuntimeError("the session is not started")
        return self.archive

    # -- samples and limits ----------------------------------------------------------------------

    def record(self, values: Mapping[str, FieldValue], t_s: float, source: str) -> None:
        """Limits first, then the archive: an archive that cannot be written (a full disk)
        must not keep a red limit from tripping (``GuardedArchive`` never raises)."""
        numeric = {
            k: float(v)
            for k, v in values.items()
            if isinstance(v, int | float) and k in self.channels
        }
        self._last_values.update(numeric)
        for channel in numeric:
            self._last_t_s[channel] = t_s
        for change in self.checker.check(numeric, t_s):
            limits = self.config.telemetry.limits[change.channel]
            unit = self.channels.get(change.channel, "")
            self._events(change.level, "limits", change.message(limits, unit), t_s)
        self.check_red()
        self._archive().add_samples(t_s, numeric, source, self.channels)

    def check_red(self) -> None:
        """Say (``on_red``) which channels are red that the operator has not acknowledged
        with a reset."""
        if not self.config.telemetry.red_is_fault:
            return
        with self._red_lock:
            red = set(self.checker.red_channels())
            self._red_acknowledged &= red  # a channel that recovered may trip again
            fresh = sorted(red - self._red_acknowledged)
        if not fresh:
            return
        parts = []
        for ch in fresh:
            limits = self.config.telemetry.limits[ch]
            unit = self.channels.get(ch, "")
            value = self._last_values.get(ch, float("nan"))
            parts.append(
                f"{ch} = {value:.6g} {unit} outside [{limits.red[0]:g}, {limits.red[1]:g}]"
            )
        self._on_red("red limit: " + "; ".join(parts))

    def on_connect(self) -> None:
        """The link (re)opened: maybe another camera, so its limits start afresh."""
        self.checker.clear()
        with self._red_lock:
            self._red_acknowledged.clear()

    def acknowledge_red(self) -> list[str]:
        """The operator reset the camera and has seen the red channels: they trip again only
        after recovering. Returns them, sorted."""
        with self._red_lock:
            self._red_acknowledged = set(self.checker.red_channels())
            return sorted(self._red_acknowledged)

    def latest_values(self) -> dict[str, float]:
        """The last value seen on each telemetry channel (this run only)."""
        return dict(self._last_values)

    # -- what the API reads ----------------------------------------------------------------------

    def latest(self) -> TelemetryResponse:
        """Latest value of every channel with its limit level (this run's, from memory, so
        that they stay current while the archive cannot be written; before the first sample,
        the archive's), the archive's size and why it cannot be written, if it cannot."""
        archive = self._archive()
        seen: dict[str, tuple[float, float]] = {
            ch: (self._last_values[ch], self._last_t_s[ch])
            for ch in list(self._last_t_s)
            if ch in self._last_values
        }
        if len(seen) < len(self.channels):
            with contextlib.suppress(SessionError):  # an unreadable archive: what we have
                for channel, sample in archive.latest(self.channels).items():
                    seen.setdefault(channel, (sample.value, sample.t_s))
        latest = {}
        for channel, (value, t_s) in seen.items():
            limits = self.config.telemetry.limits.get(channel)
            level = classify(value, limits).value if limits is not None else "ok"
            latest[channel] = ChannelLatest(
                value=value,
                unit=self.channels.get(channel, ""),
                t_s=t_s,
                limit=cast(Any, level),
            )
        return TelemetryResponse(
            latest=latest,
            limits={
                channel: ChannelLimitRanges(yellow=limits.yellow, red=limits.red)
                for channel, limits in self.config.telemetry.limits.items()
            },
            samples=archive.count(),
            archive=str(archive.path),
            archive_error=archive.failing,
        )

    def history(self, query: HistoryQuery) -> HistoryResponse:
        """Archived samples of the channels asked over a time range, each saying its source, or
        their min/mean/max/count per bucket; BadRequest for a bad range, an unknown channel or
        a result larger than ``HISTORY_POINTS_MAX`` (the message says how to narrow it)."""
        asked = _Asked(
            channels=self._channels_asked(query.channels),
            source=_source_asked(query.source),
            range_s=self._range(query),
        )
        if query.bucket_s is not None:
            return self._buckets(asked, query.bucket_s)
        return self._samples(asked, query.limit)

    def _buckets(self, asked: _Asked, bucket_s: float) -> HistoryResponse:
        if not (math.isfinite(bucket_s) and bucket_s > 0):
            raise BadRequest(f"bucket_s: {bucket_s:g} is not a width; give seconds > 0")
        start_s, end_s = asked.range_s
        # Bounded before reading: the most buckets the range can fill.
        most = math.ceil((end_s - start_s) / bucket_s) * len(asked.channels) * asked.sources
        if most > HISTORY_POINTS_MAX:
            raise BadRequest(asked.too_large(most, "buckets"))
        out = []
        for channel in asked.channels:
            rows = self._archive().buckets(channel, start_s, end_s, bucket_s, asked.source)
            t_s, src, lo, mean, hi, n = (
                (list(column) for column in zip(*rows, strict=True)) if rows else ([],) * 6
            )
            out.append(
                ChannelHistory(
                    channel=channel,
                    unit=self.channels[channel],
                    t_s=t_s,
                    source=src,
                    min=lo,
                    mean=mean,
                    max=hi,
                    count=n,
                )
            )
        return HistoryResponse(start_s=start_s, end_s=end_s, bucket_s=bucket_s, channels=out)

    def _samples(self, asked: _Asked, limit: int | None) -> HistoryResponse:
        start_s, end_s = asked.range_s
        archive = self._archive()
        # Bounded before reading: index range counts, no rows read.
        total = sum(
            min(n, limit) if limit is not None else n
            for n in (
                archive.count_range(ch, start_s, end_s, asked.source) for ch in asked.channels
            )
        )
        if total > HISTORY_POINTS_MAX:
            raise BadRequest(asked.too_large(total, "samples"))
        out = []
        for channel in asked.channels:
            rows = archive.samples(
                channel, start_s, end_s, asked.source, -1 if limit is None else limit
            )
            out.append(
                ChannelHistory(
                    channel=channel,
                    unit=self.channels[channel],
                    t_s=[r[0] for r in rows],
                    source=[cast(Any, r[2]) for r in rows],
                    value=[r[1] for r in rows],
                )
            )
        return HistoryResponse(start_s=start_s, end_s=end_s, bucket_s=None, channels=out)

    def _channels_asked(self, asked: Sequence[str]) -> list[str]:
        """The channels named (each once, in order; a name may be a comma-separated list)."""
        names = list(dict.fromkeys(n.strip() for item in asked for n in item.split(",")))
        names = [n for n in names if n]
        if not names:
            raise BadRequest(
                "channel: name at least one telemetry channel, e.g. channel=fpga_temp_degc; "
                "the channels: " + ", ".join(self.channels)
            )
        unknown = [n for n in names if n not in self.channels]
        if unknown:
            raise BadRequest(
                "channel: "
                + ", ".join(repr(n) for n in unknown)
                + (
                    " is not a telemetry channel"
                    if len(unknown) == 1
                    else " are not telemetry channels"
                )
                + "; use one of "
                + ", ".join(self.channels)
            )
        return names

    @staticmethod
    def _range(query: HistoryQuery) -> tuple[float, float]:
        now_s = time.time()
        if query.since_s is not None:
            if query.start is not None:
                raise BadRequest("since_s and start name the same thing: give only start")
            start = str(query.since_s)
        else:
            start = query.start if query.start is not None else HISTORY_START_DEFAULT
        return parse_range(start, query.end if query.end is not None else "now", now_s)

    def events(self, query: EventsQuery) -> EventsResponse:
        """The newest ``limit`` events in the range and of the levels and sources asked,
        newest last."""
        levels = _listed(query.levels)
        bad = [lvl for lvl in levels or [] if lvl not in EVENT_LEVELS]
        if bad:
            raise BadRequest(
                f"level: {', '.join(repr(b) for b in bad)} is not an event level; use "
                + ", ".join(EVENT_LEVELS)
            )
        now_s = time.time()
        start_s = end_s = None
        if query.start is not None and query.end is not None:
            start_s, end_s = parse_range(query.start, query.end, now_s)
        elif query.start is not None:
            start_s = parse_instant(query.start, now_s, "start")
        elif query.end is not None:
            end_s = parse_instant(query.end, now_s, "end")
        items = [
            EventItem(t_s=e.t_s, level=cast(Any, e.level), source=e.source, message=e.message)
            for e in self._archive().events(
                query.limit,
                start_s=start_s,
                end_s=end_s,
                levels=levels,
                sources=_listed(query.sources),
            )
        ]
        return EventsResponse(events=items)


HISTORY_START_DEFAULT = "-1h"


@dataclass(frozen=True, slots=True)
class _Asked:
    """A history query checked: channels known, source, range in Unix seconds."""

    channels: list[str]
    source: str | None  # None: both
    range_s: tuple[float, float]

    @property
    def sources(self) -> int:
        return 1 if self.source is not None else len(SAMPLE_SOURCES)

    def too_large(self, n: int, what: str) -> str:
        """Why ``n`` samples or buckets are refused, and the ``bucket_s`` that fits."""
        start_s, end_s = self.range_s
        # The bucket that keeps every channel's and source's buckets within the bound.
        bucket_s = (end_s - start_s) * len(self.channels) * self.sources / HISTORY_POINTS_MAX
        return (
            f"{n} {what} from {iso_utc(start_s)} to {iso_utc(end_s)}: more than the "
            f"{HISTORY_POINTS_MAX} one answer holds; narrow start and end, ask fewer channels, "
            f"or set bucket_s to at least {_round_up(bucket_s):g}"
        )


SAMPLE_SOURCES = ("tlm", "poll")
EVENT_LEVELS = ("info", "warning", "error")


def _listed(items: Sequence[str] | None) -> list[str] | None:
    """Repeated and comma-separated values as one list (None when none given)."""
    if not items:
        return None
    return [v.strip() for item in items for v in item.split(",") if v.strip()] or None


def _source_asked(source: str | None) -> str | None:
    if source is None or source in ("", "all"):
        return None
    if source not in SAMPLE_SOURCES:
        raise BadRequest(
            f"source: {source!r} is not a sample source; use tlm (the camera's packets), poll "
            "(the daemon's polls) or all"
        )
    return source


def _round_up(x: float) -> float:
    """``x`` rounded up to a 1, 2 or 5 times a power of ten (a bucket an operator would type)."""
    if x <= 0:
        return 0.0
    decade = 10.0 ** math.floor(math.log10(x))
    for step in (1.0, 2.0, 5.0, 10.0):
        if step * decade >= x:
            return step * decade
    return 10.0 * decade


def history_csv(doc: HistoryResponse) -> str:
    """The history as CSV, one row per sample or bucket: channel, unit, source, t_s, the time
    in ISO 8601 UTC, then value, or count, min, mean and max."""
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    bucketed = doc.bucket_s is not None
    tail = ["count", "min", "mean", "max"] if bucketed else ["value"]
    writer.writerow(["channel", "unit", "source", "t_s", "time_utc", *tail])
    for ch in doc.channels:
        for i, t_s in enumerate(ch.t_s):
            head = [ch.channel, ch.unit, ch.source[i], repr(t_s), iso_utc(t_s)]
            if bucketed:
                writer.writerow(
                    [*head, ch.count[i], repr(ch.min[i]), repr(ch.mean[i]), repr(ch.max[i])]
                )
            else:
                writer.writerow([*head, repr(ch.value[i])])
    return buf.getvalue()
