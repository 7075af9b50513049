"""What a recording keeps when its writer dies, and how a file left open is made whole again.

Both kinds of file (frame recordings and TDI scans) are written in HDF5's single-writer /
multiple-reader (SWMR) mode: the library orders its writes so that the file on disk is always
a consistent file, and a writer killed between two flushes leaves every object and every
element flushed before the kill readable. Each file carries a one-element dataset
(``/frames_flushed`` or ``/lines_flushed``) written only after a flush has put that many
frames or lines on disk, and flushed in turn; so that count never claims more than the file
holds. A writer flushes at least every ``FLUSH_PERIOD_S`` while data arrives: a kill loses at
most the data of the last flush period (and what the acquisition held in memory, not yet handed
to the recorder).

A file whose writer died still has its "open for writing" flags set: HDF5 refuses a plain open
("file is already open for write (may use <h5clear file> to clear file consistency flags)"),
although ``h5py.File(path, "r", swmr=True)`` reads it. ``clear_write_flags`` clears them the
way ``h5clear -s`` does (HDF5's own "clear_status_flags" file-access property), and
``recover_file`` then marks the file incomplete and trims it to the flushed count, so that any
HDF5 viewer opens it.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import datetime as dt
import errno
import functools
import os
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import h5py
import numpy as np

FLUSH_PERIOD_S = 1.0  # a recorder flushes at least this often while data arrives
INTERRUPTED = "the daemon stopped without closing the file (killed, crashed or lost power)"


class RecoveryError(OSError):
    """A file left open by a dead writer cannot be reopened; the message says what to do."""


def is_disk_full(exc: BaseException) -> bool:
    """True if ``exc`` (an OSError from the OS, an OSError or RuntimeError from h5py) says the
    disk is full."""
    if isinstance(exc, OSError) and exc.errno in (errno.ENOSPC, errno.EDQUOT):
        return True
    text = str(exc)
    return any(
        sign in text
        for sign in ("No space left on device", "Disk quota exceeded", "errno = 28", "errno = 122")
    )


def write_failure(path: Path, exc: BaseException) -> str:
    """Why writing ``path`` failed, in words that say what to do."""
    if is_disk_full(exc):
        return (
            f"the disk holding {path.parent} is full (No space left on device); free some "
            "space or record to another disk"
        )
    return f"cannot write {path}: {exc}"


class SpaceReserve:
    """Disk space held back for finishing a file when the disk fills up.

    HDF5 cannot close a file whose last writes failed for want of space (and a process holding
    such a file may crash at exit): so a recorder allocates ``nbytes`` in a hidden file beside
    its recording (``.NAME.reserve``), and on a full disk releases it, trims the file back to
    what was flushed and closes it. ``release`` is idempotent; a reserve left by a killed
    daemon is removed when the recording is repaired (``recover_file``'s caller)."""

    def __init__(self, recording: Path, nbytes: int) -> None:
        self.path = reserve_path(recording)
        try:
            with open(self.path, "xb") as f:
                try:
                    os.posix_fallocate(f.fileno(), 0, nbytes)
                except OSError as exc:
                    if exc.errno not in (errno.EOPNOTSUPP, errno.EINVAL):
                        raise
                    # A file system without fallocate: write the zeros.
                    block = bytes(min(nbytes, 1 << 20))
                    for start in range(0, nbytes, len(block)):
                        f.write(block[: nbytes - start])
        except OSError:
            self.path.unlink(missing_ok=True)
            raise

    def release(self) -> None:
        """Give the space back to the file system."""
        self.path.unlink(missing_ok=True)


def close_writer(
    file: h5py.File, path: Path, failed: str | None, space: SpaceReserve
) -> str | None:
    """Close a recorder's file and release its reserve; return why writing failed: ``failed``
    (a write before), or the close's own failure, or None."""
    try:
        file.close()
    except (OSError, RuntimeError) as exc:  # h5py reports a failed flush as RuntimeError
        failed = failed or write_failure(path, exc)
    space.release()
    return failed


def reserve_path(recording: Path) -> Path:
    """Where ``SpaceReserve`` keeps the space for ``recording``."""
    return recording.with_name(f".{recording.name}.reserve")


@functools.cache
def _libhdf5() -> ctypes.CDLL | None:
    """The HDF5 library h5py uses (already loaded in this process), or None if not found."""
    try:
        with open("/proc/self/maps", encoding="utf-8") as maps:
            for line in maps:
                name = line.rsplit(None, 1)[-1]
                base = Path(name).name
                if base.startswith("libhdf5") and not base.startswith("libhdf5_hl"):
                    return ctypes.CDLL(name)
    except OSError:
        pass  # not Linux: ask the linker
    found = ctypes.util.find_library("hdf5")
    return ctypes.CDLL(found) if found else None


def clear_write_flags(path: Path) -> None:
    """Clear the "open for writing" flags that a dead writer left in ``path``'s superblock
    (what ``h5clear -s`` does). RecoveryError if this HDF5 cannot."""
    lib = _libhdf5()
    if lib is None or not hasattr(lib, "H5Pset"):
        raise RecoveryError(
            f"cannot clear the write flags of {path}: the HDF5 library was not found; run "
            f"`h5clear -s {path}` (Debian: hdf5-tools), or read it with "
            "h5py.File(path, 'r', swmr=True)"
        )
    fapl = h5py.h5p.create(h5py.h5p.FILE_ACCESS)
    clear = ctypes.c_bool(True)
    lib.H5Pset.argtypes = [ctypes.c_int64, ctypes.c_char_p, ctypes.c_void_p]
    lib.H5Pset.restype = ctypes.c_int
    if lib.H5Pset(fapl.id, b"clear_status_flags", ctypes.byref(clear)) < 0:
        raise RecoveryError(
            f"cannot clear the write flags of {path}: this HDF5 has no clear_status_flags "
            f"property; run `h5clear -s {path}` (Debian: hdf5-tools)"
        )
    try:
        fid = h5py.h5f.open(str(path).encode(), h5py.h5f.ACC_RDWR, fapl=fapl)
    except OSError as exc:
        raise RecoveryError(f"cannot reopen {path} to clear its write flags: {exc}") from None
    fid.close()


@contextmanager
def open_for_repair(path: Path) -> Iterator[h5py.File]:
    """``path`` opened read-write, first clearing the flags a dead writer left in it."""
    try:
        f = h5py.File(path, "r+")
    except BlockingIOError:
        raise RecoveryError(
            f"{path} is open in another program (a writer, or a reader holding a lock); close "
            "it and try again"
        ) from None
    except OSError as exc:
        if "already open" not in str(exc):
            raise RecoveryError(f"cannot open {path} to repair it: {exc}") from None
        clear_write_flags(path)
        try:
            f = h5py.File(path, "r+")
        except OSError as again:
            raise RecoveryError(f"cannot open {path} to repair it: {again}") from None
    with f:
        yield f


@dataclass(frozen=True, slots=True)
class Recovered:
    """What ``recover_file`` found in a file whose writer died."""

    path: Path
    kind: str  # "recording" (frames) or "scan" (TDI lines)
    count: int  # frames or lines kept: the flushed count
    expected: int  # frames or lines the acquisition planned (0: until stopped)
    dropped: int  # elements past the flushed count, trimmed (never confirmed on disk)

    @property
    def unit(self) -> str:
        """What the count counts: "frames" (a recording) or "lines" (a scan)."""
        return "frames" if self.kind == "recording" else "lines"

    def describe(self) -> str:
        """One sentence for the event log."""
        of = f" of {self.expected}" if self.expected else ""
        return (
            f"{self.kind} {self.path} was left open ({INTERRUPTED}): {self.count}{of} "
            f"{self.unit} kept, marked incomplete (finished = False)"
        )


def _count_and_datasets(f: h5py.File) -> tuple[str, int, int, list[str]]:
    """(kind, flushed count, planned count, per-element datasets) of an open file."""
    fmt = f.attrs.get("format")
    if isinstance(fmt, bytes):
        fmt = fmt.decode(errors="replace")
    if fmt == "camd-recording":
        kind, counter, first = "recording", "frames_flushed", "frames"
        expected = int(f.attrs.get("frames_expected", 0))
    elif fmt == "camd-tdi-scan":
        kind, counter, first = "scan", "lines_flushed", "lines"
        scan = f["scan"].attrs if "scan" in f else {}
        expected = int(scan.get("lines", 0)) if "lines" in scan else 0
    else:
        raise RecoveryError(f"{f.filename} is not a camd recording or TDI scan (format={fmt!r})")
    per_element = [
        name
        for name, node in f.items()
        if isinstance(node, h5py.Dataset)
        and name != counter
        and node.ndim >= 1
        and node.maxshape[0] is None
        and name != "stage_changes"
    ]
    lengths = [len(f[name]) for name in per_element]
    count = min(lengths) if lengths else 0
    if counter in f:
        count = min(count, int(np.asarray(f[counter])[0]))
    if first not in f:
        count = 0
    return kind, count, expected, per_element


def recover_file(path: Path, reason: str = INTERRUPTED) -> Recovered | None:
    """Make a file whose writer died whole again: clear its write flags, trim every per-frame
    (per-line) dataset to the flushed count, and mark it incomplete (``finished`` False,
    ``interrupted`` = ``reason`` and ``recovered_utc``). None if the file was finished after
    all (its writer closed it). RecoveryError if it cannot be opened or is not camd's."""
    with open_for_repair(path) as f:
        if bool(f.attrs.get("finished", False)):
            return None
        kind, count, expected, datasets = _count_and_datasets(f)
        longest = max((len(f[name]) for name in datasets), default=0)
        for name in datasets:
            f[name].resize(count, axis=0)
        attrs: dict[str, Any] = {
            "finished": False,
            "interrupted": reason,
            "recovered_utc": dt.datetime.now(dt.UTC).isoformat(timespec="milliseconds"),
        }
        if kind == "recording":
            attrs["frames"] = count
        else:
            attrs["lines"] = count
            if "complete" in f:
                attrs["complete_lines"] = int(np.count_nonzero(f["complete"][:count]))
        f.attrs.update(attrs)
    return Recovered(path, kind, count, expected, max(0, longest - count))
