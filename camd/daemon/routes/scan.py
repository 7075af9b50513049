"""Push-broom scans with host TDI (docs/scan.md): start, follow, change M, stop."""

from __future__ import annotations

from fastapi import APIRouter

from camd.daemon.models import ScanRequest, ScanResponse, StagesRequest
from camd.daemon.request_guard import API
from camd.daemon.routes.deps import Session, needs_control

router = APIRouter(prefix=f"{API}/scan", tags=["scan"])


@router.get("", response_model=ScanResponse)
def get_scan(session: Session) -> ScanResponse:
    """The current or last scan: progress, counters, timing (state "none" before one)."""
    return session.scan.status()


@router.post("/start", response_model=ScanResponse, dependencies=[needs_control("start a scan")])
def post_scan_start(session: Session, body: ScanRequest) -> ScanResponse:
    """Start a push-broom scan with host TDI and return at once (docs/scan.md)."""
    return session.scan.start(body)


@router.post("/stop", response_model=ScanResponse, dependencies=[needs_control("stop the scan")])
def post_scan_stop(session: Session) -> ScanResponse:
    """Stop the running scan and return once its file is closed. Harmless when idle."""
    return session.scan.stop()


@router.put(
    "/stages",
    response_model=ScanResponse,
    dependencies=[needs_control("change the scan's stages")],
)
def put_scan_stages(session: Session, body: StagesRequest) -> ScanResponse:
    """Change the TDI stage count of the running scan from its next frame."""
    return session.scan.set_stages(body.stages)
