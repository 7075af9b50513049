"""The simulated camera's frame production: photons, electrons, noise and readout of frames.

``FrameMaker`` renders the frames of ``firmware_models.camera.CameraModel`` (steps 1 to 7 of
its docstring) from the camera's configuration (the scene, how the stage moves the image, the
light a filter-wheel channel lets through, binning, temperature) and what the registers set
(``firmware_models.camera_settings``). It holds what makes one camera's frames its own: the
fixed-pattern maps (PRNU, DSNU; ``firmware_models.fixed_pattern``) and the temporal noise, a
pre-drawn bank (``firmware_models.noise_bank``) indexed at offsets drawn from a seeded stream.
The per-pixel work is two compiled passes (``firmware_models.render_kernels``): the scene's
along-track sum (``Scene.integrate_rows``) and the readout (``read_out``).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, Protocol

import numpy as np
import numpy.typing as npt

from camd.sensor.profile import CameraProfile
from camd.sensor.timing_view import SensorTiming
from camd.tdi.binning import bin2x2
from firmware_models.camera_imc import compensated_photons
from firmware_models.camera_settings import RegisterSettings
from firmware_models.fixed_pattern import FixedPattern
from firmware_models.noise_bank import NoiseBank
from firmware_models.render_kernels import read_out
from firmware_models.scene import Scene

Array = npt.NDArray[Any]

_TEMPORAL_STREAM = 0x544E  # "TN": per-frame noise, independent of the fixed pattern


class CameraState(Protocol):
    """What frames are made of besides the registers (``CameraModel`` has it)."""

    @property
    def profile(self) -> CameraProfile: ...

    @property
    def scene(self) -> Scene: ...

    @property
    def binning(self) -> bool: ...

    @property
    def transmission(self) -> Callable[[Array, Array], Array] | None: ...

    def image_motion(
        self, t_s: npt.ArrayLike, timing: SensorTiming | None = None
    ) -> tuple[Array, Array]:
        """Image displacement at times ``t_s``: rows along track, columns across."""
        ...

    def dark_factor(self) -> float:
        """Dark current relative to the profile's reference temperature."""
        ...


class FrameMaker:
    """The frames of ``camera`` (see the module docstring), random as ``seed`` makes them."""

    def __init__(self, camera: CameraState, seed: int) -> None:
        self.camera = camera
        self._noise = np.random.default_rng([seed, _TEMPORAL_STREAM])
        self._bank = NoiseBank(seed)  # the standard normals the per-frame offsets index
        self.fixed = FixedPattern(camera.profile, seed)  # PRNU, DSNU: drawn per band as needed

    def reseed(self, seed: int) -> None:
        """Restart the temporal noise stream (the offsets into the bank) from ``seed``."""
        fresh = np.random.default_rng([seed, _TEMPORAL_STREAM])
        self._noise.bit_generator.state = fresh.bit_generator.state

    def warm_up(self, window: tuple[int, int, int, int]) -> None:
        """Draw the fixed pattern and the noise bank's values a frame of ``window`` needs,
        without drawing from the temporal noise stream."""
        row0, rows, _, cols = window
        self.fixed.rows(row0, rows)
        if self._bank.holds(rows * cols):
            self._bank.grow_to(self._bank.span(rows * cols))

    def render_block(
        self, times_s: Sequence[float] | Array, settings: RegisterSettings
    ) -> tuple[Array, npt.NDArray[np.int64]]:
        """``CameraModel.render_block`` with the registers' ``settings``."""
        camera = self.camera
        row0, rows, col0, cols = settings.window
        times = np.asarray(times_s, dtype=np.float64).reshape(-1)
        count = times.size
        if settings.test_pattern is not None:
            frames = np.empty((count, rows, cols), dtype=np.uint16)
            frames[...] = settings.test_pattern
            maxima = np.full(count, int(settings.test_pattern.max()), dtype=np.int64)
        else:
            timing = settings.timing
            photons, start, end = self.photons(times, settings, np.float32)
            response, dark = self.fixed.rows(row0, rows)
            row_factor = np.ones((count, rows), dtype=np.float32)
            transmission = camera.transmission
            if transmission is not None:
                for f in range(count):  # one frame at a time: its channel is the wheel's then
                    row_factor[f] = transmission(start[f], end[f])
            codes, maxima = read_out(
                photons,
                response[:, col0 : col0 + cols],
                dark[:, col0 : col0 + cols],
                row_factor.reshape(-1),
                camera.dark_factor() * timing.exposure_s,
                self._bank.take(self._noise, count, rows * cols),
                settings.readout,
            )
            frames = codes.reshape(count, rows, cols)
        if camera.binning:
            frames = bin2x2(frames)
            maxima = frames.reshape(count, -1).max(axis=1).astype(np.int64)
        return frames, maxima

    def mean_electrons(self, t_s: float, settings: RegisterSettings, dtype: npt.DTypeLike) -> Array:
        """Expected electrons (signal with the fixed pattern, and dark charge) of the frame
        whose row 0 ends at ``t_s``, before full-well clipping: ``(rows, cols)``."""
        camera = self.camera
        row0, rows, col0, cols = settings.window
        photons, start, end = self.photons(np.array([float(t_s)]), settings, dtype)
        response_rows, dark_rows = self.fixed.rows(row0, rows)
        electrons = np.empty((rows, cols), dtype=dtype)
        electrons[...] = photons
        electrons *= response_rows[:, col0 : col0 + cols]
        transmission = camera.transmission
        if transmission is not None:
            factor = np.asarray(transmission(start[0], end[0]), dtype=electrons.dtype)
            electrons *= factor[:, np.newaxis]
        # Dark rate map at T_ref times the temperature factor, times the exposure.
        scale = np.asarray(camera.dark_factor() * settings.timing.exposure_s, dtype=electrons.dtype)
        electrons += dark_rows[:, col0 : col0 + cols] * scale
        return electrons

    def photons(
        self, times: Array, settings: RegisterSettings, dtype: npt.DTypeLike
    ) -> tuple[Array, Array, Array]:
        """Photons per pixel of the frames whose row 0 ends at each of ``times`` (steps 1 to 3
        of ``CameraModel``'s docstring), the rows of all frames one after the other: ``(frames
        x rows, cols)``, or ``(frames x rows, 1)`` for a scene one column wide; and each row's
        exposure start and end, ``(frames, rows)``."""
        camera = self.camera
        row0, rows, col0, cols = settings.window
        timing = settings.timing
        start, end = exposures(times, timing, rows, settings.shutter)
        mode, interval_s, phases = settings.imc
        if mode != "none" and settings.shutter != "rolling":
            photons = np.concatenate([
                compensated_photons(
                    camera.scene,
                    camera.profile.aperture,
                    camera.image_motion,
                    float(first),
                    (mode, interval_s, phases),
                    settings,
                    dtype,
                )
                for first in start[:, 0]
            ])  # fmt: skip
            return photons, start, end
        n = start.size
        # Both ends of every row in one stage call: a stepper's position may be costly.
        moved, across = camera.image_motion(
            np.concatenate([start.reshape(-1), end.reshape(-1)]), timing
        )
        sensor_rows = np.tile(row0 + np.arange(rows, dtype=np.float64), times.size)
        photons = camera.scene.integrate_rows(
            sensor_rows,
            cols,
            moved[:n],
            moved[n:],
            lateral_at_mid_exposure(camera.scene, moved, across),
            timing.exposure_s,
            camera.profile.aperture,
            first_col=col0,
            dtype=dtype,
        )
        return photons, start, end


def lateral_at_mid_exposure(scene: Scene, moved: Array, across: Array) -> Array | None:
    """Each row's across-track shift at mid-exposure (columns) from the image's displacement
    at the exposures' starts then ends (``moved`` along, ``across`` across, both halves one
    after the other): the image motion errors' own across-track motion plus the scene's drift
    (``d tan(beta)``). None when the image does not turn (``Scene.integrate_rows`` then takes
    the drift alone, on its fast path)."""
    if not scene.motion_errors.turns:
        return None
    n = moved.size // 2
    mid_along = 0.5 * (moved[:n] + moved[n:])
    lateral: Array = 0.5 * (across[:n] + across[n:]) + scene.lateral_cols(mid_along)
    return lateral


def exposures(times: Array, timing: SensorTiming, rows: int, shutter: str) -> tuple[Array, Array]:
    """(start, end) of each row's exposure, ``(frames, rows)``, for frames whose row 0 ends
    its exposure at each of ``times`` (a rolling shutter staggers rows by ``T_line``)."""
    if shutter == "rolling":
        offsets = np.arange(rows, dtype=np.float64) * timing.line_period_s
    else:
        offsets = np.zeros(rows)
    end = times[:, np.newaxis] + offsets[np.newaxis, :]
    return end - timing.exposure_s, end
