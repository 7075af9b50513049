"""Electronic image motion compensation (IMC) on a full-frame CCD: clocking and modulation.

docs/physics.md §7 [REN15]: the image of the ground moves over the focal plane at ``v = f V / H``.
Conventional compensation moves the charge packets one row (one pixel ``w``) every ``w / v``;
REN15's improved method moves them one electrode (``w / p`` on a p-phase CCD) every
``dt = w / (p v)``. The modulation of a point beam's image (beam one pixel wide, starting ``a``
from a pixel edge) is given in closed form for both methods; the averages over ``a`` are
integrated here by hand. ``firmware_models.ccd_imc`` checks the closed forms against a numeric
charge-transfer model.

The clocking during one exposure, for any exposure and any step interval, is here too, once:
``charge_shift_schedule`` says when the packets move and by how many electrodes (the simulated
camera renders its frames with it, the charge-transfer model and the model below clock with
it). ``point_beam_profile`` integrates a point beam's image over that schedule exactly (the
closed forms are its special case of a whole number of row times), and ``point_beam_means``
averages its modulation and its squared profile over the start offset: the models a campaign
compares its measurements with.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from fractions import Fraction
from typing import Literal, NotRequired, TypedDict, Unpack, overload

import numpy as np
import numpy.typing as npt

from camd.timing._checks import count, non_negative, positive

FloatArray = npt.NDArray[np.float64]
ImcMode = Literal["none", "row", "electrode"]
IMC_MODES: tuple[ImcMode, ...] = ("none", "row", "electrode")

MAX_CHARGE_SHIFTS = 1_000_000
"""Most packet moves one exposure may hold (``charge_shift_schedule`` refuses more)."""

_STATIC_PX = 1e-7  # below this motion (pixels) a piece of the exposure is treated as static
_STEP_AT_END_RTOL = 1e-9  # a move this close to the end of the exposure falls after it

ELECTRODE_FORM_PHASES = 4
"""The electrode-step closed form of docs/physics.md §7 is REN15's, for a 4-phase CCD (FTF5066M)."""

MEAN_ROW_STEP_MODULATION = Fraction(1, 3)
"""Exact average of the row-step modulation over ``a`` uniform in ``[0, w)``."""

MEAN_ELECTRODE_STEP_MODULATION = Fraction(47, 96)
"""Exact average of the 4-phase electrode-step modulation over ``a`` uniform in ``[0, w)``."""


def image_velocity_m_s(focal_length_m: float, ground_speed_m_s: float, height_m: float) -> float:
    """Image velocity on the focal plane ``v = f V / H``.

    docs/physics.md §7 [REN15]: focal length ``f``, ground (aircraft, or lab target) speed ``V``,
    height (object distance) ``H``. Pass the speed's magnitude: the direction only decides which
    way the charge is clocked, not how fast.
    """
    focal = positive("focal_length_m", focal_length_m)
    speed = positive("ground_speed_m_s", ground_speed_m_s)
    height = positive("height_m", height_m)
    return focal * speed / height


def row_step_interval_s(pixel_m: float, image_velocity_m_s: float) -> float:
    """Clock interval of row-step (conventional) compensation: one row ``w`` every ``w / v``.

    docs/physics.md §7 [REN15]: the packets move one whole pixel each time the image has moved one.
    """
    pixel = positive("pixel_m", pixel_m)
    velocity = positive("image_velocity_m_s", image_velocity_m_s)
    return pixel / velocity


def electrode_step_interval_s(
    pixel_m: float, image_velocity_m_s: float, phases: int = ELECTRODE_FORM_PHASES
) -> float:
    """Clock interval of electrode-step compensation ``dt = w / (p v)``.

    docs/physics.md §7 [REN15]: on a p-phase CCD the packets move one electrode (``w / p``) at a
    time; ``phases = 4`` on an FTF5066M-class sensor. ``phases = 1`` is row stepping.
    """
    pixel = positive("pixel_m", pixel_m)
    velocity = positive("image_velocity_m_s", image_velocity_m_s)
    return pixel / (count("phases", phases, 1) * velocity)


def pixel_offsets(a_m: npt.ArrayLike, pixel_m: float) -> tuple[FloatArray, float]:
    """A point beam's start offsets ``a`` as a float array checked to lie in ``[0, w)``, and
    ``w`` (docs/physics.md §7); a ValueError that says what to change otherwise."""
    pixel = positive("pixel_m", pixel_m)
    if isinstance(a_m, bool):
        raise ValueError(f"a_m must be a number or an array of numbers, got {a_m!r}")
    try:
        a = np.asarray(a_m, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"a_m must be a number or an array of numbers, got {a_m!r}") from exc
    bad = ~(np.isfinite(a) & (a >= 0.0) & (a < pixel))
    if np.any(bad):
        first = float(a[bad].flat[0])
        raise ValueError(
            f"a_m must be finite and in [0, pixel_m) = [0, {pixel:.6g}) m (the beam's start "
            f"offset from a pixel edge), got {first!r}: take the offset modulo the pixel"
        )
    return a, pixel


def _like(a_m: npt.ArrayLike, m: FloatArray) -> float | FloatArray:
    """``m`` as a float for a scalar offset, else as the array (0-d arrays stay arrays)."""
    return float(m) if m.ndim == 0 and not isinstance(a_m, np.ndarray) else m


@overload
def row_step_modulation(a_m: float, pixel_m: float) -> float: ...
@overload
def row_step_modulation(a_m: npt.ArrayLike, pixel_m: float) -> FloatArray: ...
def row_step_modulation(a_m: npt.ArrayLike, pixel_m: float) -> float | FloatArray:
    """Point-beam modulation with row-step compensation ``M(a) = 2a(w - a) / w^2``.

    docs/physics.md §7 [REN15]: a beam one pixel ``w`` wide starting ``a`` from a pixel edge,
    ``0 <= a < w``. 0 at ``a = 0`` (the beam straddles two pixels equally over each row step),
    0.5 at ``a = w / 2``. Vectorised: an array of offsets gives an array of modulations, a
    number gives a float.
    """
    a, w = pixel_offsets(a_m, pixel_m)
    m: FloatArray = 2.0 * a * (w - a) / (w * w)
    return _like(a_m, m)


@overload
def electrode_step_modulation(a_m: float, pixel_m: float) -> float: ...
@overload
def electrode_step_modulation(a_m: npt.ArrayLike, pixel_m: float) -> FloatArray: ...
def electrode_step_modulation(a_m: npt.ArrayLike, pixel_m: float) -> float | FloatArray:
    """Point-beam modulation with 4-phase electrode-step compensation, docs/physics.md §7 [REN15].

    ``M(a) = |3w - 8a| / (4w)`` for ``0 <= a <= 3w/4`` and
    ``M(a) = |56 a w - 32 a^2 - 21 w^2| / (4 w^2)`` for ``3w/4 < a < w``: 0.75 at ``a = 0``,
    0 at ``a = 3w/8``, 0.75 at ``a = 3w/4`` (the branches meet), 0.875 at ``a = 7w/8``. The
    second branch's argument is at least ``3 w^2`` there, so its absolute value never acts.
    Only for ``p = 4`` (REN15's sensor); vectorised over ``a`` like ``row_step_modulation``.
    """
    a, w = pixel_offsets(a_m, pixel_m)
    low = np.abs(3.0 * w - 8.0 * a) / (4.0 * w)
    high = np.abs(56.0 * a * w - 32.0 * a * a - 21.0 * w * w) / (4.0 * w * w)
    m: FloatArray = np.where(a <= 0.75 * w, low, high)
    return _like(a_m, m)


def mean_row_step_modulation() -> float:
    """Average of the row-step modulation over ``a`` uniform in ``[0, w)``: exactly 1/3.

    From docs/physics.md §7 [REN15], with ``x = a / w``:
    ``int_0^1 2x(1 - x) dx = 2 (1/2 - 1/3) = 1/3`` (independent of ``w``).
    """
    return float(MEAN_ROW_STEP_MODULATION)


def mean_electrode_step_modulation() -> float:
    """Average of the 4-phase electrode-step modulation over ``a`` in ``[0, w)``: exactly 47/96.

    From docs/physics.md §7 [REN15], with ``x = a / w``, split where the absolute value turns
    (``x = 3/8``) and where the branches meet (``x = 3/4``):

    - ``int_0^{3/8} (3 - 8x)/4 dx = (9/8 - 9/16)/4 = 9/64``;
    - ``int_{3/8}^{3/4} (8x - 3)/4 dx = (27/16 - 9/8)/4 = 9/64``;
    - ``int_{3/4}^1 (56x - 32x^2 - 21)/4 dx = (49/4 - 37/6 - 21/4)/4 = (5/6)/4 = 5/24``;

    total ``9/32 + 5/24 = 47/96 ~= 0.4896``, against 1/3 for row steps.
    """
    return float(MEAN_ELECTRODE_STEP_MODULATION)


# -- clocking during one exposure, and the exact point-beam image ---------------------------------


@dataclass(frozen=True, slots=True)
class ChargeShifts:
    """When the charge packets move during one exposure (``charge_shift_schedule``).

    The exposure ``[0, exposure_s]`` is cut at the moves into ``pieces``: piece ``j`` lasts
    from ``bounds_s[j]`` to ``bounds_s[j + 1]``, and during it the packets sit
    ``electrodes[j]`` electrodes (``electrodes[j] / phases`` pixels) from where they started.
    """

    mode: ImcMode
    phases: int
    exposure_s: float
    bounds_s: FloatArray
    electrodes: npt.NDArray[np.int64]

    @property
    def pieces(self) -> int:
        """Pieces of the exposure between moves (moves + 1)."""
        return int(self.electrodes.size)

    @property
    def durations_s(self) -> FloatArray:
        """Length of each piece."""
        result: FloatArray = np.diff(self.bounds_s)
        return result

    @property
    def shift_px(self) -> FloatArray:
        """The packets' displacement during each piece, in pixels (``electrodes / phases``)."""
        result: FloatArray = self.electrodes / float(self.phases)
        return result


def charge_shift_schedule(
    exposure_s: float,
    electrode_interval_s: float,
    mode: ImcMode,
    phases: int = ELECTRODE_FORM_PHASES,
) -> ChargeShifts:
    """When the packets move during an exposure, docs/physics.md §7 [REN15].

    The compensation clock starts with the exposure (``t = 0``). ``"electrode"``: the packets
    move one electrode (``w / p``) at every ``k * electrode_interval_s``; ``"row"``: they move
    all ``p`` electrodes (one pixel) at every ``k * p * electrode_interval_s`` (the same
    clock, so at the matched interval ``dt = w / (p v)`` a row step comes every ``w / v``);
    ``"none"``: never. Only moves strictly inside the exposure count: one at its very end (to
    within 1e-9 of it) moves charge that no longer collects anything. ``electrode_interval_s``
    is what the camera is programmed with; it need not match the image velocity.
    """
    exposure = positive("exposure_s", exposure_s)
    p = count("phases", phases, 1)
    if mode not in IMC_MODES:
        raise ValueError(f"mode must be one of {', '.join(IMC_MODES)}, got {mode!r}")
    if mode == "none":
        return ChargeShifts(
            mode, p, exposure, np.array([0.0, exposure]), np.zeros(1, dtype=np.int64)
        )
    interval = positive("electrode_interval_s", electrode_interval_s)
    step_s, per_move = (interval, 1) if mode == "electrode" else (p * interval, p)
    last_s = exposure * (1.0 - _STEP_AT_END_RTOL)
    moves = math.floor(last_s / step_s)
    if moves > 0 and moves * step_s >= last_s:
        moves -= 1
    if moves > MAX_CHARGE_SHIFTS:
        raise ValueError(
            f"{mode} steps every {step_s:.6g} s make {moves} moves in a {exposure:.6g} s "
            f"exposure, more than the {MAX_CHARGE_SHIFTS} modelled: lengthen the step interval "
            "or shorten the exposure"
        )
    times = np.arange(1, moves + 1, dtype=np.float64) * step_s
    bounds = np.concatenate([[0.0], times, [exposure]])
    electrodes = per_move * np.arange(moves + 1, dtype=np.int64)
    return ChargeShifts(mode, p, exposure, bounds, electrodes)


def _triangle(z: FloatArray) -> FloatArray:
    """Overlap of two unit boxes whose lower edges are ``z`` apart: ``max(0, 1 - |z|)``."""
    result: FloatArray = np.clip(1.0 - np.abs(z), 0.0, None)
    return result


def _triangle_integral(z: FloatArray) -> FloatArray:
    """The integral of ``_triangle`` from -inf to ``z`` (0 below -1, 1 above 1)."""
    inner = np.clip(z, -1.0, 1.0)
    result: FloatArray = np.where(
        inner <= 0.0, 0.5 * (inner + 1.0) ** 2, 1.0 - 0.5 * (1.0 - inner) ** 2
    )
    return result


class PointBeamSetup(TypedDict):
    """``point_beam_profile``'s keyword arguments, for ``point_beam_means``, which passes them
    on: each default stays written once, in ``point_beam_profile``."""

    pixel_m: float
    image_velocity_m_s: float
    exposure_s: float
    mode: ImcMode
    electrode_interval_s: NotRequired[float | None]
    phases: NotRequired[int]


def point_beam_profile(
    a_m: float | npt.ArrayLike,
    *,
    pixel_m: float,
    image_velocity_m_s: float,
    exposure_s: float,
    mode: ImcMode,
    electrode_interval_s: float | None = None,
    phases: int = ELECTRODE_FORM_PHASES,
) -> tuple[int, FloatArray]:
    """The packets' share of a moving point beam's charge, exactly, docs/physics.md §7 [REN15].

    The geometry of ``firmware_models.ccd_imc`` (one CCD column): a beam one pixel ``w`` wide
    starts ``a`` from the edge of pixel 0 and moves at ``v`` along the column; packet ``k``'s
    collection region, pixel ``k`` when the exposure began, moves with the packets as
    ``charge_shift_schedule`` clocks them (``electrode_interval_s`` defaults to the matched
    ``dt = w / (p v)``). During a piece the beam moves linearly relative to the packets, and
    the overlap of two pixel-wide boxes is a triangle in their offset, so each piece
    contributes the difference of the triangle's integral at its ends over the motion (its
    value at mid-piece for a piece without motion): exact, no time steps.

    Returns ``(first, profile)``: ``profile[..., i]`` is the fraction of the beam's charge in
    packet ``first + i`` (it sums to 1 over the last axis), shape ``np.shape(a_m) + (K,)``.
    For a whole number of row times ``w / v`` with row or electrode steps the modulation of
    the profile is the closed form (``row_step_modulation``, ``electrode_step_modulation``).
    """
    a, w = pixel_offsets(a_m, pixel_m)
    velocity = non_negative("image_velocity_m_s", image_velocity_m_s)
    exposure = positive("exposure_s", exposure_s)
    p = count("phases", phases, 1)
    if electrode_interval_s is not None:
        interval = positive("electrode_interval_s", electrode_interval_s)
    elif mode == "none":
        interval = exposure  # not used: nothing moves
    elif velocity > 0.0:
        interval = electrode_step_interval_s(w, velocity, p)
    else:
        raise ValueError("a still image has no matched step interval: give electrode_interval_s")
    schedule = charge_shift_schedule(exposure, interval, mode, p)
    image_px = velocity * schedule.bounds_s / w
    start = image_px[:-1] - schedule.shift_px  # beam offset from the packets, pixels
    end = image_px[1:] - schedule.shift_px
    weight = schedule.durations_s / exposure
    first = math.floor(min(start.min(), end.min()))
    last = math.ceil(max(start.max(), end.max())) + 1
    x = (a / w).reshape(-1)
    profile = np.zeros((x.size, last - first + 1))
    block = max(1, (1 << 20) // max(x.size, 1))
    for lo in range(0, schedule.pieces, block):
        u0 = x[:, None] + start[None, lo : lo + block]
        u1 = x[:, None] + end[None, lo : lo + block]
        tau = weight[None, lo : lo + block]
        motion = u1 - u0
        moving = np.abs(motion) >= _STATIC_PX
        safe = np.where(moving, motion, 1.0)
        for i, k in enumerate(range(first, last + 1)):
            swept = (_triangle_integral(u1 - k) - _triangle_integral(u0 - k)) / safe
            still = _triangle(0.5 * (u0 + u1) - k)
            profile[:, i] += np.sum(tau * np.where(moving, swept, still), axis=1)
    return first, profile.reshape((*a.shape, last - first + 1))


def profile_modulation(profile: npt.ArrayLike) -> FloatArray:
    """Modulation ``(2 max - sum) / sum`` of pixel profiles along the last axis, §7 [REN15].

    The charge in the main (brightest) packet minus the charge spilled into all the others,
    over the total: the definition under which both closed forms of docs/physics.md §7 follow from
    the charge-transfer geometry (docs/imc.md). 1 for all the charge in one pixel, 0 for an
    even split over two, negative when no pixel holds half. A single profile gives a 0-d
    array.
    """
    q = np.asarray(profile, dtype=np.float64)
    if q.ndim < 1 or q.shape[-1] < 1:
        raise ValueError("profile must have at least one pixel along its last axis")
    if not np.all(np.isfinite(q)):
        raise ValueError("profile must hold finite charges")
    total = q.sum(axis=-1)
    if np.any(total <= 0.0):
        raise ValueError("profile holds no charge: expose longer or aim the beam at the column")
    result: FloatArray = (2.0 * q.max(axis=-1) - total) / total
    return result


@dataclass(frozen=True, slots=True)
class PointBeamMeans:
    """Averages over the start offset ``a`` (uniform in ``[0, w)``) of a point beam's image.

    ``modulation``: the mean of ``profile_modulation``. ``square_sum``: the mean of
    ``sum_k q_k^2`` over the normalised profile ``q``, which sets the grey-gradient sharpness
    of an edge (``camd.analysis.imc.periodic_edge_sharpness``): 2/3 for a still image, less the
    more the image smears.
    """

    modulation: float
    square_sum: float


def point_beam_means(*, offsets: int = 1024, **beam: Unpack[PointBeamSetup]) -> PointBeamMeans:
    """``point_beam_profile``'s modulation and squared profile averaged over ``a``.

    Midpoint rule over ``offsets`` offsets ``(i + 1/2) w / offsets``; the curves are piecewise
    quadratic in ``a``, so the error falls as ``1 / offsets**2`` (about 1e-6 at 1024). For a
    whole number of row times the modulation is 1/3 (row steps) or 47/96 (electrode steps,
    p = 4), the means of the closed forms.
    """
    n = count("offsets", offsets, 1)
    w = positive("pixel_m", beam["pixel_m"])
    a = (np.arange(n) + 0.5) * (w / n)
    _, profile = point_beam_profile(a, **beam)
    return PointBeamMeans(
        modulation=float(profile_modulation(profile).mean()),
        square_sum=float(np.sum(profile * profile, axis=-1).mean()),
    )
