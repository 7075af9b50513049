"""Image motion compensation's photons: a full-frame exposure with the charge clocked along.

With image motion compensation (docs/physics.md §7 [REN15]; a sensor whose map has the
IMC_CTRL, IMC_STEP and IMC_PHASES registers, the full-frame ``ftf5066``) the charge packets are
clocked along the columns with the image during the exposure, one electrode (``w / p``) every
``IMC_STEP`` clocks or one row every ``p`` of them (``camd.timing.imc.charge_shift_schedule``),
so each pixel's collection aperture moves relative to the scene by the image displacement minus
the packets' shift: a sawtooth, a sequence of linear pieces. Each piece is a moving aperture
that ``Scene.integrate`` integrates exactly; the photons are the sum over the pieces, each
weighted by its duration (identical pieces are integrated once, ``merge_pieces``, docs/imc.md).
Row ``i`` of the frame is the packet that sat in window row ``i`` when the exposure began.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import numpy.typing as npt

from camd.sensor.timing_view import SensorTiming
from camd.timing.imc import ImcMode, charge_shift_schedule
from firmware_models.camera_settings import RegisterSettings
from firmware_models.scene import Scene

Array = npt.NDArray[Any]

_MAX_MOTION_PIECES = 64  # more distinct IMC pieces than this are merged into an occupation density
_SAME_PIECE_ROWS = 1e-9  # pieces whose ends agree to this (rows) are integrated together


def compensated_photons(
    scene: Scene,
    aperture: float,
    image_motion: Callable[[Array, SensorTiming], tuple[Array, Array]],
    start_s: float,
    imc: tuple[ImcMode, float, int],
    settings: RegisterSettings,
    dtype: npt.DTypeLike,
) -> Array:
    """Photons per pixel of a full-frame exposure starting at ``start_s`` with the packets
    clocked along (module docstring): the sum over the schedule's pieces of the scene's exact
    integral of an aperture moving linearly from (image displacement - packet shift) at the
    piece's start to that at its end, each for the piece's duration. ``image_motion(t_s,
    timing)``: the image displacement at times ``t_s``, rows along and columns across track
    (``CameraModel.image_motion``)."""
    row0, rows, col0, cols = settings.window
    mode, interval_s, phases = imc
    schedule = charge_shift_schedule(settings.timing.exposure_s, interval_s, mode, phases)
    # All rows expose together.
    moved, across = image_motion(start_s + schedule.bounds_s, settings.timing)
    # Drift (and a rotated camera or a yawing stage) moves the image sideways by its own
    # displacement; the packets only move along.
    mid_along = 0.5 * (moved[0] + moved[-1])
    lateral = scene.lateral_cols(np.full(rows, mid_along)) + 0.5 * (across[0] + across[-1])
    pieces = merge_pieces(
        moved[:-1] - schedule.shift_px, moved[1:] - schedule.shift_px, schedule.durations_s
    )
    total: Array | None = None
    for lo, hi, duration_s in pieces:
        photons = scene.integrate(
            row0, rows, cols, lo, hi, lateral, duration_s, aperture, first_col=col0, dtype=dtype
        )
        total = photons if total is None else total + photons
    assert total is not None  # a schedule has at least one piece
    return total


def merge_pieces(start: Array, end: Array, durations_s: Array) -> list[tuple[float, float, float]]:
    """Linear pieces of aperture motion (rows, from ``start[j]`` to ``end[j]`` for
    ``durations_s[j]``) as fewer pieces with the same time integral, ``(lo, hi, duration)``.

    The photons a moving aperture collects depend only on how long it spends at each
    displacement (the time integral of the scene over it), not on the order or direction of
    the motion. So pieces that cover the same displacements (to 1e-9 rows: the matched IMC
    sawtooth repeats one tooth) are integrated once with their durations added. If more than
    ``_MAX_MOTION_PIECES`` distinct pieces remain (a mismatched clock drifting through many
    positions), the occupation density is cut at every piece's ends into intervals of
    constant density, each an equivalent linear piece (still exact); if still too many, its
    mass is put on ``_MAX_MOTION_PIECES`` equal bins across the range (approximate within a
    bin's width: docs/imc.md).
    """
    used = durations_s > 0.0
    lo = np.minimum(start, end)[used]
    hi = np.maximum(start, end)[used]
    keys = np.stack([np.round(lo / _SAME_PIECE_ROWS), np.round(hi / _SAME_PIECE_ROWS)], axis=1)
    _, first, group = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    tau = np.bincount(group.reshape(-1), weights=durations_s[used])
    lo, hi = lo[first], hi[first]
    if lo.size <= _MAX_MOTION_PIECES:
        return [(float(a), float(b), float(t)) for a, b, t in zip(lo, hi, tau, strict=True)]
    moving = hi - lo >= _SAME_PIECE_ROWS
    edges = np.unique(np.concatenate([lo, hi]))
    # Time per row on each interval between consecutive edges: +rate where a moving piece
    # starts, -rate where it ends, summed up; a still piece is a point mass at its edge.
    rate = tau[moving] / (hi[moving] - lo[moving])
    change = np.zeros(edges.size)
    np.add.at(change, np.searchsorted(edges, lo[moving]), rate)
    np.add.at(change, np.searchsorted(edges, hi[moving]), -rate)
    mass = np.cumsum(change)[:-1] * np.diff(edges)
    points = np.zeros(edges.size)
    np.add.at(points, np.searchsorted(edges, lo[~moving]), tau[~moving])
    if np.count_nonzero(mass > 0.0) + np.count_nonzero(points) <= _MAX_MOTION_PIECES:
        out = [(float(e), float(e), float(m)) for e, m in zip(edges, points, strict=True) if m]
        out += [
            (float(a), float(b), float(m))
            for a, b, m in zip(edges[:-1], edges[1:], mass, strict=True)
            if m > 0.0
        ]
        return out
    # Still too many: the time spent below each of equal bins' edges (piecewise linear in the
    # displacement between edges, stepping at the point masses) spread evenly over each bin.
    bins = np.linspace(edges[0], edges[-1], _MAX_MOTION_PIECES + 1)
    below_edges = np.cumsum(points) + np.concatenate([[0.0], np.cumsum(mass)])
    below = np.interp(bins, edges, below_edges)
    below[0], below[-1] = 0.0, float(tau.sum())
    per_bin = np.diff(below)
    return [
        (float(a), float(b), float(m))
        for a, b, m in zip(bins[:-1], bins[1:], per_bin, strict=True)
        if m > 0.0
    ]
