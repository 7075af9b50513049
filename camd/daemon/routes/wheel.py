"""The filter wheel (docs/wheel.md): speed, delay compensation, wheel acquisitions."""

from __future__ import annotations

from fastapi import APIRouter

from camd.daemon.models import (
    WheelAcquireRequest,
    WheelAcquireResponse,
    WheelCompensationRequest,
    WheelSpeedRequest,
    WheelStatus,
)
from camd.daemon.request_guard import API
from camd.daemon.routes.deps import Session, needs_control

router = APIRouter(prefix=f"{API}/wheel", tags=["wheel"])


@router.get("", response_model=WheelStatus)
def get_wheel(session: Session) -> WheelStatus:
    """The filter wheel: speed, angle, compensation, and camd's T_frame / T_delay / fit /
    imaging-centre offset and eq-8 uncertainty for the exposure in the registers."""
    return session.wheel.status()


@router.put(
    "/speed",
    response_model=WheelStatus,
    dependencies=[needs_control("change the filter wheel's speed")],
)
def put_wheel_speed(session: Session, body: WheelSpeedRequest) -> WheelStatus:
    """Turn the wheel at a constant speed (0 stops it); legal only when idle."""
    return session.wheel.set_speed(body.speed_deg_s)


@router.put(
    "/compensation",
    response_model=WheelStatus,
    dependencies=[needs_control("change the wheel's delay compensation")],
)
def put_wheel_compensation(session: Session, body: WheelCompensationRequest) -> WheelStatus:
    """Exposure delay compensation on or off (docs/physics.md §4 eq 5); switching on is
    refused (400, with the numbers) when the exposure in the registers cannot fit."""
    return session.wheel.set_compensation(body.on)


@router.post(
    "/acquire",
    response_model=WheelAcquireResponse,
    dependencies=[needs_control("start a wheel acquisition")],
)
def post_wheel_acquire(session: Session, body: WheelAcquireRequest) -> WheelAcquireResponse:
    """One frame per channel per pass, each started by its channel's entry pulse (plus
    T_delay with compensation); returns when done, with each frame's imaging-centre angle,
    its uncertainty (eq 8) and mean signal. Out-of-window exposures are refused (400)
    before anything is written."""
    return session.wheel.acquire(body)
