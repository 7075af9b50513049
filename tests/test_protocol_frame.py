"""The RS-422 frame codec (camd.protocol.frame): fixed vectors, counters and properties.

Expected bytes are derived from the wire layout in frame.py's docstring; CRCs are checked against
a bit-by-bit CRC-16/CCITT-FALSE written here, independent of binascii.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterable, Sequence

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from camd.protocol import (
    MAX_PAYLOAD,
    OVERHEAD,
    SYNC,
    Decoder,
    Frame,
    FrameType,
    crc16,
    encode_frame,
)


def ref_crc16(data: bytes) -> int:
    """CRC-16/CCITT-FALSE bit by bit: poly 0x1021, init 0xFFFF, MSB first, no final xor."""
    crc = 0xFFFF
    for byte in data:
        crc ^= byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) if crc & 0x8000 else (crc << 1)
            crc &= 0xFFFF
    return crc


def decode_all(
    chunks: Iterable[bytes], decoder: Decoder | None = None
) -> tuple[list[Frame], Decoder]:
    """Feed every chunk, then flush like the transport at an inter-byte timeout until empty."""
    dec = decoder if decoder is not None else Decoder()
    out: list[Frame] = []
    for chunk in chunks:
        out += dec.feed(chunk)
    while dec.pending:
        before = dec.pending
        out += dec.flush_partial()
        assert dec.pending < before, "flush_partial must make progress"
    return out, dec


def is_subsequence(needles: Sequence[Frame], haystack: Sequence[Frame]) -> bool:
    it = iter(haystack)
    return all(any(h == n for h in it) for n in needles)


def split(data: bytes, cuts: Iterable[int]) -> list[bytes]:
    points = [0, *sorted(set(cuts)), len(data)]
    return [data[a:b] for a, b in itertools.pairwise(points)]


def flip_bit(data: bytes, bit: int) -> bytes:
    out = bytearray(data)
    out[bit // 8] ^= 0x80 >> (bit % 8)
    return bytes(out)


# The hand vector: encode_frame(COMMAND, seq=0x05, opcode=0x01, payload=b"abc").
#   EB 90      sync word
#   01         type COMMAND
#   05         sequence
#   01         opcode
#   00 03      payload length 3, big-endian
#   61 62 63   "abc"
#   4C E0      CRC-16/CCITT-FALSE of 01 05 01 00 03 61 62 63, big-endian
HAND = bytes.fromhex("eb90 01 05 01 0003 616263 4ce0")
HAND_FRAME = Frame(FrameType.COMMAND, 0x05, 0x01, b"abc")


# -- fixed vectors ---------------------------------------------------------------------------------


def test_crc16_check_value() -> None:
    assert crc16(b"123456789") == 0x29B1
    assert ref_crc16(b"123456789") == 0x29B1
    assert crc16(b"") == 0xFFFF  # the initial value, no final xor


def test_hand_vector_crc() -> None:
    assert ref_crc16(bytes.fromhex("0105010003616263")) == 0x4CE0


def test_encode_hand_vector() -> None:
    assert encode_frame(FrameType.COMMAND, seq=0x05, opcode=0x01, payload=b"abc") == HAND
    assert HAND_FRAME.encode() == HAND


def test_encode_empty_payload_vector() -> None:
    # ACK, seq 0xFF, opcode 0xF0, no payload; CRC of 02 FF F0 00 00 is 0xFD7E.
    assert ref_crc16(bytes.fromhex("02fff00000")) == 0xFD7E
    assert encode_frame(FrameType.ACK, 0xFF, 0xF0) == bytes.fromhex("eb90 02 ff f0 0000 fd7e")


def test_encode_max_payload_length_field() -> None:
    wire = encode_frame(FrameType.TELEMETRY, 0, 0, bytes(MAX_PAYLOAD))
    assert wire[5:7] == b"\x04\x00"  # 1024, big-endian
    assert len(wire) == 1024 + 9
    assert Decoder().feed(wire) == [Frame(FrameType.TELEMETRY, 0, 0, bytes(MAX_PAYLOAD))]


def test_type_values() -> None:
    assert {t.name: int(t) for t in FrameType} == {
        "COMMAND": 1,
        "ACK": 2,
        "NAK": 3,
        "TELEMETRY": 4,
        "EVENT": 5,
    }


@pytest.mark.parametrize(
    ("seq", "opcode", "size", "message"),
    [
        (256, 0, 0, "sequence number 256 does not fit in 8 bits (0..255)"),
        (-1, 0, 0, "sequence number -1 does not fit in 8 bits (0..255)"),
        (0, 0x100, 0, "opcode 256 does not fit in 8 bits (0..255)"),
        (0, -1, 0, "opcode -1 does not fit in 8 bits (0..255)"),
        (0, 0, MAX_PAYLOAD + 1, "payload of 1025 bytes exceeds the maximum of 1024"),
    ],
)
def test_encode_rejects_fields_that_do_not_fit(
    seq: int, opcode: int, size: int, message: str
) -> None:
    with pytest.raises(ValueError) as info:
        encode_frame(FrameType.COMMAND, seq, opcode, bytes(size))
    assert str(info.value) == message


# -- counters against hand-built streams -----------------------------------------------------------

BAD_CRC = HAND[:-1] + bytes([HAND[-1] ^ 0x01])
# Type 0x07 does not exist; its CRC is correct so only the type check can reject it.
BAD_TYPE_BODY = bytes.fromhex("07 05 01 0003 616263")
BAD_TYPE = SYNC + BAD_TYPE_BODY + ref_crc16(BAD_TYPE_BODY).to_bytes(2, "big")


def stats_of(dec: Decoder) -> dict[str, int]:
    return dec.stats.as_dict()


def test_counters_garbage_without_sync() -> None:
    dec = Decoder()
    assert dec.feed(b"\x00\x11\x22") == []
    assert dec.pending == 0
    assert stats_of(dec) == {
        "bytes_in": 3,
        "frames": 0,
        "crc_errors": 0,
        "bad_type": 0,
        "oversize": 0,
        "resyncs": 1,
        "bytes_dropped": 3,
        "partial_flushes": 0,
    }


def test_counters_garbage_then_frame() -> None:
    dec = Decoder()
    assert dec.feed(b"\x00\x11\x22" + HAND) == [HAND_FRAME]
    assert (dec.stats.frames, dec.stats.resyncs, dec.stats.bytes_dropped) == (1, 1, 3)


def test_trailing_first_sync_byte_is_held_for_the_next_chunk() -> None:
    dec = Decoder()
    assert dec.feed(b"\x00" + HAND[:1]) == []
    assert dec.pending == 1  # the 0xEB waits for its partner
    assert (dec.stats.resyncs, dec.stats.bytes_dropped) == (1, 1)
    assert dec.feed(HAND[1:]) == [HAND_FRAME]
    assert (dec.stats.resyncs, dec.stats.bytes_dropped, dec.pending) == (1, 1, 0)


def test_counters_bad_type() -> None:
    dec = Decoder()
    assert dec.feed(BAD_TYPE) == []
    assert stats_of(dec) == {
        "bytes_in": 12,
        "frames": 0,
        "crc_errors": 0,
        "bad_type": 1,
        "oversize": 0,
        "resyncs": 1,
        "bytes_dropped": 12,
        "partial_flushes": 0,
    }
    assert dec.feed(HAND) == [HAND_FRAME]


def test_counters_oversize_decided_from_the_header_alone() -> None:
    dec = Decoder()
    # Length 0x0401 = 1025: rejected as soon as the 7 header bytes are in, without waiting.
    assert dec.feed(bytes.fromhex("eb90 01 05 01 0401")) == []
    assert dec.pending == 0
    assert (dec.stats.oversize, dec.stats.resyncs, dec.stats.bytes_dropped) == (1, 1, 7)


def test_custom_max_payload() -> None:
    dec = Decoder(max_payload=2)
    assert dec.feed(HAND) == []  # 3-byte payload
    assert (dec.stats.oversize, dec.stats.bytes_dropped) == (1, 12)
    two = encode_frame(FrameType.EVENT, 1, 2, b"hi")
    assert dec.feed(two) == [Frame(FrameType.EVENT, 1, 2, b"hi")]


def test_counters_crc_error() -> None:
    dec = Decoder()
    assert dec.feed(BAD_CRC) == []
    assert (dec.stats.crc_errors, dec.stats.resyncs, dec.stats.bytes_dropped) == (1, 1, 12)
    assert dec.pending == 0


def test_counters_mixed_stream() -> None:
    # 5 garbage bytes, good, bad CRC, good, bad type, good: every rejected candidate costs its
    # sync byte plus one resync that skips the rest of it.
    stream = bytes(5) + HAND + BAD_CRC + HAND + BAD_TYPE + HAND
    dec = Decoder()
    assert dec.feed(stream) == [HAND_FRAME] * 3
    assert dec.pending == 0
    assert stats_of(dec) == {
        "bytes_in": 5 + 5 * 12,
        "frames": 3,
        "crc_errors": 1,
        "bad_type": 1,
        "oversize": 0,
        "resyncs": 3,
        "bytes_dropped": 5 + 12 + 12,
        "partial_flushes": 0,
    }


def test_frame_hidden_inside_a_false_candidate_is_found() -> None:
    # A fake header claiming a 20-byte payload swallows HAND; once its 29 bytes are in, the CRC
    # fails and the scan restarts one byte after the fake sync word, finding HAND.
    fake = bytes.fromhex("eb90 01 00 00 0014")
    stream = fake + HAND + bytes(12)
    assert ref_crc16(stream[2:27]) != int.from_bytes(stream[27:29], "big")
    dec = Decoder()
    assert dec.feed(stream) == [HAND_FRAME]
    assert (dec.stats.crc_errors, dec.stats.resyncs, dec.stats.bytes_dropped) == (1, 2, 19)
    assert dec.pending == 0


def test_flush_partial_releases_frames_behind_a_stalled_candidate() -> None:
    fake = bytes.fromhex("eb90 04 00 00 0064")  # TELEMETRY claiming 100 bytes that never come
    dec = Decoder()
    assert dec.feed(fake + HAND) == []
    assert dec.pending == 19
    assert dec.flush_partial() == [HAND_FRAME]
    assert dec.pending == 0
    assert (dec.stats.partial_flushes, dec.stats.resyncs, dec.stats.bytes_dropped) == (1, 1, 7)
    assert dec.flush_partial() == []  # nothing pending: not counted
    assert dec.stats.partial_flushes == 1


def test_expire_gives_up_on_a_candidate_stalled_while_bytes_keep_arriving() -> None:
    fake = bytes.fromhex("eb90 04 00 00 0064")  # waits for 109 bytes
    dec = Decoder()
    assert dec.feed(fake, now_s=0.0) == []
    assert dec.feed(HAND, now_s=0.05) == []  # more bytes, same stalled head: age not reset
    assert dec.expire(now_s=0.10, max_age_s=0.1) == []  # exactly max_age: not yet
    assert dec.expire(now_s=0.11, max_age_s=0.1) == [HAND_FRAME]
    assert (dec.stats.partial_flushes, dec.stats.bytes_dropped, dec.pending) == (1, 7, 0)
    assert dec.expire(now_s=5.0, max_age_s=0.1) == []  # nothing pending


def test_expire_does_not_age_a_new_frame_by_the_idle_time_before_it() -> None:
    dec = Decoder()
    assert dec.feed(HAND, now_s=0.0) == [HAND_FRAME]
    # The line was idle for 10 s; the next frame arrives in two reads 2 ms apart.
    assert dec.feed(HAND[:1], now_s=10.0) == []
    assert dec.expire(now_s=10.001, max_age_s=0.1) == []
    assert dec.feed(HAND[1:5], now_s=10.002) == []
    assert dec.expire(now_s=10.002, max_age_s=0.1) == []
    assert dec.feed(HAND[5:], now_s=10.003) == [HAND_FRAME]
    assert dec.stats.partial_flushes == 0


def test_frames_split_byte_by_byte() -> None:
    stream = HAND + BAD_CRC + HAND
    dec = Decoder()
    out = [f for i in range(len(stream)) for f in dec.feed(stream[i : i + 1])]
    assert out == [HAND_FRAME, HAND_FRAME]
    assert (dec.stats.crc_errors, dec.stats.bytes_dropped, dec.pending) == (1, 12, 0)


@pytest.mark.parametrize(
    "frame_bytes", [HAND, encode_frame(FrameType.NAK, 0x80, 0x42, bytes(range(64)))]
)
def test_every_single_bit_flip_is_rejected_exhaustively(frame_bytes: bytes) -> None:
    for bit in range(len(frame_bytes) * 8):
        out, dec = decode_all([flip_bit(frame_bytes, bit)])
        assert out == [], f"bit {bit} flipped, frame still delivered"
        assert dec.stats.bytes_dropped == len(frame_bytes)


# -- properties ------------------------------------------------------------------------------------

# Payloads biased towards the sync bytes, so that frames carrying sync words and fake headers in
# their payload are common, and towards both ends of the length range.
_syncy_bytes = st.lists(
    st.one_of(st.sampled_from([0xEB, 0x90, 0x00, 0x01, 0x04]), st.integers(0, 255)), max_size=48
).map(bytes)
payloads = st.one_of(
    st.binary(max_size=MAX_PAYLOAD),
    _syncy_bytes,
    st.binary(min_size=MAX_PAYLOAD - 3, max_size=MAX_PAYLOAD),
)
small_payloads = st.one_of(st.binary(max_size=40), _syncy_bytes)


def frames_with(payload: st.SearchStrategy[bytes]) -> st.SearchStrategy[Frame]:
    return st.builds(
        Frame,
        type=st.sampled_from(list(FrameType)),
        seq=st.integers(0, 0xFF),
        opcode=st.integers(0, 0xFF),
        payload=payload,
    )


frames = frames_with(payloads)
small_frames = frames_with(small_payloads)


@given(crc_input=st.binary(max_size=300))
def test_crc16_matches_bitwise_reference(crc_input: bytes) -> None:
    assert crc16(crc_input) == ref_crc16(crc_input)


@given(frame=frames)
def test_round_trip_and_wire_layout(frame: Frame) -> None:
    wire = frame.encode()
    n = len(frame.payload)
    assert len(wire) == OVERHEAD + n
    assert wire[:2] == b"\xeb\x90"
    assert wire[2] == int(frame.type)
    assert wire[3] == frame.seq
    assert wire[4] == frame.opcode
    assert wire[5:7] == n.to_bytes(2, "big")
    assert wire[7 : 7 + n] == frame.payload
    assert wire[7 + n :] == ref_crc16(wire[2 : 7 + n]).to_bytes(2, "big")

    dec = Decoder()
    assert dec.feed(wire) == [frame]
    assert dec.pending == 0
    assert dec.stats.frames == 1
    assert dec.stats.bytes_dropped == 0


@given(batch=st.lists(small_frames, min_size=1, max_size=8), data=st.data())
def test_decoding_is_independent_of_chunking(batch: list[Frame], data: st.DataObject) -> None:
    stream = b"".join(f.encode() for f in batch)
    cuts = data.draw(st.lists(st.integers(0, len(stream)), max_size=24), label="cuts")
    dec = Decoder()
    out = [f for chunk in split(stream, cuts) for f in dec.feed(chunk)]
    assert out == batch
    assert dec.pending == 0
    assert dec.stats.bytes_dropped == 0
    assert dec.stats.resyncs == 0


@st.composite
def fake_headers(draw: st.DrawFn) -> bytes:
    """A sync word and a header with any type byte and any length (often a plausible one)."""
    type_ = draw(st.one_of(st.sampled_from([int(t) for t in FrameType]), st.integers(0, 255)))
    length = draw(st.one_of(st.integers(0, 64), st.integers(0, 0xFFFF)))
    seq_op = draw(st.binary(min_size=2, max_size=2))
    return SYNC + bytes([type_]) + seq_op + length.to_bytes(2, "big")


@st.composite
def truncated_frames(draw: st.DrawFn) -> bytes:
    wire = draw(small_frames).encode()
    return wire[: draw(st.integers(1, len(wire) - 1))]


@st.composite
def bit_flipped_frames(draw: st.DrawFn) -> bytes:
    wire = draw(small_frames).encode()
    return flip_bit(wire, draw(st.integers(0, len(wire) * 8 - 1)))


garbage = st.lists(
    st.one_of(
        st.binary(max_size=40),
        st.just(SYNC),
        st.just(SYNC[:1]),
        fake_headers(),
        truncated_frames(),
        bit_flipped_frames(),
    ),
    max_size=8,
).map(b"".join)


@given(junk=garbage, batch=st.lists(small_frames, min_size=1, max_size=6), data=st.data())
def test_resynchronises_after_garbage(junk: bytes, batch: list[Frame], data: st.DataObject) -> None:
    stream = junk + b"".join(f.encode() for f in batch)
    cuts = data.draw(st.lists(st.integers(0, len(stream)), max_size=8), label="cuts")
    out, dec = decode_all(split(stream, cuts))
    assert is_subsequence(batch, out), f"lost frames after {len(junk)} garbage bytes"
    # Every byte is either delivered in a frame or counted as dropped.
    assert dec.stats.bytes_dropped + sum(len(f.encode()) for f in out) == len(stream)


@given(
    junk=st.binary(max_size=200).map(lambda b: b.replace(b"\xeb", b"")),
    batch=st.lists(small_frames, min_size=1, max_size=6),
)
def test_garbage_without_sync_bytes_is_dropped_exactly(junk: bytes, batch: list[Frame]) -> None:
    dec = Decoder()
    out = dec.feed(junk + b"".join(f.encode() for f in batch))
    assert out == batch
    assert dec.pending == 0
    assert dec.stats.bytes_dropped == len(junk)
    assert dec.stats.resyncs == (1 if junk else 0)


def _check_malformed(data: bytes, cuts: Iterable[int] = ()) -> tuple[list[Frame], Decoder]:
    out, dec = decode_all(split(data, cuts))  # must not raise
    assert dec.stats.bytes_in == len(data)
    assert dec.stats.bytes_dropped + sum(len(f.encode()) for f in out) == len(data)
    for f in out:  # nothing is invented: every delivered frame is in the input as it stands
        assert f.encode() in data
    return out, dec


@given(data=st.one_of(st.binary(max_size=600), garbage), cuts=st.lists(st.integers(0, 600)))
def test_random_bytes_never_raise(data: bytes, cuts: list[int]) -> None:
    _check_malformed(data, [c for c in cuts if c <= len(data)])


@given(frame=frames, data=st.data())
def test_truncated_frame_is_held_then_dropped(frame: Frame, data: st.DataObject) -> None:
    wire = frame.encode()
    cut = data.draw(st.integers(1, len(wire) - 1), label="cut")
    dec = Decoder()
    assert dec.feed(wire[:cut]) == []
    assert dec.pending == cut  # waiting for the rest, nothing dropped yet
    out, _ = _check_malformed(wire[:cut])
    assert frame not in out


@given(frame=frames, data=st.data())
def test_single_bit_flip_is_never_delivered(frame: Frame, data: st.DataObject) -> None:
    wire = frame.encode()
    bit = data.draw(st.integers(0, len(wire) * 8 - 1), label="bit")
    out, dec = _check_malformed(flip_bit(wire, bit))
    assert frame not in out
    s = dec.stats
    assert s.crc_errors + s.bad_type + s.oversize + s.resyncs + s.partial_flushes >= 1


@settings(max_examples=50)
@given(frame=frames, data=st.data())
def test_bit_flipped_frame_does_not_hide_the_next_one(frame: Frame, data: st.DataObject) -> None:
    wire = frame.encode()
    bit = data.draw(st.integers(0, len(wire) * 8 - 1), label="bit")
    out, _ = decode_all([flip_bit(wire, bit) + HAND])
    assert frame not in out
    assert out[-1:] == [HAND_FRAME]
