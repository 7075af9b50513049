"""Standard normal draws for the simulated camera's temporal noise, from a pre-drawn bank.

Drawing one Gaussian per pixel was 62 % of an area frame's render time (12.5 ms of
``standard_normal`` for the hr400's 534 x 2048 window, against its 10.96 ms frame period). The
bank draws them once: a frame of ``n`` pixels takes a run of ``n`` consecutive values starting
at a random offset (uniform over the ``B - n + 1`` possible starts, drawn from the camera's
seeded temporal stream), a slice, no copy.

What that does to the statistics (docs/simulator.md, "Temporal noise from a bank"):

- Each pixel's value is a draw from the bank: standard normal, mean 0 and variance 1 exactly
  over the bank (each chunk of it is shifted and scaled to that), so a mean or variance
  averaged over many frames converges to the true one, not to the bank's sampling error.
- Within a frame the values are distinct draws: independent, as before.
- Two frames share the value at the same pixel only if their offsets are equal (probability
  ``1 / (B - n + 1)`` per pair of frames, under 1e-6 for the shipped windows): successive
  frames' noise is uncorrelated pixel by pixel, and a TDI line's M values are M distinct
  draws but for a coincidence of offsets (about ``M^2 / (2 (B - n))`` of the lines).
- A value comes back, elsewhere in a later frame, on average every ``(B - n) / n`` frames (3
  or more: the bank holds at least four frames): a frame's noise is partly another's,
  shifted along the pixel order. No measurement of a real camera looks there (a
  cross-correlation of two frames over all shifts would find it).
- Tails stop at the bank's largest draw, about 5.2 sigma for 4 Mi values: a true Gaussian goes
  beyond that once in some million draws.

The bank is made of chunks of ``CHUNK_VALUES`` (1 Mi) float32 values, chunk ``c`` drawn from
its own stream of the camera's start seed; frames of ``n`` pixels take their runs from the
first ``span(n)`` values (whole chunks holding ``FRAMES_PER_BANK`` frames, at least
``MIN_CHUNKS``), drawn when first needed, so the same seed and the same renders give the same
values, whatever else was drawn before. A frame larger than
``MAX_CHUNKS`` chunks allow (a full 33 Mpixel ftf5066 frame) is drawn pixel by pixel instead.
"""

from __future__ import annotations

import threading
from typing import Any

import numpy as np
import numpy.typing as npt

CHUNK_VALUES = 1 << 20
MIN_CHUNKS = 4  # 16 MiB of float32: drawn in about 60 ms, once per simulator
MAX_CHUNKS = 32  # 128 MiB: frames up to 8 Mpixel come from the bank
FRAMES_PER_BANK = 4  # the bank holds at least this many frames of the largest asked for
_BANK_STREAM = 0x4E42  # "NB"

F32 = npt.NDArray[np.float32]


class NoiseBank:
    """Pre-drawn standard normal values (float32) and the offsets frames take them from.

    ``seed`` fixes the bank (the camera's start seed); ``offsets`` draw from the generator the
    caller passes (the camera's temporal stream, which ``reseed_noise`` restarts).
    """

    def __init__(self, seed: int) -> None:
        self.seed = seed
        self._values: F32 = np.empty(0, dtype=np.float32)
        # The bank only ever grows, under this lock: a warm-up thread may grow it while a
        # stream takes from it, and a run found in it must stay in the array read after.
        self._grow_lock = threading.Lock()

    @property
    def size(self) -> int:
        """Values in the bank now."""
        return int(self._values.size)

    def holds(self, pixels: int) -> bool:
        """Whether frames of ``pixels`` pixels are taken from the bank (else drawn directly)."""
        return FRAMES_PER_BANK * pixels <= MAX_CHUNKS * CHUNK_VALUES

    def take(
        self, rng: np.random.Generator, frames: int, pixels: int
    ) -> tuple[F32, npt.NDArray[np.int64]]:
        """Standard normal noise for ``frames`` frames of ``pixels`` each, as (values, starts):
        frame ``i``'s noise is ``values[starts[i] : starts[i] + pixels]``.

        From the bank (no copy), each frame's run at its own random offset; for frames too
        large for the bank, fresh draws from ``rng``."""
        if not self.holds(pixels):
            fresh = rng.standard_normal(frames * pixels, dtype=np.float32)
            return fresh, np.arange(frames, dtype=np.int64) * pixels
        starts = self.offsets(rng, frames, pixels)  # grows the bank first if it must
        return self._values, starts

    def offsets(self, rng: np.random.Generator, frames: int, pixels: int) -> npt.NDArray[np.int64]:
        """Where each of ``frames`` frames of ``pixels`` pixels starts in the bank: uniform
        over every start that fits in ``span(pixels)`` values. One double per frame from
        ``rng``, in order: a block of frames draws what the same frames drawn one at a time
        would; and the frames of a size do not depend on what larger frames grew the bank to
        before (or a warm-up)."""
        span = self.span(pixels)
        self.grow_to(span)
        starts = rng.random(frames) * (span - pixels + 1)
        result: npt.NDArray[np.int64] = np.minimum(starts.astype(np.int64), span - pixels)
        return result

    @staticmethod
    def span(pixels: int) -> int:
        """The values frames of ``pixels`` pixels take their runs from (the ``B`` of the module
        docstring): whole chunks holding ``FRAMES_PER_BANK`` frames, at least ``MIN_CHUNKS``."""
        return max(MIN_CHUNKS, -(-FRAMES_PER_BANK * pixels // CHUNK_VALUES)) * CHUNK_VALUES

    @property
    def values(self) -> F32:
        """The bank (read-only view)."""
        view = self._values.view()
        view.flags.writeable = False
        return view

    def grow_to(self, values: int) -> None:
        """Draw the chunks up to ``values`` values that are not drawn yet (a warm-up may draw
        them ahead of the first frame; the values are the same whenever they are drawn)."""
        chunks = -(-values // CHUNK_VALUES)
        if chunks <= self.size // CHUNK_VALUES:
            return
        with self._grow_lock:
            have = self.size // CHUNK_VALUES
            if chunks <= have:
                return
            parts: list[Any] = [self._values]
            parts += [self._chunk(c) for c in range(have, chunks)]
            self._values = np.concatenate(parts)

    def _chunk(self, index: int) -> F32:
        """Chunk ``index``: standard normal draws of its own stream, shifted and scaled to mean
        0 and variance 1 exactly (over the chunk, so over the bank too)."""
        rng = np.random.default_rng([self.seed, _BANK_STREAM, index])
        chunk = rng.standard_normal(CHUNK_VALUES, dtype=np.float32)
        mean = chunk.mean(dtype=np.float64)  # the moments in float64: exact to float32's digits
        chunk -= np.float32(mean)
        chunk /= np.float32(np.sqrt(np.mean(np.square(chunk, dtype=np.float64))))
        return chunk
