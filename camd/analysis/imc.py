"""Image motion compensation measured on images of a slanted periodic edge (docs/physics.md §7).

REN15 judges electronic image motion compensation on a full-frame CCD by the grey-gradient
sharpness of the images and by the modulation of a point beam's image. Both can be measured
on one target, a periodic edge slanted by a small angle to the rows, whose columns each see an
edge at a different offset ``a`` from the pixel grid, so that the columns together sample ``a``
uniformly:

- **Point-beam modulation from an edge.** The image is linear in the radiance and the clocking
  treats every packet alike, so a beam one pixel wide, ``[a, a + w)``, is the difference of an
  edge at ``a`` and one at ``a + w``, and its image the difference of the edge's image and the
  same image one packet further: the first difference of a column along the track *is* the
  point beam's pixel profile (``edge_line_modulations``; a falling edge gives it negated).
  Its modulation ``(2 max - sum) / sum`` (``camd.timing.imc.profile_modulation``) averaged over
  the edges compares with the mean over ``a`` of the closed forms (1/3 row steps, 47/96
  electrode steps) or, for any exposure, ``camd.timing.imc.point_beam_means``.
- **Sharpness of the edges.** With bright level ``B``, dark level ``D`` (Michelson contrast
  ``c = (B - D) / (B + D)``) and period ``P`` rows, half bright, each column holds ``2 / P``
  edges per row, and the squared along-track differences across one edge sum to
  ``(B - D)^2 sum_k q_k^2`` with ``q`` the normalised point-beam profile. Averaged over the
  offsets (and so over the columns) the grey-gradient function of
  ``camd.analysis.sharpness`` along the track is

      G = (2 / P) (B - D)^2 <sum q^2> / ((B + D) / 2)^2 = 8 c^2 <sum q^2> / P

  (``periodic_edge_sharpness``), plus the noise floor ``2 sigma^2 / mean^2`` that temporal
  noise and PRNU add to every pair alike: the across-track pairs of a nearly horizontal edge
  hold that floor alone (their edge term is ``tan^2(angle)`` times smaller), so the floor is
  measured there. ``<sum q^2>`` is 2/3 for a still image and falls as the image smears.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from camd.timing.imc import profile_modulation

FloatArray = npt.NDArray[np.float64]


def periodic_edge_sharpness(square_sum: float, period_rows: float, contrast: float = 1.0) -> float:
    """Noise-free grey-gradient sharpness along the track of a periodic edge, docs/physics.md §7.

    ``G = 8 c^2 <sum q^2> / P`` (module docstring): ``square_sum`` is the point-beam profile's
    ``<sum q^2>`` over the offsets (``camd.timing.imc.point_beam_means``), ``period_rows`` the
    edge period ``P`` in rows (half bright, half dark; edges farther apart than the blur) and
    ``contrast`` its Michelson contrast. Normalised like
    ``camd.analysis.sharpness.grey_gradient_sharpness`` (pairs and the squared mean level).
    """
    if not (np.isfinite(square_sum) and 0.0 < square_sum <= 1.0):
        raise ValueError(
            f"square_sum must be in (0, 1] (a profile's sum of squares), got {square_sum}"
        )
    if not (np.isfinite(period_rows) and period_rows >= 2.0):
        raise ValueError(f"period_rows must be >= 2 rows, got {period_rows}")
    if not 0.0 <= contrast <= 1.0:
        raise ValueError(f"contrast must be in [0, 1], got {contrast}")
    return 8.0 * contrast**2 * square_sum / period_rows


def edge_line_modulations(
    image: npt.ArrayLike,
    *,
    black_dn: float = 0.0,
    half_width: int = 3,
    threshold: float = 0.2,
) -> FloatArray:
    """The point-beam modulation of every edge in an image of a periodic edge, docs/physics.md §7.

    Along each column the first difference ``I[i + 1] - I[i]`` is the point beam's pixel
    profile at that edge (module docstring). An edge is a difference that is the largest of
    its sign within ``half_width`` rows on either side (the first of equal ones) and exceeds
    ``threshold`` times the column's step height (the 95th minus the 5th percentile of the
    column); its profile is the ``2 half_width + 1`` differences centred on it, sign-corrected,
    and edges whose profile would leave the image are skipped. ``half_width`` must cover the
    blur (3 rows: a smear up to about 4 pixels) and stay below half the edges' spacing.
    Returns the modulations ``(2 max - sum) / sum``, one per edge, columns in order.
    """
    img = np.asarray(image, dtype=np.float64) - float(black_dn)
    if img.ndim != 2:
        raise ValueError(f"edge_line_modulations needs a 2-D image, got shape {img.shape}")
    if not np.all(np.isfinite(img)):
        raise ValueError("the image holds NaN or infinite pixels; crop them out")
    h = int(half_width)
    if h < 1:
        raise ValueError(f"half_width must be >= 1 row, got {half_width}")
    rows = img.shape[0]
    if rows < 2 * h + 3:
        raise ValueError(
            f"an image of {rows} rows cannot hold one edge profile of {2 * h + 1} differences; "
            f"take at least {2 * h + 3} rows"
        )
    diff = np.diff(img, axis=0)  # (rows - 1, cols)
    lo, hi = np.percentile(img, [5.0, 95.0], axis=0)
    step = hi - lo  # (cols,)
    out: list[FloatArray] = []
    for sign in (1.0, -1.0):
        d = sign * diff
        padded = np.pad(d, ((h, h), (0, 0)), constant_values=-np.inf)
        centre = padded[h : h + d.shape[0]]
        peak = centre > threshold * step[None, :]
        for offset in range(1, h + 1):
            earlier = padded[h - offset : h - offset + d.shape[0]]
            later = padded[h + offset : h + offset + d.shape[0]]
            peak &= (centre > earlier) & (centre >= later)
        peak[:h] = False  # the profile would leave the image
        peak[d.shape[0] - h :] = False
        index, column = np.nonzero(peak)
        if index.size == 0:
            continue
        window = index[:, None] + np.arange(-h, h + 1)[None, :]
        profiles = d[window, column[:, None]]
        order = np.lexsort((index, column))
        out.append(profile_modulation(profiles[order]))
    if not out:
        raise ValueError(
            "no edge found: the image needs edges along the columns (a slanted periodic edge) "
            f"with steps above {threshold:g} of the column's range"
        )
    return np.concatenate(out)
