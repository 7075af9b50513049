"""The simulated FX3 paces a stream by deadlines: frame k is due at start + k periods.

A frame made late is followed by the next one at once, not a period after it, so short delays
(a busy machine's wake-up latency, a slow render) cost no frames of the line rate: the stream
catches up. Only a delay beyond the catch-up bound (``MAX_LAG_S``, or ``MAX_LAG_FRAMES``
periods at high line rates) restarts the schedule, so that a long stall is not followed by a
flood. The clock here is plain numbers: the pacer never reads one.
"""

from __future__ import annotations

import pytest

from firmware_models.pacing import MAX_LAG_FRAMES, MAX_LAG_S, Pacer

PERIOD_S = 0.010


def test_on_time_a_block_waits_until_its_last_frame_is_due() -> None:
    pacer = Pacer(100.0)
    assert pacer.wait_s(1, PERIOD_S, now_s=100.0) == 0.0  # frame 0 is due at the start
    pacer.advance(PERIOD_S)
    assert pacer.wait_s(1, PERIOD_S, now_s=100.002) == pytest.approx(0.008)
    pacer.advance(PERIOD_S)
    # A block of 4 (frames 2..5) goes out when frame 5 is due: none leaves early.
    assert pacer.wait_s(4, PERIOD_S, now_s=100.010) == pytest.approx(0.040)
    pacer.advance(PERIOD_S, 4)
    assert pacer.due_s == pytest.approx(100.060)
    assert pacer.restarts == 0


def test_a_late_frame_is_followed_by_the_next_at_once_until_caught_up() -> None:
    pacer = Pacer(0.0)
    # Frame 0 made 35 ms late (a slow render): frames 1, 2, 3 are already due, so they follow
    # without a wait; frame 4 (due at 40 ms) waits again.
    assert pacer.wait_s(1, PERIOD_S, now_s=0.035) == 0.0
    pacer.advance(PERIOD_S)
    for k in (1, 2, 3):
        assert pacer.wait_s(1, PERIOD_S, now_s=0.036 + 0.001 * k) == 0.0
        pacer.advance(PERIOD_S)
    assert pacer.wait_s(1, PERIOD_S, now_s=0.0395) == pytest.approx(0.0005)
    assert pacer.due_s == pytest.approx(0.040)  # still the schedule from the start
    assert pacer.restarts == 0


def test_catching_up_makes_every_frame_already_due_in_one_block() -> None:
    pacer = Pacer(0.0)
    # 50 ms behind: frames 0..5 are due; one block of them (at least the usual block size).
    assert pacer.block_frames(1, PERIOD_S, 64, now_s=0.050) == 6
    assert pacer.block_frames(8, PERIOD_S, 64, now_s=0.050) == 8
    assert pacer.block_frames(1, PERIOD_S, 4, now_s=0.050) == 4  # at most the maximum
    assert pacer.block_frames(3, PERIOD_S, 64, now_s=0.0) == 3  # on time: the usual block


def test_a_stall_beyond_the_bound_restarts_the_schedule() -> None:
    pacer = Pacer(0.0)
    stall_s = MAX_LAG_S + 0.1
    assert pacer.wait_s(1, PERIOD_S, now_s=stall_s) == 0.0
    assert pacer.restarts == 1
    assert pacer.due_s == pytest.approx(stall_s)  # frame 0 goes now, frame 1 a period later
    pacer.advance(PERIOD_S)
    assert pacer.wait_s(1, PERIOD_S, now_s=stall_s) == pytest.approx(PERIOD_S)


def test_at_high_line_rates_the_bound_is_a_number_of_frames() -> None:
    period_s = 41e-6  # hr400 at M = 1
    bound_s = MAX_LAG_FRAMES * period_s
    assert bound_s < MAX_LAG_S
    pacer = Pacer(0.0)
    assert pacer.wait_s(1, period_s, now_s=0.9 * bound_s) == 0.0
    assert pacer.restarts == 0  # within the bound: catch up
    pacer = Pacer(0.0)
    assert pacer.wait_s(1, period_s, now_s=1.1 * bound_s) == 0.0
    assert pacer.restarts == 1
