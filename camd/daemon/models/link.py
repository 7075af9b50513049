"""Bodies of the command link's routes: PING, raw COMMAND frames, the link counters."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, Field

from camd.daemon.models.common import _Request

PING_COUNT_MAX = 100_000


PING_SIZE_MAX = 256


class LinkCommandRequest(_Request):
    """POST /api/v1/link/command: one COMMAND frame, for conformance tests (docs/api.md)."""

    command: str | None = Field(
        default=None,
        max_length=64,
        description="a command of the dictionary by name (config/protocol.toml); or give opcode",
    )
    opcode: int | None = Field(
        default=None, ge=0, le=255, description="the opcode byte, 0..255, any (or give command)"
    )
    fields: dict[str, int | float | str] | None = Field(
        default=None,
        description="request fields by name, encoded and range-checked by the dictionary "
        "(needs command); bytes fields as hex strings",
    )
    payload_hex: str | None = Field(
        default=None,
        max_length=2 * 1024,
        pattern=r"^([0-9a-fA-F]{2})*$",
        description="the payload as hex, sent as it is, unchecked (0..1024 bytes); or fields",
    )
    repeat: bool = Field(
        default=False,
        description="send the identical frame (same sequence number) again after the answer, "
        "as a retry after a lost answer would; both answers are returned",
    )


class LinkAnswer(BaseModel):
    """One answer frame of POST /api/v1/link/command."""

    type: Literal["ack", "nak"]
    seq: int
    payload_hex: str
    error_code: int | None = Field(description="NAK: the error code; ACK: null")
    error_name: str | None = Field(description="NAK: the code's name in the dictionary")
    detail: str | None = Field(description="NAK: the device's detail text")
    values: dict[str, int | float | str] | None = Field(
        description="ACK: the response fields as the dictionary decodes them (bytes as hex); "
        "null for a NAK or when they do not decode (see decode_error)"
    )
    decode_error: str | None = Field(description="why the ACK payload did not decode; else null")


class LinkCommandResponse(BaseModel):
    """POST /api/v1/link/command: the frame sent and the device's answer(s)."""

    command: str | None = Field(description="the opcode's name; null if the dictionary has none")
    opcode: int
    seq: int = Field(description="sequence number of the frame (both sends with repeat)")
    request_hex: str = Field(description="the payload sent")
    answers: list[LinkAnswer] = Field(description="one per send: ACK or NAK")
    attempts: int = Field(description="frames written, retries after a timeout included")
    rtt_s: float = Field(description="from the first send to the last answer")


class PingRequest(_Request):
    """POST /api/v1/ping."""

    count: int = Field(default=10, ge=1, le=PING_COUNT_MAX, description="number of PINGs")
    size: int = Field(default=16, ge=0, le=PING_SIZE_MAX, description="payload bytes per PING")


class RttMs(BaseModel):
    """Round-trip times of the successful PINGs, milliseconds (null if none succeeded)."""

    p50: float | None
    p99: float | None
    max: float | None


class PingResponse(BaseModel):
    """POST /api/v1/ping."""

    count: int
    ok: int
    failed: int
    retries: int = Field(description="re-sends needed, summed over all PINGs")
    rtt_ms: RttMs
    errors: list[str] = Field(description="up to 5 distinct failure reasons")


class DeviceLinkStats(BaseModel):
    """GET_LINK_STATS fields, plus the simulator's injected faults (null on hardware)."""

    rx_frames: int
    crc_errors: int
    resyncs: int
    bytes_dropped: int
    executed: int
    replayed: int
    nacked: int
    tx_frames: int
    injected: dict[str, int] | None


class LinkResponse(BaseModel):
    """GET /api/v1/link."""

    host: dict[str, int] = Field(description="host-side link counters")
    device: DeviceLinkStats | None = Field(description="null when the device cannot be asked")
