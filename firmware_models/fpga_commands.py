"""What every group of the FPGA's command handlers shares (``firmware_models.fpga``).

The simulated FPGA executes each command with a handler ``(spec, request, now_s) -> Outcome``:
``spec`` the command of the dictionary, ``request`` its decoded and range-checked fields,
``now_s`` the transport's clock. A refusal raises ``firmware_models.errors.Nak``. Handlers come
in groups, one per part of the camera (``fpga_control``, ``fpga_sensor``, ``fpga_stream``,
``fpga_motion``, ``fpga_wheel``, ``fpga_sim``), each saying which commands it executes
(``handlers()``); ``dispatch_table`` joins them into the one table the command link looks a
command up in.

``DeviceState`` is what the groups share besides the parts they drive: the mode, the fault, the
boot count, the clock's origin, the numbering of the frames no command answers (events), and,
while a command executes, where SIM_FAIL_NEXT end_stream cuts the stream it starts.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

from camd.protocol import CommandSpec, Dictionary, Frame, FrameType
from camd.protocol.dictionary import FieldValue
from firmware_models.errors import Nak

FW_VERSION = 0x0100  # 1.0, major * 256 + minor as GET_STATUS reports it
U32_WRAP = 2**32
_SEQ_WRAP = 256


@dataclass(frozen=True, slots=True)
class Outcome:
    """What a successful handler produced: the ACK payload and any events."""

    payload: bytes
    events: tuple[Frame, ...] = ()


Handler = Callable[[CommandSpec, dict[str, FieldValue], float], Outcome]


class CommandGroup(Protocol):
    """A group of command handlers (one part of the camera)."""

    def handlers(self) -> dict[str, Handler]:
        """The commands this group executes, by protocol name."""
        ...


def dispatch_table(groups: Sequence[CommandGroup]) -> dict[str, Handler]:
    """Every group's handlers in one table; a command claimed by two groups is a model bug."""
    table: dict[str, Handler] = {}
    for group in groups:
        for name, handler in group.handlers().items():
            if name in table:
                raise ValueError(f"{name} has a handler in two command groups")
            table[name] = handler
    return table


class DeviceState:
    """The FPGA's own state, which several groups of handlers read or change."""

    def __init__(self, dictionary: Dictionary, power_on_s: float) -> None:
        self.dictionary = dictionary
        self.power_on_s = power_on_s  # transport clock at power-on: device time 0
        self.mode = "area"
        self.fault_code = 0
        self.boot_count = 1
        # While a command armed with SIM_FAIL_NEXT end_stream executes: its stream's length.
        self.end_stream_after: int | None = None
        self._unsolicited_seq = 0

    @property
    def device_state(self) -> str:
        """The GET_STATUS device_state: ``fault`` while a fault is active, else ``idle``."""
        return "fault" if self.fault_code else "idle"

    def require_no_fault(self, spec: CommandSpec) -> None:
        """NAK DEVICE_FAULT while a fault is active (commands that change something)."""
        if self.fault_code:
            try:
                fault = f"{self.dictionary.error(self.fault_code).name} ({self.fault_code})"
            except KeyError:
                fault = f"code {self.fault_code}"
            raise Nak("DEVICE_FAULT", f"{spec.name} refused in fault {fault}; RESET clears it")

    def unsolicited(self, type_: FrameType, opcode: int, payload: bytes) -> Frame:
        """A frame that answers no command (telemetry, event): it numbers itself."""
        seq = self._unsolicited_seq
        self._unsolicited_seq = (seq + 1) % _SEQ_WRAP
        return Frame(type_, seq, opcode, payload)

    def event(self, name: str, **values: Any) -> Frame:
        """The EVENT frame ``name`` with its fields."""
        packet = self.dictionary.event(name)
        return self.unsolicited(FrameType.EVENT, packet.opcode, packet.encode(**values))


def wrap_u32(values: Mapping[str, int]) -> dict[str, int]:
    """Counters as the device's u32 registers hold them."""
    # They wrap rather than refuse to be reported.
    return {name: value % U32_WRAP for name, value in values.items()}
