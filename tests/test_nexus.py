"""The NeXus entry of scan and recording files (camd.store.nexus; docs/scan.md and
docs/stream.md, "NeXus"): what nexusformat finds, the names it reserves, and files of the
formats before it, which read as they did."""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np
import pytest

from camd.protocol.stream import FrameFlags, FrameHeader, StreamMode, crc32
from camd.store.recording import FrameRecorder, read_recording
from camd.store.tdi_recording import TdiRecorder, read_tdi_scan
from tests.nexus_support import nexus_plot

PROFILE = {
    "profile": "hr400",
    "sensor": "hr400",
    "description": "HR400 2048 x 2048 sCMOS",
    "pitch_m": {"value": 11e-6, "source": "YE23"},
    "output_bits": {"value": 12, "source": "YE23"},
}


def scan_file(path: Path, lines: int = 20, width: int = 24) -> np.ndarray:
    data = np.arange(lines * width, dtype=np.uint32).reshape(lines, width)
    r = TdiRecorder(
        path,
        width=width,
        mode="sum",
        metadata={
            "profile": PROFILE,
            "timing": {"tdi_line_period_s": 250e-6, "exposure_s": 240e-6, "n_lines": 6},
            "scan": {"stages": 4},
        },
    )
    r.append(data, index=np.arange(lines), stages_used=np.full(lines, 4),
             complete=np.ones(lines, bool))  # fmt: skip
    r.close()
    return data


def header(counter: int, pixels: np.ndarray) -> FrameHeader:
    rows, cols = pixels.shape
    return FrameHeader(counter, 1000 * counter, 1000, rows, cols, 12, StreamMode.AREA, 0, 0,
                       FrameFlags(0), pixels.nbytes, crc32(pixels.tobytes()))  # fmt: skip


def test_a_scan_is_an_image_against_line_index_and_column(tmp_path: Path) -> None:
    data = scan_file(tmp_path / "scan.h5")
    p = nexus_plot(tmp_path / "scan.h5")
    assert (p["signal"], p["shape"]) == ("lines", (20, 24))
    assert p["axes"] == [("line_index", (20,)), ("column", (24,))]
    assert np.array_equal(p["signal_values"], data)
    assert p["axis_values"][1].tolist() == list(range(24))
    assert p["detector"] == {
        "description": ("HR400 2048 x 2048 sCMOS", None),
        "local_name": ("hr400", None),
        "x_pixel_size": (11e-6, "m"),
        "y_pixel_size": (11e-6, "m"),
        "bit_depth_readout": (12, None),
        "frame_time": (250e-6, "s"),
        "count_time": (240e-6, "s"),
        "tdi_stages": (4, None),
        "tdi_mode": ("sum", None),
        "tdi_window_rows": (6, None),
    }
    with h5py.File(tmp_path / "scan.h5", "r") as f:
        # Hard links: the NeXus signal is the root's dataset, stored once.
        assert f["entry/data/lines"].id == f["lines"].id
        assert f.attrs["format_version"] == 4
    # The reader's metadata are camd's groups, not the NeXus entry.
    assert "entry" not in read_tdi_scan(tmp_path / "scan.h5").metadata


def test_a_recording_is_images_against_frame_counter_row_and_column(tmp_path: Path) -> None:
    rng = np.random.default_rng(1)
    frames = rng.integers(0, 4096, (5, 3, 7), dtype=np.uint16)
    rec = FrameRecorder(tmp_path / "rec.h5", metadata={"profile": PROFILE}, frames_expected=8)
    for k, px in enumerate(frames):
        rec.add(header(100 + k, px), px, received_ns=k)
    rec.close()
    p = nexus_plot(tmp_path / "rec.h5")
    assert (p["signal"], p["shape"]) == ("frames", (5, 3, 7))  # trimmed from the 8 reserved
    assert p["axes"] == [("frame_counter", (5,)), ("row", (3,)), ("column", (7,))]
    assert np.array_equal(p["signal_values"], frames)
    assert p["axis_values"][0].tolist() == [100, 101, 102, 103, 104]
    assert p["detector"]["bit_depth_readout"] == (12, None)
    assert p["detector"]["frame_time"] == (pytest.approx(1e-6, rel=1e-12), "s")  # 1000 ns
    assert p["title"] == "frames, hr400, 3 x 7, area mode"


def test_a_recording_without_frames_has_an_empty_image(tmp_path: Path) -> None:
    FrameRecorder(tmp_path / "empty.h5", metadata={"profile": PROFILE}).close()
    p = nexus_plot(tmp_path / "empty.h5")
    assert (p["signal"], p["shape"]) == ("frames", (0, 0, 0))
    assert p["axes"] == [("frame_counter", (0,)), ("row", (0,)), ("column", (0,))]


def test_files_of_the_formats_before_nexus_read_as_they_did(tmp_path: Path) -> None:
    data = scan_file(tmp_path / "scan.h5")
    frames = np.arange(2 * 3 * 4, dtype=np.uint16).reshape(2, 3, 4)
    rec = FrameRecorder(tmp_path / "rec.h5", metadata={"profile": PROFILE})
    for k, px in enumerate(frames):
        rec.add(header(k, px), px, received_ns=k)
    rec.close()
    # Made as the formats before (scan 3, recording 2) made them: no entry, no NeXus attributes.
    for name, version in (("scan.h5", 3), ("rec.h5", 2)):
        with h5py.File(tmp_path / name, "r+") as f:
            del f["entry"]
            del f.attrs["NX_class"], f.attrs["default"]
            f.attrs["format_version"] = version
    scan = read_tdi_scan(tmp_path / "scan.h5")
    assert np.array_equal(scan.lines, data) and scan.attrs["format_version"] == 3
    assert np.array_equal(read_recording(tmp_path / "rec.h5").frames, frames)


def test_the_entry_is_not_a_metadata_group_nor_its_attributes_close_attributes(
    tmp_path: Path,
) -> None:
    with pytest.raises(ValueError, match="nor the NeXus entry \\('entry'\\)"):
        TdiRecorder(tmp_path / "a.h5", width=4, mode="sum", metadata={"entry": {"x": 1}})
    r = TdiRecorder(tmp_path / "b.h5", width=4, mode="sum", metadata={})
    with pytest.raises(ValueError, match="cannot set the root attribute 'default'"):
        r.close({"default": "elsewhere"})
