"""Telemetry: the SQLite archive of housekeeping samples and events, and the limit checker.

The archive is one SQLite file in WAL mode (readers, e.g. ``sqlite3`` on the command line, never
block the writer), in long format: ``samples(t_s, channel, value, source)`` indexed by
(channel, t_s), and ``events(t_s, level, source, message)``. One connection is shared by the
daemon's threads behind a lock: writes are a few rows per second, far below SQLite's limits.

``LimitChecker`` classifies each value as ok / yellow / red against the configured ranges and
reports a ``LimitEvent`` only when a channel's level changes, not on every sample.

``GuardedArchive`` is what the daemon writes through: an archive that cannot be written (a full
disk, a read-only or corrupt file) must not silence the limits, so its writes never raise. The
first failure is said once (a warning event), events are kept in memory meanwhile (and shown by
``events``) and written when the archive takes writes again, which is tried at most every
``RETRY_S``; samples of that time are not archived (the latest values stay in the daemon's
memory), and the recovery is said with the gap's length.
"""

from __future__ import annotations

import collections
import math
import sqlite3
import threading
import time
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path
from typing import Any, TypeVar

from camd.daemon.config import ChannelLimits
from camd.daemon.errors import ArchiveUnreadable
from camd.daemon.telemetry_query import EventFilter, range_where

SCHEMA = """
CREATE TABLE IF NOT EXISTS samples (
    t_s     REAL NOT NULL,  -- Unix time of the sample, seconds
    channel TEXT NOT NULL,
    value   REAL NOT NULL,
    source  TEXT NOT NULL   -- 'tlm' (unsolicited packet) or 'poll' (GET_HOUSEKEEPING)
);
CREATE INDEX IF NOT EXISTS samples_by_channel_time ON samples (channel, t_s);
CREATE TABLE IF NOT EXISTS channels (
    name TEXT PRIMARY KEY,
    unit TEXT NOT NULL DEFAULT ''
);
CREATE TABLE IF NOT EXISTS events (
    id      INTEGER PRIMARY KEY,
    t_s     REAL NOT NULL,
    level   TEXT NOT NULL,  -- info, warning, error
    source  TEXT NOT NULL,  -- link, device, limits, daemon, api
    message TEXT NOT NULL
);
CREATE INDEX IF NOT EXISTS events_by_time ON events (t_s);
"""


_T = TypeVar("_T")


class Level(StrEnum):
    """A channel's limit level."""

    OK = "ok"
    YELLOW = "yellow"
    RED = "red"


_EVENT_LEVEL = {Level.OK: "info", Level.YELLOW: "warning", Level.RED: "error"}


@dataclass(frozen=True, slots=True)
class Sample:
    """The latest value of one channel."""

    t_s: float
    value: float
    source: str
    unit: str


@dataclass(frozen=True, slots=True)
class Event:
    """One archived event."""

    t_s: float
    level: str
    source: str
    message: str


class TelemetryArchive:
    """The SQLite archive at ``path`` (created with its directory if absent)."""

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._lock = threading.Lock()
        # check_same_thread=False: the lock serialises use across the daemon's threads.
        self._db = sqlite3.connect(self.path, check_same_thread=False, isolation_level=None)
        self._db.execute("PRAGMA journal_mode=WAL")
        # NORMAL in WAL mode: a power cut can lose the last transactions, never corrupt the file.
        self._db.execute("PRAGMA synchronous=NORMAL")
        self._db.executescript(SCHEMA)
        self._units: dict[str, str] = dict(self._db.execute("SELECT name, unit FROM channels"))
        # count(*) scans the table; keep a running count instead (one writer per archive).
        (self._count,) = self._db.execute("SELECT count(*) FROM samples").fetchone()

    def close(self) -> None:
        """Close the database (the WAL is checkpointed into the main file)."""
        with self._lock:
            self._db.close()

    def __enter__(self) -> TelemetryArchive:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- writing --------------------------------------------------------------------------------

    def add_samples(
        self,
        t_s: float,
        values: Mapping[str, float],
        source: str,
        units: Mapping[str, str] | None = None,
    ) -> int:
        """Archive one sample per channel at ``t_s``; return how many rows were written.

        Non-finite values are skipped (SQLite would store NaN as NULL, which the schema forbids).
        """
        rows = [(t_s, ch, float(v), source) for ch, v in values.items() if math.isfinite(float(v))]
        new_units = [(ch, (units or {}).get(ch, "")) for ch in values if ch not in self._units]
        with self._lock:
            with self._db:  # one transaction: a sample's channels land together
                self._db.execute("BEGIN")
                self._db.executemany("INSERT INTO samples VALUES (?, ?, ?, ?)", rows)
                if new_units:
                    self._db.executemany(
                        "INSERT OR IGNORE INTO channels (name, unit) VALUES (?, ?)", new_units
                    )
            self._units.update(new_units)
            self._count += len(rows)
        return len(rows)

    def add_event(self, level: str, source: str, message: str, t_s: float | None = None) -> Event:
        """Archive an event (``t_s`` defaults to now) and return it."""
        event = Event(time.time() if t_s is None else t_s, level, source, message)
        with self._lock:
            self._db.execute(
                "INSERT INTO events (t_s, level, source, message) VALUES (?, ?, ?, ?)",
                (event.t_s, event.level, event.source, event.message),
            )
        return event

    # -- queries --------------------------------------------------------------------------------

    def channels(self) -> dict[str, str]:
        """Every channel ever archived, name -> unit."""
        with self._lock:
            return dict(self._units)

    def latest(self, channels: Iterable[str] | None = None) -> dict[str, Sample]:
        """The newest sample of each channel (default: all channels archived)."""
        names = list(self.channels() if channels is None else channels)
        out: dict[str, Sample] = {}
        with self._lock:
            for name in names:
                # One index probe per channel: stays fast however long the archive grows.
                row = self._db.execute(
                    "SELECT t_s, value, source FROM samples WHERE channel = ? "
                    "ORDER BY t_s DESC LIMIT 1",
                    (name,),
                ).fetchone()
                if row is not None:
                    out[name] = Sample(row[0], row[1], row[2], self._units.get(name, ""))
        return out

    def history(
        self, channel: str, since_s: float = 0.0, limit: int = 1000
    ) -> tuple[list[float], list[float]]:
        """(times, values) of ``channel`` with t_s >= ``since_s``, oldest first; at most the
        newest ``limit`` samples."""
        with self._lock:
            rows = self._db.execute(
                "SELECT t_s, value FROM samples WHERE channel = ? AND t_s >= ? "
                "ORDER BY t_s DESC LIMIT ?",
                (channel, since_s, limit),
            ).fetchall()
        rows.reverse()
        return [r[0] for r in rows], [r[1] for r in rows]

    def samples(
        self,
        channel: str,
        start_s: float,
        end_s: float,
        source: str | None = None,
        limit: int = -1,
    ) -> list[tuple[float, float, str]]:
        """(t_s, value, source) of ``channel`` with start_s <= t_s < end_s, oldest first; of
        one source (``tlm`` or ``poll``) or of both; the newest ``limit`` (< 0: all)."""
        sql, args = range_where(channel, start_s, end_s, source)
        with self._lock:
            rows = self._db.execute(
                f"SELECT t_s, value, source FROM samples {sql} "
                "ORDER BY t_s DESC, source DESC LIMIT ?",
                (*args, limit),
            ).fetchall()
        rows.reverse()
        return [(float(t), float(v), str(s)) for t, v, s in rows]

    def count_range(
        self, channel: str, start_s: float, end_s: float, source: str | None = None
    ) -> int:
        """How many samples ``samples`` would return (an index range count, no rows read)."""
        sql, args = range_where(channel, start_s, end_s, source)
        with self._lock:
            (n,) = self._db.execute(f"SELECT count(*) FROM samples {sql}", args).fetchone()
        return int(n)

    def buckets(
        self,
        channel: str,
        start_s: float,
        end_s: float,
        bucket_s: float,
        source: str | None = None,
    ) -> list[tuple[float, str, float, float, float, int]]:
        """(bucket start, source, min, mean, max, count) of ``channel`` per ``bucket_s`` from
        ``start_s``, oldest first, buckets without samples left out.

        Per source: a packet and a poll are two samples of their own, so a bucket counts each
        sample once and never merges the two streams' counts."""
        sql, args = range_where(channel, start_s, end_s, source)
        with self._lock:
            rows = self._db.execute(
                "SELECT CAST((t_s - ?) / ? AS INTEGER) AS bucket, source, min(value), "
                f"avg(value), max(value), count(*) FROM samples {sql} "
                "GROUP BY bucket, source ORDER BY bucket, source",
                (start_s, bucket_s, *args),
            ).fetchall()
        return [
            (start_s + int(b) * bucket_s, str(s), float(lo), float(mean), float(hi), int(n))
            for b, s, lo, mean, hi, n in rows
        ]

    def prune(self, before_t_s: float) -> int:
        """Delete samples older than ``before_t_s``; return how many rows went.

        Deleted channel by channel so that each DELETE walks the (channel, t_s) index instead
        of scanning the whole table while the writers wait."""
        removed = 0
        with self._lock:
            channels = [row[0] for row in self._db.execute("SELECT DISTINCT channel FROM samples")]
            for channel in channels:
                cur = self._db.execute(
                    "DELETE FROM samples WHERE channel = ? AND t_s < ?", (channel, before_t_s)
                )
                removed += cur.rowcount
            self._count -= removed
        return removed

    def count(self, channel: str | None = None) -> int:
        """Number of archived samples (of one channel, or of all)."""
        with self._lock:
            if channel is None:
                return int(self._count)
            (n,) = self._db.execute(
                "SELECT count(*) FROM samples WHERE channel = ?", (channel,)
            ).fetchone()
            return int(n)

    def events(self, limit: int = 100, **where: Any) -> list[Event]:
        """The newest ``limit`` events, newest last; ``where``: ``EventFilter``'s fields."""
        match = EventFilter(**where)
        sql, args = match.sql()
        with self._lock:
            rows = self._db.execute(
                # By time, not by arrival: threads stamp their events before they take the
                # lock to archive them, so on a busy machine arrival order can be a few ms off
                # (seen: 3.7 ms), and device events carry the device's own time.
                f"SELECT t_s, level, source, message FROM events {sql} "
                "ORDER BY t_s DESC, id DESC LIMIT ?",
                (*args, limit),
            ).fetchall()
        rows.reverse()
        return [Event(*row) for row in rows]


def classify(value: float, limits: ChannelLimits) -> Level:
    """ok inside the yellow range, yellow inside the red range, red outside (bounds inclusive).

    NaN is red: a channel that cannot be read is as alarming as one out of range."""
    if math.isnan(value):
        return Level.RED
    if limits.yellow[0] <= value <= limits.yellow[1]:
        return Level.OK
    if limits.red[0] <= value <= limits.red[1]:
        return Level.YELLOW
    return Level.RED


@dataclass(frozen=True, slots=True)
class LimitEvent:
    """A channel changed limit level."""

    t_s: float
    channel: str
    value: float
    old: Level
    new: Level

    @property
    def level(self) -> str:
        """Event severity: error entering red, warning entering yellow, info back to ok."""
        return _EVENT_LEVEL[self.new]

    def message(self, limits: ChannelLimits, unit: str = "") -> str:
        """The event in words, with the value and the range it left or entered."""
        u = f" {unit}" if unit else ""
        if self.new == Level.OK:
            return (
                f"{self.channel} back to ok: {self.value:.6g}{u} within "
                f"[{limits.yellow[0]:g}, {limits.yellow[1]:g}]{u}"
            )
        rng = limits.yellow if self.new == Level.YELLOW else limits.red
        return (
            f"{self.channel} {self.old.value} -> {self.new.value}: {self.value:.6g}{u} outside "
            f"the {self.new.value} range [{rng[0]:g}, {rng[1]:g}]{u}"
        )


class LimitChecker:
    """Applies yellow/red limits and reports level changes only.

    Every channel starts ok, so a first sample already out of range is reported.
    """

    def __init__(self, limits: Mapping[str, ChannelLimits]) -> None:
        self.limits = dict(limits)
        self._levels: dict[str, Level] = {}
        self._lock = threading.Lock()

    def check(self, values: Mapping[str, float], t_s: float) -> list[LimitEvent]:
        """Classify the limited channels among ``values``; return the level changes."""
        events = []
        with self._lock:
            for channel, limits in self.limits.items():
                if channel not in values:
                    continue
                value = float(values[channel])
                new = classify(value, limits)
                old = self._levels.get(channel, Level.OK)
                self._levels[channel] = new
                if new != old:
                    events.append(LimitEvent(t_s, channel, value, old, new))
        return events

    def level(self, channel: str) -> Level:
        """The channel's level after the last check (ok if never checked)."""
        with self._lock:
            return self._levels.get(channel, Level.OK)

    def levels(self) -> dict[str, Level]:
        """Every checked channel's level."""
        with self._lock:
            return dict(self._levels)

    def red_channels(self) -> list[str]:
        """Channels now red."""
        with self._lock:
            return [ch for ch, lvl in self._levels.items() if lvl == Level.RED]

    def clear(self) -> None:
        """Forget the levels (a new device session starts from ok)."""
        with self._lock:
            self._levels.clear()


# -- writes that never raise -------------------------------------------------------------------

PENDING_EVENTS_MAX = 10_000  # events kept in memory while the archive cannot take them
RETRY_S = 2.0  # a failing archive is tried again at most this often
ARCHIVE_ERRORS = (sqlite3.Error, OSError)


class GuardedArchive:
    """The daemon's telemetry archive, whose writes never raise (module docstring).

    ``notify(level, message)`` is told when writing starts to fail and when it works again;
    it is called outside the guard's lock and may write an event (which is then kept in
    memory). Reads of an archive that cannot be read raise ``ArchiveUnreadable``.
    """

    def __init__(
        self,
        archive: TelemetryArchive,
        notify: Callable[[str, str], None],
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.archive = archive
        self._notify = notify
        self._clock = clock
        self._lock = threading.Lock()
        self._pending: collections.deque[Event] = collections.deque(maxlen=PENDING_EVENTS_MAX)
        self._dropped_events = 0  # pending events pushed out of the full queue
        self._failing: str | None = None
        self._failed_since_t_s = 0.0
        self._samples_missed = 0
        self._next_try = 0.0

    @property
    def path(self) -> Path:
        return self.archive.path

    @property
    def failing(self) -> str | None:
        """Why the archive cannot be written now (None while it can)."""
        return self._failing

    def close(self) -> None:
        """Write what is kept in memory if the archive takes it, then close it."""
        with self._lock:
            if self._pending:
                self._try_flush()
        self.archive.close()

    # -- writing --------------------------------------------------------------------------------

    def add_samples(
        self, t_s: float, values: Mapping[str, float], source: str, units: Mapping[str, str]
    ) -> None:
        """Archive one sample of each channel, or count it as missed while the archive fails."""
        said: tuple[str, str] | None = None
        with self._lock:
            if self._failing is not None and not self._retry_due():
                self._samples_missed += 1
                return
            try:
                self._try_flush()
                self.archive.add_samples(t_s, values, source, units)
            except ARCHIVE_ERRORS as exc:
                self._samples_missed += 1
                said = self._failed(exc)
            else:
                said = self._recovered()
        if said is not None:
            self._notify(*said)

    def add_event(self, level: str, source: str, message: str, t_s: float | None = None) -> None:
        """Archive an event, or keep it in memory until the archive takes it."""
        event = Event(time.time() if t_s is None else t_s, level, source, message)
        said: tuple[str, str] | None = None
        with self._lock:
            if self._failing is not None and not self._retry_due():
                self._keep(event)
                return
            try:
                self._try_flush()
                self.archive.add_event(event.level, event.source, event.message, event.t_s)
            except ARCHIVE_ERRORS as exc:
                self._keep(event)
                said = self._failed(exc)
            else:
                said = self._recovered()
        if said is not None:
            self._notify(*said)

    def prune(self, before_t_s: float) -> int:
        """Delete samples older than ``before_t_s`` (0 while the archive fails)."""
        with self._lock:
            if self._failing is not None:
                return 0
            try:
                return self.archive.prune(before_t_s)
            except ARCHIVE_ERRORS:
                return 0  # the next write finds out and says so

    def _keep(self, event: Event) -> None:
        if len(self._pending) == self._pending.maxlen:
            self._dropped_events += 1
        self._pending.append(event)

    def _retry_due(self) -> bool:
        now = self._clock()
        if now < self._next_try:
            return False
        self._next_try = now + RETRY_S
        return True

    def _try_flush(self) -> None:
        """Write the events kept in memory, oldest first; each leaves the queue once written."""
        while self._pending:
            e = self._pending[0]
            self.archive.add_event(e.level, e.source, e.message, e.t_s)
            self._pending.popleft()

    def _failed(self, exc: BaseException) -> tuple[str, str] | None:
        first = self._failing is None
        self._failing = f"{type(exc).__name__}: {exc}"
        self._next_try = self._clock() + RETRY_S
        if not first:
            return None
        self._failed_since_t_s = time.time()
        return (
            "warning",
            f"telemetry archive {self.path} cannot be written ({self._failing}): free space "
            "on its disk or check the file; meanwhile the limits are still checked, the latest "
            "values and the events are kept in memory, and samples are not archived",
        )

    def _recovered(self) -> tuple[str, str] | None:
        if self._failing is None:
            return None
        gap_s = time.time() - self._failed_since_t_s
        missed, dropped = self._samples_missed, self._dropped_events
        self._failing, self._samples_missed, self._dropped_events = None, 0, 0
        lost = (
            f"; {dropped} events were lost (more than {PENDING_EVENTS_MAX} kept)" if dropped else ""
        )
        return (
            "info",
            f"telemetry archive {self.path} written again after {gap_s:.0f} s: the events kept "
            f"in memory are archived, {missed} samples of that time are not{lost}",
        )

    # -- reading --------------------------------------------------------------------------------

    def events(self, limit: int = 100, **where: Any) -> list[Event]:
        """The newest ``limit`` events, archived or kept in memory, newest last; ``where``:
        ``EventFilter``'s fields."""
        match = EventFilter(**where)
        with self._lock:
            pending = [e for e in self._pending if match.matches(e)]
        try:
            archived = self.archive.events(limit, **where)
        except ARCHIVE_ERRORS as exc:
            if not pending:
                raise _unreadable(self.path, exc) from None
            archived = []
        merged = sorted(archived + pending, key=lambda e: e.t_s)
        return merged[-limit:] if limit > 0 else []

    def latest(self, channels: Iterable[str] | None = None) -> dict[str, Sample]:
        try:
            return self.archive.latest(channels)
        except ARCHIVE_ERRORS as exc:
            raise _unreadable(self.path, exc) from None

    def history(
        self, channel: str, since_s: float = 0.0, limit: int = 1000
    ) -> tuple[list[float], list[float]]:
        try:
            return self.archive.history(channel, since_s, limit)
        except ARCHIVE_ERRORS as exc:
            raise _unreadable(self.path, exc) from None

    def samples(
        self, channel: str, start_s: float, end_s: float, source: str | None, limit: int = -1
    ) -> list[tuple[float, float, str]]:
        return self._read(lambda: self.archive.samples(channel, start_s, end_s, source, limit))

    def count_range(
        self, channel: str, start_s: float, end_s: float, source: str | None = None
    ) -> int:
        return self._read(lambda: self.archive.count_range(channel, start_s, end_s, source))

    def buckets(
        self, channel: str, start_s: float, end_s: float, bucket_s: float, source: str | None
    ) -> list[tuple[float, str, float, float, float, int]]:
        return self._read(lambda: self.archive.buckets(channel, start_s, end_s, bucket_s, source))

    def _read(self, read: Callable[[], _T]) -> _T:
        """``read()``, an archive that cannot be read said as ``ArchiveUnreadable``."""
        try:
            return read()
        except ARCHIVE_ERRORS as exc:
            raise _unreadable(self.path, exc) from None

    def count(self) -> int:
        return self.archive.count()


def _unreadable(path: Path, exc: BaseException) -> ArchiveUnreadable:
    return ArchiveUnreadable(
        f"the telemetry archive {path} cannot be read ({type(exc).__name__}: {exc}); the "
        "latest values are in GET /api/v1/telemetry; check the file or move it aside, then "
        "restart camd"
    )
