"""The telemetry archive (real SQLite files) and the limit checker, against hand-computed values."""

from __future__ import annotations

import math
import sqlite3
import threading
import time
from pathlib import Path

import pytest

from camd.daemon.config import config_from_dict
from camd.daemon.config_camera import ChannelLimits
from camd.daemon.errors import ArchiveUnreadable, BadRequest
from camd.daemon.models import HISTORY_POINTS_MAX
from camd.daemon.telemetry import GuardedArchive, Level, LimitChecker, TelemetryArchive, classify
from camd.daemon.telemetry_query import HistoryQuery
from camd.daemon.telemetry_service import TelemetryService
from camd.daemon.time_range import parse_instant, parse_range
from tests.crash_support import fill_disk, small_disk

TEMP = ChannelLimits(yellow=(0.0, 70.0), red=(-20.0, 85.0))
VOLT = ChannelLimits(yellow=(3.2, 3.4), red=(3.1, 3.5))


@pytest.fixture
def archive(tmp_path: Path) -> TelemetryArchive:
    return TelemetryArchive(tmp_path / "data" / "telemetry.sqlite")


def test_creates_directory_and_uses_wal(tmp_path: Path) -> None:
    path = tmp_path / "a" / "b" / "telemetry.sqlite"
    with TelemetryArchive(path):
        assert path.is_file()
        other = sqlite3.connect(path)
        try:
            (mode,) = other.execute("PRAGMA journal_mode").fetchone()
        finally:
            other.close()
        assert mode == "wal"


def test_samples_are_stored_in_long_format(archive: TelemetryArchive) -> None:
    archive.add_samples(100.0, {"a": 1.0, "b": 2.0}, "tlm", {"a": "V", "b": "A"})
    archive.add_samples(101.0, {"a": 1.5}, "poll")
    db = sqlite3.connect(archive.path)
    try:
        rows = db.execute(
            "SELECT t_s, channel, value, source FROM samples ORDER BY rowid"
        ).fetchall()
        indexes = [r[1] for r in db.execute("PRAGMA index_list(samples)")]
    finally:
        db.close()
    assert rows == [(100.0, "a", 1.0, "tlm"), (100.0, "b", 2.0, "tlm"), (101.0, "a", 1.5, "poll")]
    assert "samples_by_channel_time" in indexes
    assert archive.channels() == {"a": "V", "b": "A"}


def test_latest_per_channel(archive: TelemetryArchive) -> None:
    archive.add_samples(10.0, {"a": 1.0, "b": 5.0}, "tlm", {"a": "V", "b": "A"})
    archive.add_samples(12.0, {"a": 3.0}, "poll")
    archive.add_samples(11.0, {"a": 2.0}, "tlm")  # arrived late: not the newest
    latest = archive.latest()
    assert (latest["a"].t_s, latest["a"].value, latest["a"].source) == (12.0, 3.0, "poll")
    assert (latest["b"].t_s, latest["b"].value, latest["b"].unit) == (10.0, 5.0, "A")
    assert archive.latest(["b", "nope"]).keys() == {"b"}


def test_history_since_and_limit(archive: TelemetryArchive) -> None:
    for i in range(10):
        archive.add_samples(100.0 + i, {"x": float(i * i), "y": -1.0}, "tlm")
    t, v = archive.history("x")
    assert t == [100.0 + i for i in range(10)] and v == [float(i * i) for i in range(10)]
    t, v = archive.history("x", since_s=105.0)
    assert t == [105.0, 106.0, 107.0, 108.0, 109.0] and v == [25.0, 36.0, 49.0, 64.0, 81.0]
    t, v = archive.history("x", limit=3)  # the newest 3, oldest first
    assert t == [107.0, 108.0, 109.0] and v == [49.0, 64.0, 81.0]
    t, v = archive.history("x", since_s=108.5, limit=3)
    assert t == [109.0]
    assert archive.history("absent") == ([], [])


def test_count_total_and_per_channel_survives_reopen(tmp_path: Path) -> None:
    path = tmp_path / "t.sqlite"
    with TelemetryArchive(path) as a:
        assert a.count() == 0
        a.add_samples(1.0, {"x": 1.0, "y": 2.0, "z": 3.0}, "tlm")
        a.add_samples(2.0, {"x": 1.0}, "poll")
        assert (a.count(), a.count("x"), a.count("y"), a.count("q")) == (4, 2, 1, 0)
    with TelemetryArchive(path) as a:
        assert a.count() == 4
        assert a.channels().keys() == {"x", "y", "z"}
        a.add_samples(3.0, {"y": 0.0}, "tlm")
        assert a.count() == 5


def test_non_finite_values_are_skipped(archive: TelemetryArchive) -> None:
    n = archive.add_samples(1.0, {"a": math.nan, "b": math.inf, "c": 1.0}, "tlm")
    assert n == 1 and archive.count() == 1 and archive.latest().keys() == {"c"}


def test_events_newest_last_and_limited(archive: TelemetryArchive) -> None:
    for i in range(5):
        archive.add_event("info", "test", f"event {i}", t_s=50.0 + i)
    ev = archive.add_event("error", "limits", "boom")
    assert ev.level == "error" and ev.t_s > 1e9  # defaulted to now
    events = archive.events(3)
    assert [e.message for e in events] == ["event 3", "event 4", "boom"]
    assert archive.events(100)[0].message == "event 0"


def test_events_come_in_time_order_whatever_order_they_arrived_in(
    archive: TelemetryArchive,
) -> None:
    # A thread that stamped its event first can archive it last (seen under load: 3.7 ms).
    archive.add_event("info", "test", "second", t_s=100.0037)
    archive.add_event("info", "test", "first", t_s=100.0)
    archive.add_event("info", "test", "third, same time as second", t_s=100.0037)
    assert [e.message for e in archive.events(10)] == [
        "first", "second", "third, same time as second",
    ]  # fmt: skip
    assert [e.message for e in archive.events(1)] == ["third, same time as second"]


def test_threads_share_the_archive(archive: TelemetryArchive) -> None:
    def writer(k: int) -> None:
        for i in range(200):
            archive.add_samples(float(i), {f"c{k}": float(i)}, "tlm")
            if i % 50 == 0:
                archive.latest()

    threads = [threading.Thread(target=writer, args=(k,)) for k in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert archive.count() == 800
    assert all(archive.count(f"c{k}") == 200 for k in range(4))


@pytest.mark.parametrize(
    ("value", "level"),
    [
        (3.3, Level.OK),
        (3.2, Level.OK),  # bounds are inclusive
        (3.4, Level.OK),
        (3.19, Level.YELLOW),
        (3.41, Level.YELLOW),
        (3.1, Level.YELLOW),
        (3.5, Level.YELLOW),
        (3.09, Level.RED),
        (3.51, Level.RED),
        (0.0, Level.RED),
        (math.nan, Level.RED),
    ],
)
def test_classify(value: float, level: Level) -> None:
    assert classify(value, VOLT) == level


def test_limit_events_on_transitions_only() -> None:
    checker = LimitChecker({"t": TEMP})
    temps = [20, 30, 71, 72, 80, 86, 90, 84, 60, 50, -25, 10]
    seen = []
    for i, temp in enumerate(temps):
        for ev in checker.check({"t": float(temp), "other": 1.0}, float(i)):
            seen.append((ev.t_s, ev.old.value, ev.new.value, ev.level))
    assert seen == [
        (2.0, "ok", "yellow", "warning"),  # 71 > 70
        (5.0, "yellow", "red", "error"),  # 86 > 85
        (7.0, "red", "yellow", "warning"),  # 84
        (8.0, "yellow", "ok", "info"),  # 60
        (10.0, "ok", "red", "error"),  # -25 < -20: straight to red
        (11.0, "red", "ok", "info"),
    ]
    assert checker.level("t") == Level.OK


def test_limit_event_messages_name_value_and_range() -> None:
    checker = LimitChecker({"vcc_io_v": VOLT})
    (ev,) = checker.check({"vcc_io_v": 3.05}, 1.0)
    assert ev.new == Level.RED and checker.red_channels() == ["vcc_io_v"]
    assert ev.message(VOLT, "V") == "vcc_io_v ok -> red: 3.05 V outside the red range [3.1, 3.5] V"
    (ev,) = checker.check({"vcc_io_v": 3.3}, 2.0)
    assert ev.message(VOLT, "V") == "vcc_io_v back to ok: 3.3 V within [3.2, 3.4] V"


def test_first_sample_out_of_range_is_reported_and_clear_forgets() -> None:
    checker = LimitChecker({"t": TEMP})
    assert [e.new for e in checker.check({"t": 100.0}, 0.0)] == [Level.RED]
    assert checker.check({"t": 101.0}, 1.0) == []
    checker.clear()
    assert checker.levels() == {}
    assert [e.new for e in checker.check({"t": 100.0}, 2.0)] == [Level.RED]


def test_channels_without_limits_are_ignored() -> None:
    checker = LimitChecker({"t": TEMP})
    assert checker.check({"uptime_s": 1e9}, 0.0) == []
    assert checker.levels() == {}


def test_prune_deletes_only_samples_older_than_the_cutoff(tmp_path: Path) -> None:
    path = tmp_path / "t.sqlite"
    with TelemetryArchive(path) as arch:
        for t in range(100):
            arch.add_samples(float(t), {"a": float(t), "b": -float(t)}, "tlm")
        arch.add_event("info", "test", "kept")
        # t = 0 .. 49 go, for both channels: 100 rows; t = 50 itself stays.
        assert arch.prune(50.0) == 100
        assert arch.count() == 100 and arch.count("a") == 50
        assert arch.prune(50.0) == 0
    with TelemetryArchive(path) as arch:  # the running count agrees with the file
        assert arch.count() == 100
        assert min(t for (t,) in sqlite3.connect(path).execute("SELECT t_s FROM samples")) == 50.0
        assert [e.message for e in arch.events()] == ["kept"]


# -- GuardedArchive: an archive on a disk that fills up and empties again -------------------------


class _Clock:
    def __init__(self) -> None:
        self.t_s = 0.0

    def __call__(self) -> float:
        return self.t_s


def test_a_full_disk_is_said_once_events_are_kept_and_archived_when_space_returns(
    tmp_path: Path,
) -> None:
    """The archive on a real 1 MiB tmpfs filled to the last page: writes never raise, the
    failure is said once, events are kept and shown, samples missed are counted, and once the
    space is back (and a retry is due) the kept events are archived and the recovery said."""
    said: list[tuple[str, str]] = []
    clock = _Clock()
    with small_disk(tmp_path / "disk", 1) as disk:
        guard = GuardedArchive(
            TelemetryArchive(disk / "telemetry.sqlite"),
            lambda level, message: said.append((level, message)),
            clock,
        )
        try:
            guard.add_samples(1.0, {"a": 1.0}, "tlm", {"a": "V"})
            guard.add_event("info", "test", "before", t_s=1.0)
            assert guard.failing is None and said == []
            fill_disk(disk)
            # Samples each add rows: one of these finds the disk full (SQLite may still fit a
            # few rows into pages it holds).
            for i in range(2, 400):
                guard.add_samples(float(i), {"a": float(i)}, "tlm", {"a": "V"})
                if guard.failing is not None:
                    break
            assert guard.failing is not None and "full" in guard.failing, guard.failing
            assert len(said) == 1 and said[0][0] == "warning"
            assert "cannot be written" in said[0][1] and "limits are still checked" in said[0][1]
            archived_before = guard.count()
            for i in range(5):  # kept in memory, no retry due: no second warning
                guard.add_event("error", "limits", f"red {i}", t_s=1000.0 + i)
                guard.add_samples(1000.0 + i, {"a": 9.0}, "tlm", {"a": "V"})
            assert len(said) == 1 and guard.count() == archived_before
            shown = [e.message for e in guard.events(3)]
            assert shown == ["red 2", "red 3", "red 4"]
            clock.t_s += 10.0  # a retry is due, but the disk is still full
            guard.add_event("error", "limits", "red 5", t_s=1005.0)
            assert guard.failing is not None and len(said) == 1
            (disk / "filler").unlink()
            guard.add_samples(1006.0, {"a": 1.0}, "tlm", {"a": "V"})
            assert guard.failing is not None  # the next retry is not due yet
            clock.t_s += 10.0
            guard.add_samples(1007.0, {"a": 1.0}, "tlm", {"a": "V"})
            assert guard.failing is None
            assert said[1][0] == "info" and "written again" in said[1][1]
            assert " samples of that time are not" in said[1][1]
            # Every event kept is in the file now, in time order.
            archived = [e.message for e in guard.archive.events(100)]
            assert archived[-6:] == [f"red {i}" for i in range(6)]
            assert archived[0] == "before"
        finally:
            guard.close()


def test_an_unreadable_archive_is_a_clear_error(tmp_path: Path) -> None:
    path = tmp_path / "telemetry.sqlite"
    guard = GuardedArchive(TelemetryArchive(path), lambda level, message: None)
    guard.archive.close()  # what a corrupt file looks like to a read: sqlite3 raises
    with pytest.raises(ArchiveUnreadable, match=r"cannot be read .* move it aside"):
        guard.history("a")
    with pytest.raises(ArchiveUnreadable):
        guard.events(10)
    guard.add_event("warning", "test", "kept", t_s=5.0)  # never raises
    assert [e.message for e in guard.events(10)] == ["kept"]


# -- history over a range, downsampled, and the events filtered (issue 34 item 7) -------------


def test_time_range_takes_iso_relative_unix_and_now_and_refuses_the_rest() -> None:
    now_s = 1_800_000_000.0
    assert parse_instant("now", now_s, "end") == now_s
    assert parse_instant("-10m", now_s, "start") == now_s - 600.0
    assert parse_instant("-2h", now_s, "start") == now_s - 7200.0
    assert parse_instant("-1.5d", now_s, "start") == now_s - 1.5 * 86400.0
    assert parse_instant("-30s", now_s, "start") == now_s - 30.0
    assert parse_instant("-60", now_s, "start") == now_s - 60.0  # seconds before now
    assert parse_instant("1700000000.5", now_s, "start") == 1_700_000_000.5
    assert parse_instant("2026-11-27T22:00:00Z", now_s, "start") == 1_795_816_800.0
    assert parse_instant("2026-11-27T23:00:00+01:00", now_s, "start") == 1_795_816_800.0
    assert parse_instant("2026-11-27T22:00:00", now_s, "start") == 1_795_816_800.0  # UTC
    with pytest.raises(BadRequest) as bad:
        parse_instant("yesterday", now_s, "start")
    assert str(bad.value) == (
        "start: 'yesterday' is not a time; give an ISO 8601 time (2026-11-27T22:00:00Z), a Unix "
        "time in seconds, now, or a time before now like -30s, -10m, -2h or -1d"
    )
    with pytest.raises(BadRequest) as bad:
        parse_instant("-100000d", now_s, "start")  # would be a time no message could write
    assert str(bad.value) == (
        "start: '-100000d' is before 1970; give a time from 1970-01-01T00:00:00Z to "
        "9999-12-31T23:59:59Z"
    )
    with pytest.raises(BadRequest) as bad:
        parse_instant("1e300", now_s, "end")
    assert str(bad.value).startswith("end: '1e300' is after 9999;")
    with pytest.raises(BadRequest) as bad:
        parse_range("-1h", "-2h", now_s)
    assert str(bad.value) == (
        "start (-1h = 2027-01-15T07:00:00Z) is not before end (-2h = 2027-01-15T06:00:00Z): "
        "give a start earlier than the end"
    )


def _written(archive: TelemetryArchive) -> None:
    """x from two sources, 0.5 s apart, values known; y only from packets."""
    for i in range(40):
        archive.add_samples(1000.0 + i * 0.5, {"x": float(i * i % 7)}, "tlm" if i % 2 else "poll")
        archive.add_samples(1000.0 + i * 0.5, {"y": float(i)}, "tlm")


def test_samples_over_a_range_say_their_source(archive: TelemetryArchive) -> None:
    _written(archive)
    rows = archive.samples("x", 1002.0, 1004.0)  # [start, end)
    assert [(t, v, s) for t, v, s in rows] == [
        (1000.0 + i * 0.5, float(i * i % 7), "tlm" if i % 2 else "poll") for i in range(4, 8)
    ]
    assert archive.samples("x", 1002.0, 1004.0, source="poll") == [
        (1002.0, 2.0, "poll"), (1003.0, 1.0, "poll")
    ]  # fmt: skip
    assert archive.count_range("x", 1002.0, 1004.0) == 4
    assert archive.count_range("x", 1002.0, 1004.0, source="tlm") == 2


def test_buckets_give_min_mean_max_count_per_source(archive: TelemetryArchive) -> None:
    _written(archive)
    got = archive.buckets("x", 1000.0, 1020.0, 3.0)
    expected = []
    for b in range(7):
        for source in ("poll", "tlm"):
            vals = [
                float(i * i % 7)
                for i in range(40)
                if 1000.0 + 3.0 * b <= 1000.0 + i * 0.5 < 1000.0 + 3.0 * (b + 1)
                and ("tlm" if i % 2 else "poll") == source
            ]
            if vals:
                expected.append((1000.0 + 3.0 * b, source, min(vals), sum(vals) / len(vals),
                                 max(vals), len(vals)))  # fmt: skip
    assert [(t, s, lo, pytest.approx(m), hi, n) for t, s, lo, m, hi, n in got] == expected
    assert sum(n for *_, n in got) == 40  # every sample counted once


def test_events_filtered_by_range_level_and_source(archive: TelemetryArchive) -> None:
    archive.add_event("info", "link", "open", 10.0)
    archive.add_event("warning", "limits", "warm", 20.0)
    archive.add_event("error", "limits", "hot", 30.0)
    archive.add_event("info", "daemon", "started", 40.0)
    assert [e.message for e in archive.events(100, start_s=15.0, end_s=40.0)] == ["warm", "hot"]
    assert [e.message for e in archive.events(100, levels=["warning", "error"])] == ["warm", "hot"]
    assert [e.message for e in archive.events(100, sources=["link", "daemon"])] == [
        "open", "started"
    ]  # fmt: skip
    assert [e.message for e in archive.events(1, sources=["limits"])] == ["hot"]


def test_the_service_refuses_a_history_too_large_saying_how_to_narrow_it(tmp_path: Path) -> None:
    """In process: a real archive with 100001 samples of one channel in the last hour (one
    transaction), read through TelemetryService as the route does."""
    config = config_from_dict({"daemon": {"data_dir": str(tmp_path)}})
    service = TelemetryService(config, lambda *event: None, lambda reason: None)
    service.open()
    try:
        assert service.archive is not None
        now_s = time.time()
        db = service.archive.archive
        n = HISTORY_POINTS_MAX + 1
        with db._lock, db._db:  # one transaction: 100001 rows in about 0.3 s
            db._db.executemany(
                "INSERT INTO samples VALUES (?, 'uptime_s', ?, 'tlm')",
                ((now_s - 1800.0 + i * 0.01, float(i)) for i in range(n)),
            )
        with pytest.raises(BadRequest) as bad:
            service.history(HistoryQuery(channels=["uptime_s"]))
        message = str(bad.value)
        assert message.startswith(f"{n} samples from ")
        assert message.endswith(
            "more than the 100000 one answer holds; narrow start and end, ask fewer channels, "
            "or set bucket_s to at least 0.1"
        )  # the last hour, one channel, both sources: 3600 s * 2 / 100000 = 0.072 s, rounded up
        fits = service.history(HistoryQuery(channels=["uptime_s"], bucket_s=0.1))
        assert sum(fits.channels[0].count) == n
        newest = service.history(HistoryQuery(channels=["uptime_s"], limit=3))
        assert newest.channels[0].value == [n - 3.0, n - 2.0, n - 1.0]
        with pytest.raises(BadRequest) as bad:
            service.history(HistoryQuery(channels=["uptime_s"], start="-1h", since_s=-60.0))
        assert str(bad.value) == "since_s and start name the same thing: give only start"
        with pytest.raises(BadRequest) as bad:
            service.history(HistoryQuery(channels=[" , "]))
        assert str(bad.value).startswith("channel: name at least one telemetry channel")
    finally:
        service.close()


def test_events_kept_in_memory_are_filtered_as_the_archived_ones(tmp_path: Path) -> None:
    """An archive that cannot be written (here: closed) keeps the events in memory; the filter
    applies to those as to the archived ones."""
    said: list[tuple[str, str]] = []
    guard = GuardedArchive(
        TelemetryArchive(tmp_path / "t.sqlite"), lambda lvl, msg: said.append((lvl, msg))
    )
    guard.archive.close()  # every write now raises sqlite3.ProgrammingError
    guard.add_event("info", "link", "open", 10.0)
    guard.add_event("warning", "limits", "warm", 20.0)
    guard.add_event("error", "limits", "hot", 30.0)
    assert guard.failing is not None and said[0][0] == "warning"
    assert [e.message for e in guard.events(10, levels=["warning", "error"])] == ["warm", "hot"]
    assert [e.message for e in guard.events(10, sources=["limits"], end_s=30.0)] == ["warm"]
    assert [e.message for e in guard.events(10, start_s=15.0)] == ["warm", "hot"]
