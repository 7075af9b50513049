"""The stream consumer of a scan: frames copied into batches, queued for the TDI worker.

``Batcher`` is added to the frame stream's consumers and so runs on its dispatcher thread: it
copies each frame into a batch buffer (no per-frame thread hand-off; the frame's pixels are
only valid during the callback) and queues ``camd.pipeline.messages`` for the worker. Lost
frames (``ReceivedFrame.gap_before``), frames of the wrong geometry and a pending change of M
end the current batch and are queued as markers between batches, so the worker sees
everything in stream order.
"""

from __future__ import annotations

import queue
import threading
import time

import numpy as np
import numpy.typing as npt

from camd.link.frame_stream import ReceivedFrame
from camd.link.packed import FrameBatch
from camd.pipeline.messages import Batch, DriftChange, Gap, Message, StageChange
from camd.protocol.stream import SMALL_PAYLOAD_BYTES

BATCH_BYTES = 16 << 20  # frames per batch: about this many bytes, so one push_many amortises
MAX_BATCH_FRAMES = 512
BATCH_BUFFERS = 4  # batches in flight between the consumer and the worker
BATCH_MAX_AGE_S = 0.1  # a partial batch older than this goes to the engine (progress, latency)
CONSUMER_WAIT_S = 5.0  # longest the consumer waits for a free batch before giving up a frame
_U16 = np.dtype(np.uint16)


def batch_frames_for(rows: int, cols: int) -> int:
    """Frames in one batch of ``rows`` x ``cols`` frames: one ``push_many`` call of a scan."""
    return max(1, min(MAX_BATCH_FRAMES, BATCH_BYTES // (2 * rows * cols)))


class Batcher:
    """The stream consumer: copies frames into batches and queues them for the worker.

    ``rows`` x ``cols`` is the frame the engine needs; a frame with more rows (the line period
    loop trimmed the window) gives its first ``rows``, a smaller or narrower one is dropped and
    counted as a gap. ``frames`` counts the frames batched, ``dropped`` those given up.
    """

    def __init__(self, rows: int, cols: int, work: queue.Queue[Message]) -> None:
        self.rows, self.cols = rows, cols
        self.batch_frames = batch_frames_for(rows, cols)
        self._free: queue.Queue[npt.NDArray[np.uint16]] = queue.Queue()
        for _ in range(BATCH_BUFFERS):
            self._free.put(np.empty((self.batch_frames, rows, cols), dtype=np.uint16))
        self._work = work
        self._lock = threading.Lock()
        self._buf: npt.NDArray[np.uint16] | None = None
        self._buf_bytes = memoryview(b"")  # the batch buffer's bytes, while there is one
        self._frame_bytes = 2 * rows * cols
        # A small frame is copied as bytes, which keeps Python's GIL (numpy lets go of it,
        # and taking it back from the stream's reader costs more than the copy; see
        # camd.protocol.stream.payload_crc32); a large one by numpy, which lets the reader run.
        self._copy_bytes = self._frame_bytes <= SMALL_PAYLOAD_BYTES
        self._counters = np.zeros(self.batch_frames, dtype=np.uint32)
        self._encoder = np.zeros(self.batch_frames, dtype=np.int32)
        self._n = 0
        self._since = 0.0
        self._pending_stages: int | None = None
        self._pending_drift: float | None = None
        self.frames = 0
        self.dropped = 0

    @property
    def pending_stages(self) -> int | None:
        """The M asked for and not yet reached by a frame (None: none pending)."""
        return self._pending_stages

    def request_stages(self, stages: int) -> None:
        """Change M at the next frame this consumer sees (the latest request wins)."""
        with self._lock:
            self._pending_stages = stages

    def request_drift(self, cols_per_line: float) -> None:
        """Change the drift the engine follows at the next frame (the latest request wins)."""
        with self._lock:
            self._pending_drift = cols_per_line

    def recycle(self, buf: npt.NDArray[np.uint16]) -> None:
        """Hand back a batch's buffer once the engine has read it."""
        self._free.put(buf)

    def __call__(self, frame: ReceivedFrame) -> None:
        with self._lock:
            self._markers(frame.gap_before)
            pixels = frame.pixels
            rows, cols = pixels.shape
            if rows < self.rows or cols != self.cols:
                # Not this scan's geometry: the engine cannot use it; the line is lost.
                self._drop()
                return
            if self._buf is None:
                try:
                    self._buf = self._free.get(timeout=CONSUMER_WAIT_S)
                except queue.Empty:
                    # The worker is this far behind: give the frame up rather than stall the
                    # stream's dispatcher (and with it the USB reader) any longer.
                    self._drop()
                    return
                self._buf_bytes = self._buf.data.cast("B")
                self._since = time.monotonic()
            n = self._n
            src = pixels if rows == self.rows else pixels[: self.rows]
            if self._copy_bytes and src.dtype == _U16 and src.flags.c_contiguous:
                start = n * self._frame_bytes
                self._buf_bytes[start : start + self._frame_bytes] = src.data.cast("B")
            else:
                self._buf[n] = src
            header = frame.header
            self._counters[n] = header.counter
            self._encoder[n] = header.stage_position
            self._n = n = n + 1
            self.frames += 1
            if n == self.batch_frames or time.monotonic() - self._since > BATCH_MAX_AGE_S:
                self._flush()

    def on_batch(self, batch: FrameBatch) -> None:
        """A run of consecutive frames (a packed transfer's): copied into the batch buffer in
        as few numpy copies as the batch boundaries allow; the same messages, in the same
        order, as a call per frame would queue."""
        pixels = batch.pixels
        k, rows, cols = pixels.shape
        if rows < self.rows or cols != self.cols:
            for i in range(k):  # not this scan's geometry: each frame dropped as a gap
                self(
                    ReceivedFrame(
                        batch.header(i),
                        pixels[i],
                        batch.received_ns,
                        batch.gap_before if i == 0 else 0,
                        batch.first_index + i,
                    )
                )
            return
        counters = batch.counters
        encoder = batch.stage_positions
        src = pixels if rows == self.rows else pixels[:, : self.rows]
        with self._lock:
            self._markers(batch.gap_before)
            done = 0
            while done < k:
                if self._buf is None:
                    try:
                        self._buf = self._free.get(timeout=CONSUMER_WAIT_S)
                    except queue.Empty:
                        for _ in range(k - done):  # the worker is this far behind
                            self._drop()
                        return
                    self._buf_bytes = self._buf.data.cast("B")
                    self._since = time.monotonic()
                n = self._n
                m = min(k - done, self.batch_frames - n)
                self._buf[n : n + m] = src[done : done + m]
                self._counters[n : n + m] = counters[done : done + m]
                self._encoder[n : n + m] = encoder[done : done + m]
                self._n = n = n + m
                self.frames += m
                done += m
                if n == self.batch_frames or time.monotonic() - self._since > BATCH_MAX_AGE_S:
                    self._flush()

    def _markers(self, gap_before: int) -> None:
        """Before the next frame (lock held): the gap before it and a pending change of M,
        each ending the current batch."""
        if gap_before:
            self._flush()
            self._work.put(Gap(int(gap_before)))
        if self._pending_stages is not None:
            self._flush()
            self._work.put(StageChange(self._pending_stages))
            self._pending_stages = None
        if self._pending_drift is not None:
            self._flush()
            self._work.put(DriftChange(self._pending_drift))
            self._pending_drift = None

    def release(self) -> None:
        """The scan has ended: give the batch buffers back to the allocator now. (The scan's
        objects refer to one another, so without this they would wait for a full garbage
        collection, which a daemon may not run for many scans: tens of MB each.)"""
        with self._lock:
            self._buf, self._n = None, 0
            self._buf_bytes = memoryview(b"")
            while True:
                try:
                    self._free.get_nowait()
                except queue.Empty:
                    break

    def flush(self) -> None:
        """Queue the partial batch now (the stream has ended)."""
        with self._lock:
            self._flush()

    def _drop(self) -> None:
        self._flush()
        self._work.put(Gap(1))
        self.dropped += 1

    def _flush(self) -> None:
        if self._buf is None or self._n == 0:
            return
        n = self._n
        self._work.put(Batch(self._buf, n, self._counters[:n].copy(), self._encoder[:n].copy()))
        self._buf, self._n = None, 0
        self._buf_bytes = memoryview(b"")
