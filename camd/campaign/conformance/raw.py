"""Raw command frames through the daemon (POST /api/v1/link/command) and their evidence.

The protocol checks need what the daemon's own endpoints never send: any payload, a wrong
length, a value out of range, a retried frame. ``send`` sends one; ``answer_text`` and
``case`` turn the answer into evidence; ``invalid_payloads`` derives, from the dictionary alone,
the payloads that the spec says the device must refuse (BAD_LENGTH, OUT_OF_RANGE).
"""

from __future__ import annotations

import math
import struct
from typing import Any

from camd.client_types import LinkAnswer, LinkCommandResponse
from camd.protocol import CommandSpec, FieldSpec

from .engine import CheckFailed, Evidence, Unit

_STRUCT = {"u8": ">B", "u16": ">H", "u32": ">I", "u64": ">Q",
           "i8": ">b", "i16": ">h", "i32": ">i", "i64": ">q", "f32": ">f"}  # fmt: skip


def send(
    unit: Unit,
    command: str | None = None,
    *,
    opcode: int | None = None,
    fields: dict[str, Any] | None = None,
    payload: bytes | None = None,
    repeat: bool = False,
) -> LinkCommandResponse:
    """One command frame; its answer(s). ``fields`` bytes values are sent as hex."""
    if fields is not None:
        fields = {k: v.hex() if isinstance(v, bytes) else v for k, v in fields.items()}
    return unit.client.link_command(
        command, opcode=opcode, fields=fields, payload=payload, repeat=repeat
    )


def answer_text(answer: LinkAnswer) -> str:
    """``ACK`` or ``NAK NAME (code)``."""
    if answer["type"] == "ack":
        return "ACK"
    return f"NAK {answer['error_name'] or 'UNDEFINED'} ({answer['error_code']})"


def ack_values(unit: Unit, command: str, fields: dict[str, Any] | None = None) -> dict[str, Any]:
    """Send ``command`` and return its decoded ACK fields; CheckFailed with the answer if the
    device refused it (a command the check relies on, not the one it tests)."""
    response = send(unit, command, fields=fields)
    answer = response["answers"][0]
    if answer["type"] != "ack" or answer["values"] is None:
        raise CheckFailed(
            f"{command} was needed by the check and the device answered {answer_text(answer)}",
            {"command": command, "answer": answer_text(answer), "detail": answer["detail"]},
        )
    return dict(answer["values"])


def case(name: str, response: LinkCommandResponse, expected: str) -> Evidence:
    """One case's evidence: what was sent, expected and answered, and whether they agree."""
    answer = response["answers"][0]
    seen = answer_text(answer)
    ok = seen == expected or (expected.startswith("NAK ") and seen.startswith(expected + " ("))
    if ok and answer["type"] == "ack" and answer["values"] is None and response["command"]:
        ok = False  # an ACK must decode as the dictionary says
    return {
        "case": name,
        "sent_hex": response["request_hex"][:96]
        + ("..." if len(response["request_hex"]) > 96 else ""),
        "sent_bytes": len(response["request_hex"]) // 2,
        "expected": expected,
        "answer": seen,
        "detail": answer["detail"] or answer["decode_error"],
        "ok": ok,
    }


# -- payloads the spec says must be refused ------------------------------------------------------


def default_fields(spec: CommandSpec) -> dict[str, Any]:
    """Values for every request field that the dictionary accepts (zero, clamped into its
    range; the first enum name; empty bytes): the base the invalid payloads are patched from."""
    values: dict[str, Any] = {}
    for f in spec.request:
        if f.type == "bytes":
            values[f.name] = b""
        elif f.type == "str":
            values[f.name] = ""
        elif f.enum:
            values[f.name] = next(iter(f.enum))
        else:
            value = 0.0
            if f.min is not None:
                value = max(value, f.min)
            if f.max is not None:
                value = min(value, f.max)
            values[f.name] = value
    return values


def _fixed_size(f: FieldSpec) -> int | None:
    code = _STRUCT.get(f.type)
    return None if code is None else struct.calcsize(code)


def _out_of_range_raw(f: FieldSpec) -> tuple[Any, str] | None:
    """A value of ``f``'s type outside its enum or range (packed as the field), and why."""
    code = _STRUCT.get(f.type)
    if code is None:
        return None
    if f.enum:
        raw = max(f.enum.values()) + 1
        if raw < 1 << (8 * struct.calcsize(code)):
            return raw, f"{f.name} = {raw}, not one of {', '.join(f.enum)}"
        return None
    if f.type == "f32":
        if f.max is not None:
            value = f.max + max(1.0, abs(f.max)) * 0.5
            return value, f"{f.name} = {value:g}, above its maximum {f.max:g}"
        return None
    bits = 8 * struct.calcsize(code)
    signed = f.type.startswith("i")
    type_min, type_max = (
        (-(1 << (bits - 1)), (1 << (bits - 1)) - 1) if signed else (0, (1 << bits) - 1)
    )
    if f.max is not None:
        raw = math.floor(f.max / f.scale + 1e-9) + 1
        if raw <= type_max:
            return raw, f"{f.name} raw {raw} (= {raw * f.scale:g}), above its maximum {f.max:g}"
    if f.min is not None:
        raw = math.ceil(f.min / f.scale - 1e-9) - 1
        if raw >= type_min:
            return raw, f"{f.name} raw {raw} (= {raw * f.scale:g}), below its minimum {f.min:g}"
    return None


def invalid_payloads(spec: CommandSpec) -> list[tuple[str, bytes, str]]:
    """(case, payload, expected answer) for the refusals the dictionary implies: a payload one
    byte too long (BAD_LENGTH) and, for the first field with an enum or a range narrower than
    its type, a value outside it (OUT_OF_RANGE)."""
    cases: list[tuple[str, bytes, str]] = []
    valid = spec.encode_request(**default_fields(spec))
    fixed = [_fixed_size(f) for f in spec.request]
    if all(size is not None for size in fixed):
        longest = len(valid)
    else:
        tail = spec.request[-1]
        longest = sum(s for s in fixed if s is not None) + int(tail.max_len or 0)
    cases.append((f"{longest + 1} bytes: one more than the longest request", b"\0" * (longest + 1),
                  "NAK BAD_LENGTH"))  # fmt: skip
    offset = 0
    for f, size in zip(spec.request, fixed, strict=True):
        if size is None:
            break
        bad = _out_of_range_raw(f)
        if bad is not None:
            raw, why = bad
            patched = valid[:offset] + struct.pack(_STRUCT[f.type], raw) + valid[offset + size :]
            cases.append((why, patched, "NAK OUT_OF_RANGE"))
            break
        offset += size
    return cases
