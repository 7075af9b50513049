"""The simulated camera (docs/simulator.md): scene, seed, ideal stage, stage faults, failures
on purpose, the polariser, and what the daemon set. On hardware each change is a 400."""

from __future__ import annotations

from fastapi import APIRouter, Response

from camd.daemon.models import (
    PolarizerRequest,
    SceneRequest,
    SeedRequest,
    SimFailNextRequest,
    SimSettings,
    SimStageFaultsRequest,
    SimStageTruth,
    SimStreamStats,
    StageRequest,
    StageResponse,
)
from camd.daemon.request_guard import API
from camd.daemon.routes.deps import Session, needs_control

router = APIRouter(prefix=f"{API}/sim", tags=["simulator"])


@router.put(
    "/polarizer",
    status_code=204,
    dependencies=[needs_control("change the simulated polariser")],
)
def put_sim_polarizer(session: Session, body: PolarizerRequest) -> Response:
    """Simulated camera only: the reference polariser in front of the scene (docs/wheel.md);
    ``angle_deg`` null takes it out."""
    session.sim.set_polarizer(body.angle_deg)
    return Response(status_code=204)


@router.put(
    "/stage/faults",
    status_code=204,
    dependencies=[needs_control("change the simulated stage's faults")],
)
def put_sim_stage_faults(session: Session, body: SimStageFaultsRequest) -> Response:
    """Simulated camera only: the stepper stage's imperfections (as --inject stage_*)."""
    session.sim.set_stage_faults(body)
    return Response(status_code=204)


@router.get("/stage/truth", response_model=SimStageTruth)
def get_sim_stage_truth(session: Session) -> SimStageTruth:
    """Simulated camera only: the stage's true position, velocity and missed steps."""
    return session.sim.stage_truth()


@router.put("/scene", status_code=204, dependencies=[needs_control("change the simulated scene")])
def put_sim_scene(session: Session, body: SceneRequest) -> Response:
    """Simulated camera only: the scene in front of it (docs/simulator.md)."""
    session.sim.set_scene(body.spec)
    return Response(status_code=204)


@router.put("/seed", status_code=204, dependencies=[needs_control("re-seed the simulator")])
def put_sim_seed(session: Session, body: SeedRequest) -> Response:
    """Simulated camera only: restart the temporal noise and frame-fault random streams
    from ``seed`` (the fixed pattern is kept), so a repeated step sees the same noise."""
    session.sim.set_seed(body.seed)
    return Response(status_code=204)


@router.put(
    "/stage",
    response_model=StageResponse,
    dependencies=[needs_control("change the simulator's ideal stage")],
)
def put_sim_stage(session: Session, body: StageRequest) -> StageResponse:
    """Simulated camera only: the scan stage tracks the synchronous speed or runs at a set
    speed (any difference from synchronous is velocity mismatch)."""
    return session.sim.set_ideal_stage(track=body.track, speed_m_s=body.speed_m_s)


@router.post(
    "/fail-next",
    status_code=204,
    dependencies=[needs_control("make a simulated command fail")],
)
def post_sim_fail_next(session: Session, body: SimFailNextRequest) -> Response:
    """Simulated camera only: make the (skip + 1)-th next ``command`` fail, refused with a
    NAK of ``error`` or lost to a dropped line for ``duration_s`` (to test recovery)."""
    session.sim.fail_next(body)
    return Response(status_code=204)


@router.delete(
    "/fail-next",
    status_code=204,
    dependencies=[needs_control("make a simulated command fail")],
)
def delete_sim_fail_next(session: Session) -> Response:
    """Simulated camera only: disarm a failure armed with POST (harmless when none is)."""
    session.sim.clear_fail_next()
    return Response(status_code=204)


@router.get("", response_model=SimSettings)
def get_sim(session: Session) -> SimSettings:
    """What this daemon last set on the simulated camera: scene, ideal stage, polariser,
    stage faults (``available`` false on hardware)."""
    return session.sim.settings()


@router.get("/stream", response_model=SimStreamStats)
def get_sim_stream(session: Session) -> SimStreamStats:
    """Simulated camera only: frames its stream engine made, sent and damaged on purpose."""
    return session.sim.stream_stats()
