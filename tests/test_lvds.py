"""LVDS link model and FPGA link training (firmware_models.lvds; docs/physics.md §3)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from firmware_models.lvds import (
    DEFAULT_TRAINING_WORD,
    Alignment,
    LaneSkew,
    LvdsLink,
    TestPattern,
    check_training_word,
    frame_to_lanes,
    lanes_to_frame,
    pattern_frame,
    prbs_frame,
    ramp_frame,
    rotations,
    training_frame,
)
from firmware_models.lvds_training import bit_errors, train, verify


def _late_bits(link: LvdsLink, lane: int, tap: int) -> int:
    """Whole bits the lane is late with this tap, from the drawn skew (test-side knowledge)."""
    skew = link.skews[lane]
    delay = skew.delay_taps + tap
    return skew.word_latency * link.word_bits + skew.bit_offset + -(-delay // link.taps_per_ui)


def _random_frame(rows: int, cols: int, seed: int, word_bits: int = 12) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 1 << word_bits, (rows, cols), dtype=np.uint16)


# -- property: training always locks and undoes the skews -----------------------------------------


@settings(max_examples=60)
@given(seed=st.integers(0, 2**32 - 1), rng_seed=st.integers(0, 2**16))
def test_training_locks_and_frame_is_bit_exact(seed: int, rng_seed: int) -> None:
    link = LvdsLink(seed=seed)
    result = train(link, DEFAULT_TRAINING_WORD, rng_seed=rng_seed)
    assert result.locked
    assert result.alignment.trained
    assert all(lane.locked for lane in result.lanes)

    frame = _random_frame(24, 2048, seed)
    assert np.array_equal(link.receive(frame, result.alignment), frame)
    assert verify(link, result.alignment) == 0

    period = link.taps_per_ui
    half_eye = (link.eye_width_taps - 1) // 2
    latencies = set()
    for lane in result.lanes:
        assert lane.eye_width_taps == link.eye_width_taps == 27
        # Taps after the start of the sampled bit: the eye spans J .. P - J, centre P / 2.
        into_bit = -(link.skews[lane.lane].delay_taps + lane.tap) % period
        margin = min(into_bit, period - into_bit) - link.jitter_taps
        assert margin >= half_eye - 1, (lane, into_bit)
        # The slip undoes the bit offset, slip + shift undo the word latency.
        late = _late_bits(link, lane.lane, lane.tap)
        assert lane.slips == late % link.word_bits
        latencies.add(late // link.word_bits + lane.shift)
    assert latencies == {result.alignment.latency}


@settings(max_examples=25)
@given(
    seed=st.integers(0, 2**32 - 1),
    lanes=st.sampled_from([1, 2, 4, 8]),
    word_bits=st.sampled_from([8, 10, 12, 14]),
    taps=st.sampled_from([16, 32, 64]),
)
def test_training_locks_for_other_link_geometries(
    seed: int, lanes: int, word_bits: int, taps: int
) -> None:
    link = LvdsLink(lanes=lanes, word_bits=word_bits, taps_per_ui=taps, jitter_taps=2, seed=seed)
    word = (1 << (word_bits // 2)) - 1  # half zeros, half ones: aperiodic
    result = train(link, word)
    assert result.locked
    frame = _random_frame(5, lanes * 40, seed, word_bits)
    assert np.array_equal(link.receive(frame, result.alignment), frame)


def test_eye_across_the_tap_wrap_is_found_circularly() -> None:
    # delay 10 puts the stable window at taps 25..31 and 0..19: split by the wrap-around.
    skews = [LaneSkew(delay_taps=10, bit_offset=5, word_latency=2)] * 8
    link = LvdsLink(skews=skews)
    result = train(link)
    assert result.locked
    lane = result.lanes[0]
    assert lane.eye == "-" * 20 + "x" * 5 + "-" * 7
    assert lane.tap == 6  # P/2 = 16 taps into the bit: -(10 + 6) % 32 == 16
    assert verify(link, result.alignment) == 0


def test_retraining_after_power_cycle() -> None:
    link = LvdsLink(seed=3)
    first = train(link)
    link.reskew(4)
    assert verify(link, first.alignment) > 0
    second = train(link)
    assert second.locked
    assert verify(link, second.alignment) == 0


def test_jitter_sets_eye_width() -> None:
    for jitter in (0, 1, 5, 10):
        link = LvdsLink(jitter_taps=jitter, seed=7)
        result = train(link)
        assert result.locked
        expected = 32 if jitter == 0 else 32 - 2 * jitter + 1
        assert {lane.eye_width_taps for lane in result.lanes} == {expected}


def test_eye_closed_by_jitter_is_refused() -> None:
    with pytest.raises(ValueError, match="closes the eye"):
        LvdsLink(jitter_taps=16)


# -- untrained link scrambles ---------------------------------------------------------------------


def test_untrained_link_scrambles_the_frame() -> None:
    link = LvdsLink(seed=0)
    frame = prbs_frame(32, 2048, 12, seed=5)
    got = link.receive(frame, Alignment.untrained(8))
    errors = bit_errors(frame, got)
    fraction = errors / (frame.size * 12)
    assert 0.35 < fraction < 0.65  # every lane is skewed: its bits are unrelated to what was sent
    assert np.count_nonzero(got != frame) > 0.9 * frame.size


def test_only_the_misaligned_lane_is_scrambled() -> None:
    link = LvdsLink(seed=11)
    alignment = train(link).alignment
    lane = next(k for k in range(8) if alignment.slips[k] < 11)
    alignment.slips[lane] += 1
    frame = ramp_frame(16, 2048)
    got = link.receive(frame, alignment)
    wrong_columns = np.flatnonzero((got != frame).any(axis=0))
    assert set(wrong_columns % 8) == {lane}
    # One more slip moves the word boundary one bit later: each word loses its MSB and takes
    # the next word's MSB as its LSB.
    sent = frame_to_lanes(frame)[lane].astype(np.uint32)
    expected = ((sent[:-1] << 1) | (sent[1:] >> 11)) & 0xFFF
    assert np.array_equal(frame_to_lanes(got)[lane][:-1], expected)


def test_wrong_lane_shift_moves_words_by_whole_words() -> None:
    link = LvdsLink(seed=12)
    alignment = train(link).alignment
    alignment.shifts[5] += 1  # one word later than the other lanes
    frame = ramp_frame(4, 256)
    got = frame_to_lanes(link.receive(frame, alignment))
    sent = frame_to_lanes(frame)
    assert np.array_equal(got[5][1:], sent[5][:-1])


def test_untrained_output_is_deterministic_per_seed() -> None:
    frame = _random_frame(8, 512, 1)
    a = LvdsLink(seed=9)
    b = LvdsLink(seed=9)
    assert a.skews == b.skews
    untrained = Alignment.untrained(8)
    assert np.array_equal(a.receive(frame, untrained), b.receive(frame, untrained))
    assert LvdsLink(seed=10).skews != a.skews


def test_metastable_tap_gives_different_bits_each_capture() -> None:
    skews = [LaneSkew(delay_taps=0, bit_offset=0, word_latency=0)] * 8
    link = LvdsLink(skews=skews)
    frame = prbs_frame(4, 512)
    # tap 0 samples right on the transitions: random wherever neighbouring bits differ.
    first = link.receive(frame, Alignment.untrained(8))
    second = link.receive(frame, Alignment.untrained(8))
    assert not np.array_equal(first, second)
    # Tap 16 samples the centre of the eye; delaying the data half a bit makes the clock edge
    # take the previous bit, which one slip undoes.
    centred = Alignment(taps=[16] * 8, slips=[1] * 8, shifts=[0] * 8)
    assert np.array_equal(link.receive(frame, centred), frame)


# -- dead lane ------------------------------------------------------------------------------------


def test_dead_lane_is_reported_not_locked() -> None:
    link = LvdsLink(seed=2, dead_lanes=[6])
    result = train(link)
    assert not result.locked
    assert not result.alignment.trained
    assert [lane.locked for lane in result.lanes] == [True] * 6 + [False, True]
    dead = result.lanes[6]
    assert dead.eye_width_taps == 0
    assert dead.eye == "x" * 32
    assert "no stable eye" in dead.reason
    # The live lanes are still aligned among themselves.
    frame = ramp_frame(8, 2048)
    got = link.receive(frame, result.alignment)
    live = np.arange(2048) % 8 != 6
    assert np.array_equal(got[:, live], frame[:, live])
    assert verify(link, result.alignment) > 0


def test_dead_lane_out_of_range_refused() -> None:
    with pytest.raises(ValueError, match="dead lanes"):
        LvdsLink(dead_lanes=[8])


# -- training word --------------------------------------------------------------------------------


@pytest.mark.parametrize("word", [0x000, 0xFFF, 0x555, 0xAAA, 0x249, 0x3CF, 0x0C3])
def test_training_word_equal_to_a_rotation_is_refused(word: int) -> None:
    with pytest.raises(ValueError, match=r"equals its own rotation by \d+ bit"):
        train(LvdsLink(seed=0), word)


def test_training_word_must_fit_the_word() -> None:
    with pytest.raises(ValueError, match="does not fit in 12 bits"):
        check_training_word(0x1003)


@pytest.mark.parametrize("word", [0x03F, 0x001, 0x0A7, 0x7FE])
def test_aperiodic_training_words_train(word: int) -> None:
    assert word not in rotations(word, 12)
    link = LvdsLink(seed=word)
    result = train(link, word)
    assert result.locked
    assert verify(link, result.alignment) == 0


def test_marker_must_differ_from_training_word_rotations() -> None:
    with pytest.raises(ValueError, match="rotations"):
        training_frame(1, 64, 0x03F, marker_word=0xFC0)


# -- frames, patterns, shapes ---------------------------------------------------------------------


def test_receive_preserves_shape_dtype_and_word_range() -> None:
    link = LvdsLink(seed=4)
    frame = _random_frame(534, 2048, 4)
    for alignment in (Alignment.untrained(8), train(link).alignment):
        got = link.receive(frame, alignment)
        assert got.shape == frame.shape
        assert got.dtype == np.uint16
        assert int(got.max()) <= 0xFFF


def test_receive_refuses_bad_frames_and_alignments() -> None:
    link = LvdsLink(seed=0)
    with pytest.raises(ValueError, match="multiple of the 8"):
        link.receive(np.zeros((2, 100), np.uint16), Alignment.untrained(8))
    with pytest.raises(ValueError, match="exceed 12 bits"):
        link.receive(np.full((2, 64), 0x1000, np.uint16), Alignment.untrained(8))
    with pytest.raises(ValueError, match="4 taps"):
        link.receive(np.zeros((2, 64), np.uint16), Alignment.untrained(4))
    bad_tap = Alignment(taps=[32] * 8, slips=[0] * 8, shifts=[0] * 8)
    with pytest.raises(ValueError, match="taps must be"):
        link.receive(np.zeros((2, 64), np.uint16), bad_tap)


def test_lane_mapping_is_column_modulo_lanes() -> None:
    frame = np.arange(2 * 32, dtype=np.uint16).reshape(2, 32)
    streams = frame_to_lanes(frame)
    assert streams.shape == (8, 8)
    assert list(streams[3]) == [3, 11, 19, 27, 35, 43, 51, 59]
    assert np.array_equal(lanes_to_frame(streams, 2, 32), frame)


def test_training_frame_sends_the_marker_on_all_lanes_at_once() -> None:
    frame = training_frame(2, 8 * 32, 0x03F, marker_word=0xA5A, marker_period=16)
    streams = frame_to_lanes(frame)
    markers = np.flatnonzero(streams[0] == 0xA5A)
    assert list(markers) == [0, 16, 32, 48]
    assert (streams == streams[0]).all()
    assert set(np.unique(streams)) == {0x03F, 0xA5A}


def test_test_patterns() -> None:
    assert pattern_frame(TestPattern.OFF, 2, 8) is None
    ramp = ramp_frame(3, 4096)
    assert ramp[0, 4095] == 4095 and ramp[1, 4095] == 0 and ramp[2, 5] == 7
    prbs = prbs_frame(64, 512, seed=3)
    assert prbs.dtype == np.uint16 and int(prbs.max()) <= 0xFFF
    bits = (prbs[..., None] >> np.arange(12)) & 1
    assert 0.48 < bits.mean() < 0.52
    assert not np.array_equal(prbs, prbs_frame(64, 512, seed=4))
    via_register = pattern_frame(TestPattern.PRBS, 64, 512, seed=3)
    assert via_register is not None and np.array_equal(prbs, via_register)
    training = pattern_frame(TestPattern.TRAINING, 1, 256)
    assert training is not None and int(training[0, 8]) == DEFAULT_TRAINING_WORD


def test_training_report_is_json_ready() -> None:
    result = train(LvdsLink(seed=5))
    report = result.to_dict()
    assert report["locked"] is True
    assert len(report["lanes"]) == 8
    assert set(report["lanes"][0]) >= {"lane", "tap", "eye_width_taps", "slips", "shift", "locked"}
    assert report["alignment"]["latency"] == result.alignment.latency
