"""Raw frame recordings in HDF5: the frames bit-exact, each frame's header, and the metadata.

One file per recording::

    /frames            (N, rows, cols) uint16, one chunk per frame, compressed losslessly as
                       the recorder was told (``camd.store.compression``; by default Bitshuffle
                       + LZ4), its attributes ``compression`` and ``compression_level`` say how
    /frame_counter     (N,) uint32   the device's frame counter
    /timestamp_ns      (N,) uint64   the device clock at the end of window row 0's exposure
    /received_unix_ns  (N,) uint64   host time the frame was complete (UTC, ns since 1970)
    /flags             (N,) uint32   header flags (docs/stream.md)
    /stage_position    (N,) int32    scan-stage encoder count at frame start
    /payload_crc32     (N,) uint32   the device's CRC of the payload, to re-check the pixels
    /gap_before        (N,) uint32   frames missing just before this one
    /frames_flushed    (1,) int64    how many frames are on disk: written after each flush has put
                                     them there (docs/stream.md "Crash safety")
    /profile, /registers, /timing, /stream   groups whose attributes hold the metadata
    /background        group, only in a recording started while the live view had a background:
                       /background/mean_dn (rows, cols) float32, its attributes say how it was
                       captured (frames, rows, cols, mode, stages, first_counter, last_counter,
                       captured_utc); see ``write_background``
    /sample, /activity groups the daemon gives (the scene, the campaign step), and any other
    /entry             the NeXus entry (format 3, all of the file since 4; ``camd.store.nexus``):
                       NXdata with /frames as its signal against frame_counter, row and column,
                       NXdetector with the sensor, every dataset (hard links) and every metadata
                       group's values with units, end_time, for tools that know NeXus (silx,
                       h5web, nexusformat)

Root attributes: ``format`` ("camd-recording"), ``format_version``, ``mode``, ``bits``,
``rows``, ``cols``, ``line_period_s``, ``created_utc``, ``camd_version``, ``frames_expected``,
``finished`` (False until the recording is closed) and, once closed, ``frames``. A recording
that holds fewer frames than asked for says why in ``ended_early`` (the camera ended the stream,
it died, or the disk filled); one whose writes failed (a full disk) keeps ``finished`` False and
says why in ``error``, and holds every frame written before (``frames`` = ``/frames_flushed`` =
the length of ``/frames``). A file whose writer died keeps ``finished`` False; the daemon that
starts next repairs it and adds ``interrupted`` and ``recovered_utc``
(``camd.store.durability``).

The file is written in HDF5's SWMR mode (file format 1.10, readable by HDF5 1.10 and later):
the frames' geometry comes with the first frame, the mode is switched on then, and the recorder
flushes at least every ``flush_period_s`` while frames arrive, so that a reader in another
process (``camd.store.recording_reading.read_recording``, or ``h5py.File(path, "r", swmr=True)``) sees the frames up to the
last flush and a killed writer loses only the frames since.
Nested metadata is flattened to dotted attribute names (``adc.adc_bits``) so that any HDF5
viewer shows it; ``read_recording`` puts it back together. ``None`` values are not stored.
"""

from __future__ import annotations

import datetime as dt
import os
import shutil
import time
from collections.abc import Callable, Mapping
from importlib import metadata as importlib_metadata
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import numpy.typing as npt

from camd.protocol.stream import FrameHeader, StreamMode
from camd.store.compression import DEFAULT, Compression, chunk_bound_bytes
from camd.store.durability import (
    FLUSH_PERIOD_S,
    FlushedWriter,
    Headroom,
    close_writer,
    create_file,
    discard_new_file,
    reopen_to_finish,
    retry_held,
    write_failure,
)
from camd.store.line_buffer import write_rows
from camd.store.nexus import (
    ENTRY,
    ENTRY_NAMES,
    Axis,
    camera_name,
    finish_nexus,
    sensor_fields,
    write_nexus,
    write_settings,
)

FORMAT = "camd-recording"
# 2: SWMR (HDF5 1.10 format), /frames_flushed, the ``finished`` attribute; 3: the NeXus entry
# (camd.store.nexus); 4: the entry holds every dataset (hard links: the root's names stay) and
# every setting (the metadata groups as NXparameters/NXcollection fields with units, the stage
# as an NXpositioner, the sample, the campaign step), the signal's units and interpretation,
# end_time. A reader needs none of these: older files read as before.
FORMAT_VERSION = 4
METADATA_GROUPS = ("profile", "registers", "timing", "stream")
BACKGROUND_GROUP = "background"
# Space kept to finish the file on a full disk (durability.Headroom): what HDF5 may hold unwritten
# when the disk fills, the per-frame columns' chunks (7 x 32 KiB at most between two flushes: the
# frames themselves go to disk as they come, no chunk cache), and the metadata.
RESERVE_BYTES = 4 << 20
# Besides a frame's pixels, what a write may take: the columns' chunks a flush writes (7 x 32 KiB)
# and the metadata it changes.
_MARGIN_BYTES = 512 << 10
_PER_FRAME: dict[str, npt.DTypeLike] = {
    "frame_counter": np.uint32,
    "timestamp_ns": np.uint64,
    "received_unix_ns": np.uint64,
    "flags": np.uint32,
    "stage_position": np.int32,
    "payload_crc32": np.uint32,
    "gap_before": np.uint32,
}


# The root's datasets: no metadata group may take their names.
PER_FRAME_COLUMNS = tuple(_PER_FRAME)
"""The per-frame datasets (frame_counter, timestamp_ns, ...), each as long as /frames."""
_RESERVED_NAMES = frozenset({"frames", "frames_flushed", *_PER_FRAME})


class RecordingError(OSError):
    """A recording cannot be written or read; the message names the file and what to do."""


def check_new_file(path: Path, planned_bytes: int = 0, reserve_bytes: int = RESERVE_BYTES) -> None:
    """Refuse, before anything is recorded, a file that cannot be written: one that exists, in
    a directory that does not exist or is not writable, or on a disk with less free space than
    ``planned_bytes`` plus the ``reserve_bytes`` its recorder holds back to close the file if
    the disk fills (a frame recording's by default; a scan's is ``TdiRecorder.reserve_bytes``).
    RecordingError says what to change."""
    if path.exists():
        raise RecordingError(f"{path} already exists; choose another file or remove it")
    folder = path.parent
    if not folder.is_dir():
        raise RecordingError(
            f"the directory {folder} does not exist; create it first (mkdir -p {folder}) or "
            "choose another file"
        )
    if not os.access(folder, os.W_OK | os.X_OK):
        raise RecordingError(
            f"cannot create files in {folder} (no write permission for the daemon's user); "
            "choose another directory"
        )
    free = shutil.disk_usage(folder).free
    if free < planned_bytes + reserve_bytes:
        raise RecordingError(
            f"the recording needs about {planned_bytes / 1e6:.1f} MB, and "
            f"{reserve_bytes / 1e6:.1f} MB more held back to close the file safely if the disk "
            f"fills, but {folder} has {free / 1e6:.1f} MB free; free some space, choose "
            "another disk, or record less"
        )


def write_background(parent: h5py.Group, mean_dn: npt.ArrayLike, attrs: Mapping[str, Any]) -> None:
    """Store a background (the mean of N frames, DN) as ``parent``'s group ``background``: the
    image as the float32 dataset ``mean_dn``, ``attrs`` (flattened) as the group's attributes."""
    group = parent.create_group(BACKGROUND_GROUP)
    group.create_dataset("mean_dn", data=np.asarray(mean_dn, dtype=np.float32))
    group.attrs.update(flatten_attrs(attrs))


def camd_version() -> str:
    """The installed camd's version, or "unknown" when running from an uninstalled checkout."""
    try:
        return importlib_metadata.version("camd")
    except importlib_metadata.PackageNotFoundError:
        return "unknown"


def flatten_attrs(values: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """Nested mappings to dotted attribute names (``adc.adc_bits``); ``None`` values dropped."""
    flat: dict[str, Any] = {}
    for key, value in values.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping):
            flat.update(flatten_attrs(value, f"{name}."))
        elif value is None:
            continue
        elif isinstance(value, (list, tuple)):
            flat[name] = np.asarray(value) if value else np.zeros(0)
        else:
            flat[name] = value
    return flat


def unflatten_attrs(attrs: Mapping[str, Any]) -> dict[str, Any]:
    """HDF5 attributes (dotted names) back to nested dicts of plain Python values."""
    out: dict[str, Any] = {}
    for name, raw in attrs.items():
        value: Any = raw
        if isinstance(value, np.ndarray):
            value = value.tolist()
        elif isinstance(value, np.generic):
            value = value.item()
        elif isinstance(value, bytes):
            value = value.decode()
        node = out
        *parents, leaf = name.split(".")
        for part in parents:
            node = node.setdefault(part, {})
        node[leaf] = value
    return out


def _check_groups(path: Path, metadata: Mapping[str, Any]) -> None:
    """RecordingError unless every metadata group of the recording ``path`` has a name free
    for it."""
    for group in metadata:
        if group in (ENTRY, BACKGROUND_GROUP, *ENTRY_NAMES, *_RESERVED_NAMES):
            raise RecordingError(
                f"{group!r} cannot be a metadata group of the recording {path}: it names one "
                "of its datasets, its background or a part of its NeXus entry; use another name"
            )


def _finish_with(add: Callable[[h5py.File], None] | None, f: h5py.File) -> str | None:
    """Run ``add(f)`` (if given); why it failed, or None. Its failure (a full disk, a name HDF5
    refuses) loses what it adds, not the recording."""
    if add is None:
        return None
    try:
        add(f)
    except (OSError, ValueError, RuntimeError) as exc:
        return str(exc) or type(exc).__name__
    return None


def _write_nexus(
    f: h5py.File,
    metadata: Mapping[str, Mapping[str, Any]],
    created_utc: str,
    geometry: tuple[int, int, int, str, float],
) -> None:
    """A frame recording's NeXus entry (camd.store.nexus): the frames against frame counter,
    row, column; ``geometry`` is (rows, cols, bits, mode, line_period_s)."""
    rows, cols, bits, mode, line_period_s = geometry
    profile = metadata.get("profile", {})
    timing = metadata.get("timing", {})
    stream = metadata.get("stream", {})
    camera = camera_name(profile)
    write_nexus(
        f,
        title=f"frames, {camera}, {rows} x {cols}, {mode} mode",
        start_time=created_utc,
        program=f"camd {camd_version()}",
        instrument=camera,
        detector={
            **sensor_fields(profile),
            "bit_depth_readout": (bits or None, ""),
            "frame_time": (line_period_s or None, "s"),
            "count_time": (timing.get("exposure_s"), "s"),
        },
        tdi={"stages": stream.get("stages")} if mode == "tdi" else None,
        signal="frames",
        axes=(
            Axis("frame_counter", link="frame_counter", long_name="device frame counter"),
            Axis("row", values=np.arange(rows), long_name="window row (pixel)"),
            Axis("column", values=np.arange(cols), long_name="column (pixel)"),
        ),
        per_element=("per_frame", (*_PER_FRAME, "frames_flushed")),
        stage="stage_position",
    )


def _trim_frames(f: h5py.File, count: int) -> None:
    """A recording ``f`` cut to its first ``count`` frames."""
    for name in ("frames", *_PER_FRAME):
        if name in f:  # a file whose first frame failed may lack some
            f[name].resize(count, axis=0)
    if "frames_flushed" in f:
        f["frames_flushed"][0] = count


class FrameRecorder(FlushedWriter):
    """Appends streamed frames to a new HDF5 file; ``close(stats)`` finishes it.

    The file is created at once with its metadata (so a bad path fails before the stream
    starts) and never overwrites an existing file; a file it could not set up is removed.
    Frames go to disk as they are added and are flushed, with their count, at least every
    ``flush_period_s`` (module docstring); a failed write (a full disk) raises RecordingError
    saying so, the file keeps every frame written before it (their count flushed at once, with
    the space the recorder held back), and the recorder then refuses further frames (``failed``
    says why). The frame geometry (rows, columns, bits, mode, line period) is taken from the
    first frame's header unless given; a later frame of another shape is refused. ``metadata``
    maps group name (profile, registers, timing, stream, and any other but the datasets' and
    the entry's names) to a dict. ``background_dn`` (with ``background_attrs``) is stored as
    ``/background``. ``compression`` is how each frame's chunk is compressed
    (``camd.store.compression``).
    """

    def __init__(
        self,
        path: Path | str,
        *,
        metadata: Mapping[str, Mapping[str, Any]] | None = None,
        frames_expected: int = 0,
        rows: int | None = None,
        cols: int | None = None,
        bits: int | None = None,
        mode: StreamMode | str | None = None,
        line_period_s: float | None = None,
        background_dn: npt.ArrayLike | None = None,
        background_attrs: Mapping[str, Any] | None = None,
        flush_period_s: float = FLUSH_PERIOD_S,
        compression: Compression = DEFAULT,
    ) -> None:
        self.path = Path(path)
        self.compression = compression
        _check_groups(self.path, metadata or {})
        retry_held()  # a file an earlier full disk held open, closed if the space is back
        if self.path.exists():
            raise RecordingError(
                f"{self.path} already exists; choose another --out or remove the old file"
            )
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            # SWMR needs the 1.10 file format.
            self._file = create_file(self.path, "the recording", libver=("v110", "latest"))
        except OSError as exc:
            raise RecordingError(str(exc)) from None
        self.count = 0  # frames added whose writes went through
        self.flushed = 0  # frames on disk: what the file keeps if the writer dies now
        self.failed: str | None = None  # why writing stopped (a full disk), None while it works
        self.finish_error: str | None = None  # why close's finish_with failed (file kept)
        self._closed = False
        self._flush_period_s = flush_period_s
        self._last_flush = time.monotonic()
        self._frames_expected = frames_expected
        self._metadata = metadata or {}
        # Host time of a frame = monotonic receive time + this offset (ns since 1970, UTC).
        self._unix_offset_ns = time.time_ns() - time.monotonic_ns()
        self._created_utc = dt.datetime.now(dt.UTC).isoformat(timespec="milliseconds")
        self._frames: Any = None
        self._frames_flushed: Any = None
        self._columns: dict[str, Any] = {}
        # The columns' values of the frames added since the last flush, written to the file by
        # the next flush, one write per column instead of seven per frame; and written afresh
        # after a failed write (a flush that fails on a full disk cannot simply be tried again:
        # HDF5 then writes a new chunk without adding it to the dataset's index; ``_failed``).
        self._unflushed: list[tuple[int, ...]] = []
        self._columns_written = 0  # frames whose column values are in the datasets
        self.rows = self.cols = 0
        self._capacity = 0
        try:
            self._headroom = Headroom(self._file, RESERVE_BYTES)
            background = 0 if background_dn is None else 4 * np.size(background_dn)
            self._headroom.ensure(background + _MARGIN_BYTES)
            self._start_file(metadata, background_dn, background_attrs)
            if rows is not None and cols is not None:
                self._create(rows, cols, bits or 16, mode or StreamMode.AREA, line_period_s or 0.0)
        except (OSError, RuntimeError) as exc:  # h5py reports a failed flush as RuntimeError
            # Nothing recorded yet: leave no file behind (a retry with the same name works).
            discard_new_file(self._file, self.path, self)
            raise RecordingError(
                f"cannot create the recording {self.path}: {write_failure(self.path, exc)}"
            ) from None

    def _start_file(
        self,
        metadata: Mapping[str, Mapping[str, Any]] | None,
        background_dn: npt.ArrayLike | None,
        background_attrs: Mapping[str, Any] | None,
    ) -> None:
        """The root attributes, the metadata groups and the background, flushed."""
        self._file.attrs.update(
            {
                "format": FORMAT,
                "format_version": FORMAT_VERSION,
                "created_utc": self._created_utc,
                "camd_version": camd_version(),
                "frames_expected": self._frames_expected,
                "finished": False,
            }
        )
        given = metadata or {}
        # The four groups always; any other the caller gives (the sample, the campaign step).
        for group in (*METADATA_GROUPS, *(g for g in given if g not in METADATA_GROUPS)):
            self._file.create_group(group).attrs.update(flatten_attrs(given.get(group, {})))
        if background_dn is not None:
            write_background(self._file, background_dn, background_attrs or {})
        # The settings' NeXus copy now, not with the first frame: it takes tens of ms.
        write_settings(self._file, {g: given.get(g, {}) for g in (*METADATA_GROUPS, *given)})
        self._headroom.flush()

    def _create(
        self, rows: int, cols: int, bits: int, mode: StreamMode | str, line_period_s: float
    ) -> None:
        f = self._file
        self._headroom.ensure(_MARGIN_BYTES)
        self.rows, self.cols = rows, cols
        mode_name = mode.name.lower() if isinstance(mode, StreamMode) else str(mode)
        f.attrs.update(
            {
                "mode": mode_name,
                "bits": bits,
                "rows": rows,
                "cols": cols,
                "line_period_s": line_period_s,
            }
        )
        # No chunk cache: each frame goes to disk as it is added, so that a full disk shows at
        # the frame that does not fit, and HDF5 never holds frames that closing the file would
        # have to write (HDF5 2's default 8 MiB cache holds three hr400 frames).
        no_cache = h5py.h5p.create(h5py.h5p.DATASET_ACCESS)
        no_cache.set_chunk_cache(1, 0, 1.0)
        self._frames = f.create_dataset(
            "frames",
            shape=(0, rows, cols),
            maxshape=(None, rows, cols),
            dtype=np.uint16,
            chunks=(1, rows, cols),
            dapl=no_cache,
            **self.compression.dataset_options(),
        )
        self._frames.attrs.update(self.compression.attrs())
        self._columns = {
            name: f.create_dataset(name, shape=(0,), maxshape=(None,), dtype=dtype, chunks=(4096,))
            for name, dtype in _PER_FRAME.items()
        }
        self._frames_flushed = f.create_dataset("frames_flushed", data=np.zeros(1, np.int64))
        _write_nexus(
            f, self._metadata, self._created_utc, (rows, cols, bits, mode_name, line_period_s)
        )
        self._reserve(max(self._frames_expected, 1))
        # Every object exists now: from here on the file is only appended to, in SWMR mode.
        f.swmr_mode = True
        self._headroom.flush()

    def _reserve(self, frames: int) -> None:
        if frames <= self._capacity:
            return
        self._frames.resize(frames, axis=0)
        for column in self._columns.values():
            column.resize(frames, axis=0)
        self._capacity = frames

    def add(
        self,
        header: FrameHeader,
        pixels: npt.NDArray[np.uint16],
        *,
        received_ns: int,
        gap_before: int = 0,
    ) -> None:
        """Append one frame (the pixels are copied into the file at once); RecordingError if it
        cannot be written (the message says why, e.g. a full disk)."""
        if self.failed is not None:
            raise RecordingError(self.failed)
        try:
            self._add(header, pixels, received_ns, gap_before)
            if time.monotonic() - self._last_flush >= self._flush_period_s:
                self.flush()
        except RecordingError:
            raise  # the caller's mistake (a frame of another shape): the file is fine
        except (OSError, RuntimeError) as exc:  # h5py reports a failed flush as RuntimeError
            raise self._failed(exc) from None

    def _failed(self, exc: BaseException) -> RecordingError:
        """Writing failed (a full disk): put on disk every frame whose write went through
        (``count``), with that count, so that nothing but the frame that did not fit is lost
        and the file can be closed; the error to raise. On a clean ``NoRoom`` HDF5 has
        written nothing and flushes into the headroom's reserve; after a failed HDF5 write the
        columns since the last flush are written afresh (``_unflushed``)."""
        kept = self._keep_after(exc, written=self.count, flushed=self.flushed)
        self.count = kept
        self._columns_written = min(self._columns_written, kept)
        self.failed = (
            f"{write_failure(self.path, exc)}; the recording keeps the {kept} frames written before"
        )
        return RecordingError(self.failed)

    def _trim_and_flush(self, count: int) -> None:
        _trim_frames(self._file, count)
        self._headroom.flush(regrow=False)

    def _flush_count(self, *, regrow: bool = True) -> None:
        """Flush the frames so far, then their count; then (``regrow``) the headroom is made
        whole again (``Headroom.flush``: NoRoom if it cannot be, all flushed all the same)."""
        self._put_columns()
        self._headroom.flush(regrow=False)
        if self._frames_flushed is not None:
            self._frames_flushed[0] = self.count
            self._headroom.flush(regrow=False)
        self.flushed = self.count
        self._unflushed.clear()
        if regrow:
            self._headroom.ensure(0)

    def _rewrite_unflushed(self) -> None:
        """After a failed write: the columns of the frames since the last flush written afresh
        (their chunks dropped first: HDF5 cannot be trusted to write them again, see
        ``_unflushed``), then everything flushed, with the count."""
        f = self._file
        if self._frames_flushed is None:  # the first frame's datasets failed: nothing to keep
            self._headroom.flush(regrow=False)
            return
        flushed, count = self.flushed, self.count
        for column in self._columns.values():
            column.resize(flushed, axis=0)
            column.resize(count, axis=0)
        self._columns_written = flushed
        self._put_columns()
        _trim_frames(f, count)
        self._headroom.flush(regrow=False)
        self._frames_flushed[0] = count
        self._headroom.flush(regrow=False)
        self.flushed = count
        self._unflushed.clear()

    def flush(self) -> None:
        """Put the frames so far on disk (where readers see them and a kill leaves them),
        then their count (``/frames_flushed``)."""
        if self._frames is None:
            return
        self._headroom.ensure(_MARGIN_BYTES)
        self._flush_count()
        self._last_flush = time.monotonic()

    def _add(
        self,
        header: FrameHeader,
        pixels: npt.NDArray[np.uint16],
        received_ns: int,
        gap_before: int,
    ) -> None:
        if self._frames is None:
            rows, cols = pixels.shape
            self._create(rows, cols, header.bits, header.mode, header.line_period_ns * 1e-9)
        if pixels.shape != (self.rows, self.cols):
            raise RecordingError(
                f"{self.path}: frame {header.counter} is {pixels.shape[0]} x {pixels.shape[1]}, "
                f"the recording is {self.rows} x {self.cols}; the window changed mid-recording"
            )
        i = self.count
        if i >= self._capacity:
            self._reserve(max(2 * self._capacity, 16))
        # Compressed, a frame of noise may take a little more than its pixels' bytes.
        self._headroom.ensure(chunk_bound_bytes(pixels.nbytes, self.compression) + _MARGIN_BYTES)
        frame = np.ascontiguousarray(pixels, dtype="<u2")
        if self.compression.on:
            # Through the filter, straight to disk: a whole chunk and no chunk cache.
            write_rows(self._frames, i, frame[np.newaxis])
        else:
            # A frame is one chunk: written as it is on disk, at once (no chunk cache to go
            # through, nothing held), without h5py's selection machinery.
            self._frames.id.write_direct_chunk((i, 0, 0), frame)
        # In _PER_FRAME's order; written by the next flush (``_put_columns``).
        self._unflushed.append(
            (
                header.counter,
                header.timestamp_ns,
                received_ns + self._unix_offset_ns,
                int(header.flags),
                header.stage_position,
                header.payload_crc32,
                gap_before,
            )
        )
        self.count += 1

    def _put_columns(self) -> None:
        """Write the column values of the frames since the last flush (not flushed), one
        hyperslab per column, unless they are in the datasets already."""
        if self._columns_written >= self.count or not self._columns:
            return
        start = self.flushed
        by_column = zip(*self._unflushed, strict=True)  # one tuple per column
        for (name, dtype), values in zip(_PER_FRAME.items(), by_column, strict=True):
            write_rows(self._columns[name], start, np.array(values, dtype=dtype))
        self._columns_written = self.count

    def close(
        self,
        stream_stats: Mapping[str, Any] | None = None,
        *,
        ended_early: str | None = None,
        finish_with: Callable[[h5py.File], None] | None = None,
    ) -> Path:
        """Trim to the frames received, store the stream's counters, mark the file finished,
        close; return the path. ``ended_early``: why the stream ended before its frames were
        all sent (the camera ended it, or died), kept as the root attribute ``ended_early``.
        ``finish_with(f)`` adds the rest (the ROI statistics) before the file counts as closed;
        its failure is said in ``finish_error``, the recording kept. After a failed write
        (``failed``), the file keeps the frames written before it, ``finished`` stays False and
        ``error`` says why. RecordingError if the file cannot even be closed that way: if the
        disk is still full it stays open, held by this process (``camd.store.durability``), for
        the next start to repair."""
        if self._closed:
            return self.path
        self._closed = True
        if self.failed is None:
            self._flush_before_close(_MARGIN_BYTES)
        count = self.count
        why = close_writer(self._file, self.path, self)
        if why is not None:
            self.failed = self.failed or why
            raise RecordingError(
                f"{self.failed}; {self.path} cannot be closed and stays open until the space is "
                "back (camd repairs it when it starts again; h5py.File(path, 'r', swmr=True) "
                f"reads its {self.flushed} flushed frames now)"
            )
        # An SWMR writer may not add or change attributes: reopen the file to finish it.
        try:
            with reopen_to_finish(self.path) as f:
                self._finish(f, count, stream_stats, ended_early)
                self.finish_error = _finish_with(finish_with, f)
            self.flushed = count
        except (OSError, RuntimeError) as exc:
            raise RecordingError(
                f"{self.failed or write_failure(self.path, exc)}; {self.path} keeps its "
                f"{self.flushed} flushed frames but is not marked as ended (camd repairs it "
                "when it starts again; h5py.File(path, 'r', swmr=True) reads it now)"
            ) from None
        return self.path

    def _finish(
        self,
        f: h5py.File,
        count: int,
        stream_stats: Mapping[str, Any] | None,
        ended_early: str | None,
    ) -> None:
        if "frames" not in f:
            # No frame came: an empty recording, still readable.
            f.attrs.update({"mode": "none", "bits": 0, "rows": 0, "cols": 0})
            f.create_dataset("frames", shape=(0, 0, 0), dtype=np.uint16)
            for name, dtype in _PER_FRAME.items():
                f.create_dataset(name, shape=(0,), dtype=dtype)
            f.create_dataset("frames_flushed", data=np.zeros(1, np.int64))
            _write_nexus(f, self._metadata, self._created_utc, (0, 0, 0, "none", 0.0))
        else:
            _trim_frames(f, count)
        attrs: dict[str, Any] = {"frames": count, "finished": self.failed is None}
        if self.failed is not None:
            attrs["error"] = self.failed  # finished = False and the error say it ended early
        if ended_early or self.failed:
            attrs["ended_early"] = ended_early or self.failed
        f.attrs.update(attrs)
        if stream_stats:
            f["stream"].attrs.update(flatten_attrs(stream_stats))
        finish_nexus(f, {"stream": stream_stats or {}})

    def __enter__(self) -> FrameRecorder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
