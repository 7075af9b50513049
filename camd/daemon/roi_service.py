"""The live view's ROIs in the daemon: define, list, delete, read (docs/live-view.md, docs/api.md).

``RoiService`` is handed the ``RoiMonitor`` that every stream feeds (a consumer of the stream
service, measuring every frame) and the stream service (the geometry the ROIs are checked
against: the current or last stream's frame; before any stream, only the frame header's
largest). It serves ``GET``, ``POST`` and ``DELETE /api/v1/live/roi`` and ``GET
/api/v1/live/roi/stats``. A refused ROI changes nothing.
"""

from __future__ import annotations

import threading

from camd.analysis.roi import Roi
from camd.daemon.errors import BadRequest, NotFound
from camd.daemon.models import (
    RoiDefinition,
    RoiFrameStats,
    RoiHistorySeries,
    RoiLatest,
    RoiList,
    RoiRequest,
    RoiStatsResponse,
)
from camd.daemon.stream_service import StreamService
from camd.pipeline.roi import RoiMonitor

FRAME_SIDE_MAX = 0xFFFF  # the frame header's rows and cols are 16-bit: no frame is larger


class RoiService:
    """The live view's ROIs for one device session (module docstring)."""

    def __init__(self, monitor: RoiMonitor, stream: StreamService) -> None:
        self.monitor = monitor
        self.stream = stream
        self._lock = threading.Lock()  # one change of the ROI set at a time

    def _geometry(self) -> tuple[int | None, int | None]:
        info = self.stream.status_info()
        rows, cols = int(info["rows"]), int(info["cols"])
        return (rows, cols) if rows and cols else (None, None)

    def listing(self) -> RoiList:
        """The ROIs and the frame geometry they are checked against (null before a stream)."""
        rows, cols = self._geometry()
        return RoiList(
            rois=[RoiDefinition(**r.as_dict()) for r in self.monitor.rois],  # type: ignore[arg-type]
            rows=rows,
            cols=cols,
        )

    def add(self, body: RoiRequest) -> RoiList:
        """Measure ``body``'s ROI from the next frame on (an ROI of its name is replaced);
        BadRequest saying what to change if it does not fit the frame."""
        roi = Roi(body.name, body.x, body.y, body.width, body.height)
        with self._lock:
            rois = [r for r in self.monitor.rois if r.name != roi.name]
            replaced = len(rois) != len(self.monitor.rois)
            at = [r.name for r in self.monitor.rois].index(roi.name) if replaced else len(rois)
            rois.insert(at, roi)
            self._set(rois)
        return self.listing()

    def delete(self, name: str) -> RoiList:
        """Stop measuring ROI ``name``; NotFound listing the ROIs there are."""
        with self._lock:
            rois = [r for r in self.monitor.rois if r.name != name]
            if len(rois) == len(self.monitor.rois):
                names = ", ".join(r.name for r in self.monitor.rois) or "none"
                raise NotFound(f"no ROI named {name!r}; the ROIs are: {names}")
            self._set(rois)
        return self.listing()

    def _set(self, rois: list[Roi]) -> None:
        rows, cols = self._geometry()
        try:
            self.monitor.set_rois(rois, rows or FRAME_SIDE_MAX, cols or FRAME_SIDE_MAX)
        except ValueError as exc:
            raise BadRequest(str(exc)) from None

    def stats(self, history: int) -> RoiStatsResponse:
        """The newest frame's statistics of every ROI and, per ROI, the newest ``history``
        frames' (0: none)."""
        h = self.monitor.history(max(1, history))  # the newest frame at least: ``latest``
        latest = h.latest()
        return RoiStatsResponse(
            rois_seq=h.rois_seq,
            measured=h.measured,
            unfit=h.unfit,
            latest=None
            if latest is None
            else RoiLatest(
                counter=latest["counter"],
                timestamp_ns=latest["timestamp_ns"],
                rois={k: RoiFrameStats(**v) for k, v in latest["rois"].items()},
            ),
            history={r.name: RoiHistorySeries(**h.roi(r.name)) for r in h.rois}
            if history > 0
            else {},
        )
