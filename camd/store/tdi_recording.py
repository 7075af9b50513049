"""Digital-TDI scans in HDF5: the lines the TDI engine made, each line's bookkeeping, the metadata.

One file per scan, appended to while the scan runs::

    /lines          (L, N) uint32 (mode "sum") or float32 (mode "mean"), chunks of chunk_lines lines,
                    compressed losslessly as the recorder was told (``camd.store.compression``;
                    by default Bitshuffle + LZ4), its attributes ``compression`` and
                    ``compression_level`` say how
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
    /entry          the NeXus entry (format 4, all of the file since 5; ``camd.store.nexus``):
                    NXdata with /lines as its signal against line_index and column, NXdetector
                    with the sensor and the TDI settings, every dataset (hard links), the stage,
                    every metadata group's values with units, end_time, for tools that know
                    NeXus (silx, h5web, nexusformat)

Root attributes: ``format`` ("camd-tdi-scan"), ``format_version``, ``mode`` ("sum" or "mean"),
``width``, ``created_utc``, ``camd_version``, NeXus's ``NX_class``, ``default``, ``file_time``,
``creator`` and ``creator_version``, ``lines``,
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

This module's ``TdiRecorder`` decides when lines are written and flushed, what a failed write
keeps and how the file is closed; the layout above is made and checked in
``camd.store.tdi_layout`` and read back in ``camd.store.tdi_reading`` (``read_tdi_scan`` and
``TdiScan`` are exported here too).
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any, SupportsIndex

import h5py
import numpy as np
import numpy.typing as npt

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
from camd.store.line_buffer import LineBuffer
from camd.store.recording import RecordingError, write_background
from camd.store.tdi_layout import (
    COLUMNS,
    FORMAT,
    FORMAT_VERSION,
    METADATA_GROUPS,
    MODES,
    RESERVED_ROOT,
    TdiDatasets,
    as_int,
    check_group_name,
    check_settings,
    finish_file,
    line_block,
    trim_lines,
)
from camd.store.tdi_reading import TdiScan, read_tdi_scan

__all__ = [
    "FORMAT",
    "FORMAT_VERSION",
    "METADATA_GROUPS",
    "MODES",
    "TdiRecorder",
    "TdiScan",
    "read_tdi_scan",
]

_RESERVE_MIN_BYTES = 4 << 20  # the least space held back for finishing the file on a full disk
# Besides the lines' chunks, what a flush may write: the columns' chunks and the metadata.
_MARGIN_BYTES = 512 << 10


class TdiRecorder(FlushedWriter):
    """Appends TDI lines to a new HDF5 file (layout in the module docstring).

    The file is created at once with its metadata (so a bad path fails before the scan starts)
    and never overwrites an existing file. ``metadata`` maps group name (profile, registers,
    timing, scan, or any other) to a dict; the groups profile, registers, timing, scan and
    counters always exist. The recorder flushes itself whenever a chunk of ``chunk_lines``
    lines is complete or ``flush_period_s`` has passed since the last flush, so a reader in
    another process (or the file after a crash) is never more than a chunk or a period behind;
    ``flush()`` makes everything so far visible (and durable against a kill) at once. A failed
    write (a full disk) raises RecordingError saying so; the lines flushed before stay readable. ``close(attributes)`` writes
    the final attributes; a ``with`` block closes the recorder whatever happens inside.
    ``background_dn`` (with ``background_attrs``) is stored as ``/background``. ``compression``
    is how each chunk of lines is compressed (``camd.store.compression``): a compressed chunk
    flushed before it filled is written again to new space, so choose ``chunk_lines`` that
    fill between flushes (``camd.store.tdi_layout.chunk_lines_for``, as the daemon does).

    The layout itself (what the file holds, what a block of lines may hold) is
    ``camd.store.tdi_layout``'s; the recorder decides when lines are written and flushed, what
    a failed write keeps, and how the file is closed.
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
        compression: Compression = DEFAULT,
    ) -> None:
        self.path = Path(path)
        self.compression = compression
        width, chunk_lines, dtype = check_settings(width, mode, chunk_lines, metadata)
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
        self._stage_change_list: list[tuple[int, int]] = []
        # The lines appended since the last flush, with their columns, written to the file by
        # the next flush (camd.store.line_buffer); and written afresh after a failed write (a
        # flush that fails on a full disk cannot simply be tried again: HDF5 then writes a new
        # chunk without adding it to the dataset's index; ``_failed``).
        self._pending = LineBuffer(
            width, dtype, chunk_lines, COLUMNS, raw_chunks=not compression.on
        )
        self._in_file = 0  # lines in the datasets: the flushed ones, or all once written
        self._closed = False
        self.failed: str | None = None  # why writing stopped (a full disk), None while it works
        retry_held()  # a file an earlier full disk held open, closed if the space is back
        chunk_bytes = chunk_lines * width * dtype.itemsize
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
            self._headroom = Headroom(
                self._file, self.reserve_bytes(width, mode, chunk_lines, compression)
            )
            background = 0 if background_dn is None else 4 * np.size(background_dn)
            self._headroom.ensure(background + _MARGIN_BYTES)
            self._data = TdiDatasets(
                self._file,
                self.path,
                width=width,
                mode=mode,
                chunk_lines=chunk_lines,
                metadata=metadata,
                compression=compression,
            )
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
    def reserve_bytes(
        width: int, mode: str, chunk_lines: int = 256, compression: Compression = DEFAULT
    ) -> int:
        """The space a recorder of these settings holds back to close its file if the disk
        fills (``camd.store.durability.Headroom``): what HDF5 may hold unwritten (two
        chunks of lines, as compressed they may take at most: ``append`` flushes before more
        are pending) and the metadata."""
        chunk_bytes = chunk_lines * width * np.dtype(MODES[mode]).itemsize
        return _RESERVE_MIN_BYTES + 2 * chunk_bound_bytes(chunk_bytes, compression)

    def _check_open(self) -> None:
        if self._closed:
            raise RecordingError(
                f"{self.path} is closed; start a new TdiRecorder (with a new path) to record more"
            )

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
        lines, columns = line_block(
            self.path,
            self.width,
            self.mode,
            data,
            index=index,
            stages_used=stages_used,
            complete=complete,
            frame_counter=frame_counter,
            stage_position=stage_position,
            m_dv_over_v=m_dv_over_v,
        )
        n = lines.shape[0]
        done_at = 0
        pending = self._pending
        while done_at < n:
            # The lines wait unflushed (in memory, written by the next flush) up to the end of
            # their chunk at most: a flush writes at most one chunk of lines, which the reserve
            # covers, and a chunk whose lines all come in one flush is written whole (the only
            # kind that is compressed: camd.store.line_buffer), also after a flush on time.
            to_chunk_end = self._chunk_lines - self.lines % self._chunk_lines
            piece = min(n - done_at, pending.room, to_chunk_end)
            if piece <= 0:
                self.flush()
                continue
            part = slice(done_at, done_at + piece)
            pending.add(lines[part], {name: values[part] for name, values in columns.items()})
            self.lines += piece
            self.complete_lines += int(np.count_nonzero(columns["complete"][part]))
            done_at += piece
            chunk_done = self.lines % self._chunk_lines == 0
            if chunk_done or time.monotonic() - self._last_flush >= self._flush_period_s:
                self.flush()

    def _put_pending(self) -> None:
        """Write the lines held in memory to the datasets (not flushed), unless they are."""
        if self._in_file < self.lines:
            self._pending.write(self._data.lines, self._data.columns, self._flushed_lines)
            self._in_file = self.lines

    def _failed(self, exc: BaseException) -> RecordingError:
        """Writing failed (a full disk): put on disk every line appended before (``lines``),
        with their count, so that nothing but the lines that did not fit is lost and the file
        can be closed; the RecordingError to raise. On a clean ``NoRoom`` HDF5 has written
        nothing and flushes into the headroom's reserve; after a failed HDF5 write the lines
        since the last flush are written afresh (``_pending``)."""
        kept = self._keep_after(exc, written=self.lines, flushed=self._flushed_lines)
        self.lines = kept  # complete_lines is counted again from the file by close()
        self._pending.clear()
        self.failed = (
            f"{write_failure(self.path, exc)}; the scan file keeps the {kept} lines written before"
        )
        return RecordingError(self.failed)

    def _trim_and_flush(self, count: int) -> None:
        self._data.resize(count)
        self._in_file = count
        self._headroom.flush(regrow=False)

    def _flush_count(self, *, regrow: bool = True) -> None:
        """Flush the lines so far, then their count (``/lines_flushed``); then (``regrow``)
        the headroom is made whole again (``Headroom.flush``: NoRoom if it cannot be, all
        flushed all the same)."""
        self._put_pending()
        self._headroom.flush(regrow=False)
        # Only now are the lines on disk: the count follows in a second, small flush.
        self._data.lines_flushed[0] = self.lines
        self._headroom.flush(regrow=False)
        self._flushed_lines = self.lines
        self._pending.clear()
        if regrow:
            self._headroom.ensure(0)

    def _rewrite_unflushed(self) -> None:
        """After a failed write: the lines since the last flush (and the stage changes)
        written afresh from memory, their chunks dropped first (HDF5 cannot be trusted to
        write them again, see ``_pending``), then everything flushed, with the count."""
        self._data.resize(self._flushed_lines)
        self._in_file = self._flushed_lines
        self._put_pending()
        start = self.lines
        self._data.rewrite_stage_changes(self._stage_change_list)
        self._headroom.flush(regrow=False)
        self._data.lines_flushed[0] = start
        self._headroom.flush(regrow=False)
        self._flushed_lines = start
        self._pending.clear()

    def note_stage_change(self, line_index: SupportsIndex, stages: SupportsIndex) -> None:
        """Record that from line ``line_index`` on the scan sums ``stages`` stages.

        The first call gives the scan's initial number of stages (at its first line)."""
        self._check_open()
        line_index = as_int(line_index, "line_index")
        stages = as_int(stages, "stages")
        if stages < 1:
            raise ValueError(f"stages must be at least 1; got {stages}")
        k = len(self._stage_change_list)
        self._data.stage_changes.resize(k + 1, axis=0)
        self._data.stage_changes[k] = (line_index, stages)
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
        """The most a flush may write now: every chunk of lines since the last flush (one,
        ``append``), as large as it may be compressed, and the margin."""
        if self.lines == self._flushed_lines:
            return _MARGIN_BYTES
        first = self._flushed_lines // self._chunk_lines
        last = (self.lines - 1) // self._chunk_lines
        chunk_bytes = self._chunk_lines * self.width * self._dtype.itemsize
        return (last - first + 1) * chunk_bound_bytes(chunk_bytes, self.compression) + _MARGIN_BYTES

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
                groups[check_group_name(name, "close() attribute group")] = value
            elif name in RESERVED_ROOT:
                raise ValueError(
                    f"close() cannot set the root attribute {name!r}: the recorder owns "
                    f"{', '.join(sorted(RESERVED_ROOT))}; use another name"
                )
            else:
                root[name] = value
        if self.failed is None:
            self._flush_before_close(self._flush_bytes())
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
            self.complete_lines = trim_lines(f, self.lines)
        self._flushed_lines = self.lines
        return finish_file(
            f,
            lines=self.lines,
            complete_lines=self.complete_lines,
            root=root,
            groups=groups,
            datasets=datasets,
        )

    def __enter__(self) -> TdiRecorder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
