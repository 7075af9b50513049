"""Image sharpness by the grey-gradient function (docs/physics.md §7, [REN15]).

REN15 compares the sharpness of images taken with and without image motion compensation by the
grey-gradient function, the sum of squared differences of neighbouring pixels, normalised.
The normalisation chosen here makes the number independent of exposure and gain:

    G = mean over neighbour pairs of (I_a - I_b)^2  /  (mean(I) - black)^2

- the sum is divided by the number of pairs, so that G does not grow with the image size;
- it is divided by the squared mean level above black, so that scaling the signal (exposure
  time, light level, gain) leaves G unchanged. An offset is not a scale: give ``black_dn``
  (the black level) so that it is removed from the mean; differences do not see it.

G is the mean squared relative gradient: for a pattern of modulation m whose neighbours
alternate (a Nyquist checkerboard along the axis) G = 4 m^2; a uniform image gives 0. Noise
adds ``2 sigma^2 / mean^2`` to it, so compare images of equal signal-to-noise ratio (or
subtract that term). A blur lowers G; it is a figure of merit for focus and motion
compensation, not an MTF.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
import numpy.typing as npt

SharpnessAxis = Literal["both", "along", "across"]


def grey_gradient_sharpness(
    image: npt.ArrayLike, *, black_dn: float = 0.0, axis: SharpnessAxis = "both"
) -> float:
    """The grey-gradient sharpness ``G`` of docs/physics.md §7 [REN15], normalised (module doc).

    ``axis``: ``"both"`` takes the pairs along axis 0 (rows, along track) and axis 1
    (columns, across track) together; ``"along"`` only pairs along axis 0, ``"across"`` only
    along axis 1 (an along-track smear lowers ``"along"`` and leaves ``"across"``).
    ``black_dn`` is subtracted from the mean level before normalising.
    """
    arr = np.asarray(image, dtype=np.float64)
    if arr.ndim != 2:
        raise ValueError(f"grey_gradient_sharpness needs a 2-D image, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError("the image holds NaN or infinite pixels; crop them out")
    if axis not in ("both", "along", "across"):
        raise ValueError(f"axis must be 'both', 'along' or 'across', got {axis!r}")
    rows, cols = arr.shape
    need_rows = axis in ("both", "along")
    need_cols = axis in ("both", "across")
    if (need_rows and rows < 2) or (need_cols and cols < 2):
        raise ValueError(
            f"an image of {rows} x {cols} pixels has no neighbour pairs along axis={axis!r}; "
            "take at least 2 pixels along each axis used"
        )
    level = float(arr.mean()) - float(black_dn)
    if not level > 0.0:
        raise ValueError(
            f"the mean level above black is {level:g} DN: the normalisation needs a positive "
            "signal; check black_dn"
        )
    total = 0.0
    pairs = 0
    if need_rows:
        d = np.diff(arr, axis=0)
        total += float(np.sum(d * d))
        pairs += d.size
    if need_cols:
        d = np.diff(arr, axis=1)
        total += float(np.sum(d * d))
        pairs += d.size
    return total / pairs / level**2
