"""camd for bluesky: ophyd-async devices that drive a camd daemon over its HTTP API.

An optional part of camd (``pip install 'camd[bluesky]'``: ophyd-async, bluesky,
event-model, hdf5plugin); nothing else in camd imports it. docs/bluesky.md is its guide.

- ``CamdConnection`` (``connection``): asynchronous HTTP to one daemon, its token and client
  name, and the control lease its devices share while staged;
- ``CamdStareDetector``, ``CamdScanDetector`` (``detector``): staring acquisitions and
  push-broom TDI scans as ophyd-async ``StandardDetector`` s, whose StreamResource and
  StreamDatum documents point into camd's HDF5 files (``files``; ``read_stream_datum`` reads
  one back);
- ``CamdStage`` (``stage``): the scan stage as a motor, in metres;
- ``CamdFilterWheel`` (``wheel``): the filter wheel, settable by its speed in deg/s;
- ``push_broom`` (``plans``): the push-broom scan as a fly scan.
"""

from __future__ import annotations

from camd.bluesky.connection import CamdConnection
from camd.bluesky.detector import CamdScanDetector, CamdStareDetector
from camd.bluesky.files import read_stream_datum
from camd.bluesky.plans import push_broom
from camd.bluesky.stage import CamdStage
from camd.bluesky.wheel import CamdFilterWheel

__all__ = [
    "CamdConnection",
    "CamdFilterWheel",
    "CamdScanDetector",
    "CamdStage",
    "CamdStareDetector",
    "push_broom",
    "read_stream_datum",
]
