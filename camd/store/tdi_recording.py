"""Digital-TDI scans in HDF5: the lines the TDI engine made, each line's bookkeeping, the metadata.

One file per scan, appended to while the scan runs::

    /lines          (L, N) uint32 (mode "sum") or float32 (mode "mean"), chunks of chunk_lines lines
    /line_index     (L,) int64    the engine's line index (docs/tdi.md: line k belongs to frame k)
    /frame_counter  (L,) uint32   the device's counter of the frame the line belongs to
    /stages_used    (L,) uint16   how many of the M stages contributed to the line
    /complete       (L,) uint8    1 if all M stages contributed (docs/tdi.md "Completeness"), else 0
    /stage_position (L,) int32    the stage encoder count latched at the line's frame start
    /m_dv_over_v    (L,) float32  M dV/V the line saw (docs/motion.md; NaN where unknown)
    /stage_changes  (K, 2) int64  [line index, stages]: the scan's first M, then every change of M
    /lines_flushed  (1,) int64    how many lines are on disk: written after each flush has put them
                                  there (docs/stream.md "Crash safety")
    /profile, /registers, /timing, /scan   groups whose attributes hold the metadata
    /counters       group whose attributes hold the scan's counters (written by ``close``)
    /motion_loop    group of 1-D datasets: the closed loop's polls (written by ``close``, if any)
    /background     group, if given: the live view's background (``mean_dn`` float32 image and
                    its attributes, as in ``camd.store.recording.write_background``)
    /entry          the NeXus entry (format 4; ``camd.store.nexus``): NXdata with /lines as
                    its signal against line_index and column, NXdetector with the sensor and
                    the TDI settings, for viewers that know NeXus (silx, h5web, nexusformat)

Root attributes: ``format`` ("camd-tdi-scan"), ``format_version``, ``mode`` ("sum" or "mean"),
``width``, ``created_utc``, ``camd_version``, NeXus's ``NX_class`` and ``default``, ``lines``,
``complete_lines`` and ``finished``
(False, 0 and 0 until the scan is closed), plus whatever ``close`` is given. Nested metadata is
flattened to dotted attribute names (``array.columns``) as in ``camd.store.recording``;
``read_tdi_scan`` puts it back together. ``None`` values are not stored.

Reading a scan while it is written: the file is written in HDF5 single-writer/multiple-reader
(SWMR) mode (file format 1.10, readable by HDF5 1.10 and later). Another process opens it with
``read_tdi_scan`` or ``h5py.File(path, "r", swmr=True)`` (a plain ``h5py.File(path, "r")`` is
refused while the scan is open: "file is already open for write") and sees every line up to the
recorder's last flush, which is at most ``chunk_lines`` lines or ``flush_period_s`` behind; a
line appended after it may still read as zeros (``read_tdi_scan`` stops at ``/lines_flushed``). An SWMR writer may only grow datasets, so the root attributes ``lines``,
``complete_lines``, ``finished``, the counters and ``close``'s attributes appear when the scan is
closed: a live reader takes the number of lines from ``/lines_flushed``. If the writing process
dies, the lines up to its last flush stay readable (``camd.store.durability``: the daemon repairs
such a file when it starts again, so that plain HDF5 readers open it too).
"""

from __future__ import annotations

import contextlib
import datetime as dt
import operator
import time
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, SupportsIndex

import h5py
import numpy as np
import numpy.typing as npt

from camd.store.durability import (
    FLUSH_PERIOD_S,
    Headroom,
    NoRoom,
    close_writer,
    create_file,
    discard_new_file,
    keep_after_failure,
    reopen_to_finish,
    retry_held,
    write_failure,
)
from camd.store.line_buffer import LineBuffer
from camd.store.nexus import ENTRY, Axis, camera_name, profile_value, sensor_fields, write_nexus
from camd.store.recording import FORMAT as RECORDING_FORMAT
from camd.store.recording import (
    RecordingError,
    camd_version,
    flatten_attrs,
    unflatten_attrs,
    write_background,
)

FORMAT = "camd-tdi-scan"
# 2: /stage_position, /m_dv_over_v and close()'s datasets; 3: /lines_flushed; 4: the NeXus
# entry (camd.store.nexus). A reader needs none of these: older files read as before.
FORMAT_VERSION = 4
MODES: dict[str, type[np.generic]] = {"sum": np.uint32, "mean": np.float32}
METADATA_GROUPS = ("profile", "registers", "timing", "scan", "counters")
# The per-line columns besides /lines, with their stored types.
_COLUMNS: dict[str, type[np.generic]] = {
    "line_index": np.int64,
    "frame_counter": np.uint32,
    "stages_used": np.uint16,
    "complete": np.uint8,
    "stage_position": np.int32,
    "m_dv_over_v": np.float32,
}
# Columns a version-1 file lacks, and what a reader fills them with.
_ADDED_IN_2: dict[str, float] = {"stage_position": 0, "m_dv_over_v": np.nan}
_DATASETS = frozenset({"lines", "stage_changes", "lines_flushed", *_COLUMNS})
_RESERVED_ROOT = frozenset(
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
        "NX_class",  # the NeXus root's (camd.store.nexus)
        "default",
    }
)
_COLUMN_CHUNK = 4096  # lines per chunk of the 1-D columns
_RESERVE_MIN_BYTES = 4 << 20  # the least space held back for finishing the file on a full disk
# Besides the lines' chunks, what a flush may write: the columns' chunks and the metadata.
_MARGIN_BYTES = 512 << 10
_UINT32_MAX = 2**32 - 1
_INT64 = np.iinfo(np.int64)


def _store_attrs(node: h5py.Group, values: Mapping[str, Any], where: str) -> list[str]:
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


def _check_group_name(name: object, what: str) -> str:
    if not isinstance(name, str) or not name or "/" in name or name in _DATASETS or name == ENTRY:
        raise ValueError(
            f"{what} {name!r} cannot be an HDF5 group of a TDI scan: use a non-empty name "
            f"without '/' that is not one of the datasets ({', '.join(sorted(_DATASETS))}) "
            f"nor the NeXus entry ({ENTRY!r})"
        )
    return name


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


def _as_int(value: object, name: str) -> int:
    if isinstance(value, bool):
        raise ValueError(f"{name} must be an integer, not {value!r}")
    try:
        return operator.index(value)  # type: ignore[arg-type]
    except TypeError:
        raise ValueError(f"{name} must be an integer; got {value!r}") from None


class TdiRecorder:
    """Appends TDI lines to a new HDF5 file (layout in the module docstring).

    The file is created at once with its metadata (so a bad path fails before the scan starts)
    and never overwrites an existing file. ``metadata`` maps group name (profile, registers,
    timing, scan, or any other) to a dict; the groups profile, registers, timing, scan and
    counters always exist. The recorder flushes itself whenever ``chunk_lines`` lines have been
    appended since the last flush or ``flush_period_s`` has passed since it, so a reader in
    another process (or the file after a crash) is never more than a chunk or a period behind;
    ``flush()`` makes everything so far visible (and durable against a kill) at once. A failed
    write (a full disk) raises RecordingError saying so; the lines flushed before stay readable. ``close(attributes)`` writes
    the final attributes; a ``with`` block closes the recorder whatever happens inside.
    ``background_dn`` (with ``background_attrs``) is stored as ``/background``.
    """

    def __init__(
        self,
        path: Path | str,
        *,
        width: int,
        mode: str,
        metadata: Mapping[str, Mapping[str, Any]],
        chunk_lines: int = 256,
        flush_period_s: float = FLUSH_PERIOD_S,
        background_dn: npt.ArrayLike | None = None,
        background_attrs: Mapping[str, Any] | None = None,
    ) -> None:
        self.path = Path(path)
        if mode not in MODES:
            raise ValueError(
                f"mode {mode!r} is not a TDI output mode: use 'sum' (uint32 sums) or "
                "'mean' (float32 means), the mode the TDI engine runs in"
            )
        width = _as_int(width, "width")
        chunk_lines = _as_int(chunk_lines, "chunk_lines")
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
            _check_group_name(group, "metadata group")
            if not isinstance(values, Mapping):
                raise ValueError(
                    f"metadata[{group!r}] must be a mapping of attribute names to values; "
                    f"got {type(values).__name__}"
                )
        if self.path.exists():
            raise RecordingError(
                f"{self.path} already exists; choose another path or remove the old file"
            )
        if not self.path.parent.is_dir():
            raise RecordingError(
                f"cannot create the TDI scan {self.path}: the directory {self.path.parent} does "
                "not exist; create it or choose another path"
            )
        self.width = width
        self.mode = mode
        self.lines = 0
        self.complete_lines = 0
        self._dtype = dtype
        self._chunk_lines = chunk_lines
        self._flushed_lines = 0
        self._flush_period_s = flush_period_s
        self._last_flush = time.monotonic()
        self._stage_change_count = 0
        self._stage_change_list: list[tuple[int, int]] = []
        # The lines appended since the last flush, with their columns, written to the file by
        # the next flush (camd.store.line_buffer); and written afresh after a failed write (a
        # flush that fails on a full disk cannot simply be tried again: HDF5 then writes a new
        # chunk without adding it to the dataset's index; ``_failed``).
        self._pending = LineBuffer(width, dtype, chunk_lines, _COLUMNS)
        self._in_file = 0  # lines in the datasets: the flushed ones, or all once written
        self._closed = False
        self.failed: str | None = None  # why writing stopped (a full disk), None while it works
        retry_held()  # a file an earlier full disk held open, closed if the space is back
        try:
            # SWMR needs the 1.10 file format; the chunk cache holds two chunks of lines so that
            # appending a few lines at a time never rewrites a whole chunk on disk.
            self._file = create_file(
                self.path,
                "the TDI scan",
                libver=("v110", "latest"),
                rdcc_nbytes=max(1 << 20, 2 * chunk_bytes),
            )
        except OSError as exc:
            raise RecordingError(str(exc)) from None
        try:
            self._headroom = Headroom(self._file, self.reserve_bytes(width, mode, chunk_lines))
            background = 0 if background_dn is None else 4 * np.size(background_dn)
            self._headroom.ensure(background + _MARGIN_BYTES)
            self._create(metadata)
            if background_dn is not None:  # before SWMR: an SWMR writer cannot add datasets
                write_background(self._file, background_dn, background_attrs or {})
            self._file.swmr_mode = True
            self._headroom.flush()
        except (OSError, RuntimeError) as exc:  # h5py reports a failed flush as RuntimeError
            # Nothing recorded yet: leave no file behind (a retry with the same name works).
            discard_new_file(self._file, self.path, self)
            raise RecordingError(
                f"cannot create the TDI scan {self.path}: {write_failure(self.path, exc)}"
            ) from None
        except BaseException:
            discard_new_file(self._file, self.path, self)
            raise

    @staticmethod
    def reserve_bytes(width: int, mode: str, chunk_lines: int = 256) -> int:
        """The space a recorder of these settings holds back to close its file if the disk
        fills (``camd.store.durability.Headroom``): what HDF5 may hold unwritten (two
        chunks of lines: ``append`` flushes before more are pending) and the metadata."""
        return _RESERVE_MIN_BYTES + 2 * chunk_lines * width * np.dtype(MODES[mode]).itemsize

    def _create(self, metadata: Mapping[str, Mapping[str, Any]]) -> None:
        f = self._file
        created_utc = dt.datetime.now(dt.UTC).isoformat(timespec="milliseconds")
        f.attrs.update(
            {
                "format": FORMAT,
                "format_version": FORMAT_VERSION,
                "mode": self.mode,
                "width": self.width,
                "created_utc": created_utc,
                "camd_version": camd_version(),
                "lines": 0,
                "complete_lines": 0,
                "finished": False,
            }
        )
        refused: list[str] = []
        for group in (*METADATA_GROUPS, *(g for g in metadata if g not in METADATA_GROUPS)):
            node = f.create_group(group)
            refused += _store_attrs(node, metadata.get(group, {}), f"{group}.")
        if refused:
            raise ValueError(
                f"{self.path}: metadata that HDF5 cannot store: {'; '.join(refused)}; use "
                "numbers, strings, booleans or lists of them"
            )
        self._lines = f.create_dataset(
            "lines",
            shape=(0, self.width),
            maxshape=(None, self.width),
            dtype=self._dtype,
            chunks=(self._chunk_lines, self.width),
        )
        self._columns = {
            name: f.create_dataset(
                name, shape=(0,), maxshape=(None,), dtype=dtype, chunks=(_COLUMN_CHUNK,)
            )
            for name, dtype in _COLUMNS.items()
        }
        self._stage_changes = f.create_dataset(
            "stage_changes", shape=(0, 2), maxshape=(None, 2), dtype=np.int64, chunks=(256, 2)
        )
        self._lines_flushed = f.create_dataset("lines_flushed", data=np.zeros(1, dtype=np.int64))
        self._write_nexus(metadata, created_utc)

    def _write_nexus(self, metadata: Mapping[str, Mapping[str, Any]], created_utc: str) -> None:
        """The NeXus entry (camd.store.nexus): the lines against line index and column."""
        profile = metadata.get("profile", {})
        timing = metadata.get("timing", {})
        scan = metadata.get("scan", {})
        camera = camera_name(profile)
        stages = scan.get("stages")
        write_nexus(
            self._file,
            title=f"TDI scan, {camera}"
            + ("" if stages is None else f", M = {stages}")
            + f", {self.mode} mode",
            start_time=created_utc,
            program=f"camd {camd_version()}",
            instrument=camera,
            detector={
                **sensor_fields(profile),
                "bit_depth_readout": (profile_value(profile, "output_bits"), ""),
                "frame_time": (timing.get("tdi_line_period_s"), "s"),
                "count_time": (timing.get("exposure_s"), "s"),
                "tdi_stages": (stages, ""),
                "tdi_mode": (self.mode, ""),
                "tdi_window_rows": (timing.get("n_lines"), ""),
            },
            signal="lines",
            axes=(
                Axis("line_index", link="line_index", long_name="TDI line index"),
                Axis("column", values=np.arange(self.width), long_name="column (pixel)"),
            ),
        )

    def _check_open(self) -> None:
        if self._closed:
            raise RecordingError(
                f"{self.path} is closed; start a new TdiRecorder (with a new path) to record more"
            )

    def _line_data(self, data: npt.ArrayLike) -> npt.NDArray[Any]:
        a = np.asarray(data)
        if a.ndim != 2 or a.shape[1] != self.width:
            raise ValueError(
                f"{self.path}: lines must be an (F, {self.width}) array (the scan is "
                f"{self.width} columns wide); got shape {a.shape}"
            )
        if self.mode == "sum":
            if a.dtype.kind != "u":
                raise ValueError(
                    f"{self.path}: a 'sum' scan stores the engine's uint32 sums; got {a.dtype} "
                    "lines (float lines belong in a 'mean' scan)"
                )
            if a.dtype.itemsize > 4 and a.size and int(a.max()) > _UINT32_MAX:
                raise ValueError(
                    f"{self.path}: a sum of {int(a.max())} does not fit the scan's uint32; clip "
                    "the sums (the engine's out_bits) before recording them"
                )
        elif a.dtype.kind != "f":
            raise ValueError(
                f"{self.path}: a 'mean' scan stores the engine's float32 means; got {a.dtype} "
                "lines (integer sums belong in a 'sum' scan)"
            )
        return a.astype(self._dtype, copy=False)

    def append(
        self,
        data: npt.ArrayLike,
        *,
        index: npt.ArrayLike,
        stages_used: npt.ArrayLike,
        complete: npt.ArrayLike,
        frame_counter: npt.ArrayLike | None = None,
        stage_position: npt.ArrayLike | None = None,
        m_dv_over_v: npt.ArrayLike | None = None,
    ) -> None:
        """Append F lines (a ``TdiBlock``'s arrays): data (F, width), index, stages_used,
        complete (bool) and, optionally, the device's frame counter of each line (F,) — by
        default the line index's low 32 bits —, the stage encoder count of each line's frame
        (default 0) and the M dV/V each line saw (default NaN). F = 0 does nothing. ValueError
        for a wrong shape, type or range, before anything is written."""
        self._check_open()
        if self.failed is not None:
            raise RecordingError(self.failed)
        lines = self._line_data(data)
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
        done_at = 0
        pending = self._pending
        while done_at < n:
            # At most chunk_lines lines wait unflushed (in memory, written by the next flush),
            # so a flush writes at most two chunks of lines, which the reserve covers.
            piece = min(n - done_at, pending.room)
            if piece <= 0:
                self.flush()
                continue
            part = slice(done_at, done_at + piece)
            pending.add(lines[part], {name: values[part] for name, values in columns.items()})
            self.lines += piece
            self.complete_lines += int(np.count_nonzero(columns["complete"][part]))
            done_at += piece
            if pending.room == 0 or time.monotonic() - self._last_flush >= self._flush_period_s:
                self.flush()

    def _put_pending(self) -> None:
        """Write the lines held in memory to the datasets (not flushed), unless they are."""
        if self._in_file < self.lines:
            self._pending.write(self._lines, self._columns, self._flushed_lines)
            self._in_file = self.lines

    def _failed(self, exc: BaseException) -> RecordingError:
        """Writing failed (a full disk): put on disk every line appended before (``lines``),
        with their count, so that nothing but the lines that did not fit is lost and the file
        can be closed; the RecordingError to raise. On a clean ``NoRoom`` HDF5 has written
        nothing and flushes into the headroom's reserve; after a failed HDF5 write the lines
        since the last flush are written afresh (``_pending``)."""
        kept = keep_after_failure(
            exc,
            written=self.lines,
            flushed=self._flushed_lines,
            flush=lambda: self._flush_count(regrow=False),
            rewrite=self._rewrite_unflushed,
            trim=self._trim_and_flush,
        )
        self.lines = kept  # complete_lines is counted again from the file by close()
        self._pending.clear()
        self.failed = (
            f"{write_failure(self.path, exc)}; the scan file keeps the {kept} lines written before"
        )
        return RecordingError(self.failed)

    def _trim_and_flush(self, count: int) -> None:
        for dataset in (self._lines, *self._columns.values()):
            dataset.resize(count, axis=0)
        self._in_file = count
        self._headroom.flush(regrow=False)

    def _flush_count(self, *, regrow: bool = True) -> None:
        """Flush the lines so far, then their count (``/lines_flushed``); then (``regrow``)
        the headroom is made whole again (``Headroom.flush``: NoRoom if it cannot be, all
        flushed all the same)."""
        self._put_pending()
        self._headroom.flush(regrow=False)
        # Only now are the lines on disk: the count follows in a second, small flush.
        self._lines_flushed[0] = self.lines
        self._headroom.flush(regrow=False)
        self._flushed_lines = self.lines
        self._pending.clear()
        if regrow:
            self._headroom.ensure(0)

    def _rewrite_unflushed(self) -> None:
        """After a failed write: the lines since the last flush (and the stage changes)
        written afresh from memory, their chunks dropped first (HDF5 cannot be trusted to
        write them again, see ``_pending``), then everything flushed, with the count."""
        for dataset in (self._lines, *self._columns.values()):
            dataset.resize(self._flushed_lines, axis=0)
        self._in_file = self._flushed_lines
        self._put_pending()
        start = self.lines
        changes = np.asarray(self._stage_change_list, dtype=np.int64).reshape(-1, 2)
        self._stage_changes.resize(0, axis=0)
        self._stage_changes.resize(len(changes), axis=0)
        if len(changes):
            self._stage_changes[:] = changes
        self._headroom.flush(regrow=False)
        self._lines_flushed[0] = start
        self._headroom.flush(regrow=False)
        self._flushed_lines = start
        self._pending.clear()

    def note_stage_change(self, line_index: SupportsIndex, stages: SupportsIndex) -> None:
        """Record that from line ``line_index`` on the scan sums ``stages`` stages.

        The first call gives the scan's initial number of stages (at its first line)."""
        self._check_open()
        line_index = _as_int(line_index, "line_index")
        stages = _as_int(stages, "stages")
        if stages < 1:
            raise ValueError(f"stages must be at least 1; got {stages}")
        k = self._stage_change_count
        self._stage_changes.resize(k + 1, axis=0)
        self._stage_changes[k] = (line_index, stages)
        self._stage_change_count = k + 1
        self._stage_change_list.append((line_index, stages))

    def flush(self) -> None:
        """Write everything appended so far to the file, where readers see it and where it
        survives the writer's death; then the count of lines on disk (``/lines_flushed``)."""
        self._check_open()
        try:
            self._headroom.ensure(self._flush_bytes())
            self._flush_count()
        except (OSError, RuntimeError) as exc:
            raise self._failed(exc) from None
        self._last_flush = time.monotonic()

    def _flush_bytes(self) -> int:
        """The most a flush may write now: every chunk of lines since the last flush (at
        most two, ``append``), and the margin."""
        if self.lines == self._flushed_lines:
            return _MARGIN_BYTES
        first = self._flushed_lines // self._chunk_lines
        last = (self.lines - 1) // self._chunk_lines
        chunk_bytes = self._chunk_lines * self.width * self._dtype.itemsize
        return (last - first + 1) * chunk_bytes + _MARGIN_BYTES

    @property
    def flushed_lines(self) -> int:
        """Lines on disk: what the file keeps if the writer dies now."""
        return self._flushed_lines

    def close(
        self,
        attributes: Mapping[str, Any] | None = None,
        datasets: Mapping[str, Mapping[str, npt.ArrayLike]] | None = None,
    ) -> None:
        """Finish the scan: write the final attributes and close the file. Idempotent.

        ``attributes`` maps names to values: a mapping value goes to the group of that name
        (``{"counters": {...}}`` fills /counters; the group is made if needed), any other value
        is a root attribute. The root's own attributes (format, lines, ...) cannot be replaced.
        ``datasets`` maps a group name to arrays stored as datasets in it (the closed loop's
        record, ``{"motion_loop": {"time_s": ...}}``): an SWMR writer cannot add objects, so
        they are written here.
        """
        if self._closed:
            return
        root: dict[str, Any] = {}
        groups: dict[str, Mapping[str, Any]] = {}
        for name, value in (attributes or {}).items():
            if isinstance(value, Mapping):
                groups[_check_group_name(name, "close() attribute group")] = value
            elif name in _RESERVED_ROOT:
                raise ValueError(
                    f"close() cannot set the root attribute {name!r}: the recorder owns "
                    f"{', '.join(sorted(_RESERVED_ROOT))}; use another name"
                )
            else:
                root[name] = value
        if self.failed is None:
            # The lines and their count on disk before the close, while the headroom is there:
            # if the file cannot be reopened below, it is whole but for its attributes.
            try:
                with contextlib.suppress(NoRoom):  # a full disk: the headroom's reserve serves
                    self._headroom.ensure(self._flush_bytes())
                self._flush_count(regrow=False)
            except (OSError, RuntimeError) as exc:
                self._failed(exc)
        self._closed = True
        why = close_writer(self._file, self.path, self)
        if why is not None:
            self.failed = self.failed or why
            raise RecordingError(
                f"{self.failed}; {self.path} cannot be closed and stays open until the space is "
                "back (camd repairs it when it starts again; read_tdi_scan reads its "
                f"{self._flushed_lines} flushed lines now)"
            )
        if self.failed is not None:
            root["error"] = self.failed
        # An SWMR writer may not add or change attributes: reopen the finished file to do it.
        try:
            with reopen_to_finish(self.path) as f:
                refused = self._finish(f, root, groups, datasets)
        except (OSError, RuntimeError) as exc:
            raise RecordingError(
                f"cannot write the final attributes of {self.path}: "
                f"{self.failed or write_failure(self.path, exc)}; its {self._flushed_lines} "
                "flushed lines are readable (read_tdi_scan), its lines/complete_lines/counters "
                "attributes are missing (camd repairs it when it starts again)"
            ) from None
        if refused:
            raise ValueError(
                f"{self.path} is closed, but HDF5 could not store these attributes: "
                f"{'; '.join(refused)}; use numbers, strings, booleans or lists of them"
            )

    def _finish(
        self,
        f: h5py.File,
        root: Mapping[str, Any],
        groups: Mapping[str, Mapping[str, Any]],
        datasets: Mapping[str, Mapping[str, npt.ArrayLike]] | None,
    ) -> list[str]:
        """Write the final counts, attributes and datasets; the attributes HDF5 refused."""
        if self.failed is not None:
            # What the failed write left: the lines put on disk with their count.
            self.lines = self._flushed_lines
            for name in ("lines", *_COLUMNS):
                f[name].resize(self.lines, axis=0)
            self.complete_lines = int(np.count_nonzero(f["complete"][: self.lines]))
        f["lines_flushed"][0] = self.lines  # every line is on disk now
        self._flushed_lines = self.lines
        f.attrs.update(
            {"lines": self.lines, "complete_lines": self.complete_lines, "finished": True}
        )
        refused = _store_attrs(f, root, "")
        for group, values in groups.items():
            node = f[group] if group in f else f.create_group(group)
            refused += _store_attrs(node, values, f"{group}.")
        for group, arrays in (datasets or {}).items():
            node = f.require_group(_check_group_name(group, "close() dataset group"))
            for name, array in arrays.items():
                node.create_dataset(name, data=np.asarray(array))
        return refused

    def __enter__(self) -> TdiRecorder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


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


def read_tdi_scan(path: Path | str) -> TdiScan:
    """Read a whole TDI scan into memory, also one still being written (SWMR).

    RecordingError for a missing file, a file that is not HDF5 or not a camd TDI scan, or a
    scan format newer than this camd reads.
    """
    path = Path(path)
    if not path.is_file():
        raise RecordingError(f"{path} does not exist (or is not a file); check the path")
    try:
        f = h5py.File(path, "r", swmr=True)
    except BlockingIOError as exc:
        raise RecordingError(
            f"cannot open {path}: another program has it open for writing without SWMR "
            f"(a camd frame recording being made?): {exc}; wait until it is closed"
        ) from None
    except OSError as exc:
        raise RecordingError(f"cannot open {path} as HDF5: {exc}") from None
    with f:
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
        try:
            # While the scan is written, the datasets may have grown unequally: keep the lines
            # every one of them has.
            present = [name for name in _COLUMNS if name in f or name not in _ADDED_IN_2]
            n = min(len(f[name]) for name in ("lines", *present))
            if "lines_flushed" in f and not bool(f.attrs.get("finished", False)):
                n = min(n, int(f["lines_flushed"][0]))  # beyond it: not on disk yet
            lines = np.asarray(f["lines"][:n])
            columns = {
                name: (
                    np.asarray(f[name][:n], dtype=t)
                    if name in f
                    else np.full(n, _ADDED_IN_2[name], dtype=t)
                )
                for name, t in _COLUMNS.items()
            }
            stage_changes = np.asarray(f["stage_changes"][...], dtype=np.int64).reshape(-1, 2)
        except KeyError as exc:
            raise RecordingError(f"{path} is a damaged TDI scan: {exc}") from None
        attrs = unflatten_attrs(dict(f.attrs))
        meta = {
            name: unflatten_attrs(dict(node.attrs))
            for name, node in f.items()
            if isinstance(node, h5py.Group) and name != ENTRY
        }
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
