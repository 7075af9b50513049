"""The compiled per-pixel kernels of the simulated camera (``firmware_models.render_kernels``
says what they compute and holds their numpy references).

float32 throughout, in the references' order of operations (no fused multiply-add: numba
leaves it off without ``fastmath``), so both give the same bits. ``nogil``: a render does not
hold the interpreter lock, so commands and the stage's closed loop run beside it. Compiled on
first use and cached on disk (``cache=True``).
"""

from __future__ import annotations

from typing import Any

import numba
import numpy as np

_JIT: dict[str, Any] = {"nogil": True, "cache": True, "boundscheck": False, "error_model": "numpy"}


@numba.njit(**_JIT)  # type: ignore[untyped-decorator]
def weighted_rows(table: Any, cell_index: Any, weights: Any, out: Any) -> None:
    """``out[i] = sum_k weights[i, k] * table[cell_index[i, k]]``, terms added in order of k."""
    rows, span = weights.shape
    width = table.shape[1]
    for i in range(rows):
        o = out[i]
        src = table[cell_index[i, 0]]
        w = weights[i, 0]
        for j in range(width):
            o[j] = src[j] * w
        for k in range(1, span):
            src = table[cell_index[i, k]]
            w = weights[i, k]
            for j in range(width):
                o[j] = o[j] + src[j] * w


@numba.njit(inline="always", **_JIT)  # type: ignore[untyped-decorator]
def _code(
    photons: Any,
    response: Any,
    factor: Any,
    dark: Any,
    dark_scale: Any,
    z: Any,
    read_variance: Any,
    full_well: Any,
    gain: Any,
    black: Any,
    adc_max: Any,
    shift: int,
) -> Any:
    """One pixel's output code from its photons (the steps of ``render_kernels.read_out``)."""
    e = photons * response
    e = e * factor
    e = e + dark * dark_scale
    sigma = np.sqrt(e + read_variance)
    e = e + sigma * z
    e = min(e, full_well)
    e = e * gain
    e = e + black
    # Clipped to the ADC's range, then rounded: the same as rounding first, since both
    # bounds are whole codes (and it keeps the loop vectorised).
    e = max(e, np.float32(0.0))
    e = min(e, adc_max)
    return np.uint16(np.uint16(np.rint(e)) >> shift)


@numba.njit(**_JIT)  # type: ignore[untyped-decorator]
def read_out(
    photons: Any,
    response: Any,
    dark_rate: Any,
    row_factor: Any,
    dark_scale: Any,
    values: Any,
    starts: Any,
    read_variance: Any,
    full_well: Any,
    gain: Any,
    black: Any,
    adc_max: Any,
    shift: int,
    out: Any,
    frame_max: Any,
) -> None:
    """Photons to output codes for a block of frames (``render_kernels.read_out``)."""
    total_rows, cols = out.shape
    rows = response.shape[0]
    one_column = photons.shape[1] == 1
    for r in range(total_rows):
        f = r // rows
        i = r - f * rows
        base = starts[f] + i * cols
        z = values[base : base + cols]
        factor = row_factor[r]
        resp = response[i]
        dark = dark_rate[i]
        p_row = photons[r]
        o = out[r]
        top = np.uint16(0)
        # Two loops, not one with a per-pixel choice of the photons' column: each vectorises.
        if one_column:
            p = p_row[0]
            for j in range(cols):
                o[j] = _code(p, resp[j], factor, dark[j], dark_scale, z[j], read_variance,
                             full_well, gain, black, adc_max, shift)  # fmt: skip
                top = max(top, o[j])
        else:
            for j in range(cols):
                o[j] = _code(p_row[j], resp[j], factor, dark[j], dark_scale, z[j], read_variance,
                             full_well, gain, black, adc_max, shift)  # fmt: skip
                top = max(top, o[j])
        if top > frame_max[f]:
            frame_max[f] = top
