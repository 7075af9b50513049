"""Bodies of the simulated camera's routes (docs/simulator.md): scene, seed, ideal stage, stage
faults, failures on purpose, polariser."""

from __future__ import annotations

from pydantic import BaseModel, Field

from camd.daemon.models.common import _Request


class SceneRequest(_Request):
    """PUT /api/v1/sim/scene."""

    spec: str = Field(min_length=1, max_length=240, description="scene spec, e.g. 'bars:lux=3'")


class SeedRequest(_Request):
    """PUT /api/v1/sim/seed."""

    seed: int = Field(ge=0, le=0xFFFFFFFF, description="seed of the restarted random streams")


class StageRequest(_Request):
    """PUT /api/v1/sim/stage."""

    track: bool = Field(default=True, description="follow the synchronous speed")
    speed_m_s: float = Field(default=0.0, ge=0.0, le=10.0, description="speed when not tracking")


class StageResponse(BaseModel):
    speed_m_s: float
    sync_speed_m_s: float
    track: bool


class SimStreamStats(BaseModel):
    """GET /api/v1/sim/stream: what the simulated camera's stream engine did and injected."""

    produced: int
    sent: int
    dropped: int
    corrupted: int
    shortened: int
    stalls: int
    undelivered: int


class SimStageFaultsRequest(_Request):
    """PUT /api/v1/sim/stage/faults: the simulated stage's imperfections."""

    error: float = Field(default=0.0, ge=-0.1, le=0.1, description="relative step-rate error")
    ripple: float = Field(default=0.0, ge=0.0, le=0.2, description="relative ripple amplitude")
    jitter: float = Field(default=0.0, ge=0.0, le=0.2, description="relative RMS speed jitter")
    drift: float = Field(default=0.0, ge=-0.1, le=0.1, description="relative drift per second")
    load: float = Field(default=0.0, ge=0.0, le=3.0, description="load / pull-out torque")


class SimFailNextRequest(_Request):
    """POST /api/v1/sim/fail-next: make one coming command fail (SIM_FAIL_NEXT), with a NAK
    (``error``), a dropped line (``duration_s``), or a stream the camera ends early
    (``end_after_frames``)."""

    command: str = Field(
        min_length=1, max_length=40, description="the command to fail, e.g. REG_WRITE_BURST"
    )
    skip: int = Field(
        default=0, ge=0, le=65535, description="commands of that kind to let through first"
    )
    error: str | None = Field(
        default=None, description="answer it with a NAK of this error, e.g. BUSY (docs/protocol.md)"
    )
    duration_s: float | None = Field(
        default=None, gt=0.0, le=600.0, description="or: drop off the line for this long, s"
    )
    end_after_frames: int | None = Field(
        default=None,
        ge=0,
        le=0xFFFF_FFFF,
        description="or: the command (START_STREAM, WHEEL_ACQUIRE) executes, and the camera ends "
        "the stream it starts after this many frames (STREAM_DONE)",
    )


class SimStageTruth(BaseModel):
    """GET /api/v1/sim/stage/truth: what the simulated stage really does."""

    position_m: float
    velocity_m_s: float
    missed_steps: int
    time_s: float


class SimSettings(BaseModel):
    """GET /api/v1/sim: what this daemon last set on the simulated camera (the simulator
    cannot be asked), so that a client can put it back."""

    available: bool = Field(description="false on real hardware (every sim request is refused)")
    scene: str = Field(description="the scene spec in front of the camera")
    ideal_stage: StageRequest = Field(description="the ideal scan stage: track, or a speed")
    polarizer_deg: float | None = Field(description="reference polariser axis; null: out")
    stage_faults: SimStageFaultsRequest = Field(description="the stepper stage's imperfections")


class PolarizerRequest(_Request):
    """PUT /api/v1/sim/polarizer: the simulated scene's reference polariser."""

    angle_deg: float | None = Field(
        ge=0.0,
        le=360.0,
        description="transmission axis, deg; null takes the polariser out of the beam",
    )
