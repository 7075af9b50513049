"""The scan stage (docs/motion.md): enable, run, move, stop, home, estop, the synchronous
solution. Stop and estop need no control: stopping is never refused."""

from __future__ import annotations

from fastapi import APIRouter, Query

from camd.daemon.models import (
    MotionEnableRequest,
    MotionHomeRequest,
    MotionMoveRequest,
    MotionRunRequest,
    MotionStatus,
    SyncResponse,
)
from camd.daemon.request_guard import API
from camd.daemon.routes.deps import Session, needs_control

router = APIRouter(prefix=f"{API}/motion", tags=["motion"])


@router.get("", response_model=MotionStatus)
def get_motion(session: Session) -> MotionStatus:
    """The scan stage: state, positions, speeds, limits, synchronisation settings."""
    return session.motion.status()


@router.post(
    "/enable",
    response_model=MotionStatus,
    dependencies=[needs_control("enable or release the stage")],
)
def post_motion_enable(session: Session, body: MotionEnableRequest) -> MotionStatus:
    """Energise the motor (programs the configured limits first; clears an estop) or
    release it."""
    return session.motion.enable(body.on)


@router.post("/run", response_model=MotionStatus, dependencies=[needs_control("run the stage")])
def post_motion_run(session: Session, body: MotionRunRequest) -> MotionStatus:
    """Ramp to a constant signed speed and hold it (0 stops)."""
    return session.motion.run(body.speed_m_s)


@router.post("/move", response_model=MotionStatus, dependencies=[needs_control("move the stage")])
def post_motion_move(session: Session, body: MotionMoveRequest) -> MotionStatus:
    """Move to a position (metres from home) and stop; waits unless ``wait`` is false."""
    return session.motion.move(body)


@router.post("/stop", response_model=MotionStatus)
def post_motion_stop(session: Session) -> MotionStatus:
    """Decelerate to a stop. Legal while streaming."""
    return session.motion.stop()


@router.post("/home", response_model=MotionStatus, dependencies=[needs_control("home the stage")])
def post_motion_home(session: Session, body: MotionHomeRequest | None = None) -> MotionStatus:
    """Find the home switch and zero the position there."""
    return session.motion.home((body or MotionHomeRequest()).wait)


@router.post("/estop", response_model=MotionStatus)
def post_motion_estop(session: Session) -> MotionStatus:
    """Emergency stop: no ramp, motor current cut, until /motion/enable."""
    return session.motion.emergency_stop()


@router.get("/sync", response_model=SyncResponse)
def get_motion_sync(
    session: Session,
    line_period_s: float | None = Query(default=None, gt=0.0, le=10.0),
    speed_m_s: float | None = Query(default=None, gt=0.0, le=10.0),
    stages: int | None = Query(default=None, ge=1, le=4096),
    binning: bool = False,
) -> SyncResponse:
    """Open-loop synchronisation (docs/physics.md §2 eqs 5-9, 13; §6 eq 9) for a line period, a
    stage speed, both (their mismatch), or neither (the registers' line period)."""
    return session.motion.sync(
        line_period_s=line_period_s, speed_m_s=speed_m_s, stages=stages, binning=binning
    )
