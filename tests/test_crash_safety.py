"""Recordings survive their writer: a kill -9 keeps every flushed frame or line, a full disk
ends the recording with a readable file, and a file left open is repaired (camd.store). The
writers compress by default (camd.store.compression), so these files are compressed: the
repair trims compressed chunks, and a full disk meets compressed frames of noise, each a
little larger than its pixels.

The daemon-level versions (a daemon killed mid-scan and mid-stare, then started again; a disk
filling up under a running daemon) are in tests/test_crash_daemon.py.
"""

from __future__ import annotations

import datetime as dt
import json
import os
import shutil
import signal
import subprocess
import sys
import threading
from pathlib import Path

import h5py
import numpy as np
import pytest

from camd.protocol.stream import FrameFlags, FrameHeader, StreamMode, crc32
from camd.store.durability import INTERRUPTED, recover_file, release_tail
from camd.store.journal import RecordingJournal, recover_left_open
from camd.store.recording import RESERVE_BYTES, FrameRecorder, RecordingError, check_new_file
from camd.store.recording_reading import read_recording
from camd.store.tdi_recording import TdiRecorder, read_tdi_scan
from tests.crash_support import NO_HEADROOM, blocks_past_end, fill_disk, small_disk

ROOT = Path(__file__).resolve().parent.parent
WIDTH = 512
ROWS, COLS = 16, 64


# A writer that appends until killed and prints, after each append, how many lines (frames)
# are on disk: the parent kills it and then requires at least that many in the file.
WRITER = """
import sys, time
import numpy as np
from camd.store.tdi_recording import TdiRecorder
from camd.store.recording import FrameRecorder
from camd.protocol.stream import FrameFlags, FrameHeader, StreamMode, crc32
kind, path = sys.argv[1], sys.argv[2]
WIDTH, ROWS, COLS, CHUNK = (int(a) for a in sys.argv[3:7])
if kind == "scan":
    rec = TdiRecorder(path, width=WIDTH, mode="sum", metadata={"scan": {"lines": 0}},
                      chunk_lines=CHUNK, flush_period_s=0.02)
    i = 0
    while True:
        n = 7
        index = np.arange(i, i + n)
        data = (index[:, None] * 3 + np.arange(WIDTH)[None, :]).astype(np.uint32)
        rec.append(data, index=index, stages_used=np.full(n, 4), complete=np.ones(n, bool))
        i += n
        print(rec.flushed_lines, flush=True)
        time.sleep(0.001)
else:
    rec = FrameRecorder(path, frames_expected=100000, flush_period_s=0.02)
    i = 0
    while True:
        pixels = ((np.arange(ROWS * COLS) + i) % 4096).astype(np.uint16).reshape(ROWS, COLS)
        header = FrameHeader(counter=i, timestamp_ns=i * 1000, line_period_ns=1000,
            rows=ROWS, cols=COLS, bits=12, mode=StreamMode.AREA, stages=0,
            stage_position=0, flags=FrameFlags(0), payload_bytes=pixels.nbytes,
            payload_crc32=crc32(pixels.astype("<u2").tobytes()))
        rec.add(header, pixels, received_ns=time.monotonic_ns())
        i += 1
        print(rec.flushed, flush=True)
        time.sleep(0.001)
"""


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT), env.get("PYTHONPATH")]))
    return env


def _kill_writer_after(
    kind: str, path: Path, flushed_at_least: int, *, chunk_lines: int = 4096
) -> int:
    """Run the writer until it has flushed ``flushed_at_least``, kill -9 it; the last flushed
    count it printed. A scan's writer flushes every 20 ms or ``chunk_lines`` lines."""
    argv = (WIDTH, ROWS, COLS, chunk_lines)
    proc = subprocess.Popen(
        [sys.executable, "-c", WRITER, kind, str(path), *(str(v) for v in argv)],
        stdout=subprocess.PIPE,
        text=True,
        env=_env(),
    )
    assert proc.stdout is not None
    last = 0
    try:
        for line in proc.stdout:
            last = int(line)
            if last >= flushed_at_least:
                break
        proc.send_signal(signal.SIGKILL)
        # Lines printed before the kill landed count too: read what is left.
        rest = proc.stdout.read()
        for line in rest.split():
            last = max(last, int(line))
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.wait(timeout=60)
    assert proc.returncode == -signal.SIGKILL
    return last


def test_a_scan_whose_writer_is_killed_keeps_every_flushed_line(tmp_path: Path) -> None:
    path = tmp_path / "scan.h5"
    flushed = _kill_writer_after("scan", path, 300)
    # Before repair: HDF5 refuses a plain open (the writer's flags), the SWMR reader works.
    with pytest.raises(OSError, match="already open for write"):
        h5py.File(path, "r")
    scan = read_tdi_scan(path)
    n = len(scan.lines)
    assert n >= flushed >= 300
    assert scan.attrs["finished"] is False
    assert np.array_equal(scan.line_index, np.arange(n))
    expected = (np.arange(n)[:, None] * 3 + np.arange(WIDTH)[None, :]).astype(np.uint32)
    assert np.array_equal(scan.lines, expected)
    # The dead writer's headroom is still allocated past the file's end: the repair's space.
    assert blocks_past_end(path) >= TdiRecorder.reserve_bytes(WIDTH, "sum", 4096) // 2

    # The daemon's start-up repair, through the journal.
    journal = RecordingJournal(tmp_path / "open-recordings")
    journal.opened(path, "scan")
    found = recover_left_open(journal)
    assert len(found) == 1 and found[0].recovered is not None
    recovered = found[0].recovered
    assert (recovered.kind, recovered.count) == ("scan", n)
    assert f"{n} lines kept, marked incomplete" in found[0].describe()
    assert journal.entries() == [] and blocks_past_end(path) < NO_HEADROOM
    with h5py.File(path, "r") as f:  # now any HDF5 reader opens it
        assert f["lines"].shape == (n, WIDTH) and len(f["line_index"]) == n
        # compressed (the default), its last chunk cut by the trim and compressed again
        assert f["lines"].attrs["compression"] == "bitshuffle-lz4"
        assert set(f["lines"]._filters) == {"32008"}
        assert f["lines_flushed"][0] == n
        assert f.attrs["finished"] is np.False_ and f.attrs["lines"] == n
        assert f.attrs["interrupted"] == INTERRUPTED and "recovered_utc" in f.attrs
        # The NeXus entry ends when the dead writer last wrote, and says the file is unfinished.
        start, end, recovered_at = (
            dt.datetime.fromisoformat(text)
            for text in (
                f["entry/start_time"][()].decode(),
                f["entry/end_time"][()].decode(),
                f.attrs["recovered_utc"],
            )
        )
        assert start < end <= recovered_at
        assert (f["entry/camd/lines"][()], f["entry/camd/finished"][()]) == (n, False)
        assert f["entry/data/lines"].shape == (n, WIDTH)
    assert np.array_equal(read_tdi_scan(path).lines, expected)


def test_a_scan_flushed_in_whole_chunks_whose_writer_is_killed_keeps_every_flushed_line(
    tmp_path: Path,
) -> None:
    # Chunks of 14 lines, blocks of 7: every other append fills the recorder's line buffer,
    # which goes to the file as one raw chunk (camd.store.line_buffer) before its count.
    path = tmp_path / "scan.h5"
    flushed = _kill_writer_after("scan", path, 300, chunk_lines=14)
    scan = read_tdi_scan(path)
    n = len(scan.lines)
    assert n >= flushed >= 300
    assert np.array_equal(scan.line_index, np.arange(n))
    assert np.array_equal(scan.stages_used, np.full(n, 4)) and scan.complete.all()
    expected = (np.arange(n)[:, None] * 3 + np.arange(WIDTH)[None, :]).astype(np.uint32)
    assert np.array_equal(scan.lines, expected)


def test_a_recording_whose_writer_is_killed_keeps_every_flushed_frame(tmp_path: Path) -> None:
    path = tmp_path / "stare.h5"
    flushed = _kill_writer_after("recording", path, 40)
    rec = read_recording(path)
    n = len(rec.frames)
    assert n >= flushed >= 40
    assert rec.attrs["finished"] is False and rec.attrs["frames_expected"] == 100000
    assert np.array_equal(rec.columns["frame_counter"], np.arange(n))
    assert rec.crc_mismatches() == []  # every kept frame's pixels are the device's
    recovered = recover_file(path)
    assert recovered is not None and (recovered.kind, recovered.count) == ("recording", n)
    assert recovered.expected == 100000
    with h5py.File(path, "r") as f:
        assert f["frames"].shape == (n, ROWS, COLS) and f.attrs["frames"] == n
        assert f.attrs["interrupted"] == INTERRUPTED
        # The NeXus entry ends at the last kept frame's arrival.
        last_ns = int(f["received_unix_ns"][n - 1])
        end = dt.datetime.fromisoformat(f["entry/end_time"][()].decode())
        assert end == dt.datetime.fromtimestamp(last_ns // 1_000_000 / 1e3, dt.UTC)
        assert end >= dt.datetime.fromisoformat(f["entry/start_time"][()].decode())
        assert f["entry/camd/frames"][()] == n
        assert f["frames"].attrs["compression"] == "bitshuffle-lz4"  # the default
        assert set(f["frames"]._filters) == {"32008"}
    again = read_recording(path)
    assert np.array_equal(again.frames, rec.frames)
    assert recover_file(path) is not None  # idempotent: still unfinished, nothing lost
    assert len(read_recording(path).frames) == n


def test_a_closed_file_needs_no_repair_and_a_missing_one_is_reported(tmp_path: Path) -> None:
    done = tmp_path / "done.h5"
    with TdiRecorder(done, width=WIDTH, mode="sum", metadata={}) as rec:
        rec.append(
            np.ones((3, WIDTH), np.uint32),
            index=np.arange(3),
            stages_used=np.full(3, 2),
            complete=np.ones(3, bool),
        )
    assert blocks_past_end(done) < NO_HEADROOM
    assert recover_file(done) is None
    journal = RecordingJournal(tmp_path / "journal")
    journal.opened(done, "scan")
    journal.opened(tmp_path / "never.h5", "recording")
    found = {f.path.name: f for f in recover_left_open(journal)}
    assert found["done.h5"].recovered is None and found["done.h5"].problem is None
    assert "closed after all" in found["done.h5"].describe()
    assert found["never.h5"].problem == "the file is gone (removed, or never written)"
    assert journal.entries() == []
    assert read_tdi_scan(done).attrs["finished"] is True


def _header(i: int, pixels: np.ndarray) -> FrameHeader:
    return FrameHeader(
        counter=i,
        timestamp_ns=i,
        line_period_ns=1000,
        rows=pixels.shape[0],
        cols=pixels.shape[1],
        bits=16,
        mode=StreamMode.AREA,
        stages=0,
        stage_position=0,
        flags=FrameFlags(0),
        payload_bytes=pixels.nbytes,
        payload_crc32=crc32(pixels.astype("<u2").tobytes()),
    )


def test_a_full_disk_ends_a_recording_with_a_readable_file(tmp_path: Path) -> None:
    with small_disk(tmp_path / "small", 24) as disk:
        path = disk / "frames.h5"
        rec = FrameRecorder(path, flush_period_s=0.0)
        rng = np.random.default_rng(1)
        frames = []
        with pytest.raises(RecordingError) as failure:
            for i in range(10_000):  # 256 KiB frames: the disk is full long before
                pixels = rng.integers(0, 65535, (256, 512), dtype=np.uint16)
                frames.append(pixels)
                rec.add(_header(i, pixels), pixels, received_ns=i)
        message = str(failure.value)
        assert f"the disk holding {disk} is full (No space left on device)" in message
        # Every frame whose write went through is kept, its count on disk: none is lost but
        # the one that did not fit.
        assert f"keeps the {len(frames) - 1} frames written before" in message
        assert rec.flushed == rec.count == len(frames) - 1
        with pytest.raises(RecordingError, match="is full"):  # and it stays refused
            rec.add(_header(0, frames[0]), frames[0], received_ns=0)
        rec.close({"frames": 1})
        assert blocks_past_end(path) < NO_HEADROOM
        with h5py.File(path, "r") as f:  # a plain reader: closed properly
            assert f.attrs["finished"] is np.False_ and "is full" in f.attrs["error"]
        kept = read_recording(path)
        assert len(kept.frames) == rec.flushed > 10
        assert kept.crc_mismatches() == []
        assert np.array_equal(kept.frames, np.stack(frames[: rec.flushed]))


def scrambled(index: np.ndarray) -> np.ndarray:
    """Lines ``index`` of 2048 samples that no filter compresses (a multiplicative hash of
    line and column), each known from its index: the disk fills after as many lines
    compressed as raw (a smooth ramp compressed 20 times more appends into the same disk)."""
    hashed = (index[:, None] * 2654435761 + np.arange(2048)[None, :] * 40503) * 97
    return (hashed % (1 << 32)).astype(np.uint32)


def test_a_full_disk_ends_a_scan_with_a_readable_file(tmp_path: Path) -> None:
    with small_disk(tmp_path / "small", 24) as disk:
        path = disk / "scan.h5"
        rec = TdiRecorder(path, width=2048, mode="sum", metadata={}, chunk_lines=64)
        lines = 0
        with pytest.raises(RecordingError, match="is full"):
            while True:
                index = np.arange(lines, lines + 50)
                data = scrambled(index)
                rec.append(
                    data, index=index, stages_used=np.full(50, 8), complete=np.ones(50, bool)
                )
                lines += 50
        assert rec.flushed_lines >= lines > 100  # every line of every append that returned
        rec.close({"state": "failed"})
        assert blocks_past_end(path) < NO_HEADROOM
        scan = read_tdi_scan(path)
        n = rec.flushed_lines
        assert scan.attrs["lines"] == n == len(scan.lines) and scan.attrs["state"] == "failed"
        assert "No space left on device" in scan.attrs["error"]
        assert np.array_equal(scan.lines, scrambled(np.arange(n)))
        with h5py.File(path, "r") as f:
            assert f["lines_flushed"][0] == n


def test_the_filler_helper_fills_the_disk(tmp_path: Path) -> None:
    with small_disk(tmp_path / "small", 4) as disk:
        written = fill_disk(disk)
        assert 3 << 20 <= written <= 4 << 20
        assert os.statvfs(disk).f_bavail == 0


def test_the_journal_survives_a_restart_and_names_each_file_once(tmp_path: Path) -> None:
    folder = tmp_path / "open-recordings"
    first = RecordingJournal(folder)
    first.opened(tmp_path / "a.h5", "scan")
    first.opened(tmp_path / "a.h5", "scan")  # the same file twice: one entry
    first.opened(tmp_path / "b.h5", "recording")
    first.closed(tmp_path / "b.h5")
    entries = RecordingJournal(folder).entries()
    assert [record["path"] for _, record in entries] == [str(tmp_path / "a.h5")]
    record = entries[0][1]
    assert record["kind"] == "scan" and int(record["pid"]) == os.getpid()
    assert json.loads(entries[0][0].read_text())["opened_utc"].endswith("+00:00")
    # an unreadable entry is dropped with a warning, not fatal
    (folder / "junk.json").write_text("{not json")
    assert len(RecordingJournal(folder).entries()) == 1


# -- a disk that fills up: never a crash, never a frame lost that the disk could hold ---------

# The case, in a process of its own (a crash in libhdf5 kills the process): eight
# 534 x 2048 frames (the hr400's default window, 2.2 MB each) into a 20 MiB disk, the recorder
# dropped afterwards as the daemon drops it. Before the headroom the disk filled while HDF5's
# 8 MiB chunk cache still held three frames, their close failed half-way and collecting the
# recorder's Dataset objects crashed the process (SIGSEGV in H5D_close). The pixels are noise
# over the whole 16-bit range: compressed (the recorder's default), each frame takes a little
# more than its 2.2 MB, which the headroom must allow for.
STARE_ON_A_SMALL_DISK = """
import gc, json, sys
import numpy as np
from camd.protocol.stream import FrameFlags, FrameHeader, StreamMode, crc32
from camd.store.recording import FrameRecorder, RecordingError
path = sys.argv[1]
rec = FrameRecorder(path, frames_expected=8)
rng = np.random.default_rng(3)
added, error = 0, None
for i in range(8):
    pixels = rng.integers(0, 65536, (534, 2048), dtype=np.uint16)
    header = FrameHeader(counter=i, timestamp_ns=i, line_period_ns=1000, rows=534, cols=2048,
        bits=16, mode=StreamMode.AREA, stages=0, stage_position=0, flags=FrameFlags(0),
        payload_bytes=pixels.nbytes, payload_crc32=crc32(pixels.astype("<u2").tobytes()))
    try:
        rec.add(header, pixels, received_ns=i)
    except RecordingError as exc:
        error = str(exc)
        break
    added += 1
rec.close({"frames": added})
del rec
gc.collect()
print(json.dumps({"added": added, "error": error}))
"""


def test_a_stare_that_fills_the_disk_keeps_its_frames_and_its_process(tmp_path: Path) -> None:
    with small_disk(tmp_path / "small", 20) as disk:
        path = disk / "stare.h5"
        done = subprocess.run(
            [sys.executable, "-c", STARE_ON_A_SMALL_DISK, str(path)],
            capture_output=True,
            text=True,
            env=_env(),
            timeout=120,
            check=False,
        )
        assert done.returncode == 0, done.stderr[-2000:]
        result = json.loads(done.stdout)
        # 8 frames and the headroom do not fit in 20 MiB: the disk held the first ones.
        added = result["added"]
        assert 4 <= added < 8
        assert f"the recording keeps the {added} frames written before" in result["error"]
        with h5py.File(path, "r") as f:  # closed properly: any reader opens it
            assert f["frames"].shape[0] == f["frames_flushed"][0] == f.attrs["frames"] == added
            assert f.attrs["finished"] is np.False_ and "is full" in f.attrs["error"]
            assert f.attrs["ended_early"] == f.attrs["error"]
        kept = read_recording(path)
        assert kept.crc_mismatches() == []  # every kept frame is the camera's, bit for bit
        assert np.array_equal(kept.columns["frame_counter"], np.arange(added))
        assert blocks_past_end(path) < NO_HEADROOM
        assert sorted(p.name for p in disk.iterdir()) == ["stare.h5"]


def _fill_while(disk: Path, started: threading.Event) -> threading.Thread:
    """Another program filling the disk: starts once ``started`` is set."""

    def fill() -> None:
        started.wait(60)
        fill_disk(disk)

    thread = threading.Thread(target=fill, daemon=True)
    thread.start()
    return thread


def test_a_recording_keeps_every_frame_while_another_program_fills_the_disk(
    tmp_path: Path,
) -> None:
    with small_disk(tmp_path / "small", 24) as disk:
        path = disk / "frames.h5"
        started = threading.Event()
        filler = _fill_while(disk, started)
        rec = FrameRecorder(path, flush_period_s=0.01)
        frames: list[np.ndarray] = []
        rng = np.random.default_rng(5)
        with pytest.raises(RecordingError, match="is full"):
            for i in range(100_000):
                pixels = rng.integers(0, 65535, (64, 512), dtype=np.uint16)
                rec.add(_header(i, pixels), pixels, received_ns=i)
                frames.append(pixels)
                started.set()
        filler.join(60)
        rec.close()
        kept = read_recording(path)
        assert len(kept.frames) == len(frames) > 0  # none lost that the disk held
        assert np.array_equal(kept.frames, np.stack(frames))
        assert kept.crc_mismatches() == []
        with h5py.File(path, "r") as f:
            assert f["frames_flushed"][0] == f.attrs["frames"] == len(frames)


def test_a_scan_keeps_every_line_while_another_program_fills_the_disk(tmp_path: Path) -> None:
    with small_disk(tmp_path / "small", 24) as disk:
        path = disk / "scan.h5"
        started = threading.Event()
        filler = _fill_while(disk, started)
        rec = TdiRecorder(path, width=2048, mode="sum", metadata={}, chunk_lines=64)
        lines = 0
        with pytest.raises(RecordingError, match="is full"):
            while True:
                n = 1 + lines % 97  # blocks of many sizes, across chunk boundaries
                index = np.arange(lines, lines + n)
                data = (index[:, None] * 7 + np.arange(2048)[None, :]).astype(np.uint32)
                rec.append(data, index=index, stages_used=np.full(n, 8), complete=np.ones(n, bool))
                lines += n
                started.set()
        filler.join(60)
        rec.close({"state": "failed"})
        scan = read_tdi_scan(path)
        n = len(scan.lines)
        assert n >= lines > 0 and scan.attrs["lines"] == n  # every line of every append kept
        expected = (np.arange(n)[:, None] * 7 + np.arange(2048)[None, :]).astype(np.uint32)
        assert np.array_equal(scan.lines, expected) and np.array_equal(
            scan.line_index, np.arange(n)
        )
        with h5py.File(path, "r") as f:
            assert f["lines_flushed"][0] == n


def test_a_refused_file_leaves_nothing_and_the_same_name_works_once_there_is_room(
    tmp_path: Path,
) -> None:
    with small_disk(tmp_path / "small", 8) as disk:
        fill_disk(disk)
        scan, frames = disk / "scan.h5", disk / "frames.h5"
        with pytest.raises(RecordingError, match=r"cannot create the TDI scan .* is full"):
            TdiRecorder(scan, width=512, mode="sum", metadata={})
        with pytest.raises(RecordingError, match=r"cannot create the recording .* is full"):
            FrameRecorder(frames)
        # Nothing left behind, not even an empty file: a retry with the same name works.
        assert sorted(p.name for p in disk.iterdir()) == ["filler"]
        (disk / "filler").unlink()
        TdiRecorder(scan, width=512, mode="sum", metadata={}).close()
        FrameRecorder(frames).close()
        assert read_tdi_scan(scan).attrs["finished"] is True
        assert read_recording(frames).attrs["finished"] is True


def test_the_free_space_check_counts_what_the_recorder_holds_back(tmp_path: Path) -> None:
    with small_disk(tmp_path / "small", 8) as disk:
        free = shutil.disk_usage(disk).free
        planned = free - RESERVE_BYTES // 2  # fits, but not with the reserve
        with pytest.raises(RecordingError) as refused:
            check_new_file(disk / "x.h5", planned)
        assert (
            f"the recording needs about {planned / 1e6:.1f} MB, and {RESERVE_BYTES / 1e6:.1f} MB "
            "more held back to close the file safely if the disk fills" in str(refused.value)
        )
        check_new_file(disk / "x.h5", free - RESERVE_BYTES)  # just fits
        scan_reserve = TdiRecorder.reserve_bytes(2048, "sum")
        with pytest.raises(RecordingError, match="more held back"):
            check_new_file(disk / "x.h5", free - scan_reserve + 1, scan_reserve)
        assert list(disk.iterdir()) == []


def test_a_dead_writers_file_is_repaired_on_a_full_disk(tmp_path: Path) -> None:
    # The writer holds back two 8 MiB chunks of lines and 4 MiB (TdiRecorder.reserve_bytes).
    with small_disk(tmp_path / "small", 48) as disk:
        path = disk / "scan.h5"
        flushed = _kill_writer_after("scan", path, 300)
        fill_disk(disk)
        assert os.statvfs(disk).f_bavail == 0
        journal = RecordingJournal(tmp_path / "open-recordings")
        journal.opened(path, "scan")
        found = recover_left_open(journal)
        # The repair wrote into the dead writer's headroom: no new space needed.
        assert found[0].problem is None and found[0].recovered is not None
        n = found[0].recovered.count
        assert n >= flushed >= 300 and journal.entries() == []
        with h5py.File(path, "r") as f:
            assert f["lines"].shape[0] == f["lines_flushed"][0] == f.attrs["lines"] == n


def test_a_repair_that_finds_no_room_keeps_its_journal_entry(tmp_path: Path) -> None:
    with small_disk(tmp_path / "small", 24) as disk:
        path = disk / "stare.h5"
        flushed = _kill_writer_after("recording", path, 40)
        release_tail(path)  # no headroom left (as if the file system had none to give)
        fill_disk(disk)
        journal = RecordingJournal(tmp_path / "open-recordings")
        journal.opened(path, "recording")
        found = recover_left_open(journal)
        assert found[0].recovered is None
        assert f"cannot repair {path}: the disk holding {disk} is full" in (found[0].problem or "")
        assert found[0].problem and "camd tries again when it next starts" in found[0].problem
        assert len(journal.entries()) == 1  # kept: the file is not whole yet
        with pytest.raises(OSError, match="already open for write"):
            h5py.File(path, "r")  # untouched: still as the dead writer left it
        (disk / "filler").unlink()
        found = recover_left_open(journal)
        assert found[0].recovered is not None and found[0].recovered.count >= flushed
        assert journal.entries() == []
        with h5py.File(path, "r") as f:
            assert f["frames"].shape[0] == f.attrs["frames"] >= flushed
