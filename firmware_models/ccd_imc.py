"""Numeric charge-transfer model of image motion compensation on a p-phase full-frame CCD.

docs/physics.md §7 [REN15] gives the modulation of a point beam's image in closed form for row-step
and electrode-step compensation. This model does not use those forms: it steps time, generates
photo-charge under each electrode, collects it into the charge packets and clocks the packets,
so that tests can hold the closed forms against it, and against the two other routes to the
same image: the exact piecewise integral of ``camd.timing.imc.point_beam_profile`` and the
simulated camera's frames (``firmware_models.camera``; tests/test_campaign_imc.py).

The geometry (one CCD column, along track, coordinate ``x`` in metres):

- pixel ``k`` is ``[k w, (k + 1) w)``, split into ``p`` electrodes of width ``w / p``;
- the beam is one pixel wide with uniform irradiance, ``[s(t), s(t) + w)`` with
  ``s(t) = a + v t``: it starts ``a`` (``0 <= a < w``) from the edge of pixel 0 and moves at
  the image velocity ``v`` in +x;
- packet ``k``'s *collection region* is the pixel-wide run of ``p`` electrodes its potential well
  occupies, ``[k w + c w/p, (k + 1) w + c w/p)`` after ``c`` electrode moves: a photo-electron
  generated under an electrode joins the packet whose region holds that electrode. The regions
  tile the column, so no charge is lost;
- the exposure lasts ``exposure_cycles`` row times ``T = w / v`` and starts on a clock edge. The
  packets move in +x (with the image): ``"row"`` by ``p`` electrodes (one pixel) every ``T``,
  ``"electrode"`` by one electrode every ``T / p`` (the intervals come from
  ``camd.timing.imc``), ``"none"`` not at all;
- time is cut into ``time_steps_per_cycle`` steps per ``T``; in each the charge under each
  electrode is the beam's overlap with it at the step's midpoint times the step (midpoint rule).
  The overlap is piecewise linear in time, so the rule is exact except in the steps where a beam
  edge crosses an electrode edge: the error falls as ``1 / time_steps_per_cycle**2``;
- after the exposure the packets are read out in order: the pixel profile. Charge is in units of
  the beam's whole signal per row time, so a profile sums to ``exposure_cycles``.

Modulation of a profile (``modulation``): the charge in the *main* packet, the brightest one,
minus the charge spilled into all the others, over the total, ``(2 max - sum) / sum``.

With this definition the model reproduces both closed forms of docs/physics.md §7 in full, absolute
values included. Row steps: per row time, the packet the beam moves into collects
``w^2/2 + a w - a^2``, its neighbours ``(w - a)^2/2`` and ``a^2/2`` (in units of irradiance *
time / v), so ``M = 2a(w - a)/w^2``. Electrode steps (p = 4): for ``a <= 3w/4`` the beam stays
within two packets, which collect ``7w^2/8 - a w`` (the one the beam starts in) and
``a w + w^2/8``; the main packet is the first for ``a < 3w/8`` and the second above, so
``M = |3w - 8a|/(4w)`` (the absolute value is the main packet changing sides). For ``a > 3w/4``
the beam reaches a third packet and ``M = 1 - 4((w - a)^2 + (a - 3w/4)^2)/w^2``, which is
``(56 a w - 32 a^2 - 21 w^2)/(4 w^2)``. The brightest packet holds at least half the charge
with row or electrode steps, so the modulation is in ``[0, 1]``; without compensation over more
than one row time the image smears over several pixels and the modulation goes negative (it is
not clipped, so the amount of smear stays visible). With one row time of exposure, ``"row"``
and ``"none"`` are the same (the first row step falls at the end of the exposure).
"""

from __future__ import annotations

from typing import TypedDict, Unpack

import numpy as np
import numpy.typing as npt

from camd.timing._checks import count, positive
from camd.timing.imc import (
    IMC_MODES,
    ImcMode,
    electrode_step_interval_s,
    pixel_offsets,
    profile_modulation,
    row_step_interval_s,
)

FloatArray = npt.NDArray[np.float64]
Method = ImcMode  # the compensation modes of camd.timing.imc (and of the camera's IMC_CTRL)
METHODS: tuple[Method, ...] = IMC_MODES

REN15_PIXEL_M = 9e-6
"""REN15's pixel (docs/physics.md §7, FTF5066M-class 4-phase full-frame CCD)."""

REN15_IMAGE_VELOCITY_M_S = 0.09 * 0.05 / 0.3
"""REN15's lab rig at its limits: f = 90 mm, V = 50 mm/s, H = 0.3 m, so v = 15 mm/s."""

_MAX_BLOCK_ELEMENTS = 1 << 21
"""Largest (offsets x time steps x electrodes) temporary per block: bounds memory, not speed."""


class PointBeamOptions(TypedDict, total=False):
    """``point_beam_profile``'s keyword arguments, for the functions that pass them on: each
    default stays written once, in ``point_beam_profile``."""

    pixel_m: float
    phases: int
    method: Method
    exposure_cycles: int
    time_steps_per_cycle: int
    image_velocity_m_s: float


def point_beam_profile(
    a_m: float | npt.ArrayLike,
    *,
    pixel_m: float = REN15_PIXEL_M,
    phases: int = 4,
    method: Method = "electrode",
    exposure_cycles: int = 1,
    time_steps_per_cycle: int = 400,
    image_velocity_m_s: float = REN15_IMAGE_VELOCITY_M_S,
) -> FloatArray:
    """Read-out pixel profile of a moving point beam, charge packets clocked during exposure.

    Returns shape ``np.shape(a_m) + (exposure_cycles + 3,)``: the packets in read-out order,
    index ``i`` holding packet ``i - 1``, packet ``k`` being the one whose collection region
    was pixel ``k`` when the exposure began (packet -1 is a spare that stays empty). See the module docstring for the geometry. ``time_steps_per_cycle`` must be a multiple of
    ``phases`` for ``"electrode"`` so that every clock edge falls between two time steps.
    The result does not depend on ``pixel_m`` or ``image_velocity_m_s`` (the clocks follow
    ``v``), except through rounding.
    """
    pixel = positive("pixel_m", pixel_m)
    velocity = positive("image_velocity_m_s", image_velocity_m_s)
    p = count("phases", phases, 1)
    cycles = count("exposure_cycles", exposure_cycles, 1)
    steps = count("time_steps_per_cycle", time_steps_per_cycle, 1)
    if method not in METHODS:
        raise ValueError(f"method must be one of {', '.join(METHODS)}, got {method!r}")
    a, _ = pixel_offsets(a_m, pixel)
    shape = a.shape
    a = a.reshape(-1)

    row_time_s = row_step_interval_s(pixel, velocity)
    if method == "electrode":
        if steps % p:
            raise ValueError(
                f"time_steps_per_cycle ({steps}) must be a multiple of phases ({p}) for "
                "electrode steps, so that each clock edge falls between two time steps"
            )
        clock_s = electrode_step_interval_s(pixel, velocity, p)
        steps_per_clock, electrodes_per_move = steps // p, 1
    else:
        # "none" is cut into row times only to bound the temporaries; nothing moves.
        clock_s = row_time_s
        steps_per_clock, electrodes_per_move = steps, (p if method == "row" else 0)
    n_clocks = round(cycles * row_time_s / clock_s)
    dt_s = clock_s / steps_per_clock
    electrode_m = pixel / p

    # Packets 0 .. cycles + 1 are enough (the beam never reaches pixel cycles + 2); the spare
    # packet -1 keeps a rounding error in an electrode index from falling off the array.
    n_packets = cycles + 3
    charge = np.zeros((a.size, n_packets))
    if a.size == 0:
        return charge.reshape((*shape, n_packets))
    moved = 0  # electrodes the packets have moved since the exposure began
    block = _block(a.size, p, steps_per_clock)
    for clock in range(n_clocks):
        for first in range(0, steps_per_clock, block):
            last = min(first + block, steps_per_clock)
            t_s = clock * clock_s + (np.arange(first, last) + 0.5) * dt_s
            edge = a[:, None] + velocity * t_s[None, :]  # trailing beam edge, (offsets, steps)
            lo = int(np.floor(edge.min() / electrode_m))
            hi = int(np.ceil((edge.max() + pixel) / electrode_m))
            bounds = np.arange(lo, hi + 1) * electrode_m
            overlap = np.minimum(edge[..., None] + pixel, bounds[1:]) - np.maximum(
                edge[..., None], bounds[:-1]
            )
            # Charge under each electrode lo .. hi-1 in this block, in beam signals per row time.
            generated = np.clip(overlap, 0.0, None).sum(axis=1) * (dt_s / (pixel * row_time_s))
            packet = (np.arange(lo, hi) - moved) // p + 1  # +1: array index 0 is packet -1
            if packet[0] < 0 or packet[-1] >= n_packets:
                raise RuntimeError("model bug: the beam left the modelled packets")
            collects = (packet[:, None] == np.arange(n_packets)[None, :]).astype(np.float64)
            charge += generated @ collects  # (offsets, electrodes) @ (electrodes, packets)
        moved += electrodes_per_move
    return charge.reshape((*shape, n_packets))


def _block(n_offsets: int, phases: int, steps: int) -> int:
    """Time steps per vectorised block, so that one temporary stays below the memory bound."""
    per_step = max(n_offsets * (3 * phases + 3), 1)
    return max(1, min(steps, _MAX_BLOCK_ELEMENTS // per_step))


def modulation(profile: npt.ArrayLike) -> FloatArray:
    """Modulation ``(2 max - sum) / sum`` of pixel profiles along the last axis.

    The charge in the main (brightest) packet minus the charge spilled into all the others,
    over the total: the definition under which this model reproduces docs/physics.md §7 [REN15]
    (module docstring). 1 for all the charge in one pixel, 0 for an even split over two,
    negative when no pixel holds half. A single profile gives a 0-d array.
    """
    q = np.asarray(profile, dtype=np.float64)
    if q.ndim < 1 or q.shape[-1] < 1:
        raise ValueError("profile must have at least one pixel along its last axis")
    if not np.all(np.isfinite(q)) or np.any(q < 0.0):
        raise ValueError("profile must hold finite charges >= 0")
    # The definition lives once, with the equations (camd.timing.imc).
    return profile_modulation(q)


def point_beam_modulation(
    a_m: float | npt.ArrayLike, **beam: Unpack[PointBeamOptions]
) -> FloatArray:
    """Modulation of the model's point-beam image for each start offset in ``a_m``.

    ``modulation(point_beam_profile(...))`` with the same arguments; shape ``np.shape(a_m)``.
    Compare with ``camd.timing.imc.row_step_modulation`` / ``electrode_step_modulation``
    (docs/physics.md §7 [REN15]).
    """
    return modulation(point_beam_profile(a_m, **beam))


def mean_point_beam_modulation(*, offsets: int = 512, **beam: Unpack[PointBeamOptions]) -> float:
    """The model's modulation averaged over ``a`` uniform in ``[0, w)`` (midpoint rule).

    ``offsets`` offsets at ``(i + 1/2) w / offsets``; compare with
    ``camd.timing.imc.mean_row_step_modulation`` (1/3) and ``mean_electrode_step_modulation``
    (47/96). The rule's error falls as ``1 / offsets**2`` (the curves are piecewise quadratic).
    """
    n = count("offsets", offsets, 1)
    pixel = positive("pixel_m", beam.get("pixel_m", REN15_PIXEL_M))
    a = (np.arange(n) + 0.5) * (pixel / n)
    return float(point_beam_modulation(a, **beam).mean())
