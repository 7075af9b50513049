"""ROI statistics in process: the pure layer (camd.analysis.roi) against plain numpy, its
refusals word for word, and the monitor (camd.pipeline.roi) on frames and packed batches."""

from __future__ import annotations

import math
from pathlib import Path

import h5py
import numpy as np
import pytest

from camd.analysis.roi import STAT_FIELDS, Roi, background_means, roi_stats, rois_problem
from camd.link.frame_stream import ReceivedFrame
from camd.pipeline.roi import RoiMonitor
from camd.protocol.stream import FrameFlags, FrameHeader, StreamMode

ROWS, COLS = 24, 40


def _frames(k: int, seed: int = 1) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.integers(0, 4096, size=(k, ROWS, COLS), dtype=np.uint16)


def _header(counter: int, bits: int = 12) -> FrameHeader:
    return FrameHeader(
        counter=counter,
        timestamp_ns=1000 * counter,
        line_period_ns=0,
        rows=ROWS,
        cols=COLS,
        bits=bits,
        mode=StreamMode.AREA,
        stages=1,
        stage_position=0,
        flags=FrameFlags(0),
        payload_bytes=ROWS * COLS * 2,
        payload_crc32=0,
    )


def test_stats_equal_plain_numpy_per_frame() -> None:
    frames = _frames(5)
    frames[2, 3:5, 4:6] = 4095  # 4 saturated pixels in ROI "a" of frame 2
    rois = [Roi("a", 2, 1, 10, 6), Roi("b", 0, 0, COLS, ROWS), Roi("c", 39, 23, 1, 1)]
    stats = roi_stats(frames, rois, bits=12)
    assert stats.shape == (5, 3, len(STAT_FIELDS))
    for k in range(5):
        for i, r in enumerate(rois):
            sub = frames[k, r.y : r.y + r.height, r.x : r.x + r.width].astype(np.float64)
            got = dict(zip(STAT_FIELDS, stats[k, i], strict=True))
            assert got["mean_dn"] == pytest.approx(sub.mean(), rel=1e-12)
            assert got["std_dn"] == pytest.approx(sub.std(), rel=1e-12, abs=1e-12)
            assert got["min_dn"] == sub.min() and got["max_dn"] == sub.max()
            assert got["sum_dn"] == sub.sum()
            assert got["saturated"] == np.count_nonzero(sub >= 4095)
            assert math.isnan(got["bg_mean_dn"])
            if r.name == "c":  # one pixel: std 0, no SNR
                assert math.isnan(got["snr"])
            else:
                assert got["snr"] == pytest.approx(sub.mean() / sub.std(), rel=1e-12)
    assert stats[2, 0, STAT_FIELDS.index("saturated")] >= 4


def test_background_subtracted_mean() -> None:
    frames = _frames(2)
    background = np.full((ROWS, COLS), 100.0, dtype=np.float32)
    background[:, :20] = 10.0
    rois = [Roi("left", 0, 0, 10, 10), Roi("across", 15, 0, 10, 10)]
    stats = roi_stats(frames, rois, 12, background_means(background, rois))
    mean, sub = STAT_FIELDS.index("mean_dn"), STAT_FIELDS.index("bg_mean_dn")
    assert stats[:, 0, sub] == pytest.approx(stats[:, 0, mean] - 10.0)
    assert stats[:, 1, sub] == pytest.approx(stats[:, 1, mean] - 55.0)


@pytest.mark.parametrize(
    ("rois", "message"),
    [
        (
            [Roi("a b", 0, 0, 1, 1)],
            "ROI name 'a b' is not valid: use 1-32 letters, digits, '_', '.' or '-'",
        ),
        (
            [Roi("frame", 0, 0, 1, 1)],
            "ROI name 'frame' names the whole frame (the focus aid's target): choose another",
        ),
        (
            [Roi("a", 0, 0, 0, 3)],
            "ROI 'a' is 0 x 3 pixels: width and height must be at least 1",
        ),
        ([Roi("a", -1, 0, 2, 2)], "ROI 'a' starts at x=-1, y=0: x and y must be 0 or more"),
        (
            [Roi("a", 30, 20, 11, 2)],
            "ROI 'a' (x=30, y=20, 11 x 2) reaches column 40, row 21, outside the 40 x 24 frame "
            "(columns 0..39, rows 0..23): make it smaller or move it",
        ),
        (
            [Roi("a", 0, 0, 1, 1), Roi("a", 1, 1, 1, 1)],
            "ROI 'a' is defined twice: give each ROI its own name",
        ),
        (
            [Roi(f"r{i}", 0, 0, 1, 1) for i in range(17)],
            "17 ROIs: at most 16 are measured at once; delete some first",
        ),
    ],
)
def test_bad_rois_refused_with_what_to_change(rois: list[Roi], message: str) -> None:
    assert rois_problem(rois, ROWS, COLS) == message
    monitor = RoiMonitor()
    with pytest.raises(ValueError, match="^" + __import__("re").escape(message) + "$"):
        monitor.set_rois(rois, ROWS, COLS)
    assert monitor.rois == ()


def test_monitor_measures_every_frame_and_keeps_a_bounded_history() -> None:
    frames = _frames(30, seed=7)
    monitor = RoiMonitor(history_max=20)
    monitor(ReceivedFrame(_header(0), frames[0], 0, 0, 0))  # no ROIs: nothing measured
    assert monitor.history().measured == 0
    rois = [Roi("dark", 0, 0, 8, 8), Roi("bar", 10, 4, 20, 3)]
    monitor.set_rois(rois, ROWS, COLS)
    for k in range(30):
        monitor(ReceivedFrame(_header(100 + k), frames[k], 0, 0, k))
    history = monitor.history()
    assert history.measured == 30 and history.unfit == 0
    assert history.counter.tolist() == list(range(110, 130))  # the newest 20
    expected = roi_stats(frames[10:], rois, 12)
    np.testing.assert_array_equal(history.stats, expected)
    bar = history.roi("bar")
    assert bar["counter"] == list(range(110, 130))
    assert bar["mean_dn"] == expected[:, 1, 0].tolist()
    latest = history.latest()
    assert latest is not None and latest["counter"] == 129
    assert latest["rois"]["dark"]["max_dn"] == float(frames[29, :8, :8].max())
    # A frame the ROIs do not fit (a smaller window) is counted, not measured.
    small = frames[0, :4, :4]
    monitor(ReceivedFrame(_header(200)._replace(rows=4, cols=4), small, 0, 0, 30))
    assert monitor.history().unfit == 1 and monitor.history().measured == 30


def test_a_recordings_log_keeps_its_frames_stops_at_a_change_and_writes_the_group(
    tmp_path: Path,
) -> None:
    frames = _frames(12, seed=3)
    monitor = RoiMonitor()
    assert monitor.start_log() is None  # no ROIs: nothing to log
    rois = [Roi("a", 0, 0, 5, 5), Roi("b", 6, 2, 3, 4)]
    monitor.set_rois(rois, ROWS, COLS)
    log = monitor.start_log()
    assert log is not None
    log.frames_max = 8  # its bound: the frames past it are counted, not kept
    for k in range(10):
        monitor(ReceivedFrame(_header(50 + k), frames[k], 0, 0, k))
    assert (log.frames, log.frames_dropped) == (8, 2)
    monitor.set_rois([Roi("c", 0, 0, 1, 1)], ROWS, COLS)  # the ROIs change: the log ends
    monitor(ReceivedFrame(_header(60), frames[10], 0, 0, 10))
    assert not log.active and log.rois_changed_at == 59 and log.frames == 8
    path = tmp_path / "r.h5"
    with h5py.File(path, "w") as f:
        log.write_into(f)
    expected = roi_stats(frames[:8], rois, 12)
    with h5py.File(path, "r") as f:
        group = f["roi"]
        assert dict(group.attrs) | {"fields": list(group.attrs["fields"])} == {
            "fields": list(STAT_FIELDS),
            "frames": 8,
            "frames_dropped": 2,
            "rois_changed_at": 59,
        }
        assert group["frame_counter"][()].tolist() == list(range(50, 58))
        assert dict(group["b"].attrs) == {"x": 6, "y": 2, "width": 3, "height": 4}
        for j, field in enumerate(STAT_FIELDS):
            np.testing.assert_array_equal(group["b"][field][()], expected[:, 1, j])


def test_a_recording_keeps_its_roi_group_written_as_it_finishes_and_survives_its_failure(
    tmp_path: Path,
) -> None:
    # The /roi group goes in while the recording finishes (before the journal calls it
    # closed); a group that cannot be written (HDF5 refuses a second /roi) loses itself, not
    # the frames: the recording is finished and readable, and finish_error says why.
    from camd.store import read_recording
    from camd.store.recording import FrameRecorder

    frames = _frames(4)
    rois = [Roi("a", 0, 0, 5, 5)]
    monitor = RoiMonitor()
    monitor.set_rois(rois, ROWS, COLS)
    log = monitor.start_log()
    assert log is not None
    for k in range(4):
        monitor(ReceivedFrame(_header(k), frames[k], 0, 0, k))
    monitor.stop_log(log)

    def twice(f: h5py.File) -> None:
        log.write_into(f)
        log.write_into(f)

    errors = []
    for name, add in (("kept.h5", log.write_into), ("twice.h5", twice)):
        recorder = FrameRecorder(tmp_path / name, flush_period_s=0.0)
        for k in range(4):
            recorder.add(_header(k), frames[k], received_ns=k)
        recorder.close({}, finish_with=add)
        errors.append(recorder.finish_error)
        recording = read_recording(tmp_path / name)
        assert recording.frames.shape[0] == 4 and recording.attrs["finished"]
        with h5py.File(tmp_path / name, "r") as f:  # the first write of the two is whole
            means = f["roi/a/mean_dn"][()].tolist()
        assert means == roi_stats(frames, rois, 12)[:, 0, 0].tolist()
    assert errors[0] is None
    assert errors[1] is not None and "name already exists" in errors[1]
