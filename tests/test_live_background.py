"""The live view's background: the capture on its own (camd.pipeline.background), the
recorders' /background group, and the endpoints over a real daemon.

On synthetic frames: the mean of N frames (a float64 sum: exact where float32 would round),
where it came from, failure when the frames change mid-capture, clear, seq, saved_to. Over a
real daemon (simulated camera, HTTP on loopback): the background is, bit for bit, the mean of
the recorded frames whose counters it names; a later frame minus it is noise of the variance
sigma^2 (1 + 1/N) around 0; every recording started while it is ready (stream, stare, scan)
holds it bit-exact as /background; refusals change nothing.
"""

from __future__ import annotations

import datetime as dt
import json
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import h5py
import httpx
import numpy as np
import pytest

from camd.client import CamdClient, CamdError
from camd.client_types import BackgroundStatus
from camd.daemon.models import BACKGROUND_FRAMES_DEFAULT, BACKGROUND_FRAMES_MAX
from camd.link.frame_stream import ReceivedFrame
from camd.pipeline.background import FRAMES_DEFAULT, FRAMES_MAX, BackgroundCapture
from camd.protocol.stream import FrameFlags, FrameHeader, StreamMode
from camd.store.recording import FrameRecorder
from camd.store.tdi_recording import TdiRecorder, read_tdi_scan
from tests.test_trust import small_window_daemon

# Not ``exclusive``: the checks are pixels (bit for bit against the recordings) and refusals;
# a frame a busy machine delays is the same frame, and the background names the counters it
# averaged. Checked beside `stress-ng --cpu 2`.

API = "/api/v1"


def received(
    counter: int,
    pixels: np.ndarray,
    *,
    index: int | None = None,
    mode: StreamMode = StreamMode.AREA,
    stages: int = 0,
) -> ReceivedFrame:
    header = FrameHeader(
        counter=counter, timestamp_ns=counter * 1000, line_period_ns=1000,
        rows=pixels.shape[0], cols=pixels.shape[1], bits=16, mode=mode, stages=stages,
        stage_position=0, flags=FrameFlags(0), payload_bytes=pixels.nbytes, payload_crc32=0,
    )  # fmt: skip
    return ReceivedFrame(header=header, pixels=pixels, received_ns=0, gap_before=0,
                         index=counter if index is None else index)  # fmt: skip


# -- the capture on synthetic frames ----------------------------------------------------------------


def test_nothing_happens_until_started_then_n_frames_are_averaged() -> None:
    capture = BackgroundCapture(clock=lambda: 1_700_000_000.25)
    base = np.arange(4 * 6, dtype=np.uint16).reshape(4, 6)
    buffer = np.zeros((4, 6), dtype=np.uint16)
    buffer[:] = base
    capture(received(1, buffer))
    assert capture.snapshot().state == "none" and capture.ready() is None
    capture.start(4)
    assert capture.snapshot().state == "capturing" and capture.snapshot().frames_done == 0
    for counter in range(10, 16):  # 10..13 averaged, 14 and 15 come after: not taken
        buffer[:] = base + 10 * (counter - 10)  # the reader reuses its buffer: copy what is kept
        capture(received(counter, buffer))
        if counter == 11:
            snap = capture.snapshot()
            progress = (snap.state, snap.frames_done, snap.first_counter, snap.last_counter)
            assert progress == ("capturing", 2, 10, 11)
    background = capture.ready()
    assert background is not None
    # mean of base + 0, 10, 20, 30 = base + 15
    assert background.pixels.dtype == np.float32 and not background.pixels.flags.writeable
    assert np.array_equal(background.pixels, base + 15.0)
    assert background.mean_dn == pytest.approx(float(np.mean(base)) + 15)
    assert background.std_dn == pytest.approx(float(np.std(base)))
    assert (background.frames, background.first_counter, background.last_counter) == (4, 10, 13)
    assert (background.rows, background.cols, background.mode, background.stages) == (
        4, 6, "area", 0
    )  # fmt: skip
    assert background.seq == 1 and background.captured_t_s == 1_700_000_000.25
    assert background.recording_attrs() == {
        "frames": 4, "rows": 4, "cols": 6, "mode": "area", "stages": 0, "first_counter": 10,
        "last_counter": 13, "captured_utc": "2023-11-14T22:13:20.250+00:00",
    }  # fmt: skip
    assert background.meta()["dtype"] == "<f4" and background.meta()["seq"] == 1
    snap = capture.snapshot()
    assert (snap.state, snap.frames_wanted, snap.frames_done, snap.error) == ("ready", 4, 4, None)


def test_the_sum_is_float64_exact_where_float32_would_round() -> None:
    # 1000 frames near 65535: the sum passes 2**24, where float32 no longer holds odd integers.
    capture = BackgroundCapture()
    capture.start(FRAMES_MAX)
    for counter in range(FRAMES_MAX):
        capture(received(counter, np.full((2, 3), 65535 - counter % 2, dtype=np.uint16)))
    background = capture.ready()
    assert background is not None
    assert np.all(background.pixels == np.float32(65534.5))


@pytest.mark.parametrize(
    ("change", "words"),
    [
        ({"pixels": np.zeros((3, 6), dtype=np.uint16)}, "4 x 6 -> 3 x 6 pixels"),
        ({"mode": StreamMode.TDI}, "mode area -> tdi"),
        ({"stages": 4}, "stages 0 -> 4"),
    ],
    ids=["rows", "mode", "stages"],
)
def test_a_frame_of_other_geometry_fails_the_capture(change: dict[str, Any], words: str) -> None:
    capture = BackgroundCapture()
    capture.start(5)
    pixels = np.ones((4, 6), dtype=np.uint16)
    capture(received(7, pixels))
    capture(received(8, pixels))
    odd = {"pixels": pixels, **change}
    capture(received(9, odd.pop("pixels"), **odd))
    snap = capture.snapshot()
    assert snap.state == "failed" and capture.ready() is None
    assert snap.error == (
        f"the frames changed after 2 of 5 frames: {words} at frame counter 9; all frames of a "
        "background must be alike: capture again once the window, mode and stages are settled"
    )
    capture(received(10, pixels))  # a failed capture takes no more frames
    assert capture.snapshot() == snap


def test_a_new_stream_mid_capture_fails_it() -> None:
    capture = BackgroundCapture()
    capture.start(3)
    pixels = np.ones((2, 2), dtype=np.uint16)
    capture(received(100, pixels, index=40))
    capture(received(0, pixels, index=0))  # the first frame of the next stream
    snap = capture.snapshot()
    assert snap.state == "failed"
    assert snap.error is not None and snap.error.startswith(
        "the stream ended after 1 of 3 frames and another one started"
    )
    assert "capture again while streaming" in snap.error


def test_fail_clear_restart_seq_and_saved_to() -> None:
    capture = BackgroundCapture(saved_max=3)
    pixels = np.full((2, 2), 7, dtype=np.uint16)
    assert not capture.fail("the stream ended", "capture again")  # nothing runs
    capture.start(3)
    capture(received(1, pixels))
    assert capture.fail("the stream ended", "capture again")
    assert capture.snapshot().error == "the stream ended after 1 of 3 frames; capture again"
    for seq in (1, 2):
        capture.start(1)
        capture(received(seq, pixels))
        ready = capture.ready()
        assert ready is not None and ready.seq == seq
    for n in range(5):
        capture.note_saved(ready, f"/data/r{n}.h5")
    assert capture.snapshot().saved_to == ("/data/r2.h5", "/data/r3.h5", "/data/r4.h5")
    # Starting a capture drops the background there was, and with it where it was saved.
    capture.start(2)
    snap = capture.snapshot()
    assert (snap.state, snap.background, snap.saved_to) == ("capturing", None, ())
    capture.note_saved(ready, "/data/late.h5")  # the old background's: ignored
    assert capture.snapshot().saved_to == ()
    capture.clear()
    assert capture.snapshot() == type(snap)(state="none")
    capture(received(9, pixels))  # cleared: no longer capturing
    assert capture.snapshot().state == "none"
    capture.start(1)
    capture(received(10, pixels))
    after = capture.ready()
    assert after is not None and after.seq == 3  # seq counts on across clear


@pytest.mark.parametrize("frames", [0, FRAMES_MAX + 1])
def test_start_refuses_frames_outside_the_range_and_changes_nothing(frames: int) -> None:
    capture = BackgroundCapture()
    capture.start(1)
    capture(received(1, np.ones((2, 2), dtype=np.uint16)))
    before = capture.snapshot()
    with pytest.raises(ValueError, match=r"frames must be 1\.\.1000 for a background"):
        capture.start(frames)
    assert capture.snapshot() == before


def test_the_api_range_is_the_pipelines() -> None:
    assert (BACKGROUND_FRAMES_MAX, BACKGROUND_FRAMES_DEFAULT) == (FRAMES_MAX, FRAMES_DEFAULT)


# -- the recorders ----------------------------------------------------------------------------------


ATTRS = {
    "frames": 3, "rows": 2, "cols": 3, "mode": "area", "stages": 0, "first_counter": 5,
    "last_counter": 7, "captured_utc": "2024-01-02T03:04:05.678+00:00",
}  # fmt: skip


def stored_background(path: Path) -> tuple[np.ndarray, dict[str, Any]]:
    with h5py.File(path, "r", swmr=True) as f:
        node = f["background"]
        attrs = {k: (v.item() if isinstance(v, np.generic) else v) for k, v in node.attrs.items()}
        return np.asarray(node["mean_dn"]), attrs


def test_the_recorders_store_a_background_given_and_none_otherwise(tmp_path: Path) -> None:
    mean = np.array([[1.5, 2.25, 3.0], [4.0, 5.125, 6.0]], dtype=np.float32)
    with FrameRecorder(tmp_path / "f.h5", background_dn=mean, background_attrs=ATTRS):
        pass
    TdiRecorder(
        tmp_path / "t.h5", width=8, mode="sum", metadata={}, background_dn=mean,
        background_attrs=ATTRS,
    ).close()  # fmt: skip
    for name in ("f.h5", "t.h5"):
        data, attrs = stored_background(tmp_path / name)
        assert data.dtype == np.float32 and np.array_equal(data, mean)
        assert attrs == ATTRS
    assert read_tdi_scan(tmp_path / "t.h5").metadata["background"] == ATTRS
    with FrameRecorder(tmp_path / "none.h5"):
        pass
    with h5py.File(tmp_path / "none.h5", "r") as f:
        assert "background" not in f


# -- over a real daemon -----------------------------------------------------------------------------


@pytest.fixture(scope="module")
def url(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    with small_window_daemon(tmp_path_factory.mktemp("camd-background")) as url:
        yield url


def wait_done(client: CamdClient, timeout_s: float = 30.0) -> BackgroundStatus:
    """The background's status once it is no longer capturing."""
    deadline = time.monotonic() + timeout_s
    status = client.background()
    while status["state"] == "capturing" and time.monotonic() < deadline:
        time.sleep(0.02)
        status = client.background()
    return status


def capture(client: CamdClient, frames: int, record: Path | None = None) -> BackgroundStatus:
    """Capture a background from a stream started for it (recorded to ``record``)."""
    client.start_stream(0, mode="area", record=None if record is None else str(record))
    try:
        started = client.capture_background(frames)
        # "ready" too: a few frames of this small window take a millisecond, which the
        # stream's thread can spend between the capture's start and its answer.
        assert started["state"] in ("capturing", "ready") and started["frames_wanted"] == frames
        status = wait_done(client)
    finally:
        client.stop_stream()
    assert status["state"] == "ready", status
    return status


def recorded(path: Path) -> dict[int, np.ndarray]:
    with h5py.File(path, "r") as f:
        counters = np.asarray(f["frame_counter"])
        frames = np.asarray(f["frames"])
    return {int(c): frames[i] for i, c in enumerate(counters)}


def record_stream(client: CamdClient, path: Path, frames: int = 40) -> None:
    """A stream until stopped, recorded, stopped once it has ``frames`` frames."""
    client.start_stream(0, mode="area", record=str(path))
    try:
        deadline = time.monotonic() + 30
        while client.stream()["stats"]["frames"] < frames and time.monotonic() < deadline:
            time.sleep(0.02)
    finally:
        client.stop_stream()


def test_with_nothing_streaming_a_capture_is_refused_with_how_to_start_one(url: str) -> None:
    with CamdClient(url, timeout_s=60) as client, httpx.Client(base_url=url, timeout=30) as http:
        client.clear_background()
        with pytest.raises(CamdError) as info:
            client.capture_background(8)
        assert (info.value.http_status, info.value.code) == (409, "illegal_state")
        assert "start a stream (`camctl stream --start`), a stare or a scan" in info.value.message
        assert client.background() == {
            "state": "none", "frames_wanted": None, "frames_done": None, "rows": None,
            "cols": None, "mode": None, "stages": None, "first_counter": None,
            "last_counter": None, "captured_t_s": None, "seq": None, "mean_dn": None,
            "std_dn": None, "saved_to": [], "error": None,
        }  # fmt: skip
        answer = http.get(f"{API}/live/background/frame")
        assert answer.status_code == 404 and answer.json()["code"] == "no_background"
        assert "POST /api/v1/live/background" in answer.json()["error"]
        for frames in (0, 1001):
            answer = http.post(f"{API}/live/background", json={"frames": frames})
            assert answer.status_code == 400, answer.text
            assert answer.json()["error"].startswith(
                f"frames: {frames} is out of range; use an integer in 1..1000"
            )


def test_the_background_of_a_flat_scene_and_the_recordings_that_store_it(
    url: str, tmp_path: Path
) -> None:
    n = 16
    during, stream_after, stare_after = (tmp_path / f"{x}.h5" for x in ("a", "b", "c"))
    with CamdClient(url, timeout_s=120) as client, httpx.Client(base_url=url, timeout=30) as http:
        client.set_scene("flat")
        client.clear_background()
        status = capture(client, n, record=during)
        meta, background = client.background_frame()
        # A stream recording started before the background was ready does not hold it.
        with h5py.File(during, "r") as f:
            assert "background" not in f
        record_stream(client, stream_after)
        client.acquire(20, mode="area", record=str(stare_after))
        live = http.get(f"{API}/live/frame")
        after = client.background()
        raw = http.get(f"{API}/live/background/frame")

    # The background is, bit for bit, the mean of the frames of the counters it names.
    first, last = status["first_counter"], status["last_counter"]
    assert first is not None and last is not None
    frames = recorded(during)
    averaged = [frames[c] for c in range(first, last + 1)]
    assert len(averaged) == n == status["frames_done"] == meta["frames"]
    mean = np.mean(np.stack(averaged).astype(np.float64), axis=0)
    assert background.shape == (16, 2048) == (status["rows"], status["cols"])
    assert np.array_equal(background, mean.astype(np.float32))
    assert raw.headers["content-type"] == "application/octet-stream"
    assert np.array_equal(np.frombuffer(raw.content, dtype="<f4").reshape(16, 2048), background)
    assert json.loads(raw.headers["X-Camd-Background"]) == meta
    assert meta == {
        "seq": status["seq"], "frames": n, "rows": 16, "cols": 2048, "mode": "area",
        "stages": status["stages"], "first_counter": first, "last_counter": last,
        "captured_t_s": status["captured_t_s"], "mean_dn": status["mean_dn"],
        "std_dn": status["std_dn"], "dtype": "<f4",
    }  # fmt: skip
    assert status["mean_dn"] == pytest.approx(float(np.mean(mean)), abs=1e-3)
    assert status["std_dn"] == pytest.approx(float(np.std(mean)), rel=1e-4)
    # The flat field's level (without photons= it fills a quarter of the range), far above
    # the black level (about 100 DN).
    assert status["mean_dn"] > 1000

    # A later frame minus the background: the fixed pattern cancels, the temporal noise stays
    # with variance sigma^2 (1 + 1/N) (sigma from the later recording, pixel by pixel).
    later = np.stack(list(recorded(stream_after).values())).astype(np.float64)
    sigma = float(np.sqrt(np.mean(np.var(later, axis=0, ddof=1))))
    difference = later[-1] - background
    assert abs(float(difference.mean())) < 2.0
    assert float(difference.std()) == pytest.approx(sigma * np.sqrt(1 + 1 / n), rel=0.02)
    assert float(later[-1].std()) > 1.5 * float(difference.std())  # the pattern was there
    # The live view's frame (the stare's last) likewise.
    assert live.status_code == 200
    live_meta = json.loads(live.headers["X-Camd-Frame"])
    pixels = np.frombuffer(live.content, dtype="<u2").reshape(live_meta["rows"], live_meta["cols"])
    assert abs(float((pixels - background).mean())) < 2.0

    # Both recordings started while it was ready hold it bit-exact, with where it came from.
    captured = dt.datetime.fromtimestamp(status["captured_t_s"] or 0, dt.UTC)
    for path in (stream_after, stare_after):
        data, attrs = stored_background(path)
        assert data.dtype == np.float32 and np.array_equal(data, background)
        assert attrs == {
            "frames": n, "rows": 16, "cols": 2048, "mode": "area", "stages": status["stages"],
            "first_counter": first, "last_counter": last,
            "captured_utc": captured.isoformat(timespec="milliseconds"),
        }  # fmt: skip
    assert after["saved_to"] == [str(stream_after), str(stare_after)]
    assert {k: v for k, v in after.items() if k != "saved_to"} == {
        k: v for k, v in status.items() if k != "saved_to"
    }


def test_refused_requests_leave_a_ready_background_as_it_was(url: str, tmp_path: Path) -> None:
    with (
        CamdClient(url, timeout_s=60) as holder,
        CamdClient(url, timeout_s=60, client="observer@elsewhere") as observer,
        httpx.Client(base_url=url, timeout=30) as http,
    ):
        holder.set_scene("flat")
        capture(holder, 4)
        record_stream(holder, tmp_path / "saved.h5", frames=5)
        before = holder.background()
        assert before["saved_to"] == [str(tmp_path / "saved.h5")]
        _, pixels = holder.background_frame()
        refusals = []
        with pytest.raises(CamdError) as info:  # nothing streams
            holder.capture_background(4)
        refusals.append(info.value.http_status)
        for frames in (0, 1001):
            refusals.append(
                http.post(f"{API}/live/background", json={"frames": frames}).status_code
            )
        holder.take_control(60)
        holder.start_stream(0, mode="area")
        try:
            for attempt in (lambda: observer.capture_background(4), observer.clear_background):
                with pytest.raises(CamdError) as info:
                    attempt()
                assert info.value.code == "not_in_control"
                assert holder.client in info.value.message  # names who holds control
                refusals.append(info.value.http_status)
        finally:
            holder.stop_stream()
            holder.release_control()
        assert refusals == [409, 400, 400, 423, 423]
        assert holder.background() == before
        _, again = holder.background_frame()
        assert np.array_equal(again, pixels)


def test_a_capture_fails_when_its_stream_ends_first(url: str) -> None:
    with CamdClient(url, timeout_s=60) as client, httpx.Client(base_url=url, timeout=30) as http:
        # A stream that ends while the capture still waits for frames. A finite stream short
        # enough to end first (999 frames, a third of a second at this window) could end before
        # a busy machine's capture request came in; instead, slow frames (1001 lines each, some
        # 20 ms: 1000 frames take 20 s) and an unending stream, stopped once the capture has
        # begun. The 20 s are the margin between seeing its first frame and the stop.
        client.write_registers({"EXPOSURE": 1000})
        try:
            client.start_stream(0, mode="area")
            try:
                started = client.capture_background(1000)
                assert started["state"] == "capturing"
                deadline = time.monotonic() + 30
                while not client.background()["frames_done"]:
                    assert time.monotonic() < deadline, client.background()
                    time.sleep(0.02)
            finally:
                client.stop_stream()
            status = wait_done(client)
            answer = http.get(f"{API}/live/background/frame")
        finally:
            client.write_registers({"EXPOSURE": 4})
    assert status["state"] == "failed" and status["frames_wanted"] == 1000
    assert status["frames_done"] is not None and 0 < status["frames_done"] < 1000
    assert status["error"] == (
        f"the stream ended after {status['frames_done']} of 1000 frames; capture again while "
        "something streams (`camctl stream --start`, a stare or a scan)"
    )
    assert status["seq"] is None and status["mean_dn"] is None
    assert answer.status_code == 404 and "the last capture failed" in answer.json()["error"]


def test_cleared_it_is_gone_and_recordings_hold_none(url: str, tmp_path: Path) -> None:
    with CamdClient(url, timeout_s=60) as client, httpx.Client(base_url=url, timeout=30) as http:
        capture(client, 2)
        cleared = client.clear_background()
        assert cleared["state"] == "none" and cleared["seq"] is None and cleared["saved_to"] == []
        assert http.get(f"{API}/live/background/frame").status_code == 404
        client.acquire(3, mode="area", record=str(tmp_path / "plain.h5"))
    with h5py.File(tmp_path / "plain.h5", "r") as f:
        assert "background" not in f


def test_a_scan_started_while_it_is_ready_holds_it(url: str, tmp_path: Path) -> None:
    out = tmp_path / "scan.h5"
    with CamdClient(url, timeout_s=120) as client:
        status = capture(client, 3)
        _, background = client.background_frame()
        client.start_scan(4, 5, out=str(out), line_period_s=3e-3, drive_stage=False,
                          quicklook=False)  # fmt: skip
        assert client.wait_scan(120)["state"] == "done"
        after = client.background()
    data, attrs = stored_background(out)
    assert np.array_equal(data, background)
    assert (attrs["frames"], attrs["first_counter"]) == (3, status["first_counter"])
    assert after["saved_to"] == [str(out)]
