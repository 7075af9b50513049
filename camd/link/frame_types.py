"""What the frame stream's parts share with its users: the delivered frame, the counters, the error.

``camd.link.frame_stream`` exports these names; the stream's parts (``stream_device``,
``frame_queue``, ``frame_ledger``, ``frame_reader``, ``frame_dispatcher``) import them from here.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from camd.protocol.stream import FrameHeader

# The stream's one logger: its parts log under the name the stream had when it was one module
# (log filters select the frame stream's lines by it).
log = logging.getLogger("camd.link.frame_stream")


class StreamError(RuntimeError):
    """The frame stream cannot be opened or read; the message says what to check."""


@dataclass(frozen=True, slots=True)
class ReceivedFrame:
    """One delivered frame.

    ``pixels`` is a read-only (rows, cols) uint16 view into the reader's slot, valid only
    during the callback: copy what you keep. ``gap_before`` is the number of frames missing
    between the previously delivered frame and this one, whatever the cause (lost on the
    link, corrupt, dropped by the queue); ``index`` counts delivered frames from 0.
    """

    header: FrameHeader
    pixels: np.ndarray
    received_ns: int  # time.monotonic_ns() when the reader had the whole frame
    gap_before: int
    index: int


@dataclass(slots=True)
class StreamStats:
    """The stream's counters since ``start()``.

    ``lost``: counters never received; ``corrupt``: bad header or payload CRC (or a
    malformed transfer); ``short``: truncated transfers; ``overruns``: dropped by the queue's
    overflow policy; ``stalls``: endpoint halts cleared; ``timeouts``: bulk reads that
    timed out (each ``timeout_s`` without data); ``out_of_order``: counters going backwards or
    repeated (dropped). ``frames``/``bytes``: delivered (header + payload bytes).
    """

    frames: int = 0
    bytes: int = 0
    lost: int = 0
    corrupt: int = 0
    short: int = 0
    overruns: int = 0
    stalls: int = 0
    timeouts: int = 0
    out_of_order: int = 0
    reads: int = 0
    consumer_errors: int = 0
    first_counter: int | None = None
    last_counter: int | None = None
    elapsed_s: float = 0.0
    mpix_per_s: float = 0.0
    mbyte_per_s: float = 0.0

    def as_dict(self) -> dict[str, int | float | None]:
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}


Consumer = Callable[[ReceivedFrame], None]
