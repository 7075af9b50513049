"""The timing a sensor's registers set: line period, exposure, frame time, TDI line period.

Pure: ``sensor_timing`` takes the register map and a function that gives the value of a value
name (``REG``, ``REG.field`` or ``GROUP``, as ``RegisterMap.value_of`` computes it from some
source of raw register values: the device, the host's shadow copy, the simulated sensor) and
computes everything with the equations of ``camd.timing``, so that each exists once:

- line period ``T_line``: ``sequencer`` model, ``clocks_per_line / clock_hz`` (docs/physics.md §3);
  ``row_blanking`` model, ``t_rb + n_pixels / f_s`` (docs/physics.md §2 eq 4);
- exposure ``n * T_line + T_RES`` (§3); first-frame time ``(n + k + 1) T_line`` (§3, §4 eq 6);
- frame period in continuous imaging ``max(k, n + 1)`` lines plus the back path, which is the
  TDI line period (§2 eqs 6-7: ``T_frm + T_back = T_line,TDI``); ``M0 = k`` stages (§2 eq 13).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from pydantic import BaseModel, ConfigDict, Field

from camd.sensor.regmap import RegisterMap, RegisterValueError
from camd.timing import (
    exposure_s,
    rolling_line_period_s,
    sequencer_frame_period_s,
    sequencer_frame_time_s,
    sequencer_line_period_s,
)

ValueOf = Callable[[str], int | str]


class SensorTiming(BaseModel):
    """What the sensor's registers make of its timing (SI units; JSON-ready via ``as_dict``).

    A frozen pydantic model, so that the API's answer (``camd.daemon.models.TimingResponse``)
    is this model under its own name rather than a copy of its fields.
    """

    model_config = ConfigDict(frozen=True)

    sensor: str
    line_period_s: float
    window_start_row: int
    window_rows: int
    exposure_lines: int
    exposure_s: float
    frame_time_s: float
    frame_period_s: float
    back_path_s: float
    tdi_line_period_s: float
    max_stages: int
    # The settings the map gives a role to (null: it has none).
    gain: int | str | None = None
    offset: int | str | None = None
    readout_mode: int | str | None = None
    test_pattern: int | str | None = None
    exposure_register: str | None = Field(
        default=None,
        description="the register (or REG.field) that sets exposure_lines: write it with "
        "POST /api/v1/registers to change the exposure",
    )

    def as_dict(self) -> dict[str, Any]:
        """Plain JSON-ready values, keyed by field name."""
        return self.model_dump()


def _required(regmap: RegisterMap, role: str, value: ValueOf) -> int:
    count = regmap.role_count(role, value)
    if count is None:
        raise RegisterValueError(
            f"sensor {regmap.sensor}'s register map has no {role} role; add it to [roles] "
            f"in config/sensors/{regmap.sensor}.toml"
        )
    return count


def _setting(regmap: RegisterMap, role: str, value: ValueOf) -> int | str | None:
    name = regmap.role(role)
    return None if name is None else value(name)


def _clocks_s(regmap: RegisterMap, role: str, value: ValueOf) -> float:
    """A duration role counted in clocks of ``timing.clock_hz``, in seconds (0 when absent)."""
    count = regmap.role_count(role, value)
    return 0.0 if count is None else count / regmap.timing.clock_hz


def line_period_s(regmap: RegisterMap, value: ValueOf) -> float:
    """The row time ``T_line`` the registers set (model per ``regmap.timing``)."""
    spec = regmap.timing
    if spec.model == "sequencer":
        clocks = regmap.role_count("line_clocks", value)
        if clocks is None:
            clocks = spec.clocks_per_line
        assert clocks is not None  # the map validator requires one of the two
        return sequencer_line_period_s(spec.clock_hz, clocks)
    blanking = regmap.role_count("row_blanking", value) or 0
    # The MT9M001 takes horizontal blanking values below its minimum as the minimum.
    blanking_clocks = spec.fixed_row_overhead_clocks + max(blanking, spec.row_blanking_min_clocks)
    n_pixels = regmap.role_count("window_columns", value)
    if n_pixels is None:
        n_pixels = regmap.columns
    return rolling_line_period_s(
        blanking_clocks / spec.clock_hz, n_pixels, spec.clock_hz * spec.pixels_per_clock
    )


def sensor_timing(regmap: RegisterMap, value: ValueOf) -> SensorTiming:
    """The timing the registers set; ``value(name)`` gives a value name's current value.

    Raises RegisterValueError when the map lacks a role the timing needs (window start row,
    window rows, exposure lines), and ValueError (from ``camd.timing``) for values the
    equations refuse (e.g. a zero-row window).
    """
    start = _required(regmap, "window_start_row", value)
    rows = _required(regmap, "window_rows", value)
    lines = _required(regmap, "exposure_lines", value)
    t_line = line_period_s(regmap, value)
    back_s = _clocks_s(regmap, "back_path", value)
    period_s = sequencer_frame_period_s(lines, rows, t_line) + back_s
    return SensorTiming(
        sensor=regmap.sensor,
        line_period_s=t_line,
        window_start_row=start,
        window_rows=rows,
        exposure_lines=lines,
        exposure_s=exposure_s(lines, t_line, regmap.timing.exposure_remainder_s),
        frame_time_s=sequencer_frame_time_s(lines, rows, t_line),
        frame_period_s=period_s,
        back_path_s=back_s,
        tdi_line_period_s=period_s,
        max_stages=rows,
        gain=_setting(regmap, "gain", value),
        offset=_setting(regmap, "offset", value),
        readout_mode=_setting(regmap, "readout_mode", value),
        test_pattern=_setting(regmap, "test_pattern", value),
        exposure_register=regmap.role("exposure_lines"),
    )


def reset_timing(regmap: RegisterMap) -> SensorTiming:
    """The timing at the registers' reset values (what a freshly powered sensor does)."""
    return sensor_timing(regmap, lambda name: regmap.value_of(name, lambda reg: reg.reset))
