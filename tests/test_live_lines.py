"""The live view's waterfall: the newest TDI lines of a scan (camd.pipeline.live.LiveLines) and
GET /api/v1/live/lines.

``LiveLines`` on its own: the ring wraps, ``since`` gives the newest lines after an index and
counts exactly the ones it leaves out, also across the index gaps of lost frames; a waiting
viewer wakes for new lines and for a new scan. The pipeline feeds it without ever failing a
scan for it. Over a real daemon (simulated camera with frames dropped on purpose, HTTP on
loopback): the lines a viewer follows while the scan runs are, bit for bit, the lines of the
scan's HDF5 file, with the same indices, completeness flags and stage counts; ``after``,
``max`` and ``skipped`` add up; bad parameters are refused naming their range.
"""

from __future__ import annotations

import itertools
import json
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import numpy.typing as npt
import pytest

from camd.client import CamdClient, CamdError
from camd.pipeline.live import LINES_CAPACITY, LiveLines
from camd.store.tdi_recording import TdiScan, read_tdi_scan
from tests.test_pipeline import make, received, run_out, shifted_ramp
from tests.test_sensor_stack import serve

# Not ``exclusive``: the live lines are checked bit for bit against the scan's file, lost
# frames and all (the lost ones are injected, seeded); a busy machine delays them, both sides
# the same. Checked beside `stress-ng --cpu 2`.

STAGES = 4
LINES = 600  # + M - 1 frames: all of them fit the daemon's 2048-line ring
INJECT = "frame_drop=0.03"  # the simulator loses ~3 % of the frames: index gaps, incomplete lines


def block(indices: Any, cols: int = 3) -> tuple[npt.NDArray[Any], ...]:
    """A block of lines as the engine gives them, each line's values telling its index."""
    index = np.asarray(list(indices), dtype=np.int64)
    data = (index[:, None] * 10 + np.arange(cols)).astype(np.uint32)
    return data, index, index % 3 != 0, (index % 5).astype(np.int32)


# -- LiveLines on its own ---------------------------------------------------------------------


def test_nothing_before_the_first_scan_and_the_ring_wraps() -> None:
    lines = LiveLines(capacity=8)
    assert lines.since(-1) is None and lines.scan is None
    assert lines.wait_newer(-1, timeout_s=0.01) is False
    lines.reset(3, scan="/data/a.h5", lines_planned=25)
    empty = lines.since(-1)
    assert empty is not None and empty.n == 0 and empty.meta()["first_index"] is None
    assert (empty.lines_done, empty.lines_planned, empty.state) == (0, 25, "running")
    for start in range(0, 25, 5):  # 25 lines through an 8-line ring, in blocks of 5
        lines.append(*block(range(start, start + 5)))
    chunk = lines.since(-1, 100)
    assert chunk is not None
    assert chunk.index.tolist() == list(range(17, 25)) and chunk.skipped == 17
    assert chunk.data.dtype == np.float32
    assert np.array_equal(chunk.data, block(range(17, 25))[0].astype(np.float32))
    assert chunk.complete.tolist() == (chunk.index % 3 != 0).tolist()
    assert chunk.stages_used.tolist() == (chunk.index % 5).tolist()
    meta = chunk.meta()
    assert meta["first_index"] == 17 and meta["n"] == 8 and meta["cols"] == 3
    assert meta["index"] == list(range(17, 25)) and meta["lines_done"] == 25
    assert (meta["scan"], meta["scan_seq"], meta["dtype"]) == ("/data/a.h5", 1, "<f4")
    # A block longer than the ring: its newest lines are kept, all are counted.
    lines.append(*block(range(25, 45)))
    chunk = lines.since(20, 100)
    assert chunk is not None and chunk.index.tolist() == list(range(37, 45))
    assert chunk.skipped == 24 - 8  # 21..44 are newer than 20; 8 sent
    # The returned lines are copies: the ring moving on does not change them.
    lines.append(*block(range(45, 53)))
    assert chunk.index.tolist() == list(range(37, 45))
    assert np.array_equal(chunk.data[:, 0], np.arange(37, 45) * 10)


def test_since_counts_exactly_across_the_gaps_of_lost_frames() -> None:
    lines = LiveLines(capacity=6)
    lines.reset(3, scan="s")
    lines.append(*block(range(0, 5)))  # 0..4
    lines.append(*block([8, 9, 10]))  # 5, 6, 7 lost
    lines.append(*block([12, 13, 20, 21]))  # a block with a jump inside: 11 and 14..19 lost
    everything = [0, 1, 2, 3, 4, 8, 9, 10, 12, 13, 20, 21]
    for after in range(-1, 23):
        newer = [i for i in everything if i > after]
        for most in (1, 2, 6, 100):
            chunk = lines.since(after, most)
            assert chunk is not None
            sent = newer[-min(len(newer), most, 6) :] if newer else []
            assert chunk.index.tolist() == sent, (after, most)
            assert chunk.skipped == len(newer) - len(sent), (after, most)
            assert np.array_equal(chunk.data[:, 0], np.asarray(sent) * 10)


def test_a_waiting_viewer_wakes_for_new_lines_and_for_a_new_scan() -> None:
    lines = LiveLines(capacity=16)
    lines.reset(3, scan="first")
    lines.append(*block(range(10)))
    assert lines.wait_newer(8, timeout_s=0.01) is True  # there already
    t0 = time.monotonic()
    assert lines.wait_newer(9, timeout_s=0.2) is False
    assert time.monotonic() - t0 >= 0.15

    def later(action: Any) -> None:
        threading.Timer(0.1, action).start()

    # Each wait below is woken by the change 0.1 s on, not by its timeout: returning well
    # inside a 60 s timeout tells the two apart, however late a busy machine runs the timer.
    later(lambda: lines.append(*block([10])))
    t0 = time.monotonic()
    assert lines.wait_newer(9, timeout_s=60) is True
    assert time.monotonic() - t0 < 30
    later(lambda: lines.end("done"))  # the scan ended: the viewer hears it at once
    t0 = time.monotonic()
    assert lines.wait_newer(10, timeout_s=60) is False
    assert time.monotonic() - t0 < 30
    chunk = lines.since(10)
    assert chunk is not None and chunk.state == "done" and chunk.n == 0
    # A new scan restarts the indices: a viewer still at the old scan's index wakes and sees
    # that the scan (scan, scan_seq) changed.
    later(lambda: lines.reset(5, scan="second", lines_planned=7))
    t0 = time.monotonic()
    lines.wait_newer(10, timeout_s=60)
    assert time.monotonic() - t0 < 30
    chunk = lines.since(10)
    assert chunk is not None and (chunk.scan, chunk.scan_seq, chunk.cols) == ("second", 2, 5)
    assert (chunk.n, chunk.lines_done, chunk.state) == (0, 0, "running")


def test_append_refuses_what_is_not_a_block_of_increasing_lines() -> None:
    lines = LiveLines(capacity=4)
    with pytest.raises(ValueError, match="before reset"):
        lines.append(*block([0]))
    lines.reset(3, scan="s")
    lines.append(*block([0, 1]))
    with pytest.raises(ValueError, match=r"line indices must increase: got 1\.\.2 after 1"):
        lines.append(*block([1, 2]))
    with pytest.raises(ValueError, match="must increase"):
        lines.append(*block([5, 4]))
    with pytest.raises(ValueError, match="F lines of 3 columns"):
        lines.append(*block([2], cols=4))
    chunk = lines.since(-1)
    assert chunk is not None and chunk.index.tolist() == [0, 1]  # nothing kept of those
    with pytest.raises(ValueError, match="capacity"):
        LiveLines(capacity=0)
    assert LINES_CAPACITY == 2048


def test_the_pipeline_feeds_the_lines_and_a_failing_sink_never_fails_the_scan(
    tmp_path: Path,
) -> None:
    frames = shifted_ramp(300)
    arrived = [*range(100), *range(103, 300)]  # frames 100..102 lost
    live = LiveLines(capacity=512)
    live.reset(12, scan="x")
    (tmp_path / "a").mkdir()
    pipeline, calls = make(tmp_path / "a", STAGES, on_lines=live.append)
    for n, k in enumerate(arrived):
        pipeline.consumer(received(frames[k], k, gap_before=3 if k == 103 else 0, index=n))
    scan = run_out(pipeline)
    chunk = live.since(-1, 512)
    assert chunk is not None and chunk.skipped == 0
    assert chunk.index.tolist() == scan.line_index.tolist() == arrived
    assert np.array_equal(chunk.data, scan.lines.astype(np.float32))
    assert chunk.complete.tolist() == scan.complete.tolist()
    assert chunk.stages_used.tolist() == scan.stages_used.tolist()

    def broken(*args: Any) -> None:
        raise RuntimeError("viewer trouble")

    (tmp_path / "b").mkdir()
    pipeline, calls = make(tmp_path / "b", STAGES, on_lines=broken)
    for k in range(50):
        pipeline.consumer(received(frames[k], k, index=k))
    scan = run_out(pipeline)
    assert len(scan.lines) == 50 and pipeline.error is None and not calls.failed.is_set()


# -- over a daemon ----------------------------------------------------------------------------


@pytest.fixture(scope="module")
def url(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    with serve(tmp_path_factory.mktemp("camd-live-lines"), "fpga", inject=INJECT) as daemon:
        with CamdClient(daemon.url) as client:
            client.write_registers({"WIN_ROWS": 16, "EXPOSURE": 4})
        yield daemon.url
    assert daemon.exit_code in (0, -15), daemon.log_path.read_text()


def get_lines(url: str, **params: Any) -> httpx.Response:
    with httpx.Client(base_url=url, timeout=30) as http:
        return http.get("/api/v1/live/lines", params=params)


def test_before_any_scan_the_lines_endpoint_says_what_to_do(url: str) -> None:
    answer = get_lines(url)
    assert answer.status_code == 404 and answer.json()["code"] == "no_scan"
    assert answer.json()["error"].startswith("no scan has run since the daemon started")
    assert "`camctl scan" in answer.json()["error"]
    with CamdClient(url) as client, pytest.raises(CamdError) as info:
        client.live_lines()
    assert (info.value.code, info.value.http_status) == ("no_scan", 404)


class Followed:
    """A scan started on the daemon and followed from its first line to its end, as the live
    page follows one: each request asks for the lines after the last index it has."""

    def __init__(self, url: str, out: Path) -> None:
        self.metas: list[dict[str, Any]] = []
        chunks: list[npt.NDArray[np.float32]] = []
        with CamdClient(url, timeout_s=60) as client:
            client.set_sim_seed(16)  # the same frames dropped at each run
            started = client.start_scan(STAGES, LINES, out=str(out), drive_stage=False)
            after, deadline = -1, time.monotonic() + 300
            while time.monotonic() < deadline:
                meta, lines = client.live_lines(after, max_lines=2048, timeout_s=1.0)
                if meta["scan"] != started["file"]:
                    continue  # the last scan's end, before this one's first line
                self.metas.append(meta)
                chunks.append(lines)
                if meta["n"]:
                    after = meta["index"][-1]
                elif meta["state"] != "running":
                    break
            self.doc = client.wait_scan(60)
        self.lines = np.concatenate(chunks)
        self.index = [i for meta in self.metas for i in meta["index"]]
        self.complete = [c for meta in self.metas for c in meta["complete"]]
        self.stages_used = [s for meta in self.metas for s in meta["stages_used"]]
        self.file: TdiScan = read_tdi_scan(out)


@pytest.fixture(scope="module")
def followed(url: str, tmp_path_factory: pytest.TempPathFactory) -> Followed:
    return Followed(url, tmp_path_factory.mktemp("followed") / "scan.h5")


def test_followed_lines_are_the_lines_of_the_file_bit_for_bit(followed: Followed) -> None:
    scan, doc = followed.file, followed.doc
    assert doc["state"] == "done" and len(followed.metas) > 2  # followed, not read at the end
    assert followed.index == scan.line_index.tolist()
    expected = scan.lines.astype(np.float32)
    assert followed.lines.shape == expected.shape == (doc["lines"], doc["width"])
    assert np.array_equal(followed.lines.view(np.uint32), expected.view(np.uint32))
    assert followed.complete == scan.complete.tolist()
    assert followed.stages_used == scan.stages_used.tolist()
    assert sum(meta["skipped"] for meta in followed.metas) == 0
    last = followed.metas[-1]
    assert (last["state"], last["lines_done"], last["n"]) == ("done", doc["lines"], 0)
    assert last["lines_planned"] == doc["frames_requested"] == LINES + STAGES - 1
    assert last["cols"] == doc["width"]


def test_dropped_frames_leave_the_same_lines_incomplete_in_both(followed: Followed) -> None:
    scan = followed.file
    index = scan.line_index
    gaps = np.flatnonzero(np.diff(index) > 1)
    assert len(gaps) > 0, "no frame was dropped: raise frame_drop"
    assert followed.doc["lost_frames"] > 0
    # After a gap the next M - 1 lines (at least) miss a stage, in the file and in the live view.
    for g in gaps:
        after_gap = index[g + 1]
        at = followed.index.index(int(after_gap))
        assert followed.complete[at] is False and not scan.complete[g + 1]
        assert followed.stages_used[at] < STAGES
    beyond_start = np.asarray(followed.complete[STAGES - 1 :])
    assert not beyond_start.all()
    incomplete = [i for i, c in zip(followed.index, followed.complete, strict=True) if not c]
    assert incomplete == index[~scan.complete].tolist()


def test_after_max_and_skipped_add_up(url: str, followed: Followed) -> None:
    scan = followed.file
    index = scan.line_index.tolist()
    n_all = len(index)
    expected = scan.lines.astype(np.float32)

    def ask(**params: Any) -> tuple[dict[str, Any], npt.NDArray[np.float32]]:
        answer = get_lines(url, **params)
        assert answer.status_code == 200, answer.text
        assert answer.headers["content-type"] == "application/octet-stream"
        meta: dict[str, Any] = json.loads(answer.headers["X-Camd-Lines"])
        data = np.frombuffer(answer.content, dtype="<f4").reshape(meta["n"], meta["cols"])
        assert meta["scan"] == followed.doc["file"] and meta["state"] == "done"
        at = [index.index(i) for i in meta["index"]]
        assert np.array_equal(data, expected[at])
        return meta, data

    meta, _ = ask(max=10)  # after defaults to -1: the newest 10 of all
    assert meta["index"] == index[-10:] and meta["first_index"] == index[-10]
    assert meta["skipped"] == n_all - 10
    meta, _ = ask()  # max defaults to 512
    assert meta["n"] == 512 and meta["skipped"] == n_all - 512
    k = 100
    meta, _ = ask(after=index[k], max=2048)
    assert meta["index"] == index[k + 1 :] and meta["skipped"] == 0
    meta, _ = ask(after=index[k], max=50)
    assert meta["index"] == index[-50:] and meta["skipped"] == n_all - (k + 1) - 50
    lost = next(i + 1 for i, j in itertools.pairwise(index) if j > i + 1)
    meta, _ = ask(after=lost, max=2048)  # the index of a lost frame: the lines after it
    assert meta["index"] == [i for i in index if i > lost] and meta["skipped"] == 0
    # Nothing newer: waits timeout_s (for a next scan), then n = 0 and an empty body.
    t0 = time.monotonic()
    answer = get_lines(url, after=index[-1], timeout_s=0.5)
    assert time.monotonic() - t0 >= 0.4
    meta = json.loads(answer.headers["X-Camd-Lines"])
    assert answer.status_code == 200 and answer.content == b""
    assert (meta["n"], meta["first_index"], meta["skipped"], meta["index"]) == (0, None, 0, [])
    assert meta["lines_done"] == n_all
    # timeout_s defaults to 0: no wait. Said by the schema, not by a wall-clock bound (a busy
    # machine can take seconds over any request); the request below takes that default.
    with httpx.Client(base_url=url, timeout=30) as http:
        schema = http.get("/openapi.json").json()["paths"]["/api/v1/live/lines"]["get"]
    timeout_param = next(p for p in schema["parameters"] if p["name"] == "timeout_s")
    assert timeout_param["schema"]["default"] == 0
    assert get_lines(url, after=10**9).headers["X-Camd-Lines"]


@pytest.mark.parametrize(
    ("params", "words"),
    [
        ({"max": 0}, "max: 0 is out of range; use an integer in 1..2048 (lines)"),
        ({"max": 2049}, "max: 2049 is out of range; use an integer in 1..2048"),
        ({"after": -2}, "after: -2 is out of range; use an integer >= -1 (the last line index"),
        (
            {"timeout_s": 6},
            "timeout_s: 6 is out of range; use a number in 0..5 (with no line newer",
        ),
        ({"timeout_s": -1}, "timeout_s: -1 is out of range; use a number in 0..5"),
        ({"after": "last"}, "after: 'last' is not valid; use an integer >= -1"),
    ],
)
def test_bad_parameters_are_refused_naming_the_range(
    url: str, params: dict[str, Any], words: str
) -> None:
    answer = get_lines(url, **params)
    assert answer.status_code == 400, answer.text
    assert answer.json()["code"] == "bad_request"
    assert words in answer.json()["error"]
