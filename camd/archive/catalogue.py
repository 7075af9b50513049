"""The Tiled side of the archive: the catalogue database and the nodes camd puts in it.

Each camd file becomes a container node whose metadata ``camd.archive.describe`` makes, with one
array node per dataset (the frames or the TDI lines, and each per-frame or per-line column).
An array node is Tiled's own HDF5 adapter over the file (mimetype ``application/x-hdf5``,
the dataset's path, ``swmr`` so that a file still being written opens, and a ``slice`` to the
part on disk when the file is unfinished): any Tiled server reads the catalogue, without camd
installed, which is what lets several servers share one PostgreSQL catalogue (docs/archive.md).
The array's chunks are the file's (one frame; the scan's blocks of lines), so a Dask client
reads one chunk per task, lazily.

``index`` brings a catalogue up to date with a data directory: new files added, files whose size
or modification time changed replaced, nodes of files gone (or no longer readable) removed. It writes the database
directly (no server needed, none in the way: a running server reads what it wrote on the next
request).
"""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import hdf5plugin  # noqa: F401  (camd's one import of it for reading: registers HDF5's filters)
from tiled.adapters.hdf5 import HDF5ArrayAdapter
from tiled.catalog import from_uri
from tiled.catalog.adapter import CatalogContainerAdapter
from tiled.server.core import NoEntry
from tiled.structures.core import Spec, StructureFamily
from tiled.structures.data_source import Asset, DataSource, Management
from tiled.utils import ensure_uri

from camd.archive.describe import (
    ArchivedFile,
    ArrayPart,
    NotCamdFile,
    camd_files,
    describe,
    file_stamp,
)

__all__ = [
    "HDF5_MIMETYPE",
    "CatalogueError",
    "IndexReport",
    "catalogue_uri",
    "index",
    "init_catalogue",
    "open_catalogue",
    "shown_uri",
]

HDF5_MIMETYPE = "application/x-hdf5"
SPECS = {"recording": "camd-recording", "scan": "camd-tdi-scan"}  # a node's spec, by kind
_PAGE = 1000  # children read per query while walking the catalogue


def catalogue_uri(catalogue: str) -> str:
    """A database URI from ``--catalog``: a URI as given, a path as an SQLite file."""
    if "://" in catalogue:
        return catalogue
    return f"sqlite:///{Path(catalogue).resolve()}"


def init_catalogue(uri: str) -> bool:
    """Make the catalogue's tables at ``uri`` if it has none (as ``tiled catalog init
    --if-not-exists`` does, in this process: its child process took 13 s to start on a busy
    machine); True if it was made now. Call it outside an event loop."""
    from sqlalchemy.ext.asyncio import create_async_engine
    from tiled.alembic_utils import UninitializedDatabase, check_database, stamp_head
    from tiled.catalog.alembic_constants import ALEMBIC_DIR, ALEMBIC_INI_TEMPLATE_PATH
    from tiled.catalog.core import ALL_REVISIONS, REQUIRED_REVISION, initialize_database
    from tiled.utils import ensure_specified_sql_driver

    database = ensure_specified_sql_driver(uri)

    async def setup() -> bool:
        engine = create_async_engine(database)
        try:
            await check_database(engine, REQUIRED_REVISION, ALL_REVISIONS)
        except UninitializedDatabase:
            await initialize_database(engine)
            return True
        finally:
            await engine.dispose()
        return False

    try:
        made = asyncio.run(setup())
        if made:
            stamp_head(ALEMBIC_INI_TEMPLATE_PATH, ALEMBIC_DIR, database)
    except Exception as exc:  # the database's driver's own errors: unreachable, refused, ...
        raise CatalogueError(
            f"cannot open the catalogue {shown_uri(uri)}: {type(exc).__name__}: {exc}; check "
            "--catalog (a PostgreSQL server must be reachable, an SQLite file's folder writable)"
        ) from None
    return made


class CatalogueError(Exception):
    """The catalogue cannot be opened or made; the message says which and why (no password)."""


def shown_uri(uri: str) -> str:
    """``uri`` as it may be shown: its password, if any, as ``***``."""
    from sqlalchemy.engine import make_url

    try:
        return make_url(uri).render_as_string(hide_password=True)
    except Exception:  # not a URL SQLAlchemy reads: show nothing of it that could be secret
        return "(the --catalog given)"


def open_catalogue(uri: str, data_dir: Path) -> CatalogContainerAdapter:
    """The catalogue at ``uri`` (made by ``init_catalogue``), allowed to read the files under
    ``data_dir``."""
    return from_uri(uri, readable_storage=[str(data_dir)])


@dataclass
class IndexReport:
    """What ``index`` did: files added, replaced (changed), removed, left as they were, and
    those passed over with why."""

    added: list[str] = field(default_factory=list)
    replaced: list[str] = field(default_factory=list)
    removed: list[str] = field(default_factory=list)
    unchanged: int = 0
    skipped: list[tuple[str, str]] = field(default_factory=list)

    def summary(self) -> str:
        return (
            f"{len(self.added)} added, {len(self.replaced)} replaced, {len(self.removed)} "
            f"removed, {self.unchanged} unchanged, {len(self.skipped)} skipped"
        )


async def index(catalogue: CatalogContainerAdapter, data_dir: Path) -> IndexReport:
    """Bring ``catalogue`` up to date with the camd files under ``data_dir`` (module
    docstring); an unreadable or foreign file is skipped, not an error."""
    report = IndexReport()
    indexed = {
        meta["file"]: (segments, meta)
        async for segments, meta in _file_nodes(catalogue, ())
        if isinstance(meta.get("file"), str)
    }
    seen: set[str] = set()
    for path in camd_files(data_dir):
        relative = path.relative_to(data_dir).as_posix()
        old = indexed.get(relative)
        try:
            if old is not None and all(old[1].get(k) == v for k, v in file_stamp(path).items()):
                seen.add(relative)
                report.unchanged += 1
                continue
            described = await asyncio.to_thread(describe, path, data_dir)
        except NotCamdFile:
            continue  # someone else's HDF5 file: not the archive's business
        except OSError as exc:  # RecordingError too: not HDF5, damaged, gone since listed
            report.skipped.append((relative, str(exc)))
            continue  # and a node it had goes below: its file is no longer what it served
        seen.add(relative)
        if old is not None:
            await _delete(catalogue, old[0])
        try:
            await _add(catalogue, described)
        except Exception as exc:  # a key taken by another file or folder, a bad dataset
            report.skipped.append((relative, f"{type(exc).__name__}: {exc}"))
            continue
        (report.replaced if old is not None else report.added).append(relative)
    for relative, (segments, _) in sorted(indexed.items()):
        if relative not in seen:
            await _delete(catalogue, segments)
            report.removed.append(relative)
    return report


async def _file_nodes(
    node: CatalogContainerAdapter, segments: tuple[str, ...]
) -> AsyncIterator[tuple[tuple[str, ...], dict[str, Any]]]:
    """Every file node under ``node`` (its path and metadata), walking the folders."""
    offset = 0
    while True:
        page = await node.items_range(offset, _PAGE)
        for key, child in page:
            meta = dict(child.metadata())
            if "file" in meta:
                yield (*segments, key), meta
            elif child.structure_family == StructureFamily.container:
                async for found in _file_nodes(child, (*segments, key)):
                    yield found
        if len(page) < _PAGE:
            return
        offset += _PAGE


async def _child(
    node: CatalogContainerAdapter, segments: list[str]
) -> CatalogContainerAdapter | None:
    """The node at ``segments`` under ``node``, None if there is none."""
    try:
        return await node.lookup_adapter(segments)
    except NoEntry:
        return None


async def _delete(catalogue: CatalogContainerAdapter, segments: tuple[str, ...]) -> None:
    node = await _child(catalogue, list(segments))
    if node is not None:
        # external_only: the node's data are the camd file, which stays where it is.
        await node.delete(recursive=True, external_only=True)


async def _add(catalogue: CatalogContainerAdapter, described: ArchivedFile) -> None:
    """The file's node, and the folder nodes above it that are not there yet."""
    parent = catalogue
    *folders, key = described.segments
    for depth, folder in enumerate(folders):
        child = await _child(parent, [folder])
        if child is None:
            child = await parent.create_node(
                structure_family=StructureFamily.container,
                metadata={"folder": "/".join(folders[: depth + 1])},
                key=folder,
            )
        parent = child
    arrays = [(part, await asyncio.to_thread(_array_source, described.path, part))
              for part in described.arrays]  # fmt: skip
    node = await parent.create_node(
        structure_family=StructureFamily.container,
        metadata=described.metadata,
        key=key,
        specs=[Spec(SPECS[described.metadata["kind"]])],
    )
    for part, source in arrays:
        await node.create_node(
            structure_family=StructureFamily.array,
            metadata={"dataset": part.dataset},
            key=part.key,
            data_sources=[source],
        )


def _array_source(path: Path, part: ArrayPart) -> DataSource[Any]:
    """The data source of one array node: Tiled's HDF5 adapter over ``part.dataset``, cut to
    the part on disk; its structure (shape, dtype, chunks) made by that adapter, so that the
    blocks a client asks for are the adapter's chunks."""
    uri = ensure_uri(str(path))
    parameters: dict[str, Any] = {"dataset": part.dataset, "swmr": True}
    adapter = HDF5ArrayAdapter.from_uris(uri, dataset=part.dataset, swmr=True)
    if adapter.structure().shape[0] != part.length:
        parameters["slice"] = f":{part.length}"
        adapter = HDF5ArrayAdapter.from_uris(
            uri, dataset=part.dataset, swmr=True, slice=parameters["slice"]
        )
    return DataSource(
        structure_family=StructureFamily.array,
        structure=adapter.structure(),
        mimetype=HDF5_MIMETYPE,
        parameters=parameters,
        assets=[
            Asset(
                data_uri=uri,
                is_directory=False,
                parameter="data_uris",
                num=0,
                size=path.stat().st_size,
            )
        ],
        management=Management.external,
    )
