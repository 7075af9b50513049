"""The fused numba TDI kernels: the same ring state and the same bits as ``kernel_numpy``.

Why three kernels: the synchronous case (whole rows, no column shift) is memory-bound, so
``integer_rows`` adds four consecutive frames' rows into each open line in one pass (the open
line is read and written once per four input rows, and the four input streams are sequential).
``fractional_rows`` (fractional rows, no column shift: a velocity mismatch) does the same with
three frames, each stage interpolated between two rows. Four frames measured slower (0.55-0.70
of a copy against about 0.9), probably because LLVM checks pointer pairs for overlap only up
to a limit before it vectorises and nine pointers pass it (not confirmed in the machine code).
Everything else (columns shifted by a drift angle, whole or fractional) goes through
``general``, one frame at a time, with the interpolation fused into the add. All three keep the
ring semantics of ``kernel_numpy``: the row of a line with no contribution yet is zero, and a
finished line's row is zeroed when it leaves. Loops run over 0-based ranges of sliced rows so
that LLVM sees unit-stride, non-negative indices and vectorises them.

Compiled on first use and cached on disk (``cache=True``; ``camd.tdi.warm_up`` does it ahead of
the first scan); ``nogil`` lets the daemon's other threads (the USB reader) run while a kernel
does.
"""

from __future__ import annotations

from typing import Any

import numba
import numpy as np

_JIT: dict[str, Any] = {"nogil": True, "cache": True, "boundscheck": False, "error_model": "numpy"}

KERNELS = ("integer_rows", "fractional_rows", "general")
"""The compiled kernels (``camd.tdi.warm_up`` compiles each ahead of the first scan)."""


@numba.njit(**_JIT)  # type: ignore[untyped-decorator]
def integer_rows(frames: Any, acc: Any, out: Any, rows: Any, first_index: int) -> None:
    """Synchronous / row-step TDI of F frames: stage i adds ``frames[f][rows[i]]`` to line
    ``first_index + f + i``; finished lines go to ``out`` (F, N)."""
    count = frames.shape[0]
    width = frames.shape[2]
    stages = acc.shape[0]
    tmp = np.empty(width, dtype=acc.dtype)
    for f in range(0, count, 4):
        group = min(4, count - f)
        k = first_index + f
        if group == 1:
            # One frame (``push``, or a block's last): each row straight into its line.
            o = out[f]
            for i in range(stages):
                a = acc[(k + i) % stages]
                src = frames[f, rows[i]]
                if i == 0:
                    for j in range(width):
                        o[j] = a[j] + src[j]
                        a[j] = 0
                else:
                    for j in range(width):
                        a[j] += src[j]
            continue
        for i in range(stages + group - 1):
            a = acc[(k + i) % stages]
            if group == 4 and 3 <= i <= stages - 1:
                p0 = frames[f, rows[i]]
                p1 = frames[f + 1, rows[i - 1]]
                p2 = frames[f + 2, rows[i - 2]]
                p3 = frames[f + 3, rows[i - 3]]
                if i == 3:
                    o = out[f + 3]
                    for j in range(width):
                        o[j] = a[j] + (
                            (np.uint32(p0[j]) + np.uint32(p1[j]))
                            + (np.uint32(p2[j]) + np.uint32(p3[j]))
                        )
                        a[j] = 0
                else:
                    for j in range(width):
                        a[j] += (np.uint32(p0[j]) + np.uint32(p1[j])) + (
                            np.uint32(p2[j]) + np.uint32(p3[j])
                        )
                continue
            # The group's edges (and groups of fewer than four frames): frames g of the group
            # whose row i - g exists, summed into tmp first.
            first = True
            for g in range(group):
                stage = i - g
                if stage < 0 or stage > stages - 1:
                    continue
                src = frames[f + g, rows[stage]]
                if first:
                    for j in range(width):
                        tmp[j] = src[j]
                    first = False
                else:
                    for j in range(width):
                        tmp[j] += src[j]
            if i < group:
                o = out[f + i]
                for j in range(width):
                    o[j] = a[j] + tmp[j]
                    a[j] = 0
            else:
                for j in range(width):
                    a[j] += tmp[j]


@numba.njit(**_JIT)  # type: ignore[untyped-decorator]
def fractional_rows(
    frames: Any,
    acc: Any,
    out: Any,
    row: Any,
    row_below: Any,
    row_weight: Any,
    one: Any,
    first_index: int,
) -> None:
    """Fractional rows, no column shift: stage i adds ``(one - w) * frames[f][row[i]] + w *
    frames[f][row_below[i]]`` (w = ``row_weight[i]``) to line ``first_index + f + i``, in units
    of 1/``one`` DN (no rounding per stage: the weights are whole numbers). ``row_below`` is
    ``row + 1``, or ``row`` itself where the weight is 0 and the row below is not there.
    Three frames per pass over the open lines."""
    count = frames.shape[0]
    width = frames.shape[2]
    stages = acc.shape[0]
    for f in range(0, count, 3):
        group = min(3, count - f)
        k = first_index + f
        for i in range(stages + group - 1):
            a = acc[(k + i) % stages]
            if group == 3 and 2 <= i <= stages - 1:
                w0, w1, w2 = row_weight[i], row_weight[i - 1], row_weight[i - 2]
                u0, u1, u2 = one - w0, one - w1, one - w2
                p0, q0 = frames[f, row[i]], frames[f, row_below[i]]
                p1, q1 = frames[f + 1, row[i - 1]], frames[f + 1, row_below[i - 1]]
                p2, q2 = frames[f + 2, row[i - 2]], frames[f + 2, row_below[i - 2]]
                if i == 2:
                    o = out[f + 2]
                    for j in range(width):
                        o[j] = a[j] + (
                            (u0 * p0[j] + w0 * q0[j])
                            + (u1 * p1[j] + w1 * q1[j])
                            + (u2 * p2[j] + w2 * q2[j])
                        )
                        a[j] = 0
                else:
                    for j in range(width):
                        a[j] += (
                            (u0 * p0[j] + w0 * q0[j])
                            + (u1 * p1[j] + w1 * q1[j])
                            + (u2 * p2[j] + w2 * q2[j])
                        )
                continue
            # The group's edges (and groups of fewer than three frames): frame g of the group
            # adds its stage i - g where that stage exists.
            for g in range(group):
                stage = i - g
                if stage < 0 or stage > stages - 1:
                    continue
                w = row_weight[stage]
                u = one - w
                p, q = frames[f + g, row[stage]], frames[f + g, row_below[stage]]
                for j in range(width):
                    a[j] += u * p[j] + w * q[j]
            if i < group:
                o = out[f + i]
                for j in range(width):
                    o[j] = a[j]
                    a[j] = 0


@numba.njit(**_JIT)  # type: ignore[untyped-decorator]
def general(
    frames: Any,
    acc: Any,
    out: Any,
    row: Any,
    row_weight: Any,
    col: Any,
    col_weight: Any,
    one: Any,
    first_index: int,
) -> None:
    """Any taps (docs/tdi.md): stage i adds the interpolated value of ``frames[f]`` at row
    ``row[i] + row_weight[i] / one`` and column offset ``col[i] + col_weight[i] / one`` to line
    ``first_index + f + i``, in units of 1/``one`` DN. ``one`` and the weights have the
    accumulator's dtype."""
    count = frames.shape[0]
    width = frames.shape[2]
    stages = acc.shape[0]
    half = one // 2
    for f in range(count):
        k = first_index + f
        for i in range(stages):
            a = acc[(k + i) % stages]
            r0 = row[i]
            d = col[i]
            wy = row_weight[i]
            wx = col_weight[i]
            lo = max(0, -d)
            hi = min(width, width - d - (1 if wx > 0 else 0))
            if hi <= lo:
                continue
            n = hi - lo
            av = a[lo:hi]
            p00 = frames[f, r0, lo + d : hi + d]
            if wy == 0 and wx == 0:
                for j in range(n):
                    av[j] += p00[j] * one
            elif wx == 0:
                p10 = frames[f, r0 + 1, lo + d : hi + d]
                uy = one - wy
                for j in range(n):
                    av[j] += uy * p00[j] + wy * p10[j]
            elif wy == 0:
                p01 = frames[f, r0, lo + d + 1 : hi + d + 1]
                ux = one - wx
                for j in range(n):
                    av[j] += ux * p00[j] + wx * p01[j]
            else:
                p01 = frames[f, r0, lo + d + 1 : hi + d + 1]
                p10 = frames[f, r0 + 1, lo + d : hi + d]
                p11 = frames[f, r0 + 1, lo + d + 1 : hi + d + 1]
                ux = one - wx
                uy = one - wy
                for j in range(n):
                    t = uy * (ux * p00[j] + wx * p01[j]) + wy * (ux * p10[j] + wx * p11[j])
                    av[j] += (t + half) // one
        a = acc[k % stages]
        o = out[f]
        for j in range(width):
            o[j] = a[j]
            a[j] = 0
