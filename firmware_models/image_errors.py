"""Image motion the stage's encoder cannot see: a magnification error, a camera rotated about
the optical axis, a stage that yaws (docs/simulator.md, "Image motion errors").

The encoder counts the stage's travel ``x`` (metres). The image moves ``m x / p`` rows for the
optics' nominal magnification ``m`` and the pixel pitch ``p`` (docs/physics.md §2); these errors
change where the image really goes, not what the encoder counts:

- ``magnification_error`` ``e``: the image moves ``(1 + e)`` times as far (a focal length or
  object distance off its nominal value), a velocity mismatch ``dV/V = e`` under the
  encoder-synchronised loop.
- ``rotation_deg`` ``r``: the sensor's columns are turned by ``r`` from the direction of
  travel, so each row of along-track motion carries ``tan(r)`` columns across track.
- ``yaw_deg_per_m`` ``k``: the direction of travel turns by ``k`` per metre of stage travel
  (from the stage's position 0), so the across-track drift grows along the scan.

Together the image's direction at travel ``u`` is ``phi(u) = r + k u`` from the columns and its
displacement after ``x`` of travel is ``(1 + e) (m / p) integral_0^x (cos phi, sin phi) du``
(rows along, columns across), in closed form ``x (cos, sin)(r + k x / 2) sinc(k x / 2)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

Array = npt.NDArray[Any]

MAGNIFICATION_ERROR_LIMIT = 0.1
"""Largest ``|magnification_error|``: 10 %, beyond any focus or mounting error a bench meets."""
ROTATION_LIMIT_DEG = 10.0
"""Largest ``|rotation_deg|``: a camera on its mount is off by a degree or so, not more."""
YAW_LIMIT_DEG_PER_M = 100.0
"""Largest ``|yaw_deg_per_m|``: 10 degrees over a 0.1 m scan."""


@dataclass(frozen=True, slots=True)
class ImageMotionErrors:
    """The three errors (module docstring); all zero: the image moves as the encoder says."""

    magnification_error: float = 0.0
    rotation_deg: float = 0.0
    yaw_deg_per_m: float = 0.0

    def __post_init__(self) -> None:
        checks = (
            ("magnification_error", self.magnification_error, MAGNIFICATION_ERROR_LIMIT, ""),
            ("rotation_deg", self.rotation_deg, ROTATION_LIMIT_DEG, " deg"),
            ("yaw_deg_per_m", self.yaw_deg_per_m, YAW_LIMIT_DEG_PER_M, " deg/m"),
        )
        for name, value, limit, unit in checks:
            if not (math.isfinite(value) and abs(value) <= limit):
                raise ValueError(f"{name} must be within +-{limit:g}{unit}, got {value:g}")

    @property
    def any(self) -> bool:
        """Whether the image moves differently from what the encoder says."""
        return bool(self.magnification_error or self.rotation_deg or self.yaw_deg_per_m)

    @property
    def turns(self) -> bool:
        """Whether the image moves across track (a rotation or a yaw)."""
        return bool(self.rotation_deg or self.yaw_deg_per_m)

    def displacement(self, stage_m: npt.ArrayLike, rows_per_m: float) -> tuple[Array, Array]:
        """The image's displacement (rows along track, columns across) after ``stage_m`` of
        stage travel, the nominal image scale being ``rows_per_m`` (``m / p``)."""
        travel_m = np.asarray(stage_m, dtype=np.float64)
        scale = (1.0 + self.magnification_error) * rows_per_m
        rotation_rad = math.radians(self.rotation_deg)
        half_turn_rad = 0.5 * math.radians(self.yaw_deg_per_m) * travel_m
        # sinc(k x / 2) written so that it is exactly 1 without a yaw (np.sinc is sin(pi x)/(pi x)).
        sinc = np.sinc(half_turn_rad / math.pi)
        heading_rad = rotation_rad + half_turn_rad
        length = scale * travel_m * sinc
        along: Array = length * np.cos(heading_rad)
        across: Array = length * np.sin(heading_rad)
        return along, across


def rotate_cells(
    cells: Array, rotation_deg: float, *, oversample: int, x_oversample: int, columns: int
) -> Array:
    """A scene's radiance cells turned by ``rotation_deg`` in the focal plane (a camera turned
    on its mount sees the target turned the other way round its columns' frame).

    Sensor position ``(y, x)`` (rows, columns) sees the unturned scene at ``(y cos r + x sin r,
    -y sin r + x cos r)``: the direction of travel, along the scene's rows, then runs at ``r``
    to the columns, as ``ImageMotionErrors.displacement`` moves the image. Each new cell takes
    the bilinear interpolation of the old cells' centres at that point, wrapping round the
    scene's period both ways (exact for a scene linear over the cells). A scene narrower than
    ``columns`` is first tiled to that width, since a turned scene varies across track. The
    result keeps the old period, so a turned periodic scene has a seam where one tile meets
    the next (along track every period, across track at the sensor's edge): a shift of
    ``period sin r`` rows or columns there.
    """
    width_px = cells.shape[1] // x_oversample
    if width_px < columns:
        cells = np.tile(cells, (1, -(-columns // width_px)))
    n_rows, n_cols = cells.shape
    rotation_rad = math.radians(rotation_deg)
    cos_r, sin_r = math.cos(rotation_rad), math.sin(rotation_rad)
    y = ((np.arange(n_rows, dtype=np.float64) + 0.5) / oversample)[:, np.newaxis]
    x = ((np.arange(n_cols, dtype=np.float64) + 0.5) / x_oversample)[np.newaxis, :]
    # The source point in cell-centre coordinates of the old cells.
    source_row = (y * cos_r + x * sin_r) * oversample - 0.5
    source_col = (x * cos_r - y * sin_r) * x_oversample - 0.5
    row0 = np.floor(source_row)
    col0 = np.floor(source_col)
    frac_row = source_row - row0
    frac_col = source_col - col0
    r0 = row0.astype(np.int64) % n_rows
    c0 = col0.astype(np.int64) % n_cols
    r1 = (r0 + 1) % n_rows
    c1 = (c0 + 1) % n_cols
    top = cells[r0, c0] * (1.0 - frac_col) + cells[r0, c1] * frac_col
    bottom = cells[r1, c0] * (1.0 - frac_col) + cells[r1, c1] * frac_col
    turned: Array = top * (1.0 - frac_row) + bottom * frac_row
    return turned
