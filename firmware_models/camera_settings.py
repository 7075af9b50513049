"""What the sensor's registers set for the simulated camera's renders (``CameraModel.settings``).

The window, the timing, the shutter, the system gain and black level, image motion
compensation and a test pattern's frame, worked out once per register version: reading a
register goes through the register map's pydantic models, about a tenth of a small frame's
time when it was done per frame (docs/simulator.md, "Speed").
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from camd.sensor.profile import SHUTTERS, CameraProfile
from camd.sensor.timing_view import SensorTiming
from camd.timing.imc import IMC_MODES, ImcMode
from firmware_models.lvds import DEFAULT_TRAINING_WORD, TestPattern, pattern_frame
from firmware_models.render_kernels import Readout
from firmware_models.sensor import SensorModel

Array = npt.NDArray[Any]


@dataclass(frozen=True, slots=True)
class RegisterSettings:
    """What the sensor's registers set for a render, worked out once per register version
    (reading a register goes through the register map's pydantic models: about a tenth of a
    small frame's time when it was done per frame)."""

    window: tuple[int, int, int, int]  # first row, rows, first column, columns (array indices)
    timing: SensorTiming
    shutter: str
    gain_dn_per_e: float
    black_dn: float
    imc: tuple[ImcMode, float, int]
    test_pattern: Array | None  # the frame a test pattern sends instead of pixels (read-only)
    readout: Readout


def work_out_settings(p: CameraProfile, sensor: SensorModel) -> RegisterSettings:
    """What the registers of ``sensor`` set for a render of camera ``p``, from the registers
    themselves."""
    regmap = sensor.regmap
    timing = sensor.timing()
    mode = sensor.readout_mode if regmap.role("readout_mode") else None
    shutter = mode if isinstance(mode, str) and mode in SHUTTERS else p.shutter.value
    gain = sensor.gain if regmap.role("gain") else None
    gain_dn_per_e = p.system_gain_dn_per_e(p.analog_gain_factor(gain))
    offset = sensor.offset if regmap.role("offset") else None
    black_dn = p.black_level_for(offset)
    window = _window(sensor, timing)
    pattern = _test_pattern(p, sensor, window[1], window[3])
    if pattern is not None:
        pattern.flags.writeable = False  # shared by every frame of the settings
    return RegisterSettings(
        window=window,
        timing=timing,
        shutter=shutter,
        gain_dn_per_e=gain_dn_per_e,
        black_dn=black_dn,
        imc=_imc(sensor),
        test_pattern=pattern,
        readout=Readout(
            read_variance_e2=p.read_noise_e.value**2,
            full_well_e=p.full_well_e.value,
            gain_dn_per_e=gain_dn_per_e,
            black_dn=black_dn,
            adc_max_dn=p.adc_max_dn,
            shift_bits=p.output_shift_bits,
        ),
    )


def _test_pattern(p: CameraProfile, sensor: SensorModel, rows: int, cols: int) -> Array | None:
    """The frame a test pattern setting sends instead of pixels, or None for pixels."""
    regmap = sensor.regmap
    if regmap.role("test_pattern") is None:
        return None
    setting = sensor.test_pattern
    if setting in ("off", 0):
        return None
    bits = p.output_bits.value
    if setting == "test_data" and regmap.has_register("TEST_DATA"):
        # MT9M001: the sensor repeats the TEST_DATA register's value (mt9m001.toml).
        value = int(sensor.value("TEST_DATA")) & ((1 << bits) - 1)
        return np.full((rows, cols), value, dtype=np.uint16)
    name = setting.upper() if isinstance(setting, str) else ""
    kind = TestPattern[name] if name in TestPattern.__members__ else TestPattern.RAMP
    word_name = regmap.role("training_word")
    word = DEFAULT_TRAINING_WORD if word_name is None else int(sensor.value(word_name))
    frame = pattern_frame(
        kind,
        rows,
        cols,
        word_bits=bits,
        lanes=regmap.output.lanes,
        training_word=word & ((1 << bits) - 1),
    )
    assert frame is not None  # OFF was handled above
    return frame


def _window(sensor: SensorModel, timing: SensorTiming) -> tuple[int, int, int, int]:
    """(first row, rows, first column, columns) of the registers' window, array indices."""
    regmap = sensor.regmap
    row0 = timing.window_start_row - regmap.first_row
    col_start = regmap.role_count("window_start_column", sensor.value)
    col0 = 0 if col_start is None else col_start - regmap.first_column
    cols = regmap.role_count("window_columns", sensor.value) or regmap.columns
    rows = timing.window_rows
    if row0 < 0 or row0 + rows > regmap.rows or col0 < 0 or col0 + cols > regmap.columns:
        raise ValueError(
            f"window rows {row0}..{row0 + rows - 1}, columns {col0}..{col0 + cols - 1} "
            f"(array indices) leave the {regmap.rows} x {regmap.columns} array; move or "
            "shrink the window"
        )
    return row0, rows, col0, cols


def _imc(sensor: SensorModel) -> tuple[ImcMode, float, int]:
    """``CameraModel.imc`` for the registers of ``sensor``."""
    regmap = sensor.regmap
    if not regmap.has_register("IMC_CTRL"):
        return "none", math.inf, 1
    mode = sensor.value("IMC_CTRL.mode")
    if mode not in IMC_MODES:
        raise ValueError(f"IMC_CTRL.mode is {mode!r}; the map must name none, row, electrode")
    interval_s = int(sensor.value("IMC_STEP")) / regmap.timing.clock_hz
    phases = int(sensor.value("IMC_PHASES"))
    return mode, interval_s, phases
