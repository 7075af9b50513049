"""Bodies of the sensor routes: registers, the timing they set, LVDS link training."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from camd.daemon.models.common import _Request
from camd.sensor.timing_view import SensorTiming

RegisterValue = int | str


class RegisterReading(BaseModel):
    """One register as read: raw value and its fields (enum fields by name)."""

    name: str
    address: int
    value: int
    fields: dict[str, RegisterValue]


class RegistersResponse(BaseModel):
    """GET /api/v1/registers: every register of the map, in address order."""

    sensor: str
    bridge: str
    registers: list[RegisterReading]


class RegisterWriteRequest(_Request):
    """POST /api/v1/registers: values by name (REG, REG.field or a group such as EXPOSURE)."""

    values: dict[str, RegisterValue] = Field(
        min_length=1, description="name -> raw integer (or enum name for an enum field)"
    )


class RegisterWriteResponse(BaseModel):
    """The registers written, as read back after the write (verified where the map allows)."""

    sensor: str
    written: list[RegisterReading]


class RegisterDiffRequest(_Request):
    """POST /api/v1/registers/diff: compare against reset values or given register values."""

    against: Literal["reset", "values"] = Field(default="reset")
    values: dict[str, int] | None = Field(
        default=None, description="register name -> expected raw value (with against = values)"
    )


class RegisterDifference(BaseModel):
    name: str
    address: int
    expected: int
    actual: int


class RegisterDiffResponse(BaseModel):
    sensor: str
    against: str
    differences: list[RegisterDifference]


class RegisterConfig(BaseModel):
    """A whole sensor configuration: the configurable (RW/WO, non-volatile) registers."""

    model_config = ConfigDict(extra="forbid", strict=True)  # as _Request: true is not 1

    sensor: str
    registers: dict[str, int]


class TimingResponse(SensorTiming):
    """GET /api/v1/timing: the sensor timing its registers set (docs/physics.md §2, §3)."""


class LaneResult(BaseModel):
    lane: int
    tap: int
    eye_width: int
    slips: int
    shift: int
    locked: bool


class TrainResponse(BaseModel):
    """POST/GET /api/v1/train: the last LVDS link training."""

    sensor: str
    interface: str
    trained: bool = Field(description="locked on every lane and the PRBS check error-free")
    lanes: int
    locked_lanes: int
    locked: bool
    bit_errors: int
    verified_bits: int
    lane_results: list[LaneResult]
    t_s: float | None = Field(
        description="Unix time of the last training; None if the daemon has not trained since it "
        "started (or the interface has nothing to train)"
    )
    lost_t_s: float | None = Field(
        description="Unix time the link lost that training (LINK_LOST, a camera restart): "
        "`trained` is then false and the rest describes the last training; None while it holds"
    )
    summary: str = Field(description="the link's training in one sentence")
