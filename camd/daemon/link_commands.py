"""The command link as the API shows it: PING runs, raw COMMAND frames and the link's counters.

``LinkCommands`` is handed the device access (the link behind its FIFO lock, the state
machine, the emergency-stop latch), the simulator's controls (the faults it injected, beside
the device's counters) and a predicate that says the daemon is shutting down (a long ping run
then ends at once, so that its request answers within uvicorn's grace). It serves
``POST /api/v1/ping``, ``POST /api/v1/link/command`` and ``GET /api/v1/link`` (docs/api.md).
"""

from __future__ import annotations

import contextlib
import logging
import random
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from camd.daemon.device import DeviceAccess
from camd.daemon.errors import (
    BadRequest,
    DeviceRejected,
    DeviceTimeout,
    Disconnected,
    SessionError,
)
from camd.daemon.models import (
    DeviceLinkStats,
    LinkAnswer,
    LinkCommandRequest,
    LinkCommandResponse,
    LinkResponse,
    PingResponse,
    RttMs,
)
from camd.daemon.sim_control import SimulatorControl
from camd.daemon.state import Request, State
from camd.protocol import CommandSpec, Frame, FrameType, PayloadError

# The session's logger: these lines kept the name they had before the link commands were a
# service of their own (log filters select the daemon's lines by it).
log = logging.getLogger("camd.daemon.session")

PING_ERRORS_MAX = 5


@dataclass(eq=False)
class LinkCommands:
    """PING runs, raw commands and link counters for one device session (module docstring)."""

    device: DeviceAccess
    sim: SimulatorControl
    _stopping: Callable[[], bool]

    def host_counters(self) -> dict[str, int]:
        """The link's host-side counters."""
        link = self.device.link
        return link.counters() if link is not None else {}

    def ping(self, count: int = 10, size: int = 16) -> PingResponse:
        """Send ``count`` PINGs of ``size`` random bytes; a differing echo is a failure."""
        self.device.require(Request.PING)
        rtts_s: list[float] = []
        errors: dict[str, None] = {}  # distinct reasons, in order of first appearance
        ok = failed = retries = 0
        for i in range(count):
            if self._stopping():
                failed += count - i
                errors.setdefault("the daemon is shutting down; ping run cut short")
                break
            payload = random.randbytes(size)
            try:
                response = self.device.request("PING", data=payload)
            except Disconnected as exc:
                if i == 0:
                    raise
                failed += count - i
                errors.setdefault(str(exc))
                break
            except DeviceTimeout as exc:
                failed += 1
                retries += self.device.config.link_retries  # every re-send went unanswered too
                errors.setdefault(str(exc))
                continue
            except DeviceRejected as exc:
                failed += 1
                errors.setdefault(str(exc))
                continue
            retries += response.attempts - 1
            echo = response.values.get("data")
            if echo != payload:
                failed += 1
                errors.setdefault(
                    f"PING echo differs from the {size} bytes sent: the line corrupted it "
                    "undetected; check the link quality (GET /api/v1/link)"
                )
                continue
            ok += 1
            rtts_s.append(response.rtt_s)
        if rtts_s:
            rtt_ms = np.asarray(rtts_s) * 1e3
            p50, p99 = (float(v) for v in np.percentile(rtt_ms, [50, 99]))
            rtt = RttMs(p50=p50, p99=p99, max=float(rtt_ms.max()))
        else:
            rtt = RttMs(p50=None, p99=None, max=None)
        return PingResponse(
            count=count,
            ok=ok,
            failed=failed,
            retries=retries,
            rtt_ms=rtt,
            errors=list(errors)[:PING_ERRORS_MAX],
        )

    def command(self, body: LinkCommandRequest) -> LinkCommandResponse:
        """Send one COMMAND frame as the request says and return the answer frames undecoded
        and decoded (docs/api.md): for conformance tests of the device's own checks. The
        daemon's view of the camera (mode, register copy, stage) is not updated; a client that
        changes the camera with it puts it back."""
        dictionary = self.device.dictionary
        if (body.command is None) == (body.opcode is None):
            raise BadRequest("give either command (a name in config/protocol.toml) or opcode")
        if body.fields is not None and body.payload_hex is not None:
            raise BadRequest("give either fields (encoded by the dictionary) or payload_hex")
        spec: CommandSpec | None
        if body.command is not None:
            try:
                spec = dictionary.command(body.command.upper())
            except KeyError as exc:
                raise BadRequest(str(exc.args[0])) from None
            opcode = spec.opcode
        else:
            assert body.opcode is not None
            opcode = body.opcode
            found = dictionary.command_for_opcode(opcode)
            if body.fields is not None and found is None:
                raise BadRequest(
                    f"opcode 0x{opcode:02X} is not in the dictionary: send payload_hex, not fields"
                )
            spec = found
        if body.payload_hex is not None:
            payload = bytes.fromhex(body.payload_hex)
        elif spec is not None:
            try:
                fields = {
                    name: bytes.fromhex(value)
                    if isinstance(value, str) and _bytes_field(spec, name)
                    else value
                    for name, value in (body.fields or {}).items()
                }
                payload = spec.encode_request(**fields)
            except (ValueError, TypeError) as exc:
                raise BadRequest(f"{spec.name}: {exc}") from None
        else:
            payload = b""
        self.device.require(Request.LINK_COMMAND)
        self.device.estop.check_raw(None if spec is None else spec.name)
        with self.device.device_op() as link:
            try:
                exchange = link.exchange(opcode, payload, repeat=body.repeat)
            except ValueError as exc:
                raise BadRequest(str(exc)) from None
        answers = [self._answer(spec, frame) for frame in exchange.answers]
        return LinkCommandResponse(
            command=None if spec is None else spec.name,
            opcode=opcode,
            seq=exchange.seq,
            request_hex=payload.hex(),
            answers=answers,
            attempts=exchange.attempts,
            rtt_s=exchange.rtt_s,
        )

    def _answer(self, spec: CommandSpec | None, frame: Frame) -> LinkAnswer:
        """One answer frame in words: a NAK's code, name and detail; an ACK's fields."""
        dictionary = self.device.dictionary
        if frame.type == FrameType.NAK:
            try:
                code, detail = dictionary.decode_nak(frame.payload)
            except PayloadError as exc:
                code, detail = None, f"malformed NAK payload: {exc}"
            name: str | None = None
            if code is not None:
                with contextlib.suppress(KeyError):
                    name = dictionary.error(code).name
            return LinkAnswer(type="nak", seq=frame.seq, payload_hex=frame.payload.hex(),
                              error_code=code, error_name=name, detail=detail, values=None,
                              decode_error=None)  # fmt: skip
        values: dict[str, int | float | str] | None = None
        problem: str | None = None
        if spec is None:
            problem = "the dictionary has no command with this opcode"
        else:
            try:
                decoded = spec.decode_response(frame.payload)
                values = {k: v.hex() if isinstance(v, bytes) else v for k, v in decoded.items()}
            except PayloadError as exc:
                problem = str(exc)
        return LinkAnswer(type="ack", seq=frame.seq, payload_hex=frame.payload.hex(),
                          error_code=None, error_name=None, detail=None, values=values,
                          decode_error=problem)  # fmt: skip

    def stats(self) -> LinkResponse:
        """Host counters, and the device's (null when it cannot be asked)."""
        host = self.host_counters()
        device: DeviceLinkStats | None = None
        if self.device.state != State.DISCONNECTED:
            try:
                stats: dict[str, Any] = dict(self.device.request("GET_LINK_STATS").values)
                injected = self.sim.injected()
                device = DeviceLinkStats.model_validate({**stats, "injected": injected})
            except SessionError as exc:
                log.info("link: device counters unavailable: %s", exc)
        return LinkResponse(host=host, device=device)


def _bytes_field(spec: CommandSpec, name: str) -> bool:
    """``name`` is a bytes field of ``spec``'s request (given as hex, sent as those bytes)."""
    return any(f.name == name and f.type == "bytes" for f in spec.request)
