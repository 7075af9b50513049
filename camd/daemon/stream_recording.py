"""A stream's HDF5 recording: made before the stream starts, fed every frame, closed at its end.

``StreamRecording`` makes the ``camd.store.recording.FrameRecorder`` of a stream that records
(a stare's or a stream's ``record``; a wheel acquisition's), after noting it on the journal of
open recordings (so that a daemon killed at any point after leaves an entry the next one
repairs), attaches it to the stream's reader as a consumer, and closes it with the stream's
counters and why it ended early, if it did (``camd.store.journal.close_recording``). A frame
that cannot be written (a full disk) is said once, and the stream service is told to stop the
stream; the daemon goes on serving.

``attach`` and ``detach`` are called with the stream's lock held (``camd.daemon.stream_run``).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from camd.daemon.device import DeviceAccess
from camd.daemon.errors import BadRequest, SessionError
from camd.link.frame_stream import Consumer, FrameStream, ReceivedFrame
from camd.pipeline.background import Background
from camd.pipeline.roi import RoiLog, RoiMonitor
from camd.store.compression import Compression
from camd.store.journal import close_recording
from camd.store.recording import FrameRecorder, RecordingError


class StreamRecording:
    """The recording of the current or last stream (module docstring).

    ``on_failed(cause)`` is called (on the stream's dispatcher thread) when a frame could not be
    written; ``cause`` says which file stopped and why.
    """

    def __init__(
        self,
        device: DeviceAccess,
        on_failed: Callable[[str], None],
        roi: RoiMonitor | None = None,
    ) -> None:
        self.device = device
        self._on_failed = on_failed
        # The live view's ROIs: their statistics of the recorded frames go into the file.
        self._roi = roi
        self._roi_log: RoiLog | None = None
        self._to: tuple[FrameRecorder, Consumer] | None = None  # the recording being written
        self.path: str | None = None  # of the current or last stream's recording
        self._frames_flushed = 0  # of the last recording, once closed

    @property
    def recording(self) -> bool:
        """Whether a recording is being written now."""
        return self._to is not None

    @property
    def frames_flushed(self) -> int:
        """Frames on disk: of the recording being written, else of the last one closed."""
        return self._frames_flushed if self._to is None else self._to[0].flushed

    def forget(self) -> None:
        """A new stream starts: the last one's recording is no longer the current one."""
        self.path = None
        self._frames_flushed = 0

    def create(
        self,
        path: Path,
        frames_expected: int,
        metadata: Mapping[str, Mapping[str, Any]],
        compression: Compression,
        background: Background | None = None,
    ) -> FrameRecorder:
        """A new recording with the camera's ``metadata`` (and the live view's ``background``,
        if one is ready), its frames compressed with ``compression``, made before the stream
        starts so that its first frame is recorded too; the frames set its geometry.
        BadRequest if the file cannot be made."""
        # On the journal before the file exists: a daemon killed at any point after leaves an
        # entry, and the next one repairs the file (or finds it was never made).
        journal = self.device.recordings
        try:
            journal.opened(path, "recording")
        except OSError as exc:
            raise SessionError(
                f"cannot note the recording in {journal.folder}: {exc}; check the data directory"
            ) from None
        try:
            return FrameRecorder(
                path,
                frames_expected=frames_expected,
                metadata=metadata,
                background_dn=None if background is None else background.pixels,
                background_attrs=None if background is None else background.recording_attrs(),
                compression=compression,
            )
        except RecordingError as exc:
            journal.closed(path)  # no file was left (FrameRecorder removes what it began)
            raise BadRequest(str(exc)) from None

    def attach(self, recorder: FrameRecorder, reader: FrameStream) -> None:
        """Record every frame ``reader`` delivers from now on."""

        def record(frame: ReceivedFrame) -> None:
            if recorder.failed is not None:
                return  # said once; the stream is being stopped
            try:
                recorder.add(
                    frame.header, frame.pixels, received_ns=frame.received_ns,
                    gap_before=frame.gap_before,
                )  # fmt: skip
            except RecordingError as exc:
                self._failed(recorder, str(exc))

        self._to = (recorder, record)
        self.path = str(recorder.path)
        self._frames_flushed = 0
        # Before the recorder: the log starts no later than the file's first frame.
        self._roi_log = self._roi.start_log() if self._roi is not None else None
        reader.add_consumer(record)

    def _failed(self, recorder: FrameRecorder, why: str) -> None:
        """A frame could not be written (a full disk): say so once, and have the stream
        stopped (not from the reader's dispatch thread, which stopping joins)."""
        self.device.log_event(
            "error", "stream", f"recording {recorder.path} stopped: {why}; stopping the stream"
        )
        self._on_failed(f"the recording {recorder.path} stopped: {why}")

    def detach(
        self,
        reader: FrameStream,
        stats: dict[str, Any] | None = None,
        *,
        ended_early: str | None = None,
    ) -> None:
        """Stop recording ``reader``'s frames and close the file with the stream's counters
        (``stats``; None: the stream never started) and why it ended early, if it did."""
        if self._to is None:
            return
        recorder, record = self._to
        self._to = None
        reader.remove_consumer(record)
        # The ROI statistics of the stream's frames go into the file as its /roi group
        # (docs/stream.md) while it is finished, before the journal counts it as closed: a crash
        # then is repaired as any recording left open. A file whose writing failed gets none.
        log, self._roi_log = self._roi_log, None
        if log is not None and self._roi is not None:
            self._roi.stop_log(log)
        add_rois = log.write_into if log is not None and recorder.failed is None else None
        close_recording(
            recorder,
            stats,
            self.device.recordings,
            self.device.log_event,
            ended_early=ended_early,
            finish_with=add_rois,
        )
        self._frames_flushed = recorder.flushed
