"""Drive timing of an HR400-class sCMOS rolling-shutter sequencer.

docs/physics.md §3 (and §4 eq 6) [YE23]: a line period of 513 sequencer clocks, exposure in whole
lines plus a fixed remainder, and a window of ``k`` rows whose first frame takes ``n + k + 1``
lines. ``firmware_models.sequencer`` generates the row-address sequence these numbers describe;
its tests check that the two agree.
"""

from __future__ import annotations

from camd.timing._checks import count, non_negative, positive

HR400_CLOCKS_PER_LINE = 513
"""Sequencer clocks per line period of the HR400 (docs/physics.md §3 [YE23])."""


def sequencer_line_period_s(clock_hz: float, clocks_per_line: int = HR400_CLOCKS_PER_LINE) -> float:
    """Line period ``T_line = clocks_per_line * T_clk_seq`` (513 clocks on the HR400).

    docs/physics.md §3 [YE23]. E.g. a 25 MHz sequencer clock gives 513 / 25e6 = 20.52 us.
    """
    clock = positive("clock_hz", clock_hz)
    clocks = count("clocks_per_line", clocks_per_line, 1)
    return clocks / clock


def exposure_s(exposure_lines: int, line_period_s: float, t_res_s: float = 0.0) -> float:
    """Exposure ``T_exp = n * T_line + T_RES``.

    docs/physics.md §3 [YE23]. ``t_res_s`` (T_RES, the time from a row's reset phase to the end of
    its line period) defaults to 0, the paper's approximation ``T_exp = n * T_line``. ``n = 0``
    is allowed: the row is read in the line after its reset, exposing for T_RES only.
    """
    lines = count("exposure_lines", exposure_lines, 0)
    line = positive("line_period_s", line_period_s)
    t_res = non_negative("t_res_s", t_res_s)
    return lines * line + t_res


def sequencer_frame_time_s(exposure_lines: int, window_rows: int, line_period_s: float) -> float:
    """Time of one frame from the first reset to the end of the last read: ``(n + k + 1) T_line``.

    docs/physics.md §3 and §4 eq 6 [YE23]: ``n`` exposure lines, ``k`` window rows. Row ``x`` is
    reset in line 0 and read in line ``n + 1``; the last row ``x + k - 1`` is read in line
    ``n + k``, so the frame spans lines 0 .. n + k.
    """
    lines = count("exposure_lines", exposure_lines, 0)
    rows = count("window_rows", window_rows, 1)
    line = positive("line_period_s", line_period_s)
    return (lines + rows + 1) * line


def sequencer_frame_period_lines(exposure_lines: int, window_rows: int) -> int:
    """Lines between successive frames in continuous imaging: ``max(k, n + 1)``.

    Derived from the address sequence of docs/physics.md §3 [YE23] (the paper states only the
    first frame's time, eq 6): with ``n < k`` the reset address cycles through the ``k`` rows
    without gaps, so a frame starts every ``k`` lines; with ``n >= k`` each row is read and
    re-reset in the same line, so a row's next read comes ``n + 1`` lines after its last one.
    """
    lines = count("exposure_lines", exposure_lines, 0)
    rows = count("window_rows", window_rows, 1)
    return max(rows, lines + 1)


def sequencer_frame_period_s(exposure_lines: int, window_rows: int, line_period_s: float) -> float:
    """``sequencer_frame_period_lines`` in seconds (docs/physics.md §3 [YE23], derived)."""
    line = positive("line_period_s", line_period_s)
    return sequencer_frame_period_lines(exposure_lines, window_rows) * line
