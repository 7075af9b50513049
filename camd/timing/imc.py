"""Electronic image motion compensation (IMC) on a full-frame CCD: clocking and modulation.

physics.md §7 [REN15]: the image of the ground moves over the focal plane at ``v = f V / H``.
Conventional compensation moves the charge packets one row (one pixel ``w``) every ``w / v``;
REN15's improved method moves them one electrode (``w / p`` on a p-phase CCD) every
``dt = w / (p v)``. The modulation of a point beam's image (beam one pixel wide, starting ``a``
from a pixel edge) is given in closed form for both methods; the averages over ``a`` are
integrated here by hand. ``firmware_models.ccd_imc`` checks the closed forms against a numeric
charge-transfer model.
"""

from __future__ import annotations

from fractions import Fraction
from typing import overload

import numpy as np
import numpy.typing as npt

from camd.timing._checks import count, positive

FloatArray = npt.NDArray[np.float64]

ELECTRODE_FORM_PHASES = 4
"""The electrode-step closed form of physics.md §7 is REN15's, for a 4-phase CCD (FTF5066M)."""

MEAN_ROW_STEP_MODULATION = Fraction(1, 3)
"""Exact average of the row-step modulation over ``a`` uniform in ``[0, w)``."""

MEAN_ELECTRODE_STEP_MODULATION = Fraction(47, 96)
"""Exact average of the 4-phase electrode-step modulation over ``a`` uniform in ``[0, w)``."""


def image_velocity_m_s(focal_length_m: float, ground_speed_m_s: float, height_m: float) -> float:
    """Image velocity on the focal plane ``v = f V / H``.

    physics.md §7 [REN15]: focal length ``f``, ground (aircraft, or lab target) speed ``V``,
    height (object distance) ``H``. Pass the speed's magnitude: the direction only decides which
    way the charge is clocked, not how fast.
    """
    focal = positive("focal_length_m", focal_length_m)
    speed = positive("ground_speed_m_s", ground_speed_m_s)
    height = positive("height_m", height_m)
    return focal * speed / height


def row_step_interval_s(pixel_m: float, image_velocity_m_s: float) -> float:
    """Clock interval of row-step (conventional) compensation: one row ``w`` every ``w / v``.

    physics.md §7 [REN15]: the packets move one whole pixel each time the image has moved one.
    """
    pixel = positive("pixel_m", pixel_m)
    velocity = positive("image_velocity_m_s", image_velocity_m_s)
    return pixel / velocity


def electrode_step_interval_s(
    pixel_m: float, image_velocity_m_s: float, phases: int = ELECTRODE_FORM_PHASES
) -> float:
    """Clock interval of electrode-step compensation ``dt = w / (p v)``.

    physics.md §7 [REN15]: on a p-phase CCD the packets move one electrode (``w / p``) at a
    time; ``phases = 4`` on an FTF5066M-class sensor. ``phases = 1`` is row stepping.
    """
    pixel = positive("pixel_m", pixel_m)
    velocity = positive("image_velocity_m_s", image_velocity_m_s)
    return pixel / (count("phases", phases, 1) * velocity)


def _offsets(a_m: npt.ArrayLike, pixel_m: float) -> tuple[FloatArray, float]:
    """``a`` as a float array checked to lie in ``[0, w)``, and ``w``; a ValueError otherwise."""
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

    physics.md §7 [REN15]: a beam one pixel ``w`` wide starting ``a`` from a pixel edge,
    ``0 <= a < w``. 0 at ``a = 0`` (the beam straddles two pixels equally over each row step),
    0.5 at ``a = w / 2``. Vectorised: an array of offsets gives an array of modulations, a
    number gives a float.
    """
    a, w = _offsets(a_m, pixel_m)
    m: FloatArray = 2.0 * a * (w - a) / (w * w)
    return _like(a_m, m)


@overload
def electrode_step_modulation(a_m: float, pixel_m: float) -> float: ...
@overload
def electrode_step_modulation(a_m: npt.ArrayLike, pixel_m: float) -> FloatArray: ...
def electrode_step_modulation(a_m: npt.ArrayLike, pixel_m: float) -> float | FloatArray:
    """Point-beam modulation with 4-phase electrode-step compensation, physics.md §7 [REN15].

    ``M(a) = |3w - 8a| / (4w)`` for ``0 <= a <= 3w/4`` and
    ``M(a) = |56 a w - 32 a^2 - 21 w^2| / (4 w^2)`` for ``3w/4 < a < w``: 0.75 at ``a = 0``,
    0 at ``a = 3w/8``, 0.75 at ``a = 3w/4`` (the branches meet), 0.875 at ``a = 7w/8``. The
    second branch's argument is at least ``3 w^2`` there, so its absolute value never acts.
    Only for ``p = 4`` (REN15's sensor); vectorised over ``a`` like ``row_step_modulation``.
    """
    a, w = _offsets(a_m, pixel_m)
    low = np.abs(3.0 * w - 8.0 * a) / (4.0 * w)
    high = np.abs(56.0 * a * w - 32.0 * a * a - 21.0 * w * w) / (4.0 * w * w)
    m: FloatArray = np.where(a <= 0.75 * w, low, high)
    return _like(a_m, m)


def mean_row_step_modulation() -> float:
    """Average of the row-step modulation over ``a`` uniform in ``[0, w)``: exactly 1/3.

    From physics.md §7 [REN15], with ``x = a / w``:
    ``int_0^1 2x(1 - x) dx = 2 (1/2 - 1/3) = 1/3`` (independent of ``w``).
    """
    return float(MEAN_ROW_STEP_MODULATION)


def mean_electrode_step_modulation() -> float:
    """Average of the 4-phase electrode-step modulation over ``a`` in ``[0, w)``: exactly 47/96.

    From physics.md §7 [REN15], with ``x = a / w``, split where the absolute value turns
    (``x = 3/8``) and where the branches meet (``x = 3/4``):

    - ``int_0^{3/8} (3 - 8x)/4 dx = (9/8 - 9/16)/4 = 9/64``;
    - ``int_{3/8}^{3/4} (8x - 3)/4 dx = (27/16 - 9/8)/4 = 9/64``;
    - ``int_{3/4}^1 (56x - 32x^2 - 21)/4 dx = (49/4 - 37/6 - 21/4)/4 = (5/6)/4 = 5/24``;

    total ``9/32 + 5/24 = 47/96 ~= 0.4896``, against 1/3 for row steps.
    """
    return float(MEAN_ELECTRODE_STEP_MODULATION)
