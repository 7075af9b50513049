"""Scan-stage profiles as data: ``config/stages/<name>.toml``, validated by pydantic.

A stage profile holds the mechanics of one stepper-driven scan stage: the motor (full steps per
revolution), the microstepping driver (microsteps per full step, highest step input rate), the
drive (a lead screw on a linear rail, or a gear onto a turntable), the encoder, the motion limits
the daemon enforces, and a ``[sim]`` table with the simulator's defaults (the stage model of
``firmware_models.stage``). Both the daemon and the simulated camera read the same files, so this
module imports only pydantic, numpy, the standard library and ``camd.paths``.

Two kinds (``kind``):

- ``linear``: a carriage on a rail driven by a lead screw (``lead_m_per_rev``), mechanical
  travel ``travel_m`` from the home switch at the low end, an incremental linear encoder
  (``linear_encoder_counts_per_m``). The carriage carries the target: its position is on the
  object side, and the image moves ``m`` times as fast (docs/physics.md §6, ``V_m = n_mag V_motor``):
  ``image_scale(m) = m``.
- ``turntable``: a table driven through a gear (``gear_ratio`` motor turns per table turn) with
  the sensor at the distance ``radius_m`` (``l``) from the axis, travel unlimited, an encoder on
  the table (``table_encoder_counts_per_rev``). Positions, speeds and accelerations in "metres"
  are arc length at ``radius_m``: the image moves at ``v_image = w l`` (docs/physics.md §2 eq 5,
  ``T_line,TDI = a / (w l)``), so ``image_scale(m) = 1``.

Every physical value is an inline table with its provenance, exactly one of ``source`` or
``assumed``, as in the camera profiles::

    lead_m_per_rev = { value = 0.005, assumed = "5 mm ball screw, a common rail drive" }

A file that does not validate raises ``StageProfileError`` naming the file, the line of the key
and what to change, e.g.::

    config/stages/linear_rail.toml:24: max_speed_m_s: 0.9 m/s needs 576000 microsteps/s, above
    driver_max_rate_hz = 400000; lower max_speed_m_s to at most 0.625 or use fewer microsteps
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from camd.datafile import (
    Count,
    DataFileError,
    DataFileKind,
    KeyedError,
    Positive,
    Sourced,
    unit_of,
)
from camd.datafile import physical as _key
from camd.paths import config_dir

StageKind = Literal["linear", "turntable"]

Microsteps = Annotated[int, Field(ge=1, le=256)]
OpenFraction = Annotated[float, Field(gt=0, lt=1)]
TorqueFraction = Annotated[float, Field(ge=0, lt=1)]

# The keys each kind needs (and the other kind must not have).
LINEAR_KEYS = ("lead_m_per_rev", "travel_m", "linear_encoder_counts_per_m")
TURNTABLE_KEYS = ("gear_ratio", "radius_m", "table_encoder_counts_per_rev")


class StageProfileError(DataFileError):
    """A stage profile is invalid; the message starts with ``file:line:`` (or ``file:``)."""


class StageSim(BaseModel):
    """The ``[sim]`` table: the simulated stage's imperfection model and its default knobs.

    The five knobs ``error``, ``ripple``, ``jitter``, ``drift`` and ``load`` are the defaults
    of ``--inject stage_error=...`` etc. and of SIM_SET_STAGE_FAULTS (plain numbers: they are
    settings, not facts). The other keys shape the model and carry their provenance.
    """

    model_config = ConfigDict(extra="forbid", frozen=True, strict=True)

    ripple_period_m: Sourced[Positive] = _key(
        "spatial period of the periodic speed ripple (stage position, m)", "m"
    )
    jitter_corr_s: Sourced[Positive] = _key(
        "correlation time of the random speed jitter (exponential autocorrelation)", "s"
    )
    pullout_corner_m_s: Sourced[Positive] = _key(
        "stage speed above which the pull-out torque falls as 1 / speed (constant-power region "
        "of a chopper driver); below it the pull-out torque is its low-speed value T0",
        "m/s",
    )
    accel_torque_fraction: Sourced[TorqueFraction] = _key(
        "torque needed to accelerate the load at max_accel_m_s2, as a fraction of T0", "1"
    )
    stall_check_s: Sourced[Positive] = _key(
        "period (and window) of the FPGA's following-error check between commanded steps and "
        "encoder",
        "s",
    )
    stall_ratio: Sourced[OpenFraction] = _key(
        "a window in which the encoder moved less than this fraction of the commanded motion "
        "is a stall",
        "1",
    )
    stall_min_counts: Sourced[Count] = _key(
        "commanded motion (encoder counts) below which a window is not checked", "count"
    )
    error: float = Field(
        default=0.0, ge=-0.1, le=0.1, description="relative step-rate error (default knob)"
    )
    ripple: float = Field(
        default=0.0, ge=0.0, le=0.2, description="relative amplitude of the speed ripple"
    )
    jitter: float = Field(default=0.0, ge=0.0, le=0.2, description="relative rms speed jitter")
    drift: float = Field(
        default=0.0, ge=-0.1, le=0.1, description="relative speed drift per second of running"
    )
    load: float = Field(default=0.0, ge=0.0, le=3.0, description="load torque as a fraction of T0")


class StageProfile(BaseModel):
    """One scan stage's mechanics, as loaded from ``config/stages/<name>.toml``."""

    model_config = ConfigDict(extra="forbid", frozen=True, strict=True)

    name: str = Field(pattern=r"^[a-z0-9][a-z0-9_]*$", description="profile name (file stem)")
    description: str = Field(default="", description="one line on the stage")
    kind: StageKind = Field(description="linear (a rail) or turntable")
    full_steps_per_rev: Sourced[Count] = _key("motor full steps per revolution", "step/rev")
    microsteps: Sourced[Microsteps] = _key(
        "driver microsteps per full step (1 .. 256)", "microstep/step"
    )
    driver_max_rate_hz: Sourced[Positive] = _key(
        "highest step input rate of the microstepping driver", "microstep/s"
    )
    lead_m_per_rev: Sourced[Positive] | None = _key(
        "linear: carriage travel per motor revolution (screw lead)", "m/rev", None
    )
    travel_m: Sourced[Positive] | None = _key(
        "linear: mechanical travel from the home switch at the low end", "m", None
    )
    linear_encoder_counts_per_m: Sourced[Positive] | None = _key(
        "linear: encoder counts per metre of carriage travel", "count/m", None
    )
    gear_ratio: Sourced[Positive] | None = _key(
        "turntable: motor revolutions per table revolution", "1", None
    )
    radius_m: Sourced[Positive] | None = _key(
        "turntable: distance l of the sensor from the axis (docs/physics.md §2 eq 5)", "m", None
    )
    table_encoder_counts_per_rev: Sourced[Positive] | None = _key(
        "turntable: encoder counts per table revolution", "count/rev", None
    )
    max_speed_m_s: Sourced[Positive] = _key(
        "highest stage speed (turntable: arc speed at radius_m); the daemon refuses more", "m/s"
    )
    max_accel_m_s2: Sourced[Positive] = _key(
        "acceleration of every ramp, and its highest programmable value", "m/s^2"
    )
    home_speed_m_s: Sourced[Positive] = _key("speed of the run to the home switch", "m/s")
    sim: StageSim = Field(description="the simulator's stage model (table [sim])")

    @model_validator(mode="after")
    def _check(self) -> StageProfile:
        need, other, other_kind = (
            (LINEAR_KEYS, TURNTABLE_KEYS, "turntable")
            if self.kind == "linear"
            else (TURNTABLE_KEYS, LINEAR_KEYS, "linear")
        )
        for key in other:
            if getattr(self, key) is not None:
                raise KeyedError(
                    key,
                    f'kind = "{self.kind}" does not use {key}; remove it (it belongs to '
                    f'kind = "{other_kind}")',
                )
        for key in need:
            if getattr(self, key) is None:
                unit = StageProfile.unit_of(key)
                raise KeyedError(
                    "kind",
                    f'kind = "{self.kind}" needs {key} ({unit}); add '
                    f'`{key} = {{ value = ..., source = "..." }}` (or assumed = "...")',
                )
        rate = self.max_speed_m_s.value * self.microsteps_per_m
        driver = self.driver_max_rate_hz.value
        if rate > driver * (1 + 1e-12):
            highest = driver * self.metres_per_microstep
            raise KeyedError(
                "max_speed_m_s",
                f"{self.max_speed_m_s.value:g} m/s needs {rate:.6g} microsteps/s, above "
                f"driver_max_rate_hz = {driver:g}; lower max_speed_m_s to at most {highest:.6g} "
                "or use fewer microsteps",
            )
        if self.home_speed_m_s.value > self.max_speed_m_s.value:
            raise KeyedError(
                "home_speed_m_s",
                f"{self.home_speed_m_s.value:g} m/s is above max_speed_m_s = "
                f"{self.max_speed_m_s.value:g}; lower it",
            )
        if self.travel_m is not None:
            ramp = self.max_speed_m_s.value**2 / self.max_accel_m_s2.value
            if ramp >= self.travel_m.value:
                raise KeyedError(
                    "travel_m",
                    f"{self.travel_m.value:g} m is shorter than one ramp up and down at "
                    f"max_speed_m_s and max_accel_m_s2 ({ramp:.4g} m); lengthen the travel "
                    "or lower the speed",
                )
        return self

    # -- schema helpers -------------------------------------------------------------------------

    @classmethod
    def unit_of(cls, key: str) -> str | None:
        """The unit of a physical key, None for other keys."""
        return unit_of(cls, key)

    # -- derived values -------------------------------------------------------------------------

    @property
    def is_linear(self) -> bool:
        return self.kind == "linear"

    @property
    def microsteps_per_rev(self) -> int:
        """Microsteps per motor revolution: ``full_steps_per_rev * microsteps``."""
        return self.full_steps_per_rev.value * self.microsteps.value

    @property
    def circumference_m(self) -> float | None:
        """Turntable: arc length of one table revolution at ``radius_m`` (None for linear)."""
        if self.radius_m is None:
            return None
        return 2.0 * math.pi * self.radius_m.value

    @property
    def metres_per_microstep(self) -> float:
        """Stage travel per microstep: ``lead / (steps * microsteps)`` on a rail, the arc at
        ``radius_m`` ``2 pi l / (steps * microsteps * gear_ratio)`` on a turntable."""
        if self.lead_m_per_rev is not None:
            return self.lead_m_per_rev.value / self.microsteps_per_rev
        assert self.gear_ratio is not None and self.circumference_m is not None  # validated
        return self.circumference_m / (self.microsteps_per_rev * self.gear_ratio.value)

    @property
    def microsteps_per_m(self) -> float:
        """``1 / metres_per_microstep``, computed without the round trip through a reciprocal."""
        if self.lead_m_per_rev is not None:
            return self.microsteps_per_rev / self.lead_m_per_rev.value
        assert self.gear_ratio is not None and self.circumference_m is not None
        return self.microsteps_per_rev * self.gear_ratio.value / self.circumference_m

    @property
    def microsteps_per_table_rev(self) -> float | None:
        """Turntable: microsteps per table revolution (None for linear)."""
        if self.gear_ratio is None:
            return None
        return self.microsteps_per_rev * self.gear_ratio.value

    @property
    def encoder_counts_per_m(self) -> float:
        """Encoder counts per metre of stage travel (turntable: per metre of arc at radius)."""
        if self.linear_encoder_counts_per_m is not None:
            return self.linear_encoder_counts_per_m.value
        assert self.table_encoder_counts_per_rev is not None and self.circumference_m is not None
        return self.table_encoder_counts_per_rev.value / self.circumference_m

    @property
    def travel_microsteps(self) -> int | None:
        """Linear: the mechanical travel in whole microsteps (None: unlimited, a turntable)."""
        if self.travel_m is None:
            return None
        return math.floor(self.travel_m.value * self.microsteps_per_m + 1e-9)

    @property
    def max_rate_hz(self) -> float:
        """``max_speed_m_s`` as a step rate (microsteps per second)."""
        return self.max_speed_m_s.value * self.microsteps_per_m

    @property
    def max_accel_hz_per_s(self) -> float:
        """``max_accel_m_s2`` in microsteps per second squared."""
        return self.max_accel_m_s2.value * self.microsteps_per_m

    @property
    def home_rate_hz(self) -> float:
        """``home_speed_m_s`` as a step rate."""
        return self.home_speed_m_s.value * self.microsteps_per_m

    def image_scale(self, camera_magnification: float) -> float:
        """Image displacement on the focal plane per metre of stage position.

        Linear: the carriage moves the target, the optics image it at ``camera_magnification``
        (docs/physics.md §6: ``v_image = m v_stage``). Turntable: the sensor rides on the table, so
        the image moves at the arc speed at ``radius_m`` (docs/physics.md §2 eq 5: ``v_image = w l``)
        and the scale is 1 whatever the magnification. Image rows = ``image_scale * x / p``.
        """
        return float(camera_magnification) if self.is_linear else 1.0


# -- loading ------------------------------------------------------------------------------------


def stages_dir() -> Path:
    """The directory of the shipped stage profiles, ``config/stages``."""
    return config_dir() / "stages"


def list_stage_profiles() -> list[str]:
    """Names of the shipped stage profiles."""
    return _STAGES.names()


def load_stage_profile(name_or_path: str | Path) -> StageProfile:
    """Load and validate a stage profile by name (``linear_rail``) or by ``.toml`` path."""
    return _STAGES.find(name_or_path)


_STAGES = DataFileKind(StageProfile, StageProfileError, folder=stages_dir, noun="stage profile")
