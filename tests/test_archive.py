"""``camd archive`` (docs/archive.md): a data directory served through Tiled.

One real server for the module, started as a user starts it (``camd archive serve DATA_DIR
--port 0``, a child process on loopback), over a data directory written by camd's own writers
in this process: two TDI scans (M = 32 on an hr400, M = 8 on an ibis5), a stare, a campaign
run's stare, a recording whose writer "died" (a copy taken after a flush, before the close), a
foreign HDF5 file and a file that is not HDF5. Through Tiled's own client: the metadata searches
find exactly the right nodes, every array reads back bit-exact against h5py, a Dask client reads
them chunk by chunk, a file written after the start appears after ``camd archive index`` (and
one removed disappears), a file being written is indexed as far as it is on disk and replaced as
it grows, the key is required and never logged, docs/archive.md's Dask example computes what
h5py does, and a bad data directory is refused with nothing made.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import shutil
import socket
import subprocess
import sys
import threading
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import h5py
import hdf5plugin
import httpx
import numpy as np
import pytest
from tiled.client import from_uri
from tiled.queries import Key

from camd.cli.camd_main import main as camd_main
from camd.protocol.stream import FrameFlags, FrameHeader, StreamMode, crc32
from camd.store.recording import FrameRecorder
from camd.store.tdi_recording import TdiRecorder
from tests.crash_support import wait_for

ROOT = Path(__file__).resolve().parents[1]
ARCHIVE_MD = ROOT / "docs" / "archive.md"
START_TIMEOUT_S = 120.0  # a busy 2-core host: Tiled's imports alone take seconds
# What the campaign runner says before a step (the control activity), kept in the file.
STEP_TEXT = "campaign tdi_snr_stages: step 1/2 acquire dark[0]"


def profile(name: str) -> dict[str, Any]:
    return {"profile": name, "sensor": name, "description": f"{name} camera",
            "pitch_m": {"value": 11e-6, "source": "test"}}  # fmt: skip


def write_scan(path: Path, *, name: str, stages: int, lines: int, width: int = 24) -> None:
    rng = np.random.default_rng(stages)
    data = rng.integers(0, 4096 * stages, (lines, width), dtype=np.uint32)
    r = TdiRecorder(
        path,
        width=width,
        mode="sum",
        chunk_lines=16,  # several chunks: the Dask client reads them one by one
        metadata={
            "profile": profile(name),
            "timing": {"tdi_line_period_s": 250e-6, "exposure_s": 240e-6, "n_lines": 6},
            "scan": {"stages": stages, "lines": lines, "binning": "off"},
        },
    )
    r.append(data, index=np.arange(lines), stages_used=np.full(lines, stages),
             complete=np.ones(lines, bool))  # fmt: skip
    r.close({"state": "done"})


def header(counter: int, pixels: np.ndarray) -> FrameHeader:
    rows, cols = pixels.shape
    return FrameHeader(counter, 1000 * counter, 1000, rows, cols, 12, StreamMode.AREA, 0, 0,
                       FrameFlags(0), pixels.nbytes, crc32(pixels.tobytes()))  # fmt: skip


def start_stare(
    path: Path, frames: int, *, seed: int, context: dict[str, dict[str, Any]] | None = None
) -> FrameRecorder:
    """``context``: the groups the daemon adds to a new file (its scene, the campaign step)."""
    rng = np.random.default_rng(seed)
    metadata = {"profile": profile("hr400"), "stream": {"stages": 0}, **(context or {})}
    rec = FrameRecorder(path, metadata=metadata, frames_expected=frames + 2, mode="area")
    for k in range(frames):
        px = rng.integers(0, 4096, (6, 10), dtype=np.uint16)
        rec.add(header(k, px), px, received_ns=k)
    return rec


def write_stare(
    path: Path, frames: int, *, seed: int, context: dict[str, dict[str, Any]] | None = None
) -> None:
    start_stare(path, frames, seed=seed, context=context).close()


def compress_frames(path: Path) -> None:
    """The file's /frames rewritten with Bitshuffle + LZ4 (hdf5plugin), as a compressed
    recording stores them: same values, same chunks, same names (the NeXus link too)."""
    with h5py.File(path, "r+") as f:
        frames, attrs = f["frames"][()], dict(f["frames"].attrs)
        del f["entry/data/frames"], f["frames"]
        f.create_dataset("frames", data=frames, chunks=(1, *frames.shape[1:]),
                         **hdf5plugin.Bitshuffle(cname="lz4"))  # fmt: skip
        f["frames"].attrs.update(attrs)
        f["entry/data/frames"] = f["frames"]


@dataclass
class Archive:
    data_dir: Path
    url: str
    key: str
    proc: subprocess.Popen[str]
    stderr: list[str]

    def client(self, **kwargs: Any) -> Any:
        return from_uri(self.url, api_key=self.key, **kwargs)


def camd(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "camd", *args], capture_output=True,
                          text=True, timeout=START_TIMEOUT_S)  # fmt: skip


@pytest.fixture(scope="module")
def archive(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Archive]:
    data = tmp_path_factory.mktemp("data")
    for folder in ("scans", "recordings", "campaigns/run1/raw"):
        (data / folder).mkdir(parents=True)
    write_scan(data / "scans" / "hr400_m32.h5", name="hr400", stages=32, lines=40)
    write_scan(data / "scans" / "ibis5_m8.h5", name="ibis5", stages=8, lines=20)
    write_stare(data / "recordings" / "stare.h5", 5, seed=1)
    write_stare(data / "recordings" / "compressed.h5", 4, seed=5)
    compress_frames(data / "recordings" / "compressed.h5")
    write_stare(data / "recordings" / "empty.h5", 0, seed=0)  # stopped before its first frame
    write_stare(data / "campaigns" / "run1" / "raw" / "dark__0.h5", 3, seed=2, context={
        "activity": {"text": STEP_TEXT, "done": 0, "total": 2},
        "sample": {"scene": "dark"}})  # fmt: skip
    (data / "campaigns" / "run1" / "state.json").write_text(json.dumps(
        {"campaign": "tdi_snr_stages", "completed": {"dark[0]": {"file": "raw/dark__0.h5"}}}
    ))  # fmt: skip
    # A writer that died after its last flush: the copy is what a killed daemon leaves.
    live = start_stare(data / "live.h5", 4, seed=3)
    live.flush()
    shutil.copy(data / "live.h5", data / "recordings" / "crashed.h5")
    live.close()
    (data / "live.h5").unlink()
    with h5py.File(data / "recordings" / "foreign.h5", "w") as f:
        f["x"] = np.arange(3)
    (data / "recordings" / "garbage.h5").write_bytes(b"not HDF5 at all")

    with serving(data) as (url, proc, stderr):
        key = (data / "archive" / "api_key").read_text().strip()
        yield Archive(data, url, key, proc, stderr)


@contextlib.contextmanager
def serving(data: Path, *options: str) -> Iterator[tuple[str, subprocess.Popen[str], list[str]]]:
    """``camd archive serve DATA --port 0 OPTIONS`` as a child process, until the block ends:
    its URL (from its one stdout line), the process and its stderr lines so far."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "camd", "archive", "serve", str(data), "--port", "0", *options],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    stderr: list[str] = []
    threading.Thread(target=lambda: stderr.extend(proc.stderr or ()), daemon=True).start()
    found: list[str] = []
    reader = threading.Thread(
        target=lambda: found.append(proc.stdout.readline() if proc.stdout else "")
    )
    reader.start()
    reader.join(START_TIMEOUT_S)
    line = found[0] if found else ""
    match = re.fullmatch(r"camd archive serving (http://127\.0\.0\.1:\d+/api/v1/)\n", line)
    try:
        assert match, f"no serving line: {line!r}; stderr: {''.join(stderr)[-2000:]}"
        yield match.group(1), proc, stderr
    finally:
        proc.terminate()
        assert proc.wait(30) == 0  # SIGTERM: a clean stop


def paths(results: Any) -> set[str]:
    return {"/".join(path) for path in results}


def test_searches_by_metadata_find_exactly_the_right_nodes(archive: Archive) -> None:
    c = archive.client()
    assert paths(c.search_deep(Key("mode") == "scan")) == {"scans/hr400_m32", "scans/ibis5_m8"}
    assert paths(c.search_deep(Key("stages") == 32)) == {"scans/hr400_m32"}
    assert paths(c.search_deep(Key("profile") == "ibis5")) == {"scans/ibis5_m8"}
    assert paths(c.search_deep(Key("mode") == "stare")) == {
        "recordings/stare", "recordings/crashed", "recordings/compressed", "recordings/empty",
        "campaigns/run1/raw/dark__0"}  # fmt: skip
    assert paths(c.search_deep(Key("finished") == False)) == {"recordings/crashed"}  # noqa: E712
    assert paths(c.search_deep(Key("campaign.name") == "tdi_snr_stages")) == {
        "campaigns/run1/raw/dark__0"}  # fmt: skip
    meta = c["campaigns"]["run1"]["raw"]["dark__0"].metadata
    assert meta["campaign"] == {"name": "tdi_snr_stages", "step": "dark[0]", "run": "run1"}
    # The file's own NXnote and NXsample, searchable too.
    assert (meta["activity"], meta["sample"]) == (STEP_TEXT, "dark")
    assert paths(c.search_deep(Key("sample") == "dark")) == {"campaigns/run1/raw/dark__0"}
    scan = c["scans"]["hr400_m32"].metadata
    assert {k: scan[k] for k in ("kind", "camera", "sensor", "tdi_mode", "lines", "finished")} == {
        "kind": "scan", "camera": "hr400", "sensor": "hr400", "tdi_mode": "sum", "lines": 40,
        "finished": True}  # fmt: skip
    assert scan["date"] == scan["created_utc"][:10]
    # The foreign HDF5 file and the file that is not HDF5 are not nodes.
    assert sorted(c["recordings"]) == ["compressed", "crashed", "empty", "stare"]
    empty = c["recordings"]["empty"]
    assert (empty.metadata["frames"], empty.metadata["finished"], list(empty)) == (0, True, [])


def test_every_array_reads_back_bit_exact_against_h5py(archive: Archive) -> None:
    c = archive.client()
    checked = 0
    for path, node in c.search_deep(Key("finished") == True).items():  # noqa: E712
        file = archive.data_dir / node.metadata["file"]
        with h5py.File(file, "r") as f:
            for key in node:
                served = node[key].read()
                stored = f[node[key].metadata["dataset"]][()]
                # Bit-exact: the bytes, so that NaN (an unknown M dV/V) compares too.
                assert (served.dtype, served.shape) == (stored.dtype, stored.shape), (path, key)
                assert served.tobytes() == stored.tobytes(), (path, key)
                checked += 1
    # 2 scans x (lines + 6 columns), 3 stares x (frames + 7 columns); the empty stare has none
    assert checked == 2 * 7 + 3 * 8
    with h5py.File(archive.data_dir / "recordings" / "compressed.h5", "r") as f:
        assert "32008" in f["frames"]._filters  # Bitshuffle's filter id: compressed indeed


def test_a_crashed_recording_is_served_up_to_its_last_flush(archive: Archive) -> None:
    node = archive.client()["recordings"]["crashed"]
    assert (node.metadata["finished"], node.metadata["frames"]) == (False, 4)
    # swmr: the copy keeps the flag of a file open for writing, as a killed writer leaves it.
    with h5py.File(archive.data_dir / "recordings" / "crashed.h5", "r", swmr=True) as f:
        assert len(f["frames"]) == 6  # reserved for frames_expected: two never written
        assert np.array_equal(node["frames"].read(), f["frames"][:4])


def test_a_dask_client_reads_the_files_chunks_lazily(
    archive: Archive, monkeypatch: pytest.MonkeyPatch
) -> None:
    c = archive.client(structure_clients="dask")
    frames, lines = c["recordings"]["stare"]["frames"], c["scans"]["hr400_m32"]["lines"]
    # The server's blocks are the file's chunks: one frame; the scan's blocks of 16 lines.
    assert frames.structure().chunks == ((1,) * 5, (6,), (10,))
    assert lines.structure().chunks == ((16, 16, 8), (24,))
    # Tiled's Dask client asks for up to RESPONSE_BYTESIZE_LIMIT (100 MiB) per request, cut at
    # those blocks: with a limit of one frame, one request per frame, made when computed.
    monkeypatch.setattr(type(frames), "RESPONSE_BYTESIZE_LIMIT", 6 * 10 * 2)
    lazy = frames.read()
    assert lazy.chunks == ((1,) * 5, (6,), (10,))
    with h5py.File(archive.data_dir / "recordings" / "stare.h5", "r") as f:
        assert float(lazy.mean().compute()) == float(f["frames"][()].mean())


def test_the_key_is_required_and_never_logged(archive: Archive) -> None:
    anonymous = httpx.get(archive.url + "metadata/scans", timeout=30)
    assert anonymous.status_code == 401
    keyed = httpx.get(archive.url + "metadata/scans", params={"api_key": archive.key}, timeout=30)
    assert keyed.status_code == 200
    assert (archive.data_dir / "archive" / "api_key").stat().st_mode & 0o777 == 0o600
    # The access line comes after the response: wait for it to reach the pipe and the reader.
    wait_for(
        "the keyed request's access line",
        lambda: "GET /api/v1/metadata/scans?api_key=*** HTTP/1.1" in "".join(archive.stderr),
        timeout_s=30,
    )
    assert archive.key not in "".join(archive.stderr)


def test_public_reading_needs_no_key_beside_another_server(archive: Archive) -> None:
    # A second server over the same SQLite catalogue: the one machine's several readers.
    with serving(archive.data_dir, "--public") as (url, _, stderr):
        assert httpx.get(url + "metadata/scans", timeout=30).status_code == 200
        public = from_uri(url, api_key=None)
        assert paths(public.search_deep(Key("stages") == 32)) == {"scans/hr400_m32"}
        assert paths(archive.client().search_deep(Key("stages") == 32)) == {"scans/hr400_m32"}
        wait_for("the public notice", lambda: "(reading is public)" in "".join(stderr), 30)


def test_docs_dask_example_computes_the_level_per_scan(
    archive: Archive, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    text = ARCHIVE_MD.read_text(encoding="utf-8")
    code = re.search(r"<!-- run by tests/test_archive\.py -->\n```python\n(.*?)```", text, re.S)
    assert code, "docs/archive.md has no example marked as run by tests/test_archive.py"
    monkeypatch.setenv("TILED_API_KEY", archive.key)
    exec(code.group(1).replace("http://127.0.0.1:8423/api/v1/", archive.url), {})
    expected = {}
    for name in ("hr400_m32", "ibis5_m8"):
        with h5py.File(archive.data_dir / "scans" / f"{name}.h5", "r") as f:
            expected[f"scans/{name}"] = f["lines"][()].mean() / f["scan"].attrs["stages"]
    assert capsys.readouterr().out == "".join(
        f"{name}: {level:.3f} DN per stage\n" for name, level in sorted(expected.items())
    )


def test_a_file_written_after_the_start_appears_after_index(archive: Archive) -> None:
    c = archive.client()
    assert paths(c.search_deep(Key("stages") == 16)) == set()
    write_scan(archive.data_dir / "scans" / "late_m16.h5", name="hr400", stages=16, lines=10)
    (archive.data_dir / "recordings" / "stare.h5").unlink()
    (archive.data_dir / "recordings" / "compressed.h5").write_bytes(b"damaged")
    done = camd("archive", "index", str(archive.data_dir))
    assert done.returncode == 0, done.stderr
    assert done.stdout == (
        f"indexed {archive.data_dir}: 1 added, 0 replaced, 2 removed, 5 unchanged, 2 skipped\n"
    )
    assert "skipped recordings/garbage.h5: cannot open" in done.stderr
    assert "skipped recordings/compressed.h5: cannot open" in done.stderr
    assert paths(c.search_deep(Key("stages") == 16)) == {"scans/late_m16"}
    # Gone, and no longer readable: neither keeps a node that would serve what is not there.
    assert sorted(c["recordings"]) == ["crashed", "empty"]
    with h5py.File(archive.data_dir / "scans" / "late_m16.h5", "r") as f:
        assert np.array_equal(c["scans"]["late_m16"]["lines"].read(), f["lines"][()])


def test_a_file_being_written_is_replaced_as_it_grows(
    archive: Archive, capsys: pytest.CaptureFixture[str]
) -> None:
    path = archive.data_dir / "recordings" / "growing.h5"
    rec = start_stare(path, 3, seed=4)  # open for writing (SWMR) in this process, as the daemon
    c = archive.client()

    def index_and_read() -> tuple[str, Any, np.ndarray]:
        # In this process (camd's main, as the command runs it): Tiled is loaded already.
        assert camd_main(["archive", "index", str(archive.data_dir)]) == 0
        counts = capsys.readouterr().out.split(": ", 1)[1].split(", ")
        node = c["recordings"]["growing"]
        return ", ".join(counts[:2]), node.metadata, node["frames"].read()

    try:
        rec.flush()
        counts, meta, frames = index_and_read()
        assert (counts, meta["finished"], meta["frames"], len(frames)) == (
            "1 added, 0 replaced", False, 3, 3)  # fmt: skip
        px = np.full((6, 10), 7, np.uint16)
        rec.add(header(3, px), px, received_ns=3)
        rec.flush()
        counts, meta, frames = index_and_read()
        assert (counts, meta["finished"], meta["frames"]) == ("0 added, 1 replaced", False, 4)
        assert np.array_equal(frames[3], px)
    finally:
        rec.close()
    counts, meta, frames = index_and_read()
    assert (counts, meta["finished"], meta["frames"]) == ("0 added, 1 replaced", True, 4)
    with h5py.File(path, "r") as f:
        assert np.array_equal(frames, f["frames"][()])


@pytest.mark.parametrize("made", ["missing", "file", "empty"])
def test_a_bad_data_dir_is_refused_and_nothing_is_made(
    tmp_path: Path, made: str, capsys: pytest.CaptureFixture[str]
) -> None:
    target = tmp_path / "data"
    if made == "file":
        target.write_text("")
    elif made == "empty":
        target.mkdir()
    before = sorted(os.listdir(tmp_path))
    assert camd_main(["archive", "serve", str(target), "--port", "0"]) == 2
    why = {
        "missing": f"the data directory {target} does not exist",
        "file": f"{target} is not a directory",
        "empty": f"{target} is not a camd data directory: it holds none of recordings, scans, "
        "campaigns, telemetry.sqlite",
    }[made]
    assert capsys.readouterr().err == (
        f"camd archive serve: error: {why}; give the daemon's data directory "
        "(daemon.data_dir in its config, docs/config.md)\n"
    )
    assert sorted(os.listdir(tmp_path)) == before
    if made == "empty":
        assert os.listdir(target) == []


def test_a_port_in_use_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "scans").mkdir()
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        assert camd_main(["archive", "serve", str(tmp_path), "--port", str(port)]) == 2
    assert capsys.readouterr().err.endswith(
        f"camd archive serve: error: cannot listen on 127.0.0.1:{port}: Address already in use; "
        "stop what uses the port or choose another with --port\n"
    )


def test_an_unreachable_catalogue_is_refused_without_its_password(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    (tmp_path / "scans").mkdir()
    with socket.socket() as closed:  # a port that nothing listens on
        closed.bind(("127.0.0.1", 0))
        port = closed.getsockname()[1]
    uri = f"postgresql://camd:hunter2@127.0.0.1:{port}/archive"
    assert camd_main(["archive", "index", str(tmp_path), "--catalog", uri]) == 2
    err = capsys.readouterr().err
    assert err.startswith(
        f"camd archive index: error: cannot open the catalogue "
        f"postgresql://camd:***@127.0.0.1:{port}/archive: ConnectionRefusedError: "
    )
    assert err.endswith(
        "; check --catalog (a PostgreSQL server must be reachable, an SQLite file's folder "
        "writable)\n"
    )
    assert "hunter2" not in err
    assert sorted(os.listdir(tmp_path)) == [
        "scans"
    ]  # no archive folder: the catalogue is elsewhere
