"""A TDI scan read back (``read_tdi_scan``), also one still being written (SWMR), or
described without its lines (``read_tdi_scan_info``).

The file's layout is ``camd.store.tdi_layout``'s (listed in ``camd.store.tdi_recording``'s
docstring); files of every format version up to ``FORMAT_VERSION`` read, the columns an older
one lacks filled in. ``camd.store.tdi_recording`` exports these names too.
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

from camd.store.nexus import ENTRY
from camd.store.recording import FORMAT as RECORDING_FORMAT
from camd.store.recording import RecordingError, unflatten_attrs
from camd.store.recording_reading import open_for_reading
from camd.store.tdi_layout import ADDED_IN_2, COLUMNS, FORMAT, FORMAT_VERSION


@dataclass(frozen=True, slots=True)
class TdiScan:
    """A TDI scan read back: the lines, each line's bookkeeping, the metadata."""

    path: Path
    lines: npt.NDArray[Any]  # (L, N) uint32 ("sum") or float32 ("mean")
    line_index: npt.NDArray[np.int64]
    frame_counter: npt.NDArray[np.uint32]
    stages_used: npt.NDArray[np.uint16]
    complete: npt.NDArray[np.bool_]
    stage_position: npt.NDArray[np.int32]  # encoder count at each line's frame start
    m_dv_over_v: npt.NDArray[np.float32]  # M dV/V each line saw (NaN: unknown)
    stage_changes: npt.NDArray[np.int64]  # (K, 2): [line index, stages]
    attrs: dict[str, Any]  # root attributes
    metadata: dict[str, dict[str, Any]]  # profile, registers, timing, scan, counters, ...


# What read_tdi_scan says when another program holds the file open for writing without SWMR.
_HELD_FOR_WRITING = (
    "another program has it open for writing without SWMR (a camd frame recording being "
    "made?): {exc}; wait until it is closed"
)


@dataclass(frozen=True, slots=True)
class TdiScanInfo:
    """A TDI scan described without its lines: what an index of many files needs (``camd
    archive``), read in milliseconds whatever the file's size."""

    path: Path
    lines: int  # lines on disk that every column has: up to /lines_flushed while unfinished
    columns: tuple[str, ...]  # the per-line datasets the file holds (an older format lacks some)
    attrs: dict[str, Any]  # root attributes
    metadata: dict[str, dict[str, Any]]  # profile, registers, timing, scan, counters, ...


@contextmanager
def _open_scan(path: Path) -> Iterator[h5py.File]:
    """``path`` open for reading once it is known to be a TDI scan this camd reads."""
    with open_for_reading(path, held_for_writing=_HELD_FOR_WRITING) as f:
        fmt = f.attrs.get("format")
        if isinstance(fmt, bytes):
            fmt = fmt.decode(errors="replace")
        if fmt == RECORDING_FORMAT:
            raise RecordingError(
                f"{path} is a camd frame recording (format {RECORDING_FORMAT!r}), not a TDI "
                "scan; read it with camd.store.read_recording"
            )
        if fmt != FORMAT:
            raise RecordingError(
                f"{path} is not a camd TDI scan (format={fmt!r}, expected {FORMAT!r})"
            )
        version = int(f.attrs.get("format_version", 0))
        if version > FORMAT_VERSION:
            raise RecordingError(
                f"{path} is TDI scan format {version}; this camd reads up to {FORMAT_VERSION}: "
                "upgrade camd"
            )
        yield f


def _lines_on_disk(f: h5py.File, path: Path) -> tuple[int, list[str]]:
    """How many lines every dataset holds on disk, and the per-line columns the file has."""
    try:
        # While the scan is written, the datasets may have grown unequally: keep the lines
        # every one of them has.
        present = [name for name in COLUMNS if name in f or name not in ADDED_IN_2]
        n = min(len(f[name]) for name in ("lines", *present))
        if "lines_flushed" in f and not bool(f.attrs.get("finished", False)):
            n = min(n, int(f["lines_flushed"][0]))  # beyond it: not on disk yet
    except KeyError as exc:
        raise RecordingError(f"{path} is a damaged TDI scan: {exc}") from None
    return n, present


def _scan_metadata(f: h5py.File) -> tuple[dict[str, Any], dict[str, dict[str, Any]]]:
    """The root attributes and the metadata groups, as nested dicts of plain values."""
    attrs = unflatten_attrs(dict(f.attrs))
    meta = {
        name: unflatten_attrs(dict(node.attrs))
        for name, node in f.items()
        if isinstance(node, h5py.Group) and name != ENTRY
    }
    return attrs, meta


def read_tdi_scan_info(path: Path | str) -> TdiScanInfo:
    """A scan's metadata and how many lines it holds, without reading the lines, also one
    still being written; RecordingError as ``read_tdi_scan``."""
    path = Path(path)
    with _open_scan(path) as f:
        n, present = _lines_on_disk(f, path)
        return TdiScanInfo(path, n, tuple(present), *_scan_metadata(f))


def read_tdi_scan(path: Path | str) -> TdiScan:
    """Read a whole TDI scan into memory, also one still being written (SWMR).

    RecordingError for a missing file, a file that is not HDF5 or not a camd TDI scan, or a
    scan format newer than this camd reads.
    """
    path = Path(path)
    with _open_scan(path) as f:
        n, _ = _lines_on_disk(f, path)
        try:
            lines = np.asarray(f["lines"][:n])
            columns = {
                name: (
                    np.asarray(f[name][:n], dtype=t)
                    if name in f
                    else np.full(n, ADDED_IN_2[name], dtype=t)
                )
                for name, t in COLUMNS.items()
            }
            stage_changes = np.asarray(f["stage_changes"][...], dtype=np.int64).reshape(-1, 2)
        except KeyError as exc:
            raise RecordingError(f"{path} is a damaged TDI scan: {exc}") from None
        attrs, meta = _scan_metadata(f)
    return TdiScan(
        path=path,
        lines=lines,
        line_index=columns["line_index"],
        frame_counter=columns["frame_counter"],
        stages_used=columns["stages_used"],
        complete=columns["complete"].astype(bool),
        stage_position=columns["stage_position"],
        m_dv_over_v=columns["m_dv_over_v"],
        stage_changes=stage_changes,
        attrs=attrs,
        metadata=meta,
    )
