"""The digital TDI engine and binning (numpy/numba; no I/O). docs/tdi.md is the contract.

- ``TdiEngine``, ``tdi_batch``: M window rows of one ground line summed into one line
  (docs/physics.md §1 eqs 11-12), streaming or batch, with completeness flags
- ``warm_up``: load or compile the kernels ahead of the first scan
- ``bin2x2``: FPGA-side 2x2 binning, the sum of four neighbours (docs/physics.md §3)
"""

from camd.tdi.binning import bin2x2
from camd.tdi.engine import TdiBlock, TdiEngine, TdiLine, numba_available, tdi_batch, warm_up
from camd.tdi.taps import FIXED_POINT_ONE, StageTaps, stage_taps

__all__ = [
    "FIXED_POINT_ONE",
    "StageTaps",
    "TdiBlock",
    "TdiEngine",
    "TdiLine",
    "bin2x2",
    "numba_available",
    "stage_taps",
    "tdi_batch",
    "warm_up",
]
