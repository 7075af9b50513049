"""Raw frame recordings read back: a whole recording (``read_recording``), or only its
metadata and how many frames it holds (``read_recording_info``, what ``camd archive`` indexes);
the layout is in ``camd.store.recording``'s docstring, which writes it.

A file still being written, or one whose writer died, is opened SWMR (``open_for_reading``)
and read up to ``/frames_flushed``: what is on disk.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import numpy.typing as npt

from camd.protocol.stream import crc32
from camd.store.nexus import ENTRY
from camd.store.recording import (
    BACKGROUND_GROUP,
    FORMAT,
    FORMAT_VERSION,
    PER_FRAME_COLUMNS,
    RecordingError,
    unflatten_attrs,
)


@dataclass(frozen=True, slots=True)
class Recording:
    """A recording read back: the frames, each frame's header values, the metadata."""

    path: Path
    frames: npt.NDArray[np.uint16]
    columns: dict[str, npt.NDArray[Any]]  # frame_counter, timestamp_ns, ... (see the module)
    attrs: dict[str, Any]  # root attributes
    metadata: dict[str, dict[str, Any]]  # profile, registers, timing, stream, and any other

    def crc_mismatches(self) -> list[int]:
        """Indices of frames whose pixels no longer match the device's payload CRC."""
        crcs = self.columns["payload_crc32"]
        return [
            i
            for i in range(len(self.frames))
            if crc32(np.ascontiguousarray(self.frames[i]).astype("<u2").tobytes()) != int(crcs[i])
        ]


def open_for_reading(path: Path, *, held_for_writing: str | None = None) -> h5py.File:
    """``path`` opened for reading, SWMR: also a file still being written, or one whose writer
    died. RecordingError for a missing file or one HDF5 cannot open; ``held_for_writing`` is
    what to say instead when another program holds the file open for writing without SWMR, with
    ``{exc}`` for HDF5's words (None: the same as for any file HDF5 cannot open)."""
    if not path.is_file():
        raise RecordingError(f"{path} does not exist (or is not a file); check the path")
    try:
        return h5py.File(path, "r", swmr=True)
    except BlockingIOError as exc:
        if held_for_writing is None:
            raise RecordingError(f"cannot open {path} as HDF5: {exc}") from None
        raise RecordingError(f"cannot open {path}: " + held_for_writing.format(exc=exc)) from None
    except OSError as exc:
        raise RecordingError(f"cannot open {path} as HDF5: {exc}") from None


@dataclass(frozen=True, slots=True)
class RecordingInfo:
    """A recording described without its pixels: what an index of many files needs (``camd
    archive``), read in milliseconds whatever the file's size."""

    path: Path
    frames: int  # frames on disk: up to /frames_flushed while the file is unfinished
    attrs: dict[str, Any]  # root attributes
    metadata: dict[str, dict[str, Any]]  # profile, registers, timing, stream


def file_format(path: Path | str) -> str:
    """The ``format`` a camd HDF5 file says it has at its root (``FORMAT``, or a TDI scan's
    ``camd.store.tdi_layout.FORMAT``), "" for an HDF5 file that says none: how a reader of
    many files chooses the reader of each. RecordingError for a file HDF5 cannot open."""
    with open_for_reading(Path(path)) as f:
        fmt = f.attrs.get("format", "")
    return fmt.decode(errors="replace") if isinstance(fmt, bytes) else str(fmt)


@contextmanager
def _open_recording(path: Path) -> Iterator[h5py.File]:
    """``path`` open for reading once it is known to be a recording this camd reads."""
    with open_for_reading(path) as f:
        if f.attrs.get("format") != FORMAT:
            raise RecordingError(f"{path} is not a camd recording (no format={FORMAT!r})")
        version = int(f.attrs.get("format_version", 0))
        if version > FORMAT_VERSION:
            raise RecordingError(
                f"{path} is recording format {version}; this camd reads up to {FORMAT_VERSION}: "
                "upgrade camd"
            )
        yield f


def _frames_on_disk(f: h5py.File) -> int:
    n = len(f["frames"])
    if "frames_flushed" in f and not bool(f.attrs.get("finished", True)):
        n = min(n, int(f["frames_flushed"][0]))  # beyond it: not on disk yet
    return n


def _recording_metadata(f: h5py.File) -> tuple[dict[str, Any], dict[str, dict[str, Any]]]:
    """The root attributes and the metadata groups, as nested dicts of plain values."""
    attrs = unflatten_attrs(dict(f.attrs))
    meta = {
        name: unflatten_attrs(dict(node.attrs))
        for name, node in f.items()
        if isinstance(node, h5py.Group) and name not in (ENTRY, BACKGROUND_GROUP)
    }
    return attrs, meta


def read_recording_info(path: Path | str) -> RecordingInfo:
    """A recording's metadata and how many frames it holds, without reading the frames;
    RecordingError as ``read_recording``."""
    path = Path(path)
    with _open_recording(path) as f:
        return RecordingInfo(path, _frames_on_disk(f), *_recording_metadata(f))


def read_recording(path: Path | str) -> Recording:
    """Read a whole recording into memory; RecordingError if it is not one."""
    path = Path(path)
    with _open_recording(path) as f:
        n = _frames_on_disk(f)
        frames = np.asarray(f["frames"][:n], dtype=np.uint16)
        columns = {name: np.asarray(f[name][:n]) for name in PER_FRAME_COLUMNS}
        attrs, meta = _recording_metadata(f)
    return Recording(path, frames, columns, attrs, meta)
