"""Snapshots of the live view (docs/live-view.md, "Snapshots"): the API, `camctl snapshot` and
the page's buttons, over one daemon on the simulated hr400 (token, 64-row window).

What could be wrong is checked against what the daemon serves elsewhere: the snapshot TIFF read
back with tifffile is, pixel for pixel, the frame ``GET /api/v1/live/frame`` gives (the same seq,
which the snapshot says); its metadata holds that frame's description, the registers the test
wrote, the daemon's version and the ROIs defined; the CSV parses to the statistics of
``GET /api/v1/live/roi/stats``. Before any frame the endpoints answer 404 saying what to do; a
snapshot of a seq the live view no longer holds is a 409.
"""

from __future__ import annotations

import csv
import io
import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
import tifffile

import camd
from camd.cli.camctl import main as camctl_main
from tests.browser import PageLog
from tests.test_live_page import TOKEN, Bench, open_live, shot, wait_for
from tests.test_live_page import bench as bench  # the module's daemon (module-scoped fixture)

# Not ``exclusive``: every check compares bytes and values, whenever they come.

ROI = {"name": "dark", "x": 8, "y": 4, "width": 16, "height": 8}


@pytest.fixture
def http(bench: Bench) -> Iterator[httpx.Client]:
    with httpx.Client(
        base_url=bench.url, timeout=60, headers={"Authorization": f"Bearer {TOKEN}"}
    ) as client:
        yield client


def newest_frame(http: httpx.Client) -> tuple[dict[str, Any], np.ndarray]:
    answer = http.get("/api/v1/live/frame")
    assert answer.status_code == 200, answer.text
    meta = json.loads(answer.headers["X-Camd-Frame"])
    return meta, np.frombuffer(answer.content, "<u2").reshape(meta["rows"], meta["cols"])


def test_before_any_frame_the_snapshots_say_what_to_do(http: httpx.Client) -> None:
    # First in the module: the daemon has streamed nothing yet.
    tiff = http.get("/api/v1/live/snapshot/frame.tiff")
    assert tiff.status_code == 404 and tiff.json()["code"] == "no_frame"
    assert "start a stream (`camctl stream --frames 100`)" in tiff.json()["error"]
    table = http.get("/api/v1/live/snapshot/roi.csv")
    assert table.status_code == 404 and table.json()["code"] == "no_frame"


def stream_with_roi(bench: Bench) -> None:
    """An ROI, then the ramp test pattern streamed until both the live view and the ROI have
    a few frames; the stream stopped, the live view's frame stays."""
    with bench.client() as client:
        client.take_control(force=True)
        client.add_roi(**ROI)
        client.write_registers({"TEST_PATTERN.mode": "ramp"})
        client.start_stream(0, mode="area")
        wait_for("frames measured", lambda: client.roi_stats()["measured"] >= 5)
        client.stop_stream()
        client.release_control()


def test_the_snapshot_tiff_is_the_served_frame_with_its_settings_and_the_csv_its_stats(
    bench: Bench, http: httpx.Client
) -> None:
    stream_with_roi(bench)
    meta, pixels = newest_frame(http)
    answer = http.get("/api/v1/live/snapshot/frame.tiff", params={"seq": meta["seq"]})
    assert answer.status_code == 200, answer.text
    assert answer.headers["content-type"] == "image/tiff"
    assert f'filename="camd-snapshot-{meta["seq"]}.tiff"' in answer.headers["content-disposition"]
    assert json.loads(answer.headers["X-Camd-Frame"]) == meta
    with tifffile.TiffFile(io.BytesIO(answer.content)) as tif:
        image = tif.asarray()
        described = json.loads(tif.pages[0].description)
    assert image.dtype == np.uint16 and np.array_equal(image, pixels)
    assert described["frame"] == meta
    assert described["daemon"]["version"] == camd.__version__
    assert described["registers"]["WIN_ROWS"] == 64
    assert described["registers"]["TEST_PATTERN"] & 0b11 == 2  # mode: ramp
    assert described["profile"]["sensor"] == "hr400"
    assert described["timing"]["window_rows"] == 64 and described["timing"]["exposure_s"] > 0
    assert described["status"]["state"] == "idle"
    assert described["rois"] == [ROI]

    # The statistics of this very frame, as the ROI history gives them (every frame measured).
    history = http.get("/api/v1/live/roi/stats", params={"history": 4096}).json()["history"]
    dark = history["dark"]
    at = dark["counter"].index(meta["counter"])
    stats = {k: v[at] for k, v in dark.items() if k != "counter"}
    assert described["roi_stats"] == {"dark": stats}
    table = http.get("/api/v1/live/snapshot/roi.csv", params={"seq": meta["seq"]})
    assert table.status_code == 200 and table.headers["content-type"].startswith("text/csv")
    rows = list(csv.DictReader(io.StringIO(table.text)))
    assert [r["roi"] for r in rows] == ["dark"]
    row = rows[0]
    assert int(row["counter"]) == meta["counter"]
    assert int(row["timestamp_ns"]) == meta["timestamp_ns"]
    assert [int(row[k]) for k in ("x", "y", "width", "height")] == [8, 4, 16, 8]
    for key, value in stats.items():
        assert (row[key] == "") if value is None else float(row[key]) == value
    # The ramp, (row + col) mod 4096: rows 4..11, columns 8..23 -> 12..34, mean 23.
    assert float(row["mean_dn"]) == 23.0 and float(row["min_dn"]) == 12.0


def test_a_snapshot_of_a_seq_no_longer_held_is_refused(http: httpx.Client) -> None:
    meta, _ = newest_frame(http)
    for path in ("/api/v1/live/snapshot/frame.tiff", "/api/v1/live/snapshot/roi.csv"):
        for seq in {max(1, meta["seq"] - 1), meta["seq"] + 1} - {meta["seq"]}:
            answer = http.get(path, params={"seq": seq})
            assert answer.status_code == 409 and answer.json()["code"] == "frame_gone"
            assert f"the live view holds seq {meta['seq']}, not {seq}" in answer.json()["error"]
        bad = http.get(path, params={"seq": 0})
        assert bad.status_code == 400 and "seq" in bad.json()["error"]


def test_camctl_snapshot_writes_the_tiff_and_csv_in_the_directory_named(
    bench: Bench, http: httpx.Client, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    meta, pixels = newest_frame(http)
    out = tmp_path / "snaps"
    argv = ["--url", bench.url, "--token", TOKEN, "--json", "snapshot", str(out)]
    assert camctl_main(argv) == 0
    doc = json.loads(capsys.readouterr().out)
    tiff, table = (
        out / f"camd-snapshot-{meta['seq']}.tiff",
        out / f"camd-snapshot-{meta['seq']}.csv",
    )
    assert doc == {"seq": meta["seq"], "counter": meta["counter"], "files": [str(tiff), str(table)]}
    assert np.array_equal(tifffile.imread(tiff), pixels)
    assert [r["roi"] for r in csv.DictReader(table.open())] == ["dark"]
    # Never overwritten: a second snapshot of the same frame is refused, the files untouched.
    before = tiff.stat().st_mtime_ns
    assert camctl_main(argv) == 2
    assert f"{tiff}, {table} already exists: name another directory" in capsys.readouterr().err
    assert tiff.stat().st_mtime_ns == before


def test_the_page_downloads_the_tiff_the_png_and_the_csv(
    bench: Bench, http: httpx.Client, page: tuple[Any, PageLog], tmp_path: Path
) -> None:
    meta, pixels = newest_frame(http)
    live, log = page
    open_live(live, log, bench, "snapshot-page")
    wait_for("the frame on the page", lambda: live.evaluate("window.camdLive.lastMeta?.seq"))
    shot(live, "snapshot")
    saved = {}
    for button in ("snapshot-tiff", "snapshot-png", "snapshot-csv"):
        with live.expect_download(timeout=60_000) as download:
            live.click(f"#{button}")
        path = tmp_path / download.value.suggested_filename
        download.value.save_as(path)
        saved[button] = path
    assert saved["snapshot-tiff"].name == f"camd-snapshot-{meta['seq']}.tiff"
    assert np.array_equal(tifffile.imread(saved["snapshot-tiff"]), pixels)
    png = saved["snapshot-png"]
    assert png.name == f"camd-snapshot-{meta['seq']}.png"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert [r["roi"] for r in csv.DictReader(saved["snapshot-csv"].open())] == ["dark"]
    assert log.errors == [] and log.off_loopback() == []


def test_the_csv_of_a_frame_measured_by_no_roi_says_what_to_do(
    bench: Bench, http: httpx.Client
) -> None:
    # Last in the module: the ROI goes; the live view's frame stays, but nothing measured it.
    with bench.client() as client:
        client.take_control(force=True)
        client.delete_roi(ROI["name"])
        client.release_control()
    meta, _ = newest_frame(http)
    table = http.get("/api/v1/live/snapshot/roi.csv")
    assert table.status_code == 404 and table.json()["code"] == "no_roi_stats"
    assert f"no ROI statistics of the live frame (seq {meta['seq']})" in table.json()["error"]
    assert "POST /api/v1/live/roi" in table.json()["error"]
    # The TIFF is still there, saying its frame has no statistics.
    tiff = http.get("/api/v1/live/snapshot/frame.tiff")
    with tifffile.TiffFile(io.BytesIO(tiff.content)) as tif:
        assert json.loads(tif.pages[0].description)["roi_stats"] is None
