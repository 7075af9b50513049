"""The HR400 rolling-shutter sequencer: read and reset row addresses per line period.

docs/physics.md §3 [YE23]. Each line period has a read phase, then a reset phase, each with a row
address; resetting a row starts its exposure, reading it ends it. The window is ``k = rows``
rows at addresses ``x .. x+k-1`` (``x = start_row``); ``n = exposure_lines``.

One rule covers both of the paper's cases. With the frame period ``P = max(k, n + 1)`` lines
(``camd.timing.sequencer_frame_period_lines``), window row ``x + j`` of frame ``f`` is

    reset in line  f*P + j
    read  in line  f*P + j + n + 1

and every other phase addresses the dummy row (4000, a row that does not exist). Hence:

- ``n < k`` (P = k): the reset address runs x, x+1, .., x+k-1 and wraps to x without a gap; the
  read address is the dummy row until line ``n + 1``, where row x is read while row x+n+1 is
  reset, so reset = read + n + 1 (modulo the window: once read + n + 1 passes x+k-1 the reset
  address has wrapped to the next frame); after reading x+k-1 the read wraps to x.
- ``n >= k`` (P = n + 1): lines 0..k-1 reset x..x+k-1 with a dummy read; then both addresses are
  dummy (stretching the exposure) until row x is due in line n + 1; from then on every valid row
  is read and re-reset in the same line (read == reset), and dummy/dummy lines fill the gap
  between the last row of one frame and the first of the next.
- The first frame ends with the read of x+k-1 in line n + k: ``T_frame = (n + k + 1) T_line``.

Exposure: reset in line t (late in the line) and read at the start of line t + n + 1 span
n whole lines plus T_RES, the time from the reset phase to the end of line t:
``T_exp = n T_line + T_RES``. ``n = 0`` is allowed and follows the same rule: a row is read in
the line after its reset and has been exposed for T_RES only (the shortest exposure); a read
and reset of one row in the *same* line would end an exposure before it started.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterator

from camd.timing import sequencer_frame_period_lines

DUMMY_ROW = 4000
"""The HR400's dummy row address: a row that does not exist (docs/physics.md §3 [YE23])."""


def _check(start_row: int, rows: int, exposure_lines: int, dummy_row: int) -> None:
    for name, value in (
        ("start_row", start_row),
        ("rows", rows),
        ("exposure_lines", exposure_lines),
        ("dummy_row", dummy_row),
    ):
        if isinstance(value, bool) or not isinstance(value, int):
            raise ValueError(f"{name} must be an integer, got {value!r}")
    if start_row < 0:
        raise ValueError(f"start_row must be >= 0, got {start_row}")
    if rows < 1:
        raise ValueError(f"rows must be >= 1, got {rows}")
    if exposure_lines < 0:
        raise ValueError(f"exposure_lines must be >= 0, got {exposure_lines}")
    if dummy_row < 0:
        raise ValueError(f"dummy_row must be >= 0, got {dummy_row}")
    if start_row <= dummy_row < start_row + rows:
        raise ValueError(
            f"dummy row {dummy_row} lies inside the window {start_row}..{start_row + rows - 1}; "
            "it must address a row that does not exist"
        )


def line_addresses(
    line: int, start_row: int, rows: int, exposure_lines: int, dummy_row: int = DUMMY_ROW
) -> tuple[int, int]:
    """(read_address, reset_address) in line period ``line`` (0 = first reset of row x).

    Random access to ``rolling_sequence``: the same rule (module docstring, docs/physics.md §3).
    """
    _check(start_row, rows, exposure_lines, dummy_row)
    if isinstance(line, bool) or not isinstance(line, int) or line < 0:
        raise ValueError(f"line must be an integer >= 0, got {line!r}")
    period = sequencer_frame_period_lines(exposure_lines, rows)
    return _addresses(line, start_row, rows, exposure_lines, dummy_row, period)


def _addresses(
    line: int, start: int, rows: int, n: int, dummy: int, period: int
) -> tuple[int, int]:
    phase = line % period
    reset = start + phase if phase < rows else dummy
    read = dummy
    if line > n:
        read_phase = (line - n - 1) % period
        if read_phase < rows:
            read = start + read_phase
    return read, reset


def rolling_sequence(
    start_row: int, rows: int, exposure_lines: int, dummy_row: int = DUMMY_ROW
) -> Iterator[tuple[int, int]]:
    """Yield (read_address, reset_address) for each line period, from line 0 forever.

    docs/physics.md §3 [YE23]; the rule and both cases (n < k, n >= k) are in the module docstring.
    Infinite: take what you need with ``itertools.islice``. Arguments are checked when this is
    called (not at the first ``next``): rows >= 1, start_row >= 0, exposure_lines >= 0 and a
    dummy row outside the window.
    """
    _check(start_row, rows, exposure_lines, dummy_row)
    return _sequence(start_row, rows, exposure_lines, dummy_row)


def _sequence(start: int, rows: int, n: int, dummy: int) -> Iterator[tuple[int, int]]:
    period = sequencer_frame_period_lines(n, rows)
    for line in itertools.count():
        yield _addresses(line, start, rows, n, dummy, period)


def first_frame_lines(rows: int, exposure_lines: int) -> int:
    """Line periods of the first frame, first reset to last read: ``n + k + 1`` (§3 eq 6)."""
    # Any window with the dummy row just past it: only rows and exposure_lines matter here.
    _check(0, rows, exposure_lines, dummy_row=rows)
    return exposure_lines + rows + 1


def row_exposures(
    start_row: int,
    rows: int,
    exposure_lines: int,
    lines: int,
    dummy_row: int = DUMMY_ROW,
) -> dict[int, list[tuple[int, int]]]:
    """For each window row, the (reset line, read line) pairs observed in lines 0..lines-1.

    Replays ``rolling_sequence`` as the pixel array sees it: within a line the read phase
    comes before the reset phase, so a row read and reset in the same line closes its old
    exposure first and then opens a new one. Exposures still open at the end are left out; a
    read of a row that was never reset (cannot happen in this sequencer) raises. Only window rows
    are keys; dummy addresses are ignored. Feeds tests and the frame simulator.
    """
    if isinstance(lines, bool) or not isinstance(lines, int) or lines < 0:
        raise ValueError(f"lines must be an integer >= 0, got {lines!r}")
    sequence = rolling_sequence(start_row, rows, exposure_lines, dummy_row)
    opened: dict[int, int] = {}
    result: dict[int, list[tuple[int, int]]] = {start_row + j: [] for j in range(rows)}
    for line, (read, reset) in enumerate(itertools.islice(sequence, lines)):
        if read != dummy_row:
            if read not in opened:
                raise RuntimeError(f"row {read} read in line {line} without a reset")
            result[read].append((opened.pop(read), line))
        if reset != dummy_row:
            opened[reset] = line
    return result


def frame_reads(
    start_row: int, rows: int, exposure_lines: int, frames: int, dummy_row: int = DUMMY_ROW
) -> Iterator[tuple[int, int, int]]:
    """Yield (frame, row, line) for every valid read of the first ``frames`` frames, in order.

    The read-out order a frame simulator needs: frame ``f``'s row ``x + j`` is read in line
    ``f * P + j + n + 1`` (module docstring), so frame f ends in line ``f * P + n + k``.
    """
    _check(start_row, rows, exposure_lines, dummy_row)
    if isinstance(frames, bool) or not isinstance(frames, int) or frames < 0:
        raise ValueError(f"frames must be an integer >= 0, got {frames!r}")
    period = sequencer_frame_period_lines(exposure_lines, rows)
    for frame in range(frames):
        for j in range(rows):
            yield frame, start_row + j, frame * period + j + exposure_lines + 1
