"""The list, on disk, of the recordings a daemon has open: what a restart must look at.

A recording can be written anywhere (``--out`` is the user's), so after a crash nothing but
this list says which files were left open. Each open file is one small JSON file in the
journal's folder (``<data_dir>/open-recordings/``), written (atomically: temporary file, then
rename) before the first frame and removed once the file is closed; a daemon killed in between
leaves the entry behind, and ``recover_left_open`` at the next start repairs each file it names
(``camd.store.durability.recover_file``) and says what it found.
"""

from __future__ import annotations

import datetime as dt
import hashlib
import json
import logging
import os
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from camd.store.durability import (
    Recovered,
    RecoveryError,
    is_disk_full,
    is_held_open,
    recover_file,
)
from camd.store.recording import FrameRecorder, RecordingError

if TYPE_CHECKING:
    import h5py

log = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True)
class LeftOpen:
    """One entry found at start: the file, its kind, when it was opened, and what became of it."""

    path: Path
    kind: str  # "recording" or "scan"
    opened_utc: str
    recovered: Recovered | None  # None: missing, finished after all, or not repairable
    problem: str | None  # why it could not be repaired (None: it was, or it was finished)

    def describe(self) -> str:
        """One sentence for the event log."""
        if self.recovered is not None:
            return self.recovered.describe()
        if self.problem is not None:
            return (
                f"{self.kind} {self.path} (opened {self.opened_utc}) was left open: {self.problem}"
            )
        return f"{self.kind} {self.path} was closed after all; nothing to repair"


class RecordingJournal:
    """The open recordings, one JSON file each in ``folder`` (module docstring)."""

    def __init__(self, folder: Path) -> None:
        self.folder = folder

    def _entry(self, path: Path) -> Path:
        digest = hashlib.sha256(str(path).encode()).hexdigest()[:24]
        return self.folder / f"{digest}.json"

    def opened(self, path: Path, kind: str) -> None:
        """Note that ``path`` (a "recording" or a "scan") is open for writing."""
        self.folder.mkdir(parents=True, exist_ok=True)
        entry = self._entry(path)
        temporary = entry.with_suffix(".tmp")
        record = {
            "path": str(path),
            "kind": kind,
            "opened_utc": dt.datetime.now(dt.UTC).isoformat(timespec="seconds"),
            "pid": os.getpid(),
        }
        temporary.write_text(json.dumps(record) + "\n", encoding="utf-8")
        temporary.replace(entry)

    def closed(self, path: Path) -> None:
        """Note that ``path`` was closed (or removed): nothing to repair."""
        self._entry(path).unlink(missing_ok=True)

    def entries(self) -> list[tuple[Path, dict[str, str]]]:
        """The entries left in the folder: (entry file, its record)."""
        if not self.folder.is_dir():
            return []
        found: list[tuple[Path, dict[str, str]]] = []
        for entry in sorted(self.folder.glob("*.json")):
            try:
                record = json.loads(entry.read_text(encoding="utf-8"))
                found.append((entry, {k: str(v) for k, v in record.items()}))
            except (OSError, ValueError) as exc:
                log.warning("unreadable entry %s in the recording journal: %s", entry, exc)
                entry.unlink(missing_ok=True)
        return found


def recover_left_open(journal: RecordingJournal) -> list[LeftOpen]:
    """Repair every file the journal says was left open; each entry is then removed, but for a
    file whose repair failed for want of space (it is tried again at the next start, and the
    problem says so); a file that cannot be repaired for another reason is reported, not
    retried forever."""
    report: list[LeftOpen] = []
    for entry, record in journal.entries():
        path = Path(record.get("path", ""))
        kind = record.get("kind", "recording")
        opened = record.get("opened_utc", "?")
        recovered: Recovered | None = None
        problem: str | None = None
        if not path.is_file():
            problem = "the file is gone (removed, or never written)"
        else:
            try:
                recovered = recover_file(path)
            except (RecoveryError, OSError, KeyError, ValueError) as exc:
                problem = f"cannot repair it: {exc}"
                if is_disk_full(exc):
                    problem += "; camd tries again when it next starts"
                    report.append(LeftOpen(path, kind, opened, recovered, problem))
                    continue  # the entry stays
        report.append(LeftOpen(path, kind, opened, recovered, problem))
        entry.unlink(missing_ok=True)
    return report


def close_recording(
    recorder: FrameRecorder,
    stats: Mapping[str, Any] | None,
    journal: RecordingJournal,
    log_event: Callable[[str, str, str], None],
    *,
    ended_early: str | None = None,
    finish_with: Callable[[h5py.File], None] | None = None,
) -> None:
    """Close a frame recording (``ended_early``: why it holds fewer frames than asked for;
    ``finish_with``: what else it keeps, as ``FrameRecorder.close``) and take it off the
    journal once the file is whole (``settle_failed_close`` if the close failed); the event
    log says how it ended."""
    path = recorder.path
    try:
        recorder.close(stats, ended_early=ended_early, finish_with=finish_with)
    except RecordingError as exc:
        settle_failed_close(path, exc, "recording", journal, log_event, "stream")
        return
    if recorder.failed is not None:
        log_event(
            "warning",
            "stream",
            f"recording {path} closed after a failed write: {recorder.flushed} frames kept, "
            "marked unfinished",
        )
    else:
        log_event("info", "stream", f"recording {path} closed: {recorder.flushed} frames")
    if recorder.finish_error is not None:
        log_event(
            "warning",
            "stream",
            f"recording {path}: its ROI statistics could not be stored: {recorder.finish_error}",
        )
    journal.closed(path)


def settle_failed_close(
    path: Path,
    exc: BaseException,
    kind: str,
    journal: RecordingJournal,
    log_event: Callable[[str, str, str], None],
    source: str,
) -> bool:
    """A writer's close failed (``exc``): repair the file at once if it can be
    (``recover_file``; never one this process still holds open, which HDF5 would share) and
    take it off the journal; else leave it on the journal for the next start. The event log
    says which; True if the file is whole."""
    if is_held_open(path):
        log_event(
            "error",
            source,
            f"{kind} {path} could not be closed: {exc}; camd repairs it when it next starts",
        )
        return False
    try:
        recover_file(path, reason=str(exc))
    except (RecoveryError, OSError, KeyError, ValueError) as again:
        log_event(
            "error",
            source,
            f"{kind} {path} could not be closed ({exc}) nor repaired ({again}); camd tries "
            "again when it next starts",
        )
        return False
    log_event("warning", source, f"{kind} {path} was repaired after: {exc}")
    journal.closed(path)
    return True
