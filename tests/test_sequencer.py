"""The HR400 rolling-shutter sequencer model (firmware_models.sequencer) against docs/physics.md §3.

The mission window of YE23 is rows 757..1290 (k = 534); dummy row 4000.
"""

from __future__ import annotations

import itertools

import pytest
from hypothesis import given
from hypothesis import strategies as st

from camd.timing import (
    exposure_s,
    sequencer_frame_period_lines,
    sequencer_frame_time_s,
    sequencer_line_period_s,
)
from firmware_models.sequencer import (
    DUMMY_ROW,
    first_frame_lines,
    frame_reads,
    line_addresses,
    rolling_sequence,
    row_exposures,
)

X, K = 757, 534
LAST = X + K - 1  # 1290
T_LINE_S = sequencer_line_period_s(25e6)


def take(
    start: int, rows: int, n: int, lines: int, dummy: int = DUMMY_ROW
) -> list[tuple[int, int]]:
    return list(itertools.islice(rolling_sequence(start, rows, n, dummy), lines))


# -- the cases: start row 757, 534 rows --------------------------------------------------


def test_short_exposure_reset_leads_read_by_n_plus_one() -> None:
    n = 2
    seq = take(X, K, n, 3 * K + n + 1)
    # lines 0..n: rows 757, 758, 759 reset while the read addresses the dummy row
    assert seq[: n + 1] == [(DUMMY_ROW, 757), (DUMMY_ROW, 758), (DUMMY_ROW, 759)]
    # line n + 1 = 3: row x is read while row x + n + 1 = 760 is reset
    assert seq[3] == (757, 760)
    for t, (read, reset) in enumerate(seq[n + 1 :], start=n + 1):
        assert X <= read <= LAST and X <= reset <= LAST, t
        if read + 3 <= LAST:
            assert reset == read + 3, t
        else:  # the reset address has wrapped to the next frame
            assert reset == read + 3 - K, t
    # the wrap, written out: after resetting 1290 the reset goes back to 757
    assert seq[533] == (1287, 1290)
    assert seq[534] == (1288, 757)
    # after reading x + k - 1 the read wraps to x
    assert seq[n + K] == (LAST, 759)
    assert seq[n + K + 1] == (X, 760)


def test_long_exposure_reads_and_resets_the_same_row() -> None:
    n = 537
    period = n + 1
    seq = take(X, K, n, n + 1 + 3 * period)
    # lines 0..k-1: reset x..x+k-1, read dummy
    assert seq[:K] == [(DUMMY_ROW, X + t) for t in range(K)]
    # lines k..n: both addresses dummy, stretching the exposure (4 lines: 534..537)
    assert seq[K : n + 1] == [(DUMMY_ROW, DUMMY_ROW)] * (n + 1 - K)
    assert n + 1 - K == 4
    # line n + 1 = 538: row x is read and immediately reset
    assert seq[n + 1] == (X, X)
    for t, (read, reset) in enumerate(seq[n + 1 :], start=n + 1):
        assert read == reset, t
        phase = (t - n - 1) % period
        assert read == (X + phase if phase < K else DUMMY_ROW), t


def test_dummy_row_exactly_where_the_papers_put_it() -> None:
    # n < k: the dummy row only ever appears as the read address, in lines 0..n
    seq = take(X, K, 2, 5 * K)
    assert [t for t, (read, _) in enumerate(seq) if read == DUMMY_ROW] == [0, 1, 2]
    assert all(reset != DUMMY_ROW for _, reset in seq)
    # n >= k: reads dummy in lines 0..n; resets dummy in lines k..n and then in the n + 1 - k
    # gap lines between frames (both dummy there)
    n = 537
    seq = take(X, K, n, 5 * (n + 1))
    dummy_reads = {t for t, (read, _) in enumerate(seq) if read == DUMMY_ROW}
    dummy_resets = {t for t, (_, reset) in enumerate(seq) if reset == DUMMY_ROW}
    gaps = {t for t in range(len(seq)) if t % (n + 1) >= K}
    assert dummy_resets == gaps
    assert dummy_reads == set(range(n + 1)) | gaps


@pytest.mark.parametrize("n", [0, 1, 2, 100, 532, 533, 534, 535, 537, 2000])
def test_first_frame_time_is_n_plus_k_plus_one_lines(n: int) -> None:
    seq = take(X, K, n, n + K + 2)
    last_read_line = max(t for t, (read, _) in enumerate(seq) if read == LAST)
    assert last_read_line == n + K
    assert first_frame_lines(K, n) == n + K + 1 == last_read_line + 1
    assert (last_read_line + 1) * T_LINE_S == pytest.approx(
        sequencer_frame_time_s(n, K, T_LINE_S), rel=1e-12
    )


def test_zero_exposure_reads_the_line_after_reset() -> None:
    seq = take(10, 3, 0, 8)
    assert seq == [
        (DUMMY_ROW, 10),
        (10, 11),
        (11, 12),
        (12, 10),
        (10, 11),
        (11, 12),
        (12, 10),
        (10, 11),
    ]


def test_one_less_than_window_reads_and_resets_same_row_without_gap() -> None:
    # n = k - 1: both rules meet; period k = n + 1, read == reset, no dummy lines
    seq = take(10, 3, 2, 9)
    assert seq[3:] == [(10, 10), (11, 11), (12, 12)] * 2


def test_line_addresses_is_random_access_to_the_sequence() -> None:
    for n in (2, 537):
        seq = take(X, K, n, 3 * (n + K))
        assert [line_addresses(t, X, K, n) for t in range(len(seq))] == seq


# -- argument checks -------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("args", "message"),
    [
        ((X, 0, 2), "rows must be >= 1"),
        ((-1, K, 2), "start_row must be >= 0"),
        ((X, K, -1), "exposure_lines must be >= 0"),
        ((X, K, 2.0), "exposure_lines must be an integer"),
        ((X, K, 2, 1000), "dummy row 1000 lies inside the window 757..1290"),
        ((3900, 101, 2), "dummy row 4000 lies inside the window 3900..4000"),
    ],
)
def test_bad_arguments_raise_at_call(args: tuple[int, ...], message: str) -> None:
    with pytest.raises(ValueError, match=message):
        rolling_sequence(*args)  # checked before the first next()


def test_other_helpers_check_arguments() -> None:
    with pytest.raises(ValueError, match="line must be an integer >= 0"):
        line_addresses(-1, X, K, 2)
    with pytest.raises(ValueError, match="lines must be an integer >= 0"):
        row_exposures(X, K, 2, -5)
    with pytest.raises(ValueError, match="frames must be an integer >= 0"):
        list(frame_reads(X, K, 2, -1))
    with pytest.raises(ValueError, match="rows must be >= 1"):
        first_frame_lines(0, 2)


# -- properties over n, k, x -----------------------------------------------------------------------

windows = st.tuples(
    st.integers(min_value=0, max_value=3000),  # start row
    st.integers(min_value=1, max_value=60),  # rows
    st.integers(min_value=0, max_value=80),  # exposure lines
)


@given(windows)
def test_every_exposure_is_n_plus_one_line_boundaries(window: tuple[int, int, int]) -> None:
    x, k, n = window
    period = sequencer_frame_period_lines(n, k)
    frames = 4
    lines = n + 1 + frames * period
    exposures = row_exposures(x, k, n, lines)
    assert set(exposures) == set(range(x, x + k))
    for row, pairs in exposures.items():
        # row x + j: reset in line f*P + j, read in line f*P + j + n + 1, for each frame f
        j = row - x
        assert pairs == [(f * period + j, f * period + j + n + 1) for f in range(frames)], row


@given(windows)
def test_rows_read_once_per_frame_in_order(window: tuple[int, int, int]) -> None:
    x, k, n = window
    frames = 5
    lines = n + 1 + frames * sequencer_frame_period_lines(n, k)
    seq = take(x, k, n, lines)
    reads = [(t, read) for t, (read, _) in enumerate(seq) if read != DUMMY_ROW]
    assert [row for _, row in reads] == list(range(x, x + k)) * frames
    assert reads == [(line, row) for _, row, line in frame_reads(x, k, n, frames)]
    # the first frame ends after reading x + k - 1 in line n + k
    assert reads[k - 1] == (n + k, x + k - 1)


@given(windows, st.integers(min_value=0, max_value=4095))
def test_no_valid_address_outside_the_window(window: tuple[int, int, int], dummy: int) -> None:
    x, k, n = window
    if x <= dummy < x + k:
        with pytest.raises(ValueError, match="inside the window"):
            rolling_sequence(x, k, n, dummy)
        return
    for read, reset in take(x, k, n, 3 * (n + k + 1), dummy):
        assert read == dummy or x <= read < x + k
        assert reset == dummy or x <= reset < x + k
        if n >= k:  # both dummy or both the same valid row once reading has started
            assert read in (dummy, reset)


@given(windows)
def test_sequence_repeats_with_the_frame_period(window: tuple[int, int, int]) -> None:
    x, k, n = window
    period = sequencer_frame_period_lines(n, k)
    seq = take(x, k, n, n + 1 + 4 * period)
    # resets are periodic from line 0, reads once row x has first been read (line n + 1)
    assert all(seq[t + period][1] == seq[t][1] for t in range(len(seq) - period))
    assert all(seq[t + period] == seq[t] for t in range(n + 1, len(seq) - period))
    # and no shorter: row x is reset exactly at multiples of the period
    assert [t for t, (_, reset) in enumerate(seq) if reset == x] == list(range(0, len(seq), period))


@given(
    windows,
    st.floats(min_value=1e6, max_value=100e6),
    st.floats(min_value=0.0, max_value=1.0),
)
def test_agrees_with_camd_timing(
    window: tuple[int, int, int], clock_hz: float, t_res_fraction: float
) -> None:
    x, k, n = window
    line_s = sequencer_line_period_s(clock_hz)
    # the reset phase sits T_RES before the end of its line; the read phase starts its line
    t_res_s = t_res_fraction * line_s
    seq = take(x, k, n, n + k + 1)
    # frame time: first reset in line 0 to the end of the line that reads x + k - 1
    last = max(t for t, (read, _) in enumerate(seq) if read == x + k - 1)
    assert (last + 1) * line_s == pytest.approx(sequencer_frame_time_s(n, k, line_s), rel=1e-12)
    # exposure of every row: read line start minus reset phase time
    for pairs in row_exposures(x, k, n, n + k + 1).values():
        ((reset_line, read_line),) = pairs
        measured_s = read_line * line_s - (reset_line * line_s + (line_s - t_res_s))
        assert measured_s == pytest.approx(exposure_s(n, line_s, t_res_s), rel=1e-9, abs=1e-15)
        # and T_exp = n T_line (T_RES ignored) within T_RES
        assert abs(measured_s - exposure_s(n, line_s)) <= t_res_s + 1e-15
    # period of continuous imaging
    seq = take(x, k, n, n + 1 + 3 * sequencer_frame_period_lines(n, k))
    reads_of_x = [t for t, (read, _) in enumerate(seq) if read == x]
    gaps = {b - a for a, b in itertools.pairwise(reads_of_x)}
    assert gaps == {sequencer_frame_period_lines(n, k)}
