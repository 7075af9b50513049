"""The simulated camera's per-pixel work, each as one compiled pass with a numpy reference.

Two steps of a frame touch every pixel (``firmware_models.camera``):

- ``weighted_rows``: a scene row as the weighted sum of the few cells of the scene's
  aperture-integrated table that the moving pixel aperture crossed
  (``firmware_models.scene``);
- ``read_out``: electrons from photons (quantum efficiency and PRNU, a filter's transmission per
  row, dark charge with DSNU), one Gaussian of the shot and read noise per pixel (from
  ``firmware_models.noise_bank``), full-well clipping, the ADC (gain, black level, rounding,
  clipping to its range) and the output's most significant bits.

In numpy each is a dozen passes over float32 arrays; compiled (numba, ``render_numba``) each is
one, run without the interpreter lock, so the simulator's command thread is not held up by a
render. Both do the same float32 operations in the same order, so they give the same frames
bit for bit (tests/test_sim_render.py); the numpy one is used where numba is not installed.
The compiled kernels load on first use (about 0.3 s to import numba, then from the on-disk
cache; a first compile takes a few seconds).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

Array = npt.NDArray[Any]
F32 = npt.NDArray[np.float32]

_COMPILED: dict[str, Any] = {}  # "kernels": the render_numba module, or None without numba


def compiled() -> Any:
    """``firmware_models.render_numba`` (imported on first use), or None without numba."""
    if "kernels" not in _COMPILED:
        try:
            from firmware_models import render_numba
        except ImportError:  # pragma: no cover - numba is a dependency; a stripped install
            _COMPILED["kernels"] = None
        else:
            _COMPILED["kernels"] = render_numba
    return _COMPILED["kernels"]


def warm_up() -> None:
    """Load the compiled kernels (numba's import, then each kernel from the on-disk cache) for
    the argument layouts a render passes: a window's maps are contiguous rows when it spans
    every column, strided views when not. About a second of one core; a simulator does it on a
    thread of its own when it starts, so that its first stream does not wait (docs/simulator.md,
    ``CAMD_SIM_WARM_UP``). Draws nothing from any random stream."""
    kernels = compiled()
    if kernels is None:  # pragma: no cover - numba is a dependency
        return
    wide = np.ones((2, 4), dtype=np.float32)
    for maps in (wide, wide[:, :2]):  # all columns (contiguous), a part of them (strided)
        rows, cols = maps.shape
        weighted_rows(maps, np.zeros((rows, 2), dtype=np.int64), np.ones((rows, 2), np.float32))
        for width in (1, cols):
            read_out(
                np.ones((rows, width), dtype=np.float32),
                maps,
                maps,
                np.ones(rows, dtype=np.float32),
                1.0,
                (np.zeros(rows * cols, dtype=np.float32), np.zeros(1, dtype=np.int64)),
                Readout(1.0, 100.0, 1.0, 0.0, 4095, 0),
            )


@dataclass(frozen=True, slots=True)
class Readout:
    """What the sensor and the ADC do to a pixel's charge (the registers' values worked out):
    read noise variance (e-^2), full well (e-), system gain (DN/e-), black level (DN), the
    ADC's largest code and the bits dropped from the output."""

    read_variance_e2: float
    full_well_e: float
    gain_dn_per_e: float
    black_dn: float
    adc_max_dn: int
    shift_bits: int


def weighted_rows(
    table: Array,
    cell_index: npt.NDArray[np.int64],
    weights: Array,
    *,
    use_compiled: bool = True,
) -> Array:
    """``out[i] = sum_k weights[i, k] * table[cell_index[i, k]]`` (``cell_index`` within the
    table), the terms added in order of k, in the table's dtype."""
    rows = weights.shape[0]
    kernels = compiled() if use_compiled else None
    if kernels is not None:
        out = np.empty((rows, table.shape[1]), dtype=table.dtype)
        kernels.weighted_rows(table, cell_index, weights.astype(table.dtype, copy=False), out)
        return out
    span = weights.shape[1]
    out = np.take(table, cell_index[:, 0], axis=0)
    out *= weights[:, :1]
    term = np.empty_like(out)
    for k in range(1, span):
        np.take(table, cell_index[:, k], axis=0, out=term)
        term *= weights[:, k : k + 1]
        out += term
    return out


def read_out(
    photons: F32,
    response: F32,
    dark_rate: F32,
    row_factor: F32,
    dark_scale: float,
    noise: tuple[F32, npt.NDArray[np.int64]],
    readout: Readout,
    *,
    use_compiled: bool = True,
) -> tuple[npt.NDArray[np.uint16], npt.NDArray[np.int64]]:
    """Output frames of a block of frames, and each frame's largest code.

    ``photons``: (frames x rows, 1 or cols) photons per pixel (one column: the same across the
    row); ``response`` and ``dark_rate``: (rows, cols) QE x (1 + PRNU) and dark current (e-/s)
    of the window's pixels; ``row_factor``: (frames x rows) light transmitted per row;
    ``dark_scale``: dark-current factor x exposure (s); ``noise``: (values, starts), frame f's
    standard normals ``values[starts[f]:][: rows * cols]`` (``NoiseBank.take``).

    Per pixel, in float32: ``e = photons x response x row_factor + dark_rate x dark_scale``,
    ``e += sqrt(e + read^2) z`` (one Gaussian of mean S + D and variance S + D + read^2),
    ``e = min(e, full well)``, ``DN = rint(e K + B)`` clipped to ``[0, adc_max]``, then
    ``>> shift``. Returns ``(frames x rows, cols)`` uint16 and ``(frames,)`` maxima.
    """
    rows, cols = response.shape
    frames = photons.shape[0] // rows
    values, starts = noise
    kernels = compiled() if use_compiled else None
    out = np.empty((frames * rows, cols), dtype=np.uint16)
    if kernels is not None:
        frame_max = np.zeros(frames, dtype=np.int64)
        kernels.read_out(
            photons,
            response,
            dark_rate,
            row_factor,
            np.float32(dark_scale),
            values,
            starts,
            np.float32(readout.read_variance_e2),
            np.float32(readout.full_well_e),
            np.float32(readout.gain_dn_per_e),
            np.float32(readout.black_dn),
            np.float32(readout.adc_max_dn),
            readout.shift_bits,
            out,
            frame_max,
        )
        return out, frame_max
    frame_max = np.empty(frames, dtype=np.int64)
    dark = dark_rate * np.asarray(dark_scale, dtype=np.float32)
    for f in range(frames):
        part = slice(f * rows, (f + 1) * rows)
        electrons = np.empty((rows, cols), dtype=np.float32)
        electrons[...] = photons[part]
        electrons *= response
        electrons *= row_factor[part, np.newaxis]
        electrons += dark
        sigma = electrons + np.float32(readout.read_variance_e2)
        np.sqrt(sigma, out=sigma)
        start = int(starts[f])
        sigma *= values[start : start + rows * cols].reshape(rows, cols)
        electrons += sigma
        np.minimum(electrons, np.float32(readout.full_well_e), out=electrons)
        electrons *= np.float32(readout.gain_dn_per_e)
        electrons += np.float32(readout.black_dn)
        np.rint(electrons, out=electrons)
        np.clip(electrons, 0.0, float(readout.adc_max_dn), out=electrons)
        frame = electrons.astype(np.uint16)
        if readout.shift_bits:
            frame >>= readout.shift_bits
        out[part] = frame
        frame_max[f] = int(frame.max())
    return out, frame_max
