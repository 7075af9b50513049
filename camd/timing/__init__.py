"""The timing equations of docs/physics.md §2-3: pure functions of plain values, SI units.

Each function's docstring names its section and equation in docs/physics.md (and through it the
paper). Bad inputs (non-positive periods or clocks, negative counts, non-finite numbers) raise
``ValueError`` naming the argument.

- §2 eqs 1-4, rolling/global shutter: ``rolling_line_period_s``, ``rolling_frame_time_s``,
  ``global_frame_time_s``, ``max_rolling_integration_s``
- §2 eqs 5-9, 13, TDI window: ``tdi_line_period_s``, ``turntable_line_period_s``,
  ``tdi_window`` -> ``TdiWindow``, ``synchronous_stage_speed_m_s``
- §6, velocity mismatch: ``velocity_mismatch`` (dV/V), ``line_mismatch`` (M dV/V per line)
- §2 eq 5 and §6 eq 9, synchronous motion: ``scan_speed`` -> ``ScanSpeed`` (the stage speed
  for a line period), ``synchronous_motion`` -> ``SyncSolution``, ``step_rate_hz``,
  ``turntable_angular_velocity_rad_s``
- §7, motion compensation on a full-frame CCD: ``image_velocity_m_s``,
  ``row_step_interval_s``, ``electrode_step_interval_s``, ``row_step_modulation``,
  ``electrode_step_modulation`` and their means over the offset
- §3, HR400 sequencer: ``sequencer_line_period_s``, ``exposure_s``, ``sequencer_frame_time_s``,
  ``sequencer_frame_period_lines``, ``sequencer_frame_period_s``
"""

from camd.timing.imc import (
    electrode_step_interval_s,
    electrode_step_modulation,
    image_velocity_m_s,
    mean_electrode_step_modulation,
    mean_row_step_modulation,
    row_step_interval_s,
    row_step_modulation,
)
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
from camd.timing.sync import (
    ScanSpeed,
    SyncSolution,
    line_mismatch,
    scan_speed,
    step_rate_hz,
    synchronous_motion,
    turntable_angular_velocity_rad_s,
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
    "ScanSpeed",
    "SyncSolution",
    "TdiWindow",
    "electrode_step_interval_s",
    "electrode_step_modulation",
    "exposure_s",
    "global_frame_time_s",
    "image_velocity_m_s",
    "line_mismatch",
    "max_rolling_integration_s",
    "mean_electrode_step_modulation",
    "mean_row_step_modulation",
    "rolling_frame_time_s",
    "rolling_line_period_s",
    "row_step_interval_s",
    "row_step_modulation",
    "scan_speed",
    "sequencer_frame_period_lines",
    "sequencer_frame_period_s",
    "sequencer_frame_time_s",
    "sequencer_line_period_s",
    "step_rate_hz",
    "synchronous_motion",
    "synchronous_stage_speed_m_s",
    "tdi_line_period_s",
    "tdi_window",
    "turntable_angular_velocity_rad_s",
    "turntable_line_period_s",
    "velocity_mismatch",
]
