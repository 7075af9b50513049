"""The lines a TDI scan holds between two flushes: copied in as they come, written once per flush.

Each write to an HDF5 dataset costs tens of microseconds of library calls whatever its size
(h5py's selection machinery alone is about 90 us), and a scan has seven per-line datasets.
Written at every append, that was about 0.65 ms per block of lines, 11-16 us per line at the
fastest line rates. So ``TdiRecorder.append`` copies each block into a ``LineBuffer`` and
every flush writes the buffer out: each dataset grown once and written once, through h5py's
low-level calls (one hyperslab each), and, when ``/lines`` is not compressed, a buffer that is
exactly one aligned chunk of it as one raw chunk (``H5Dwrite_chunk``: no chunk cache, no extra
copy).

A compressed ``/lines`` (camd.store.compression) goes through its filter. A chunk written
again (a flush before it filled, then the rest) changes size and goes to new space, and the SWMR
writer never reuses the space it leaves: a scan's file grows by the chunk each time. So the
recorder flushes at every chunk's end (a fast scan writes each chunk whole, once), and a slow
scan takes chunks that fill within a flush period (``camd.store.tdi_layout.chunk_lines_for``).

What a reader sees does not change: a reader (or the file after the writer's death) sees the
lines up to ``/lines_flushed``, which a flush writes only after the lines themselves are on
disk; lines appended since were never promised to it.
"""

from __future__ import annotations

from collections.abc import Mapping

import h5py
import numpy as np
import numpy.typing as npt
from h5py import h5s


class LineBuffer:
    """Up to ``capacity`` lines of ``width`` columns of ``dtype``, with one value per line of
    each column in ``columns`` (name: dtype), held until ``write`` puts them in a file.
    ``raw_chunks``: the lines' dataset stores its chunks as they are (no compression filter),
    so that a whole chunk may be written directly."""

    def __init__(
        self,
        width: int,
        dtype: np.dtype[np.generic],
        capacity: int,
        columns: Mapping[str, type[np.generic]],
        *,
        raw_chunks: bool = True,
    ) -> None:
        self.capacity = capacity
        self._raw_chunks = raw_chunks
        self._width = width
        self._dtype = dtype
        self._column_types = dict(columns)
        # Allocated at the first line: a recorder that never gets one costs nothing.
        self._lines: npt.NDArray[np.generic] | None = None
        self._columns: dict[str, npt.NDArray[np.generic]] = {}
        self.n = 0  # lines held

    @property
    def room(self) -> int:
        """Lines that still fit."""
        return self.capacity - self.n

    def add(
        self, lines: npt.NDArray[np.generic], columns: Mapping[str, npt.NDArray[np.generic]]
    ) -> None:
        """Copy ``lines`` (at most ``room``) and their ``columns`` in."""
        if self._lines is None:
            self._lines = np.empty((self.capacity, self._width), dtype=self._dtype)
            self._columns = {
                name: np.empty(self.capacity, dtype=t) for name, t in self._column_types.items()
            }
        k = lines.shape[0]
        start, stop = self.n, self.n + k
        if stop > self.capacity:
            raise ValueError(f"{k} lines do not fit the {self.room} left in the line buffer")
        self._lines[start:stop] = lines
        for name, values in columns.items():
            self._columns[name][start:stop] = values
        self.n = stop

    def clear(self) -> None:
        """The lines are on disk: forget them."""
        self.n = 0

    def write(
        self,
        lines_ds: h5py.Dataset,
        column_ds: Mapping[str, h5py.Dataset],
        start: int,
    ) -> None:
        """Grow every dataset to ``start + n`` rows and write the lines held at rows
        ``start ..`` (nothing flushed: the caller flushes). ``lines_ds`` is chunked in
        ``capacity`` lines. Raises what HDF5 raises."""
        n = self.n
        stop = start + n
        lines_ds.id.set_extent((stop, self._width))
        for ds in column_ds.values():
            ds.id.set_extent((stop,))
        if n == 0 or self._lines is None:
            return
        if self._raw_chunks and n == self.capacity and start % n == 0:
            # Exactly one aligned chunk (the fast line rates' case): the chunk as it is on disk.
            lines_ds.id.write_direct_chunk((start, 0), self._lines)
        else:
            write_rows(lines_ds, start, self._lines[:n])
        for name, ds in column_ds.items():
            write_rows(ds, start, self._columns[name][:n])


def write_rows(ds: h5py.Dataset, start: int, values: npt.NDArray[np.generic]) -> None:
    """Write ``values`` at rows ``start ..`` of ``ds`` (already that long): one hyperslab,
    through h5py's low-level calls (a quarter of the high-level ``ds[a:b] = values``)."""
    shape = values.shape
    file_space = ds.id.get_space()
    file_space.select_hyperslab((start, *(0 for _ in shape[1:])), shape)
    ds.id.write(h5s.create_simple(shape), file_space, np.ascontiguousarray(values))
