"""Telemetry through a real daemon (`camd serve --sim`, fast housekeeping): the live values and
their archive, the history over a range (several channels, bucketed, CSV) against the samples
the archive holds, its refusals, and the events by range, level and source (docs/api.md,
"Telemetry over time").
"""

from __future__ import annotations

import csv
import io
import sqlite3
import time
from collections.abc import Iterator
from typing import Any

import pytest

from tests.test_daemon import API, Daemon, error_of, idle_daemon, wait_for


@pytest.fixture(scope="module")
def daemon(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Daemon]:
    with idle_daemon(tmp_path_factory.mktemp("daemon-telemetry")) as d:
        yield d


def test_telemetry_changes_and_is_archived(daemon: Daemon) -> None:
    first = wait_for(
        lambda: daemon.get(f"{API}/telemetry").json(), lambda d: d["latest"], timeout_s=30
    )
    assert first["archive"] == str(daemon.data_dir / "telemetry.sqlite")
    latest = first["latest"]
    assert {"fpga_temp_degc", "vcc_io_v", "supply_current_a", "uptime_s"} <= latest.keys()
    assert latest["vcc_io_v"]["unit"] == "V" and latest["vcc_io_v"]["limit"] == "ok"
    assert 3.0 < latest["vcc_io_v"]["value"] < 3.6

    second = wait_for(
        lambda: daemon.get(f"{API}/telemetry").json(),
        lambda d: d["latest"]["uptime_s"]["t_s"] > latest["uptime_s"]["t_s"],
        timeout_s=30,
    )
    assert second["latest"]["uptime_s"]["value"] > latest["uptime_s"]["value"]
    assert second["samples"] > first["samples"]

    def archived() -> tuple[dict[str, int], int]:
        db = sqlite3.connect(f"file:{first['archive']}?mode=ro", uri=True)
        try:
            sources = dict(db.execute("SELECT source, count(*) FROM samples GROUP BY source"))
            n_events = db.execute("SELECT count(*) FROM events").fetchone()[0]
        finally:
            db.close()
        return sources, n_events

    # Packets and polls come on their own threads: wait for one of each, however busy.
    sources, n_events = wait_for(
        archived, lambda a: a[0].get("tlm", 0) > 0 and a[0].get("poll", 0) > 0, timeout_s=30
    )
    assert sources.get("tlm", 0) > 0 and sources.get("poll", 0) > 0, sources
    assert n_events > 0

    (h,) = daemon.get(
        f"{API}/telemetry/history", params={"channel": "fpga_temp_degc", "limit": 5}
    ).json()["channels"]
    assert h["channel"] == "fpga_temp_degc" and h["unit"] == "degC"
    assert 1 <= len(h["t_s"]) == len(h["value"]) == len(h["source"]) <= 5
    assert h["t_s"] == sorted(h["t_s"]) and set(h["source"]) <= {"tlm", "poll"}
    asked_at = time.time()  # the daemon's "60 s ago" is later than asked_at - 60, however slow
    (recent,) = daemon.get(
        f"{API}/telemetry/history", params={"channel": "uptime_s", "since_s": -60}
    ).json()["channels"]
    assert recent["t_s"] and min(recent["t_s"]) >= asked_at - 61


def _archived_samples(path: str, channel: str, start_s: float, end_s: float) -> list[Any]:
    """(t_s, value, source) of ``channel`` in [start_s, end_s), read from the SQLite file."""
    db = sqlite3.connect(f"file:{path}?mode=ro", uri=True)
    try:
        return db.execute(
            "SELECT t_s, value, source FROM samples WHERE channel = ? AND t_s >= ? AND t_s < ? "
            "ORDER BY t_s, source",
            (channel, start_s, end_s),
        ).fetchall()
    finally:
        db.close()


def _newest_by_source(path: str) -> dict[str, float]:
    """The newest sample's time of each source in the archive."""
    db = sqlite3.connect(f"file:{path}?mode=ro", uri=True)
    try:
        return dict(db.execute("SELECT source, max(t_s) FROM samples GROUP BY source"))
    finally:
        db.close()


def test_history_range_buckets_and_csv_are_the_samples_written(daemon: Daemon) -> None:
    """A closed range of two channels gives exactly the rows in the archive, each with its
    source; buckets give the min/mean/max/count computed here from those rows (every sample
    counted once); the CSV parses back to the same numbers."""
    archive = daemon.get(f"{API}/telemetry").json()["archive"]
    start_s = time.time()
    end_s = start_s + 2.0
    # Closed: each source's samples are archived in order by one thread (packets: the link's
    # reader; polls: the service loop), so once both have one at or after end_s, the range
    # holds the same rows however often, and however late on a busy machine, we ask.
    wait_for(lambda: _newest_by_source(archive), lambda n: len(n) == 2 and min(n.values()) >= end_s,
             timeout_s=30, poll_s=0.2)  # fmt: skip
    channels = ["fpga_temp_degc", "uptime_s"]
    params: dict[str, Any] = {"channel": channels, "start": repr(start_s), "end": repr(end_s)}
    doc = daemon.get(f"{API}/telemetry/history", params=params).json()
    assert (doc["start_s"], doc["end_s"], doc["bucket_s"]) == (start_s, end_s, None)
    assert [c["channel"] for c in doc["channels"]] == channels
    for got in doc["channels"]:
        written = _archived_samples(archive, got["channel"], start_s, end_s)
        assert {s for *_, s in written} == {"tlm", "poll"}, written  # both at 0.2 s
        assert list(zip(got["t_s"], got["value"], got["source"], strict=True)) == [
            tuple(r) for r in written
        ]

    bucket_s = 0.5
    doc = daemon.get(f"{API}/telemetry/history", params={**params, "bucket_s": bucket_s}).json()
    assert doc["bucket_s"] == bucket_s
    for got in doc["channels"]:
        groups: dict[tuple[int, str], list[float]] = {}
        written = _archived_samples(archive, got["channel"], start_s, end_s)
        for t_s, value, source in written:
            groups.setdefault((int((t_s - start_s) // bucket_s), source), []).append(value)
        expected = [
            (start_s + b * bucket_s, src, min(v), sum(v) / len(v), max(v), len(v))
            for (b, src), v in sorted(groups.items())
        ]
        rows = zip(got["t_s"], got["source"], got["min"], got["mean"], got["max"], got["count"],
                   strict=True)  # fmt: skip
        assert [
            (pytest.approx(t), s, lo, pytest.approx(m), hi, n) for t, s, lo, m, hi, n in rows
        ] == expected
        assert sum(got["count"]) == len(written) and got["value"] == []

    csv_text = daemon.get(f"{API}/telemetry/history", params={**params, "format": "csv"})
    assert csv_text.headers["content-type"].startswith("text/csv")
    by_accept = daemon.get(
        f"{API}/telemetry/history", params=params, headers={"accept": "text/csv"}
    )
    assert by_accept.text == csv_text.text
    lines = list(csv.reader(io.StringIO(csv_text.text)))
    assert lines[0] == ["channel", "unit", "source", "t_s", "time_utc", "value"]
    expected_rows = [
        [ch, unit, s, float(t), v]
        for ch, unit in zip(channels, ["degC", "s"], strict=True)
        for t, v, s in _archived_samples(archive, ch, start_s, end_s)
    ]
    assert [[c, u, s, float(t), float(v)] for c, u, s, t, _, v in lines[1:]] == expected_rows


@pytest.mark.parametrize(
    ("params", "words"),
    [
        ({"channel": "uptime_s", "start": "yesterday"},
         ["start: 'yesterday' is not a time", "ISO 8601", "-10m"]),
        ({"channel": "uptime_s", "start": "-1h", "end": "-2h"},
         ["start (-1h = ", "is not before end (-2h = "]),
        ({"channel": ["uptime_s", "cpu_load"]},
         ["'cpu_load' is not a telemetry channel", "fpga_temp_degc"]),
        ({"channel": "uptime_s", "start": "-1000d", "bucket_s": 1},
         ["buckets", "more than the 100000", "set bucket_s to at least 2000"]),
        ({"channel": "uptime_s", "bucket_s": 0}, ["bucket_s: 0 is not a width"]),
        ({"channel": "uptime_s", "source": "radio"}, ["source: 'radio'", "tlm", "poll"]),
        ({"channel": "uptime_s", "format": "xml"}, ["format: 'xml'", "json or csv"]),
    ],
)  # fmt: skip
def test_history_refuses_bad_queries_saying_what_to_change(
    daemon: Daemon, params: dict[str, Any], words: list[str]
) -> None:
    message = error_of(daemon.get(f"{API}/telemetry/history", params=params), 400, "bad_request")
    for word in words:
        assert word in message, message


def test_events_filtered_by_range_level_and_source(daemon: Daemon) -> None:
    every = daemon.get(f"{API}/events", params={"limit": 1000}).json()["events"]
    assert len(every) >= 2
    cut = every[len(every) // 2]["t_s"]
    later = daemon.get(
        f"{API}/events", params={"limit": 1000, "start": repr(cut), "end": repr(every[-1]["t_s"])}
    ).json()["events"]
    assert later == [e for e in every if cut <= e["t_s"] < every[-1]["t_s"]]
    # Up to the newest event seen (exclusive), so that events arriving meanwhile stay out.
    kinds = {"level": ["info", "warning"], "source": "daemon,link", "end": repr(every[-1]["t_s"])}
    chosen = daemon.get(f"{API}/events", params={"limit": 1000, **kinds}).json()["events"]
    assert chosen == [
        e
        for e in every[:-1]
        if e["level"] in ("info", "warning") and e["source"] in ("daemon", "link")
    ]
    assert chosen  # the link opened, the daemon started
    message = error_of(daemon.get(f"{API}/events", params={"level": "loud"}), 400, "bad_request")
    assert "level: 'loud' is not an event level; use info, warning, error" in message
