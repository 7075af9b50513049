"""The device end of the command link: a received frame to its handler and back (sans-I/O).

``CommandLink.receive(frame, now_s)`` executes one received command frame (or answers it from
the record) and returns the frames the device sends back: an ACK or NAK, then any EVENT frames
the command caused. It decodes the payload, checks what the codec leaves to the device (the
length, the fields' ranges) and calls the command's handler from the dispatch table
(``firmware_models.fpga_commands``).

At-most-once execution
----------------------
The host runs strict stop-and-wait: it sends one command, waits for its answer and, if the
answer is lost, re-sends the *identical* frame (same sequence number, same bytes). The device
keeps a record of the last command it executed and the ACK/NAK it produced. A command frame
equal to the recorded one is answered by re-sending the recorded ACK/NAK without executing it
again; any other command frame executes and replaces the record.

One entry is enough because a stop-and-wait host never re-sends an older command after it has
sent a newer one: the only command that can legitimately arrive again is the last one. Comparing
the whole frame (not just the sequence number) means a new command that happens to reuse the
sequence number after the 8-bit counter wrapped, or after the host restarted, still executes.
The record survives RESET, so a retried RESET is not executed twice. Events are not part of the
record: they reported a state change that happened once.

That it holds is measured, not assumed: the device also remembers the last
``_RECENT_EXECUTED`` command frames it executed, and an execution of a frame equal to one of
them counts ``executed_twice`` (SIM_GET_INJECTED). A command that legitimately repeats another
frame byte for byte needs the 8-bit sequence number to come round, 256 commands later, far
outside that window; only a host restarting at a random sequence number could, rarely, repeat
a recent frame. 0 is expected on any line.

Failures on purpose
-------------------
SIM_FAIL_NEXT arms one failure of a coming command (``arm``; by opcode, after ``skip`` of them):
a NAK with a chosen error code, or a silence of ``duration_s`` (a dropped line: ``silent(now_s)``
is true, frames received are ignored and the transport sends nothing). The failed command is
not executed, so the host's recovery from a request that fails part-way can be tested. The
third kind, ``end_stream``, lets the command (START_STREAM, WHEEL_ACQUIRE) execute but ends the
stream it starts after ``frames`` frames with STREAM_DONE, as a camera that ends a stream early.
"""

from __future__ import annotations

import math
import struct
from collections import Counter, deque
from collections.abc import Mapping
from dataclasses import dataclass, fields

from camd.protocol import CommandSpec, FieldSpec, Frame, FrameType, PayloadError, ProtocolError
from camd.protocol.dictionary import FieldValue
from firmware_models.defects import Defects
from firmware_models.errors import Nak
from firmware_models.fpga_commands import DeviceState, Handler

# Executed command frames remembered to detect one executed twice (module docstring); far
# below the 256 commands after which the host's sequence number repeats.
_RECENT_EXECUTED = 32


@dataclass(slots=True)
class LinkCounters:
    """The device side of the command link, as GET_LINK_STATS reports it (plus ``ignored``)."""

    rx_frames: int = 0  # frames handed to the model after the receiver (and any line loss)
    executed: int = 0
    replayed: int = 0
    nacked: int = 0
    tx_frames: int = 0
    ignored: int = 0  # received frames of a type other than COMMAND
    silenced: int = 0  # received while silent (SIM_FAIL_NEXT silence): not seen, not answered
    executed_twice: int = 0  # executions of a frame equal to a recently executed one

    def as_dict(self) -> dict[str, int]:
        """The counters by name."""
        return {f.name: getattr(self, f.name) for f in fields(self)}


@dataclass(frozen=True, slots=True)
class _Record:
    """The last executed command and its ACK/NAK (see the module docstring)."""

    command: Frame
    response: Frame


@dataclass(slots=True)
class ArmedFailure:
    """The failure SIM_FAIL_NEXT armed: the command it fails and how."""

    action: str  # "nak", "silence" or "end_stream"
    opcode: int
    skip: int  # commands with ``opcode`` still to let through
    error_code: int  # action nak
    duration_s: float  # action silence
    frames: int = 0  # action end_stream: the stream ends after this many frames


class CommandLink:
    """Frames in, frames out for the handlers of ``table`` (see the module docstring).

    ``table`` (command name -> handler) is given once the handlers exist: some of them read
    the link's counters or arm its failures. ``counters`` and ``executions`` (opcode ->
    commands executed, replays not counted) say what the link did; ``sent`` counts every frame
    the device sends, events and telemetry included.
    """

    def __init__(self, state: DeviceState, *, defects: Defects) -> None:
        self.state = state
        self.dictionary = state.dictionary
        self.table: Mapping[str, Handler] = {}
        self.defects = defects
        self.counters = LinkCounters()
        self.executions: Counter[int] = Counter()
        self._record: _Record | None = None
        self._recent: deque[Frame] = deque(maxlen=_RECENT_EXECUTED)  # executed command frames
        self._armed: ArmedFailure | None = None
        self._silent_until_s = -math.inf  # transport clock; SIM_FAIL_NEXT silence

    def receive(self, frame: Frame, now_s: float) -> list[Frame]:
        """Execute (or replay) one received frame; return the frames to send, in order."""
        if self.silent(now_s):
            self.counters.silenced += 1
            return []
        self.counters.rx_frames += 1
        if frame.type != FrameType.COMMAND:
            self.counters.ignored += 1
            return []
        record = self._record
        # replay_executes: the record is never consulted, so a retry executes again.
        if record is not None and record.command == frame and not self.defects.replay_executes:
            self.counters.replayed += 1
            return self.sent([record.response])
        cut_after = None
        if self._fails_now(frame):
            armed = self._armed
            assert armed is not None
            if armed.action != "end_stream":
                return self._fail(frame, now_s)
            # It executes; the stream it starts ends early (START_STREAM, WHEEL_ACQUIRE).
            self._armed, cut_after = None, armed.frames
        self.counters.executed += 1
        if frame in self._recent:
            self.counters.executed_twice += 1  # at-most-once broken (module docstring)
        self._recent.append(frame)
        self.executions[frame.opcode] += 1
        self.state.end_stream_after = cut_after
        try:
            response, events = self._execute(frame, now_s)
        finally:
            self.state.end_stream_after = None
        if response.type == FrameType.NAK:
            self.counters.nacked += 1
        self._record = _Record(frame, response)
        return self.sent([response, *events])

    def silent(self, now_s: float) -> bool:
        """True while the device is off the line (SIM_FAIL_NEXT silence): it answers nothing,
        and the transport sends nothing it makes (events, telemetry) until ``now_s`` passes."""
        return now_s < self._silent_until_s

    def arm(self, failure: ArmedFailure | None) -> None:
        """Fail a coming command as ``failure`` says (None: disarm)."""
        self._armed = failure

    def sent(self, frames: list[Frame]) -> list[Frame]:
        """Count ``frames`` as sent by the device; return them."""
        self.counters.tx_frames += len(frames)
        return frames

    def _fails_now(self, frame: Frame) -> bool:
        """Count ``frame`` against the armed failure; True if it is the one to fail."""
        armed = self._armed
        if armed is None or frame.opcode != armed.opcode:
            return False
        if armed.skip > 0:
            armed.skip -= 1
            return False
        return True

    def _fail(self, frame: Frame, now_s: float) -> list[Frame]:
        """Fail ``frame`` as armed (it is not executed) and disarm."""
        armed = self._armed
        assert armed is not None
        self._armed = None
        if armed.action == "silence":
            self._silent_until_s = now_s + armed.duration_s
            self.counters.silenced += 1
            return []
        name = self.dictionary.command(frame.opcode).name
        payload = self.dictionary.encode_nak(
            armed.error_code, f"{name} failed on purpose (SIM_FAIL_NEXT)"
        )
        response = Frame(FrameType.NAK, frame.seq, frame.opcode, payload)
        self.counters.nacked += 1
        # Recorded like any answer: a retry of this frame gets the same NAK, not an execution.
        self._record = _Record(frame, response)
        return self.sent([response])

    def _execute(self, frame: Frame, now_s: float) -> tuple[Frame, tuple[Frame, ...]]:
        spec = self.dictionary.command_for_opcode(frame.opcode)
        handler = self.table.get(spec.name) if spec is not None else None
        try:
            if spec is None or handler is None:
                raise Nak(
                    "UNKNOWN_OPCODE",
                    f"opcode 0x{frame.opcode:02X} is not implemented by this device",
                )
            request = decode_request(spec, frame.payload)
            outcome = handler(spec, request, now_s)
        except Nak as nak:
            payload = self.dictionary.encode_nak(nak.error, nak.detail)
            return Frame(FrameType.NAK, frame.seq, frame.opcode, payload), ()
        except ProtocolError as exc:
            # A response that cannot be encoded is a model bug; answer like firmware would.
            payload = self.dictionary.encode_nak("INTERNAL", str(exc))
            return Frame(FrameType.NAK, frame.seq, frame.opcode, payload), ()
        return Frame(FrameType.ACK, frame.seq, frame.opcode, outcome.payload), outcome.events


# -- payload checks the codec leaves to the device -------------------------------------------


def decode_request(spec: CommandSpec, payload: bytes) -> dict[str, FieldValue]:
    """The request fields of ``payload``; NAK BAD_LENGTH or OUT_OF_RANGE as the device would."""
    try:
        values = spec.decode_request(payload)
    except PayloadError as exc:
        # The codec raises PayloadError for a wrong size and for an undefined enum value
        # alike; the host needs to know which, so tell them apart by the length.
        if _length_fits(spec.request, len(payload)):
            raise Nak("OUT_OF_RANGE", str(exc)) from None
        expected = _expected_length(spec.request)
        raise Nak("BAD_LENGTH", f"{exc}; {spec.name} takes {expected}") from None
    _check_ranges(spec, values)
    return values


def _length_bounds(fields_: list[FieldSpec]) -> tuple[int, int]:
    """(shortest, longest) payload laid out as ``fields_``, in bytes."""
    fixed = sum(f.size for f in fields_ if f.size is not None)
    variable = sum(f.max_size for f in fields_ if f.size is None)
    return fixed, fixed + variable


def _length_fits(fields_: list[FieldSpec], length: int) -> bool:
    shortest, longest = _length_bounds(fields_)
    return shortest <= length <= longest


def _expected_length(fields_: list[FieldSpec]) -> str:
    shortest, longest = _length_bounds(fields_)
    if shortest != longest:
        return f"{shortest} to {longest} payload bytes"
    return f"{shortest} payload byte{'' if shortest == 1 else 's'}"


def _check_ranges(spec: CommandSpec, values: Mapping[str, FieldValue]) -> None:
    """NAK OUT_OF_RANGE for a decoded value outside its field's min/max (decode does not check)."""
    for f in spec.request:
        value = values[f.name]
        if f.enum is not None or not isinstance(value, int | float):
            continue
        lo = -math.inf if f.min is None else _as_sent(f, f.min)
        hi = math.inf if f.max is None else _as_sent(f, f.max)
        if not lo <= value <= hi:  # NaN fails too
            raise Nak(
                "OUT_OF_RANGE",
                f"{spec.name}.{f.name}: {value:g} is out of range (valid: {f.valid_range()})",
            )


def _as_sent(f: FieldSpec, bound: float) -> float:
    """A bound as it looks after the trip through the wire type (f32 rounds 0.01 up or down)."""
    if f.type == "f32":
        return float(struct.unpack(">f", struct.pack(">f", bound))[0])
    return bound
