"""TDI scans in HDF5 (real files): lines and bookkeeping round-trip, live reading, quicklooks."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import cv2
import h5py
import numpy as np
import pytest

from camd.store import FrameRecorder, RecordingError
from camd.store.quicklook import write_quicklook_png
from camd.store.tdi_reading import read_tdi_scan_info
from camd.store.tdi_recording import TdiRecorder, read_tdi_scan

REPO_ROOT = Path(__file__).resolve().parents[1]
WIDTH = 12
META: dict[str, dict[str, Any]] = {
    "profile": {"name": "hr400", "array": {"columns": 2048, "pitch_m": 11e-6}},
    "registers": {"WIN_START": 757, "WIN_ROWS": 534},
    "timing": {"line_period_s": 20.52e-6, "gain": "x2", "test_pattern": None},
    "scan": {"stages": 8, "reverse": False, "bands": ["pan", "red"], "rows_per_line": 1.0},
}


class Block:
    """What a TdiBlock carries (docs/tdi.md "Results"), made up for the store."""

    def __init__(self, mode: str, start: int, n: int, stages: int = 4, seed: int = 0) -> None:
        rng = np.random.default_rng(seed + start)
        if mode == "sum":
            # The full 32-bit range: any bit lost on the way shows.
            self.data: np.ndarray = rng.integers(0, 1 << 32, size=(n, WIDTH), dtype=np.uint32)
        else:
            self.data = (rng.random((n, WIDTH)) * 4095.0).astype(np.float32)
        self.index = np.arange(start, start + n, dtype=np.int64)
        self.stages_used = np.minimum(self.index + 1, stages).astype(np.int32)
        self.complete = self.stages_used == stages

    def __getitem__(self, s: slice) -> Block:
        part = object.__new__(Block)
        part.data, part.index = self.data[s], self.index[s]
        part.stages_used, part.complete = self.stages_used[s], self.complete[s]
        return part

    def append_to(self, rec: TdiRecorder, **kwargs: Any) -> None:
        rec.append(
            self.data,
            index=self.index,
            stages_used=self.stages_used,
            complete=self.complete,
            **kwargs,
        )


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(REPO_ROOT), env.get("PYTHONPATH")) if p)
    return env


READER = """
import json, sys
from camd.store.tdi_recording import read_tdi_scan
scan = read_tdi_scan(sys.argv[1])
print(json.dumps({"lines": int(scan.lines.shape[0]), "sum": int(scan.lines.sum(dtype="u8")),
                  "index": scan.line_index.tolist(), "finished": bool(scan.attrs["finished"]),
                  "stage_changes": scan.stage_changes.tolist()}))
"""


def _read_in_another_process(path: Path) -> dict[str, Any]:
    out = subprocess.run(
        [sys.executable, "-c", READER, str(path)],
        env=_env(),
        capture_output=True,
        text=True,
        timeout=60,
        check=True,
    )
    result: dict[str, Any] = json.loads(out.stdout)
    return result


@pytest.fixture
def scan_path(tmp_path: Path) -> Iterator[Path]:
    yield tmp_path / "scan.h5"


# --- round trips -------------------------------------------------------------------------------


@pytest.mark.parametrize(("mode", "dtype"), [("sum", np.uint32), ("mean", np.float32)])
def test_lines_and_bookkeeping_read_back_exactly(scan_path: Path, mode: str, dtype: type) -> None:
    block = Block(mode, 0, 40)
    counters = np.arange(1000, 1040, dtype=np.uint32)
    with TdiRecorder(scan_path, width=WIDTH, mode=mode, metadata=META) as rec:
        block.append_to(rec, frame_counter=counters)
        assert (rec.lines, rec.complete_lines) == (40, 37)
    scan = read_tdi_scan(scan_path)
    assert scan.path == scan_path
    assert scan.lines.dtype == dtype and scan.lines.shape == (40, WIDTH)
    assert np.array_equal(scan.lines, block.data)
    assert scan.line_index.dtype == np.int64 and scan.line_index.tolist() == list(range(40))
    assert scan.frame_counter.dtype == np.uint32 and np.array_equal(scan.frame_counter, counters)
    assert scan.stages_used.dtype == np.uint16
    assert scan.stages_used.tolist() == [1, 2, 3] + [4] * 37
    assert scan.complete.dtype == np.bool_ and scan.complete.tolist() == [False] * 3 + [True] * 37
    assert scan.attrs["mode"] == mode and scan.attrs["width"] == WIDTH
    assert (scan.attrs["lines"], scan.attrs["complete_lines"]) == (40, 37)
    assert scan.attrs["finished"] is True
    # The stored types are the documented ones, for readers that are not camd.
    with h5py.File(scan_path, "r") as f:
        assert f["lines"].dtype == dtype and f["lines"].chunks == (256, WIDTH)
        assert f["lines"].maxshape == (None, WIDTH)
        assert f["complete"].dtype == np.uint8 and f["stages_used"].dtype == np.uint16


def test_frame_counter_defaults_to_the_line_index_low_32_bits(scan_path: Path) -> None:
    with TdiRecorder(scan_path, width=WIDTH, mode="sum", metadata={}) as rec:
        block = Block("sum", 0, 3)
        block.index = np.array([0, 2**32 - 1, 2**32 + 5], dtype=np.int64)
        block.append_to(rec)
    assert read_tdi_scan(scan_path).frame_counter.tolist() == [0, 2**32 - 1, 5]


@pytest.mark.parametrize("mode", ["sum", "mean"])
def test_appending_in_blocks_of_any_size_gives_the_same_file_content(
    tmp_path: Path, mode: str
) -> None:
    block = Block(mode, 0, 100, stages=6)
    whole, parts = tmp_path / "whole.h5", tmp_path / "parts.h5"
    with TdiRecorder(whole, width=WIDTH, mode=mode, metadata=META, chunk_lines=7) as rec:
        block.append_to(rec)
    with TdiRecorder(parts, width=WIDTH, mode=mode, metadata=META, chunk_lines=7) as rec:
        start = 0
        for size in (1, 0, 6, 7, 13, 2, 50, 21):  # across chunk boundaries, with an empty block
            block[start : start + size].append_to(rec)
            start += size
        assert start == 100
    a, b = read_tdi_scan(whole), read_tdi_scan(parts)
    for name in ("lines", "line_index", "frame_counter", "stages_used", "complete"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
    assert np.array_equal(b.lines, block.data)
    assert a.attrs["lines"] == b.attrs["lines"] == 100
    assert a.attrs["complete_lines"] == b.attrs["complete_lines"] == 95


def test_stage_changes_are_stored_in_order(scan_path: Path) -> None:
    with TdiRecorder(scan_path, width=WIDTH, mode="sum", metadata={}) as rec:
        rec.note_stage_change(0, 8)
        Block("sum", 0, 10, stages=8).append_to(rec)
        rec.note_stage_change(10, 16)
        rec.note_stage_change(np.int64(25), np.int32(4))  # numpy integers are integers
    scan = read_tdi_scan(scan_path)
    assert scan.stage_changes.dtype == np.int64
    assert scan.stage_changes.tolist() == [[0, 8], [10, 16], [25, 4]]


def test_no_stage_change_and_no_line_is_a_valid_empty_scan(scan_path: Path) -> None:
    TdiRecorder(scan_path, width=WIDTH, mode="mean", metadata={}).close()
    scan = read_tdi_scan(scan_path)
    assert scan.lines.shape == (0, WIDTH) and scan.lines.dtype == np.float32
    assert scan.stage_changes.shape == (0, 2)
    assert scan.attrs["lines"] == 0 and scan.attrs["finished"] is True


def test_metadata_round_trips(scan_path: Path) -> None:
    meta = {**META, "motion": {"stage_speed_m_s": 0.0125}}
    TdiRecorder(scan_path, width=WIDTH, mode="sum", metadata=meta).close()
    scan = read_tdi_scan(scan_path)
    assert scan.attrs["format"] == "camd-tdi-scan" and scan.attrs["format_version"] == 5
    assert isinstance(scan.attrs["camd_version"], str)
    assert scan.attrs["created_utc"].startswith("20")
    assert scan.metadata["profile"] == {
        "name": "hr400",
        "array": {"columns": 2048, "pitch_m": 11e-6},
    }
    assert scan.metadata["registers"] == {"WIN_START": 757, "WIN_ROWS": 534}
    # None is not stored; everything else is, lists of strings too.
    assert scan.metadata["timing"] == {"line_period_s": 20.52e-6, "gain": "x2"}
    assert scan.metadata["scan"] == {
        "stages": 8,
        "reverse": False,
        "bands": ["pan", "red"],
        "rows_per_line": 1.0,
    }
    assert scan.metadata["motion"] == {"stage_speed_m_s": 0.0125}
    assert scan.metadata["counters"] == {}
    # Flattened dotted names, so that any HDF5 viewer shows them.
    with h5py.File(scan_path, "r") as f:
        assert f["profile"].attrs["array.columns"] == 2048


def test_the_info_is_the_readers_metadata_and_count_without_the_lines(scan_path: Path) -> None:
    with TdiRecorder(scan_path, width=WIDTH, mode="sum", metadata=META) as rec:
        Block("sum", 0, 40).append_to(rec)
    scan, info = read_tdi_scan(scan_path), read_tdi_scan_info(scan_path)
    assert (info.path, info.lines, info.attrs, info.metadata) == (
        scan_path, 40, scan.attrs, scan.metadata)  # fmt: skip
    assert info.columns == ("line_index", "frame_counter", "stages_used", "complete",
                            "stage_position", "m_dv_over_v")  # fmt: skip


def test_close_writes_counters_and_extra_attributes_once(scan_path: Path) -> None:
    rec = TdiRecorder(scan_path, width=WIDTH, mode="sum", metadata=META)
    Block("sum", 0, 5).append_to(rec)
    stats = {"frames": 5, "lost": 0, "link": {"retries": 2}}
    rec.close({"counters": stats, "stop_reason": "operator", "qa": {"ok": True}})
    rec.close({"counters": {"frames": 99}})  # idempotent: the second close does nothing
    scan = read_tdi_scan(scan_path)
    assert scan.metadata["counters"] == {"frames": 5, "lost": 0, "link": {"retries": 2}}
    assert scan.metadata["qa"] == {"ok": True}
    assert scan.attrs["stop_reason"] == "operator"
    with pytest.raises(RecordingError, match="is closed; start a new TdiRecorder"):
        Block("sum", 5, 1).append_to(rec)


def test_close_refuses_to_replace_the_recorders_attributes_and_stays_open(
    scan_path: Path,
) -> None:
    rec = TdiRecorder(scan_path, width=WIDTH, mode="sum", metadata={})
    with pytest.raises(ValueError, match="cannot set the root attribute 'lines'"):
        rec.close({"lines": 3})
    Block("sum", 0, 2).append_to(rec)  # still open
    rec.close()
    assert read_tdi_scan(scan_path).attrs["lines"] == 2


# --- refusals ----------------------------------------------------------------------------------


def test_an_existing_path_or_a_missing_directory_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "scan.h5"
    path.write_bytes(b"precious")
    with pytest.raises(RecordingError, match="already exists; choose another path or remove"):
        TdiRecorder(path, width=WIDTH, mode="sum", metadata={})
    assert path.read_bytes() == b"precious"
    missing = tmp_path / "nowhere" / "scan.h5"
    with pytest.raises(RecordingError, match="does not exist; create it or choose another"):
        TdiRecorder(missing, width=WIDTH, mode="sum", metadata={})
    assert not missing.parent.exists()


def test_bad_settings_are_refused_before_a_file_exists(scan_path: Path) -> None:
    with pytest.raises(ValueError, match=r"use 'sum' .* or 'mean'"):
        TdiRecorder(scan_path, width=WIDTH, mode="median", metadata={})
    with pytest.raises(ValueError, match="width must be at least 1"):
        TdiRecorder(scan_path, width=0, mode="sum", metadata={})
    with pytest.raises(ValueError, match="chunk_lines must be at least 1"):
        TdiRecorder(scan_path, width=WIDTH, mode="sum", metadata={}, chunk_lines=0)
    with pytest.raises(ValueError, match="metadata group 'a/b' cannot be an HDF5 group"):
        TdiRecorder(scan_path, width=WIDTH, mode="sum", metadata={"a/b": {}})
    assert not scan_path.exists()
    # Metadata HDF5 cannot hold: refused, and no half-made file is left behind.
    with pytest.raises(ValueError, match=r"scan\.odd = "):
        TdiRecorder(scan_path, width=WIDTH, mode="sum", metadata={"scan": {"odd": object()}})
    assert not scan_path.exists()


def test_bad_blocks_are_refused_and_nothing_is_written(scan_path: Path) -> None:
    n = 4
    ok: dict[str, Any] = {
        "index": np.arange(n),
        "stages_used": np.full(n, 4),
        "complete": np.ones(n, dtype=bool),
    }
    with TdiRecorder(scan_path, width=WIDTH, mode="sum", metadata={}) as rec:
        lines = np.zeros((n, WIDTH), dtype=np.uint32)
        with pytest.raises(ValueError, match=rf"must be an \(F, {WIDTH}\) array .* got shape"):
            rec.append(np.zeros((n, WIDTH + 1), dtype=np.uint32), **ok)
        with pytest.raises(ValueError, match="got shape"):
            rec.append(np.zeros(WIDTH, dtype=np.uint32), **ok)
        with pytest.raises(ValueError, match="'sum' scan stores the engine's uint32 sums"):
            rec.append(lines.astype(np.float32), **ok)
        with pytest.raises(ValueError, match="does not fit the scan's uint32"):
            rec.append(np.full((n, WIDTH), 2**32, dtype=np.uint64), **ok)
        with pytest.raises(ValueError, match=r"index must have one value per line, shape \(4,\)"):
            rec.append(lines, **{**ok, "index": np.arange(n + 1)})
        with pytest.raises(ValueError, match="complete must be a bool array"):
            rec.append(lines, **{**ok, "complete": np.ones(n, dtype=np.int64)})
        with pytest.raises(ValueError, match=r"stages_used must lie in 0\.\.65535"):
            rec.append(lines, **{**ok, "stages_used": np.full(n, 70000)})
        with pytest.raises(ValueError, match="stages_used must be integers"):
            rec.append(lines, **{**ok, "stages_used": np.full(n, 4.0)})
        with pytest.raises(ValueError, match=r"frame_counter must lie in 0\.\.4294967295"):
            rec.append(lines, **ok, frame_counter=np.full(n, -1))
        with pytest.raises(ValueError, match="stages must be at least 1"):
            rec.note_stage_change(0, 0)
        assert rec.lines == 0
        rec.append(lines, **ok)
    with TdiRecorder(scan_path.with_name("mean.h5"), width=WIDTH, mode="mean", metadata={}) as m:
        with pytest.raises(ValueError, match="'mean' scan stores the engine's float32 means"):
            m.append(lines, **ok)
        m.append(lines.astype(np.float64), **ok)  # float64 means are stored as float32
    assert read_tdi_scan(scan_path).lines.shape == (n, WIDTH)
    assert read_tdi_scan(scan_path.with_name("mean.h5")).lines.dtype == np.float32


def test_reading_something_else_says_what_it_is(tmp_path: Path) -> None:
    with pytest.raises(RecordingError, match="does not exist"):
        read_tdi_scan(tmp_path / "nothing.h5")
    junk = tmp_path / "junk.h5"
    junk.write_bytes(b"not hdf5")
    with pytest.raises(RecordingError, match=r"cannot open .* as HDF5"):
        read_tdi_scan(junk)
    frames = tmp_path / "stare.h5"
    FrameRecorder(frames, rows=2, cols=2, bits=12, mode="area", line_period_s=1.0).close()
    with pytest.raises(
        RecordingError,
        match=r"is a camd frame recording .* read it with camd\.store\.read_recording",
    ):
        read_tdi_scan(frames)
    plain = tmp_path / "plain.h5"
    with h5py.File(plain, "w") as f:
        f["x"] = 1
    with pytest.raises(RecordingError, match="is not a camd TDI scan"):
        read_tdi_scan(plain)


# --- reading while the scan is written ---------------------------------------------------------


def test_the_same_process_reads_a_scan_being_written(scan_path: Path) -> None:
    block = Block("sum", 0, 30)
    with TdiRecorder(scan_path, width=WIDTH, mode="sum", metadata=META) as rec:
        rec.note_stage_change(0, 4)
        block[:10].append_to(rec)
        rec.flush()
        live = read_tdi_scan(scan_path)
        assert np.array_equal(live.lines, block.data[:10])
        assert live.stage_changes.tolist() == [[0, 4]]
        assert live.metadata["profile"]["name"] == "hr400"
        # The final attributes come at close: a live reader counts the datasets.
        assert live.attrs["finished"] is False and live.attrs["lines"] == 0
        with h5py.File(scan_path, "r") as f:  # plain h5py works in the writer's process
            assert f["lines"].shape == (10, WIDTH)
        block[10:].append_to(rec)
    assert np.array_equal(read_tdi_scan(scan_path).lines, block.data)


def test_another_process_reads_a_scan_being_written(scan_path: Path) -> None:
    block = Block("sum", 0, 30)
    with TdiRecorder(scan_path, width=WIDTH, mode="sum", metadata=META, chunk_lines=8) as rec:
        rec.note_stage_change(0, 4)
        block[:5].append_to(rec)
        rec.flush()
        seen = _read_in_another_process(scan_path)
        assert seen["lines"] == 5 and seen["index"] == list(range(5))
        assert seen["sum"] == int(block.data[:5].sum(dtype=np.uint64))
        assert seen["stage_changes"] == [[0, 4]] and seen["finished"] is False
        # No explicit flush: the recorder flushes itself at every chunk's end (line 8: a chunk
        # is written whole, once, which a compressed one needs), so lines 8..12 wait.
        block[5:13].append_to(rec)
        seen = _read_in_another_process(scan_path)
        assert seen["lines"] == 8
        assert seen["sum"] == int(block.data[:8].sum(dtype=np.uint64))
        block[13:].append_to(rec)
    seen = _read_in_another_process(scan_path)
    assert seen["lines"] == 30 and seen["finished"] is True


HOLDER = """
import sys, h5py
f = h5py.File(sys.argv[1], "r", swmr=True)
print(f["lines"].shape[0], flush=True)
sys.stdin.readline()
f.close()
"""


def test_a_reader_holding_the_file_does_not_stop_close(scan_path: Path) -> None:
    rec = TdiRecorder(scan_path, width=WIDTH, mode="mean", metadata={})
    Block("mean", 0, 6).append_to(rec)
    rec.flush()
    holder = subprocess.Popen(
        [sys.executable, "-c", HOLDER, str(scan_path)],
        env=_env(),
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert holder.stdout is not None and holder.stdin is not None
        assert holder.stdout.readline().strip() == "6"
        rec.close({"counters": {"frames": 6}})
        holder.stdin.write("done\n")
        holder.stdin.flush()
        assert holder.wait(timeout=60) == 0
    finally:
        if holder.poll() is None:
            holder.kill()
            holder.wait()
    scan = read_tdi_scan(scan_path)
    assert scan.attrs["lines"] == 6 and scan.metadata["counters"] == {"frames": 6}


# --- quicklook ---------------------------------------------------------------------------------


def _png(path: Path) -> np.ndarray:
    png = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    assert png is not None, f"{path} is not a readable image"
    return png


def _ramp() -> np.ndarray:
    # 0 .. 1000: the 0.5th percentile is 5.0 and the 99.5th is 995.0 (numpy's linear method).
    return np.arange(1001, dtype=np.uint32).reshape(7, 143)


def test_quicklook_stretches_between_the_percentiles(tmp_path: Path) -> None:
    path = write_quicklook_png(tmp_path / "ql.png", _ramp())
    assert path == tmp_path / "ql.png"
    png = _png(path)
    assert png.dtype == np.uint8 and png.shape == (7, 143)  # greyscale: nothing to mark
    flat = png.ravel()
    # 255 / (995 - 5) per DN from 5 up: 203 -> 51, 797 -> 204; clipped outside 5 .. 995.
    assert flat[[0, 4, 5, 203, 797, 995, 996, 1000]].tolist() == [0, 0, 0, 51, 204, 255, 255, 255]
    assert np.all(np.diff(flat.astype(int)) >= 0)
    # Other percentiles: the whole range.
    png = _png(write_quicklook_png(path, _ramp() * 2, low_pct=0, high_pct=100))
    assert png.ravel()[[0, 1000]].tolist() == [0, 255]


def test_quicklook_marks_incomplete_lines_and_stretches_on_complete_ones(tmp_path: Path) -> None:
    image = np.zeros((9, 143), dtype=np.float32)
    image[2:] = _ramp().astype(np.float32)
    image[:2] = 1e9  # partial sums at the start of a run: they must not set the stretch
    complete = np.ones(9, dtype=bool)
    complete[[0, 1, 5]] = False
    png = _png(write_quicklook_png(tmp_path / "ql.png", image, complete=complete))
    assert png.shape == (9, 143, 3)
    red = [0, 0, 255]
    for line in range(9):
        band = png[line, :3].tolist()
        if complete[line]:
            assert all(b == g == r for b, g, r in band), line  # grey
        else:
            assert band == [red] * 3, line
    # Outside the band everything is grey, and the complete lines are stretched as before.
    assert np.all(png[:, 3:, 0] == png[:, 3:, 2])
    ramp = png[2:, :, 0].ravel()
    assert ramp[[5, 203, 797, 995]].tolist() == [0, 51, 204, 255]
    assert png[0, 50, 0] == 255


def test_quicklook_of_a_flat_image_is_mid_grey(tmp_path: Path) -> None:
    png = _png(write_quicklook_png(tmp_path / "flat.png", np.full((5, 8), 7, dtype=np.uint32)))
    assert png.shape == (5, 8) and np.all(png == 128)
    # No complete line at all: the stretch uses all lines.
    png = _png(
        write_quicklook_png(tmp_path / "none.png", _ramp(), complete=np.zeros(7, dtype=bool))
    )
    assert png.shape == (7, 143, 3) and png[6, 142, 0] == 255 and png[0, 3, 0] == 0


def test_a_long_quicklook_is_shrunk_by_averaging_lines(tmp_path: Path) -> None:
    image = np.zeros((10_000, 8), dtype=np.uint32)
    image[1::2] = 100
    image[0, 0] = 255  # sets the stretch 0 .. 255: one DN per grey level
    complete = np.ones(10_000, dtype=bool)
    complete[5001] = False
    png = _png(
        write_quicklook_png(
            tmp_path / "long.png",
            image,
            complete=complete,
            low_pct=0,
            high_pct=100,
            max_lines=1000,
        )
    )
    assert png.shape == (1000, 8, 3)
    assert np.all(png[1:, 3:] == 50)  # five 0s and five 100s per output line
    marked = np.flatnonzero(np.all(png[:, :3] == [0, 0, 255], axis=(1, 2)))
    assert marked.tolist() == [500]


def test_quicklook_refuses_bad_input(tmp_path: Path) -> None:
    path = tmp_path / "ql.png"
    with pytest.raises(ValueError, match="must be 2-D"):
        write_quicklook_png(path, np.zeros(5))
    with pytest.raises(ValueError, match="must be 2-D"):
        write_quicklook_png(path, np.zeros((0, 5)))
    with pytest.raises(ValueError, match=r"one value per line, shape \(3,\)"):
        write_quicklook_png(path, np.zeros((3, 5)), complete=np.ones(4, dtype=bool))
    with pytest.raises(ValueError, match="0 <= low_pct < high_pct <= 100"):
        write_quicklook_png(path, np.zeros((3, 5)), low_pct=50, high_pct=50)
    with pytest.raises(ValueError, match="max_lines must be"):
        write_quicklook_png(path, np.zeros((3, 5)), max_lines=0)
    with pytest.raises(ValueError, match=r"ending in \.png"):
        write_quicklook_png(tmp_path / "ql.jpg", np.zeros((3, 5)))
    assert not path.exists()
    with pytest.raises(RecordingError, match="cannot write the quicklook"):
        write_quicklook_png(tmp_path / "nowhere" / "ql.png", np.zeros((3, 5)))


def test_motion_columns_and_loop_datasets(scan_path: Path) -> None:
    rec = TdiRecorder(scan_path, width=WIDTH, mode="sum", metadata=META)
    n = 5
    rec.append(
        np.ones((n, WIDTH), dtype=np.uint32),
        index=np.arange(n),
        stages_used=np.full(n, 4),
        complete=np.ones(n, dtype=bool),
        stage_position=np.array([-(2**31), -5, 0, 7, 2**31 - 1]),
        m_dv_over_v=np.array([np.nan, 0.5, -0.25, 1.0, 2.0]),
    )
    rec.append(
        np.ones((2, WIDTH), dtype=np.uint32),
        index=np.arange(n, n + 2),
        stages_used=np.full(2, 4),
        complete=np.ones(2, dtype=bool),
    )
    with pytest.raises(ValueError, match="stage_position"):
        rec.append(
            np.ones((1, WIDTH), dtype=np.uint32), index=[9], stages_used=[4],
            complete=np.ones(1, dtype=bool), stage_position=[2**31],
        )  # fmt: skip
    rec.close(datasets={"motion_loop": {"time_s": [0.0, 0.01], "encoder_m": [1.0, 1.5]}})
    scan = read_tdi_scan(scan_path)
    assert scan.stage_position.tolist() == [-(2**31), -5, 0, 7, 2**31 - 1, 0, 0]
    assert np.isnan(scan.m_dv_over_v[[0, 5, 6]]).all()
    assert scan.m_dv_over_v[1:5].tolist() == [0.5, -0.25, 1.0, 2.0]
    with h5py.File(scan_path, "r") as f:
        assert f["motion_loop/encoder_m"][...].tolist() == [1.0, 1.5]


def test_version_1_files_read_with_default_motion_columns(scan_path: Path) -> None:
    rec = TdiRecorder(scan_path, width=WIDTH, mode="sum", metadata=META)
    rec.append(
        np.ones((3, WIDTH), dtype=np.uint32), index=np.arange(3), stages_used=np.full(3, 2),
        complete=np.ones(3, dtype=bool),
    )  # fmt: skip
    rec.close()
    with h5py.File(scan_path, "r+") as f:  # what a version-1 writer made
        del f["stage_position"], f["m_dv_over_v"]
        f.attrs["format_version"] = 1
    scan = read_tdi_scan(scan_path)
    assert scan.lines.shape == (3, WIDTH)
    assert scan.stage_position.tolist() == [0, 0, 0]
    assert np.isnan(scan.m_dv_over_v).all()
