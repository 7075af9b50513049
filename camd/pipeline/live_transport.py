"""What the live WebSocket sends each viewer: its own binning, rate and compression.

A viewer on another PC of the lab network cannot take 44 MB/s (534 x 2048 uint16 at 20 frames a
second). Each viewer chooses (docs/live-view.md, "Transport"):

- ``bin``: 1, 2, 4 or 8; each ``bin`` x ``bin`` block becomes its mean, rounded to the nearest DN
  (half to even), still uint16; the rows and columns past the last whole block are dropped;
- ``max_fps``: at most this many frames a second (decimation; the live view keeps 20 at most);
- ``compression``: ``none`` or ``deflate`` (zlib's format: what the browser's
  ``DecompressionStream("deflate")`` inflates), at level 1: fast, and the images' noise leaves
  little for higher levels to find.

The work is done for the viewer, never on the acquisition's threads (the live tap stays a copy
a twentieth of a second): ``TransportEncoder.encode`` runs in the WebSocket's worker thread,
behind one lock, so that however many viewers there are, encoding takes at most one core; a
slow encoder makes viewers get fewer frames (always the newest), never slows the stream. Viewers
with the same settings share the work: the newest frame's encoding is kept per (bin, compression).
"""

from __future__ import annotations

import math
import threading
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt
from zlib_ng import zlib_ng

from camd.pipeline.live import MAX_RATE_HZ, LiveFrame

BINNINGS = (1, 2, 4, 8)
COMPRESSIONS = ("none", "deflate")
DEFLATE_LEVEL = 1
TRANSPORT_KEYS = ("bin", "max_fps", "compression")


@dataclass(frozen=True, slots=True)
class Transport:
    """One viewer's settings (module docstring); the defaults: what the WebSocket always sent."""

    bin: int = 1
    max_fps: float = MAX_RATE_HZ
    compression: str = "none"

    @property
    def min_interval_s(self) -> float:
        return 1.0 / self.max_fps

    def as_dict(self) -> dict[str, Any]:
        return {"bin": self.bin, "max_fps": self.max_fps, "compression": self.compression}


def parse_transport(values: Mapping[str, Any], base: Transport | None = None) -> Transport:
    """``base`` (default: the defaults) with the settings in ``values`` (query parameters or a
    viewer's JSON message; strings or numbers); ValueError saying what to change for an unknown
    key or a bad value."""
    base = base or Transport()
    unknown = sorted(set(values) - set(TRANSPORT_KEYS) - {"token"})
    if unknown:
        raise ValueError(
            f"unknown transport setting {', '.join(map(repr, unknown))}: the settings are "
            f"{', '.join(TRANSPORT_KEYS)}"
        )
    binning, max_fps, compression = base.bin, base.max_fps, base.compression
    if "bin" in values:
        text = str(values["bin"])
        if text not in {str(b) for b in BINNINGS}:
            raise ValueError(
                f"bin={text!r} is not a binning: use {', '.join(map(str, BINNINGS))} "
                "(each bin x bin block sent as its mean)"
            )
        binning = int(text)
    if "max_fps" in values:
        try:
            max_fps = float(values["max_fps"])
        except (TypeError, ValueError):
            max_fps = math.nan
        if not 0 < max_fps <= MAX_RATE_HZ:
            raise ValueError(
                f"max_fps={values['max_fps']!r} is not a rate: use a number of frames a second "
                f"above 0 and at most {MAX_RATE_HZ:g} (what the live view keeps)"
            )
    if "compression" in values:
        compression = str(values["compression"])
        if compression not in COMPRESSIONS:
            raise ValueError(
                f"compression={compression!r} is not offered: use {' or '.join(COMPRESSIONS)}"
            )
    return Transport(binning, max_fps, compression)


def block_mean(pixels: npt.NDArray[np.uint16], binning: int) -> npt.NDArray[np.uint16]:
    """Each ``binning`` x ``binning`` block's mean, rounded to the nearest DN (half to even);
    rows and columns past the last whole block dropped."""
    if binning == 1:
        return pixels
    rows, cols = pixels.shape[0] // binning, pixels.shape[1] // binning
    blocks = pixels[: rows * binning, : cols * binning].reshape(rows, binning, cols, binning)
    # Sums in uint32 (8 x 8 x 65535 fits), the mean in float64: exact before the rounding.
    sums = blocks.sum(axis=(1, 3), dtype=np.uint32)
    means: npt.NDArray[np.uint16] = np.rint(sums / float(binning * binning)).astype(np.uint16)
    return means


@dataclass(frozen=True, slots=True)
class Encoded:
    """A frame as one viewer's settings send it: its description and payload."""

    meta: dict[str, Any]
    payload: bytes


class TransportEncoder:
    """Encodes frames for viewers, one at a time, sharing the newest frame's encodings."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._cache: dict[tuple[int, str], tuple[int, Encoded]] = {}
        self.encoded = 0  # encodings made (not served from the cache)

    def encode(self, frame: LiveFrame, transport: Transport) -> Encoded:
        """``frame`` binned and compressed as ``transport`` says. Its description (as
        ``LiveFrame.meta``) says what was applied: ``rows`` and ``cols`` are those of the
        pixels sent; ``frame_rows`` and ``frame_cols`` the camera's frame; ``bin``,
        ``compression``, ``max_fps``; ``bytes`` the payload's length; binned, ``saturated`` and
        ``zero``: the camera frame's pixels at full scale (``2**bits - 1``) and at 0."""
        key = (transport.bin, transport.compression)
        with self._lock:
            cached = self._cache.get(key)
            if cached is not None and cached[0] == frame.seq:
                encoded = cached[1]
            else:
                encoded = self._encode(frame, transport)
                self._cache[key] = (frame.seq, encoded)
                self.encoded += 1
        # max_fps is the viewer's own: the cached description is shared.
        return Encoded({**encoded.meta, "max_fps": transport.max_fps}, encoded.payload)

    @staticmethod
    def _encode(frame: LiveFrame, transport: Transport) -> Encoded:
        pixels = block_mean(frame.pixels, transport.bin)
        raw = pixels.astype("<u2", copy=False).tobytes()
        payload = (
            zlib_ng.compress(raw, DEFLATE_LEVEL) if transport.compression == "deflate" else raw
        )
        meta = {
            **frame.meta(),
            "rows": int(pixels.shape[0]),
            "cols": int(pixels.shape[1]),
            "frame_rows": frame.rows,
            "frame_cols": frame.cols,
            "bin": transport.bin,
            "compression": transport.compression,
            "bytes": len(payload),
        }
        if transport.bin > 1:
            # Block means hide clipped pixels: the viewer's clipping counts are the frame's.
            full_scale = (1 << frame.bits) - 1
            meta["saturated"] = int(np.count_nonzero(frame.pixels >= full_scale))
            meta["zero"] = int(np.count_nonzero(frame.pixels == 0))
        return Encoded(meta, payload)
