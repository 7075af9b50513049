"""Raw frame recordings in HDF5: the frames bit-exact, each frame's header, and the metadata.

One file per recording::

    /frames            (N, rows, cols) uint16, one chunk per frame, gzip-free (bit-exact, fast)
    /frame_counter     (N,) uint32   the device's frame counter
    /timestamp_ns      (N,) uint64   the device clock at the end of window row 0's exposure
    /received_unix_ns  (N,) uint64   host time the frame was complete (UTC, ns since 1970)
    /flags             (N,) uint32   header flags (docs/stream.md)
    /stage_position    (N,) int32    scan-stage encoder count at frame start
    /payload_crc32     (N,) uint32   the device's CRC of the payload, to re-check the pixels
    /gap_before        (N,) uint32   frames missing just before this one
    /profile, /registers, /timing, /stream   groups whose attributes hold the metadata
    /background        group, only in a recording started while the live view had a background:
                       /background/mean_dn (rows, cols) float32, its attributes say how it was
                       captured (frames, rows, cols, mode, stages, first_counter, last_counter,
                       captured_utc); see ``write_background``

Root attributes: ``format`` ("camd-recording"), ``format_version``, ``mode``, ``bits``,
``rows``, ``cols``, ``line_period_s``, ``created_utc``, ``camd_version``, ``frames_expected``.
Nested metadata is flattened to dotted attribute names (``adc.adc_bits``) so that any HDF5
viewer shows it; ``read_recording`` puts it back together. ``None`` values are not stored.
"""

from __future__ import annotations

import datetime as dt
import os
import shutil
import time
from collections.abc import Mapping
from dataclasses import dataclass
from importlib import metadata as importlib_metadata
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import numpy.typing as npt

from camd.protocol.stream import FrameHeader, StreamMode, crc32

FORMAT = "camd-recording"
FORMAT_VERSION = 1
METADATA_GROUPS = ("profile", "registers", "timing", "stream")
BACKGROUND_GROUP = "background"
_PER_FRAME: dict[str, npt.DTypeLike] = {
    "frame_counter": np.uint32,
    "timestamp_ns": np.uint64,
    "received_unix_ns": np.uint64,
    "flags": np.uint32,
    "stage_position": np.int32,
    "payload_crc32": np.uint32,
    "gap_before": np.uint32,
}


class RecordingError(OSError):
    """A recording cannot be written or read; the message names the file and what to do."""


def check_new_file(path: Path, planned_bytes: int = 0) -> None:
    """Refuse, before anything is recorded, a file that cannot be written: one that exists, in
    a directory that does not exist or is not writable, or on a disk with less free space than
    ``planned_bytes``. RecordingError says what to change."""
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
    if free < planned_bytes:
        raise RecordingError(
            f"the recording needs about {planned_bytes / 1e6:.1f} MB but {folder} has "
            f"{free / 1e6:.1f} MB free; free some space, choose another disk, or record less"
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


class FrameRecorder:
    """Appends streamed frames to a new HDF5 file; ``close(stats)`` finishes it.

    The file is created at once with its metadata (so a bad path fails before the stream
    starts) and never overwrites an existing file. The frame geometry (rows, columns, bits,
    mode, line period) is taken from the first frame's header unless given; a later frame of
    another shape is refused. ``metadata`` maps group name (profile, registers, timing, stream)
    to a dict. ``background_dn`` (with ``background_attrs``) is stored as ``/background``.
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
    ) -> None:
        self.path = Path(path)
        if self.path.exists():
            raise RecordingError(
                f"{self.path} already exists; choose another --out or remove the old file"
            )
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._file = h5py.File(self.path, "w-")
        except OSError as exc:
            raise RecordingError(
                f"cannot create the recording {self.path}: {exc}; check that the daemon's user "
                "may write there"
            ) from None
        self.count = 0
        self._frames_expected = frames_expected
        # Host time of a frame = monotonic receive time + this offset (ns since 1970, UTC).
        self._unix_offset_ns = time.time_ns() - time.monotonic_ns()
        self._file.attrs.update(
            {
                "format": FORMAT,
                "format_version": FORMAT_VERSION,
                "created_utc": dt.datetime.now(dt.UTC).isoformat(timespec="milliseconds"),
                "camd_version": camd_version(),
                "frames_expected": frames_expected,
            }
        )
        for group in METADATA_GROUPS:
            self._file.create_group(group).attrs.update(
                flatten_attrs((metadata or {}).get(group, {}))
            )
        if background_dn is not None:
            write_background(self._file, background_dn, background_attrs or {})
        self.rows = self.cols = 0
        self._frames: Any = None
        self._columns: dict[str, Any] = {}
        self._capacity = 0
        if rows is not None and cols is not None:
            self._create(rows, cols, bits or 16, mode or StreamMode.AREA, line_period_s or 0.0)

    def _create(
        self, rows: int, cols: int, bits: int, mode: StreamMode | str, line_period_s: float
    ) -> None:
        f = self._file
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
        self._frames = f.create_dataset(
            "frames",
            shape=(0, rows, cols),
            maxshape=(None, rows, cols),
            dtype=np.uint16,
            chunks=(1, rows, cols),
        )
        self._columns = {
            name: f.create_dataset(name, shape=(0,), maxshape=(None,), dtype=dtype, chunks=(4096,))
            for name, dtype in _PER_FRAME.items()
        }
        self._reserve(max(self._frames_expected, 1))

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
        """Append one frame (the pixels are copied into the file at once)."""
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
        self._frames[i] = pixels
        values = {
            "frame_counter": header.counter,
            "timestamp_ns": header.timestamp_ns,
            "received_unix_ns": received_ns + self._unix_offset_ns,
            "flags": int(header.flags),
            "stage_position": header.stage_position,
            "payload_crc32": header.payload_crc32,
            "gap_before": gap_before,
        }
        for name, value in values.items():
            self._columns[name][i] = value
        self.count += 1

    def close(self, stream_stats: Mapping[str, Any] | None = None) -> Path:
        """Trim to the frames received, store the stream's counters, close; return the path."""
        if not self._file:
            return self.path
        if self._frames is None:
            # No frame came: an empty recording, still readable.
            self._file.attrs.update({"mode": "none", "bits": 0, "rows": 0, "cols": 0})
            self._file.create_dataset("frames", shape=(0, 0, 0), dtype=np.uint16)
            for name, dtype in _PER_FRAME.items():
                self._file.create_dataset(name, shape=(0,), dtype=dtype)
        else:
            self._frames.resize(self.count, axis=0)
            for column in self._columns.values():
                column.resize(self.count, axis=0)
        self._file.attrs["frames"] = self.count
        if stream_stats:
            self._file["stream"].attrs.update(flatten_attrs(stream_stats))
        self._file.close()
        return self.path

    def __enter__(self) -> FrameRecorder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


@dataclass(frozen=True, slots=True)
class Recording:
    """A recording read back: the frames, each frame's header values, the metadata."""

    path: Path
    frames: npt.NDArray[np.uint16]
    columns: dict[str, npt.NDArray[Any]]  # frame_counter, timestamp_ns, ... (see the module)
    attrs: dict[str, Any]  # root attributes
    metadata: dict[str, dict[str, Any]]  # profile, registers, timing, stream

    def crc_mismatches(self) -> list[int]:
        """Indices of frames whose pixels no longer match the device's payload CRC."""
        crcs = self.columns["payload_crc32"]
        return [
            i
            for i in range(len(self.frames))
            if crc32(np.ascontiguousarray(self.frames[i]).astype("<u2").tobytes()) != int(crcs[i])
        ]


def read_recording(path: Path | str) -> Recording:
    """Read a whole recording into memory; RecordingError if it is not one."""
    path = Path(path)
    try:
        f = h5py.File(path, "r")
    except OSError as exc:
        raise RecordingError(f"cannot open {path} as HDF5: {exc}") from None
    with f:
        if f.attrs.get("format") != FORMAT:
            raise RecordingError(f"{path} is not a camd recording (no format={FORMAT!r})")
        version = int(f.attrs.get("format_version", 0))
        if version > FORMAT_VERSION:
            raise RecordingError(
                f"{path} is recording format {version}; this camd reads up to {FORMAT_VERSION}: "
                "upgrade camd"
            )
        frames = np.asarray(f["frames"][...], dtype=np.uint16)
        columns = {name: np.asarray(f[name][...]) for name in _PER_FRAME}
        attrs = unflatten_attrs(dict(f.attrs))
        meta = {group: unflatten_attrs(dict(f[group].attrs)) for group in METADATA_GROUPS}
    return Recording(path, frames, columns, attrs, meta)
