"""The simulated sensor's fixed pattern: each pixel's response (QE x (1 + PRNU)) and dark current.

Drawn once from the camera's seed, as the sensor's own pixels would be: ``response`` is
``QE (1 + PRNU n1)`` (clipped at 0) and ``dark`` is ``I_dark + DSNU n2`` in e-/s at the
profile's reference temperature (clipped at 0), ``n1``, ``n2`` standard normal per pixel. An
array of more than 8 Mpixel (the ftf5066's 33 Mpixel) draws its maps per band of 256 rows when a
window first reads one, each band from its own seeded stream, so a window reads the same
pattern whichever band it crosses first.
"""

from __future__ import annotations

import threading
from typing import Any

import numpy as np
import numpy.typing as npt

from camd.sensor.profile import CameraProfile

Array = npt.NDArray[Any]

_FIXED_PATTERN_STREAM = 0x4650  # "FP": PRNU and DSNU maps
_BANDED_MAP_PIXELS = 1 << 23  # larger arrays draw their fixed pattern per band of rows
_MAP_BAND_ROWS = 256


class FixedPattern:
    """The response and dark-current maps of ``profile``'s array, drawn from ``seed``."""

    def __init__(self, profile: CameraProfile, seed: int) -> None:
        self.profile = profile
        self.seed = seed
        # Drawn on first use: a 2048 x 2048 array takes ~0.1 s, and not every model renders.
        self._maps: tuple[Array, Array] | None = None
        # Bands of a large array's maps, drawn when a window first reads them.
        self.bands: dict[int, tuple[Array, Array]] = {}
        # A warm-up thread may draw them while a stream's first frame wants them: once.
        self._draw_lock = threading.Lock()

    @property
    def banded(self) -> bool:
        """The array is drawn per band of rows (more than 8 Mpixel)."""
        p = self.profile
        return p.rows.value * p.columns.value > _BANDED_MAP_PIXELS

    def rows(self, row0: int, rows: int) -> tuple[Array, Array]:
        """(response, dark current) of array rows ``row0 .. row0 + rows - 1``, all columns."""
        if not self.banded:
            response, dark = self._whole()
            return response[row0 : row0 + rows], dark[row0 : row0 + rows]
        first, last = row0 // _MAP_BAND_ROWS, (row0 + rows - 1) // _MAP_BAND_ROWS
        parts = [self._band(b) for b in range(first, last + 1)]
        offset = row0 - first * _MAP_BAND_ROWS
        if len(parts) == 1:
            response, dark = parts[0]
        else:
            response = np.concatenate([r for r, _ in parts])
            dark = np.concatenate([d for _, d in parts])
        return response[offset : offset + rows], dark[offset : offset + rows]

    def _band(self, band: int) -> tuple[Array, Array]:
        """Band ``band`` (rows ``band * 256 ..``) of a large array's maps, from its own stream."""
        cached = self.bands.get(band)
        if cached is None:
            with self._draw_lock:
                cached = self.bands.get(band)
                if cached is None:
                    p = self.profile
                    rows = min(_MAP_BAND_ROWS, p.rows.value - band * _MAP_BAND_ROWS)
                    rng = np.random.default_rng([self.seed, _FIXED_PATTERN_STREAM, band])
                    cached = self._draw(rng, (rows, p.columns.value))
                    self.bands[band] = cached
        return cached

    def _whole(self) -> tuple[Array, Array]:
        """Both maps of the whole array."""
        maps = self._maps
        if maps is None:
            with self._draw_lock:
                maps = self._maps
                if maps is None:
                    p = self.profile
                    rng = np.random.default_rng([self.seed, _FIXED_PATTERN_STREAM])
                    maps = self._draw(rng, (p.rows.value, p.columns.value))
                    self._maps = maps
        return maps

    def _draw(self, rng: np.random.Generator, shape: tuple[int, int]) -> tuple[Array, Array]:
        """QE * (1 + PRNU) and the dark-current map of ``shape`` pixels from ``rng``."""
        p = self.profile
        response = rng.standard_normal(shape, dtype=np.float32)
        response *= np.float32(p.prnu_fraction.value)
        response += np.float32(1.0)
        response *= np.float32(p.quantum_efficiency.value)
        np.maximum(response, 0.0, out=response)
        dark = rng.standard_normal(shape, dtype=np.float32)
        dark *= np.float32(p.dsnu_e_per_s.value)
        dark += np.float32(p.dark_current_e_per_s.value)
        # A pixel cannot have negative dark current; with DSNU <= 20 % of the mean this clips
        # nothing in practice (5 sigma).
        np.maximum(dark, 0.0, out=dark)
        return response, dark
