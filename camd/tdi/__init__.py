"""The digital TDI engine and binning (numpy/OpenCV; no I/O).

- ``bin2x2``: FPGA-side 2x2 binning, the sum of four neighbours (physics.md §3)
"""

from camd.tdi.binning import bin2x2

__all__ = ["bin2x2"]
