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

A full disk must never cost more than the data that did not fit, nor crash the process. HDF5
cannot survive a failed write of its own: a dataset whose close could not write what HDF5 still
held (its chunk cache) is left half freed, and the next reference to it (the writer's own
Dataset object being collected) crashes the process in libhdf5; a failed flush of the metadata
leaves the file unable to flush ever again ("slist already enabled"); and a chunk whose first
write failed is written again without being entered in the dataset's index (it reads as
zeros). So a writer never lets HDF5 meet a full disk: before each write that takes space it asks
its ``Headroom`` (space allocated in the file itself, past HDF5's end) for it, and stops on a
clean ENOSPC with the headroom's reserve still there for the data HDF5 holds and for the close.
``close_writer`` flushes before it closes, and closes only once the flush went through; a file
whose flush still fails (another program's error, or a disk that lies about its space) is held
open, untouched, with every object of its writer, and ``retry_held`` closes it once the space is
back (each new recorder tries); its journal entry stays, so that the next start repairs it. For
the same reason a file is never reopened in the process that holds it open (``is_held_open``).
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import datetime as dt
import errno
import functools
import os
from abc import ABC, abstractmethod
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from camd.store.compression import filtered_bound_bytes
from camd.store.nexus import finish_nexus

FLUSH_PERIOD_S = 1.0  # a recorder flushes at least this often while data arrives
INTERRUPTED = "the daemon stopped without closing the file (killed, crashed or lost power)"


class RecoveryError(OSError):
    """A file left open by a dead writer cannot be reopened; the message says what to do."""


def is_disk_full(exc: BaseException) -> bool:
    """True if ``exc`` (an OSError from the OS, an OSError or RuntimeError from h5py) says the
    disk is full."""
    if isinstance(exc, OSError) and exc.errno in (errno.ENOSPC, errno.EDQUOT):
        return True
    return says_disk_full(str(exc))


def says_disk_full(text: str) -> bool:
    """True if the message ``text`` (an error's, or a failure written from one) says the disk
    is full."""
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


class NoRoom(OSError):
    """``Headroom.ensure`` found no space for the next write: nothing was written (errno
    ENOSPC or EDQUOT)."""


class Headroom:
    """Disk space allocated past the end of a writer's file, for what HDF5 writes next.

    HDF5 cannot survive a failed write of its own (module docstring), and on a disk that another
    program is filling, space set aside anywhere else could be taken before HDF5 uses it. So
    the space is allocated in the file itself, past the end HDF5 has allocated (its "end of
    allocation"), where HDF5 puts whatever it writes next: ``ensure(n)`` before each write of
    up to ``n`` bytes allocates ``n`` plus ``reserve`` bytes there (``allocate_past``: blocks
    only, no data, the file's length unchanged), or raises ``NoRoom`` before HDF5 has written
    anything. After that error the ``reserve`` bytes are still there: enough for the writer to
    put on disk what HDF5 holds and to close the file (each recorder sizes it so). HDF5 cuts
    the file (and the blocks past it) where a flush moves its end of allocation back, so the
    writer flushes through ``flush``, which allocates the headroom again at once; a killed
    writer's file keeps its headroom, which the repair at the next start writes into.
    ``ensure_room`` makes room again for reopening a closed file to finish it;
    ``release_tail`` gives the blocks back once the file is finished."""

    def __init__(self, file: h5py.File, reserve: int) -> None:
        self._file = file
        self._fd = file.id.get_vfd_handle()
        self.reserve = reserve
        # The blocks up to here are allocated: only HDF5's flushes free any (``flush``).
        self._allocated = os.fstat(self._fd).st_size
        self.ensure(0)

    def flush(self, *, regrow: bool = True) -> None:
        """HDF5's flush, then (``regrow``) the headroom made whole again: a flush that moves
        HDF5's end of allocation back (it gives back unused space at the end) cuts the file
        there, and the blocks past it go too. NoRoom if it cannot be made whole (the flush
        itself went through). Without ``regrow``: the writer is about to close the file."""
        self._file.flush()
        st = os.fstat(self._fd)
        if st.st_blocks * 512 + _CUT_SLACK < self._allocated:
            # Fewer blocks than the headroom had: HDF5 cut the file, and the blocks past it.
            self._allocated = min(self._allocated, st.st_size)
        if regrow:
            self.ensure(0)

    def ensure(self, nbytes: int) -> None:
        """Make room for a write of up to ``nbytes`` with ``reserve`` to spare after it;
        ``NoRoom`` if the disk has not the space (nothing written)."""
        end = self._file.id.get_filesize()  # HDF5's end of allocation: where it writes next
        want = end + nbytes + self.reserve
        if want <= self._allocated:
            return
        try:
            # Only what is missing: on some file systems (tmpfs) a failed request gives back
            # the blocks in its range that were allocated before and not yet written.
            allocate_past(self._fd, self._allocated, want - self._allocated)
            self._allocated = want
        except OSError as exc:
            if exc.errno not in (errno.ENOSPC, errno.EDQUOT):
                raise
            raise NoRoom(
                exc.errno,
                f"No space left on device (the next write needs {nbytes} bytes and "
                f"{self.reserve} more are kept to close the file)",
            ) from None


def keep_after_failure(
    exc: BaseException,
    *,
    written: int,
    flushed: int,
    flush: Callable[[], None],
    rewrite: Callable[[], None],
    trim: Callable[[int], None],
) -> int:
    """After a write failed (``exc``), put on disk what a writer can keep; how many frames or
    lines that is. After a clean ``NoRoom`` HDF5 has written nothing: ``flush`` puts all
    ``written`` on disk with their count, into the headroom's reserve. After a failed HDF5
    write, ``rewrite`` writes the data since the last flush afresh (HDF5 cannot be trusted to
    write it again: module docstring) and flushes. If that fails too, ``trim`` goes back to
    the ``flushed`` count; if even that fails the writer's close holds the file open and the
    next start repairs it."""
    try:
        (flush if isinstance(exc, NoRoom) else rewrite)()
    except (OSError, RuntimeError):
        with contextlib.suppress(OSError, RuntimeError):
            trim(flushed)
        return flushed
    return written


class FlushedWriter(ABC):
    """A writer of a file with a ``Headroom`` (``FrameRecorder``, ``TdiRecorder``): what it
    keeps when a write fails (``keep_after_failure``) and its last flush before the close,
    through the steps each writer implements for its own data and count."""

    _headroom: Headroom

    @abstractmethod
    def _flush_count(self, *, regrow: bool = True) -> None:
        """Flush the data so far, then its count; then (``regrow``) the headroom is made
        whole again (``Headroom.flush``: NoRoom if it cannot be, all flushed all the same)."""

    @abstractmethod
    def _rewrite_unflushed(self) -> None:
        """After a failed write: the data since the last flush written afresh, then
        everything flushed, with the count."""

    @abstractmethod
    def _trim_and_flush(self, count: int) -> None:
        """Go back to ``count`` (frames or lines) on disk."""

    @abstractmethod
    def _failed(self, exc: BaseException) -> OSError:
        """Writing failed: keep what can be kept (``_keep_after``); the error to raise."""

    def _keep_after(self, exc: BaseException, *, written: int, flushed: int) -> int:
        """``keep_after_failure`` with this writer's steps; how many frames or lines are kept."""
        return keep_after_failure(
            exc,
            written=written,
            flushed=flushed,
            flush=lambda: self._flush_count(regrow=False),
            rewrite=self._rewrite_unflushed,
            trim=self._trim_and_flush,
        )

    def _flush_before_close(self, margin_bytes: int) -> None:
        """The data and its count on disk before the close, while the headroom is there (room
        for ``margin_bytes`` asked first): if the file cannot be reopened to be finished, it is
        whole but for its attributes. A failure goes through ``_failed``, which records it."""
        try:
            with contextlib.suppress(NoRoom):  # a full disk: the headroom's reserve serves
                self._headroom.ensure(margin_bytes)
            self._flush_count(regrow=False)
        except (OSError, RuntimeError) as exc:
            self._failed(exc)


FINISH_BYTES = 1 << 20  # room a closed file is given before it is reopened to be finished
_KEEP_SIZE = 0x01  # fallocate(2): FALLOC_FL_KEEP_SIZE
_PUNCH_HOLE = 0x02  # fallocate(2): FALLOC_FL_PUNCH_HOLE
_TAIL_MAX = 1 << 36  # past the end of a finished file: the most a headroom may have allocated
_PIECE = 256 << 10  # allocate_past's request size
# A headroom is taken as cut when the file has this much fewer blocks than it allocated (more
# than the holes HDF5 leaves, less than any reserve).
_CUT_SLACK = 1 << 20


@functools.cache
def _fallocate() -> Any:
    """libc's fallocate(2) (Linux), or None."""
    try:
        fn = ctypes.CDLL(None, use_errno=True).fallocate
    except (AttributeError, OSError):
        return None
    fn.argtypes = [ctypes.c_int, ctypes.c_int, ctypes.c_int64, ctypes.c_int64]
    fn.restype = ctypes.c_int
    return fn


def allocate_past(fd: int, offset: int, length: int) -> None:
    """Allocate the blocks of ``[offset, offset + length)`` of the file ``fd`` without
    changing its length (fallocate with FALLOC_FL_KEEP_SIZE), so that HDF5 writing there
    later needs no new space; OSError (ENOSPC) if the disk has not the space. Where the file
    system cannot, ``os.posix_fallocate`` (the file grows: HDF5 accepts a file longer than
    it allocated, and cuts it when it closes the file)."""
    fn = _fallocate()
    if fn is None:
        os.posix_fallocate(fd, offset, length)
        return
    end = offset + length
    while offset < end:
        # In pieces: a failed request may give back the unwritten blocks of its whole range
        # (tmpfs), so a failure costs at most one piece of what was allocated before.
        piece = min(end, (offset // _PIECE + 1) * _PIECE) - offset
        if fn(fd, _KEEP_SIZE, offset, piece) != 0:
            err = ctypes.get_errno()
            if err in (errno.EOPNOTSUPP, errno.ENOSYS):
                os.posix_fallocate(fd, offset, end - offset)
                return
            raise OSError(err, os.strerror(err))
        offset += piece


def ensure_room(path: Path, nbytes: int = FINISH_BYTES) -> None:
    """Before a closed writer's file is reopened to be finished or repaired: ``nbytes``
    allocated past HDF5's end of allocation (read from the superblock), where what is written
    then goes. There the writer's ``Headroom`` still is (for a killed writer too), so this
    needs no new space but where HDF5 cut the file. OSError(ENOSPC) if the disk has not the
    space: the file must then not be written (HDF5 cannot survive a failed write)."""
    fd = os.open(path, os.O_RDWR)
    try:
        try:
            allocate_past(fd, _end_of_allocation(fd), nbytes)
        except OSError as exc:
            if exc.errno not in (errno.ENOSPC, errno.EDQUOT):
                raise
            raise OSError(
                exc.errno, f"No space left on device (writing to {path} needs {nbytes} bytes)"
            ) from None
    finally:
        os.close(fd)


def release_tail(path: Path) -> None:
    """Give back the blocks a ``Headroom`` allocated past the end of ``path`` (finished or
    repaired: nothing will be written there)."""
    try:
        fd = os.open(path, os.O_RDWR)
    except OSError:
        return
    try:
        fn = _fallocate()
        size = os.fstat(fd).st_size
        if fn is not None:
            fn(fd, _KEEP_SIZE | _PUNCH_HOLE, size, _TAIL_MAX)  # tmpfs gives them back so
        # ext4 punches no hole past the file's size (measured: a repair that adds 2 KB of
        # objects kept its 30 MB headroom): a truncate to the same size frees the blocks past
        # the end there, and on most file systems.
        os.ftruncate(fd, size)
    except OSError:
        pass  # a few MB stay allocated: harmless
    finally:
        os.close(fd)


_SIGNATURE = b"\x89HDF\r\n\x1a\n"


def _end_of_allocation(fd: int) -> int:
    """The end-of-file address in the superblock of the HDF5 file open as ``fd`` (version 2
    or 3, as camd writes: the HDF5 file format specification, "Superblock"), else its size."""
    head = os.pread(fd, 48, 0)
    size = os.fstat(fd).st_size
    if len(head) < 12 or head[:8] != _SIGNATURE or head[8] not in (2, 3):
        return size
    width = head[9]  # size of offsets
    at = 12 + 2 * width  # after the base address and the superblock extension's
    if width not in (4, 8) or len(head) < at + width:
        return size
    return min(int.from_bytes(head[at : at + width], "little"), size)


@dataclass(slots=True)
class _Held:
    """A writer's file that could not be flushed for its close (the disk stayed full), kept open
    with its writer (every h5py object of it) so that nothing of it is collected."""

    path: Path
    inode: tuple[int, int] | None  # (st_dev, st_ino): the path may be reused for a new file
    file: h5py.File
    writer: object


_held: list[_Held] = []


def close_writer(file: h5py.File, path: Path, writer: object) -> str | None:
    """Close a writer's file (module docstring): flush what HDF5 holds (into the file's
    ``Headroom``), then close. None once closed; else why the flush failed, and the file stays
    open in HDF5, held with ``writer`` (``is_held_open``) until ``retry_held`` closes it."""
    try:
        file.flush()
    except (OSError, RuntimeError) as exc:  # h5py reports a failed flush as RuntimeError
        _held.append(_Held(path, _inode(path), file, writer))
        return write_failure(path, exc)
    # Nothing is left to write but the superblock's flags, in place: the close cannot run out
    # of space now.
    file.close()
    return None


def create_file(path: Path, what: str, **options: Any) -> h5py.File:
    """A new HDF5 file at ``path`` ("w-": never an existing one) for a writer, with ``options``
    (h5py.File's); an OSError saying what to do if it cannot be created; a
    file the failed attempt left (HDF5 creates it before writing its superblock: a 0-byte
    file on a full disk) is removed, so that a retry with the same name works."""
    try:
        return h5py.File(path, "w-", **options)
    except FileExistsError:
        raise  # someone else's file, made since the caller checked: not ours to remove
    except OSError as exc:
        with contextlib.suppress(OSError):
            path.unlink(missing_ok=True)
        why = (
            write_failure(path, exc)
            if is_disk_full(exc)
            else f"{exc}; check that the daemon's user may write there"
        )
        raise OSError(f"cannot create {what} {path}: {why}") from None


def discard_new_file(file: h5py.File, path: Path, writer: object) -> None:
    """Give up a writer's file that failed while it was being set up (before any data): close
    it as ``close_writer`` does (never a failed close) and remove it, so that a retry with the
    same name works."""
    close_writer(file, path, writer)
    path.unlink(missing_ok=True)


def retry_held() -> list[Path]:
    """Try again to close the files ``close_writer`` had to hold open; the paths it closed (each
    still needs its repair: ``recover_file``)."""
    closed: list[Path] = []
    for held in list(_held):
        try:
            held.file.flush()
        except (OSError, RuntimeError):
            continue  # still full: try again later
        held.file.close()
        _held.remove(held)
        closed.append(held.path)
    return closed


def is_held_open(path: Path) -> bool:
    """True if this process holds ``path`` open for writing after a failed close: it must not
    be opened again here (HDF5 would share the broken file), only repaired by the next start."""
    inode = _inode(path)
    return any(h.path == path and (h.inode is None or h.inode == inode) for h in _held)


def _inode(path: Path) -> tuple[int, int] | None:
    try:
        st = path.stat()
    except OSError:
        return None
    return st.st_dev, st.st_ino


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
    """``path`` opened read-write, first clearing the flags a dead writer left in it (and room
    made for the repair's writes: ``ensure_room``)."""
    try:
        ensure_room(path)
    except OSError as exc:
        raise RecoveryError(f"cannot repair {path}: {write_failure(path, exc)}") from None
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
    try:
        yield f
    finally:
        _close_flushed(f, path)
    release_tail(path)


@contextmanager
def reopen_to_finish(path: Path) -> Iterator[h5py.File]:
    """A writer's file, closed, opened read-write again to write what an SWMR writer may not
    (attributes, new datasets), with room made for that first (``ensure_room``: OSError if the
    disk has none); closed as ``close_writer`` closes (never a failed close: RecoveryError if
    it cannot be written out, the file then held open)."""
    ensure_room(path)
    try:
        f = h5py.File(path, "r+")
    except BlockingIOError:
        # A reader holds the file (and a shared lock on it): it sees what is written here when
        # it opens the file again.
        f = h5py.File(path, "r+", locking=False)
    try:
        yield f
    finally:
        _close_flushed(f, path)
    release_tail(path)


def _close_flushed(f: h5py.File, path: Path) -> None:
    """Close ``f``, flushing first (module docstring: HDF5 must never be asked to close a file
    it cannot write out); RecoveryError, and the file held open, if it cannot be written."""
    try:
        f.flush()
    except (OSError, RuntimeError) as exc:
        _held.append(_Held(path, _inode(path), f, None))
        raise RecoveryError(f"cannot write {path}: {write_failure(path, exc)}") from None
    f.close()


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


def _utc(t_s: float) -> str:
    return dt.datetime.fromtimestamp(t_s, dt.UTC).isoformat(timespec="milliseconds")


def _end_time(f: h5py.File, kind: str, count: int, last_write_s: float) -> str:
    """When a dead writer's data end: a recording's last kept frame's arrival (if it is after
    the file was made: a host clock set back says nothing), else the file's last write (its
    modification time before the repair touched it)."""
    if kind == "recording" and count and "received_unix_ns" in f:
        arrived_s = int(f["received_unix_ns"][count - 1]) / 1e9
        created = f.attrs.get("created_utc", "")
        try:
            text = created.decode() if isinstance(created, bytes) else str(created)
            created_s = dt.datetime.fromisoformat(text).timestamp()
        except ValueError:
            created_s = 0.0
        if arrived_s >= created_s:
            return _utc(arrived_s)
    return _utc(last_write_s)


def _trim_bytes(f: h5py.File, datasets: list[str], count: int) -> int:
    """The most that trimming ``datasets`` to ``count`` elements may write to new space: HDF5
    fills the part of a chunk cut by the new end (its elements past it), and a compressed chunk
    rewritten goes to new space (a raw one is rewritten in place)."""
    need = 0
    for name in datasets:
        ds = f[name]
        chunks = ds.chunks
        if chunks is None or count % chunks[0] == 0 or count >= len(ds):
            continue
        if ds.id.get_create_plist().get_nfilters() == 0:
            continue
        need += filtered_bound_bytes(int(np.prod(chunks)) * ds.dtype.itemsize)
    return need


def recover_file(path: Path, reason: str = INTERRUPTED) -> Recovered | None:
    """Make a file whose writer died whole again: clear its write flags, trim every per-frame
    (per-line) dataset to the flushed count, mark it incomplete (``finished`` False,
    ``interrupted`` = ``reason`` and ``recovered_utc``) and give its NeXus entry an
    ``end_time`` (the last kept frame's arrival, or the dead writer's last write) and the root's
    new values (``camd.store.nexus.finish_nexus``). None if the file was finished after all
    (its writer closed it). RecoveryError if it cannot be opened or is not camd's."""
    try:
        last_write_s = path.stat().st_mtime
    except OSError:
        last_write_s = dt.datetime.now(dt.UTC).timestamp()
    with open_for_repair(path) as f:
        if bool(f.attrs.get("finished", False)):
            return None
        kind, count, expected, datasets = _count_and_datasets(f)
        longest = max((len(f[name]) for name in datasets), default=0)
        try:
            Headroom(f, 0).ensure(_trim_bytes(f, datasets, count))
        except OSError as exc:
            raise RecoveryError(f"cannot repair {path}: {write_failure(path, exc)}") from None
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
        finish_nexus(f, end_time=_end_time(f, kind, count, last_write_s))
    return Recovered(path, kind, count, expected, max(0, longest - count))
