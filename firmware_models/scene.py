"""The scene the simulated camera looks at: a radiance map moving along the sensor's columns.

Coordinates (rows and columns of pixel pitch, at the focal plane). The image moves along track
"from row M towards row 1" (docs/physics.md §1): the object seen by row ``r`` of frame ``k + 1`` was
seen by row ``r + 1`` of frame ``k``. With the image displaced by ``d`` rows, sensor row ``r``
(array index, 0-based; the pixel spans ``[r, r + 1)``) sees scene rows ``y = r + d`` and sensor
column ``x`` sees scene column ``x + s``, ``s = d tan(beta)`` for a drift angle ``beta`` (the
image also moves ``tan(beta)`` columns per row of along-track motion, docs/physics.md §1).

Radiance is piecewise constant on cells: ``oversample`` cells per row along track and per column
across track (image files: one cell per pixel), in photons per pixel area per second at the focal
plane. The scene tiles periodically: along track with its period (``period_rows``), across track
with its width (``width_cols``, the sensor's columns for most built-ins).

What a pixel collects (``Scene.integrate``): its photosensitive aperture is a centred square of
side ``q = sqrt(fill_factor)`` pitches. Across track the aperture integral is done once per
aperture when the scene is first used (exactly, on the cells). Along track the aperture moves
linearly from displacement ``d0`` to ``d1`` during the exposure ``T``; the photons it collects
are the exact double integral over time and aperture,

    N = T / (d1 - d0) * [G(a + q + d1) - G(a + q + d0) - G(a + d1) + G(a + d0)]

with ``a`` the aperture's lower edge, ``F`` the cumulative integral of the (x-integrated)
radiance along ``y`` and ``G`` the cumulative integral of ``F``; for ``d1 == d0`` it is
``T [F(a + q + d0) - F(a + d0)]``. Because the radiance is a sum of cell indicators, ``N`` is a
weighted sum of the cells the moving aperture touches; each weight is the same formula for one
cell, evaluated in float64 in coordinates local to the pixel (so no large cumulative sums are
subtracted), which is exact and cheap (``motion_weights``).

Drift: the lateral shift is applied at mid-exposure, per row, by linear interpolation between
the x-integrated columns. The lateral motion inside one exposure, ``tan(beta) |d1 - d0|``
columns (0.009 columns for beta = 0.5 deg and one row of along-track motion), is neglected.

Built-in scenes (``SceneSpec.parse("kind:key=value,...")``):

- ``flat``: uniform; a pixel collects ``L q^2 T`` photons (the fill factor times the level).
- ``bars``: square-wave groups at 0.05 .. 0.5 cycles/pixel (Nyquist); ``orientation=along``
  puts the groups side by side across the columns with bars varying along track (period 40
  rows), ``across`` stacks them in 32-row bands along track with bars varying across track.
- ``edge``: bright where ``(y - x tan(angle_deg)) mod period < period / 2`` (default 5 deg,
  64 rows): edges across track whose ESF varies along track, slanted for super-resolved ESFs.
  ``x_oversample=1`` gives each column one cell across (the edge at the column's centre), so
  fine cells along track (``oversample=16``: a cell smears the edge over 1/16 row) stay cheap
  on a wide sensor (the motion-compensation campaign's target, docs/imc.md). ``texture_cols``
  puts the natural texture (``seed``) in that many central columns instead (``_with_texture``).
- ``star``: a Siemens star of ``spokes`` pairs in a ``size`` x ``size`` tile (tiled).
- ``ramp``: ``level * (y mod period) / period`` along track (a sawtooth; a test scene: the
  box integral of a linear function is its centre value).
- ``natural``: a synthetic natural-image texture (``natural_texture``: the 1/f amplitude
  spectrum of natural images, seeded), ``period`` rows by the sensor's columns, one cell per
  pixel, tiling seamlessly.
- ``image``: a greyscale image file (``cv2.imread``, any depth; colour is converted to grey),
  one image pixel per sensor pixel, tiled in both directions.

Every kind takes ``blur_px``: the optics out of focus, a Gaussian point spread function of that
standard deviation in pixels applied to the radiance (``blur_cells``), so that every acquisition
integrates the blurred scene.

Bars and edges are exact cell averages along the axis they vary on; the star is averaged over
2 x 2 points per cell. Levels are given in ``photons`` (per pixel per second at the focal
plane) or ``lux`` (focal-plane illuminance, converted at the 555 nm equivalent by
``lux_to_photons_per_pixel_s``); ``contrast`` maps a target's pattern ``p`` in [0, 1] to
``level * (lo + (1 - lo) p)`` with ``lo = (1 - contrast) / (1 + contrast)`` (Michelson contrast).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from firmware_models.image_errors import ImageMotionErrors, rotate_cells
from firmware_models.render_kernels import weighted_rows
from firmware_models.scene_spec import (
    BAR_FREQUENCIES_CY_PER_PX,
    SceneSpec,
    SceneSpecError,
    lux_to_photons_per_pixel_s,
)
from firmware_models.scene_spec import (
    PLANCK_J_S as PLANCK_J_S,
)
from firmware_models.scene_spec import (
    SCENE_KINDS as SCENE_KINDS,
)
from firmware_models.scene_spec import (
    SPEED_OF_LIGHT_M_S as SPEED_OF_LIGHT_M_S,
)
from firmware_models.scene_spec import (
    SceneKind as SceneKind,
)

Array = npt.NDArray[Any]
FloatArray = npt.NDArray[np.floating[Any]]

_STATIC_CELLS = 1e-7  # below this motion (in cells) the exposure is treated as static
_SUPERSAMPLE = 2  # analytic targets: sub-samples per cell and axis, averaged into the cell


class Scene:
    """A radiance map on cells (photons per pixel per second), periodic in both directions.

    ``radiance`` has shape ``(period_rows * oversample, width_cols * x_oversample)``.
    """

    def __init__(
        self,
        radiance: npt.ArrayLike,
        *,
        oversample: int = 1,
        x_oversample: int | None = None,
        drift_deg: float = 0.0,
        spec: SceneSpec | None = None,
    ) -> None:
        cells = np.asarray(radiance, dtype=np.float64)
        if cells.ndim != 2 or cells.size == 0:
            raise ValueError(f"radiance must be a non-empty 2-D array, got shape {cells.shape}")
        if not np.all(np.isfinite(cells)) or cells.min() < 0.0:
            raise ValueError("radiance must be finite and >= 0 (photons per pixel per second)")
        x_over = oversample if x_oversample is None else x_oversample
        if oversample < 1 or x_over < 1:
            raise ValueError("oversample must be >= 1")
        if cells.shape[1] % x_over:
            raise ValueError(
                f"radiance has {cells.shape[1]} cells across, not a multiple of x_oversample "
                f"{x_over}"
            )
        if abs(drift_deg) > 45.0:
            raise ValueError(f"drift_deg must be within +-45 deg, got {drift_deg}")
        self.radiance = cells
        self.oversample = oversample
        self.x_oversample = x_over
        self.drift_deg = float(drift_deg)
        self.spec = spec
        self._tables: dict[tuple[float, str], Array] = {}
        self._tiled_key: tuple[int, int, int] | None = None
        self._tiled_table: Array | None = None

    @classmethod
    def from_pattern(
        cls,
        pattern: npt.ArrayLike,
        photons: float,
        *,
        contrast: float = 1.0,
        oversample: int = 1,
        drift_deg: float = 0.0,
    ) -> Scene:
        """A scene from a pattern in [0, 1] (cells), scaled to ``photons`` with ``contrast``."""
        return cls(
            scale_pattern(np.asarray(pattern, dtype=np.float64), photons, contrast),
            oversample=oversample,
            drift_deg=drift_deg,
        )

    @property
    def period_rows(self) -> float:
        """Along-track period of the tiling, rows."""
        return int(self.radiance.shape[0]) / self.oversample

    @property
    def width_cols(self) -> int:
        """Across-track period of the tiling, columns."""
        return int(self.radiance.shape[1]) // self.x_oversample

    @property
    def peak_photons(self) -> float:
        return float(self.radiance.max())

    def describe(self) -> str:
        if self.spec is not None:
            return self.spec.describe()
        rows, cols = self.radiance.shape
        return f"array {rows} x {cols} cells, oversample {self.oversample}"

    @property
    def motion_errors(self) -> ImageMotionErrors:
        """The image motion errors the spec sets (none for a scene made from an array)."""
        spec = self.spec
        if spec is None:
            return ImageMotionErrors()
        return ImageMotionErrors(spec.magnification_error, spec.rotation_deg, spec.yaw_deg_per_m)

    def lateral_cols(self, d_rows: FloatArray) -> FloatArray:
        """Across-track image shift for an along-track displacement: ``d tan(beta)``."""
        result: FloatArray = np.asarray(d_rows, dtype=np.float64) * math.tan(
            math.radians(self.drift_deg)
        )
        return result

    def table(self, aperture: float, dtype: npt.DTypeLike = np.float32) -> Array:
        """The radiance integrated over the aperture across track: ``(cells along, columns)``.

        Column ``j`` holds ``integral of L(x) over [j + (1 - q)/2, j + (1 + q)/2]`` for each
        cell along track, exactly for the piecewise-constant cells (photons per second per row
        of length along track). Cached per aperture and dtype.
        """
        key = (round(float(aperture), 12), np.dtype(dtype).str)
        cached = self._tables.get(key)
        if cached is not None:
            return cached
        if not 0.0 < aperture <= 1.0:
            raise ValueError(f"aperture must be in (0, 1] pitches, got {aperture}")
        over = self.x_oversample
        cells = self.radiance
        n_cells = cells.shape[1]
        cumulative = np.zeros((cells.shape[0], n_cells + 1))
        np.cumsum(cells, axis=1, out=cumulative[:, 1:])
        centres = np.arange(self.width_cols, dtype=np.float64) + 0.5

        def integral_to(x_cols: FloatArray) -> FloatArray:
            s = x_cols * over
            whole = np.minimum(np.floor(s).astype(np.int64), n_cells - 1)
            part = s - whole
            value: FloatArray = (cumulative[:, whole] + cells[:, whole] * part) / over
            return value

        table = integral_to(centres + aperture / 2) - integral_to(centres - aperture / 2)
        result = np.ascontiguousarray(table, dtype=dtype)
        self._tables[key] = result
        return result

    def _tiled(self, table: Array, first_col: int, cols: int) -> Array:
        """Columns ``first_col .. first_col + cols - 1`` of a table, tiled (cached: per frame
        the camera asks for the same window)."""
        key = (id(table), first_col, cols)
        if self._tiled_key != key or self._tiled_table is None:
            index = (first_col + np.arange(cols)) % table.shape[1]
            # take along axis 1, not table[:, index]: that result is not C-contiguous, and
            # gathering whole rows from it later would be slow.
            self._tiled_table = np.take(table, index, axis=1)
            self._tiled_key = key
        return self._tiled_table

    def integrate(
        self,
        first_row: int,
        rows: int,
        cols: int,
        d_start: npt.ArrayLike,
        d_end: npt.ArrayLike,
        lateral_cols: npt.ArrayLike | None,
        exposure_s: float,
        aperture: float,
        *,
        first_col: int = 0,
        dtype: npt.DTypeLike = np.float32,
    ) -> Array:
        """Expected photons collected by each pixel of a window during its exposure.

        Sensor rows ``first_row .. first_row + rows - 1`` (array indices) and columns
        ``first_col .. first_col + cols - 1``; row ``i``'s image displacement moves linearly
        from ``d_start[i]`` to ``d_end[i]`` rows during ``exposure_s``; ``lateral_cols[i]`` is
        its across-track shift at mid-exposure (None: from the scene's drift angle, ``tan(beta)``
        times the mid-exposure displacement). ``aperture`` is the side ``q`` of the pixel's
        photosensitive square in pitches (``sqrt(fill_factor)``). Returns ``(rows, cols)`` in
        ``dtype`` (float32 by default; float64 for precision tests).
        """
        if rows < 1 or cols < 1:
            raise ValueError(f"need rows >= 1 and cols >= 1, got {rows} x {cols}")
        sensor_rows = first_row + np.arange(rows, dtype=np.float64)
        along = self.integrate_rows(
            sensor_rows, cols, d_start, d_end, lateral_cols, exposure_s, aperture,
            first_col=first_col, dtype=dtype,
        )  # fmt: skip
        if along.shape[1] == cols:
            return along
        out = np.empty((rows, cols), dtype=dtype)
        out[...] = along  # a scene one column wide: the same value across the window
        return out

    def integrate_rows(
        self,
        sensor_rows: npt.ArrayLike,
        cols: int,
        d_start: npt.ArrayLike,
        d_end: npt.ArrayLike,
        lateral_cols: npt.ArrayLike | None,
        exposure_s: float,
        aperture: float,
        *,
        first_col: int = 0,
        dtype: npt.DTypeLike = np.float32,
    ) -> Array:
        """``integrate`` for any list of sensor rows (array indices, e.g. the window's rows
        of several frames one after the other, each with its own motion), in one pass.

        Returns ``(len(sensor_rows), cols)``, or ``(len(sensor_rows), 1)`` for a scene one
        column wide without drift (the same value across each row: the caller broadcasts).
        """
        row_index = np.asarray(sensor_rows, dtype=np.float64).reshape(-1)
        rows = row_index.size
        if rows < 1 or cols < 1:
            raise ValueError(f"need rows >= 1 and cols >= 1, got {rows} x {cols}")
        if exposure_s < 0.0:
            raise ValueError(f"exposure_s must be >= 0, got {exposure_s}")
        d0 = _per_row(d_start, rows)
        d1 = _per_row(d_end, rows)
        over = self.oversample
        # Aperture's lower edge in cells, at exposure start and end (row r spans [r, r + 1)).
        lower = (row_index + (1.0 - aperture) / 2.0) * over
        origin, weights = motion_weights(lower + d0 * over, lower + d1 * over, aperture * over)
        weights *= exposure_s / over  # cells x s -> rows x s
        n_cells = self.radiance.shape[0]
        cell_index = (origin[:, None] + np.arange(weights.shape[1])) % n_cells

        if lateral_cols is None:
            lateral = self.lateral_cols((d0 + d1) / 2.0) if self.drift_deg else None
        else:
            lateral = np.broadcast_to(np.asarray(lateral_cols, dtype=np.float64), (rows,))
        if lateral is not None and not np.any(lateral):
            lateral = None

        table = self.table(aperture, dtype)
        width = table.shape[1]
        if lateral is None and width > 1:
            if first_col + cols <= width:
                table = table[:, first_col : first_col + cols]
            else:
                table = self._tiled(table, first_col, cols)
        along = _weighted_rows(table, cell_index, weights.astype(dtype))  # (rows, table cols)

        if lateral is not None and width > 1:
            return _shift_columns(along, lateral, first_col, cols)
        return along


def _per_row(values: npt.ArrayLike, rows: int) -> FloatArray:
    """One float64 value per row (a scalar repeated; an array of one per row as it is)."""
    array = np.asarray(values, dtype=np.float64)
    if array.shape == (rows,):
        return array
    result: FloatArray = np.broadcast_to(array, (rows,))
    return result


def motion_weights(
    lower_start: FloatArray, lower_end: FloatArray, width: float
) -> tuple[npt.NDArray[np.int64], FloatArray]:
    """Exact time-integrated overlap of a moving box with unit cells, per row.

    A box of ``width`` (cells) whose lower edge moves linearly from ``lower_start[i]`` to
    ``lower_end[i]`` (cell coordinates) over a unit time overlaps cell ``origin[i] + k`` for a
    time-averaged length ``weights[i, k]`` (cells):

        w_k = [R(u4 - k) - R(u3 - k) - R(u2 - k) + R(u1 - k)] / (u2 - u1)

    with ``u1, u2`` the lower edge at start and end, ``u3, u4`` the upper edge, all relative to
    ``origin = floor(min(u1, u2))``, and ``R`` the double integral of one cell's indicator
    (``0``, ``z^2 / 2``, ``z - 1/2``): the cumulative-integral formula of the module docstring
    applied to one cell. Without motion (``|u2 - u1|`` below 1e-7 cells) it is the static
    overlap at mid-exposure. The weights of a row sum to ``width``.
    """
    u1 = np.asarray(lower_start, dtype=np.float64)
    u2 = np.asarray(lower_end, dtype=np.float64)
    origin = np.floor(np.minimum(u1, u2)).astype(np.int64)
    u1 = u1 - origin
    u2 = u2 - origin
    top = np.maximum(u1, u2) + width
    span = int(np.ceil(top.max())) if top.size else 1
    k = np.arange(max(span, 1), dtype=np.float64)[None, :]
    motion = u2 - u1
    moving = np.abs(motion) >= _STATIC_CELLS
    weights = np.empty((u1.size, k.shape[1]))
    if np.any(moving):
        a1, a2 = u1[moving, None], u2[moving, None]
        dm = motion[moving, None]
        weights[moving] = (
            _double_integral(a2 + width - k)
            - _double_integral(a1 + width - k)
            - _double_integral(a2 - k)
            + _double_integral(a1 - k)
        ) / dm
    if not np.all(moving):
        mid = ((u1 + u2) / 2.0)[~moving, None]
        weights[~moving] = np.clip(mid + width - k, 0.0, 1.0) - np.clip(mid - k, 0.0, 1.0)
    return origin, weights


def _double_integral(z: FloatArray) -> FloatArray:
    """``R(z)``: the integral from -inf to z of the integral of the unit cell [0, 1]'s indicator."""
    result: FloatArray = np.where(z <= 0.0, 0.0, np.where(z < 1.0, 0.5 * z * z, z - 0.5))
    return result


def _weighted_rows(table: Array, cell_index: npt.NDArray[np.int64], weights: Array) -> Array:
    """``out[i] = sum_k weights[i, k] * table[cell_index[i, k]]`` (indices within the table)."""
    rows, span = weights.shape
    n_cells = table.shape[0]
    if n_cells <= 8 * span:
        # Few distinct cells (flat fields, short periods, long blur): one small matrix product.
        dense = np.zeros((rows, n_cells), dtype=weights.dtype)
        np.add.at(dense, (np.arange(rows)[:, None], cell_index), weights)
        product: Array = dense @ table
        return product
    # Many cells: each row gathers its few, in one compiled pass (render_kernels).
    return weighted_rows(table, cell_index, weights)


def _shift_columns(along: Array, lateral: FloatArray, first_col: int, cols: int) -> Array:
    """Column ``x`` of row ``i`` takes scene column ``first_col + x + lateral[i]`` (periodic),
    by linear interpolation between the two neighbouring columns."""
    width = along.shape[1]
    whole = np.floor(lateral).astype(np.int64)
    frac = (lateral - whole).astype(along.dtype)[:, None]
    index = (first_col + np.arange(cols)[None, :] + whole[:, None]) % width
    left = np.take_along_axis(along, index, axis=1)
    right = np.take_along_axis(along, (index + 1) % width, axis=1)
    left *= 1 - frac
    right *= frac
    left += right
    return left


# -- building scenes from a spec --------------------------------------------------------------------


def scale_pattern(pattern: FloatArray, photons: float, contrast: float = 1.0) -> FloatArray:
    """``photons * (lo + (1 - lo) p)`` with ``lo = (1 - c) / (1 + c)``: contrast ``c`` between
    the bright level ``photons`` and the dark level ``photons * lo`` (Michelson)."""
    if not 0.0 <= contrast <= 1.0:
        raise ValueError(f"contrast must be in [0, 1], got {contrast}")
    low = (1.0 - contrast) / (1.0 + contrast)
    clipped = np.clip(pattern, 0.0, 1.0)
    scaled: FloatArray = photons * (low + (1.0 - low) * clipped)
    return scaled


def build_scene(
    spec: SceneSpec,
    *,
    columns: int,
    pitch_m: float,
    default_photons: float,
) -> Scene:
    """The Scene a spec describes, for a sensor ``columns`` wide with pixel pitch ``pitch_m``.

    The level is ``photons``, ``lux`` converted with ``lux_to_photons_per_pixel_s``, or
    ``default_photons``. A ``rotation_deg`` turns the cells in the focal plane
    (``rotate_cells``). A ``blur_px`` above 0 blurs the radiance (``blur_cells``): the optics
    out of focus, seen alike by every acquisition (area, TDI) since all integrate this scene.
    """
    scene = _sharp_scene(spec, columns=columns, pitch_m=pitch_m, default_photons=default_photons)
    cells: Array = scene.radiance
    if spec.rotation_deg and cells.size > 1:
        # The camera turned on its mount sees the scene turned (a flat field looks the same).
        cells = rotate_cells(
            cells,
            spec.rotation_deg,
            oversample=scene.oversample,
            x_oversample=scene.x_oversample,
            columns=columns,
        )
    if spec.blur_px > 0.0:
        cells = blur_cells(
            cells, spec.blur_px, oversample=scene.oversample, x_oversample=scene.x_oversample
        )
    if cells is scene.radiance:
        return scene
    return Scene(
        cells,
        oversample=scene.oversample,
        x_oversample=scene.x_oversample,
        drift_deg=scene.drift_deg,
        spec=spec,
    )


def blur_cells(
    cells: FloatArray, blur_px: float, *, oversample: int, x_oversample: int
) -> FloatArray:
    """The radiance ``cells`` convolved with a Gaussian point spread function of standard
    deviation ``blur_px`` pixels (``blur_px * oversample`` cells along track, ``blur_px *
    x_oversample`` across), periodically as the scene tiles.

    Done in the Fourier domain of the scene's own period (the Gaussian's transfer function
    ``exp(-2 pi^2 sigma^2 f^2)`` per axis), so the light is kept exactly and the tiling stays
    seamless. The cells are treated as samples, which is exact for the light and its spread;
    a scene of one cell across (flat, ramp) is unchanged across. Tiny negative values of the
    transform's rounding are clipped to 0.
    """
    result = np.asarray(cells, dtype=np.float64)
    for axis, per_px in ((0, oversample), (1, x_oversample)):
        n = result.shape[axis]
        if n < 2:
            continue
        sigma_cells = blur_px * per_px
        f = np.fft.rfftfreq(n)
        transfer = np.exp(-2.0 * math.pi**2 * sigma_cells**2 * f**2)
        shape = [1, 1]
        shape[axis] = transfer.size
        spectrum = np.fft.rfft(result, axis=axis) * transfer.reshape(shape)
        result = np.fft.irfft(spectrum, n=n, axis=axis)
    clipped: FloatArray = np.maximum(result, 0.0)
    return clipped


def _sharp_scene(
    spec: SceneSpec,
    *,
    columns: int,
    pitch_m: float,
    default_photons: float,
) -> Scene:
    """``build_scene`` before the blur: the target at best focus."""
    if spec.photons is not None:
        level = spec.photons
    elif spec.lux is not None:
        level = lux_to_photons_per_pixel_s(spec.lux, pitch_m)
    else:
        level = default_photons
    if spec.kind == "flat":
        return Scene(np.full((1, 1), level), drift_deg=spec.drift_deg, spec=spec)
    if spec.kind in ("image", "natural"):
        if spec.kind == "natural":
            pattern = natural_texture(spec.period_rows, columns, seed=spec.seed)
        else:
            assert spec.path is not None  # the spec's validator requires it
            pattern = read_grey_image(spec.path)
        return Scene(
            scale_pattern(pattern, level, spec.contrast), drift_deg=spec.drift_deg, spec=spec
        )
    over = spec.oversample
    period = spec.period_rows
    if spec.kind == "ramp":
        y = (np.arange(period * over) + 0.5) / over
        pattern = (y / period)[:, None]
        return Scene(
            scale_pattern(pattern, level, spec.contrast),
            oversample=over,
            x_oversample=1,
            drift_deg=spec.drift_deg,
            spec=spec,
        )
    width = spec.size if spec.kind == "star" else columns
    x_over = over if spec.x_oversample is None else spec.x_oversample
    pattern = _target(spec, period, width, over, x_over)
    if spec.kind == "edge" and spec.texture_cols:
        pattern = _with_texture(pattern, spec, period, width, over, x_over)
    return Scene(
        scale_pattern(pattern, level, spec.contrast),
        oversample=over,
        x_oversample=x_over,
        drift_deg=spec.drift_deg,
        spec=spec,
    )


def _target(
    spec: SceneSpec, period: int, width: int, over: int, x_over: int | None = None
) -> FloatArray:
    """The target's pattern as cell averages in [0, 1], shape ``(period * over, width * x_over)``
    (``x_over`` cells per pixel across, default ``over``).

    Bars and edges are exact cell averages along the axis their bars vary on (a closed-form
    measure of the bright part of each cell) and take the value at the cell centre along the
    other; the star is averaged over ``_SUPERSAMPLE`` ^ 2 points per cell.
    """
    y_edges = np.arange(period * over + 1) / over
    x_over = over if x_over is None else x_over
    x_edges = np.arange(width * x_over + 1) / x_over
    y_mid = (y_edges[:-1] + y_edges[1:]) / 2
    x_mid = (x_edges[:-1] + x_edges[1:]) / 2
    freqs = np.asarray(BAR_FREQUENCIES_CY_PER_PX)
    groups = len(freqs)
    if spec.kind == "bars" and spec.orientation == "along":
        # Groups side by side across the columns; bars vary along track.
        group = np.minimum((x_mid * groups / width).astype(np.int64), groups - 1)
        per_group = _bright_fraction(y_edges[:-1, None], y_edges[1:, None], 1.0 / freqs[None, :])
        result: FloatArray = per_group[:, group]
        return result
    if spec.kind == "bars":
        # Groups in bands along track; bars vary across track.
        group = np.minimum((y_mid * groups / period).astype(np.int64), groups - 1)
        per_group = _bright_fraction(x_edges[None, :-1], x_edges[None, 1:], 1.0 / freqs[:, None])
        result = per_group[group, :]
        return result
    if spec.kind == "edge":
        shift = x_mid[None, :] * math.tan(math.radians(spec.angle_deg))
        result = _bright_fraction(y_edges[:-1, None] - shift, y_edges[1:, None] - shift, period)
        return result
    fine = over * _SUPERSAMPLE
    y = (np.arange(period * fine) + 0.5) / fine
    x = (np.arange(width * fine) + 0.5) / fine
    blocks = _star(spec, y[:, None], x[None, :]).reshape(
        period * over, _SUPERSAMPLE, width * over, _SUPERSAMPLE
    )
    result = blocks.mean(axis=(1, 3))
    return result


def _with_texture(
    pattern: FloatArray, spec: SceneSpec, period: int, width: int, over: int, x_over: int
) -> FloatArray:
    """``pattern`` (an edge target's cells) with its central ``spec.texture_cols`` columns
    replaced by the natural texture of one period (``natural_texture``, one value per pixel,
    each spread over its cells): the image motion monitor measures the central columns, and a
    straight edge only shows the motion across it (the aperture problem), so a scan can keep
    edges for the MTF either side and a texture for the motion in the middle."""
    cols = min(spec.texture_cols, width)
    first = (width - cols) // 2
    texture = natural_texture(period, cols, seed=spec.seed)
    cells = np.repeat(np.repeat(texture, over, axis=0), x_over, axis=1)
    result = pattern.copy()
    result[:, first * x_over : (first + cols) * x_over] = cells
    return result


def _bright_fraction(lo: FloatArray, hi: FloatArray, period: FloatArray | float) -> FloatArray:
    """Fraction of ``[lo, hi]`` in the bright half ``[0, period / 2) mod period`` (exact)."""

    def bright_up_to(u: FloatArray) -> FloatArray:
        # The remainder from the same floor (np.mod may disagree with it by one period).
        whole = np.floor(u / period)
        rest = np.clip(u - whole * period, 0.0, period / 2)
        value: FloatArray = whole * (period / 2) + rest
        return value

    result: FloatArray = (bright_up_to(hi) - bright_up_to(lo)) / (hi - lo)
    return result


def _star(spec: SceneSpec, y: FloatArray, x: FloatArray) -> FloatArray:
    """Siemens star of ``spokes`` bright/dark pairs in a tile; mid grey outside its circle."""
    half = spec.size / 2
    dy, dx = y - half, x - half
    radius = np.hypot(dx, dy)
    spokes = (np.sin(spec.spokes * np.arctan2(dy, dx)) >= 0).astype(np.float64)
    result: FloatArray = np.where(radius <= 0.95 * half, spokes, 0.5)
    return result


NATURAL_SPECTRUM_EXPONENT = 1.0
"""Amplitude spectrum of the ``natural`` texture, ``|F(f)| ~ 1 / f^1``: the average spectrum of
natural images (Field 1987, JOSA A 4:2379; van der Schaaf and van Hateren 1996)."""


def natural_texture(rows: int, cols: int, *, seed: int) -> FloatArray:
    """A synthetic natural-image texture in [0, 1], ``rows x cols``, periodic in both axes.

    Gaussian noise shaped to the ``1 / f`` amplitude spectrum of natural images (so it has
    structure at every scale, like a landscape: what TAO12 §5.1's natural scene needs), the
    mean removed, then mapped linearly so the 0.1 and 99.9 percentiles span [0, 1] (clipped).
    The same seed gives the same texture; it tiles seamlessly because it is built in the
    Fourier domain of its own period.
    """
    rng = np.random.default_rng(seed)
    noise = np.fft.rfft2(rng.standard_normal((rows, cols)))
    fy = np.fft.fftfreq(rows)[:, None]
    fx = np.fft.rfftfreq(cols)[None, :]
    radius = np.hypot(fy, fx)
    radius[0, 0] = np.inf  # no DC term: the level is set by the scene's photons
    field = np.fft.irfft2(noise / radius**NATURAL_SPECTRUM_EXPONENT, s=(rows, cols))
    lo, hi = np.percentile(field, [0.1, 99.9])
    texture: FloatArray = np.clip((field - lo) / (hi - lo), 0.0, 1.0)
    return texture


def read_grey_image(path: str | Path) -> FloatArray:
    """An image file as grey levels in [0, 1] (cv2.imread, any depth, colour -> grey)."""
    import cv2  # deferred: only image scenes need OpenCV

    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise SceneSpecError(f"cannot read image {str(path)!r}; give a PNG, TIFF, JPEG... file")
    if image.ndim == 3:
        code = cv2.COLOR_BGRA2GRAY if image.shape[2] == 4 else cv2.COLOR_BGR2GRAY
        image = cv2.cvtColor(image, code)
    if np.issubdtype(image.dtype, np.integer):
        grey = image.astype(np.float64) / float(np.iinfo(image.dtype.name).max)
    else:
        grey = np.clip(image.astype(np.float64), 0.0, 1.0)
    result: FloatArray = grey
    return result
