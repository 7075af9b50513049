"""camctl's snapshot: the live view's frame saved on the client's side (docs/cli.md).

    camctl snapshot DIR [--png [--colormap NAME]]
        write camd-snapshot-<seq>.tiff (raw DN, the settings as metadata) and
        camd-snapshot-<seq>.csv (the ROIs' statistics on that frame); with --png also
        camd-snapshot-<seq>.png, the frame as the page displays it (the page's default contrast)

The CSV is made from the TIFF's own metadata, with the daemon's writer of the same table
(``camd.analysis.roi_table``): both files are of the same frame however fast the stream moves
on. A file that exists is never overwritten: the command is refused, nothing written.
"""

from __future__ import annotations

import argparse
import io
import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import tifffile
from rich.console import Console

from camd.analysis.roi_table import roi_csv
from camd.cli.camctl_sensor import UsageError
from camd.client import CamdClient


def add_parsers(command: Callable[[str, str], argparse.ArgumentParser]) -> None:
    """Add ``snapshot`` through camctl's ``command(name, help)`` factory."""
    p = command(
        "snapshot",
        "save the live view's frame here: a TIFF of raw DN with its settings, and the ROIs' "
        "statistics as CSV",
    )
    p.add_argument(
        "directory", type=Path, help="where to write the files (on this computer; made if needed)"
    )
    p.add_argument(
        "--png",
        action="store_true",
        help="also the frame as the page displays it (percentiles 0.1-99.9 %% shown black-white)",
    )
    p.add_argument(
        "--colormap",
        default="gray",
        metavar="NAME",
        help="the PNG's colours: gray (default), viridis, inferno, cividis, turbo",
    )


def cmd_snapshot(client: CamdClient, args: argparse.Namespace) -> Any:
    meta, tiff = client.snapshot_tiff()
    with tifffile.TiffFile(io.BytesIO(tiff)) as tif:
        description = json.loads(tif.pages.first.description)
    directory: Path = args.directory
    base = f"camd-snapshot-{meta['seq']}"
    files: list[tuple[Path, bytes]] = [(directory / f"{base}.tiff", tiff)]
    if args.png:
        png = client.snapshot_png(meta["seq"], colormap=args.colormap)
        files.append((directory / f"{base}.png", png))
    stats = description.get("roi_stats")
    if stats:
        table = roi_csv(meta["counter"], meta["timestamp_ns"], stats, description["rois"])
        files.append((directory / f"{base}.csv", table.encode()))
    existing = [str(path) for path, _ in files if path.exists()]
    if existing:
        raise UsageError(f"{', '.join(existing)} already exists: name another directory")
    directory.mkdir(parents=True, exist_ok=True)
    for path, content in files:
        path.write_bytes(content)
    return {"seq": meta["seq"], "counter": meta["counter"], "files": [str(p) for p, _ in files]}


COMMANDS: dict[str, Callable[[CamdClient, argparse.Namespace], Any]] = {"snapshot": cmd_snapshot}


def render_snapshot(out: Console, doc: Any, args: argparse.Namespace) -> None:
    out.print(f"frame seq {doc['seq']} (counter {doc['counter']}):", markup=False)
    for path in doc["files"]:
        out.print(f"  {path}", markup=False)
    if not any(path.endswith(".csv") for path in doc["files"]):
        out.print("  no CSV: no ROI measured this frame (`camctl roi add`)", markup=False)


RENDER: dict[str, Callable[[Console, Any, argparse.Namespace], None]] = {
    "snapshot": render_snapshot
}
