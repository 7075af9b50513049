"""The live view's frames: the tap on the stream (camd.pipeline.live) and its two endpoints.

The tap on its own with a stepped clock: how many frames it keeps and skips, and that what it
keeps is its own copy. Over a real daemon (simulated camera, HTTP and WebSocket on loopback):
the frame served is, pixel for pixel, the frame of the same counter in the stream's HDF5
recording; at most 20 frames a second are kept, whatever the stream's rate.
"""

from __future__ import annotations

import itertools
import json
from collections.abc import Iterator
from pathlib import Path

import h5py
import httpx
import numpy as np
import pytest
from websockets.sync.client import connect

from camd.client import CamdClient
from camd.link.frame_stream import ReceivedFrame
from camd.pipeline.live import MAX_RATE_HZ, LiveTap
from camd.protocol.stream import FrameFlags, FrameHeader, StreamMode
from tests.test_trust import small_window_daemon

# Not ``exclusive``: the frame served is checked, pixel for pixel, against the recorded frame
# of its counter, whenever it comes. Checked beside `stress-ng --cpu 2`.


def received(counter: int, pixels: np.ndarray, gap_before: int = 0) -> ReceivedFrame:
    header = FrameHeader(
        counter=counter, timestamp_ns=counter * 1000, line_period_ns=1000,
        rows=pixels.shape[0], cols=pixels.shape[1], bits=12, mode=StreamMode.AREA, stages=1,
        stage_position=0, flags=FrameFlags(0), payload_bytes=pixels.nbytes, payload_crc32=0,
    )  # fmt: skip
    return ReceivedFrame(header=header, pixels=pixels, received_ns=0, gap_before=gap_before,
                         index=counter)  # fmt: skip


def test_the_tap_keeps_at_most_max_rate_and_counts_what_it_skips() -> None:
    now = [0.0]
    tap = LiveTap(max_rate_hz=20.0, clock=lambda: now[0])
    buffer = np.zeros((4, 6), dtype=np.uint16)
    kept = []
    for counter in range(100):  # 1 kHz for 0.1 s: kept at t = 0 and t = 0.05 s
        now[0] = counter * 1e-3
        buffer[:] = counter
        tap(received(counter, buffer, gap_before=3 if counter == 50 else 0))
        frame = tap.latest()
        if frame is not None and (not kept or kept[-1].seq != frame.seq):
            kept.append(frame)
    assert [(f.seq, f.counter, f.index, f.skipped) for f in kept] == [(1, 0, 1, 0), (2, 50, 51, 49)]
    assert kept[1].gap_before == 3 and kept[1].meta()["gap_before"] == 3
    # The tap's copy: the reader's buffer has moved on to frame 99 since.
    assert int(kept[1].pixels.max()) == 50 and not kept[1].pixels.flags.writeable
    assert tap.seen == 100 and tap.kept == 2
    assert tap.wait_newer(2, timeout_s=0.01) is None
    assert tap.wait_newer(1, timeout_s=0.01) is kept[1]


@pytest.fixture(scope="module")
def url(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    with small_window_daemon(tmp_path_factory.mktemp("camd-live")) as url:
        yield url


def recorded(path: Path) -> dict[int, np.ndarray]:
    with h5py.File(path, "r") as f:
        counters = np.asarray(f["frame_counter"])
        frames = np.asarray(f["frames"])
    return {int(c): frames[i] for i, c in enumerate(counters)}


def test_before_any_stream_the_frame_endpoint_says_what_to_do(url: str) -> None:
    with httpx.Client(base_url=url, timeout=30) as http:
        answer = http.get("/api/v1/live/frame", params={"after": 10**6, "timeout_s": 0.2})
    assert answer.status_code == 404 and answer.json()["code"] == "no_frame"
    assert "start a stream (`camctl stream --frames 100`)" in answer.json()["error"]


def test_the_served_frame_is_the_recorded_frame_of_its_counter(url: str, tmp_path: Path) -> None:
    path = tmp_path / "live.h5"
    with CamdClient(url, timeout_s=120) as client, httpx.Client(base_url=url, timeout=30) as http:
        client.acquire(300, mode="area", record=str(path))
        answer = http.get("/api/v1/live/frame")
    assert answer.status_code == 200, answer.text
    meta = json.loads(answer.headers["X-Camd-Frame"])
    frames = recorded(path)
    pixels = np.frombuffer(answer.content, dtype="<u2").reshape(meta["rows"], meta["cols"])
    assert meta["mode"] == "area" and meta["dtype"] == "<u2"
    assert np.array_equal(pixels, frames[meta["counter"]])
    # 300 frames went by; the tap kept some of them (its newest is one of the 300).
    assert meta["seq"] < meta["index"] <= 300


def test_the_websocket_pushes_recorded_frames_newest_first(url: str, tmp_path: Path) -> None:
    path = tmp_path / "ws.h5"
    ws_url = url.replace("http://", "ws://") + "/api/v1/live/ws"
    with CamdClient(url, timeout_s=120) as client, connect(ws_url, open_timeout=30) as ws:
        client.start_stream(0, mode="area", record=str(path))
        try:
            got = []
            # The first message may be the newest frame of the stream before this one.
            json.loads(ws.recv(timeout=30))
            ws.recv(timeout=30)
            for _ in range(4):
                meta = json.loads(ws.recv(timeout=30))
                data = ws.recv(timeout=30)
                assert isinstance(data, bytes)
                got.append(
                    (meta, np.frombuffer(data, dtype="<u2").reshape(meta["rows"], meta["cols"]))
                )
        finally:
            client.stop_stream()
    frames = recorded(path)
    seqs = [meta["seq"] for meta, _ in got]
    assert seqs == sorted(seqs) and len(set(seqs)) == 4
    for meta, pixels in got:
        assert np.array_equal(pixels, frames[meta["counter"]]), meta
    # Frames between two that were pushed were skipped, never queued: index says how many.
    indices = [meta["index"] for meta, _ in got]
    assert all(b > a for a, b in itertools.pairwise(indices))


def test_max_rate_is_a_screens_rate() -> None:
    assert MAX_RATE_HZ == 20.0
