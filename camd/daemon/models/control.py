"""Bodies of status and control (docs/api.md): the status document, the controlling client,
the emergency stop, the imaging mode."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, Field, ValidationInfo, field_validator

from camd.daemon.models.common import Mode, _Request

StateName = Literal["disconnected", "idle", "streaming", "fault"]


ACTIVITY_TEXT_MAX = 200


class LinkInfo(BaseModel):
    """The link part of the status."""

    port: str = Field(description="serial device, pyserial URL, or the simulator's pty link")
    connected: bool
    last_error: str | None = Field(default=None, description="why the port is not open")
    sim_pid: int | None = Field(
        default=None, description="pid of the simulator this daemon spawned, while it runs"
    )
    sim_state: Literal["running", "restarting", "exited", "gave_up"] | None = Field(
        default=None,
        description="the spawned simulator: running, restarting (it died; waiting out the "
        "backoff or starting again), exited (not restarted: sim.restart = false), gave_up (too "
        "many failures in a row); null on hardware",
    )
    sim_restarts: int | None = Field(
        default=None,
        description="times the daemon restarted its simulator after it died; null on hardware",
    )


class DeviceStatus(BaseModel):
    """GET_STATUS fields, as the device reported them."""

    mode: Mode
    device_state: Literal["idle", "busy", "fault"]
    fault_code: int = Field(description="error code of the active fault, 0 if none")
    uptime_s: float = Field(description="time since power-on or RESET")
    fw_version: int = Field(description="firmware version, major * 256 + minor")
    boot_count: int


class DaemonInfo(BaseModel):
    """The daemon process."""

    version: str
    pid: int
    uptime_s: float
    scheduling: dict[str, str] = Field(
        description="what each of the threads the hardware waits on runs at, e.g. "
        '{"frame_reader": "SCHED_RR 10", "command_link": ..., "service_loop": ..., '
        '"closed_loop": ...} (each once it has run), and "why" one got no more than shown '
        "(docs/config.md, daemon.realtime)"
    )


class ControlActivity(BaseModel):
    """What the controlling client says it is doing (PUT /api/v1/control/activity)."""

    text: str = Field(description="e.g. 'campaign mtf: step 3/12 acquire scan_m8'")
    done: int | None = Field(description="steps done so far (null: not given)")
    total: int | None = Field(description="steps in all (null: not given)")
    t_s: float = Field(description="Unix time it was set")


class ControlInfo(BaseModel):
    """Who holds control of the camera (docs/api.md#control)."""

    holder: str | None = Field(description="the controlling client; null: nobody holds control")
    since_t_s: float | None = Field(description="Unix time the holder took control")
    why: str | None = Field(
        description="'lease' (taken with POST /api/v1/control), or the acquisition it started"
    )
    expires_t_s: float | None = Field(
        description="Unix time the lease ends unless renewed; null while an acquisition holds it"
    )
    you: str = Field(description="the client name this request was made under (X-Camd-Client)")
    activity: ControlActivity | None = Field(
        default=None,
        description="what the holder last said it is doing (PUT /api/v1/control/activity); "
        "null: nothing said, or control was given back or taken over since",
    )


class ControlRequest(_Request):
    """POST /api/v1/control: take (or renew) control."""

    ttl_s: float = Field(
        default=60.0, gt=0.0, le=86400.0, description="lease length; ask again to renew"
    )
    force: bool = Field(
        default=False, description="take control from another client (logged as an event)"
    )


class ActivityRequest(_Request):
    """PUT /api/v1/control/activity: what the controlling client is doing, for observers."""

    text: str = Field(
        min_length=1,
        max_length=ACTIVITY_TEXT_MAX,
        description=f"what it is doing, 1 to {ACTIVITY_TEXT_MAX} printable characters",
    )
    done: int | None = Field(default=None, ge=0, description="steps done so far")
    total: int | None = Field(default=None, ge=0, description="steps in all (>= done)")

    @field_validator("text")
    @classmethod
    def _printable(cls, text: str) -> str:
        if not text.isprintable():
            raise ValueError("text must be printable (no newlines, tabs or control characters)")
        return text

    @field_validator("total")
    @classmethod
    def _done_within_total(cls, total: int | None, info: ValidationInfo) -> int | None:
        done = info.data.get("done")
        if total is not None and done is not None and done > total:
            raise ValueError(f"done = {done} is more than total = {total}")
        return total


class AcquisitionInfo(BaseModel):
    """The acquisition slot's current or last acquisition."""

    kind: Literal["scan", "stare", "stream", "wheel"]
    description: str
    client: str = Field(description="who started it ('' for the daemon itself)")
    started_t_s: float
    ended_t_s: float | None = Field(description="null while it runs")
    running: bool


class EstopState(BaseModel):
    """GET /api/v1/estop, POST /api/v1/estop/release: the emergency-stop latch."""

    latched: bool = Field(
        description="true from an emergency stop until a client with control releases it: "
        "nothing moves or acquires meanwhile (409 estop_latched)"
    )
    since_t_s: float | None = Field(description="when this latch began (Unix time)")
    by: str | None = Field(description="the client that asked for the stop")
    last_t_s: float | None = Field(description="the newest emergency stop (Unix time)")
    stopped: list[str] = Field(description="what the newest stop stopped")
    failed: list[str] = Field(description="what it could not stop, with why")
    count: int = Field(description="emergency stops asked for on this data directory")
    released_t_s: float | None = Field(description="when the last latch was released")
    released_by: str | None = Field(description="who released it")
    how_to_release: str = Field(description="what to do to release it")


class BackendInfo(BaseModel):
    """How the daemon reaches one of the camera's interfaces (docs/hardware.md)."""

    kind: Literal["sim", "hardware"] = Field(
        description="the simulated camera's interface, or real hardware"
    )
    backend: Literal["sim", "serial", "libusb", "fpga", "usb-spi"] = Field(
        description="link: sim or serial; stream: sim or libusb; registers: fpga (REG_* over "
        "the link) or usb-spi (an MCP2210)"
    )
    detail: str = Field(description="the port, the socket or the USB id it uses")


class BackendsInfo(BaseModel):
    """The status's backends: which camera each interface talks to (docs/config.md, "Hardware
    or simulator")."""

    camera: Literal["sim", "hardware", "mixed"] = Field(
        description="all simulated, all hardware, or mixed (a config that sets a stream or "
        "bridge backend against its link)"
    )
    link: BackendInfo = Field(description="the RS-422 command link")
    stream: BackendInfo = Field(description="the USB frame stream")
    registers: BackendInfo = Field(description="the sensor's register bridge")


class StatusResponse(BaseModel):
    """GET /api/v1/status and POST /api/v1/reset."""

    state: StateName
    reason: str | None = Field(description="why the daemon is in this state (null when idle)")
    mode: Mode | None = Field(description="imaging mode last known, null before first contact")
    link: LinkInfo
    device: DeviceStatus | None = Field(description="null when the device cannot be asked")
    daemon: DaemonInfo
    control: ControlInfo
    acquisition: AcquisitionInfo | None = Field(
        description="the running acquisition, or the last started one (null before the first)"
    )
    estop: EstopState = Field(description="the emergency-stop latch")
    backends: BackendsInfo = Field(description="simulated or real: each interface's backend")


class EstopResponse(BaseModel):
    """POST /api/v1/estop: what the emergency stop did, and the latch it set."""

    stopped: list[str] = Field(
        description="what was stopped (stage, acquisition, wheel, campaign job)"
    )
    failed: list[str] = Field(description="what could not be stopped, with why")
    latch: EstopState


class ModeRequest(_Request):
    """POST /api/v1/mode."""

    mode: Mode = Field(description="area (staring, for focusing) or tdi (push-broom)")


class ModeResponse(BaseModel):
    """POST /api/v1/mode."""

    mode: Mode
