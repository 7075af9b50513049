"""What the archive says of one camd file: its node's place, its searchable metadata, its arrays.

Read through camd's own readers (``camd.store.read_recording_info``,
``camd.store.tdi_reading.read_tdi_scan_info``), which read the metadata and count what is on
disk without reading the pixels: indexing a 100 GB recording costs what indexing a small one
does. The searchable keys sit at the top of each node's metadata (docs/archive.md, "Searching");
the file's whole metadata follows under ``camd``. Nothing here imports Tiled: this module is the
camd side of the catalogue, ``camd.archive.catalogue`` the Tiled side.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from camd.store.nexus import ACTIVITY_GROUP, SAMPLE_GROUP, camera_name
from camd.store.recording import (
    FORMAT as RECORDING_FORMAT,
)
from camd.store.recording import PER_FRAME_COLUMNS
from camd.store.recording_reading import file_format, read_recording_info
from camd.store.tdi_layout import FORMAT as SCAN_FORMAT
from camd.store.tdi_reading import read_tdi_scan_info

__all__ = [
    "SUFFIXES",
    "ArchivedFile",
    "ArrayPart",
    "NotCamdFile",
    "camd_files",
    "describe",
    "file_stamp",
    "node_segments",
]

SUFFIXES = (".h5", ".hdf5", ".nxs")
"""The file names the index opens; any other file in the data directory is passed over."""

CAMPAIGNS_FOLDER = "campaigns"  # the data directory's folder of campaign jobs (docs/campaigns.md)
# A campaign run's files (camd.campaign.runner): OUT/raw/STEP.h5 beside OUT/state.json (while it
# runs) and OUT/results.json (once it has ended), which map each step's key to its file.
_CAMPAIGN_RAW = "raw"
_CAMPAIGN_DOCS = ("results.json", "state.json")


class NotCamdFile(Exception):
    """An HDF5 file that is not a camd recording or scan: the index passes it over."""


@dataclass(frozen=True, slots=True)
class ArrayPart:
    """One array of a file's node: ``key`` under the node, the HDF5 ``dataset`` it serves and
    the ``length`` of its first axis that is on disk (the part a reader may read)."""

    key: str
    dataset: str
    length: int


@dataclass(frozen=True, slots=True)
class ArchivedFile:
    """One camd file as the archive shows it."""

    path: Path
    segments: tuple[str, ...]  # the node's path in the catalogue: ("scans", "scan-0001")
    metadata: dict[str, Any]
    arrays: tuple[ArrayPart, ...]


def node_segments(relative: Path) -> tuple[str, ...]:
    """A file's node path: its folders in the data directory, then its name without the
    suffix (Tiled's keys carry no storage format)."""
    return (*relative.parent.parts, relative.stem)


def file_stamp(path: Path) -> dict[str, int]:
    """What tells the index that a file changed since it was indexed: its size and mtime."""
    st = path.stat()
    return {"file_size_bytes": st.st_size, "file_mtime_ns": st.st_mtime_ns}


def describe(path: Path, data_dir: Path) -> ArchivedFile:
    """``path`` (inside ``data_dir``) as the archive shows it; NotCamdFile for an HDF5 file
        that is not camd's, ``camd.store.RecordingError`` for one that cannot be read (naming the file
    and why), OSError for one gone since it was listed."""
    relative = path.relative_to(data_dir)
    stamp = file_stamp(path)  # before reading: a file that grows meanwhile is indexed again
    fmt = file_format(path)
    common: dict[str, Any] = {"file": relative.as_posix(), **stamp}
    if fmt == SCAN_FORMAT:
        scan = read_tdi_scan_info(path)
        metadata = _scan_metadata(scan.attrs, scan.metadata, scan.lines)
        arrays = tuple(ArrayPart(name, name, scan.lines) for name in ("lines", *scan.columns))
        attrs, groups = scan.attrs, scan.metadata
    elif fmt == RECORDING_FORMAT:
        rec = read_recording_info(path)
        metadata = _recording_metadata(rec.attrs, rec.metadata, rec.frames)
        arrays = tuple(ArrayPart(name, name, rec.frames) for name in ("frames", *PER_FRAME_COLUMNS))
        attrs, groups = rec.attrs, rec.metadata
    else:
        raise NotCamdFile(
            f"{path} is an HDF5 file but not a camd recording or scan (format={fmt!r})"
        )
    profile = groups.get("profile", {})
    metadata = {
        **metadata,
        "camera": camera_name(profile),
        "profile": profile.get("profile"),
        "sensor": profile.get("sensor"),
        "created_utc": attrs.get("created_utc"),
        "date": str(attrs.get("created_utc", ""))[:10] or None,
        "finished": bool(attrs.get("finished", False)),
        **_present(
            # What the client in control said it was doing when the file was made (a
            # campaign's step: `campaign NAME: step I/N KIND KEY`), the file's NXnote.
            activity=groups.get(ACTIVITY_GROUP, {}).get("text"),
            sample=_sample(groups),
            error=attrs.get("error") or None,  # a scan that ended well says error=""
            interrupted=attrs.get("interrupted"),
            format=attrs.get("format"),
            format_version=attrs.get("format_version"),
            camd_version=attrs.get("camd_version"),
        ),
        **_campaign(path, data_dir),
        **common,
        "camd": {"attrs": attrs, **groups},
    }
    # An empty array (a recording stopped before its first frame) has no block to serve.
    return ArchivedFile(
        path, node_segments(relative), _json_safe(metadata), tuple(a for a in arrays if a.length)
    )


def _scan_metadata(
    attrs: Mapping[str, Any], groups: Mapping[str, Mapping[str, Any]], lines: int
) -> dict[str, Any]:
    scan = groups.get("scan", {})
    return _present(
        kind="scan",
        mode="scan",
        imaging_mode="tdi",
        tdi_mode=attrs.get("mode"),
        stages=scan.get("stages"),
        lines=lines,
        lines_wanted=scan.get("lines"),
        complete_lines=attrs.get("complete_lines"),
        width=attrs.get("width"),
        binning=scan.get("binning"),
        state=attrs.get("state"),
    )


def _recording_metadata(
    attrs: Mapping[str, Any], groups: Mapping[str, Mapping[str, Any]], frames: int
) -> dict[str, Any]:
    stream = groups.get("stream", {})
    return _present(
        kind="recording",
        mode="stare",
        imaging_mode=attrs.get("mode"),
        stages=stream.get("stages"),
        frames=frames,
        frames_expected=attrs.get("frames_expected"),
        rows=attrs.get("rows"),
        cols=attrs.get("cols"),
        bits=attrs.get("bits"),
        binning=stream.get("binning"),
        ended_early=attrs.get("ended_early"),
    )


def _present(**values: Any) -> dict[str, Any]:
    """The values that are there: a key a file lacks is left out, not stored as null."""
    return {key: value for key, value in values.items() if value is not None}


def _sample(groups: Mapping[str, Mapping[str, Any]]) -> Any:
    """The scene or target in front of the camera, as the file's NXsample names it
    (``camd.store.nexus``): the daemon's ``sample`` group, else the scan's or the stream's
    settings; None if none says."""
    for group in (SAMPLE_GROUP, "scan", "stream"):
        for key in ("target", "scene"):
            if groups.get(group, {}).get(key) is not None:
                return groups[group][key]
    return None


def _campaign(path: Path, data_dir: Path) -> dict[str, Any]:
    """``{"campaign": {"name", "step"}}`` for a file a campaign run made (``OUT/raw/STEP.h5``
    with the run's results.json or state.json in OUT), else nothing."""
    raw = path.parent
    if raw.name != _CAMPAIGN_RAW or not raw.parent.is_relative_to(data_dir):
        return {}
    out = raw.parent
    for name in _CAMPAIGN_DOCS:
        try:
            doc = json.loads((out / name).read_text(encoding="utf-8"))
        except (OSError, ValueError):
            continue
        if not isinstance(doc, dict) or not isinstance(doc.get("campaign"), str):
            continue
        relative = path.relative_to(out).as_posix()
        files = doc.get("files")
        if not isinstance(files, dict):  # state.json: each completed step's record
            completed = doc.get("completed", {})
            files = {k: v.get("file") for k, v in completed.items() if isinstance(v, dict)}
        step = next((key for key, file in files.items() if file == relative), None)
        return {"campaign": _present(name=doc["campaign"], step=step, run=out.name)}
    if out.parent == data_dir / CAMPAIGNS_FOLDER:
        return {"campaign": {"run": out.name}}  # a run whose state file is not written yet
    return {}


def _json_safe(value: Any) -> Any:
    """Metadata as JSON holds it: NaN and infinities (a column's "unknown") become None."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {str(k): _json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_safe(v) for v in value]
    return value


def camd_files(data_dir: Path) -> list[Path]:
    """The files under ``data_dir`` the index opens (``SUFFIXES``), sorted; hidden folders and
    files (a name starting with ".") are passed over."""
    found: list[Path] = []
    for root, dirs, files in os.walk(data_dir):
        dirs[:] = sorted(d for d in dirs if not d.startswith("."))
        found.extend(
            Path(root) / name
            for name in sorted(files)
            if name.endswith(SUFFIXES) and not name.startswith(".")
        )
    return found
