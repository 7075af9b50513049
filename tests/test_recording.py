"""HDF5 recordings: frames bit-exact, per-frame header values and metadata read back."""

from __future__ import annotations

import zlib
from pathlib import Path

import h5py
import numpy as np
import pytest

from camd.protocol.stream import FrameFlags, StreamMode, frame_header
from camd.store import FrameRecorder, RecordingError, read_recording
from camd.store.recording_reading import file_format, read_recording_info

ROWS, COLS = 6, 10


def _frames(n: int, seed: int = 0) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    # The full 16-bit range: any bit lost on the way shows.
    return [rng.integers(0, 1 << 16, size=(ROWS, COLS), dtype=np.uint16) for _ in range(n)]


def _record(path: Path, frames: list[np.ndarray], **kwargs: object) -> None:
    metadata = {
        "profile": {"name": "hr400", "array": {"columns": 2048, "pitch_m": 11e-6}},
        "registers": {"WIN_START": 757, "WIN_ROWS": 534},
        "timing": {"line_period_s": 20.52e-6, "gain": "x2", "test_pattern": None},
        "stream": {"binning": "off"},
    }
    with FrameRecorder(
        path,
        rows=ROWS,
        cols=COLS,
        bits=12,
        mode=StreamMode.AREA,
        line_period_s=0.011,
        metadata=metadata,
        frames_expected=len(frames),
        **kwargs,  # type: ignore[arg-type]
    ) as rec:
        for i, pixels in enumerate(frames):
            header = frame_header(
                pixels,
                counter=100 + 2 * i,
                timestamp_ns=1_000_000 * i,
                line_period_ns=11_000_000,
                bits=12,
                mode=StreamMode.AREA,
                stage_position=-5 * i,
                flags=FrameFlags.SATURATED if i == 1 else FrameFlags(0),
            )
            rec.add(header, pixels, received_ns=2_000 + i, gap_before=1 if i else 0)


def test_frames_and_headers_read_back_bit_exactly(tmp_path: Path) -> None:
    frames = _frames(5)
    path = tmp_path / "stare.h5"
    _record(path, frames)
    rec = read_recording(path)
    assert rec.frames.dtype == np.uint16 and rec.frames.shape == (5, ROWS, COLS)
    assert np.array_equal(rec.frames, np.stack(frames))
    assert rec.columns["frame_counter"].tolist() == [100, 102, 104, 106, 108]
    assert rec.columns["timestamp_ns"].tolist() == [0, 1_000_000, 2_000_000, 3_000_000, 4_000_000]
    assert rec.columns["stage_position"].tolist() == [0, -5, -10, -15, -20]
    assert rec.columns["flags"].tolist() == [0, int(FrameFlags.SATURATED), 0, 0, 0]
    assert rec.columns["gap_before"].tolist() == [0, 1, 1, 1, 1]
    assert rec.columns["payload_crc32"].tolist() == [
        zlib.crc32(f.astype("<u2").tobytes()) for f in frames
    ]
    assert rec.crc_mismatches() == []
    # Host receive times are monotonic ns shifted onto the Unix epoch: consecutive, in 2026.
    received = rec.columns["received_unix_ns"]
    assert np.diff(received.astype(np.int64)).tolist() == [1, 1, 1, 1]
    assert 1.7e18 < received[0] < 2.2e18


def test_metadata_round_trips(tmp_path: Path) -> None:
    path = tmp_path / "stare.h5"
    _record(path, _frames(2))
    rec = read_recording(path)
    assert rec.attrs["format"] == "camd-recording" and rec.attrs["format_version"] == 4
    assert rec.attrs["mode"] == "area" and rec.attrs["bits"] == 12
    assert rec.attrs["frames"] == 2 and rec.attrs["frames_expected"] == 2
    assert rec.attrs["line_period_s"] == pytest.approx(0.011)
    assert rec.metadata["profile"] == {
        "name": "hr400",
        "array": {"columns": 2048, "pitch_m": 11e-6},
    }
    assert rec.metadata["registers"] == {"WIN_START": 757, "WIN_ROWS": 534}
    # None is not stored; everything else is.
    assert rec.metadata["timing"] == {"line_period_s": 20.52e-6, "gain": "x2"}


def test_the_info_is_the_readers_metadata_and_count_without_the_frames(tmp_path: Path) -> None:
    path = tmp_path / "stare.h5"
    _record(path, _frames(3))
    rec, info = read_recording(path), read_recording_info(path)
    assert (info.path, info.frames, info.attrs, info.metadata) == (
        path, 3, rec.attrs, rec.metadata)  # fmt: skip
    assert file_format(path) == "camd-recording"
    with pytest.raises(RecordingError, match="is not a camd recording"):
        read_recording_info(_plain_hdf5(tmp_path / "other.h5"))


def _plain_hdf5(path: Path) -> Path:
    with h5py.File(path, "w") as f:
        f["x"] = np.arange(3)
    return path


def test_a_corrupted_file_is_caught_by_the_device_crc(tmp_path: Path) -> None:
    path = tmp_path / "stare.h5"
    _record(path, _frames(3))
    with h5py.File(path, "r+") as f:
        f["frames"][1, 2, 3] ^= 1
    assert read_recording(path).crc_mismatches() == [1]


def test_recorder_refuses_to_overwrite_and_to_change_shape(tmp_path: Path) -> None:
    path = tmp_path / "stare.h5"
    path.write_bytes(b"precious")
    with pytest.raises(RecordingError, match="already exists; choose another --out"):
        FrameRecorder(path, rows=2, cols=2, bits=12, mode="area", line_period_s=1.0)
    assert path.read_bytes() == b"precious"
    other = tmp_path / "new.h5"
    rec = FrameRecorder(other, rows=2, cols=2, bits=12, mode="area", line_period_s=1.0)
    pixels = np.zeros((3, 2), dtype=np.uint16)
    header = frame_header(
        pixels, counter=0, timestamp_ns=0, line_period_ns=1, bits=12, mode=StreamMode.AREA
    )
    with pytest.raises(RecordingError, match="the window changed mid-recording"):
        rec.add(header, pixels, received_ns=0)
    assert rec.close() == other
    assert read_recording(other).frames.shape == (0, 2, 2)


def test_reading_something_else_says_so(tmp_path: Path) -> None:
    junk = tmp_path / "junk.h5"
    junk.write_bytes(b"not hdf5")
    with pytest.raises(RecordingError, match=r"cannot open .* as HDF5"):
        read_recording(junk)
    plain = tmp_path / "plain.h5"
    with h5py.File(plain, "w") as f:
        f["x"] = 1
    with pytest.raises(RecordingError, match="is not a camd recording"):
        read_recording(plain)
