"""Compressed recordings and scans (camd.store.compression; docs/stream.md, "Compression"):
every filter reads back bit-exact through camd's readers and plain h5py, the default one through
nexusformat and silx too; the file says how it is compressed; a chunk of noise stays within the
space the writers hold for it; the choices are checked with messages that name the valid ones
(the config's here, the requests' in tests/test_record_paths.py); and ``camd bench store``
measures every filter (a small run).

The crash repair of compressed files is tests/test_crash_safety.py's (the writers compress by
default, so its killed writers leave compressed files).
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

from camd.daemon.config import ConfigError, config_from_dict
from camd.protocol.stream import FrameFlags, FrameHeader, StreamMode, crc32
from camd.store.compression import (
    DEFAULT,
    FILTERS,
    Compression,
    chunk_bound_bytes,
)
from camd.store.recording import FrameRecorder
from camd.store.recording_reading import read_recording
from camd.store.tdi_layout import chunk_lines_for
from camd.store.tdi_recording import TdiRecorder, read_tdi_scan
from tests.nexus_support import nexus_plot

ROWS, COLS, FRAMES = 32, 256, 6
WIDTH, LINES = 512, 300
# The HDF5 filter ids each choice puts on the dataset (h5py's and hdf5plugin's).
FILTER_IDS = {
    "off": set(),
    "bitshuffle-lz4": {"32008"},
    "bitshuffle-zstd": {"32008"},
    "blosc2-zstd": {"32026"},
    "gzip": {"shuffle", "gzip"},
    "lzf": {"shuffle", "lzf"},
}


def camera_frames(n: int = FRAMES, seed: int = 0) -> np.ndarray:
    """Frames like the simulator's: a dark level with a little noise and a few bars (12 bits)."""
    rng = np.random.default_rng(seed)
    bars = ((np.arange(COLS) // 8) % 2 * 900).astype(np.int64)
    noise = rng.normal(0, 6, (n, ROWS, COLS))
    return np.clip(500 + bars + noise, 0, 4095).astype(np.uint16)


def scan_lines(seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return (40_000 + rng.poisson(200, (LINES, WIDTH))).astype(np.uint32)


def header(counter: int, pixels: np.ndarray) -> FrameHeader:
    rows, cols = pixels.shape
    return FrameHeader(counter, 1000 * counter, 1000, rows, cols, 12, StreamMode.AREA, 0, 0,
                       FrameFlags(0), pixels.nbytes, crc32(pixels.tobytes()))  # fmt: skip


def record(path: Path, frames: np.ndarray, compression: Compression = DEFAULT) -> None:
    with FrameRecorder(path, frames_expected=len(frames), compression=compression) as rec:
        for i, pixels in enumerate(frames):
            rec.add(header(i, pixels), pixels, received_ns=i)


def scan(path: Path, lines: np.ndarray, compression: Compression = DEFAULT) -> None:
    n = len(lines)
    with TdiRecorder(path, width=WIDTH, mode="sum", metadata={"scan": {"stages": 4}},
                     chunk_lines=64, compression=compression) as rec:  # fmt: skip
        for start in range(0, n, 50):  # blocks that straddle the chunks
            part = slice(start, min(n, start + 50))
            k = part.stop - part.start
            rec.append(lines[part], index=np.arange(part.start, part.stop),
                       stages_used=np.full(k, 4), complete=np.ones(k, bool))  # fmt: skip


@pytest.mark.parametrize("name", list(FILTERS))
def test_every_filter_reads_back_bit_exact_and_says_how_it_is_compressed(
    tmp_path: Path, name: str
) -> None:
    compression = Compression.of(name)
    frames, lines = camera_frames(), scan_lines()
    record(tmp_path / "stare.h5", frames, compression)
    scan(tmp_path / "scan.h5", lines, compression)

    stare = read_recording(tmp_path / "stare.h5")
    assert np.array_equal(stare.frames, frames) and stare.crc_mismatches() == []
    assert np.array_equal(read_tdi_scan(tmp_path / "scan.h5").lines, lines)
    # Plain h5py (this process imported hdf5plugin with camd.store): the data, the filter on
    # the dataset, and the dataset's own words for it.
    for file, dataset, data in (("stare.h5", "frames", frames), ("scan.h5", "lines", lines)):
        with h5py.File(tmp_path / file, "r") as f:
            ds = f[dataset]
            assert np.array_equal(ds[...], data)
            assert set(ds._filters) == FILTER_IDS[name], ds._filters
            assert ds.attrs["compression"] == name
            assert ds.attrs.get("compression_level") == FILTERS[name].default_level
            stored = ds.id.get_storage_size()
        if name == "off":
            assert stored >= data.nbytes  # whole chunks, as they are
        else:
            assert stored < data.nbytes / 1.5, (name, file, data.nbytes / stored)


def test_the_default_is_bitshuffle_lz4_and_nexusformat_and_silx_read_it(tmp_path: Path) -> None:
    """The writers compress unless told not to; a NeXus viewer (nexusformat, silx) finds the
    compressed signal and reads it whole."""
    from silx.io import open as silx_open
    from silx.io.nxdata import get_default

    frames, lines = camera_frames(), scan_lines()
    with FrameRecorder(tmp_path / "stare.h5") as rec:  # no compression given: the default
        for i, pixels in enumerate(frames):
            rec.add(header(i, pixels), pixels, received_ns=i)
    with TdiRecorder(tmp_path / "scan.h5", width=WIDTH, mode="sum", metadata={}) as rec:
        rec.append(lines, index=np.arange(LINES), stages_used=np.full(LINES, 4),
                   complete=np.ones(LINES, bool))  # fmt: skip
    assert Compression("bitshuffle-lz4", None) == DEFAULT
    for file, signal, data in (("stare.h5", "frames", frames), ("scan.h5", "lines", lines)):
        path = tmp_path / file
        with h5py.File(path, "r") as f:
            assert f[signal].attrs["compression"] == "bitshuffle-lz4"
            assert set(f[signal]._filters) == {"32008"}
        plot = nexus_plot(path)
        assert plot["signal"] == signal and np.array_equal(plot["signal_values"], data)
        with silx_open(str(path)) as f:
            nxdata = get_default(f)
            assert nxdata is not None and nxdata.is_valid
            assert nxdata.signal.name == f"/entry/data/{signal}"  # its label: 'frames (DN)'
            assert np.array_equal(nxdata.signal[...], data)


@pytest.mark.parametrize("name", [n for n in FILTERS if n != "off"])
def test_a_chunk_of_noise_stays_within_the_space_the_writers_hold_for_it(
    tmp_path: Path, name: str
) -> None:
    """Incompressible data (noise over the whole range) comes out of a filter larger than it
    went in: the headroom a writer asks for before a write is the bound, not the raw size."""
    rng = np.random.default_rng(5)
    frames = rng.integers(0, 65536, (3, 256, 512), dtype=np.uint16)
    compression = Compression.of(name)
    record(tmp_path / "noise.h5", frames, compression)
    with h5py.File(tmp_path / "noise.h5", "r") as f:
        sizes = [f["frames"].id.get_chunk_info(i).size for i in range(3)]
    bound = chunk_bound_bytes(frames[0].nbytes, compression)
    assert max(sizes) <= bound, (sizes, bound)
    assert np.array_equal(read_recording(tmp_path / "noise.h5").frames, frames)
    assert chunk_bound_bytes(frames[0].nbytes, Compression.of("off")) == frames[0].nbytes


def test_a_slow_scans_chunks_fill_between_flushes_and_its_file_stays_compressed(
    tmp_path: Path,
) -> None:
    """A compressed chunk flushed before it filled is written again to new space (the SWMR
    writer never reuses what it leaves): 256-line chunks flushed every 4 lines made a file 8
    times the raw lines. The daemon's scans take chunks that fill between two flushes."""
    assert chunk_lines_for(10.0, 1.0) == 1  # the longest line period: a line a chunk
    assert chunk_lines_for(0.01, 1.0) == 75
    assert chunk_lines_for(96 * 20.52e-6, 1.0) == 256  # hr400 at M = 96
    lines = scan_lines()
    path = tmp_path / "slow.h5"
    chunk = 4  # a flush every 4 lines, as a scan of 4 lines per flush period gets
    with TdiRecorder(path, width=WIDTH, mode="sum", metadata={}, chunk_lines=chunk) as rec:
        for start in range(0, LINES, chunk):
            rec.append(lines[start : start + chunk], index=np.arange(start, start + chunk),
                       stages_used=np.full(chunk, 4), complete=np.ones(chunk, bool))  # fmt: skip
            rec.flush()
    assert path.stat().st_size < lines.nbytes / 2
    assert np.array_equal(read_tdi_scan(path).lines, lines)


@pytest.mark.parametrize(
    ("name", "level", "message"),
    [
        ("zip", None, "unknown compression 'zip': choose one of 'off', 'bitshuffle-lz4', "
                      "'bitshuffle-zstd', 'blosc2-zstd', 'gzip', 'lzf'"),
        ("lzf", 3, "compression 'lzf' has no levels: leave the level out (or choose a filter "
                   "with levels: 'bitshuffle-zstd' 1..22, 'blosc2-zstd' 1..9, 'gzip' 1..9)"),
        ("gzip", 10, "compression level 10 is out of range for 'gzip': choose 1..9 (default 1)"),
        ("gzip", True, "compression level True must be a whole number"),
    ],
)  # fmt: skip
def test_a_bad_choice_names_the_valid_ones(name: str, level: object, message: str) -> None:
    with pytest.raises(ValueError) as refused:
        Compression.of(name, level)
    assert str(refused.value) == message


def test_the_config_chooses_the_filter_and_refuses_what_it_does_not_know() -> None:
    assert config_from_dict({}).store.compression_for(None, None) == DEFAULT
    chosen = config_from_dict({"store": {"compression": "blosc2-zstd", "compression_level": 5}})
    assert chosen.store.compression_for(None, None) == Compression("blosc2-zstd", 5)
    # A request's own choice wins over the config's.
    assert chosen.store.compression_for("off", None) == Compression("off", None)
    assert chosen.store.compression_for("gzip", None) == Compression("gzip", 1)
    # The fastest scans are stored uncompressed unless their request names a compression.
    default = config_from_dict({}).store
    assert default.scan_compression_max_mbyte_s == 100.0
    assert default.compression_for(None, None, mbyte_s=199.6) == Compression("off", None)
    assert default.compression_for(None, None, mbyte_s=4.2) == DEFAULT
    assert default.compression_for("bitshuffle-lz4", None, mbyte_s=199.6) == DEFAULT
    for store, message in (
        ({"compression": "zip"}, "store.compression: unknown compression 'zip': choose one of "
                                 "'off', 'bitshuffle-lz4'"),
        ({"compression": "gzip", "compression_level": 0},
         "store.compression_level: compression level 0 is out of range for 'gzip': choose 1..9"),
        ({"compression": "bitshuffle-lz4", "compression_level": 2},
         "store.compression_level: compression 'bitshuffle-lz4' has no levels"),
        ({"compression_level": 2}, "store.compression_level: compression 'bitshuffle-lz4' has "
                                   "no levels"),
        ({"compression": 3}, "store.compression: 3 is an integer, the wrong type"),
        ({"scan_compression_max_mbyte_s": -1.0}, "store.scan_compression_max_mbyte_s: -1.0 is "
                                                 "out of range"),
    ):  # fmt: skip
        with pytest.raises(ConfigError) as refused:
            config_from_dict({"store": store})
        assert message in str(refused.value), str(refused.value)


def test_bench_store_measures_every_filter_against_off(tmp_path: Path) -> None:
    """A small ``camd bench store --json``: each input has every filter, off's ratio is 1.0,
    a real filter's ratio on the flat scene is above 1, and every rate is a positive number."""
    done = subprocess.run(
        [sys.executable, "-m", "camd", "bench", "store", "--json", "--input-mb", "6",
         "--rounds", "1", "--seconds", "0.05", "--rows", "64",
         "--filters", "off,bitshuffle-lz4,lzf"],
        capture_output=True, text=True, timeout=600, check=False,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]
    doc = json.loads(done.stdout.strip().splitlines()[-1])
    assert 150 < doc["camera_full_window_mbyte_s"] < 250  # hr400: about 200 MB/s
    assert [case["input"] for case in doc["inputs"]] == ["flat", "bars", "tdi"]
    for case in doc["inputs"]:
        assert case["raw_bytes"] >= 6e6
        assert list(case["filters"]) == ["off", "bitshuffle-lz4", "lzf"]
        assert case["filters"]["off"]["ratio"] == 1.0
        assert case["filters"]["off"]["speed_over_off"] == 1.0
        for figures in case["filters"].values():
            for key in ("mbyte_s_one_core", "mbyte_s_wall", "over_camera_rate"):
                assert figures[key] > 0, (case["input"], key, figures)
            lo, hi = figures["speed_over_off_range"]
            assert 0 < lo <= figures["speed_over_off"] <= hi
    flat = doc["inputs"][0]["filters"]
    assert flat["bitshuffle-lz4"]["ratio"] > 1.5 and flat["lzf"]["ratio"] > 1.0
    assert doc["inputs"][2]["dtype"] == "uint32" and doc["inputs"][2]["shape"][1] == 2048
