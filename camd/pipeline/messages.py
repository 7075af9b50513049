"""What the batcher tells the TDI worker, in stream order: a batch of frames, lost frames, a
change of M or of the drift, the end.

The batcher (``camd.pipeline.batcher``) runs on the stream's dispatcher thread and the worker
(``camd.pipeline.tdi_pipeline``) on its own; a queue of these messages is all they share
besides the batch buffers, which the worker hands back once the engine has read them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt


@dataclass(frozen=True, slots=True)
class Batch:
    """Consecutive frames: the first ``n`` of ``pixels`` (a (capacity, rows, cols) uint16
    buffer lent by the batcher, handed back after use), with each frame's device counter and
    the stage encoder count latched at its start."""

    pixels: npt.NDArray[np.uint16]
    n: int
    counters: npt.NDArray[np.uint32]  # (n,)
    encoder: npt.NDArray[np.int32]  # (n,) encoder counts

    @property
    def frames(self) -> npt.NDArray[np.uint16]:
        """The batch's frames, (n, rows, cols): a view of the buffer."""
        return self.pixels[: self.n]


@dataclass(frozen=True, slots=True)
class Gap:
    """``frames`` frames never reached the batch before the next one (lost, corrupt, overrun,
    or of the wrong geometry): their lines are skipped and the next M - 1 are incomplete."""

    frames: int


@dataclass(frozen=True, slots=True)
class StageChange:
    """From the next frame on the engine sums ``stages`` stages (a new run starts there)."""

    stages: int


@dataclass(frozen=True, slots=True)
class DriftChange:
    """From the next frame on the engine's stages follow ``cols_per_line`` columns of drift per
    line (the image loop's trim; the lines already open keep what they summed)."""

    cols_per_line: float


@dataclass(frozen=True, slots=True)
class End:
    """No more messages: the worker stops."""


Message = Batch | Gap | StageChange | DriftChange | End
