"""The camera as ophyd-async detectors: staring acquisitions and push-broom TDI scans.

Both are ophyd-async ``StandardDetector`` s assembled from its three kinds of logic:

- trigger logic (``CamdTriggerLogic``): how many collections the next acquisition takes
  (internal triggering only: the camera times its own frames; livetime and deadtime are the
  registers', docs/sensors.md);
- acquire logic: starts the acquisition through the API and follows it to its end
  (``StareAcquireLogic``: POST /api/v1/stream/acquire recording a new file, following GET
  /api/v1/stream's ``frames_flushed``; ``ScanAcquireLogic``: POST /api/v1/scan/start, following
  GET /api/v1/scan's ``lines_flushed``), and stops it when unstaged early;
- data logic (``CamdDataLogic``): a ``camd.bluesky.files.CamdFiles`` per prepare, the
  StreamResource/StreamDatum documents of the files the acquisitions write.

A stare takes one file per trigger (``count``, a stage ``scan``: one event per file, of
``collections_per_event`` frames); a kickoff takes one acquisition of every event prepared
(a scan's lines: ``camd.bluesky.plans.push_broom``). Staging takes the connection's control
lease and unstaging gives it back (``camd.bluesky.connection``). When an acquisition fails, the
trigger or ``complete`` raises the daemon's error at once (its message says why and what the
file keeps), rather than waiting for counts that will not come.
"""

from __future__ import annotations

import asyncio
import contextlib
import datetime as dt
import uuid
from abc import abstractmethod
from collections.abc import AsyncIterator, Mapping, Sequence
from pathlib import PurePosixPath
from typing import Any

import httpx
from ophyd_async.core import (
    AsyncStatus,
    DetectorAcquireLogic,
    DetectorDataLogic,
    DetectorTriggerLogic,
    SignalR,
    StandardDetector,
    WatchableAsyncStatus,
    WatcherUpdate,
    soft_signal_rw,
)

from camd.bluesky.connection import CamdConnection, holder_name
from camd.bluesky.files import CamdFiles, FileSegment
from camd.client.connection import CamdError
from camd.client_requests import ScanRequestOptions, StreamAcquireOptions

POLL_S = 0.2  # how often a running acquisition's counters are read
RUNNING_SCAN = frozenset({"starting", "running"})
LINE_DTYPES = {"sum": "<u4", "mean": "<f4"}  # a TDI line's samples by the scan's mode
FRAME_DTYPE = "<u2"


class CamdTriggerLogic(DetectorTriggerLogic):
    """Internal triggering: the number of collections (frames, lines) the next acquisition
    takes. ``signals`` are the detector's settings, read into its configuration."""

    def __init__(self, signals: Sequence[SignalR[Any]] = ()) -> None:
        self.collections = 1
        self._signals = set(signals)

    def config_sigs(self) -> set[SignalR[Any]]:
        return self._signals

    async def prepare_internal(self, num: int, livetime: float, deadtime: float) -> None:
        if livetime or deadtime:
            raise ValueError(
                f"camd's exposure and frame period are its sensor's registers, not a trigger's "
                f"(livetime={livetime:g} s, deadtime={deadtime:g} s asked): prepare with "
                "TriggerInfo(livetime=0, deadtime=0) and set EXPOSURE with `camctl reg write` "
                "or POST /api/v1/registers (docs/sensors.md)"
            )
        self.collections = num


class CamdDataLogic(DetectorDataLogic):
    """The files the acquisitions write, as stream documents: dataset ``dataset`` of each,
    one collection of ``shape`` (None: a dimension the first acquisition says) and ``dtype``."""

    def __init__(self, dataset: str, shape: tuple[int | None, ...], dtype: str) -> None:
        self.dataset = dataset
        self.shape = shape
        self.dtype = dtype
        self.files: CamdFiles | None = None

    async def prepare_unbounded(self, datakey_name: str) -> CamdFiles:
        self.files = CamdFiles(datakey_name, self.dataset, shape=self.shape, dtype=self.dtype)
        return self.files

    def get_hinted_fields(self, datakey_name: str) -> Sequence[str]:
        return [datakey_name]


class CamdAcquireLogic(DetectorAcquireLogic):
    """An acquisition through the API, followed to its end by a task (``follower``) that
    updates the files' counts and ends with the daemon's error if the acquisition fails."""

    def __init__(
        self,
        connection: CamdConnection,
        trigger: CamdTriggerLogic,
        data: CamdDataLogic,
        *,
        options: Mapping[str, Any],
        settings: dict[str, SignalR[Any]],
        prefix: str,
        directory: str,
    ) -> None:
        self.connection = connection
        self.trigger = trigger
        self.data = data
        self.options = options  # the request's keys but the settings' and the file's
        self.settings = settings
        self.prefix = prefix
        self.directory = directory
        self.follower: asyncio.Task[None] | None = None

    def file_name(self) -> str:
        """A new file's name for the daemon: ``directory/prefix-UTC time-random.h5``
        (relative: in the daemon's data directory, docs/api.md "Files")."""
        stamp = dt.datetime.now(dt.UTC).strftime("%Y%m%dT%H%M%S")
        name = f"{self.prefix}-{stamp}-{uuid.uuid4().hex[:8]}.h5"
        return str(PurePosixPath(self.directory) / name) if self.directory else name

    async def settings_now(self) -> dict[str, Any]:
        """The request keys the detector's setting signals hold now."""
        values = await asyncio.gather(*(signal.get_value() for signal in self.settings.values()))
        return dict(zip(self.settings, values, strict=True))

    def failure(self) -> BaseException | None:
        """The error the last acquisition ended with, once it has ended in one."""
        task = self.follower
        if task is None or not task.done() or task.cancelled():
            return None
        return task.exception()

    async def start_acquiring(self) -> None:
        files = self.data.files
        if files is None:
            raise RuntimeError("the detector was not prepared (stage, then trigger or prepare)")
        segment = files.new_segment(self.file_name())
        self.follower = await self.start(files, segment, self.trigger.collections)

    @abstractmethod
    async def start(
        self, files: CamdFiles, segment: FileSegment, collections: int
    ) -> asyncio.Task[None]:
        """Start the acquisition of ``collections`` into ``segment``'s file; the task that
        follows it."""

    @abstractmethod
    async def stop_request(self) -> None:
        """Ask the daemon to stop the running acquisition."""

    async def wait_for_idle(self) -> None:
        if self.follower is not None:
            await self.follower

    async def ensure_stopped(self) -> None:
        task = self.follower
        if task is None or task.done():
            return
        # Unstaged while it runs (an aborted plan): stop it, keep what the file holds.
        await self.stop_request()
        with contextlib.suppress(CamdError):  # it ended stopped: what was asked
            await task

    def loop(self) -> asyncio.AbstractEventLoop:
        return asyncio.get_running_loop()


class StareAcquireLogic(CamdAcquireLogic):
    """A stare: POST /api/v1/stream/acquire of N frames recorded to a new file, its
    ``frames_flushed`` followed through GET /api/v1/stream while it runs."""

    async def start(
        self, files: CamdFiles, segment: FileSegment, collections: int
    ) -> asyncio.Task[None]:
        settings = await self.settings_now()
        return self.loop().create_task(self._stare(files, segment, collections, settings))

    async def stop_request(self) -> None:
        await self.connection.request("POST", "/stream/stop")

    async def _stare(
        self, files: CamdFiles, segment: FileSegment, frames: int, settings: dict[str, Any]
    ) -> None:
        body = {**self.options, **settings, "frames": frames, "record": segment.name}
        # The daemon bounds the stare (by timeout_s, or twice its expected time): only
        # connecting is bounded here.
        asked = self.options.get("timeout_s")
        timeout = httpx.Timeout(
            self.connection.timeout_s, read=None if asked is None else asked + 30
        )
        acquire = self.loop().create_task(
            self.connection.request("POST", "/stream/acquire", body, timeout=timeout)
        )
        try:
            while not acquire.done():
                await asyncio.wait([acquire], timeout=POLL_S)
                if acquire.done():
                    break
                doc = await self.connection.get("/stream")
                if _same_file(doc.get("recording"), segment.name):
                    _update_stare(files, segment, doc)
                else:  # not started yet: the daemon is setting it up
                    files.touch()
            doc = acquire.result()
        finally:
            acquire.cancel()
        _update_stare(files, segment, doc)
        if segment.written < frames:
            stats = doc["stats"]
            raise CamdError(
                f"the stare recorded {segment.written} of {frames} frames in {segment.path} "
                f"(lost {stats['lost']}, corrupt {stats['corrupt']}, short {stats['short']}, "
                f"overruns {stats['overruns']}); see `camctl stream` and `camctl events`",
                "incomplete",
            )


class ScanAcquireLogic(CamdAcquireLogic):
    """A push-broom scan: POST /api/v1/scan/start writing a new file, its ``lines_flushed``
    followed through GET /api/v1/scan until the scan ends; it must end ``done``."""

    async def start(
        self, files: CamdFiles, segment: FileSegment, collections: int
    ) -> asyncio.Task[None]:
        settings = await self.settings_now()
        stages = int(settings["stages"])
        if collections < stages:
            raise ValueError(
                f"a scan at M = {stages} stages writes M - 1 = {stages - 1} incomplete lines "
                f"before its first complete one, so it holds at least {stages} lines; "
                f"{collections} were prepared: prepare lines + M - 1 events "
                "(camd.bluesky.plans.push_broom does)"
            )
        body: dict[str, Any] = {
            **self.options,
            **settings,
            "lines": collections - (stages - 1),
            "out": segment.name,
        }
        doc = await self.connection.request("POST", "/scan/start", body)
        _update_scan(files, segment, doc)
        return self.loop().create_task(self._follow(files, segment, collections))

    async def stop_request(self) -> None:
        await self.connection.request("POST", "/scan/stop")

    async def _follow(self, files: CamdFiles, segment: FileSegment, lines: int) -> None:
        while True:
            await asyncio.sleep(POLL_S)
            doc = await self.connection.get("/scan")
            if doc["file"] != segment.path:
                raise CamdError(
                    f"the daemon's scan is now {doc['file']}, not {segment.path}: another "
                    "client started one; see `camctl scan --status` and `camctl events`",
                    "scan_taken",
                )
            _update_scan(files, segment, doc)
            if doc["state"] not in RUNNING_SCAN:
                break
        if doc["state"] != "done":
            raise CamdError(
                f"the scan {segment.path} ended {doc['state']}, not done: {doc['error']} "
                f"({doc['lines_flushed']} lines on disk)",
                f"scan_{doc['state']}",
            )
        if segment.written < lines:
            raise CamdError(
                f"the scan {segment.path} ended done with {segment.written} of {lines} lines "
                f"on disk ({doc['lost_frames']} frames lost, {doc['not_sent_frames']} not sent)",
                "incomplete",
            )


def _same_file(recording: str | None, name: str) -> bool:
    # The daemon answers the resolved path of the name it was sent.
    return recording is not None and PurePosixPath(recording).name == PurePosixPath(name).name


def _update_stare(files: CamdFiles, segment: FileSegment, doc: dict[str, Any]) -> None:
    files.update(
        segment,
        path=doc["recording"],
        written=doc["frames_flushed"],
        shape=(doc["rows"], doc["cols"]),
        dtype=FRAME_DTYPE,
    )


def _update_scan(files: CamdFiles, segment: FileSegment, doc: dict[str, Any]) -> None:
    files.update(
        segment,
        path=doc["file"],
        written=doc["lines_flushed"],
        shape=(doc["width"],),
        dtype=LINE_DTYPES[doc["mode"]],
    )


class CamdDetector(StandardDetector):
    """What both of camd's detectors share: their logics, the connection, the control lease
    held while staged, and triggers and completions that end with the daemon's error as soon
    as the acquisition fails. ``settings`` are the signals sent as request keys (and read into
    the configuration), ``dataset`` the files' dataset, one collection of ``shape`` and
    ``dtype``; ``acquire`` the kind of acquisition, with its request's other ``options``."""

    def __init__(
        self,
        connection: CamdConnection,
        name: str,
        *,
        settings: dict[str, SignalR[Any]],
        dataset: str,
        shape: tuple[int | None, ...],
        dtype: str,
        acquire: type[StareAcquireLogic] | type[ScanAcquireLogic],
        options: Mapping[str, Any],
        prefix: str,
        directory: str,
    ) -> None:
        self.connection = connection
        trigger = CamdTriggerLogic(list(settings.values()))
        data = CamdDataLogic(dataset, shape, dtype)
        self._acquisition = acquire(
            connection,
            trigger,
            data,
            options=options,
            settings=settings,
            prefix=name or prefix,
            directory=directory,
        )
        self.add_detector_logics(trigger, self._acquisition, data)
        super().__init__(name=name)

    @AsyncStatus.wrap
    async def stage(self) -> None:
        """Take control (the connection's lease), then make the detector ready."""
        await self.connection.staged(holder_name(self), super().stage)

    @AsyncStatus.wrap
    async def unstage(self) -> None:
        """Stop an acquisition still running, then give control back."""
        await self.connection.unstaged(holder_name(self), super().unstage)

    @WatchableAsyncStatus.wrap
    async def trigger(self) -> AsyncIterator[WatcherUpdate[int]]:
        async for update in self._until_failed(super().trigger()):
            yield update

    @WatchableAsyncStatus.wrap
    async def complete(self) -> AsyncIterator[WatcherUpdate[int]]:
        async for update in self._until_failed(super().complete()):
            yield update

    async def _until_failed(
        self, status: WatchableAsyncStatus[int]
    ) -> AsyncIterator[WatcherUpdate[int]]:
        """``status``'s progress, until it is done or the acquisition has failed (then its
        error, at once: the counts ``status`` waits for will not come)."""
        updates: list[WatcherUpdate[int]] = []

        def watcher(
            current: int | None = None,
            initial: int | None = None,
            target: int | None = None,
            name: str | None = None,
            unit: str | None = None,
            precision: int | None = None,
            fraction: float | None = None,
            time_elapsed: float | None = None,
            time_remaining: float | None = None,
        ) -> None:
            if current is not None and initial is not None and target is not None:
                updates.append(
                    WatcherUpdate(
                        current,
                        initial,
                        target,
                        name,
                        unit,
                        precision,
                        fraction,
                        time_elapsed,
                        time_remaining,
                    )
                )

        status.watch(watcher)
        while not status.done:
            await asyncio.wait([status.task], timeout=POLL_S)
            while updates:
                yield updates.pop(0)
            failure = self._acquisition.failure()
            if failure is not None and not status.done:
                status.task.cancel()
                raise failure
        await status


class CamdStareDetector(CamdDetector):
    """Staring acquisitions: each trigger takes ``collections_per_event`` frames (1 unless
    prepared otherwise) into a new recording, the datakey ``<name>`` the recording's
    ``/frames`` (uint16, rows x cols as the stream delivers them).

    ``options`` are the stare's request keys (``mode``, ``stages``, ``binning``, ``timeout_s``;
    ``camd.client_requests.StreamAcquireOptions``); ``directory`` where the recordings go on the
    daemon's host (relative: in its data directory's recordings; default there).
    """

    def __init__(
        self,
        connection: CamdConnection,
        name: str = "",
        *,
        options: StreamAcquireOptions | None = None,
        directory: str = "",
    ) -> None:
        options = StreamAcquireOptions(**(options or {}))
        if "record" in options:
            raise ValueError("the detector names each recording itself; give `directory`")
        self.mode = soft_signal_rw(str, options.get("mode") or "area")
        self.binning = soft_signal_rw(str, options.get("binning", "off"))
        super().__init__(
            connection,
            name,
            settings={"mode": self.mode, "binning": self.binning},
            dataset="/frames",
            shape=(None, None),
            dtype=FRAME_DTYPE,
            acquire=StareAcquireLogic,
            options=options,
            prefix="stare",
            directory=directory,
        )


class CamdScanDetector(CamdDetector):
    """Push-broom TDI scans: a kickoff starts a scan that writes every prepared event as one
    TDI line (the first M - 1 incomplete, docs/scan.md), the datakey ``<name>`` the scan file's
    ``/lines`` (uint32 sums or float32 means, one row of ``width`` samples per line).

    ``stages`` is the signal of M (default ``stages``); ``options`` the scan's other request
    keys (``speed_m_s`` or ``line_period_s``, ``drive_stage``, ``mode``, ``scene``, ...;
    ``camd.client_requests.ScanRequestOptions``); ``directory`` where the files go on the
    daemon's host (relative: in its data directory's scans; default there).
    """

    def __init__(
        self,
        connection: CamdConnection,
        name: str = "",
        *,
        stages: int = 8,
        options: ScanRequestOptions | None = None,
        directory: str = "",
    ) -> None:
        options = ScanRequestOptions(**(options or {}))
        if "out" in options:
            raise ValueError("the detector names each scan file itself; give `directory`")
        mode = options.get("mode", "sum")
        self.stages = soft_signal_rw(int, stages)
        self.tdi_mode = soft_signal_rw(str, mode)
        super().__init__(
            connection,
            name,
            settings={"stages": self.stages, "mode": self.tdi_mode},
            dataset="/lines",
            shape=(None,),
            dtype=LINE_DTYPES[mode],
            acquire=ScanAcquireLogic,
            options=options,
            prefix="scan",
            directory=directory,
        )
