"""camd's HDF5 files as bluesky sees them: StreamResource and StreamDatum documents.

A detector's acquisitions since it was prepared write one file each (a stare's recording, a
scan's file): a ``FileSegment`` per file, in order. ``CamdFiles`` is ophyd-async's
``StreamableDataProvider`` over them: its ``collections_written_signal`` is the sum of what the
files hold on disk (each file's frames-flushed or lines-flushed counter, as the daemon reports
it while the acquisition runs and the file keeps it), and ``make_stream_docs`` emits, for each
file that holds new data, its StreamResource (once) and a StreamDatum whose ``indices`` count
in that file's own events (``indices`` i..j is the dataset's rows ``i * n .. j * n`` for ``n``
collections per event).

The resources point at the datasets' root paths (``/frames``, ``/lines``), which every camd
format keeps (as links once the datasets live inside the NeXus entry). ``read_stream_datum``
reads one datum's data back; it is the one place in ``camd.bluesky`` that opens camd's files,
and it imports ``hdf5plugin`` first so that compressed files read too.
"""

from __future__ import annotations

from collections.abc import AsyncIterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any
from urllib.parse import unquote, urlparse

import numpy as np
import numpy.typing as npt
from bluesky.protocols import StreamAsset
from event_model import ComposeStreamResource, ComposeStreamResourceBundle, DataKey, StreamRange
from ophyd_async.core import StreamableDataProvider, soft_signal_r_and_setter

MIMETYPE = "application/x-hdf5"


@dataclass
class FileSegment:
    """One acquisition's file: ``name`` as sent to the daemon, ``path`` as the daemon resolved
    it (None until it answers), ``written`` the collections (frames or lines) on disk."""

    name: str
    path: str | None = None
    written: int = 0
    bundle: ComposeStreamResourceBundle | None = field(default=None, repr=False)
    emitted: int = 0  # events whose StreamDatum has been emitted


class CamdFiles(StreamableDataProvider):
    """The files of one detector's acquisitions, as a StreamableDataProvider: the datakey
    ``data_key`` is dataset ``dataset`` (``/frames`` or ``/lines``) of each file.

    ``shape`` and ``dtype`` describe one collection before the first file says them (None: a
    dimension not known yet); each acquisition's answer then gives them.
    """

    def __init__(
        self,
        data_key: str,
        dataset: str,
        *,
        shape: tuple[int | None, ...],
        dtype: str,
    ) -> None:
        self.data_key = data_key
        self.dataset = dataset
        self.shape = shape
        self.dtype = dtype
        self.segments: list[FileSegment] = []
        signal, self._set_written = soft_signal_r_and_setter(int, 0)
        self.collections_written_signal = signal

    def new_segment(self, name: str) -> FileSegment:
        """The file of the acquisition about to start (sent to the daemon as ``name``)."""
        segment = FileSegment(name)
        self.segments.append(segment)
        return segment

    def update(
        self,
        segment: FileSegment,
        *,
        path: str,
        written: int,
        shape: tuple[int, ...] | None = None,
        dtype: str | None = None,
    ) -> None:
        """What the daemon says of ``segment``'s file: where it is, how much it holds on disk,
        and one collection's shape and dtype. Sets the signal the detector waits on (also when
        nothing changed: each poll is news that the acquisition is alive)."""
        segment.path = path
        segment.written = max(segment.written, written)
        if shape is not None:
            self.shape = shape
        if dtype is not None:
            self.dtype = dtype
        self.touch()

    def touch(self) -> None:
        """Set the signal the detector waits on to what it holds: news that the acquisition is
        alive while it has nothing on disk yet (ophyd-async times out a wait without news)."""
        self._set_written(sum(s.written for s in self.segments))

    async def make_datakeys(self, collections_per_event: int) -> dict[str, DataKey]:
        uri = file_uri(self.segments[-1].path) if self.segments and self.segments[-1].path else ""
        return {
            self.data_key: DataKey(
                source=uri or f"camd:{self.dataset}",
                shape=[collections_per_event, *self.shape],
                dtype="array",
                dtype_numpy=self.dtype,
                external="STREAM:",
            )
        }

    async def make_stream_docs(
        self, collections_written: int, collections_per_event: int
    ) -> AsyncIterator[StreamAsset]:
        events_wanted = collections_written // collections_per_event
        events_before = 0
        for segment in self.segments:
            in_file = segment.written // collections_per_event
            ready = min(in_file, max(0, events_wanted - events_before))
            events_before += in_file
            if ready <= segment.emitted or segment.path is None:
                continue
            if segment.bundle is None:
                segment.bundle = self._resource(segment, collections_per_event)
                yield "stream_resource", segment.bundle.stream_resource_doc
            indices = StreamRange(start=segment.emitted, stop=ready)
            segment.emitted = ready
            yield "stream_datum", segment.bundle.compose_stream_datum(indices)

    def _resource(self, segment: FileSegment, per_event: int) -> ComposeStreamResourceBundle:
        # No chunk_shape: the chunking is the file's (camd.store, and a compressed file's
        # differs); a reader asks the dataset.
        return ComposeStreamResource()(
            mimetype=MIMETYPE,
            uri=file_uri(str(segment.path)),
            data_key=self.data_key,
            parameters={
                "dataset": self.dataset,
                "collections_per_event": per_event,
                "swmr": True,
            },
        )


def file_uri(path: str) -> str:
    """``file://localhost/...`` of an absolute path on the daemon's host."""
    return Path(path).as_uri().replace("file:///", "file://localhost/", 1)


def uri_path(uri: str) -> Path:
    """The path of a ``file://`` URI (``file://localhost/x`` or ``file:///x``)."""
    parsed = urlparse(uri)
    if parsed.scheme != "file" or parsed.netloc not in ("", "localhost"):
        raise ValueError(f"{uri!r} is not a file:// URI on this host")
    return Path(unquote(parsed.path))


def read_stream_datum(resource: Mapping[str, Any], datum: Mapping[str, Any]) -> npt.NDArray[Any]:
    """The data a StreamDatum (``datum``) of a StreamResource (``resource``) from these
    devices points at: the dataset's rows ``indices.start * n`` to ``indices.stop * n`` (``n``
    collections per event), shaped (events, n, *one collection). The file is read with SWMR, so
    also while it is being written."""
    import hdf5plugin  # noqa: F401  # registers the compression filters camd's files may use

    from camd.store.recording_reading import open_for_reading

    if datum["stream_resource"] != resource["uid"]:
        raise ValueError(
            f"stream datum {datum['uid']} belongs to resource {datum['stream_resource']}, "
            f"not {resource['uid']}"
        )
    params = resource["parameters"]
    per_event = int(params.get("collections_per_event", 1))
    start, stop = int(datum["indices"]["start"]), int(datum["indices"]["stop"])
    with open_for_reading(uri_path(resource["uri"])) as f:
        data = np.asarray(f[params["dataset"]][start * per_event : stop * per_event])
    return data.reshape(stop - start, per_event, *data.shape[1:])
