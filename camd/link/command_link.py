"""The RS-422 command link over pyserial: stop-and-wait requests, retries, reconnect.

One reader thread owns the port's input: it feeds the sans-I/O ``Decoder``, hands ACK/NAK
frames to the waiting request, and delivers unsolicited telemetry and events to subscribers.
Requests are serialised (strict stop-and-wait): a retry re-sends the *identical* frame, same
sequence number, so the device answers it from its record instead of executing it twice.

A lost port (device unplugged, pty closed) is reported to subscribers as a ``ConnectionChange``
and reopened with exponential backoff; requests made while it is down fail at once with
``LinkDown``. Nothing here raises out of the reader thread.

The port, its reader thread and the messages it delivers are ``camd.link.link_port``'s
(``LinkPort``); ``CommandLink`` is a ``LinkPort`` that sends requests over it. Import the names
from here (or from ``camd.link``).
"""

from __future__ import annotations

import random
import threading
import time
from dataclasses import dataclass
from typing import Any, Unpack

from camd.link.link_port import (
    ConnectionChange,
    LinkCounters,
    LinkDown,
    LinkError,
    LinkPort,
    LinkPortOptions,
    Message,
    Pending,
    Subscriber,
    Unsolicited,
)
from camd.protocol import (
    MAX_PAYLOAD,
    Frame,
    FrameType,
    PayloadError,
    encode_frame,
)
from camd.protocol.dictionary import FieldValue

__all__ = [
    "CommandLink",
    "CommandRejected",
    "CommandTimeout",
    "ConnectionChange",
    "LinkCounters",
    "LinkDown",
    "LinkError",
    "Message",
    "RawExchange",
    "Response",
    "Subscriber",
    "Unsolicited",
]


class CommandTimeout(LinkError):
    """No answer after every retry."""


class CommandRejected(LinkError):
    """The device answered NAK. ``code``/``name`` identify the error; str() is in words."""

    def __init__(self, command: str, code: int, name: str, text: str) -> None:
        super().__init__(f"{command} refused by the device: {text}")
        self.command = command
        self.code = code
        self.name = name


@dataclass(frozen=True, slots=True)
class Response:
    """A command's acknowledge, decoded."""

    command: str
    seq: int
    values: dict[str, FieldValue]
    attempts: int
    rtt_s: float


@dataclass(frozen=True, slots=True)
class RawExchange:
    """What ``CommandLink.exchange`` got: the answer frames (two with ``repeat``), undecoded."""

    seq: int
    answers: list[Frame]
    attempts: int  # frames sent in all, retries included
    rtt_s: float


class CommandLink(LinkPort):
    """A command link to one camera.

    ``port`` is anything pyserial opens: a device path (``/dev/ttyUSB0``, a symlink to a pty) or
    a pyserial URL. ``timeout_s`` is the wait for each attempt; a command is sent at most
    ``1 + retries`` times. The other keyword arguments are ``LinkPort``'s (``LinkPortOptions``).
    """

    def __init__(
        self,
        port: str,
        *,
        timeout_s: float = 0.1,
        retries: int = 5,
        **options: Unpack[LinkPortOptions],
    ) -> None:
        if timeout_s <= 0:
            raise ValueError(f"timeout_s must be > 0, got {timeout_s}")
        if retries < 0:
            raise ValueError(f"retries must be >= 0, got {retries}")
        super().__init__(port, **options)
        self.timeout_s = timeout_s
        self.retries = retries
        self._request_lock = threading.Lock()  # one command in flight
        # A fresh session's first sequence number rarely collides with the device's record.
        self._seq = random.randrange(256)

    # -- requests -------------------------------------------------------------------------------

    def request(
        self,
        command: str,
        /,
        *,
        timeout_s: float | None = None,
        retries: int | None = None,
        **fields: Any,
    ) -> Response:
        """Send ``command`` with its request fields and wait for the acknowledge.

        Raises EncodeError (a ValueError) for bad field values before anything is sent,
        CommandRejected for a NAK, CommandTimeout when every attempt went unanswered, and
        LinkDown when the port is not open.
        """
        spec = self.dictionary.command(command)
        payload = spec.encode_request(**fields)
        with self._request_lock:
            seq = self._next_seq()
            t0 = time.perf_counter()
            frame, attempts = self._send(spec.name, seq, spec.opcode, payload, timeout_s, retries)
            return self._finish(spec.name, frame, attempts, t0)

    def exchange(
        self,
        opcode: int,
        payload: bytes,
        *,
        repeat: bool = False,
        timeout_s: float | None = None,
        retries: int | None = None,
    ) -> RawExchange:
        """Send one COMMAND frame with any opcode and payload, unchecked by the dictionary, and
        return the device's answer frames undecoded (ACK or NAK alike): for conformance tests
        of the device's own checks (docs/conformance.md). With ``repeat`` the identical frame
        (same sequence number) is sent once more after the answer, as a retry after a lost
        answer would be; the device must answer it from its at-most-once record.

        Raises CommandTimeout and LinkDown as ``request`` does; ValueError for a payload above
        the frame's maximum."""
        if not 0 <= opcode <= 0xFF:
            raise ValueError(f"opcode {opcode} is not a byte (0 .. 255)")
        if len(payload) > MAX_PAYLOAD:
            raise ValueError(f"payload of {len(payload)} bytes; a frame carries 0 .. {MAX_PAYLOAD}")
        try:
            name = self.dictionary.command(opcode).name
        except KeyError:
            name = f"opcode 0x{opcode:02X}"
        with self._request_lock:
            seq = self._next_seq()
            t0 = time.perf_counter()
            answers = [self._send(name, seq, opcode, payload, timeout_s, retries)]
            if repeat:
                answers.append(self._send(name, seq, opcode, payload, timeout_s, retries))
            rtt_s = time.perf_counter() - t0
        for frame, _ in answers:
            if frame.type == FrameType.NAK:
                self._counters.nacked += 1
            else:
                self._counters.acked += 1
        return RawExchange(seq, [frame for frame, _ in answers], sum(n for _, n in answers), rtt_s)

    def _next_seq(self) -> int:
        """The next command's sequence number (request lock held)."""
        seq = self._seq
        self._seq = (self._seq + 1) & 0xFF
        return seq

    def _send(
        self,
        name: str,
        seq: int,
        opcode: int,
        payload: bytes,
        timeout_s: float | None,
        retries: int | None,
    ) -> tuple[Frame, int]:
        """Send one command frame (request lock held), retrying the identical frame until an
        answer comes; (the answer, attempts)."""
        wait_s = self.timeout_s if timeout_s is None else timeout_s
        attempts_max = 1 + (self.retries if retries is None else retries)
        wire = encode_frame(FrameType.COMMAND, seq, opcode, payload)
        pending = Pending(seq, opcode)
        try:
            with self._state_lock:
                self._pending = pending
            for attempt in range(1, attempts_max + 1):
                if attempt > 1:
                    self._counters.retries += 1
                self._write(wire)
                # `done` is set by the first answer to any attempt, or by the link's loss.
                if pending.done.wait(wait_s):
                    if pending.frame is None:
                        raise LinkDown(self._down_message())
                    return pending.frame, attempt
                self._counters.timeouts += 1
        except LinkDown:
            self._counters.failed += 1
            raise
        finally:
            with self._state_lock:
                self._pending = None
        self._counters.failed += 1
        raise CommandTimeout(
            f"{name}: no answer from the device on {self.port} after {attempts_max} "
            f"attempt(s) of {wait_s * 1e3:.0f} ms; check the cable and that the camera is "
            "powered, or raise link.timeout_s / link.retries in the config"
        )

    def _finish(self, command: str, frame: Frame, attempts: int, t0: float) -> Response:
        rtt_s = time.perf_counter() - t0
        spec = self.dictionary.command(command)
        if frame.type == FrameType.NAK:
            self._counters.nacked += 1
            try:
                code, detail = self.dictionary.decode_nak(frame.payload)
            except PayloadError as exc:
                raise CommandRejected(command, 0, "MALFORMED_NAK", str(exc)) from None
            try:
                name = self.dictionary.error(code).name
            except KeyError:
                name = "UNKNOWN"
            raise CommandRejected(command, code, name, self.dictionary.describe_error(code, detail))
        self._counters.acked += 1
        try:
            values = spec.decode_response(frame.payload)
        except PayloadError as exc:
            self._counters.undecodable += 1
            raise LinkError(
                f"{command}: the device's acknowledge does not match the dictionary ({exc}); "
                "host and firmware dictionaries differ"
            ) from None
        return Response(command, frame.seq, values, attempts, rtt_s)
