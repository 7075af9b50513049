"""Bodies of the scan stage's routes (docs/motion.md)."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, Field

from camd.daemon.models.common import _Request


class StageReadingModel(BaseModel):
    """The scan stage at one device time (SI: m, m/s)."""

    state: str = Field(description="disabled, idle, ramping, running, moving, homing, estop")
    homed: bool
    position_m: float = Field(description="commanded position (step count)")
    encoder_m: float = Field(description="measured position (encoder)")
    speed_m_s: float = Field(description="commanded speed now, ramps included")
    encoder_speed_m_s: float = Field(description="the encoder's speed over the last 10 ms")
    at_limit: str = Field(description="none, low or high: a soft limit the stage stands at")
    time_s: float = Field(description="device time of the sample")


class StageLimitsModel(BaseModel):
    """Soft travel limits, speed limit and ramp acceleration in force."""

    low_m: float
    high_m: float
    max_speed_m_s: float
    accel_m_s2: float


class StageOperationModel(BaseModel):
    """The last move or homing started through the API, for a client to follow it
    (docs/motion.md, "Waiting for a move or a homing"). Times are the device's clock."""

    seq: int = Field(description="numbers the moves and homings since the daemon started")
    kind: Literal["move", "home"] = Field(description="move (to target_m) or home")
    active: bool = Field(
        description="still under way: the stage is moving (homing) for this operation"
    )
    start_m: float = Field(description="commanded position when it started")
    target_m: float | None = Field(description="move: the target; home: null (0 once homed)")
    speed_m_s: float = Field(description="move: cruise speed; home: the homing speed")
    expected_duration_s: float = Field(description="the device's estimate of its duration")
    started_time_s: float = Field(description="device time when it started")
    elapsed_s: float = Field(description="device time since it started, at this reading")
    remaining_s: float = Field(description="expected_duration_s - elapsed_s, at least 0")
    fraction_done: float = Field(
        description="0..1: move, distance covered of the whole; home, time elapsed of the "
        "expected (1 once finished)"
    )


class MotionStatus(BaseModel):
    """GET /api/v1/motion: the stage, its limits and the synchronisation settings."""

    profile: str = Field(description="config/stages/<profile>.toml")
    kind: str = Field(description="linear or turntable")
    reading: StageReadingModel
    limits: StageLimitsModel
    closed_loop: str = Field(description="what a scan's closed loop trims, or off")
    yellow: float = Field(description="M |dV/V| yellow limit")
    red: float = Field(description="M |dV/V| red limit")
    operation: StageOperationModel | None = Field(
        default=None,
        description="the last move or homing started through the API (null: none since the "
        "daemon started, or a scan or a jog took the stage since)",
    )


class MotionEnableRequest(_Request):
    """POST /api/v1/motion/enable."""

    on: bool = Field(default=True, description="energise (true) or release (false) the motor")


class MotionRunRequest(_Request):
    """POST /api/v1/motion/run: hold a constant signed speed."""

    speed_m_s: float = Field(ge=-10.0, le=10.0, description="signed speed; 0 stops")


class MotionMoveRequest(_Request):
    """POST /api/v1/motion/move: go to a position and stop."""

    position_m: float = Field(ge=-100.0, le=100.0, description="target, metres from home")
    speed_m_s: float | None = Field(
        default=None, gt=0.0, le=10.0, description="cruise speed; null = the speed limit"
    )
    wait: bool = Field(
        default=True,
        description="answer once the stage has stopped (kept for old clients: a long move "
        "holds the request; false answers at once, then poll GET /api/v1/motion)",
    )


class MotionHomeRequest(_Request):
    """POST /api/v1/motion/home."""

    wait: bool = Field(
        default=True,
        description="answer once homing has finished (kept for old clients; false answers at "
        "once, then poll GET /api/v1/motion)",
    )


class SyncResponse(BaseModel):
    """GET /api/v1/motion/sync: the open-loop synchronisation (docs/physics.md §2 eqs 5-9, 13; §6).

    The first ten keys are the contract of ``camctl sync --json``.
    """

    line_period_s: float = Field(description="TDI line period")
    row_time_s: float = Field(description="rolling line period T_line,roll (eq 4)")
    n_lines: int = Field(description="window rows (eq 8)")
    back_path_s: float = Field(description="back path (eq 9)")
    m0: int = Field(description="largest stage count (eq 13)")
    stages: int = Field(description="M")
    sync_speed: float = Field(description="synchronous stage speed, m/s (§6 eq 9)")
    step_rate_hz: float = Field(description="stepper rate for it, microsteps/s")
    dv_over_v: float = Field(description="mismatch of the stage speed given, (V - V_m)/V")
    m_dv_over_v: float = Field(description="M dV/V: smear over M stages, pixels")
    image_speed_m_s: float = Field(description="image speed on the focal plane at sync speed")
    stage_speed_m_s: float = Field(description="the stage speed the mismatch is for")
    stage_profile: str
    image_scale: float = Field(description="focal-plane metres per metre of stage travel")
    pixel_pitch_m: float = Field(description="pitch on the focal plane (doubled when binned)")
    angular_velocity_rad_s: float | None = Field(
        description="turntable only: table speed for the line period (eq 5)"
    )
    tolerance_ok: bool = Field(description="|M dV/V| within the yellow limit")
