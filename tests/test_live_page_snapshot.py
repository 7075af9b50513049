"""Snapshots of the live view and each viewer's transport (docs/live-view.md, "Snapshots" and
"Transport"): the API, `camctl snapshot`, the WebSocket's binning, rate and compression, and the
page's buttons, over one daemon on the simulated hr400 (token, 64-row window).

What could be wrong is checked against what the daemon serves elsewhere: the snapshot TIFF read
back with tifffile is, pixel for pixel, the frame ``GET /api/v1/live/frame`` gives (the same seq,
which the snapshot says); its metadata holds that frame's description, the registers the test
wrote, the daemon's version and the ROIs defined; the CSV parses to the statistics of
``GET /api/v1/live/roi/stats``. Before any frame the endpoints answer 404 saying what to do; a
snapshot of a seq the live view no longer holds is a 409. A binned frame is the block mean of
the raw frame of the same seq, computed here; a deflated one inflates to the same bytes; a
viewer's rate limit holds over seconds; bad settings are refused saying what to use.
"""

from __future__ import annotations

import csv
import io
import json
import math
import time
import zlib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
import tifffile
from websockets.sync.client import ClientConnection, connect

import camd
from camd.cli.camctl import main as camctl_main
from camd.pipeline.live import RECENT_BYTES_MAX, RECENT_FRAMES, LiveTap
from camd.pipeline.live_transport import block_mean
from camd.web import STATIC_DIR
from tests.browser import PageLog
from tests.test_live_page import TESTER, TOKEN, Bench, open_live, shot, wait_for
from tests.test_live_page import bench as bench  # the module's daemon (module-scoped fixture)
from tests.test_live_view import received

# Not ``exclusive``: every check compares bytes and values, whenever they come.

ROI = {"name": "dark", "x": 8, "y": 4, "width": 16, "height": 8}


def test_the_tap_holds_its_newest_frames_by_seq_within_a_memory_bound() -> None:
    # In process, a stepped clock: small frames, RECENT_FRAMES held; 534 x 2048 frames, as many
    # as fit in RECENT_BYTES_MAX (30); 4096 x 4096 frames (32 MiB), two.
    now = [0.0]
    tap = LiveTap(clock=lambda: now[0])
    fed = RECENT_FRAMES + 3
    for rows, cols, held in ((4, 6, RECENT_FRAMES), (534, 2048, 30), (4096, 4096, 2)):
        for i in range(fed):
            now[0] += 1.0
            tap(received(i, np.full((rows, cols), i, dtype=np.uint16)))
        newest = tap.kept
        assert tap.held() == (newest - held + 1, newest)
        assert tap.frame(newest - held) is None
        frame = tap.frame(newest - held + 1)
        assert frame is not None and int(frame.pixels[0, 0]) == fed - held
    assert sum(f.pixels.nbytes for f in tap._recent) <= RECENT_BYTES_MAX


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


def test_the_display_png_is_the_frame_through_the_contrast_and_colour_map(
    http: httpx.Client,
) -> None:
    import cv2

    meta, pixels = newest_frame(http)
    lut = np.array(json.loads((STATIC_DIR / "live" / "colormaps.json").read_text())["viridis"])
    params = {"seq": meta["seq"], "lo": 100, "hi": 3000, "colormap": "viridis"}
    answer = http.get("/api/v1/live/snapshot/display.png", params=params)
    assert answer.status_code == 200 and answer.headers["content-type"] == "image/png"
    assert f'filename="camd-snapshot-{meta["seq"]}.png"' in answer.headers["content-disposition"]
    image = cv2.imdecode(np.frombuffer(answer.content, np.uint8), cv2.IMREAD_COLOR)[:, :, ::-1]
    # The page's mapping: DN lo..hi onto the map's 256 entries, clipped at both ends.
    index = np.clip(np.rint((pixels - 100.0) * 255 / 2900), 0, 255).astype(int)
    assert image.shape == (*pixels.shape, 3) and np.array_equal(image, lut[index])
    # Default: grey, percentiles 0.1 .. 99.9 % (the page's default); the dark end is black.
    grey = http.get("/api/v1/live/snapshot/display.png", params={"seq": meta["seq"]})
    decoded = cv2.imdecode(np.frombuffer(grey.content, np.uint8), cv2.IMREAD_COLOR)
    assert decoded[pixels == pixels.min()].max() == 0 and decoded.max() == 255
    for bad, message in (
        (
            {"colormap": "jet"},
            "colormap 'jet' is not offered: use gray, viridis, inferno, cividis, turbo",
        ),
        ({"lo": 10, "hi": 10}, "lo (10) must be below hi (10): the DN shown black and white"),
        ({"lo": 10}, "give lo and hi together (the DN shown black and white), or neither"),
    ):
        refused = http.get("/api/v1/live/snapshot/display.png", params={"seq": meta["seq"], **bad})
        assert refused.status_code == 400 and refused.json()["error"] == message


def test_a_snapshot_of_a_seq_no_longer_held_is_refused(http: httpx.Client) -> None:
    meta, _ = newest_frame(http)
    for path in ("/api/v1/live/snapshot/frame.tiff", "/api/v1/live/snapshot/roi.csv"):
        for seq in (meta["seq"] + 1, meta["seq"] + 1000):
            answer = http.get(path, params={"seq": seq})
            assert answer.status_code == 409 and answer.json()["code"] == "frame_gone"
            assert "the live view holds seq " in answer.json()["error"]
            assert (
                f"..{meta['seq']}, not {seq}: it keeps its newest {RECENT_FRAMES} frames only"
                in (answer.json()["error"])
            )
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
    # With --png: the frame as displayed too, the daemon's rendering of the same frame.
    again = tmp_path / "again"
    argv = ["--url", bench.url, "--token", TOKEN, "--json", "snapshot", str(again), "--png",
            "--colormap", "inferno"]  # fmt: skip
    assert camctl_main(argv) == 0
    files = [Path(f) for f in json.loads(capsys.readouterr().out)["files"]]
    assert [f.suffix for f in files] == [".tiff", ".png", ".csv"]
    params = {"seq": meta["seq"], "colormap": "inferno"}
    assert (
        files[1].read_bytes()
        == http.get("/api/v1/live/snapshot/display.png", params=params).content
    )


def test_a_snapshot_saved_on_the_daemon_goes_into_its_data_dirs_snapshots(
    bench: Bench, http: httpx.Client
) -> None:
    meta, pixels = newest_frame(http)
    folder = bench.data_dir / "snapshots"

    def post(body: dict[str, Any], client: str = TESTER) -> httpx.Response:
        return http.post("/api/v1/live/snapshot", json=body, headers={"X-Camd-Client": client})

    with bench.client() as client:
        client.take_control(force=True)
        try:
            # Saving writes the daemon's disk: another client's is refused; refused, bad or of
            # a frame gone, nothing is written.
            other = post({}, client="someone-else")
            assert other.status_code == 423 and other.json()["code"] == "not_in_control"
            bad = post({"seq": "1"})
            assert bad.status_code == 400 and "seq" in bad.json()["error"]
            gone = post({"seq": meta["seq"] + 1000})
            assert gone.status_code == 409 and gone.json()["code"] == "frame_gone"
            assert not folder.exists() or list(folder.iterdir()) == []
            saved = client.save_snapshot(meta["seq"])
        finally:
            client.release_control()
    assert saved["seq"] == meta["seq"] and saved["counter"] == meta["counter"]
    tiff, table = (Path(f) for f in saved["files"])
    assert tiff.parent == table.parent == folder
    assert tiff.name.endswith(f"-seq{meta['seq']}.tiff") and table.suffix == ".csv"
    assert np.array_equal(tifffile.imread(tiff), pixels)
    assert [r["roi"] for r in csv.DictReader(table.open())] == ["dark"]
    assert sorted(folder.iterdir()) == sorted([tiff, table])


# -- each viewer's transport: binning, rate, compression --------------------------------------


def ws(bench: Bench, query: str = "") -> ClientConnection:
    url = bench.url.replace("http://", "ws://") + f"/api/v1/live/ws?token={TOKEN}"
    return connect(url + (f"&{query}" if query else ""), open_timeout=30, max_size=2**24)


def next_frame(socket: ClientConnection) -> tuple[dict[str, Any], bytes]:
    """The next frame's description and payload (settings answers skipped)."""
    while True:
        text = socket.recv(timeout=30)
        assert isinstance(text, str)
        meta = json.loads(text)
        if "seq" in meta:
            payload = socket.recv(timeout=30)
            assert isinstance(payload, bytes)
            return meta, payload


def block_means(pixels: np.ndarray, b: int) -> np.ndarray:
    """Each b x b block's mean rounded to the nearest DN (half to even), partial blocks
    dropped: computed here pixel block by pixel block, not with the daemon's code."""
    rows, cols = pixels.shape[0] // b, pixels.shape[1] // b
    out = np.empty((rows, cols), dtype=np.uint16)
    for r in range(rows):
        strip = pixels[r * b : (r + 1) * b].astype(np.int64)
        sums = np.add.reduceat(strip.sum(axis=0)[: cols * b], np.arange(0, cols * b, b))
        out[r] = np.rint(sums / (b * b))
    return out


def test_block_means_drop_the_rows_and_columns_past_the_last_whole_block() -> None:
    # In process: hr400's 534 rows and an odd width, full-scale pixels (the sums' range).
    rng = np.random.default_rng(34)
    pixels = rng.integers(0, 65536, size=(534, 2051), dtype=np.uint16)
    pixels[:8, :8] = 65535
    for b in (1, 2, 4, 8):
        sent = block_mean(pixels, b)
        assert sent.shape == (534 // b, 2051 // b) and sent.dtype == np.uint16
        assert np.array_equal(sent, block_means(pixels, b)), b
    assert block_mean(pixels, 8)[0, 0] == 65535


def test_binned_and_deflated_frames_are_the_block_means_of_the_raw_frame(
    bench: Bench, http: httpx.Client
) -> None:
    # A real scene (noise: block means that could be wrong), the stream over: every viewer
    # gets the newest frame first, the frame /live/frame gives.
    with bench.client() as client:
        client.take_control(force=True)
        client.write_registers({"TEST_PATTERN.mode": "off"})
        client.acquire(30, mode="area")
        client.release_control()
    meta, pixels = newest_frame(http)
    assert pixels.std() > 1.0
    sizes = {}
    for b in (1, 2, 4, 8):
        expected = block_means(pixels, b)
        for compression in ("none", "deflate"):
            with ws(bench, f"bin={b}&compression={compression}") as socket:
                got, payload = next_frame(socket)
            assert got["seq"] == meta["seq"] and got["counter"] == meta["counter"]
            assert (got["bin"], got["compression"], got["max_fps"]) == (b, compression, 20.0)
            assert (got["frame_rows"], got["frame_cols"]) == (64, meta["cols"])
            assert (got["rows"], got["cols"]) == expected.shape == (64 // b, meta["cols"] // b)
            assert got["bytes"] == len(payload)
            # Block means hide clipped pixels: a binned frame's description counts them.
            clipped = {"saturated": int((pixels >= 4095).sum()), "zero": int((pixels == 0).sum())}
            assert {k: got.get(k) for k in clipped} == (
                clipped if b > 1 else dict.fromkeys(clipped)
            )
            raw = zlib.decompress(payload) if compression == "deflate" else payload
            sent = np.frombuffer(raw, "<u2").reshape(got["rows"], got["cols"])
            assert np.array_equal(sent, expected), (b, compression)
            sizes[b, compression] = len(payload)
    assert sizes[1, "none"] == 64 * meta["cols"] * 2
    assert sizes[1, "deflate"] < sizes[1, "none"] and sizes[8, "none"] == sizes[1, "none"] // 64

    # A binned viewer's readout: the raw DN of any pixel of that frame.
    for row, col in ((0, 0), (63, meta["cols"] - 1), (17, 1001)):
        with bench.client() as client:
            answer = client.live_pixel(row, col, meta["seq"])
        assert answer == {
            "seq": meta["seq"], "counter": meta["counter"], "row": row, "col": col,
            "raw_dn": int(pixels[row, col]),
        }  # fmt: skip
    outside = http.get("/api/v1/live/pixel", params={"row": 64, "col": 0})
    assert outside.status_code == 400 and outside.json()["error"] == (
        f"pixel (row 64, col 0) is outside the 64 x {meta['cols']} frame of seq {meta['seq']}: "
        f"rows 0..63, columns 0..{meta['cols'] - 1}"
    )


def test_bad_transport_settings_are_refused_saying_what_to_use(bench: Bench) -> None:
    cases = {
        "bin=3": "bin='3' is not a binning: use 1, 2, 4, 8 (each bin x bin block sent as its mean)",
        "max_fps=0": "max_fps='0' is not a rate: use a number of frames a second above 0 and at "
        "most 20 (what the live view keeps)",
        "compression=gzip": "compression='gzip' is not offered: use none or deflate",
        "binning=2": "unknown transport setting 'binning': the settings are bin, max_fps, "
        "compression",
    }
    for query, message in cases.items():
        with ws(bench, query) as socket:
            assert json.loads(socket.recv(timeout=30)) == {"error": message, "code": "bad_request"}
            with pytest.raises(Exception, match="1008"):
                socket.recv(timeout=30)
    # In a message: refused, the settings kept; a good one answered with the new settings.
    with ws(bench, "bin=2") as socket:
        next_frame(socket)
        socket.send(json.dumps({"bin": 5}))
        socket.send(json.dumps({"compression": "deflate", "max_fps": 4}))
        answers = []
        while len(answers) < 2:
            doc = json.loads(socket.recv(timeout=30))
            if "seq" in doc:
                socket.recv(timeout=30)
            else:
                answers.append(doc)
    assert answers == [
        {"error": "settings unchanged: bin='5' is not a binning: use 1, 2, 4, 8 (each bin x bin "
         "block sent as its mean)", "code": "bad_request"},
        {"transport": {"bin": 2, "max_fps": 4.0, "compression": "deflate"}},
    ]  # fmt: skip
    # A message longer than api.max_body_bytes (65536) closes the viewer's socket unread (1009).
    with ws(bench) as socket:
        next_frame(socket)
        socket.send(json.dumps({"bin": 2, "padding": "x" * 70_000}))
        with pytest.raises(Exception, match="1009"):
            while True:
                socket.recv(timeout=30)


def test_a_viewers_rate_limit_holds(bench: Bench) -> None:
    # 2 frames a second at most, counted over about 6 s of a stream the live view keeps 20 of.
    with bench.client() as client:
        client.take_control(force=True)
        client.start_stream(0, mode="area")
        try:
            with ws(bench, "max_fps=2") as limited:
                first, _ = next_frame(limited)
                start = time.monotonic()
                seqs = [first["seq"]]
                while time.monotonic() - start < 6.0:
                    seqs.append(next_frame(limited)[0]["seq"])
                elapsed_s = time.monotonic() - start
        finally:
            client.stop_stream()
            client.release_control()
    # n frames after the first need (n - 1) / 2 s at least: the bound, with one frame to spare.
    assert len(seqs) - 1 <= 2 * elapsed_s + 1, (len(seqs), elapsed_s)
    assert len(seqs) >= 3 and seqs == sorted(set(seqs))
    # Meanwhile the tap kept more frames than the viewer got: it was sent the newest each time.
    assert seqs[-1] - seqs[0] > len(seqs)


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


def test_the_page_binned_and_deflated_reads_raw_dn_under_the_cursor(
    bench: Bench, page: tuple[Any, PageLog]
) -> None:
    live, log = page
    with bench.client() as client:
        client.take_control(force=True)
        client.write_registers({"TEST_PATTERN.mode": "ramp"})
        client.start_stream(0, mode="area")
        try:
            # The address names the binning (a bookmark); the bar then changes the compression.
            open_live(live, log, bench, "binned-viewer&bin=4")
            wait_for("a frame", lambda: live.evaluate("window.camdLive.framesShown") >= 1)
            assert live.input_value("#tx-bin") == "4"
            live.select_option("#tx-compression", "deflate")
            wait_for(
                "a binned, deflated frame on show",
                lambda: (
                    live.evaluate(
                        "[window.camdLive.view.frame?.meta.bin, window.camdLive.view.frame?.meta"
                        ".compression]"
                    )
                    == [4, "deflate"]
                ),
            )
            shown = live.evaluate("window.camdLive.framesShown")
            wait_for(
                "more inflated frames",
                lambda: live.evaluate("window.camdLive.framesShown") > shown + 3,
            )
            note = live.inner_text("#transport-note")
            assert (
                "display binned 4x4 (block means of the 64x2048 frame; the readout is raw)" in note
            )
            assert "deflate" in note
            assert live.evaluate("window.camdLive.view.frame.rows") == 16
            live.select_option("#zoom", "4")  # one screen pixel: one raw pixel
            live.dispatch_event("#zoom", "change")
            box = live.locator("#image").bounding_box()
            left = int(live.input_value("#origin-col"))  # in the binned frame's columns
            for row, col in ((0, 4 * left), (5, 4 * left + 7), (62, 4 * left + 130)):
                x = math.ceil(box["x"] + col - 4 * left)
                y = math.ceil(box["y"] + row)
                live.mouse.move(x, y)
                expected = str((row + col) % 4096)
                wait_for(
                    f"the raw DN of ({row}, {col})",
                    lambda expected=expected: live.inner_text("#px-raw") == expected,
                )
                assert (live.inner_text("#px-row"), live.inner_text("#px-col")) == (
                    str(row),
                    str(col),
                )
            # ROIs (the tool, the outlines) are in the camera frame's pixels too: at 4x a binned
            # pixel is 4 screen pixels and 4 frame pixels, so frame pixel (8, 4 left + 16) is at
            # screen (16, 8 - 4 top) and back; the ROI tool's bounds are the frame's 64 x 2048.
            top = int(live.input_value("#origin-row"))
            mapped = live.evaluate(
                "(([row, col]) => { const v = window.camdLive.view; const a = v.imageToCanvas(row,"
                " col); const b = v.canvasToImage(a.x, a.y); const s = v.imageSize;"
                " return [a.x, a.y, b.row, b.col, s.rows, s.cols]; })",
                [8, 4 * left + 16],
            )
            assert mapped == [16, 8 - 4 * top, 8, 4 * left + 16, 64, 2048]
            # Below 1x too: at 1/2x one screen pixel is 2 x 2 binned pixels, 8 x 8 of the frame;
            # the readout still names the frame's pixel and its raw DN.
            live.select_option("#zoom", "0.5")
            live.dispatch_event("#zoom", "change")
            for x, y in ((3, 1), (40, 5), (150, 7)):
                live.mouse.move(math.ceil(box["x"]) + x, math.ceil(box["y"]) + y)

                def readout_of_the_ramp() -> bool:
                    row, col, raw = (live.inner_text(f"#px-{k}") for k in ("row", "col", "raw"))
                    return row.isdigit() and col.isdigit() and raw == str(int(row) + int(col))

                wait_for(f"the raw DN at 1/2x under ({x}, {y})", readout_of_the_ramp)
                assert (
                    int(live.inner_text("#px-col")) // 8
                    == x + int(live.input_value("#origin-col")) // 2
                )
            # Block means hide clipped pixels: the counts are the daemon's on the frame. The
            # ramp has one 0 (row 0, column 0; its block's mean is 3) and no 4095 (at most 2110).
            assert live.evaluate("window.camdLive.view.frame.meta.zero") == 1
            assert live.evaluate(
                "[window.camdLive.view.clip.saturated, window.camdLive.view.clip.zero]"
            ) == [0, 1]
            shot(live, "transport-binned")
        finally:
            client.stop_stream()
            client.write_registers({"TEST_PATTERN.mode": "off"})
            client.release_control()
    # A readout asked of a frame that has left the live view (a loaded machine) is answered 409
    # and the browser notes it; the page then asks of the next frame (the values above).
    assert [e for e in log.errors if "status of 409" not in e] == []
    assert log.off_loopback() == []


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
