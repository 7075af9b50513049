"""Rolling- and global-shutter line and frame times of a windowed CMOS sensor.

docs/physics.md §2 eqs 1-4 [TAO12]: a window of ``n_lines`` rows, each row read in a line period of
row blanking plus ``n_pixels`` pixels at the pixel rate.
"""

from __future__ import annotations

from camd.timing._checks import count, non_negative, positive


def rolling_line_period_s(row_blanking_s: float, n_pixels: int, pixel_rate_hz: float) -> float:
    """Rolling-shutter line period ``T_line,roll = t_rb + n_pixels / f_s``.

    docs/physics.md §2 eq 4 [TAO12]. ``row_blanking_s`` (``t_rb``, e.g. 3.5 us on the IBIS5, spent
    on correlated double sampling) may be 0; ``n_pixels`` >= 1; ``pixel_rate_hz`` > 0.
    """
    t_rb = non_negative("row_blanking_s", row_blanking_s)
    pixels = count("n_pixels", n_pixels, 1)
    rate = positive("pixel_rate_hz", pixel_rate_hz)
    return t_rb + pixels / rate


def rolling_frame_time_s(line_period_s: float, n_lines: int) -> float:
    """Rolling-shutter frame time ``T_frm,roll = T_line,roll * n_lines``.

    docs/physics.md §2 eq 2 [TAO12]: integration overlaps readout, so only the readout counts.
    """
    line = positive("line_period_s", line_period_s)
    lines = count("n_lines", n_lines, 1)
    return line * lines


def global_frame_time_s(integration_s: float, line_period_s: float, n_lines: int) -> float:
    """Global-shutter (synchronous) frame time ``T_frm,syn = T_int,syn + T_line * n_lines``.

    docs/physics.md §2 eq 1 [TAO12]: all rows integrate together, then are read one by one, so the
    integration and the readout add.
    """
    integration = non_negative("integration_s", integration_s)
    return integration + rolling_frame_time_s(line_period_s, n_lines)


def max_rolling_integration_s(line_period_s: float, n_lines: int) -> float:
    """Longest rolling-shutter integration ``T_int,roll <= T_line,roll * (n_lines - 1)``.

    docs/physics.md §2 eq 3 [TAO12]. A one-row window gives 0: in this scheme a row's reset and read
    must fall within one frame of the window, so there is no room to integrate.
    """
    line = positive("line_period_s", line_period_s)
    lines = count("n_lines", n_lines, 1)
    return line * (lines - 1)
