"""The command dictionary (camd.protocol.dictionary): shipped data, codecs, errors, validation.

Expected payload bytes are derived by hand from the field layouts in config/protocol.toml; type
widths and ranges below are written out here, not taken from the module under test.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from camd.protocol import (
    MAX_PAYLOAD,
    Decoder,
    Dictionary,
    DictionaryError,
    EncodeError,
    FieldSpec,
    FrameType,
    PayloadError,
    encode_frame,
    load_dictionary,
)

DICT = load_dictionary()

WIDTH = {"u8": 1, "u16": 2, "u32": 4, "u64": 8, "i8": 1, "i16": 2, "i32": 4, "i64": 8, "f32": 4}
INT_RANGE = {
    "u8": (0, 255),
    "u16": (0, 65535),
    "u32": (0, 4294967295),
    "i8": (-128, 127),
    "i16": (-32768, 32767),
    "i32": (-2147483648, 2147483647),
    "u64": (0, 2**64 - 1),
    "i64": (-(2**63), 2**63 - 1),
}


# -- value strategies, one per FieldSpec -----------------------------------------------------------


def _f32_inside(x: float, towards: float) -> float:
    """The float32 nearest to ``x`` on the ``towards`` side (hypothesis wants exact bounds)."""
    y = np.float32(x)
    if (towards > x and float(y) < x) or (towards < x and float(y) > x):
        y = np.nextafter(y, np.float32(towards))
    return float(y)


def value_strategy(f: FieldSpec) -> st.SearchStrategy[Any]:
    if f.type == "bytes":
        assert f.max_len is not None
        return st.binary(max_size=f.max_len)
    if f.type == "str":
        n = f.max_len
        assert n is not None
        # Characters may take up to 4 UTF-8 bytes: cut to max_len bytes at a character boundary.
        return st.text(max_size=n).map(lambda s: s.encode()[:n].decode(errors="ignore"))
    if f.enum is not None:
        return st.sampled_from(sorted(f.enum))
    if f.type == "f32":
        lo = -math.inf if f.min is None else _f32_inside(f.min, math.inf)
        hi = math.inf if f.max is None else _f32_inside(f.max, -math.inf)
        return st.floats(lo, hi, width=32, allow_nan=False, allow_infinity=False)
    raw_lo, raw_hi = INT_RANGE[f.type]
    if f.scale == 1.0:
        lo_i = raw_lo if f.min is None else max(raw_lo, math.ceil(f.min))
        hi_i = raw_hi if f.max is None else min(raw_hi, math.floor(f.max))
        return st.integers(lo_i, hi_i)
    lo_p = raw_lo * f.scale if f.min is None else max(raw_lo * f.scale, f.min)
    hi_p = raw_hi * f.scale if f.max is None else min(raw_hi * f.scale, f.max)
    return st.floats(lo_p, hi_p, allow_nan=False, allow_infinity=False)


def values_for(fields: list[FieldSpec]) -> st.SearchStrategy[dict[str, Any]]:
    return st.fixed_dictionaries({f.name: value_strategy(f) for f in fields})


def expected_size(fields: list[FieldSpec], values: dict[str, Any]) -> int:
    size = 0
    for f in fields:
        if f.type == "bytes":
            size += len(values[f.name])
        elif f.type == "str":
            size += len(values[f.name].encode())
        else:
            size += WIDTH[f.type]
    return size


def assert_round_trip(fields: list[FieldSpec], sent: dict[str, Any], got: dict[str, Any]) -> None:
    assert list(got) == [f.name for f in fields]
    for f in fields:
        a, b = sent[f.name], got[f.name]
        if f.type in ("bytes", "str") or f.enum is not None or f.type == "f32":
            assert b == a, f.name
            assert type(b) is type(a), f.name
        elif f.scale == 1.0:
            assert b == a, f.name
            assert type(b) is int, f.name
        else:  # scaled integer: quantised to the nearest multiple of scale
            # Half a raw step, or the float64 spacing of a value as large as a u64 allows.
            tolerance = f.scale / 2 * (1 + 1e-9) + 4 * math.ulp(abs(a))
            assert abs(b - a) <= tolerance, (f.name, a, b)


def check_layout_round_trip(
    fields: list[FieldSpec], encode: Any, decode: Any, values: dict[str, Any]
) -> bytes:
    payload = encode(**values)
    assert isinstance(payload, bytes)
    assert len(payload) == expected_size(fields, values)
    assert len(payload) <= MAX_PAYLOAD
    assert_round_trip(fields, values, decode(payload))
    return payload


# -- round trips of the shipped dictionary ---------------------------------------------------------

COMMANDS = [c.name for c in DICT.commands]
TELEMETRY = [p.name for p in DICT.telemetry]
EVENTS = [p.name for p in DICT.events]


@settings(max_examples=60)
@pytest.mark.parametrize("name", COMMANDS)
@given(data=st.data())
def test_command_round_trip(name: str, data: st.DataObject) -> None:
    cmd = DICT.command(name)
    request = data.draw(values_for(cmd.request), label="request")
    payload = check_layout_round_trip(cmd.request, cmd.encode_request, cmd.decode_request, request)
    response = data.draw(values_for(cmd.response), label="response")
    check_layout_round_trip(cmd.response, cmd.encode_response, cmd.decode_response, response)
    # The payload travels in a frame unchanged.
    wire = encode_frame(FrameType.COMMAND, 7, cmd.opcode, payload)
    (frame,) = Decoder().feed(wire)
    assert DICT.command(frame.opcode) is cmd
    assert_round_trip(cmd.request, request, cmd.decode_request(frame.payload))


@settings(max_examples=60)
@pytest.mark.parametrize("name", TELEMETRY)
@given(data=st.data())
def test_telemetry_round_trip(name: str, data: st.DataObject) -> None:
    pkt = DICT.telemetry_packet(name)
    values = data.draw(values_for(pkt.fields))
    check_layout_round_trip(pkt.fields, pkt.encode, pkt.decode, values)


@settings(max_examples=30)
@pytest.mark.parametrize("name", EVENTS)
@given(data=st.data())
def test_event_round_trip(name: str, data: st.DataObject) -> None:
    pkt = DICT.event(name)
    values = data.draw(values_for(pkt.fields))
    check_layout_round_trip(pkt.fields, pkt.encode, pkt.decode, values)


# A dictionary that uses every field type and bound combination the shipped one does not.
ALL_TYPES = Dictionary.model_validate(
    {
        "version": 1,
        "errors": [{"code": 1, "name": "E", "message": "e"}],
        "commands": [
            {
                "name": "ALL",
                "opcode": 0x10,
                "request": [
                    {"name": "a", "type": "i8"},
                    {"name": "b", "type": "i32", "scale": 0.5, "unit": "m", "min": -1000.0},
                    {"name": "c", "type": "i16", "min": -5, "max": 5},
                    {"name": "d", "type": "f32"},
                    {"name": "e", "type": "u32", "scale": 1e-6, "max": 10.0},
                    {"name": "f", "type": "i8", "enum": {"neg": -128, "zero": 0, "pos": 127}},
                    {"name": "g", "type": "str", "max_len": 20},
                ],
                "response": [{"name": "blob", "type": "bytes", "max_len": 1024}],
            }
        ],
    }
)


@given(data=st.data())
def test_every_field_type_round_trips(data: st.DataObject) -> None:
    cmd = ALL_TYPES.command("ALL")
    request = data.draw(values_for(cmd.request))
    check_layout_round_trip(cmd.request, cmd.encode_request, cmd.decode_request, request)
    response = data.draw(values_for(cmd.response))
    check_layout_round_trip(cmd.response, cmd.encode_response, cmd.decode_response, response)


# -- hand-derived payload vectors ------------------------------------------------------------------


def test_set_mode_vectors() -> None:
    cmd = DICT.command("SET_MODE")
    assert cmd.opcode == 0x05
    assert cmd.encode_request(mode="area") == b"\x00"
    assert cmd.encode_request(mode="tdi") == b"\x01"
    assert cmd.decode_response(b"\x01") == {"mode": "tdi"}


def test_get_status_vector() -> None:
    cmd = DICT.command("GET_STATUS")
    values = {
        "mode": "tdi",
        "device_state": "fault",
        "fault_code": 6,
        "uptime_s": 12.345,  # 12345 ms = 0x3039
        "fw_version": 0x0102,
        "boot_count": 3,
    }
    wire = bytes.fromhex("01 02 0006 00003039 0102 0003")
    assert cmd.encode_response(**values) == wire
    back = cmd.decode_response(wire)
    assert back["uptime_s"] == pytest.approx(12.345, abs=1e-9)
    assert {k: v for k, v in back.items() if k != "uptime_s"} == {
        k: v for k, v in values.items() if k != "uptime_s"
    }


HK_VALUES = {
    "uptime_s": 1.5,  # 1500 = 0x000005DC
    "fpga_temp_degc": -12.5,  # -1250 = 0xFB1E (two's complement)
    "sensor_temp_degc": 25.0,  # 2500 = 0x09C4
    "vcc_core_v": 1.0,  # 1000 = 0x03E8
    "vcc_io_v": 3.3,  # 3300 = 0x0CE4
    "vcc_sensor_v": 2.8,  # 2800 = 0x0AF0
    "supply_current_a": 0.25,  # 250 = 0x00FA
    "executed": 7,
}
HK_WIRE = bytes.fromhex("000005DC FB1E 09C4 03E8 0CE4 0AF0 00FA 00000007")


def test_housekeeping_vector_and_get_housekeeping_shares_it() -> None:
    assert DICT.telemetry_packet("HOUSEKEEPING").encode(**HK_VALUES) == HK_WIRE
    assert DICT.telemetry_packet(0x01).name == "HOUSEKEEPING"
    cmd = DICT.command("GET_HOUSEKEEPING")
    assert cmd.response_from_telemetry == "HOUSEKEEPING"
    assert cmd.encode_response(**HK_VALUES) == HK_WIRE
    back = cmd.decode_response(HK_WIRE)
    assert back["fpga_temp_degc"] == pytest.approx(-12.5)
    assert back["vcc_io_v"] == pytest.approx(3.3)
    assert back["executed"] == 7


def test_sim_set_inject_f32_vector() -> None:
    cmd = DICT.command("SIM_SET_INJECT")
    assert cmd.simulator_only
    payload = cmd.encode_request(ber=0.0, drop=0.5, garbage=0.25, delay_ms=1000.0)
    assert payload == bytes.fromhex("00000000 3F000000 3E800000 447A0000")


def test_other_vectors() -> None:
    assert DICT.command("PING").encode_request(data=b"\x00\xff") == b"\x00\xff"
    assert DICT.command("SIM_SET_FAULT").encode_request(fault_code=0x1234) == b"\x12\x34"
    assert DICT.command("RESET").encode_request() == b""
    assert DICT.event("MODE_CHANGED").encode(mode="tdi") == b"\x01"
    assert DICT.event(0x03).decode(b"\x00\x06") == {"fault_code": 6}


def test_lookups_and_simulator_range() -> None:
    assert DICT.command(0x05).name == "SET_MODE"
    assert DICT.command_for_opcode(0x99) is None
    with pytest.raises(KeyError, match="unknown command 'NOPE'; the dictionary has: PING, "):
        DICT.command("NOPE")
    with pytest.raises(KeyError, match="unknown event 9"):
        DICT.event(9)
    assert {c.name for c in DICT.commands if c.simulator_only} == {
        "SIM_GET_INJECTED",
        "SIM_SET_INJECT",
        "SIM_GET_SPI_STATS",
        "SIM_RESKEW",
        "SIM_SET_FAULT",
        "SIM_GET_STREAM_STATS",
        "SIM_SET_SCENE",
        "SIM_SET_STAGE",
        "SIM_SET_STAGE_FAULTS",
        "SIM_GET_STAGE",
        "SIM_SET_POLARIZER",
        "SIM_SET_SEED",
        "SIM_FAIL_NEXT",
    }
    assert all(c.name.startswith("SIM_") == (c.opcode >= 0xF0) for c in DICT.commands)


# -- encode errors: the message names the field, the value and what is allowed ---------------------


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (
            lambda: DICT.command("SET_MODE").encode_request(mode="scan"),
            "SET_MODE.mode: 'scan' is not valid; use one of area, tdi",
        ),
        (
            lambda: DICT.command("SET_MODE").encode_request(mode=1),
            "SET_MODE.mode: 1 is not valid; use one of area, tdi",
        ),
        (
            lambda: DICT.command("SIM_SET_INJECT").encode_request(
                ber=0.02, drop=0, garbage=0, delay_ms=0
            ),
            "SIM_SET_INJECT.ber: 0.02 is out of range (0 .. 0.01)",
        ),
        (
            lambda: DICT.command("SIM_SET_INJECT").encode_request(
                ber=0, drop=0, garbage=0, delay_ms=-1
            ),
            "SIM_SET_INJECT.delay_ms: -1 is out of range (0 .. 1000 ms)",
        ),
        (
            lambda: DICT.command("SIM_SET_INJECT").encode_request(
                ber=math.nan, drop=0, garbage=0, delay_ms=0
            ),
            "SIM_SET_INJECT.ber: nan is not a finite number",
        ),
        (
            lambda: DICT.command("SIM_SET_FAULT").encode_request(fault_code=0),
            "SIM_SET_FAULT.fault_code: 0 is out of range (1 .. 65535)",
        ),
        (
            lambda: DICT.command("SIM_SET_FAULT").encode_request(fault_code=True),
            "SIM_SET_FAULT.fault_code: expected a number, got True",
        ),
        (
            lambda: DICT.command("SIM_SET_FAULT").encode_request(fault_code="3"),
            "SIM_SET_FAULT.fault_code: expected a number, got '3'",
        ),
        (
            lambda: DICT.telemetry_packet("HOUSEKEEPING").encode(**{**HK_VALUES, "uptime_s": -1}),
            "HOUSEKEEPING.uptime_s: -1 is out of range (0 .. 4294967.295 s)",
        ),
        (
            lambda: DICT.telemetry_packet("HOUSEKEEPING").encode(
                **{**HK_VALUES, "uptime_s": 4294967.3}
            ),
            "HOUSEKEEPING.uptime_s: 4294967.3 is out of range (0 .. 4294967.295 s)",
        ),
        (
            lambda: DICT.telemetry_packet("HOUSEKEEPING").encode(
                **{**HK_VALUES, "fpga_temp_degc": 400}
            ),
            "HOUSEKEEPING.fpga_temp_degc: 400 is out of range (-327.68 .. 327.67 degC)",
        ),
        (
            lambda: DICT.event("BOOT").encode(boot_count=65536),
            "BOOT.boot_count: 65536 is out of range (0 .. 65535)",
        ),
        (
            lambda: DICT.command("PING").encode_request(data=bytes(257)),
            "PING.data: 257 bytes is too long (at most 256 bytes)",
        ),
        (
            lambda: DICT.command("PING").encode_request(data="hello"),
            "PING.data: expected bytes, got str",
        ),
        (
            lambda: DICT.command("SET_MODE").encode_request(mode="tdi", speed=3),
            "SET_MODE: unknown field(s) speed; fields: mode",
        ),
        (
            lambda: DICT.command("RESET").encode_request(x=1),
            "RESET: unknown field(s) x; fields: none",
        ),
        (
            lambda: DICT.command("SIM_SET_INJECT").encode_request(ber=0),
            "SIM_SET_INJECT: missing field(s) drop, garbage, delay_ms",
        ),
        (
            lambda: FieldSpec(name="x", type="f32").encode(1e39, "T"),
            "T.x: 1e+39 does not fit in f32",
        ),
        (
            lambda: FieldSpec(name="n", type="i8").encode(-129, "T"),
            "T.n: -129 is out of range (-128 .. 127)",
        ),
    ],
)
def test_encode_error_messages(call: Any, message: str) -> None:
    with pytest.raises(EncodeError) as info:
        call()
    assert str(info.value) == message
    assert isinstance(info.value, ValueError)  # callers may catch ValueError


# -- decode errors: PayloadError and nothing else --------------------------------------------------

LAYOUTS = [
    *((f"{c.name} request", c.request, c.decode_request) for c in DICT.commands),
    *((f"{c.name} response", c.response, c.decode_response) for c in DICT.commands),
    *((f"{p.name} telemetry", p.fields, p.decode) for p in DICT.telemetry),
    *((f"{p.name} event", p.fields, p.decode) for p in DICT.events),
    *((f"ALL_TYPES {c.name}", c.request, c.decode_request) for c in ALL_TYPES.commands),
]
LAYOUT_IDS = [name for name, _, _ in LAYOUTS]


@settings(max_examples=30)
@pytest.mark.parametrize(("name", "fields", "decode"), LAYOUTS, ids=LAYOUT_IDS)
@given(data=st.data())
def test_short_and_long_payloads_raise_payload_error(
    name: str, fields: list[FieldSpec], decode: Any, data: st.DataObject
) -> None:
    values = data.draw(values_for(fields))
    payload = b"".join(f.encode(values[f.name], name) for f in fields)
    fixed = sum(WIDTH.get(f.type, 0) for f in fields)
    for cut in range(fixed):
        with pytest.raises(PayloadError):
            decode(payload[:cut])
    if not fields or fields[-1].type not in ("bytes", "str"):
        with pytest.raises(PayloadError, match=r"1 unexpected trailing byte\(s\)"):
            decode(payload + b"\x00")
    else:
        room = (fields[-1].max_len or 0) - (len(payload) - fixed)
        with pytest.raises(PayloadError, match="exceeds max_len"):
            decode(payload + b"a" * (room + 1))


@settings(max_examples=30)
@pytest.mark.parametrize(("name", "fields", "decode"), LAYOUTS, ids=LAYOUT_IDS)
@given(payload=st.binary(max_size=40))
def test_random_payloads_decode_or_raise_payload_error(
    name: str, fields: list[FieldSpec], decode: Any, payload: bytes
) -> None:
    try:
        values = decode(payload)
    except PayloadError:
        return
    assert list(values) == [f.name for f in fields]


def test_decode_error_messages() -> None:
    with pytest.raises(PayloadError) as info:
        DICT.command("GET_STATUS").decode_response(b"\x00")
    assert str(info.value) == "GET_STATUS.device_state: payload too short (1 bytes)"
    with pytest.raises(PayloadError) as info:
        DICT.command("SET_MODE").decode_request(b"\x01\x00")
    assert str(info.value) == "SET_MODE: 1 unexpected trailing byte(s)"
    with pytest.raises(PayloadError) as info:
        DICT.command("SET_MODE").decode_request(b"\x07")
    assert str(info.value) == "SET_MODE.mode: raw value 7 is not one of area, tdi"
    with pytest.raises(PayloadError) as info:
        DICT.command("PING").decode_request(bytes(257))
    assert str(info.value) == "PING.data: 257 bytes exceeds max_len 256"
    with pytest.raises(PayloadError, match=r"ALL\.g: not valid UTF-8"):
        ALL_TYPES.command("ALL").decode_request(bytes(19) + b"\xff")


# -- negative acknowledges -------------------------------------------------------------------------


def test_error_codes_are_as_shipped() -> None:
    assert {e.name: e.code for e in DICT.errors} == {
        "UNKNOWN_OPCODE": 1,
        "BAD_LENGTH": 2,
        "OUT_OF_RANGE": 3,
        "ILLEGAL_STATE": 4,
        "BUSY": 5,
        "DEVICE_FAULT": 6,
        "INTERNAL": 7,
        "REG_UNKNOWN": 8,
        "REG_READ_ONLY": 9,
        "REG_WRITE_ONLY": 10,
        "LINK_UNTRAINED": 11,
    }


def test_nak_encode_decode() -> None:
    payload = DICT.encode_nak("OUT_OF_RANGE", "ber 0.02 > 0.01")
    assert payload == b"\x00\x03ber 0.02 > 0.01"
    assert DICT.encode_nak(3, "ber 0.02 > 0.01") == payload
    assert DICT.decode_nak(payload) == (3, "ber 0.02 > 0.01")
    assert DICT.encode_nak("BUSY") == b"\x00\x05"
    assert DICT.decode_nak(b"\x01\x00") == (256, "")
    with pytest.raises(KeyError, match="unknown error 'NOPE'"):
        DICT.encode_nak("NOPE")
    for short in (b"", b"\x00"):
        with pytest.raises(
            PayloadError, match=f"NAK payload of {len(short)} bytes has no error code"
        ):
            DICT.decode_nak(short)


def test_nak_detail_is_truncated_to_fit_a_frame() -> None:
    payload = DICT.encode_nak("INTERNAL", "x" * 2000)
    assert len(payload) == MAX_PAYLOAD
    assert DICT.decode_nak(payload) == (7, "x" * (MAX_PAYLOAD - 2))


def test_nak_detail_is_cut_at_a_character_boundary() -> None:
    # 1 + 2 * 510 = 1021 bytes fit in the 1022 left after the code; the next "é" would not.
    assert DICT.decode_nak(DICT.encode_nak("BUSY", "a" + "é" * 600)) == (5, "a" + "é" * 510)


@settings(max_examples=50)
@given(detail=st.one_of(st.text(max_size=40), st.text(min_size=300, max_size=1100)))
def test_nak_detail_round_trips_as_a_prefix(detail: str) -> None:
    payload = DICT.encode_nak("BAD_LENGTH", detail)
    assert len(payload) <= MAX_PAYLOAD
    code, back = DICT.decode_nak(payload)
    assert code == 2
    assert detail.startswith(back)
    if len(detail.encode()) <= MAX_PAYLOAD - 2:
        assert back == detail
    else:  # only the character that did not fit whole is lost (UTF-8: at most 4 bytes)
        assert MAX_PAYLOAD - 2 - 3 <= len(back.encode()) <= MAX_PAYLOAD - 2


def test_describe_error_words() -> None:
    assert (
        DICT.describe_error(3, "ber 0.02 > 0.01")
        == "OUT_OF_RANGE (3): a parameter is outside its valid range: ber 0.02 > 0.01"
    )
    assert (
        DICT.describe_error(6) == "DEVICE_FAULT (6): the device is in fault; send RESET to clear it"
    )
    assert DICT.describe_error(99) == "error code 99 (not in the dictionary)"
    assert DICT.describe_error(99, "why") == "error code 99 (not in the dictionary): why"
    for e in DICT.errors:
        assert DICT.describe_error(e.code).startswith(f"{e.name} ({e.code}): ")
        assert len(e.message) > 10


# -- invalid dictionaries are rejected with the reason ---------------------------------------------

BASE = """
version = 1

[[errors]]
code = 1
name = "UNKNOWN_OPCODE"
message = "no such command"

[[commands]]
name = "PING"
opcode = 0x01
request = [{ name = "data", type = "bytes", max_len = 16 }]
response = [{ name = "data", type = "bytes", max_len = 16 }]

[[telemetry]]
name = "HK"
opcode = 0x01
fields = [{ name = "temp_degc", type = "i16", scale = 0.01, unit = "degC" }]
"""


def load_text(tmp_path: Path, text: str) -> Dictionary:
    path = tmp_path / "protocol.toml"
    path.write_text(text)
    return load_dictionary(path)


def test_base_dictionary_is_valid(tmp_path: Path) -> None:
    d = load_text(tmp_path, BASE)
    assert d.command(1).name == "PING"
    assert d.telemetry_packet("HK").fields[0].scale == 0.01


@pytest.mark.parametrize(
    ("extra", "reasons"),
    [
        pytest.param(
            '[[commands]]\nname = "ECHO"\nopcode = 0x01\n',
            ["command 'ECHO' repeats opcode 1 of 'PING'"],
            id="duplicate-opcode",
        ),
        pytest.param(
            '[[commands]]\nname = "PING"\nopcode = 0x02\n',
            ["command 'PING' repeats name 'PING'"],
            id="duplicate-name",
        ),
        pytest.param(
            '[[errors]]\ncode = 1\nname = "OTHER"\nmessage = "x"\n',
            ["error 'OTHER' repeats code 1 of 'UNKNOWN_OPCODE'"],
            id="duplicate-error-code",
        ),
        pytest.param(
            '[[commands]]\nname = "SEND"\nopcode = 0x02\n'
            'request = [{ name = "data", type = "bytes", max_len = 4 }, '
            '{ name = "flag", type = "u8" }]\n',
            ["command SEND request: variable-length field 'data' must be the last field"],
            id="variable-not-last",
        ),
        pytest.param(
            '[[commands]]\nname = "MODE"\nopcode = 0x02\n'
            'request = [{ name = "mode", type = "u8", enum = { area = 0, huge = 256 } }]\n',
            ["field 'mode': enum huge=256 does not fit u8"],
            id="enum-out-of-width",
        ),
        pytest.param(
            '[[commands]]\nname = "BIG"\nopcode = 0x02\n'
            'request = [{ name = "header", type = "u32" }, '
            '{ name = "data", type = "bytes", max_len = 1024 }]\n',
            ["command BIG request: up to 1028 bytes exceeds the 1024-byte payload limit"],
            id="payload-over-1024",
        ),
        pytest.param(
            '[[commands]]\nname = "HK_READ"\nopcode = 0x02\nresponse_from_telemetry = "HK"\n'
            'response = [{ name = "x", type = "u8" }]\n',
            ["command HK_READ: give response or response_from_telemetry"],
            id="response-and-response-from-telemetry",
        ),
        pytest.param(
            '[[commands]]\nname = "HK_READ"\nopcode = 0x02\nresponse_from_telemetry = "NOPE"\n',
            ["command HK_READ: no telemetry packet 'NOPE'"],
            id="missing-telemetry-packet",
        ),
        pytest.param(
            '[[commands]]\nname = "WIDE"\nopcode = 0x02\n'
            'request = [{ name = "count", type = "u128" }]\n',
            [":23: command WIDE: request.0.type: 'u128' is not allowed; use 'u8', 'u16'"],
            id="unknown-field-type",
        ),
        pytest.param(
            '[[commands]]\nname = "LIMITS"\nopcode = 0x02\n'
            'request = [{ name = "gain", type = "u8", min = 10, max = 1 }]\n',
            ["field 'gain': min 10.0 > max 1.0"],
            id="min-above-max",
        ),
        pytest.param(
            '[[commands]]\nname = "LIMITS"\nopcode = 0x02\n'
            'request = [{ name = "gain", type = "u8", scale = 0.1, max = 30 }]\n',
            ["field 'gain': bound 30.0 is not representable in u8 with scale 0.1"],
            id="bound-not-representable",
        ),
        pytest.param(
            '[[commands]]\nname = "OOPS"\nopcode = 0x02\ncolour = "red"\n',
            [":23: command OOPS: colour: unknown key; known keys: name, opcode"],
            id="unknown-key",
        ),
    ],
)
def test_invalid_dictionary_is_rejected_with_the_reason(
    tmp_path: Path, extra: str, reasons: list[str]
) -> None:
    with pytest.raises(DictionaryError) as info:
        load_text(tmp_path, BASE + "\n" + extra)
    message = str(info.value)
    # file:line: where: what (issue 31: it was pydantic's raw text over many lines)
    assert message.startswith(f"{tmp_path / 'protocol.toml'}:")
    assert "\n" not in message
    for reason in reasons:
        assert reason in message


def test_unreadable_dictionary(tmp_path: Path) -> None:
    with pytest.raises(DictionaryError, match="cannot read the command dictionary"):
        load_dictionary(tmp_path / "missing.toml")
    with pytest.raises(DictionaryError) as info:
        load_text(tmp_path, BASE + "\nversion = [\n")
    last = len((BASE + "\nversion = [\n").splitlines())  # the end of the file: its last line
    assert str(info.value) == (
        f"{tmp_path / 'protocol.toml'}:{last}: not valid TOML: Invalid value (at end of document)"
    )
