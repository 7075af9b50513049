"""Generate docs/protocol.md from the frame codec and the command dictionary.

The protocol document is rendered from the same objects the host and the simulated camera use, so
it cannot drift from them; ``tests/test_docs.py`` fails when the committed file is stale.

    python -m camd.protocol.docgen            write docs/protocol.md
    python -m camd.protocol.docgen --check    exit 1 if docs/protocol.md differs from the render
"""

from __future__ import annotations

import dataclasses
import sys
from collections.abc import Sequence
from pathlib import Path

from camd.markdown import docgen_parser, table, write_or_check
from camd.protocol.dictionary import (
    CommandSpec,
    Dictionary,
    DictionaryError,
    FieldSpec,
    FieldValue,
    PacketSpec,
    load_dictionary,
)
from camd.protocol.frame import (
    CRC_SIZE,
    HEADER_SIZE,
    MAX_PAYLOAD,
    OVERHEAD,
    SYNC,
    DecoderStats,
    FrameType,
    crc16,
    encode_frame,
)

SIMULATOR_OPCODES = range(0xF0, 0x100)
# The commands a device in fault refuses with DEVICE_FAULT: those that would start something
# (firmware_models/fpga.py, _require_no_fault). Stopping, reading, registers and RESET stay
# allowed, so a fault never keeps the stage or a stream running. tests/test_doc_device.py
# checks the list against the simulated camera.
REFUSED_IN_FAULT = (
    "SET_MODE", "TRAIN", "START_STREAM", "WHEEL_ACQUIRE", "MOTOR_ENABLE", "MOTOR_SET_RATE",
    "MOTOR_MOVE", "MOTOR_HOME", "MOTOR_SET_LIMITS", "SIM_SET_STAGE_FAULTS",
)  # fmt: skip

_TYPE_ROWS: dict[FrameType, tuple[str, str, str]] = {
    FrameType.COMMAND: ("host → device", "command opcode", "the command's request fields"),
    FrameType.ACK: ("device → host", "the command's opcode", "the command's response fields"),
    FrameType.NAK: ("device → host", "the command's opcode", "error code and detail text"),
    FrameType.TELEMETRY: ("device → host", "telemetry packet id", "the packet's fields"),
    FrameType.EVENT: ("device → host", "event id", "the event's fields"),
}

_COUNTER_DOCS: dict[str, str] = {
    "bytes_in": "bytes received",
    "frames": "valid frames delivered",
    "crc_errors": "candidates rejected for a CRC mismatch",
    "bad_type": "candidates rejected for an unknown type byte",
    "oversize": "candidates rejected for a length above the maximum payload",
    "resyncs": "times bytes were skipped to reach the next sync word",
    "bytes_dropped": "bytes discarded (rejected candidates and skipped garbage)",
    "partial_flushes": "stalled candidate frames given up (`expire()` / `flush_partial()`)",
}


def _hex(data: bytes) -> str:
    return " ".join(f"{b:02X}" for b in data)


def _num(x: float) -> str:
    return f"{x:.10g}"


# -- payload layouts -------------------------------------------------------------------------------


def _range(f: FieldSpec) -> str:
    if f.enum is not None:
        return ", ".join(f"`{name}` = {raw}" for name, raw in f.enum.items())
    if f.type in ("bytes", "str"):
        return f"0 .. {f.max_len} bytes" + (" of UTF-8" if f.type == "str" else "")
    text = f.valid_range()
    suffix = f" {f.unit}" if f.unit else ""
    return text.removesuffix(suffix)


def _payload_size(fields: Sequence[FieldSpec]) -> str:
    fixed = sum(f.size or 0 for f in fields)
    if fields and fields[-1].size is None:
        return f"{fixed} .. {fixed + fields[-1].max_size} bytes"
    if not fields:
        return "empty"
    return f"{fixed} byte" if fixed == 1 else f"{fixed} bytes"


def _fieldtable(fields: Sequence[FieldSpec]) -> list[str]:
    rows: list[list[str]] = []
    offset = 0
    for f in fields:
        size = str(f.size) if f.size is not None else f"0 .. {f.max_len}"
        scale = _num(f.scale) if f.scale != 1.0 else ""
        rows.append([str(offset), size, f"`{f.name}`", f.type, scale, f.unit, _range(f), f.doc])
        offset += f.size or 0
    header = ["Offset", "Size", "Field", "Type", "Scale", "Unit", "Range", "Description"]
    return table(header, rows)


def _layout(title: str, fields: Sequence[FieldSpec], note: str = "") -> list[str]:
    lines = [f"**{title}** ({_payload_size(fields)}){note}", ""]
    if fields:
        lines += [*_fieldtable(fields), ""]
    return lines


# -- worked example --------------------------------------------------------------------------------


def _example_value(f: FieldSpec) -> FieldValue:
    if f.enum is not None:
        return list(f.enum)[-1]
    if f.type == "bytes":
        return b"\x12\x34"[: f.max_len]
    if f.type == "str":
        return "ok"[: f.max_len]
    value = 1.0 if f.type == "f32" else f.scale
    if f.min is not None:
        value = max(value, f.min)
    if f.max is not None:
        value = min(value, f.max)
    return int(value) if f.type != "f32" and f.scale == 1.0 else value


def _example_command(d: Dictionary) -> CommandSpec:
    for cmd in d.commands:
        if cmd.request and all(f.size is not None for f in cmd.request):
            return cmd
    return d.commands[0]


def _show(value: FieldValue) -> str:
    if isinstance(value, bytes):
        return _hex(value)
    if isinstance(value, float):
        return _num(value)
    return str(value)


def _frame_rows(
    type_: FrameType,
    seq: int,
    cmd: CommandSpec,
    fields: Sequence[FieldSpec],
    values: dict[str, FieldValue],
) -> tuple[bytes, list[list[str]]]:
    payload = b"".join(f.encode(values[f.name], cmd.name) for f in fields)
    wire = encode_frame(type_, seq, cmd.opcode, payload)
    rows = [
        [f"`{_hex(wire[0:2])}`", "sync word", ""],
        [f"`{_hex(wire[2:3])}`", "type", type_.name],
        [f"`{_hex(wire[3:4])}`", "sequence number", str(seq)],
        [f"`{_hex(wire[4:5])}`", "opcode", cmd.name],
        [f"`{_hex(wire[5:7])}`", "payload length", str(len(payload))],
    ]
    for f in fields:
        rows.append(
            [
                f"`{_hex(f.encode(values[f.name], cmd.name))}`",
                f"payload: `{f.name}`",
                _show(values[f.name]),
            ]
        )
    crc_range = _hex(wire[2:-CRC_SIZE])
    rows.append([f"`{_hex(wire[-CRC_SIZE:])}`", "CRC", f"CRC-16/CCITT-FALSE of `{crc_range}`"])
    return wire, rows


def _example(d: Dictionary) -> list[str]:
    cmd = _example_command(d)
    seq = 0x05
    request = {f.name: _example_value(f) for f in cmd.request}
    response = {f.name: _example_value(f) for f in cmd.response}
    call = ", ".join(f"{k}={_show(v)}" for k, v in request.items())
    cmd_wire, cmd_rows = _frame_rows(FrameType.COMMAND, seq, cmd, cmd.request, request)
    ack_wire, ack_rows = _frame_rows(FrameType.ACK, seq, cmd, cmd.response, response)
    err = next((e for e in d.errors if e.name == "ILLEGAL_STATE"), d.errors[0])
    nak_wire = encode_frame(FrameType.NAK, seq, cmd.opcode, d.encode_nak(err.code))
    lines = [
        "## 2. Worked example",
        "",
        f"The host sends `{cmd.name}` (opcode 0x{cmd.opcode:02X}) with {call or 'no fields'}, "
        f"sequence number {seq}:",
        "",
        "```",
        _hex(cmd_wire),
        "```",
        "",
        *table(["Bytes", "Field", "Meaning"], cmd_rows),
        "",
        "The device executes it and acknowledges with the same sequence number and opcode:",
        "",
        "```",
        _hex(ack_wire),
        "```",
        "",
        *table(["Bytes", "Field", "Meaning"], ack_rows),
        "",
        f"Had the device refused it with {err.name}, the answer would have been:",
        "",
        "```",
        _hex(nak_wire),
        "```",
        "",
        "that is, a NAK frame with the command's sequence number and opcode and the payload "
        f"`{_hex(nak_wire[HEADER_SIZE:-CRC_SIZE])}` (error code {err.code}, no detail text). "
        f"The user would have read “{d.describe_error(err.code)}”.",
        "",
    ]
    return lines


# -- sections --------------------------------------------------------------------------------------


def _frame_format() -> list[str]:
    n = "*n*"
    layout = table(
        ["Offset", "Size", "Field", "Value"],
        [
            ["0", "2", "sync word", f"`{_hex(SYNC)}`"],
            ["2", "1", "type", "see *Frame types*"],
            ["3", "1", "sequence number", "0 .. 255"],
            ["4", "1", "opcode", "command opcode, telemetry packet id or event id"],
            ["5", "2", f"payload length {n}", f"0 .. {MAX_PAYLOAD}"],
            [str(HEADER_SIZE), n, "payload", "laid out by the dictionary (sections 5 to 7)"],
            [
                f"{HEADER_SIZE} + {n}",
                str(CRC_SIZE),
                "CRC",
                f"CRC-16/CCITT-FALSE of bytes 2 .. {HEADER_SIZE - 1} + {n}",
            ],
        ],
    )
    types = table(
        ["Value", "Type", "Direction", "Opcode field", "Payload"],
        [[f"0x{int(t):02X}", t.name, *_TYPE_ROWS.get(t, ("", "", ""))] for t in FrameType],
    )
    check = crc16(b"123456789")
    return [
        "## 1. Frame format",
        "",
        "Every message on the link, in either direction, is one frame. Multi-byte fields are "
        "big-endian (most significant byte first).",
        "",
        *layout,
        "",
        f"A frame is {OVERHEAD} + {n} bytes long: {OVERHEAD} .. {OVERHEAD + MAX_PAYLOAD}. The "
        f"payload is at most {MAX_PAYLOAD} bytes; a length field above that is invalid.",
        "",
        "### Frame types",
        "",
        *types,
        "",
        "### CRC",
        "",
        "CRC-16/CCITT-FALSE: polynomial 0x1021, initial value 0xFFFF, input and output not "
        "reflected, no final XOR. It covers every byte after the sync word up to the end of the "
        "payload (type, sequence number, opcode, length and payload) and is sent big-endian. "
        f"Check value: the CRC of the ASCII bytes `123456789` is 0x{check:04X}. In Python: "
        "`binascii.crc_hqx(data, 0xFFFF)`.",
        "",
        "### Payload fields",
        "",
        "- `u8`, `u16`, `u32`, `u64`, `i8`, `i16`, `i32`, `i64`: big-endian integers, two's "
        "complement when signed.",
        "- `f32`: IEEE-754 binary32, big-endian.",
        "- `bytes`, `str`: variable length, only as the last field of a payload; the length is "
        "what the frame's payload length leaves. `str` is UTF-8.",
        "- Scale: the physical value (in the field's unit) is the raw integer times the scale; "
        "the host sends physical values divided by the scale and rounded to the nearest integer.",
        "- Enumerations travel as their raw value; the host takes and gives their names.",
        "- Ranges are physical values. The host refuses a value outside its range before sending "
        "anything, with a message that names the field, the value and the range.",
        "",
    ]


def _receiving() -> list[str]:
    counters = table(
        ["Counter", "Meaning"],
        [[f"`{f.name}`", _COUNTER_DOCS.get(f.name, "")] for f in dataclasses.fields(DecoderStats)],
    )
    return [
        "## 3. Receiving: resynchronisation",
        "",
        "Both ends decode the byte stream with the same incremental decoder "
        "(`camd.protocol.Decoder`), which accepts the stream in chunks of any size:",
        "",
        f"1. Scan for the sync word `{_hex(SYNC)}`; bytes before it are dropped (one resync). A "
        f"trailing `{SYNC[0]:02X}` is held: its partner may arrive in the next chunk.",
        f"2. Once the {HEADER_SIZE} header bytes are in, reject the candidate if the type byte is "
        f"not one of the frame types, or if the payload length exceeds {MAX_PAYLOAD}; this is "
        "decided from the header alone, without waiting for the payload.",
        "3. Once the whole frame is in, reject it if the CRC does not match; otherwise deliver it.",
        "4. A rejected candidate costs one byte: scanning restarts one byte after its sync word, "
        "so a genuine frame hidden inside the bytes of a false candidate (garbage that happened "
        "to contain the sync word) is still found.",
        "5. Stalled candidates: a corrupted length field can leave the decoder waiting for bytes "
        "that never come, or that belong to later frames. Both ends give up on a candidate "
        "that has waited at the head of the buffer longer than a maximum-size frame takes on "
        "the line, however many bytes arrived since (`expire()`; an idle-line timeout alone "
        "would never fire while retries keep the line busy). Its first byte is dropped and the "
        "bytes after it are scanned again, "
        "releasing any complete frames they hold.",
        "6. A rejected frame is never answered: none of its fields can be trusted. The sender's "
        "timeout and retry recover from it (section 4).",
        "",
        "The decoder counts what it delivered and what it dropped:",
        "",
        *counters,
        "",
    ]


def _exchanges(d: Dictionary) -> list[str]:
    room = MAX_PAYLOAD - 2
    nak = table(
        ["Offset", "Size", "Field", "Description"],
        [
            ["0", "2", "error code", "u16, one of the error codes in section 8"],
            ["2", f"0 .. {room}", "detail", "optional UTF-8 text from the device, cut at a "
             f"character boundary to fit {room} bytes"],
        ],
    )  # fmt: skip
    sim = [c for c in d.commands if c.opcode in SIMULATOR_OPCODES]
    sim_names = ", ".join(f"`{c.name}`" for c in sim) or "none at present"
    unknown = next((e for e in d.errors if e.name == "UNKNOWN_OPCODE"), None)
    unknown_text = f"NAK {unknown.name} (code {unknown.code})" if unknown else "NAK"
    fault_names = ", ".join(
        f"{c.name}" + (" (simulator only)" if c.opcode in SIMULATOR_OPCODES else "")
        for c in d.commands
        if c.name in REFUSED_IN_FAULT
    )
    return [
        "## 4. Exchanges",
        "",
        "- **Stop-and-wait.** The host sends one COMMAND frame and waits for its answer, ACK or "
        "NAK, before it sends the next command. The answer carries the command's sequence "
        "number and opcode; the host matches it on type, sequence number and opcode and "
        "discards any other answer (a late answer to an earlier attempt).",
        "- **Sequence numbers.** Each new command takes the next sequence number, modulo 256.",
        "- **Retries.** When no answer arrives within the per-attempt timeout, the host sends "
        "the identical frame again (same sequence number, opcode and payload), up to its retry "
        "limit, and then reports a timeout. The timeout and the retry limit are host settings "
        "(`link.timeout_s`, `link.retries` in the daemon's config, [config.md](config.md)).",
        "- **At-most-once execution.** The device keeps a record of the last command it "
        "answered: the command frame's sequence number, opcode and payload, and the answer "
        "frame it sent (ACK or NAK). A command identical to the record is a retry after a lost "
        "answer: the device sends the recorded answer again and does not execute the command a "
        "second time. Any other command is executed and its answer replaces the record. One "
        "record suffices because under strict stop-and-wait only the most recent command can "
        "ever be retried, and the next new command has a different sequence number.",
        "- **Unsolicited frames.** TELEMETRY and EVENT frames are sent by the device at any time "
        "between other frames, including between a command and its answer. They are never "
        "answered and never taken for the answer to a command; the host keeps waiting for the "
        "ACK or NAK.",
        "- **Checks before execution.** The device checks every command before it executes "
        "it, in this order: an opcode it does not implement gets NAK UNKNOWN_OPCODE; a payload "
        "length the command does not take (section 5) NAK BAD_LENGTH; a value outside a "
        "field's enumeration or range (the ranges the host checks, section 1) NAK "
        "OUT_OF_RANGE. Only then come the checks of the device's state (fault, streaming, "
        "stage), each with the error its command names. A refused command changes nothing.",
        "- **Device in fault.** While a fault is active (GET_STATUS `device_state` fault, "
        "announced by a FAULT event), the commands that would start something are refused "
        f"with NAK DEVICE_FAULT: {fault_names}. Every other command executes as usual: the "
        "reads and status, PING, the registers, STOP_STREAM, MOTOR_STOP and MOTOR_ESTOP (a "
        "fault must not keep anything running), the wheel's speed and compensation, and "
        "RESET, which clears the fault.",
        "- **Frames the device does not answer.** A valid frame that is not a COMMAND (ACK, "
        "NAK, TELEMETRY or EVENT sent to the device) is counted in GET_LINK_STATS `rx_frames` "
        "and otherwise ignored.",
        "- **Sequence numbers of unsolicited frames.** TELEMETRY and EVENT frames number "
        "themselves from a counter of their own (0, 1, 2, ... modulo 256, both kinds on one "
        "counter), independent of the commands' sequence numbers; the host matches no "
        "command to them.",
        f"- **Simulator-only opcodes.** Opcodes 0x{SIMULATOR_OPCODES[0]:02X} .. "
        f"0x{SIMULATOR_OPCODES[-1]:02X} are implemented only by the simulated camera "
        f"({sim_names}); hardware answers them with {unknown_text}.",
        "",
        "### NAK payload",
        "",
        *nak,
        "",
        "The user sees the error in words: the name, the code, its meaning from section 8 and "
        "the device's detail, e.g. "
        f"“{d.describe_error(d.errors[0].code, 'detail text')}”. A code missing from the "
        "dictionary is shown as such, never dropped.",
        "",
    ]


def _commands(d: Dictionary) -> list[str]:
    summary = table(
        ["Opcode", "Command", "Request", "Response", "Description"],
        [
            [
                f"0x{c.opcode:02X}",
                f"`{c.name}`" + (" (simulator only)" if c.opcode in SIMULATOR_OPCODES else ""),
                _payload_size(c.request),
                _payload_size(c.response),
                c.doc,
            ]
            for c in d.commands
        ],
    )
    lines = [
        "## 5. Commands",
        "",
        "Host → device in COMMAND frames; the device answers each with an ACK carrying the "
        "response fields, or a NAK (section 4).",
        "",
        *summary,
        "",
    ]
    for c in d.commands:
        sim = " (simulator only)" if c.opcode in SIMULATOR_OPCODES else ""
        lines += [f"### 0x{c.opcode:02X} {c.name}{sim}", ""]
        if c.doc:
            lines += [c.doc, ""]
        lines += _layout("Request", c.request)
        note = ""
        if c.response_from_telemetry is not None:
            note = f": the fields of the {c.response_from_telemetry} telemetry packet"
        lines += _layout("Response", c.response, note)
    return lines


def _packets(title: str, intro: str, packets: Sequence[PacketSpec]) -> list[str]:
    lines = [title, "", intro, ""]
    if not packets:
        return [*lines, "None.", ""]
    lines += [
        *table(
            ["Id", "Name", "Payload", "Description"],
            [[f"0x{p.opcode:02X}", f"`{p.name}`", _payload_size(p.fields), p.doc] for p in packets],
        ),
        "",
    ]
    for p in packets:
        lines += [f"### 0x{p.opcode:02X} {p.name}", ""]
        if p.doc:
            lines += [p.doc, ""]
        lines += _layout("Payload", p.fields)
    return lines


def _errors(d: Dictionary) -> list[str]:
    return [
        "## 8. Error codes",
        "",
        "Carried by NAK frames (section 4).",
        "",
        *table(["Code", "Name", "Meaning"], [[str(e.code), e.name, e.message] for e in d.errors]),
        "",
    ]


def render_protocol_doc(dictionary: Dictionary) -> str:
    """Return the full text of docs/protocol.md for ``dictionary``."""
    d = dictionary
    lines = [
        "# RS-422 command link protocol",
        "",
        "<!-- Generated by `python -m camd.protocol.docgen`; do not edit by hand. -->",
        "",
        "This document is generated from the frame codec (`camd/protocol/frame.py`) and the "
        f"command dictionary (`config/protocol.toml`, version {d.version}) by "
        "`python -m camd.protocol.docgen`. `tests/test_docs.py` fails when it differs from the "
        "generated text, so edit the dictionary and regenerate rather than editing this file.",
        "",
        "1. Frame format",
        "2. Worked example",
        "3. Receiving: resynchronisation",
        "4. Exchanges",
        "5. Commands",
        "6. Telemetry packets",
        "7. Events",
        "8. Error codes",
        "",
        *_frame_format(),
        *_example(d),
        *_receiving(),
        *_exchanges(d),
        *_commands(d),
        *_packets(
            "## 6. Telemetry packets",
            "Device → host in TELEMETRY frames, unsolicited; the opcode field is the packet id.",
            d.telemetry,
        ),
        *_packets(
            "## 7. Events",
            "Device → host in EVENT frames, unsolicited; the opcode field is the event id.",
            d.events,
        ),
        *_errors(d),
    ]
    return "\n".join(lines).rstrip("\n") + "\n"


def main(argv: Sequence[str] | None = None) -> int:
    parser = docgen_parser(
        "python -m camd.protocol.docgen",
        "Generate docs/protocol.md from the frame codec and the command dictionary.",
        "protocol.md",
    )
    parser.add_argument(
        "--dictionary",
        type=Path,
        default=None,
        help="command dictionary (default: the shipped config/protocol.toml)",
    )
    args = parser.parse_args(argv)
    output: Path = args.output
    try:
        text = render_protocol_doc(load_dictionary(args.dictionary))
    except DictionaryError as exc:
        print(f"docgen: {exc}", file=sys.stderr)
        return 2
    return write_or_check(output, text, check=args.check, command="python -m camd.protocol.docgen")


if __name__ == "__main__":
    raise SystemExit(main())
