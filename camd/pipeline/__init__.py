"""The acquisition pipeline of a scan: frames -> batches -> TDI engine -> recorder.

Below the daemon and free of it: it imports the link (``ReceivedFrame``), the store, the TDI
engine and the timing equations only, takes plain values and reports through callbacks.

- ``TdiPipeline``: one scan's batcher, worker thread, engine and recorder, its progress
  (``camd.pipeline.tdi_pipeline``)
- ``Batcher``: the frame stream consumer copying frames into batches on the stream's
  dispatcher thread (``camd.pipeline.batcher``)
- ``Batch``, ``Gap``, ``StageChange``, ``End``: the typed messages from the batcher to the
  worker, in stream order (``camd.pipeline.messages``)
- ``MismatchTracker``: each line's M dV/V from the encoder counts (docs/physics.md §6), its maximum,
  RMS and yellow/red level (``camd.pipeline.mismatch``)
"""

from camd.pipeline.batcher import Batcher
from camd.pipeline.messages import Batch, End, Gap, Message, StageChange
from camd.pipeline.mismatch import BatchMismatch, Level, MismatchTracker
from camd.pipeline.tdi_pipeline import Progress, TdiPipeline

__all__ = [
    "Batch",
    "BatchMismatch",
    "Batcher",
    "End",
    "Gap",
    "Level",
    "Message",
    "MismatchTracker",
    "Progress",
    "StageChange",
    "TdiPipeline",
]
