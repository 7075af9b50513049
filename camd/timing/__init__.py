"""The timing equations of physics.md §2-3: pure functions of plain values, SI units.

Each function's docstring names its section and equation in physics.md (and through it the
paper). Bad inputs (non-positive periods or clocks, negative counts, non-finite numbers) raise
``ValueError`` naming the argument.

- §2 eqs 1-4, rolling/global shutter: ``rolling_line_period_s``, ``rolling_frame_time_s``,
  ``global_frame_time_s``, ``max_rolling_integration_s``
- §2 eqs 5-9, 13, TDI window: ``tdi_line_period_s``, ``turntable_line_period_s``,
  ``tdi_window`` -> ``TdiWindow``, ``synchronous_stage_speed_m_s``
- §6, velocity mismatch: ``velocity_mismatch`` (dV/V)
- §3, HR400 sequencer: ``sequencer_line_period_s``, ``exposure_s``, ``sequencer_frame_time_s``,
  ``sequencer_frame_period_lines``, ``sequencer_frame_period_s``
"""

from camd.timing.rolling import (
    global_frame_time_s,
    max_rolling_integration_s,
    rolling_frame_time_s,
    rolling_line_period_s,
)
from camd.timing.sequencer import (
    HR400_CLOCKS_PER_LINE,
    exposure_s,
    sequencer_frame_period_lines,
    sequencer_frame_period_s,
    sequencer_frame_time_s,
    sequencer_line_period_s,
)
from camd.timing.tdi import (
    EXACT_MULTIPLE_RTOL,
    TdiWindow,
    synchronous_stage_speed_m_s,
    tdi_line_period_s,
    tdi_window,
    turntable_line_period_s,
    velocity_mismatch,
)

__all__ = [
    "EXACT_MULTIPLE_RTOL",
    "HR400_CLOCKS_PER_LINE",
    "TdiWindow",
    "exposure_s",
    "global_frame_time_s",
    "max_rolling_integration_s",
    "rolling_frame_time_s",
    "rolling_line_period_s",
    "sequencer_frame_period_lines",
    "sequencer_frame_period_s",
    "sequencer_frame_time_s",
    "sequencer_line_period_s",
    "synchronous_stage_speed_m_s",
    "tdi_line_period_s",
    "tdi_window",
    "turntable_line_period_s",
    "velocity_mismatch",
]
