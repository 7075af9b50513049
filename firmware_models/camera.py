"""The simulated camera's physics: scene, stage, optics and sensor make window frames.

``CameraModel(profile, sensor)`` renders what the sensor whose registers ``sensor`` holds
(``firmware_models.sensor.SensorModel``) would read out, for the camera ``profile`` describes
(``camd.sensor.profile``). It reads the window, exposure, gain, offset, test pattern and timing
from the registers for every render (worked out once per register version: ``settings``), so
register writes take effect on the next frame.

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
5. Temporal noise (docs/physics.md §5): photon and dark shot noise and read noise, as ONE
   Gaussian per pixel with mean ``S + D`` and variance ``S + D + sigma_read^2`` (the Poisson
   shot noise replaced by a Gaussian of the same mean and variance: mean and variance exact,
   higher moments not), its standard normal taken from a pre-drawn bank at a random offset
   per frame (``firmware_models.noise_bank``: what that changes, and what not). Then
   full-well clipping (a saturated pixel reads the full-well charge, without read noise).
6. ADC (docs/physics.md §5): ``DN = e K + B``, ``K`` the system gain for the gain register
   (``CameraProfile.system_gain_dn_per_e``), ``B`` the black level for the offset register;
   rounded to whole DN and clipped to ``[0, 2^adc_bits - 1]``; then the ADC's
   ``output_bits`` MSBs are kept (the IBIS5 drops 2 LSBs).
7. Binning (``binning``; docs/physics.md §3): the FPGA sums 2x2 blocks (``camd.tdi.bin2x2``).

Steps 4 to 6 are one compiled pass per frame (``firmware_models.render_kernels``), and step
3's along-track sum over the scene's cells another; ``render_block`` renders several frames
(the rows of all of them) in one go, as the imaging pipeline does at high line rates.

The parts: what the registers set (``firmware_models.camera_settings``), the frames' making
(``camera_frames``: photons, electrons, noise, readout) and image motion compensation's
photons (``camera_imc``); ``CameraModel`` holds the configuration they are made from.

Fixed-pattern maps (PRNU, DSNU) cover the whole array, drawn once from ``seed``
(``firmware_models.fixed_pattern``); each frame's temporal noise starts at an offset drawn from
a separate seeded stream, so frames are independent and the same seed with the same sequence
of renders gives identical frames. A test pattern other than ``off`` in the sensor's
test_pattern role replaces the pixels (``firmware_models.lvds``). The model does not advance
the sensor's frame counter: whoever reads frames out does.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

from camd.analysis.sensor_noise import dark_current_e_per_s
from camd.sensor.profile import CameraProfile
from camd.sensor.timing_view import SensorTiming
from camd.tdi.binning import bin2x2
from camd.timing import synchronous_stage_speed_m_s
from camd.timing.imc import ImcMode
from firmware_models import render_kernels
from firmware_models.camera_frames import FrameMaker, exposures
from firmware_models.camera_settings import RegisterSettings, work_out_settings
from firmware_models.scene import Scene, build_scene
from firmware_models.scene_spec import SceneSpec
from firmware_models.sensor import SensorModel
from firmware_models.stage import LinearStage, Stage

__all__ = ["DEFAULT_FILL_OF_RANGE", "CameraModel", "RegisterSettings"]

Array = npt.NDArray[Any]

DEFAULT_FILL_OF_RANGE = 0.25  # the default flat field fills a quarter of the output range
_SETTINGS_KEPT = 16  # register snapshots whose settings are kept (a stream's recent changes)


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
        # ``transmission(start_s, end_s)`` of one frame's rows -> factor per row (asked frame
        # by frame: the channel is the wheel's at that frame); None: everything passes.
        self.transmission: Callable[[Array, Array], Array] | None = None
        # The ideal stage is at position 0 at this device time (see ``stream_started``).
        self._ideal_origin_s = 0.0
        self._anchor_next_stream = False
        self._frames = FrameMaker(self, seed)  # fixed pattern, noise: a camera's own
        # id(sensor) -> (sensor, its version then, the settings): see ``settings``.
        self._settings: dict[int, tuple[SensorModel, int, RegisterSettings]] = {}
        self._default_photons = self._moderate_photons()
        self.scene: Scene = build_scene(
            SceneSpec(),
            columns=profile.columns.value,
            pitch_m=profile.pitch_m.value,
            default_photons=self._default_photons,
        )

    def reseed_noise(self, seed: int) -> None:
        """Restart the temporal noise stream as if the camera had been made with ``seed``.

        The next stream starts the ideal stage at position 0 (``stream_started``). The fixed
        pattern and the noise bank keep the start seed's values: only the offsets at which
        frames take their noise from the bank follow the new seed."""
        self._frames.reseed(seed)
        self._anchor_next_stream = True

    def warm_up(self) -> None:
        """Do now what the first frame of the present window would do first (load the compiled
        kernels, draw the fixed pattern and the noise bank's values), without drawing from the
        temporal noise stream: frames stay what they would have been."""
        render_kernels.warm_up()
        self._frames.warm_up(self.window())

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

    def synchronous_speed_m_s(self, timing: SensorTiming | None = None) -> float:
        """Stage speed that moves the image one row per TDI line period: ``p / (m T_TDI)``.

        docs/physics.md §2 (``T_line,TDI = p / v_image``) and §6 eq 9 (``V_t = n_mag p / T_L``,
        object side) with ``v_image = m v_stage``; ``T_TDI`` is the frame period the registers
        set now (``SensorTiming.tdi_line_period_s``), or ``timing``'s.
        """
        timing = self.sensor.timing() if timing is None else timing
        return synchronous_stage_speed_m_s(
            self.profile.pitch_m.value,
            timing.tdi_line_period_s,
            self.profile.magnification.value,
        )

    def current_stage(self, timing: SensorTiming | None = None) -> Stage:
        """The stage that moves the target now: ``stage``, or a linear stage at
        ``stage_speed_m_s``, or (both None) at the synchronous speed (of ``timing``'s line
        period, default the registers' now)."""
        if self.stage is not None:
            return self.stage
        speed = self.stage_speed_m_s
        if speed is None:
            speed = self.synchronous_speed_m_s(timing)
        return LinearStage(speed, -speed * self._ideal_origin_s)

    def image_rows(self, t_s: npt.ArrayLike, timing: SensorTiming | None = None) -> Array:
        """Image displacement in rows at times ``t_s``: ``m x_stage(t) / p`` (docs/physics.md §2),
        with the scene's image motion errors (``image_motion``)."""
        return self.image_motion(t_s, timing)[0]

    def image_motion(
        self, t_s: npt.ArrayLike, timing: SensorTiming | None = None
    ) -> tuple[Array, Array]:
        """Image displacement at times ``t_s``: rows along track (``m x_stage(t) / p`` for an
        exact optics and mount) and columns across track from the scene's image motion errors
        (``firmware_models.image_errors``: magnification error, camera rotation, stage yaw;
        zero without a rotation or yaw). The encoder counts ``x_stage`` and sees none of them.
        A drift angle (``drift_deg``) is the scene's own and added where it is rendered."""
        times = np.asarray(t_s, dtype=np.float64)
        position = np.asarray(self.current_stage(timing).position_m(times), dtype=np.float64)
        image_scale = self.stage_image_scale
        if image_scale is None or self.stage is None:
            image_scale = self.profile.magnification.value
        rows_per_m = image_scale / self.profile.pitch_m.value
        errors = self.scene.motion_errors
        if not errors.any:
            along: Array = position * rows_per_m
            return along, np.zeros_like(along)
        return errors.displacement(position, rows_per_m)

    # -- settings the registers make --------------------------------------------------------------

    def settings(self, sensor: SensorModel | None = None) -> RegisterSettings:
        """What the registers of ``sensor`` (default: the camera's; a stream passes register
        snapshots) set for a render. Kept per register version: worked out again only after
        a register changes."""
        sensor = self.sensor if sensor is None else sensor
        kept = self._settings.get(id(sensor))
        if kept is not None and kept[0] is sensor and kept[1] == sensor.version:
            return kept[2]
        settings = work_out_settings(self.profile, sensor)
        if len(self._settings) >= _SETTINGS_KEPT:
            self._settings.clear()
        self._settings[id(sensor)] = (sensor, sensor.version, settings)
        return settings

    @property
    def shutter(self) -> str:
        """The readout mode's shutter if it names one (IBIS5: rolling/global), else the profile's."""
        return self.settings().shutter

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
        return self.settings().gain_dn_per_e

    def black_level_dn(self) -> float:
        """Black level in ADC DN for the offset register's value now."""
        return self.settings().black_dn

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
        return self.settings().imc

    def window(self) -> tuple[int, int, int, int]:
        """(first row, rows, first column, columns) of the window, as array indices."""
        return self.settings().window

    # -- frames -----------------------------------------------------------------------------------

    def render(self, t_s: float) -> Array:
        """One window frame (uint16, ``(rows, cols)``; halved when binned) whose window row 0
        ends its exposure at ``t_s``."""
        frames, _ = self.render_block([t_s])
        frame: Array = frames[0]
        return frame

    def render_block(
        self, times_s: Sequence[float] | Array, *, sensor: SensorModel | None = None
    ) -> tuple[Array, npt.NDArray[np.int64]]:
        """Frames whose window row 0 ends its exposure at each of ``times_s``, with the
        registers of ``sensor`` (default: the camera's), all in one pass: ``(frames, rows,
        cols)`` uint16 (halved and summed when binned) and each frame's largest code.

        The same frames, bit for bit, as one ``render`` per time in order: each frame takes its
        own noise offset, in order, and every row is integrated on its own (to float32
        rounding only where the frames move by very different amounts during their exposures,
        a stage ramping within the block: the block's rows sum as many scene cells as its
        widest motion needs, which may choose the scene's dense sum for all of them)."""
        return self._frames.render_block(times_s, self.settings(sensor))

    def expected_electrons(self, t_s: float, *, dtype: npt.DTypeLike = np.float32) -> Array:
        """Noise-free charge per pixel (signal + dark, full-well clipped) of ``render(t_s)``'s
        frame, including the fixed pattern; summed over 2x2 blocks when binned."""
        electrons = self._frames.mean_electrons(t_s, self.settings(), dtype)
        np.minimum(electrons, self.profile.full_well_e.value, out=electrons)
        return bin2x2(electrons) if self.binning else electrons

    def expected_dn(self, t_s: float, *, dtype: npt.DTypeLike = np.float32) -> Array:
        """Noise-free output of ``render(t_s)`` before quantisation, in output DN.

        ``e K + B`` clipped to the ADC range, divided by ``2^(adc_bits - output_bits)`` (not
        floored), summed over 2x2 blocks when binned.
        """
        electrons = self._frames.mean_electrons(t_s, self.settings(), dtype)
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
        settings = self.settings()
        timing = settings.timing if timing is None else timing
        n = timing.window_rows if rows is None else rows
        start, end = exposures(np.array([float(t_s)]), timing, n, settings.shutter)
        return start[0], end[0]

    # -- internals --------------------------------------------------------------------------------

    def _moderate_photons(self) -> float:
        """Photons/pixel/s that fill DEFAULT_FILL_OF_RANGE of the output range at the current
        exposure (the lower of full well and the ADC range above the black level)."""
        p = self.profile
        timing = self.sensor.timing()
        gain = self.system_gain_dn_per_e()
        range_e = min(p.full_well_e.value, (p.adc_max_dn - self.black_level_dn()) / gain)
        per_photon_s = p.quantum_efficiency.value * p.fill_factor.value * timing.exposure_s
        return DEFAULT_FILL_OF_RANGE * range_e / max(per_photon_s, 1e-300)
