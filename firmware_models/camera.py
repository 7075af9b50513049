"""The simulated camera's physics: scene, stage, optics and sensor make window frames.

``CameraModel(profile, sensor)`` renders what the sensor whose registers ``sensor`` holds
(``firmware_models.sensor.SensorModel``) would read out, for the camera ``profile`` describes
(``camd.sensor.profile``). It reads the window, exposure, gain, offset, test pattern and timing
from the registers on every render, so register writes take effect on the next frame.

One frame (``render(t_s)``; window row 0 ends its exposure at ``t_s``):

1. Timing (docs/physics.md §2 eq 4, §3): a rolling shutter ends row ``i``'s exposure at
   ``t_s + i T_line``; global, frame-transfer and full-frame shutters end every row at
   ``t_s``. Each row starts its exposure ``T_exp`` before it ends. ``T_line``, ``T_exp`` and
   the TDI line period come from ``sensor.timing()``.
2. Motion: the stage's position at each row's exposure start and end, in image rows
   ``d = magnification * x_stage / pitch`` (docs/physics.md §2: ``T_line,TDI = p / v_image``,
   ``v_image = magnification * v_stage``). Without an explicit stage or speed the stage tracks:
   it runs at the synchronous speed for the current TDI line period, one row per period.
3. Photons: the scene's exact time-and-aperture integral (``firmware_models.scene``).
   Image motion compensation (docs/physics.md §7 [REN15]; a sensor whose map has the IMC_CTRL,
   IMC_STEP and IMC_PHASES registers, the full-frame ``ftf5066``): the charge packets are
   clocked along the columns with the image during the exposure, one electrode (``w / p``)
   every ``IMC_STEP`` clocks or one row every ``p`` of them
   (``camd.timing.imc.charge_shift_schedule``), so each pixel's collection aperture moves
   relative to the scene by the image displacement minus the packets' shift: a sawtooth, a
   sequence of linear pieces. Each piece is a moving aperture that ``Scene.integrate``
   integrates exactly; the photons are the sum over the pieces, each weighted by its
   duration (identical pieces are integrated once, docs/imc.md). Row ``i`` of the frame is the
   packet that sat in window row ``i`` when the exposure began.
4. Electrons: ``QE * photons * (1 + PRNU)`` plus dark charge
   ``I_dark(T) * (1 + DSNU) * T_exp`` with ``I_dark(T) = I_ref * 2^((T - T_ref) / T_double)``.
5. Temporal noise (docs/physics.md §5): photon and dark shot noise and read noise, drawn as ONE
   Gaussian per pixel with mean ``S + D`` and variance ``S + D + sigma_read^2`` (the Poisson
   shot noise replaced by a Gaussian of the same mean and variance: mean and variance exact,
   higher moments not; one draw keeps a 534 x 2048 frame fast). Then full-well clipping
   (a saturated pixel reads the full-well charge, without read noise).
6. ADC (docs/physics.md §5): ``DN = e K + B``, ``K`` the system gain for the gain register
   (``CameraProfile.system_gain_dn_per_e``), ``B`` the black level for the offset register;
   rounded to whole DN and clipped to ``[0, 2^adc_bits - 1]``; then the ADC's
   ``output_bits`` MSBs are kept (the IBIS5 drops 2 LSBs).
7. Binning (``binning``; docs/physics.md §3): the FPGA sums 2x2 blocks (``camd.tdi.bin2x2``).

Fixed-pattern maps (PRNU, DSNU) cover the whole array, drawn once from ``seed`` (an array of
more than 8 Mpixel, the ftf5066's 33 Mpixel, draws them per band of 256 rows when a window
first reads one, each band from its own seeded stream); temporal noise
is drawn fresh for every frame from a separate seeded stream, so frames are independent and the
same seed with the same sequence of renders gives identical frames. A test pattern other than
``off`` in the sensor's test_pattern role replaces the pixels (``firmware_models.lvds``).
The model does not advance the sensor's frame counter: whoever reads frames out does.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Callable
from typing import Any

import numpy as np
import numpy.typing as npt

from camd.analysis.sensor_noise import dark_current_e_per_s
from camd.sensor.profile import SHUTTERS, CameraProfile
from camd.sensor.timing_view import SensorTiming
from camd.tdi.binning import bin2x2
from camd.timing import synchronous_stage_speed_m_s
from camd.timing.imc import IMC_MODES, ImcMode, charge_shift_schedule
from firmware_models.lvds import DEFAULT_TRAINING_WORD, TestPattern, pattern_frame
from firmware_models.scene import Scene, SceneSpec, build_scene
from firmware_models.sensor import SensorModel
from firmware_models.stage import LinearStage, Stage

Array = npt.NDArray[Any]

_FIXED_PATTERN_STREAM = 0x4650  # "FP": PRNU and DSNU maps
_TEMPORAL_STREAM = 0x544E  # "TN": per-frame noise, independent of the fixed pattern
DEFAULT_FILL_OF_RANGE = 0.25  # the default flat field fills a quarter of the output range
_BANDED_MAP_PIXELS = 1 << 23  # larger arrays draw their fixed pattern per band of rows
_MAP_BAND_ROWS = 256
_MAX_MOTION_PIECES = 64  # more distinct IMC pieces than this are merged into an occupation density
_SAME_PIECE_ROWS = 1e-9  # pieces whose ends agree to this (rows) are integrated together


class CameraModel:
    """Scene + stage + optics + the sensor's physics; see the module docstring.

    Attributes the caller may change between renders: ``scene`` (or ``set_scene``),
    ``stage_speed_m_s`` (None: track the TDI line period), ``stage`` (an explicit ``Stage``,
    which overrides ``stage_speed_m_s``; ``stage_image_scale`` says how its travel scales onto
    the focal plane), ``transmission`` (a filter-wheel channel's light per row),
    ``temperature_degc``, ``binning``.
    """

    def __init__(self, profile: CameraProfile, sensor: SensorModel, *, seed: int = 0) -> None:
        regmap = sensor.regmap
        if regmap.sensor != profile.sensor:
            raise ValueError(
                f"profile {profile.profile} is for sensor {profile.sensor}, but the sensor model "
                f"carries the {regmap.sensor} register map; use load_register_map"
                f"({profile.sensor!r})"
            )
        if (regmap.rows, regmap.columns) != (profile.rows.value, profile.columns.value):
            raise ValueError(
                f"profile {profile.profile} has {profile.rows.value} x {profile.columns.value} "
                f"pixels, the {regmap.sensor} map {regmap.rows} x {regmap.columns}"
            )
        self.profile = profile
        self.sensor = sensor
        self.seed = seed
        self.temperature_degc: float = profile.dark_reference_temp_degc.value
        self.binning = False
        self.stage_speed_m_s: float | None = None
        self.stage: Stage | None = None
        # Focal-plane metres per metre of ``stage`` travel; None: the optics' magnification
        # (a turntable carrying the sensor moves the image by its arc: 1).
        self.stage_image_scale: float | None = None
        # Per-row light transmission over each row's exposure (a filter-wheel channel):
        # ``transmission(start_s, end_s)`` -> factor per row; None: everything passes.
        self.transmission: Callable[[Array, Array], Array] | None = None
        self._noise = np.random.default_rng([seed, _TEMPORAL_STREAM])
        # The ideal stage is at position 0 at this device time (see ``stream_started``).
        self._ideal_origin_s = 0.0
        self._anchor_next_stream = False
        # Drawn on first use: a 2048 x 2048 array takes ~0.1 s, and not every model renders.
        self._maps: tuple[Array, Array] | None = None
        # Bands of a large array's maps, drawn when a window first reads them; the dict is
        # shared with ``frozen`` twins (a shallow copy), so a band is drawn once.
        self._bands: dict[int, tuple[Array, Array]] = {}
        self._default_photons = self._moderate_photons()
        self.scene: Scene = build_scene(
            SceneSpec(),
            columns=profile.columns.value,
            pitch_m=profile.pitch_m.value,
            default_photons=self._default_photons,
        )

    def frozen(self, sensor: SensorModel) -> CameraModel:
        """This camera reading ``sensor`` (a register snapshot) instead: renders from it never
        see a register write half-way (the fixed pattern, noise stream, scene and stage are
        shared)."""
        if not self._banded_maps:
            self._fixed_patterns()  # drawn once here, so the twin shares them
        twin = copy.copy(self)
        twin.sensor = sensor
        return twin

    def reseed_noise(self, seed: int) -> None:
        """Restart the temporal noise stream as if the camera had been made with ``seed``.

        The generator is reset in place, not replaced: ``frozen`` twins share it and must draw
        from the restarted stream too, and the next stream starts the ideal stage at position
        0 (``stream_started``). The fixed pattern keeps the start seed's maps."""
        fresh = np.random.default_rng([seed, _TEMPORAL_STREAM])
        self._noise.bit_generator.state = fresh.bit_generator.state
        self._anchor_next_stream = True

    def stream_started(self, t0_s: float) -> None:
        """A stream starts at device time ``t0_s``. After ``reseed_noise`` the ideal stage is
        put at position 0 then: its frames see the scene from the same place whenever the
        stream starts, so a re-seeded acquisition is repeatable (campaign resume) -- a
        stream's timing relative to its start is fixed, its absolute device time is not."""
        if self._anchor_next_stream:
            self._ideal_origin_s = t0_s
            self._anchor_next_stream = False

    # -- scene and stage --------------------------------------------------------------------------

    def set_scene(self, spec: SceneSpec | str | Scene) -> Scene:
        """Show a scene: a Scene, a SceneSpec or its text (``"bars:lux=3,drift_deg=0.5"``).

        Without a level in the spec the scene gets the camera's default level (a quarter of the
        output range at the exposure the registers held when the camera was made).
        """
        if isinstance(spec, Scene):
            self.scene = spec
            return spec
        parsed = SceneSpec.parse(spec) if isinstance(spec, str) else spec
        self.scene = build_scene(
            parsed,
            columns=self.profile.columns.value,
            pitch_m=self.profile.pitch_m.value,
            default_photons=self._default_photons,
        )
        return self.scene

    def synchronous_speed_m_s(self) -> float:
        """Stage speed that moves the image one row per TDI line period: ``p / (m T_TDI)``.

        docs/physics.md §2 (``T_line,TDI = p / v_image``) and §6 eq 9 (``V_t = n_mag p / T_L``,
        object side) with ``v_image = m v_stage``; ``T_TDI`` is the frame period the registers
        set now (``SensorTiming.tdi_line_period_s``).
        """
        return synchronous_stage_speed_m_s(
            self.profile.pitch_m.value,
            self.sensor.timing().tdi_line_period_s,
            self.profile.magnification.value,
        )

    def current_stage(self) -> Stage:
        """The stage that moves the target now: ``stage``, or a linear stage at
        ``stage_speed_m_s``, or (both None) at the synchronous speed."""
        if self.stage is not None:
            return self.stage
        speed = (
            self.synchronous_speed_m_s() if self.stage_speed_m_s is None else self.stage_speed_m_s
        )
        return LinearStage(speed, -speed * self._ideal_origin_s)

    def image_rows(self, t_s: npt.ArrayLike) -> Array:
        """Image displacement in rows at times ``t_s``: ``m x_stage(t) / p`` (docs/physics.md §2)."""
        times = np.asarray(t_s, dtype=np.float64)
        position = self.current_stage().position_m(times)
        image_scale = self.stage_image_scale
        if image_scale is None or self.stage is None:
            image_scale = self.profile.magnification.value
        scale = image_scale / self.profile.pitch_m.value
        result: Array = np.asarray(position, dtype=np.float64) * scale
        return result

    # -- settings the registers make --------------------------------------------------------------

    @property
    def shutter(self) -> str:
        """The readout mode's shutter if it names one (IBIS5: rolling/global), else the profile's."""
        mode = self.sensor.readout_mode if self.sensor.regmap.role("readout_mode") else None
        if isinstance(mode, str) and mode in SHUTTERS:
            return mode
        return self.profile.shutter.value

    @property
    def rows(self) -> int:
        """Rows of the window the registers set (before binning)."""
        return self.window()[1]

    @property
    def columns(self) -> int:
        """Columns of the window the registers set (before binning)."""
        return self.window()[3]

    @property
    def bits(self) -> int:
        """Bits per output pixel: ``output_bits``, two more when binned (a sum of 4)."""
        return self.profile.output_bits.value + (2 if self.binning else 0)

    def system_gain_dn_per_e(self) -> float:
        """``K`` (ADC DN per electron) for the gain register's value now."""
        gain = self.sensor.gain if self.sensor.regmap.role("gain") else None
        return self.profile.system_gain_dn_per_e(self.profile.analog_gain_factor(gain))

    def black_level_dn(self) -> float:
        """Black level in ADC DN for the offset register's value now."""
        offset = self.sensor.offset if self.sensor.regmap.role("offset") else None
        return self.profile.black_level_for(offset)

    def dark_factor(self) -> float:
        """Dark current at ``temperature_degc`` relative to the profile's reference temperature:
        ``2^((T - T_ref) / T_double)`` (the doubling rule; it scales the DSNU map too)."""
        p = self.profile
        return dark_current_e_per_s(
            1.0,
            p.dark_reference_temp_degc.value,
            p.dark_doubling_temp_degc.value,
            self.temperature_degc,
        )

    def dark_current_e_per_s(self) -> float:
        """Mean dark current at ``temperature_degc`` (doubling rule, see the profile)."""
        return self.profile.dark_current_e_per_s.value * self.dark_factor()

    def imc(self) -> tuple[ImcMode, float, int]:
        """Image motion compensation the registers set: (mode, electrode interval in s, phases).

        ``IMC_CTRL.mode`` (none, row, electrode), ``IMC_STEP`` (the electrode-step interval in
        clocks of the map's ``timing.clock_hz``) and ``IMC_PHASES`` (p, read-only); a sensor
        without them never compensates: ``("none", inf, 1)``.
        """
        regmap = self.sensor.regmap
        if not regmap.has_register("IMC_CTRL"):
            return "none", math.inf, 1
        mode = self.sensor.value("IMC_CTRL.mode")
        if mode not in IMC_MODES:
            raise ValueError(f"IMC_CTRL.mode is {mode!r}; the map must name none, row, electrode")
        interval_s = int(self.sensor.value("IMC_STEP")) / regmap.timing.clock_hz
        phases = int(self.sensor.value("IMC_PHASES"))
        return mode, interval_s, phases

    def window(self) -> tuple[int, int, int, int]:
        """(first row, rows, first column, columns) of the window, as array indices."""
        regmap = self.sensor.regmap
        timing = self.sensor.timing()
        row0 = timing.window_start_row - regmap.first_row
        col_start = regmap.role_count("window_start_column", self.sensor.value)
        col0 = 0 if col_start is None else col_start - regmap.first_column
        cols = regmap.role_count("window_columns", self.sensor.value) or regmap.columns
        rows = timing.window_rows
        if row0 < 0 or row0 + rows > regmap.rows or col0 < 0 or col0 + cols > regmap.columns:
            raise ValueError(
                f"window rows {row0}..{row0 + rows - 1}, columns {col0}..{col0 + cols - 1} "
                f"(array indices) leave the {regmap.rows} x {regmap.columns} array; move or "
                "shrink the window"
            )
        return row0, rows, col0, cols

    # -- frames -----------------------------------------------------------------------------------

    def render(self, t_s: float) -> Array:
        """One window frame (uint16, ``(rows, cols)``; halved when binned) whose window row 0
        ends its exposure at ``t_s``."""
        row0, rows, col0, cols = self.window()
        pattern = self._test_pattern(rows, cols)
        if pattern is not None:
            return bin2x2(pattern) if self.binning else pattern
        timing = self.sensor.timing()
        electrons = self._mean_electrons(t_s, timing, (row0, rows, col0, cols), np.float32)
        p = self.profile
        # One Gaussian per pixel: mean S + D, variance S + D + read^2 (module docstring, 5).
        sigma = electrons + np.float32(p.read_noise_e.value**2)
        np.sqrt(sigma, out=sigma)
        sigma *= self._noise.standard_normal(electrons.shape, dtype=np.float32)
        electrons += sigma
        np.minimum(electrons, np.float32(p.full_well_e.value), out=electrons)
        electrons *= np.float32(self.system_gain_dn_per_e())
        electrons += np.float32(self.black_level_dn())
        np.rint(electrons, out=electrons)
        np.clip(electrons, 0.0, float(p.adc_max_dn), out=electrons)
        frame = electrons.astype(np.uint16)
        if p.output_shift_bits:
            frame >>= p.output_shift_bits
        return bin2x2(frame) if self.binning else frame

    def expected_electrons(self, t_s: float, *, dtype: npt.DTypeLike = np.float32) -> Array:
        """Noise-free charge per pixel (signal + dark, full-well clipped) of ``render(t_s)``'s
        frame, including the fixed pattern; summed over 2x2 blocks when binned."""
        window = self.window()
        electrons = self._mean_electrons(t_s, self.sensor.timing(), window, dtype)
        np.minimum(electrons, self.profile.full_well_e.value, out=electrons)
        return bin2x2(electrons) if self.binning else electrons

    def expected_dn(self, t_s: float, *, dtype: npt.DTypeLike = np.float32) -> Array:
        """Noise-free output of ``render(t_s)`` before quantisation, in output DN.

        ``e K + B`` clipped to the ADC range, divided by ``2^(adc_bits - output_bits)`` (not
        floored), summed over 2x2 blocks when binned.
        """
        window = self.window()
        electrons = self._mean_electrons(t_s, self.sensor.timing(), window, dtype)
        p = self.profile
        np.minimum(electrons, p.full_well_e.value, out=electrons)
        dn = electrons * self.system_gain_dn_per_e() + self.black_level_dn()
        np.clip(dn, 0.0, float(p.adc_max_dn), out=dn)
        dn /= 2**p.output_shift_bits
        return bin2x2(dn) if self.binning else dn

    def exposure_times_s(
        self, t_s: float, timing: SensorTiming | None = None, rows: int | None = None
    ) -> tuple[Array, Array]:
        """(start, end) of each window row's exposure for the frame whose row 0 ends at ``t_s``
        (docs/physics.md §2 eq 4, §3: a rolling shutter staggers rows by ``T_line``)."""
        timing = self.sensor.timing() if timing is None else timing
        n = timing.window_rows if rows is None else rows
        if self.shutter == "rolling":
            end = t_s + np.arange(n, dtype=np.float64) * timing.line_period_s
        else:
            end = np.full(n, float(t_s))
        return end - timing.exposure_s, end

    # -- internals --------------------------------------------------------------------------------

    def _mean_electrons(
        self,
        t_s: float,
        timing: SensorTiming,
        window: tuple[int, int, int, int],
        dtype: npt.DTypeLike,
    ) -> Array:
        row0, rows, col0, cols = window
        start, end = self.exposure_times_s(t_s, timing, rows)
        mode, interval_s, phases = self.imc()
        if mode != "none" and self.shutter != "rolling":
            electrons = self._compensated_photons(
                float(start[0]), timing.exposure_s, (mode, interval_s, phases), window, dtype
            )
        else:
            # Both ends in one stage call: a stepper's position may be costly to evaluate.
            moved = self.image_rows(np.concatenate([start, end]))
            electrons = self.scene.integrate(
                row0,
                rows,
                cols,
                moved[:rows],
                moved[rows:],
                None,
                timing.exposure_s,
                self.profile.aperture,
                first_col=col0,
                dtype=dtype,
            )
        response_rows, dark_rows = self._pattern_rows(row0, rows)
        response = response_rows[:, col0 : col0 + cols]
        dark_ref = dark_rows[:, col0 : col0 + cols]
        electrons *= response
        if self.transmission is not None:
            factor = np.asarray(self.transmission(start, end), dtype=electrons.dtype)
            electrons *= factor[:, np.newaxis]
        # Dark rate map at T_ref times the temperature factor, times the exposure.
        scale = np.asarray(self.dark_factor() * timing.exposure_s, dtype=electrons.dtype)
        dark = dark_ref * scale
        electrons += dark
        return electrons

    def _compensated_photons(
        self,
        start_s: float,
        exposure_s: float,
        imc: tuple[ImcMode, float, int],
        window: tuple[int, int, int, int],
        dtype: npt.DTypeLike,
    ) -> Array:
        """Photons per pixel of a full-frame exposure with the packets clocked along (module
        docstring, 3): the sum over the schedule's pieces of the scene's exact integral of an
        aperture moving linearly from (image displacement - packet shift) at the piece's start
        to that at its end, each for the piece's duration."""
        row0, rows, col0, cols = window
        mode, interval_s, phases = imc
        schedule = charge_shift_schedule(exposure_s, interval_s, mode, phases)
        moved = self.image_rows(start_s + schedule.bounds_s)  # all rows expose together
        # Drift moves the image sideways by its own displacement; the packets only move along.
        lateral = self.scene.lateral_cols(np.full(rows, 0.5 * (moved[0] + moved[-1])))
        pieces = _merge_pieces(
            moved[:-1] - schedule.shift_px, moved[1:] - schedule.shift_px, schedule.durations_s
        )
        total: Array | None = None
        for lo, hi, duration_s in pieces:
            photons = self.scene.integrate(
                row0, rows, cols, lo, hi, lateral, duration_s, self.profile.aperture,
                first_col=col0, dtype=dtype,
            )  # fmt: skip
            total = photons if total is None else total + photons
        assert total is not None  # a schedule has at least one piece
        return total

    @property
    def _banded_maps(self) -> bool:
        p = self.profile
        return p.rows.value * p.columns.value > _BANDED_MAP_PIXELS

    def _pattern_rows(self, row0: int, rows: int) -> tuple[Array, Array]:
        """The fixed-pattern maps (``_fixed_patterns``) of array rows ``row0 .. row0 + rows - 1``
        (all columns); a large array's from its bands."""
        if not self._banded_maps:
            response, dark = self._fixed_patterns()
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
        cached = self._bands.get(band)
        if cached is None:
            p = self.profile
            rows = min(_MAP_BAND_ROWS, p.rows.value - band * _MAP_BAND_ROWS)
            rng = np.random.default_rng([self.seed, _FIXED_PATTERN_STREAM, band])
            cached = self._draw_maps(rng, (rows, p.columns.value))
            self._bands[band] = cached
        return cached

    def _fixed_patterns(self) -> tuple[Array, Array]:
        """QE * (1 + PRNU) and the dark-current map at T_ref (e-/s, >= 0), whole array."""
        if self._maps is not None:
            return self._maps
        p = self.profile
        rng = np.random.default_rng([self.seed, _FIXED_PATTERN_STREAM])
        self._maps = self._draw_maps(rng, (p.rows.value, p.columns.value))
        return self._maps

    def _draw_maps(self, rng: np.random.Generator, shape: tuple[int, int]) -> tuple[Array, Array]:
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

    def _moderate_photons(self) -> float:
        """Photons/pixel/s that fill DEFAULT_FILL_OF_RANGE of the output range at the current
        exposure (the lower of full well and the ADC range above the black level)."""
        p = self.profile
        timing = self.sensor.timing()
        gain = self.system_gain_dn_per_e()
        range_e = min(p.full_well_e.value, (p.adc_max_dn - self.black_level_dn()) / gain)
        per_photon_s = p.quantum_efficiency.value * p.fill_factor.value * timing.exposure_s
        return DEFAULT_FILL_OF_RANGE * range_e / max(per_photon_s, 1e-300)

    def _test_pattern(self, rows: int, cols: int) -> Array | None:
        """The frame a test pattern setting sends instead of pixels, or None for pixels."""
        regmap = self.sensor.regmap
        if regmap.role("test_pattern") is None:
            return None
        setting = self.sensor.test_pattern
        if setting in ("off", 0):
            return None
        bits = self.profile.output_bits.value
        if setting == "test_data" and regmap.has_register("TEST_DATA"):
            # MT9M001: the sensor repeats the TEST_DATA register's value (mt9m001.toml).
            value = int(self.sensor.value("TEST_DATA")) & ((1 << bits) - 1)
            return np.full((rows, cols), value, dtype=np.uint16)
        name = setting.upper() if isinstance(setting, str) else ""
        kind = TestPattern[name] if name in TestPattern.__members__ else TestPattern.RAMP
        word_name = regmap.role("training_word")
        word = DEFAULT_TRAINING_WORD if word_name is None else int(self.sensor.value(word_name))
        frame = pattern_frame(
            kind,
            rows,
            cols,
            word_bits=bits,
            lanes=regmap.output.lanes,
            training_word=word & ((1 << bits) - 1),
        )
        assert frame is not None  # OFF was handled above
        return frame


def _merge_pieces(start: Array, end: Array, durations_s: Array) -> list[tuple[float, float, float]]:
    """Linear pieces of aperture motion (rows, from ``start[j]`` to ``end[j]`` for
    ``durations_s[j]``) as fewer pieces with the same time integral, ``(lo, hi, duration)``.

    The photons a moving aperture collects depend only on how long it spends at each
    displacement (the time integral of the scene over it), not on the order or direction of
    the motion. So pieces that cover the same displacements (to 1e-9 rows: the matched IMC
    sawtooth repeats one tooth) are integrated once with their durations added. If more than
    ``_MAX_MOTION_PIECES`` distinct pieces remain (a mismatched clock drifting through many
    positions), the occupation density is cut at every piece's ends into intervals of
    constant density, each an equivalent linear piece (still exact); if still too many, its
    mass is put on ``_MAX_MOTION_PIECES`` equal bins across the range (approximate within a
    bin's width: docs/imc.md).
    """
    used = durations_s > 0.0
    lo = np.minimum(start, end)[used]
    hi = np.maximum(start, end)[used]
    keys = np.stack([np.round(lo / _SAME_PIECE_ROWS), np.round(hi / _SAME_PIECE_ROWS)], axis=1)
    _, first, group = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    tau = np.bincount(group.reshape(-1), weights=durations_s[used])
    lo, hi = lo[first], hi[first]
    if lo.size <= _MAX_MOTION_PIECES:
        return [(float(a), float(b), float(t)) for a, b, t in zip(lo, hi, tau, strict=True)]
    moving = hi - lo >= _SAME_PIECE_ROWS
    edges = np.unique(np.concatenate([lo, hi]))
    # Time per row on each interval between consecutive edges: +rate where a moving piece
    # starts, -rate where it ends, summed up; a still piece is a point mass at its edge.
    rate = tau[moving] / (hi[moving] - lo[moving])
    change = np.zeros(edges.size)
    np.add.at(change, np.searchsorted(edges, lo[moving]), rate)
    np.add.at(change, np.searchsorted(edges, hi[moving]), -rate)
    mass = np.cumsum(change)[:-1] * np.diff(edges)
    points = np.zeros(edges.size)
    np.add.at(points, np.searchsorted(edges, lo[~moving]), tau[~moving])
    if np.count_nonzero(mass > 0.0) + np.count_nonzero(points) <= _MAX_MOTION_PIECES:
        out = [(float(e), float(e), float(m)) for e, m in zip(edges, points, strict=True) if m]
        out += [
            (float(a), float(b), float(m))
            for a, b, m in zip(edges[:-1], edges[1:], mass, strict=True)
            if m > 0.0
        ]
        return out
    # Still too many: the time spent below each of equal bins' edges (piecewise linear in the
    # displacement between edges, stepping at the point masses) spread evenly over each bin.
    bins = np.linspace(edges[0], edges[-1], _MAX_MOTION_PIECES + 1)
    below_edges = np.cumsum(points) + np.concatenate([[0.0], np.cumsum(mass)])
    below = np.interp(bins, edges, below_edges)
    below[0], below[-1] = 0.0, float(tau.sum())
    per_bin = np.diff(below)
    return [
        (float(a), float(b), float(m))
        for a, b, m in zip(bins[:-1], bins[1:], per_bin, strict=True)
        if m > 0.0
    ]
