"""The frame stream format (camd.protocol.stream) against the layout of docs/stream.md."""

from __future__ import annotations

import re
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from camd.protocol import (
    HEADER_BYTES,
    FrameFlags,
    FrameHeader,
    StreamFormatError,
    StreamMode,
    decode_header,
    encode_header,
    frame_header,
    payload_ok,
)
from camd.protocol.stream import pack_header, payload_crc32

ROOT = Path(__file__).resolve().parents[1]
STREAM_MD = ROOT / "docs" / "stream.md"

# The worked example of docs/stream.md: a 2 x 3 TDI frame, 12 bits, one pixel at 0xFFF.
EXAMPLE_PIXELS = np.array([[0x0001, 0x0203, 0x0405], [0x0FFF, 0x0000, 0x0800]], dtype="<u2")
EXAMPLE_FIELDS = {
    "counter": 7,
    "timestamp_ns": 1_000_000_000,
    "line_period_ns": 25_000,
    "bits": 12,
    "mode": StreamMode.TDI,
    "stages": 2,
    "stage_position": -5,
    "flags": FrameFlags.SATURATED,
}
# Written out field by field from the layout table, not produced by the code under test.
EXAMPLE_HEADER_HEX = (
    "43414d46"  # 0  magic "CAMF"
    "0100"  # 4  version 1
    "4000"  # 6  header_bytes 64
    "07000000"  # 8  counter 7
    "00ca9a3b00000000"  # 12 timestamp_ns 1e9 = 0x3B9ACA00
    "a8610000"  # 20 line_period_ns 25000 = 0x61A8
    "0200"  # 24 rows 2
    "0300"  # 26 cols 3
    "0c"  # 28 bits 12
    "01"  # 29 mode tdi
    "0200"  # 30 stages 2
    "fbffffff"  # 32 stage_position -5
    "04000000"  # 36 flags SATURATED
    "0c000000"  # 40 payload_bytes 2 * 3 * 2 = 12
    "dd8751f1"  # 44 payload_crc32 0xF15187DD
    "000000000000000000000000"  # 48 reserved
    "50a6507a"  # 60 header_crc32 0x7A50A650
)


def crc32_bitwise(data: bytes) -> int:
    """CRC-32/ISO-HDLC from its definition (reflected poly 0xEDB88320, init and xorout ~0)."""
    crc = 0xFFFFFFFF
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = (crc >> 1) ^ 0xEDB88320 if crc & 1 else crc >> 1
    return crc ^ 0xFFFFFFFF


def example_header() -> FrameHeader:
    return frame_header(EXAMPLE_PIXELS, **EXAMPLE_FIELDS)  # type: ignore[arg-type]


def test_the_crc_is_zlib_crc32_as_defined() -> None:
    assert crc32_bitwise(b"123456789") == zlib.crc32(b"123456789") == 0xCBF43926
    assert crc32_bitwise(EXAMPLE_PIXELS.tobytes()) == 0xF15187DD


@pytest.mark.parametrize(
    "nbytes", [0, 1, 4095, 4096, 4097, 8192 + 64, 65535, 65536, 65537, 200_000]
)
def test_payload_crc32_in_pieces_is_the_crc_of_the_whole(nbytes: int) -> None:
    # Up to 64 KiB the dispatcher's CRC runs in 4 KiB pieces (each keeps Python's GIL): the
    # pieces' chained CRC must be the CRC of the whole, at and around every piece boundary.
    data = np.random.default_rng(nbytes).integers(0, 256, nbytes, dtype=np.uint8).tobytes()
    assert payload_crc32(memoryview(data)) == zlib.crc32(data)


def test_header_bytes_match_the_hand_written_layout() -> None:
    h = example_header()
    wire = encode_header(h)
    assert len(wire) == HEADER_BYTES == 64
    assert wire.hex() == EXAMPLE_HEADER_HEX
    assert crc32_bitwise(wire[:60]) == struct.unpack_from("<I", wire, 60)[0]
    assert struct.calcsize("<4sHHIQIHHBBHiIII12xI") == 64
    assert decode_header(wire) == h


def test_pack_header_is_encode_header_without_the_checks() -> None:
    h = example_header()
    assert pack_header(h) == encode_header(h) == bytes.fromhex(EXAMPLE_HEADER_HEX)
    flagged = h._replace(flags=h.flags | FrameFlags.LAST)  # as the FX3 adds it
    assert pack_header(flagged) == encode_header(flagged)
    assert decode_header(pack_header(flagged)).flags & FrameFlags.LAST
    # It checks nothing: the payload size no longer matches, and only encode_header says so.
    wrong = h._replace(payload_bytes=h.payload_bytes + 2)
    with pytest.raises(StreamFormatError, match="payload_bytes is 14"):
        encode_header(wrong)
    with pytest.raises(StreamFormatError, match="payload_bytes is 14"):
        decode_header(pack_header(wrong))


def test_docs_worked_example_is_what_the_code_sends() -> None:
    text = STREAM_MD.read_text(encoding="utf-8")
    wire = encode_header(example_header())
    dumped = re.findall(r"^([0-9a-f]{2}) ((?:[0-9A-F]{2} ?){16})$", text, flags=re.MULTILINE)
    assert [int(off, 16) for off, _ in dumped] == [0, 16, 32, 48]
    assert bytes.fromhex("".join(row for _, row in dumped)) == wire
    assert "01 00 03 02 05 04 FF 0F 00 00 00 08" in text  # the payload bytes
    assert "0xF15187DD" in text and "0x7A50A650" in text and "0xCBF43926" in text


@given(
    counter=st.integers(0, 2**32 - 1),
    timestamp_ns=st.integers(0, 2**64 - 1),
    line_period_ns=st.integers(0, 2**32 - 1),
    rows=st.integers(1, 0xFFFF),
    cols=st.integers(1, 40),
    bits=st.integers(1, 16),
    tdi=st.booleans(),
    stages=st.integers(1, 0xFFFF),
    stage_position=st.integers(-(2**31), 2**31 - 1),
    flags=st.integers(0, 0x1F),
    payload_crc32=st.integers(0, 2**32 - 1),
)
def test_every_field_round_trips(
    counter: int,
    timestamp_ns: int,
    line_period_ns: int,
    rows: int,
    cols: int,
    bits: int,
    tdi: bool,
    stages: int,
    stage_position: int,
    flags: int,
    payload_crc32: int,
) -> None:
    h = FrameHeader(
        counter=counter,
        timestamp_ns=timestamp_ns,
        line_period_ns=line_period_ns,
        rows=rows,
        cols=cols,
        bits=bits,
        mode=StreamMode.TDI if tdi else StreamMode.AREA,
        stages=stages if tdi else 0,
        stage_position=stage_position,
        flags=FrameFlags(flags),
        payload_bytes=rows * cols * 2,
        payload_crc32=payload_crc32,
    )
    back = decode_header(encode_header(h))
    assert back == h
    assert type(back.mode) is StreamMode and type(back.flags) is FrameFlags


def test_decode_takes_any_buffer_and_ignores_what_follows() -> None:
    wire = encode_header(example_header())
    frame = bytearray(wire + EXAMPLE_PIXELS.tobytes())
    for buf in (bytes(frame), frame, memoryview(frame)):
        assert decode_header(buf) == example_header()


def test_frame_header_computes_sizes_and_crc() -> None:
    h = example_header()
    assert (h.rows, h.cols, h.payload_bytes, h.frame_bytes) == (2, 3, 12, 76)
    assert h.payload_crc32 == zlib.crc32(EXAMPLE_PIXELS.tobytes()) == 0xF15187DD
    assert payload_ok(h, EXAMPLE_PIXELS)
    assert payload_ok(h, EXAMPLE_PIXELS.tobytes())
    assert payload_ok(h, memoryview(bytearray(EXAMPLE_PIXELS.tobytes())))
    flipped = bytearray(EXAMPLE_PIXELS.tobytes())
    flipped[5] ^= 0x10
    assert not payload_ok(h, bytes(flipped))
    assert not payload_ok(h, EXAMPLE_PIXELS.tobytes()[:-2])  # wrong size
    wrapped = frame_header(EXAMPLE_PIXELS, **{**EXAMPLE_FIELDS, "counter": 2**32 + 3})  # type: ignore[arg-type]
    assert wrapped.counter == 3


@pytest.mark.parametrize(
    ("pixels", "message"),
    [
        (np.zeros((2, 3), dtype=np.uint8), r"2-D little-endian uint16 array, got 2-D uint8"),
        (np.zeros(6, dtype="<u2"), r"got 1-D uint16"),
        (np.zeros((2, 3), dtype=">u2"), r"little-endian uint16"),
        (np.zeros((3, 4), dtype="<u2")[:, ::2], r"C-contiguous"),
    ],
)
def test_frame_header_refuses_arrays_it_cannot_send(pixels: np.ndarray, message: str) -> None:
    with pytest.raises(StreamFormatError, match=message):
        frame_header(pixels, **EXAMPLE_FIELDS)  # type: ignore[arg-type]


def _patched(offset: int, fmt: str, value: int, *, fix_crc: bool = True) -> bytes:
    wire = bytearray(encode_header(example_header()))
    struct.pack_into(fmt, wire, offset, value)
    if fix_crc:
        struct.pack_into("<I", wire, 60, zlib.crc32(wire[:60]))
    return bytes(wire)


@pytest.mark.parametrize(
    ("wire", "message"),
    [
        (_patched(0, "<I", 0x46504D43), r"magic is b'CMPF', expected b'CAMF'"),
        (_patched(4, "<H", 2), r"version is 2, this host reads version 1"),
        (_patched(6, "<H", 32), r"header_bytes is 32, expected 64"),
        (
            _patched(8, "<I", 8, fix_crc=False),
            r"header_crc32 is 0x7A50A650, the header's bytes 0..59 give 0x[0-9A-F]{8}",
        ),
        (_patched(50, "<B", 1), r"reserved bytes 48..59 are not zero"),
        (_patched(29, "<B", 2), r"mode is 2, expected 0 \(area\) or 1 \(tdi\)"),
        (_patched(28, "<B", 17), r"bits is 17, expected 1 \.\. 16"),
        (_patched(28, "<B", 0), r"bits is 0, expected 1 \.\. 16"),
        (_patched(36, "<I", 0x24), r"flags = 0x24 has bits outside 0x1F"),
        (_patched(24, "<H", 0), r"rows x cols is 0 x 3"),
        (_patched(30, "<H", 0), r"stages is 0 in tdi mode"),
        (
            _patched(40, "<I", 14),
            r"payload_bytes is 14, but rows x cols = 2 x 3 uint16 pixels is 12",
        ),
        (encode_header(example_header())[:63], r"a frame header is 64 bytes, got 63"),
    ],
)
def test_each_corruption_is_refused_with_its_reason(wire: bytes, message: str) -> None:
    with pytest.raises(StreamFormatError, match=message) as exc:
        decode_header(wire)
    assert isinstance(exc.value, ValueError)


def test_area_mode_has_no_stages() -> None:
    wire = bytearray(encode_header(example_header()._replace(mode=StreamMode.AREA, stages=0)))
    struct.pack_into("<H", wire, 30, 4)
    struct.pack_into("<I", wire, 60, zlib.crc32(wire[:60]))
    with pytest.raises(StreamFormatError, match="stages is 4 in area mode, expected 0"):
        decode_header(wire)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"counter": 2**32}, r"counter = 4294967296 is outside 0 \.\. 4294967295"),
        ({"timestamp_ns": -1}, r"timestamp_ns = -1 is outside"),
        ({"stage_position": 2**31}, r"stage_position = 2147483648 is outside"),
        ({"bits": 17}, r"bits = 17 is outside 1 \.\. 16"),
        ({"rows": 70000}, r"rows = 70000 is outside 1 \.\. 65535"),
        ({"flags": FrameFlags(0x40)}, r"flags = 0x40 has bits outside 0x1F"),
        ({"payload_bytes": 10}, r"payload_bytes is 10, but rows x cols = 2 x 3"),
    ],
)
def test_encode_refuses_values_that_do_not_fit(change: dict[str, object], message: str) -> None:
    with pytest.raises(StreamFormatError, match=message):
        encode_header(example_header()._replace(**change))  # type: ignore[arg-type]
