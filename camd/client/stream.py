"""The frame stream over USB (start, acquire, stop, counters, headers) and the live view's parts
that a script reads: the background and the lines of a TDI scan (docs/stream.md,
docs/live-view.md)."""

from __future__ import annotations

import json
from typing import TYPE_CHECKING, Any, Unpack, cast
from urllib.parse import quote

import httpx

from camd.client.connection import API, UNSET, HttpClient, Unset, given
from camd.client_requests import StreamAcquireOptions, StreamStartRequestOptions
from camd.client_types import (
    BackgroundStatus,
    FocusResponse,
    ImageMotionResponse,
    LivePixel,
    RoiList,
    RoiStatsResponse,
    SnapshotSaved,
    StreamHeadersResponse,
    StreamResponse,
)

if TYPE_CHECKING:
    import numpy as np
    import numpy.typing as npt


class StreamClient(HttpClient):
    """The client of the stream routes and of the live view's background, ROIs and lines."""

    def stream(self) -> StreamResponse:
        """The current or last stream and the host's ingest counters."""
        return cast(StreamResponse, self._json("GET", f"{API}/stream"))

    def start_stream(
        self, frames: int | Unset = UNSET, **options: Unpack[StreamStartRequestOptions]
    ) -> StreamResponse:
        """Start streaming and return at once (0 frames, the default: until ``stop_stream``)."""
        body = {**given(frames=frames), **options}
        return cast(StreamResponse, self._json("POST", f"{API}/stream/start", json=body))

    def acquire(self, frames: int, **options: Unpack[StreamAcquireOptions]) -> StreamResponse:
        """Take ``frames`` frames (recording them to the new HDF5 file ``record`` on the daemon's
        host, if given: relative = in its data directory's recordings, docs/api.md "Files") and
        return the counters when the stream has ended."""
        body = {"frames": frames, **options}
        # The daemon bounds the acquisition (by timeout_s, or twice the expected time); the
        # answer may take that long, so only connecting is bounded by the client's timeout.
        timeout_s = options.get("timeout_s")
        read_s = None if timeout_s is None else timeout_s + 30.0
        timeout = httpx.Timeout(self.timeout_s, read=read_s)
        return cast(
            StreamResponse, self._json("POST", f"{API}/stream/acquire", json=body, timeout=timeout)
        )

    def stop_stream(self) -> StreamResponse:
        """Stop the stream (harmless when not streaming)."""
        return cast(StreamResponse, self._json("POST", f"{API}/stream/stop"))

    def stream_headers(self) -> StreamHeadersResponse:
        """The headers of the first frames of the current or last stream, with the payload
        CRC the host computed for each (frames the payload CRC rejected included)."""
        return cast(StreamHeadersResponse, self._json("GET", f"{API}/stream/headers"))

    # -- the live view's background and lines ---------------------------------------------------

    def capture_background(self, frames: int | Unset = UNSET) -> BackgroundStatus:
        """Start averaging the next ``frames`` (1..1000; not given: the daemon's default) frames
        of the running stream into the live view's background and return at once;
        ``background()`` shows when it is ready."""
        return cast(
            BackgroundStatus,
            self._json("POST", f"{API}/live/background", json=given(frames=frames)),
        )

    def background(self) -> BackgroundStatus:
        """The background's state: none, capturing, ready or failed."""
        return cast(BackgroundStatus, self._json("GET", f"{API}/live/background"))

    def background_frame(self) -> tuple[dict[str, Any], npt.NDArray[np.float32]]:
        """The ready background: its description (seq, frames, rows, cols, mode, stages,
        first_counter, last_counter, captured_t_s, mean_dn, std_dn, dtype) and its pixels,
        float32 DN, shape (rows, cols)."""
        import numpy as np  # only here: the rest of the client needs no numpy

        response = self._request("GET", f"{API}/live/background/frame")
        meta = json.loads(response.headers["X-Camd-Background"])
        pixels = np.frombuffer(response.content, dtype="<f4").reshape(meta["rows"], meta["cols"])
        return meta, pixels.astype(np.float32)

    def clear_background(self) -> BackgroundStatus:
        """Drop the background (and stop a capture)."""
        return cast(BackgroundStatus, self._json("DELETE", f"{API}/live/background"))

    # -- the live view's ROIs ---------------------------------------------------------------------

    def rois(self) -> RoiList:
        """The ROIs measured on every frame, and the frame geometry they were checked against."""
        return cast(RoiList, self._json("GET", f"{API}/live/roi"))

    def add_roi(self, name: str, x: int, y: int, width: int, height: int) -> RoiList:
        """Measure the rectangle ``name`` (pixels from the frame's top left; an ROI of that
        name is replaced) on every frame from the next one on."""
        body = {"name": name, "x": x, "y": y, "width": width, "height": height}
        return cast(RoiList, self._json("POST", f"{API}/live/roi", json=body))

    def delete_roi(self, name: str) -> RoiList:
        """Stop measuring ROI ``name``."""
        return cast(RoiList, self._json("DELETE", f"{API}/live/roi/{quote(name, safe='')}"))

    def roi_stats(self, history: int = 0) -> RoiStatsResponse:
        """Every ROI's statistics on the newest frame and, per ROI, the newest ``history``
        frames' (0..4096)."""
        return cast(
            RoiStatsResponse,
            self._json("GET", f"{API}/live/roi/stats", params={"history": history}),
        )

    # -- the image's motion from the frames ---------------------------------------------------

    def image_motion(self, history: int = 0) -> ImageMotionResponse:
        """The image's motion measured from blocks of the streams' TDI windows (dV/V, M dV/V,
        drift angle; docs/motion.md): the newest block and the newest ``history`` (0..1024)."""
        return cast(
            ImageMotionResponse,
            self._json("GET", f"{API}/live/motion", params={"history": history}),
        )

    # -- the live view's focus aid -----------------------------------------------------------------

    def focus(self, history: int = 0) -> FocusResponse:
        """The focus aid's sharpness figures (the frame's and each ROI's), the best since the
        last reset, and the newest ``history`` figures (0..1200). Asking keeps the daemon
        measuring for ``watch_s`` more seconds."""
        return cast(
            FocusResponse, self._json("GET", f"{API}/live/focus", params={"history": history})
        )

    def reset_focus_best(self) -> FocusResponse:
        """Forget the best focus figures (a new focusing starts)."""
        return cast(FocusResponse, self._json("DELETE", f"{API}/live/focus/best"))

    def snapshot_tiff(self, seq: int | None = None) -> tuple[dict[str, Any], bytes]:
        """A snapshot of the live view's frame (``seq``; None: the newest): its description
        (as ``X-Camd-Frame``) and the TIFF file's bytes (raw DN; its ImageDescription the
        JSON of the frame, the camera's settings and the ROIs' statistics on it). CamdError
        ``no_frame`` before any, ``frame_gone`` if ``seq`` is no longer the live view's."""
        params = {} if seq is None else {"seq": seq}
        response = self._request("GET", f"{API}/live/snapshot/frame.tiff", params=params)
        return json.loads(response.headers["X-Camd-Frame"]), response.content

    def snapshot_png(
        self,
        seq: int,
        *,
        lo: float | None = None,
        hi: float | None = None,
        colormap: str = "gray",
    ) -> bytes:
        """The live frame ``seq`` as the page displays it, PNG bytes: DN ``lo``..``hi`` (None:
        the page's default contrast, percentiles 0.1 .. 99.9 %) onto ``colormap``."""
        params: dict[str, Any] = {"seq": seq, "colormap": colormap}
        if lo is not None and hi is not None:
            params.update(lo=lo, hi=hi)
        return self._request("GET", f"{API}/live/snapshot/display.png", params=params).content

    def live_pixel(self, row: int, col: int, seq: int | None = None) -> LivePixel:
        """One pixel's raw DN in the live frame ``seq`` (None: the newest; the live view holds
        its newest 40, at most 64 MiB): what a binned viewer reads under its cursor."""
        params: dict[str, int] = {"row": row, "col": col}
        if seq is not None:
            params["seq"] = seq
        return cast(LivePixel, self._json("GET", f"{API}/live/pixel", params=params))

    def save_snapshot(self, seq: int | None = None) -> SnapshotSaved:
        """Have the daemon save the snapshot of the live frame ``seq`` (None: the newest) in
        its data directory's ``snapshots`` folder (the TIFF, and the ROI statistics' CSV);
        the paths written, on the daemon's computer. Needs control."""
        return cast(SnapshotSaved, self._json("POST", f"{API}/live/snapshot", json={"seq": seq}))

    def live_lines(
        self, after: int = -1, *, max_lines: int = 512, timeout_s: float = 0.0
    ) -> tuple[dict[str, Any], npt.NDArray[np.float32]]:
        """The live view's lines of the running (or last) TDI scan with index > ``after``:
        their description (scan, scan_seq, first_index, n, cols, index, complete, stages_used,
        skipped, lines_done, lines_planned, state, dtype) and the lines, float32, shape
        (n, cols). With none newer the daemon waits up to ``timeout_s`` (0..5) for one, then
        answers n = 0. CamdError ``no_scan`` before the daemon's first scan."""
        import numpy as np  # only here: the rest of the client needs no numpy

        params: dict[str, Any] = {"after": after, "max": max_lines, "timeout_s": timeout_s}
        timeout = self.timeout_s + max(0.0, timeout_s)
        response = self._request("GET", f"{API}/live/lines", params=params, timeout=timeout)
        meta = json.loads(response.headers["X-Camd-Lines"])
        lines = np.frombuffer(response.content, dtype="<f4").reshape(meta["n"], meta["cols"])
        return meta, lines.astype(np.float32)
