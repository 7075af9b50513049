"""The sensor (docs/api.md, docs/lvds.md): its registers, the timing they set, LVDS training."""

from __future__ import annotations

from fastapi import APIRouter

from camd.daemon.models import (
    RegisterConfig,
    RegisterDiffRequest,
    RegisterDiffResponse,
    RegisterReading,
    RegistersResponse,
    RegisterWriteRequest,
    RegisterWriteResponse,
    TimingResponse,
    TrainResponse,
)
from camd.daemon.request_guard import API
from camd.daemon.routes.deps import Session, needs_control

router = APIRouter(prefix=API, tags=["sensor"])


@router.get("/registers", response_model=RegistersResponse)
def get_registers(session: Session) -> RegistersResponse:
    """Every sensor register, read from the device (write-only ones from the host's copy)."""
    return session.sensor.dump()


@router.post(
    "/registers",
    response_model=RegisterWriteResponse,
    dependencies=[needs_control("write sensor registers")],
)
def post_registers(session: Session, body: RegisterWriteRequest) -> RegisterWriteResponse:
    """Write registers by name: all validated first (nothing written if one is invalid),
    sent in one burst, read back and verified."""
    return session.sensor.write(dict(body.values))


@router.post("/registers/diff", response_model=RegisterDiffResponse)
def post_registers_diff(
    session: Session, body: RegisterDiffRequest | None = None
) -> RegisterDiffResponse:
    """Registers that differ from their reset values or from the given values."""
    body = body or RegisterDiffRequest()
    return session.sensor.diff(body.against, body.values)


@router.get("/registers/config", response_model=RegisterConfig)
def get_register_config(session: Session) -> RegisterConfig:
    """The whole configuration (RW and WO non-volatile registers), for `camctl reg save`."""
    return session.sensor.configuration()


@router.put(
    "/registers/config",
    response_model=RegisterWriteResponse,
    dependencies=[needs_control("load a register configuration")],
)
def put_register_config(session: Session, body: RegisterConfig) -> RegisterWriteResponse:
    """Load a whole configuration: refused whole if invalid or for another sensor."""
    return session.sensor.load_configuration(body)


# After /registers/config and /registers/diff: the first route whose path matches answers.
@router.get("/registers/{key}", response_model=RegisterReading)
def get_register(session: Session, key: str) -> RegisterReading:
    """One register by name (case-insensitive) or address (0x10 or 16)."""
    return session.sensor.read(key)


@router.get("/timing", response_model=TimingResponse)
def get_timing(session: Session) -> TimingResponse:
    """Line period, exposure, frame time and window, from the sensor's registers."""
    return session.sensor.timing()


@router.post(
    "/train", response_model=TrainResponse, dependencies=[needs_control("train the sensor link")]
)
def post_train(session: Session) -> TrainResponse:
    """Train the sensor's LVDS link now; ``trained`` says whether it locked error-free."""
    return session.sensor.train()


@router.get("/train", response_model=TrainResponse)
def get_train(session: Session) -> TrainResponse:
    """The last training result (no device traffic)."""
    return session.sensor.last_training()
