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
import logging
import threading
import time
from collections.abc import Callable, Mapping
from typing import Any, cast

from camd.daemon.config import Config, telemetry_channels
from camd.daemon.device import EventSink
from camd.daemon.errors import BadRequest, SessionError
from camd.daemon.models import (
    ChannelLatest,
    EventItem,
    EventsResponse,
    HistoryResponse,
    TelemetryResponse,
)
from camd.daemon.telemetry import GuardedArchive, LimitChecker, TelemetryArchive, classify
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
            samples=archive.count(),
            archive=str(archive.path),
            archive_error=archive.failing,
        )

    def history(self, channel: str, since_s: float = 0.0, limit: int = 1000) -> HistoryResponse:
        """Archived samples of ``channel``, oldest first; ``since_s`` < 0 means "seconds ago"."""
        if channel not in self.channels:
            raise BadRequest(
                f"channel: {channel!r} is not a telemetry channel; use one of "
                + ", ".join(self.channels)
            )
        if since_s < 0:
            since_s = time.time() + since_s
        t_s, values = self._archive().history(channel, since_s, limit)
        return HistoryResponse(channel=channel, unit=self.channels[channel], t_s=t_s, value=values)

    def events(self, limit: int = 100) -> EventsResponse:
        """The newest ``limit`` events, newest last."""
        items = [
            EventItem(t_s=e.t_s, level=cast(Any, e.level), source=e.source, message=e.message)
            for e in self._archive().events(limit)
        ]
        return EventsResponse(events=items)
