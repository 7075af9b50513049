"""The acquisition pipeline on its own: frames in, an HDF5 scan out, no daemon.

Frames are built as ``camd.link.frame_stream`` delivers them (``ReceivedFrame`` with a
``FrameHeader``) and fed to the pipeline's consumer on the test's thread, as the stream's
dispatcher would; a real ``TdiRecorder`` writes a real file, read back with ``read_tdi_scan``.
The expected lines are worked here with numpy from docs/physics.md §1 eq 11 (line k is
``sum_i frames[k - i][row i]``), independently of ``camd.tdi``.
"""

from __future__ import annotations

import ast
import queue
import threading
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import pytest

from camd.link.frame_stream import ReceivedFrame
from camd.link.packed import FrameBatch, Run, header_fields, run_pixels
from camd.pipeline import (
    Batch,
    Batcher,
    Gap,
    Message,
    MismatchTracker,
    StageChange,
    TdiPipeline,
)
from camd.pipeline import batcher as batcher_module
from camd.pipeline.background import BackgroundCapture
from camd.pipeline.live import LiveTap
from camd.protocol.stream import HEADER_BYTES, FrameFlags, FrameHeader, StreamMode, encode_header
from camd.store.tdi_recording import TdiRecorder, TdiScan, read_tdi_scan
from camd.tdi import TdiEngine
from camd.timing import line_mismatch

ROOT = Path(__file__).resolve().parents[1]
COLS = 12
ROWS = 8  # window rows of every frame: room for up to 8 stages
WAIT_S = 60.0  # generous: these waits end as soon as the worker has done its part


@pytest.fixture(autouse=True)
def _patient_batcher(monkeypatch: pytest.MonkeyPatch) -> None:
    """The batcher gives a frame up when no batch buffer comes free within its wait: on a busy
    machine the worker may be slow to hand one back, which is not what these tests test."""
    monkeypatch.setattr(batcher_module, "CONSUMER_WAIT_S", WAIT_S)


def received(pixels: npt.NDArray[np.uint16], counter: int, *, encoder: int = 0,
             gap_before: int = 0, index: int = 0) -> ReceivedFrame:  # fmt: skip
    """A frame as the stream delivers it (header fields the pipeline does not read are 0)."""
    rows, cols = pixels.shape
    header = FrameHeader(
        counter=counter % (1 << 32),
        timestamp_ns=0,
        line_period_ns=100_000,
        rows=rows,
        cols=cols,
        bits=12,
        mode=StreamMode.TDI,
        stages=4,
        stage_position=encoder,
        flags=FrameFlags(0),
        payload_bytes=rows * cols * 2,
        payload_crc32=0,
    )
    view = pixels.view()
    view.flags.writeable = False  # the reader's slot is read-only, as here
    return ReceivedFrame(
        header=header, pixels=view, received_ns=0, gap_before=gap_before, index=index
    )


def shifted_ramp(frames: int, rows: int = ROWS, cols: int = COLS) -> npt.NDArray[np.uint16]:
    """Frames of a scene moving one row per frame: frame f, row r sees ground line f + r, whose
    pixels are a ramp (7 g + 3 c) mod 4096. Line k of M stages therefore sums ground line k
    M times."""
    f = np.arange(frames)[:, None, None]
    r = np.arange(rows)[None, :, None]
    c = np.arange(cols)[None, None, :]
    return ((7 * (f + r) + 3 * c) % 4096).astype(np.uint16)


def reference(
    frames: dict[int, npt.NDArray[np.uint16]], indices: Iterable[int], runs: list[tuple[int, int]]
) -> tuple[npt.NDArray[np.uint32], npt.NDArray[np.int64]]:
    """Eq 11 by hand: line k sums row i of frame k - i over the M stages of k's run (a run
    starts at its first line index, ``runs`` = [(start, M), ...]), for the frames that
    arrived; returns the lines and the stages each used."""
    lines, used = [], []
    for k in indices:
        start, m = max((run for run in runs if run[0] <= k), key=lambda run: run[0])
        got = [frames[k - i][i].astype(np.uint32) for i in range(m) if k - i >= start and
               k - i in frames]  # fmt: skip
        lines.append(np.sum(got, axis=0, dtype=np.uint32))
        used.append(len(got))
    return np.asarray(lines, dtype=np.uint32), np.asarray(used, dtype=np.int64)


class Recorded:
    """The pipeline's callbacks, recorded; ``failed`` is set by ``on_failure``."""

    def __init__(self) -> None:
        self.events: list[tuple[str, str, str]] = []
        self.failed = threading.Event()
        self.reds = 0

    def event(self, level: str, source: str, message: str) -> None:
        self.events.append((level, source, message))

    def red(self) -> None:
        self.reds += 1


def make(tmp_path: Path, stages: int = 4, *, recorder_type: type[TdiRecorder] = TdiRecorder,
         **kwargs: Any) -> tuple[TdiPipeline, Recorded]:  # fmt: skip
    calls = Recorded()
    recorder = recorder_type(tmp_path / "scan.h5", width=COLS, mode="sum", metadata={})
    pipeline = TdiPipeline(
        TdiEngine(stages, COLS, kernel="numpy"),
        recorder,
        rows=ROWS,
        on_event=calls.event,
        on_failure=calls.failed.set,
        on_red=calls.red,
        **kwargs,
    )
    pipeline.start()
    return pipeline, calls


def run_out(pipeline: TdiPipeline) -> TdiScan:
    """The stream has ended: finish, close the file, read it back."""
    assert pipeline.finish(timeout_s=WAIT_S)
    pipeline.recorder.close()
    return read_tdi_scan(pipeline.recorder.path)


def test_lines_are_eq11_sums_of_the_frames_across_batches(tmp_path: Path) -> None:
    m, count = 4, 1300  # more frames than one batch holds: the engine's ring spans batches
    frames = shifted_ramp(count, rows=ROWS + 2)  # taller than the engine needs: first ROWS used
    pipeline, calls = make(tmp_path, m)
    assert pipeline.consumer.batch_frames < count
    for k in range(count):
        pipeline.consumer(received(frames[k], 1000 + k, encoder=5 * k, index=k))
    scan = run_out(pipeline)

    expected, used = reference(dict(enumerate(frames)), range(count), [(0, m)])
    assert np.array_equal(scan.lines, expected)
    # The same worked the other way: a complete line is M times its ground line's ramp.
    ground = (7 * np.arange(count)[:, None] + 3 * np.arange(COLS)) % 4096
    assert np.array_equal(scan.lines[m - 1 :], m * ground[m - 1 :])
    assert scan.line_index.tolist() == list(range(count))
    assert scan.stages_used.tolist() == used.tolist() == [1, 2, 3, *[4] * (count - 3)]
    assert scan.complete.tolist() == [False] * (m - 1) + [True] * (count - m + 1)
    assert scan.frame_counter.tolist() == list(range(1000, 1000 + count))
    assert scan.stage_position.tolist() == [5 * k for k in range(count)]
    assert np.isnan(scan.m_dv_over_v).all()  # no counts_per_pixel: no mismatch monitor
    assert scan.stage_changes.tolist() == [[0, m]]
    progress = pipeline.progress()
    assert (progress.lines, progress.complete_lines) == (count, count - m + 1)
    assert (progress.frames_in, progress.frames_batched, progress.backlog_frames) == (
        count,
        count,
        0,
    )
    assert (progress.gap_frames, progress.dropped_frames) == (0, 0)
    assert progress.stage_changes == ((0, m),)
    assert progress.mismatch_max is None and progress.mismatch_level == "ok"
    assert calls.events == [] and not calls.failed.is_set() and pipeline.error is None


def test_a_gap_skips_the_lost_lines_and_leaves_the_next_m_minus_1_incomplete(
    tmp_path: Path,
) -> None:
    m = 4
    frames = shifted_ramp(40)
    arrived = [*range(10), *range(13, 40)]  # frames 10, 11 and 12 lost on the way
    pipeline, _ = make(tmp_path, m)
    for n, k in enumerate(arrived):
        gap = 3 if k == 13 else 0
        pipeline.consumer(received(frames[k], k, gap_before=gap, index=n))
    scan = run_out(pipeline)

    assert scan.line_index.tolist() == arrived
    assert scan.frame_counter.tolist() == arrived
    after = scan.line_index >= 13
    assert scan.complete[after].tolist() == [False] * (m - 1) + [True] * (len(arrived) - 13)
    assert scan.stages_used[after][:m].tolist() == [1, 2, 3, 4]
    expected, used = reference({k: frames[k] for k in arrived}, arrived, [(0, m)])
    assert np.array_equal(scan.lines, expected)
    assert scan.stages_used.tolist() == used.tolist()
    assert pipeline.progress().gap_frames == 3


def test_a_stage_change_starts_a_new_run_at_the_next_frame_and_is_recorded(
    tmp_path: Path,
) -> None:
    frames = shifted_ramp(50)
    pipeline, _ = make(tmp_path, 4)
    for k in range(20):
        pipeline.consumer(received(frames[k], k, index=k))
    pipeline.request_stages(6)
    assert pipeline.pending_stages == 6 and pipeline.stages in (4, 6)
    for k in range(20, 50):
        pipeline.consumer(received(frames[k], k, index=k))
    scan = run_out(pipeline)

    assert pipeline.pending_stages is None and pipeline.stages == 6
    assert scan.stage_changes.tolist() == [[0, 4], [20, 6]]
    assert pipeline.progress().stage_changes == ((0, 4), (20, 6))
    # The new run mixes nothing of the old one in: lines 20..24 are incomplete.
    assert scan.stages_used[18:27].tolist() == [4, 4, 1, 2, 3, 4, 5, 6, 6]
    assert scan.complete.tolist() == [False] * 3 + [True] * 17 + [False] * 5 + [True] * 25
    expected, _ = reference(dict(enumerate(frames)), range(50), [(0, 4), (20, 6)])
    assert np.array_equal(scan.lines, expected)


def test_a_frame_of_the_wrong_geometry_is_dropped_and_counted_as_a_gap(tmp_path: Path) -> None:
    m = 3
    frames = shifted_ramp(20)
    pipeline, _ = make(tmp_path, m)
    for k in range(20):
        if k == 7:
            narrow = np.zeros((ROWS, COLS - 2), dtype=np.uint16)
            pipeline.consumer(received(narrow, k, index=k))
        elif k == 12:
            short = np.zeros((ROWS - 1, COLS), dtype=np.uint16)
            pipeline.consumer(received(short, k, index=k))
        else:
            pipeline.consumer(received(frames[k], k, index=k))
    scan = run_out(pipeline)

    kept = [k for k in range(20) if k not in (7, 12)]
    assert scan.line_index.tolist() == kept
    # Lines 8 and 9 lack frame 7, lines 13 and 14 frame 12 (each keeps its other stages).
    assert scan.stages_used[7:13].tolist() == [2, 2, 3, 3, 2, 2]  # lines 8-11, 13, 14
    assert scan.complete[7:13].tolist() == [False, False, True, True, False, False]
    expected, _ = reference({k: frames[k] for k in kept}, kept, [(0, m)])
    assert np.array_equal(scan.lines, expected)
    progress = pipeline.progress()
    assert (progress.dropped_frames, progress.gap_frames) == (2, 2)
    assert (progress.frames_batched, progress.frames_in, progress.lines) == (18, 18, 18)


def test_each_line_gets_its_m_dv_over_v_across_batches_and_a_counter_wrap(
    tmp_path: Path,
) -> None:
    """A stage 10 % fast: 11 encoder counts per frame where one pitch is 10 counts. Over the
    M = 4 periods of a complete line the image moved 4.4 pitches: M dV/V = 4 - 4.4 = -0.4
    pixels (docs/physics.md §6)."""
    m, count, per_pixel = 4, 1200, 10.0
    first = (1 << 32) - 600  # the device's 32-bit counter wraps mid-scan
    frames = shifted_ramp(count)
    pipeline, calls = make(tmp_path, m, counts_per_pixel=per_pixel, yellow_px=0.3, red_px=2.0)
    encoder = -3000 + 11 * np.arange(count)
    for k in range(count):
        pipeline.consumer(received(frames[k], first + k, encoder=int(encoder[k]), index=k))
    scan = run_out(pipeline)

    assert scan.frame_counter[599] == (1 << 32) - 1 and scan.frame_counter[600] == 0
    whole = line_mismatch(encoder, first + np.arange(count), stages=m, counts_per_pixel=per_pixel)
    assert np.array_equal(scan.m_dv_over_v, whole.astype(np.float32), equal_nan=True)
    assert np.isnan(scan.m_dv_over_v[0])
    assert scan.m_dv_over_v[1:4] == pytest.approx([-0.1, -0.2, -0.3])  # fewer periods so far
    assert scan.m_dv_over_v[m:] == pytest.approx(np.full(count - m, -0.4))
    progress = pipeline.progress()
    assert progress.mismatch_max == pytest.approx(0.4)
    # Over the complete lines: line 3 spans the 3 periods since the first frame, -0.3.
    assert progress.mismatch_rms == pytest.approx(
        np.sqrt((0.3**2 + (count - m) * 0.4**2) / (count - m + 1))
    )
    assert progress.mismatch_last == pytest.approx(0.4)
    assert progress.mismatch_level == "yellow"
    assert pipeline.counts_per_pixel == per_pixel
    # One event, on the change from ok to yellow; never red.
    assert calls.events == [
        ("warning", "motion", "scan velocity mismatch yellow: M |dV/V| up to 0.4 pixels "
         "(limits 0.3 / 2)"),
    ]  # fmt: skip
    assert calls.reds == 0


def test_red_is_reported_once_and_the_tracker_grades_each_batch() -> None:
    changes: list[tuple[str, str]] = []
    tracker = MismatchTracker(
        10.0, yellow_px=0.1, red_px=0.3, on_level=lambda *c: changes.append(c)
    )
    counters = np.arange(8, dtype=np.uint32)
    complete = np.ones(8, dtype=bool)
    fast = tracker.add(counters, 11 * np.arange(8), complete, stages=4)  # 10 % fast: red
    assert fast.red and tracker.level == "red" and tracker.now == "red"
    assert [level for level, _ in changes] == ["red"]
    # Synchronous from frame 8 on: the first lines still reach back into the fast frames
    # carried over from the batch before; only the lines after them count here.
    settled = np.arange(8) >= 4
    calm = tracker.add(counters + 8, 88 + 10 * np.arange(8), settled, stages=4)
    assert calm.values[:4] == pytest.approx([-0.4, -0.3, -0.2, -0.1])
    assert calm.values[4:] == pytest.approx(np.zeros(4))
    assert not calm.red and tracker.now == "ok" and tracker.level == "red"
    assert [level for level, _ in changes] == ["red", "ok"]
    assert tracker.max == pytest.approx(0.4) and tracker.last == pytest.approx(0.0)


def test_the_pipeline_calls_on_red_once(tmp_path: Path) -> None:
    frames = shifted_ramp(30)
    pipeline, calls = make(tmp_path, 4, counts_per_pixel=10.0, yellow_px=0.1, red_px=0.3)
    for k in range(30):
        pipeline.consumer(received(frames[k], k, encoder=11 * k, index=k))
        if k % 7 == 0:
            pipeline.consumer.flush()  # several batches, each red
    run_out(pipeline)
    assert calls.reds == 1
    assert ("error", "motion") in {(level, source) for level, source, _ in calls.events}
    assert pipeline.progress().mismatch_level == "red"


class FullDisk(TdiRecorder):
    """A recorder whose disk is full."""

    def append(self, *args: Any, **kwargs: Any) -> None:
        raise OSError(28, "No space left on device")


def test_a_failing_worker_calls_on_failure_sets_the_error_and_drains(tmp_path: Path) -> None:
    frames = shifted_ramp(30)
    pipeline, calls = make(tmp_path, 4, recorder_type=FullDisk)
    for k in range(10):
        pipeline.consumer(received(frames[k], k, index=k))
    pipeline.consumer.flush()
    assert calls.failed.wait(WAIT_S)
    assert pipeline.failed
    assert pipeline.error == "TDI worker: [Errno 28] No space left on device"
    assert calls.events == [
        ("error", "scan", "scan failed: [Errno 28] No space left on device; stopping the stream")
    ]
    # The stream goes on until stopped: the rest is drained unused, the buffers handed back.
    for k in range(10, 30):
        pipeline.consumer(received(frames[k], k, index=k))
    assert pipeline.finish(timeout_s=WAIT_S)
    assert not pipeline.running
    progress = pipeline.progress()
    assert (progress.lines, progress.frames_batched, progress.dropped_frames) == (0, 30, 0)
    pipeline.recorder.close()
    assert read_tdi_scan(pipeline.recorder.path).lines.shape == (0, COLS)
    assert len(calls.events) == 1


def test_an_aborted_pipeline_writes_nothing_queued(tmp_path: Path) -> None:
    frames = shifted_ramp(5)
    pipeline, calls = make(tmp_path, 4)
    for k in range(5):
        pipeline.consumer(received(frames[k], k, index=k))
    assert pipeline.abort(WAIT_S)  # without a flush: the partial batch is dropped
    assert pipeline.failed and pipeline.error is None and not calls.failed.is_set()
    assert not pipeline.running
    pipeline.recorder.close()
    written = read_tdi_scan(pipeline.recorder.path).lines.shape[0]
    assert written == pipeline.progress().lines < 5


def test_the_batcher_sends_frames_and_markers_in_stream_order(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(batcher_module, "BATCH_MAX_AGE_S", float("inf"))  # cut by content only
    work: queue.Queue[Message] = queue.Queue()
    batcher = Batcher(4, COLS, work)
    frames = shifted_ramp(10, rows=6)
    for k in (0, 1, 2):
        batcher(received(frames[k], k, encoder=10 * k))
    batcher(received(frames[5], 5, encoder=50, gap_before=2))
    batcher.request_stages(2)
    assert batcher.pending_stages == 2
    batcher(received(frames[6], 6, encoder=60))
    batcher.flush()
    messages = [work.get_nowait() for _ in range(work.qsize())]
    assert [type(m) for m in messages] == [Batch, Gap, Batch, StageChange, Batch]
    first, gap, second, change, third = messages
    assert isinstance(first, Batch) and isinstance(second, Batch) and isinstance(third, Batch)
    assert np.array_equal(first.frames, frames[:3, :4])  # the engine's rows only
    assert first.counters.tolist() == [0, 1, 2] and first.encoder.tolist() == [0, 10, 20]
    assert gap == Gap(2) and change == StageChange(2)
    assert second.counters.tolist() == [5] and third.counters.tolist() == [6]
    assert batcher.pending_stages is None and batcher.frames == 5 and batcher.dropped == 0


@pytest.mark.parametrize(
    "layout", ["as the stream gives them", "Fortran order", "big-endian", "int32", "large"]
)
def test_the_batcher_copies_every_layout_of_frame_exactly(
    monkeypatch: pytest.MonkeyPatch, layout: str
) -> None:
    # Small frames are copied as bytes (the GIL kept), others by numpy: both must give the
    # engine's rows of each frame, whatever the frame's memory layout or type.
    monkeypatch.setattr(batcher_module, "BATCH_MAX_AGE_S", float("inf"))
    cols = 40_000 if layout == "large" else COLS  # 4 rows x 40,000: 320 kB, over 64 KiB
    frames = shifted_ramp(5, rows=6, cols=cols)
    work: queue.Queue[Message] = queue.Queue()
    batcher = Batcher(4, cols, work)
    for k, frame in enumerate(frames):
        given: npt.NDArray[Any] = frame
        if layout == "Fortran order":
            given = np.asfortranarray(frame)
        elif layout == "big-endian":
            given = frame.astype(">u2")
        elif layout == "int32":
            given = frame.astype(np.int32)
        batcher(received(given, k))
    batcher.flush()
    batch = work.get_nowait()
    assert isinstance(batch, Batch) and batch.n == 5
    assert batch.frames.dtype == np.uint16 and np.array_equal(batch.frames, frames[:, :4])


def packed_batch(
    frames: npt.NDArray[np.uint16], first: int, *, gap_before: int = 0, index: int = 0
) -> tuple[FrameBatch, list[ReceivedFrame]]:
    """``frames`` as a packed transfer delivers them (one ``FrameBatch`` over the wire bytes,
    counters from ``first``, encoder counts 10 per counter), and the same frames one by one."""
    stride = HEADER_BYTES + frames[0].nbytes
    singles = [
        received(frame, first + k, encoder=10 * (first + k), gap_before=gap_before if k == 0
                 else 0, index=index + k)
        for k, frame in enumerate(frames)
    ]  # fmt: skip
    wire = bytearray(b"".join(encode_header(f.header) + f.pixels.tobytes() for f in singles))
    run = Run(0, stride, len(frames), header_fields(wire, 0, stride, len(frames)))
    batch = FrameBatch(run_pixels(wire, run, 0, len(frames)), run.fields, 0, gap_before, index)
    return batch, singles


def test_the_batcher_takes_a_run_of_frames_as_it_takes_them_one_by_one(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # Runs crossing batch boundaries, a gap before a run, a change of M and a frame of the
    # wrong geometry: the same messages, in the same order, with the same contents.
    monkeypatch.setattr(batcher_module, "BATCH_MAX_AGE_S", float("inf"))
    monkeypatch.setattr(batcher_module, "MAX_BATCH_FRAMES", 5)
    monkeypatch.setattr(batcher_module, "BATCH_BUFFERS", 16)  # no worker hands them back
    frames = shifted_ramp(30, rows=6)
    narrow = shifted_ramp(2, rows=3)  # fewer rows than the engine needs: dropped, a gap each
    runs = [
        packed_batch(frames[0:7], 0),
        packed_batch(frames[9:12], 9, gap_before=2, index=7),
        packed_batch(narrow, 12, index=10),
        packed_batch(frames[14:30], 14, index=12),
    ]
    messages: dict[str, list[Message]] = {}
    for how in ("batches", "frames"):
        work: queue.Queue[Message] = queue.Queue()
        batcher = Batcher(4, COLS, work)
        for k, (batch, singles) in enumerate(runs):
            if k == 3:
                batcher.request_stages(2)
            if how == "batches":
                batcher.on_batch(batch)
            else:
                for frame in singles:
                    batcher(frame)
        batcher.flush()
        messages[how] = [work.get_nowait() for _ in range(work.qsize())]
        assert (batcher.frames, batcher.dropped) == (26, 2)
    by_batch, by_frame = messages["batches"], messages["frames"]
    assert [type(m) for m in by_batch] == [type(m) for m in by_frame]
    assert StageChange(2) in by_batch and Gap(2) in by_batch and by_batch.count(Gap(1)) == 2
    for a, b in zip(by_batch, by_frame, strict=True):
        if isinstance(a, Batch):
            assert isinstance(b, Batch)
            assert np.array_equal(a.frames, b.frames)
            assert a.counters.tolist() == b.counters.tolist()
            assert a.encoder.tolist() == b.encoder.tolist()
        else:
            assert a == b


class Clock:
    """A clock that says what the test sets."""

    now = 0.0

    def __call__(self) -> float:
        return self.now


def test_the_live_tap_and_the_background_take_runs_of_frames_as_frames_one_by_one() -> None:
    # A clock read once per run: the tap keeps what a call per frame at that time would keep;
    # the background averages the same frames to the same mean.
    frames = shifted_ramp(12, rows=6)
    runs = [
        packed_batch(frames[0:5], 0),
        packed_batch(frames[5:8], 5, index=5),
        packed_batch(frames[9:12], 9, gap_before=1, index=8),
    ]
    times = [0.0, 0.01, 0.2]  # a frame due, none due, one due again (20 a second at most)
    seen: dict[str, list[tuple[object, ...]]] = {}
    means: dict[str, npt.NDArray[np.float32]] = {}
    for how in ("batches", "frames"):
        clock = Clock()
        tap = LiveTap(clock=clock)
        capture = BackgroundCapture()
        capture.start(10)
        kept: list[tuple[object, ...]] = []
        for (batch, singles), t in zip(runs, times, strict=True):
            clock.now = t
            if how == "batches":
                tap.on_batch(batch)
                capture.on_batch(batch)
            else:
                for frame in singles:
                    tap(frame)
                    capture(frame)
            latest = tap.latest()
            assert latest is not None
            kept.append((latest.seq, latest.index, latest.counter, latest.skipped,
                         latest.gap_before, tap.seen, tap.kept))  # fmt: skip
        seen[how] = kept
        background = capture.ready()
        assert background is not None and background.frames == 10
        assert (background.first_counter, background.last_counter) == (0, 10)
        means[how] = background.pixels
    assert seen["batches"] == seen["frames"]
    assert seen["frames"][-1] == (2, 9, 9, 7, 1, 11, 2)
    assert np.array_equal(means["batches"], means["frames"])


FORBIDDEN = ("camd.daemon", "camd.motion", "camd.sensor", "camd.cli", "camd.bench", "camd.soak",
             "camd.campaign", "camd.client")  # fmt: skip


@pytest.mark.parametrize("path", sorted((ROOT / "camd" / "pipeline").glob("*.py")), ids=str)
def test_the_pipeline_imports_nothing_above_it_nor_devices(path: Path) -> None:
    """Below the daemon: link, store, tdi, timing and numpy only (the layer contract alone
    would let it import motion and sensor)."""
    imported: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            imported |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module:
            imported.add(node.module)
    bad = sorted(m for m in imported if m.startswith(FORBIDDEN))
    assert not bad, f"{path.name} imports {', '.join(bad)}"
