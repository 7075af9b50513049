"""The TDI scan file's layout: what it holds, made in a new file, checked on the way in, finished.

The layout is listed in ``camd.store.tdi_recording``'s docstring (and docs/scan.md); this
module makes it and keeps it: the settings and metadata a scan may have (``check_settings``),
the root attributes, metadata groups, datasets and NeXus entry of a new file
(``TdiDatasets``), what a block of appended lines may hold (``line_block``), and the final
counts and attributes written when the scan is closed (``trim_lines``, ``finish_file``). The
recorder (``camd.store.tdi_recording``) decides when to write; ``camd.store.tdi_reading``
reads the layout back.
"""

from __future__ import annotations

import datetime as dt
import operator
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import numpy.typing as npt

from camd.store.compression import Compression
from camd.store.nexus import (
    ENTRY,
    ENTRY_NAMES,
    ROOT_NEXUS_ATTRS,
    Axis,
    camera_name,
    finish_nexus,
    profile_value,
    sensor_fields,
    write_nexus,
    write_settings,
)
from camd.store.recording import camd_version, flatten_attrs

FORMAT = "camd-tdi-scan"
# 2: /stage_position, /m_dv_over_v and close()'s datasets; 3: /lines_flushed; 4: the NeXus
# entry (camd.store.nexus); 5: the entry holds every dataset (hard links: the root's names
# stay) and every setting (the metadata groups as NXparameters/NXcollection fields with units,
# the stage as an NXpositioner, the sample, the campaign step), the signal's units and
# interpretation, the TDI settings in an NXcollection, end_time. A reader needs none of these:
# older files read as before.
FORMAT_VERSION = 5
MODES: dict[str, type[np.generic]] = {"sum": np.uint32, "mean": np.float32}
METADATA_GROUPS = ("profile", "registers", "timing", "scan", "counters")
# The per-line columns besides /lines, with their stored types.
COLUMNS: dict[str, type[np.generic]] = {
    "line_index": np.int64,
    "frame_counter": np.uint32,
    "stages_used": np.uint16,
    "complete": np.uint8,
    "stage_position": np.int32,
    "m_dv_over_v": np.float32,
}
# Columns a version-1 file lacks, and what a reader fills them with.
ADDED_IN_2: dict[str, float] = {"stage_position": 0, "m_dv_over_v": np.nan}
DATASETS = frozenset({"lines", "stage_changes", "lines_flushed", *COLUMNS})
RESERVED_ROOT = frozenset(
    {
        "format",
        "format_version",
        "mode",
        "width",
        "created_utc",
        "camd_version",
        "lines",
        "complete_lines",
        "finished",
        *ROOT_NEXUS_ATTRS,  # the NeXus root's (camd.store.nexus)
    }
)
_COLUMN_CHUNK = 4096  # lines per chunk of the 1-D columns
CHUNK_LINES_MAX = 256  # lines per chunk of /lines at the fast line rates (TdiRecorder's default)
_UINT32_MAX = 2**32 - 1
_INT64 = np.iinfo(np.int64)


def store_attrs(node: h5py.Group, values: Mapping[str, Any], where: str) -> list[str]:
    """Write flattened ``values`` as attributes of ``node``; return the ones HDF5 refused."""
    refused: list[str] = []
    for name, value in flatten_attrs(values).items():
        if isinstance(value, np.ndarray) and value.dtype.kind == "U":
            # numpy's fixed-width unicode has no HDF5 type; store variable-length UTF-8.
            value = np.asarray(value.tolist(), dtype=h5py.string_dtype())
        try:
            node.attrs[name] = value
        except (TypeError, ValueError) as exc:
            refused.append(f"{where}{name} = {value!r} ({exc})")
    return refused


def check_group_name(name: object, what: str) -> str:
    """``name`` if it can be a group of a scan file, else ValueError saying why (``what``)."""
    if (
        not isinstance(name, str)
        or not name
        or "/" in name
        or name in DATASETS
        or name == ENTRY
        or name in ENTRY_NAMES
    ):
        raise ValueError(
            f"{what} {name!r} cannot be an HDF5 group of a TDI scan: use a non-empty name "
            f"without '/' that is not one of the datasets ({', '.join(sorted(DATASETS))}) "
            f"nor the NeXus entry ({ENTRY!r}) nor a name the entry holds "
            f"({', '.join(sorted(ENTRY_NAMES))})"
        )
    return name


def as_int(value: object, name: str) -> int:
    """``value`` as an int (any integer type but bool), else ValueError naming ``name``."""
    if isinstance(value, bool):
        raise ValueError(f"{name} must be an integer, not {value!r}")
    try:
        return operator.index(value)  # type: ignore[arg-type]
    except TypeError:
        raise ValueError(f"{name} must be an integer; got {value!r}") from None


def chunk_lines_for(line_period_s: float, flush_period_s: float) -> int:
    """Lines per chunk of ``/lines`` for a scan at ``line_period_s``: as many as arrive in
    three quarters of a flush period, 1 to ``CHUNK_LINES_MAX``. A recorder flushes at least
    every ``flush_period_s``, and at every chunk's end; a compressed chunk flushed before it
    filled is written again when it fills, to new space (camd.store.line_buffer), so a slow
    scan's chunks fill before the period is up, and each is written once, whole (a 10 s line
    period: one line a chunk; 100 lines/s: 75; hr400 at M = 96, 507 lines/s: 256)."""
    if not line_period_s > 0:
        return CHUNK_LINES_MAX
    return max(1, min(CHUNK_LINES_MAX, int(0.75 * flush_period_s / line_period_s)))


def check_settings(
    width: object, mode: str, chunk_lines: object, metadata: Mapping[str, Mapping[str, Any]]
) -> tuple[int, int, np.dtype[Any]]:
    """A scan's ``width``, ``chunk_lines`` and the dtype of its lines, checked with its
    ``mode`` and ``metadata``; ValueError saying what to change."""
    if mode not in MODES:
        raise ValueError(
            f"mode {mode!r} is not a TDI output mode: use 'sum' (uint32 sums) or "
            "'mean' (float32 means), the mode the TDI engine runs in"
        )
    width = as_int(width, "width")
    chunk_lines = as_int(chunk_lines, "chunk_lines")
    if width < 1:
        raise ValueError(f"width must be at least 1 column; got {width}")
    if chunk_lines < 1:
        raise ValueError(f"chunk_lines must be at least 1; got {chunk_lines}")
    dtype = np.dtype(MODES[mode])
    chunk_bytes = chunk_lines * width * dtype.itemsize
    if chunk_bytes >= 2**32:
        raise ValueError(
            f"a chunk of {chunk_lines} lines x {width} columns is {chunk_bytes} bytes; HDF5 "
            "chunks must be under 4 GiB: use a smaller chunk_lines"
        )
    for group, values in metadata.items():
        check_group_name(group, "metadata group")
        if not isinstance(values, Mapping):
            raise ValueError(
                f"metadata[{group!r}] must be a mapping of attribute names to values; "
                f"got {type(values).__name__}"
            )
    return width, chunk_lines, dtype


class TdiDatasets:
    """A new scan file's layout, made in ``f`` (the root attributes, the metadata groups, the
    datasets, the NeXus entry); the datasets a recorder writes, as attributes. ``/lines`` is
    compressed with ``compression`` (its attributes say how: ``Compression.attrs``)."""

    def __init__(
        self,
        f: h5py.File,
        path: Path,
        *,
        width: int,
        mode: str,
        chunk_lines: int,
        metadata: Mapping[str, Mapping[str, Any]],
        compression: Compression,
    ) -> None:
        dtype = np.dtype(MODES[mode])
        created_utc = dt.datetime.now(dt.UTC).isoformat(timespec="milliseconds")
        f.attrs.update(
            {
                "format": FORMAT,
                "format_version": FORMAT_VERSION,
                "mode": mode,
                "width": width,
                "created_utc": created_utc,
                "camd_version": camd_version(),
                "lines": 0,
                "complete_lines": 0,
                "finished": False,
            }
        )
        refused: list[str] = []
        groups = (*METADATA_GROUPS, *(g for g in metadata if g not in METADATA_GROUPS))
        for group in groups:
            node = f.create_group(group)
            refused += store_attrs(node, metadata.get(group, {}), f"{group}.")
        if refused:
            raise ValueError(
                f"{path}: metadata that HDF5 cannot store: {'; '.join(refused)}; use "
                "numbers, strings, booleans or lists of them"
            )
        self.lines = f.create_dataset(
            "lines",
            shape=(0, width),
            maxshape=(None, width),
            dtype=dtype,
            chunks=(chunk_lines, width),
            **compression.dataset_options(),
        )
        self.lines.attrs.update(compression.attrs())
        self.columns = {
            name: f.create_dataset(
                name, shape=(0,), maxshape=(None,), dtype=stored, chunks=(_COLUMN_CHUNK,)
            )
            for name, stored in COLUMNS.items()
        }
        self.stage_changes = f.create_dataset(
            "stage_changes", shape=(0, 2), maxshape=(None, 2), dtype=np.int64, chunks=(256, 2)
        )
        self.lines_flushed = f.create_dataset("lines_flushed", data=np.zeros(1, dtype=np.int64))
        _write_nexus(f, mode, width, metadata, created_utc)
        write_settings(f, {group: metadata.get(group, {}) for group in groups})

    def resize(self, count: int) -> None:
        """Every per-line dataset (the lines and their columns) to ``count`` lines."""
        for dataset in (self.lines, *self.columns.values()):
            dataset.resize(count, axis=0)

    def rewrite_stage_changes(self, changes: list[tuple[int, int]]) -> None:
        """``/stage_changes`` written afresh with ``changes`` ([line index, stages] each)."""
        rows = np.asarray(changes, dtype=np.int64).reshape(-1, 2)
        self.stage_changes.resize(0, axis=0)
        self.stage_changes.resize(len(rows), axis=0)
        if len(rows):
            self.stage_changes[:] = rows


def _write_nexus(
    f: h5py.File,
    mode: str,
    width: int,
    metadata: Mapping[str, Mapping[str, Any]],
    created_utc: str,
) -> None:
    """The NeXus entry (camd.store.nexus): the lines against line index and column."""
    profile = metadata.get("profile", {})
    timing = metadata.get("timing", {})
    scan = metadata.get("scan", {})
    camera = camera_name(profile)
    stages = scan.get("stages")
    write_nexus(
        f,
        title=f"TDI scan, {camera}"
        + ("" if stages is None else f", M = {stages}")
        + f", {mode} mode",
        start_time=created_utc,
        program=f"camd {camd_version()}",
        instrument=camera,
        detector={
            **sensor_fields(profile),
            "bit_depth_readout": (profile_value(profile, "output_bits"), ""),
            "frame_time": (timing.get("tdi_line_period_s"), "s"),
            "count_time": (timing.get("exposure_s"), "s"),
        },
        tdi={"mode": mode, "stages": stages, "window_rows": timing.get("n_lines")},
        signal="lines",
        axes=(
            Axis("line_index", link="line_index", long_name="TDI line index"),
            Axis("column", values=np.arange(width), long_name="column (pixel)"),
        ),
        per_element=("per_line", (*COLUMNS, "stage_changes", "lines_flushed")),
        stage="stage_position",
    )


def _int_column(
    name: str, values: npt.ArrayLike, n: int, lo: int, hi: int, dtype: type[np.generic]
) -> npt.NDArray[Any]:
    """A (n,) integer array with values in lo..hi, converted to ``dtype``; ValueError if not."""
    a = np.asarray(values)
    if a.ndim != 1 or a.shape[0] != n:
        raise ValueError(f"{name} must have one value per line, shape ({n},); got {a.shape}")
    if a.dtype.kind not in "iu":
        raise ValueError(f"{name} must be integers (the TDI engine's int64/int32); got {a.dtype}")
    if n and (int(a.min()) < lo or int(a.max()) > hi):
        raise ValueError(f"{name} must lie in {lo}..{hi}; got {int(a.min())}..{int(a.max())}")
    return a.astype(dtype, copy=False)


def _float_column(name: str, values: npt.ArrayLike | None, n: int) -> npt.NDArray[np.float32]:
    if values is None:
        return np.full(n, np.nan, dtype=np.float32)
    a = np.asarray(values, dtype=np.float32)
    if a.shape != (n,):
        raise ValueError(f"{name} must have one value per line, shape ({n},); got {a.shape}")
    return a


def _line_data(path: Path, width: int, mode: str, data: npt.ArrayLike) -> npt.NDArray[Any]:
    a = np.asarray(data)
    if a.ndim != 2 or a.shape[1] != width:
        raise ValueError(
            f"{path}: lines must be an (F, {width}) array (the scan is "
            f"{width} columns wide); got shape {a.shape}"
        )
    if mode == "sum":
        if a.dtype.kind != "u":
            raise ValueError(
                f"{path}: a 'sum' scan stores the engine's uint32 sums; got {a.dtype} "
                "lines (float lines belong in a 'mean' scan)"
            )
        if a.dtype.itemsize > 4 and a.size and int(a.max()) > _UINT32_MAX:
            raise ValueError(
                f"{path}: a sum of {int(a.max())} does not fit the scan's uint32; clip "
                "the sums (the engine's out_bits) before recording them"
            )
    elif a.dtype.kind != "f":
        raise ValueError(
            f"{path}: a 'mean' scan stores the engine's float32 means; got {a.dtype} "
            "lines (integer sums belong in a 'sum' scan)"
        )
    return a.astype(MODES[mode], copy=False)


def line_block(
    path: Path,
    width: int,
    mode: str,
    data: npt.ArrayLike,
    *,
    index: npt.ArrayLike,
    stages_used: npt.ArrayLike,
    complete: npt.ArrayLike,
    frame_counter: npt.ArrayLike | None,
    stage_position: npt.ArrayLike | None,
    m_dv_over_v: npt.ArrayLike | None,
) -> tuple[npt.NDArray[Any], dict[str, npt.NDArray[Any]]]:
    """A block of lines for the scan ``path`` (``TdiRecorder.append``'s arguments) as stored:
    the (F, width) lines and each column's F values; ValueError for a wrong shape, type or
    range."""
    lines = _line_data(path, width, mode, data)
    n = lines.shape[0]
    line_index = _int_column("index", index, n, int(_INT64.min), int(_INT64.max), np.int64)
    done = np.asarray(complete)
    if done.shape != (n,) or done.dtype.kind != "b":
        raise ValueError(
            f"complete must be a bool array with one value per line, shape ({n},); got "
            f"{done.dtype} with shape {done.shape}"
        )
    columns = {
        "line_index": line_index,
        "frame_counter": (
            (line_index & _UINT32_MAX).astype(np.uint32)
            if frame_counter is None
            else _int_column("frame_counter", frame_counter, n, 0, _UINT32_MAX, np.uint32)
        ),
        "stages_used": _int_column("stages_used", stages_used, n, 0, 2**16 - 1, np.uint16),
        "complete": done.astype(np.uint8),
        "stage_position": (
            np.zeros(n, dtype=np.int32)
            if stage_position is None
            else _int_column("stage_position", stage_position, n, -(2**31), 2**31 - 1, np.int32)
        ),
        "m_dv_over_v": _float_column("m_dv_over_v", m_dv_over_v, n),
    }
    return lines, columns


def trim_lines(f: h5py.File, count: int) -> int:
    """A closed scan ``f`` cut to its first ``count`` lines (what a failed write left on disk);
    how many of them are complete."""
    for name in ("lines", *COLUMNS):
        f[name].resize(count, axis=0)
    return int(np.count_nonzero(f["complete"][:count]))


def finish_file(
    f: h5py.File,
    *,
    lines: int,
    complete_lines: int,
    root: Mapping[str, Any],
    groups: Mapping[str, Mapping[str, Any]],
    datasets: Mapping[str, Mapping[str, npt.ArrayLike]] | None,
) -> list[str]:
    """Write a closed scan's final counts, attributes and datasets (``TdiRecorder.close``);
    the attributes HDF5 refused."""
    f["lines_flushed"][0] = lines  # every line is on disk now
    f.attrs.update({"lines": lines, "complete_lines": complete_lines, "finished": True})
    refused = store_attrs(f, root, "")
    for group, values in groups.items():
        node = f[group] if group in f else f.create_group(group)
        refused += store_attrs(node, values, f"{group}.")
    for group, arrays in (datasets or {}).items():
        node = f.require_group(check_group_name(group, "close() dataset group"))
        for name, array in arrays.items():
            node.create_dataset(name, data=np.asarray(array))
    finish_nexus(f, groups)
    return refused
