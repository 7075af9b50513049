"""The camera's USB frame reader, and the consumers every stream's frames go to.

``StreamReader`` holds the ``camd.link.frame_stream.FrameStream`` of the camera's USB bulk
endpoint, opened on first use through the pyusb backend the config chose (the simulated FX3 or
libusb, ``camd.daemon.backends``) and opened afresh after the camera reconnected or its device
went away. Consumers (the live view's tap, a scan's batcher) are kept here across streams, so
that every reader opened gets them; a consumer given for one stream only (a wheel acquisition's
frame means) is attached and detached with that stream. It also answers the reader's counters
and header log as the API's documents.

Every method but ``add_consumer``, ``remove_consumer``, ``stats`` and ``headers`` is called with
the stream's lock held (``camd.daemon.stream_run``).
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from typing import Any

from camd.daemon.config_camera import StreamSection
from camd.daemon.errors import NoFrameDevice
from camd.daemon.models import StreamFrameHeader, StreamHeadersResponse, StreamStats
from camd.daemon.realtime import REALTIME
from camd.link.frame_stream import HEADER_LOG, PACK_BYTES, Consumer, FrameStream, StreamError
from camd.protocol.stream import StreamMode

log = logging.getLogger(__name__)

# How long the line must be quiet, after a stream's end was announced (STOP_STREAM's or
# STREAM_DONE's next_counter), before the frames the camera counted that have not come count as
# lost. One read timeout (0.2 s) is ample for a camera, but a simulator starved of CPU on a busy
# host went 600 ms without answering, and it sends a block it was making when stopped only when
# that is done: given one read timeout, such frames were lost to their stream and came during the
# next one. Well inside the drain's limit (stream_run.DRAIN_TIMEOUT_S, 5 s); a stream whose last
# frames really were lost takes this long to stop.
END_QUIET_S = 2.0


class StreamReader:
    """The USB reader (opened on first use) and the frame consumers (module docstring)."""

    def __init__(
        self, config: StreamSection, usb_backend: Callable[[], Any], lock: threading.RLock
    ) -> None:
        self.config = config
        self._usb_backend = usb_backend
        self._lock = lock  # the stream's bookkeeping lock
        self.current: FrameStream | None = None  # the reader of the current or last stream
        self._consumers: list[Consumer] = []
        self._stream_consumer: Consumer | None = None  # one stream's only
        self._reopen = False  # the camera (re)connected: open the USB device afresh

    # -- consumers ------------------------------------------------------------------------------

    def add_consumer(self, consumer: Consumer) -> None:
        """Call ``consumer(frame)`` for every delivered frame of every stream, in order."""
        with self._lock:
            self._consumers.append(consumer)
            if self.current is not None:
                self.current.add_consumer(consumer)

    def remove_consumer(self, consumer: Consumer) -> None:
        with self._lock:
            if consumer in self._consumers:
                self._consumers.remove(consumer)
            if self.current is not None:
                self.current.remove_consumer(consumer)

    def attach_stream_consumer(self, reader: FrameStream, consumer: Consumer) -> None:
        """``consumer`` gets the frames of the stream ``reader`` is about to read only."""
        self._stream_consumer = consumer
        reader.add_consumer(consumer)

    def detach_stream_consumer(self, reader: FrameStream) -> None:
        consumer, self._stream_consumer = self._stream_consumer, None
        if consumer is not None:
            reader.remove_consumer(consumer)

    # -- the USB device -------------------------------------------------------------------------

    def reopen_next(self) -> None:
        """The camera (re)connected: the next stream opens the USB device afresh (a camera that
        restarted enumerates anew: a handle to the old one reads nothing)."""
        self._reopen = True

    def open(self) -> FrameStream:
        """The USB reader, opened on first use; NoFrameDevice (503) if the device is absent or
        cannot be opened: its message names the device looked for and what to check."""
        try:
            return self._opened()
        except (StreamError, ConnectionError, OSError) as exc:
            raise NoFrameDevice(str(exc)) from None

    def _opened(self) -> FrameStream:
        stale = self.current
        if stale is not None and (self._reopen or stale.error is not None):
            # The camera reconnected, or its USB device went away under the last stream.
            self.current = None
            self._close(stale)
        self._reopen = False
        if self.current is None:
            config = self.config
            reader = FrameStream(
                vendor_id=config.vendor_id,
                product_id=config.product_id,
                backend=self._usb_backend(),
                queue_frames=config.queue_frames,
                queue_bytes=round(config.queue_mb * 1e6),
                overflow=config.overflow,
                read_bytes=config.read_bytes,
                # Small frames packed into transfers, where the device can (docs/stream.md).
                pack_bytes=0 if config.read_bytes else PACK_BYTES,
                timeout_s=config.timeout_s,
                end_quiet_s=END_QUIET_S,
                thread_start=REALTIME.enter,
            )
            reader.open()
            for consumer in self._consumers:
                reader.add_consumer(consumer)
            self.current = reader
        return self.current

    def take(self) -> FrameStream | None:
        """Hand over the reader (daemon shutdown: the caller stops and closes it)."""
        reader, self.current = self.current, None
        return reader

    @staticmethod
    def _close(reader: FrameStream) -> None:
        """Release a reader's USB device, gone or not, and a simulated FX3's socket."""
        try:
            reader.close()
        except Exception as exc:  # a device that went away may fail to let go
            log.info("closing the old frame stream: %s", exc)
        close_backend = getattr(reader.backend, "close", None)  # the simulated FX3's socket
        if callable(close_backend):
            close_backend()

    # -- documents ------------------------------------------------------------------------------

    def stats(self) -> StreamStats:
        """The host's ingest counters of the current or last stream (no device traffic)."""
        reader = self.current
        if reader is None:
            return StreamStats(
                frames=0, bytes=0, lost=0, corrupt=0, short=0, overruns=0, stalls=0,
                timeouts=0, out_of_order=0, elapsed_s=0.0, mpix_per_s=0.0, mbyte_per_s=0.0,
            )  # fmt: skip
        values = reader.stats().as_dict()
        return StreamStats.model_validate({k: values[k] for k in StreamStats.model_fields})

    def headers(self) -> StreamHeadersResponse:
        """The first headers of the current or last stream (``FrameStream.header_log``)."""
        with self._lock:
            reader = self.current
        log_ = [] if reader is None else reader.header_log()
        return StreamHeadersResponse(
            kept_max=HEADER_LOG,
            frames=[
                StreamFrameHeader(
                    counter=h.counter,
                    timestamp_ns=h.timestamp_ns,
                    line_period_ns=h.line_period_ns,
                    rows=h.rows,
                    cols=h.cols,
                    bits=h.bits,
                    mode="tdi" if h.mode == StreamMode.TDI else "area",
                    stages=h.stages,
                    stage_position=h.stage_position,
                    flags=int(h.flags),
                    payload_bytes=h.payload_bytes,
                    payload_crc32=h.payload_crc32,
                    payload_crc32_host=computed,
                )
                for h, computed in log_
            ],
        )
