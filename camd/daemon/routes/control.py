"""Status and control (docs/api.md, "Control"): the status document, who holds control, the
emergency stop, the imaging mode and the camera's reset."""

from __future__ import annotations

from fastapi import APIRouter

from camd.daemon.models import (
    ActivityRequest,
    ControlInfo,
    ControlRequest,
    EstopResponse,
    EstopState,
    ModeRequest,
    ModeResponse,
    StatusResponse,
)
from camd.daemon.request_guard import API
from camd.daemon.routes.deps import Client, Session, needs_control

router = APIRouter(prefix=API)


@router.get("/status", response_model=StatusResponse, tags=["status"])
def get_status(session: Session, client: Client) -> StatusResponse:
    """State, reason, mode, link, the device's status, the daemon's identity, who holds
    control and the current or last acquisition."""
    return session.status(client)


@router.get("/control", response_model=ControlInfo, tags=["control"])
def get_control(session: Session, client: Client) -> ControlInfo:
    """Who holds control (no device traffic); reading never needs control."""
    return session.control_info(client)


@router.post("/control", response_model=ControlInfo, tags=["control"])
def post_control(
    session: Session, client: Client, body: ControlRequest | None = None
) -> ControlInfo:
    """Take control for ``ttl_s`` seconds, or renew it; 423 while another client holds
    it, unless ``force`` (a takeover, logged as an event)."""
    body = body or ControlRequest()
    session.take_control(client, body.ttl_s, force=body.force)
    return session.control_info(client)


@router.delete("/control", response_model=ControlInfo, tags=["control"])
def delete_control(session: Session, client: Client) -> ControlInfo:
    """Give control back (harmless when this client holds none)."""
    session.control.release(client)
    return session.control_info(client)


@router.put("/control/activity", response_model=ControlInfo, tags=["control"])
def put_control_activity(session: Session, client: Client, body: ActivityRequest) -> ControlInfo:
    """Say what the controlling client is doing (a campaign's step, with steps done and
    in all), for observers: it shows in the control document until control is given back,
    expires or is taken over. Only the holder may: 423 while another client holds
    control, 409 ``no_control`` while nobody does."""
    session.control.set_activity(client, body.text, body.done, body.total)
    return session.control_info(client)


@router.post("/estop", response_model=EstopResponse, tags=["control"])
def post_estop(session: Session, client: Client) -> EstopResponse:
    """Emergency stop of the stage (no ramp, current cut), the running acquisition, the
    filter wheel and a running campaign job (paused). Never refused, whoever asks and
    whatever holds control; it latches: nothing moves or acquires until a client with
    control releases it (``POST /api/v1/estop/release``)."""
    return session.estop.engage(client)


@router.get("/estop", response_model=EstopState, tags=["control"])
def get_estop(session: Session) -> EstopState:
    """The emergency-stop latch: whether it holds, since when, who asked, what was stopped."""
    return session.estop.state()


@router.post(
    "/estop/release",
    response_model=EstopState,
    tags=["control"],
    dependencies=[needs_control("release the emergency stop")],
)
def post_estop_release(session: Session, client: Client) -> EstopState:
    """Release the latch (needs control, or free control); the stage stays disabled and the
    wheel stopped until someone starts them. Harmless when not latched."""
    return session.estop.release(client)


@router.post(
    "/mode",
    response_model=ModeResponse,
    tags=["control"],
    dependencies=[needs_control("change the imaging mode")],
)
def post_mode(session: Session, body: ModeRequest) -> ModeResponse:
    """Select area (staring) or tdi (push-broom) imaging mode; legal only when idle."""
    return session.set_mode(body.mode)


@router.post(
    "/reset",
    response_model=StatusResponse,
    tags=["control"],
    dependencies=[needs_control("reset the camera")],
)
def post_reset(session: Session) -> StatusResponse:
    """Soft-reset the camera; clears a fault. Returns the status afterwards."""
    return session.reset()
