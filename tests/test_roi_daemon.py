"""ROI statistics over a real daemon (simulated camera, HTTP on loopback, a real HDF5 file).

Over a 2,000-frame stare of 2 x 2048 frames (small: the test runs in seconds), the daemon's
per-frame statistics of four ROIs are those computed from the recorded frames: every frame,
matched by frame counter, none skipped (the monitor is not decimated like the live view).
The recording's ``/roi`` group holds the same statistics of the same frames. Bad ROIs are refused with what to change and change nothing; ``camctl roi`` adds, lists,
removes and reads them.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path

import h5py
import httpx
import numpy as np
import pytest

from camd.client import CamdClient, CamdError
from tests.test_camctl import camctl, camctl_command, camctl_json
from tests.test_trust import small_window_daemon

# Not ``exclusive``: the checks are values per frame counter (whatever a busy machine delays,
# the same frames are measured and recorded) and refusals.

API = "/api/v1"
FRAMES = 2000
ROWS = 2  # the window: 2 x 2048 frames, 8 kB each
ROIS = {
    "edge": (0, 0, 16, 2),
    "bar": (100, 0, 200, 1),
    "right": (2000, 1, 48, 1),
    "pixel": (1000, 0, 1, 1),
}


@pytest.fixture(scope="module")
def url(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    with small_window_daemon(tmp_path_factory.mktemp("camd-roi")) as url:
        with CamdClient(url) as client:
            client.write_registers({"WIN_ROWS": ROWS})
        yield url


def _clear(client: CamdClient) -> None:
    for roi in client.rois()["rois"]:
        client.delete_roi(roi["name"])


def test_every_frames_roi_statistics_equal_the_recorded_frames(url: str, tmp_path: Path) -> None:
    path = tmp_path / "stare.h5"
    with CamdClient(url, timeout_s=120) as client:
        _clear(client)
        for name, (x, y, w, h) in ROIS.items():
            client.add_roi(name, x, y, w, h)
        done = client.acquire(FRAMES, mode="area", record=str(path), timeout_s=120)
        stats = client.roi_stats(history=4096)
    assert done["stats"]["frames"] == FRAMES
    with h5py.File(path, "r") as f:
        counters = np.asarray(f["frame_counter"]).astype(np.int64)
        frames = np.asarray(f["frames"])
        bits = int(done["bits"])
        stored = {name: {k: np.asarray(v) for k, v in f["roi"][name].items()} for name in ROIS}
        stored_counters = np.asarray(f["roi/frame_counter"])
        stored_attrs = dict(f["roi"].attrs)
        rects = {name: dict(f["roi"][name].attrs) for name in ROIS}
    assert frames.shape == (FRAMES, ROWS, 2048)
    assert stats["measured"] == FRAMES and stats["unfit"] == 0
    assert set(stats["history"]) == set(ROIS)
    for name, (x, y, w, h) in ROIS.items():
        series = stats["history"][name]
        assert series["counter"] == counters.tolist(), name  # the same frames, every one
        sub = frames[:, y : y + h, x : x + w]
        sums = sub.sum(axis=(1, 2), dtype=np.int64)
        assert series["mean_dn"] == (sums / (w * h)).tolist(), name
        assert series["sum_dn"] == sums.astype(np.float64).tolist(), name
        assert series["min_dn"] == sub.min(axis=(1, 2)).astype(np.float64).tolist(), name
        assert series["max_dn"] == sub.max(axis=(1, 2)).astype(np.float64).tolist(), name
        saturated = np.count_nonzero(sub >= (1 << bits) - 1, axis=(1, 2))
        assert series["saturated"] == saturated.astype(np.float64).tolist(), name
        np.testing.assert_allclose(series["std_dn"], sub.std(axis=(1, 2)), rtol=1e-9)
    # The recording's /roi group: the same statistics of the same frames.
    assert stored_counters.tolist() == counters.tolist()
    assert (stored_attrs["frames"], stored_attrs["frames_dropped"]) == (FRAMES, 0)
    assert stored_attrs["rois_changed_at"] == -1
    for name, (x, y, w, h) in ROIS.items():
        assert rects[name] == {"x": x, "y": y, "width": w, "height": h}
        for field, values in stored[name].items():
            as_json = [None if v != v else v for v in values.tolist()]  # NaN: JSON's null
            assert as_json == stats["history"][name][field], (name, field)
    latest = stats["latest"]
    assert latest is not None and latest["counter"] == int(counters[-1])
    assert latest["rois"]["pixel"]["std_dn"] == 0.0 and latest["rois"]["pixel"]["snr"] is None


def test_bad_rois_are_refused_with_what_to_change_and_change_nothing(url: str) -> None:
    with CamdClient(url, timeout_s=60) as client, httpx.Client(base_url=url, timeout=30) as http:
        _clear(client)
        client.acquire(2, mode="area")  # the geometry the ROIs are checked against: 2 x 2048
        before = client.add_roi("keep", 0, 0, 8, 2)
        assert (before["rows"], before["cols"]) == (ROWS, 2048)
        bad = {
            "outside": (
                {"name": "wide", "x": 2040, "y": 0, "width": 10, "height": 1},
                "ROI 'wide' (x=2040, y=0, 10 x 1) reaches column 2049, row 0, outside the "
                "2048 x 2 frame (columns 0..2047, rows 0..1): make it smaller or move it",
            ),
            "empty": (
                {"name": "flat", "x": 0, "y": 0, "width": 0, "height": 1},
                "ROI 'flat' is 0 x 1 pixels: width and height must be at least 1",
            ),
            "name": (
                {"name": "a/b", "x": 0, "y": 0, "width": 1, "height": 1},
                "ROI name 'a/b' is not valid: use 1-32 letters, digits, '_', '.' or '-'",
            ),
        }
        for what, (body, message) in bad.items():
            answer = http.post(f"{API}/live/roi", json=body)
            assert answer.status_code == 400, (what, answer.text)
            assert answer.json() == {"error": message, "code": "bad_request"}, what
            assert client.rois() == before, what
        for body in ({"name": "x", "x": "left", "y": 0, "width": 1, "height": 1}, {"name": "y"}):
            answer = http.post(f"{API}/live/roi", json=body)
            assert answer.status_code == 400 and answer.json()["code"] == "bad_request", body
            assert client.rois() == before
        answer = http.get(f"{API}/live/roi/stats", params={"history": 4097})
        assert answer.status_code == 400, answer.text
        assert answer.json()["error"].startswith(
            "history: 4097 is out of range; use an integer in 0..4096"
        )
        with pytest.raises(CamdError) as info:
            client.delete_roi("nothere")
        assert (info.value.http_status, info.value.code) == (404, "not_found")
        assert info.value.message == "no ROI named 'nothere'; the ROIs are: keep"
        assert client.rois() == before
        client.delete_roi("keep")


def test_camctl_roi_add_list_stats_rm(url: str) -> None:
    with CamdClient(url, timeout_s=60) as client:
        _clear(client)
    camctl_json(url, "roi", "add", "spot", "0", "0", "1", "1")
    camctl_json(url, "roi", "add", "other", "5", "1", "2", "1")
    # The same name again replaces the ROI, in its place.
    added = camctl_json(url, "roi", "add", "spot", "10", "0", "4", "2")
    assert added["rois"] == [
        {"name": "spot", "x": 10, "y": 0, "width": 4, "height": 2},
        {"name": "other", "x": 5, "y": 1, "width": 2, "height": 1},
    ]
    assert camctl_json(url, "roi", "rm", "other")["rois"] == added["rois"][:1]
    with CamdClient(url, timeout_s=60) as client:
        client.acquire(5, mode="area")
    stats = camctl_json(url, "roi", "stats", "--history", "3")
    assert stats["measured"] == 5 and len(stats["history"]["spot"]["counter"]) == 3
    shown = camctl(url, "roi", "stats")
    assert shown.returncode == 0, shown.stderr
    assert "5 frames measured" in shown.stdout and "spot: mean" in shown.stdout
    listed = camctl_command(url, "roi", "list")  # the installed command, once
    assert listed.returncode == 0, listed.stderr
    assert "1 ROI (checked against: 2048 x 2 frame)" in listed.stdout
    assert "spot: x=10 y=0 4 x 2" in listed.stdout
    refused = camctl(url, "roi", "add", "big", "0", "0", "4096", "1")
    assert refused.returncode == 1
    assert "outside the 2048 x 2 frame" in refused.stderr
    assert camctl_json(url, "roi", "rm", "spot")["rois"] == []


def test_the_background_subtracted_mean_uses_the_daemons_background(url: str) -> None:
    with CamdClient(url, timeout_s=60) as client:
        _clear(client)
        client.clear_background()
        client.add_roi("bar", 100, 0, 200, ROWS)
        client.start_stream(0, mode="area")
        try:
            client.capture_background(8)
            deadline = time.monotonic() + 30
            while client.background()["state"] == "capturing" and time.monotonic() < deadline:
                time.sleep(0.02)
            measured = client.roi_stats()["measured"]
            while client.roi_stats()["measured"] < measured + 20 and time.monotonic() < deadline:
                time.sleep(0.02)
        finally:
            client.stop_stream()
        stats = client.roi_stats(history=4096)
        _, background = client.background_frame()
        client.clear_background()
        client.delete_roi("bar")
    series = stats["history"]["bar"]
    bg_mean = float(background[0:ROWS, 100:300].mean())
    with_bg = [
        (m, b)
        for m, b in zip(series["mean_dn"], series["bg_mean_dn"], strict=True)
        if b is not None
    ]
    assert len(with_bg) >= 20  # every frame measured once the background was ready
    assert series["bg_mean_dn"][-1] is not None
    for mean, subtracted in with_bg:
        assert subtracted == pytest.approx(mean - bg_mean, rel=1e-12, abs=1e-9)
