"""Camera profiles as data: ``config/profiles/<name>.toml``, validated by pydantic.

A profile holds the physical facts the simulated camera needs about one camera (docs/physics.md §8):
array size, pitch, fill factor, shutter, ADC and output bits, readout rate, full well,
conversion gain and ADC full scale (hence the system gain), read noise, dark current and its
temperature law, fixed-pattern noise, quantum efficiency, black level, optics magnification,
and how the sensor's gain register maps to an analogue gain factor. ``sensor`` names the
register map (``config/sensors/<sensor>.toml``) the camera's sensor carries.

Every physical value is an inline table with its provenance, exactly one of ``source`` (where
the number comes from) or ``assumed`` (why this value was chosen)::

    pitch_m = { value = 11e-6, source = "YE23 §3.2 / docs/physics.md §8" }
    fill_factor = { value = 0.8, assumed = "sCMOS with microlenses; no paper gives it" }

A file that does not validate raises ``ProfileError`` naming the file, the line of the key and
what to change, e.g.::

    config/profiles/hr400.toml:14: pitch_m: give exactly one of `source` (where the value comes
    from) or `assumed` (why it was chosen), not both
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from camd.analysis.sensor_noise import system_gain_dn_per_e
from camd.datafile import (
    Count,
    DataFileError,
    DataFileKind,
    KeyedError,
    NonNegative,
    Positive,
    Sourced,
    unit_of,
)
from camd.datafile import physical as _key
from camd.paths import config_dir
from camd.sensor.regmap import (
    FieldSpec,
    RegisterMap,
    RegisterMapError,
    RegisterSpec,
    load_register_map,
)
from camd.timing import rolling_line_period_s

Shutter = Literal["rolling", "global", "frame_transfer", "full_frame"]
SHUTTERS: tuple[str, ...] = ("rolling", "global", "frame_transfer", "full_frame")

Fraction = Annotated[float, Field(gt=0, le=1)]
SmallFraction = Annotated[float, Field(ge=0, lt=1)]
Bits = Annotated[int, Field(ge=1, le=16)]
Celsius = Annotated[float, Field(ge=-273.15)]


class ProfileError(DataFileError):
    """A profile file is invalid; the message starts with ``file:line:`` (or ``file:``)."""


class GainSpec(BaseModel):
    """How the gain role's value (``SensorModel.gain``) maps to an analogue gain factor.

    - ``table``: an enum label (or a raw value written as a string) -> factor, e.g.
      ``{ x1 = 1.0, x2 = 2.0 }``; every label of the register map's gain enum needs a factor.
    - ``code``: ``factor = (code mod 2^double_bit) / divisor``, doubled when bit ``double_bit``
      is set (the MT9M001's coding); ``table`` entries (keys ``"0x61"`` etc.) override codes.
    - ``db``: ``factor = 10^((db_at_zero + db_per_code * code) / 20)``, a PGA linear in dB.
    """

    model_config = ConfigDict(extra="forbid", frozen=True, strict=True)

    kind: Literal["table", "code", "db"] = Field(description="table, code or db (see above)")
    table: dict[str, Positive] = Field(
        default_factory=dict,
        description='table: label -> factor; code: code (as a string, e.g. "0x61") -> factor',
    )
    divisor: Positive | None = Field(default=None, description="code: factor = code / divisor")
    double_bit: int | None = Field(
        default=None, ge=0, le=15, description="code: this bit doubles the factor (absent: none)"
    )
    db_per_code: float | None = Field(default=None, description="db: gain step per code, dB")
    db_at_zero: float = Field(default=0.0, description="db: gain at code 0, dB")
    source: str | None = Field(default=None, description="where the coding comes from")
    assumed: str | None = Field(default=None, description="why the coding was chosen")

    @model_validator(mode="after")
    def _check(self) -> GainSpec:
        given = [k for k in ("source", "assumed") if (getattr(self, k) or "").strip()]
        if len(given) != 1:
            raise ValueError(
                "give exactly one of `source` (where the coding comes from) or `assumed` "
                "(why it was chosen)"
            )
        if self.kind == "table" and not self.table:
            raise ValueError('kind = "table" needs `table = { label = factor, ... }`')
        if self.kind == "code":
            if self.divisor is None:
                raise ValueError('kind = "code" needs `divisor` (factor = code / divisor)')
            for key in self.table:
                if _code_key(key) is None:
                    raise ValueError(
                        f'kind = "code": table key {key!r} is not a code; write e.g. "0x61"'
                    )
        if self.kind == "db" and self.db_per_code is None:
            raise ValueError('kind = "db" needs `db_per_code`')
        return self

    @property
    def provenance(self) -> str:
        return f"source: {self.source}" if self.source else f"assumed: {self.assumed}"

    def factor(self, setting: int | str | None) -> float:
        """The analogue gain factor for the gain role's value (``None``: no gain role, 1.0)."""
        if setting is None:
            return 1.0
        if self.kind == "table":
            key = setting if isinstance(setting, str) else str(setting)
            if key not in self.table:
                known = ", ".join(self.table)
                raise ValueError(f"gain setting {setting!r} has no factor; known: {known}")
            return self.table[key]
        if isinstance(setting, str):
            raise ValueError(f"gain setting {setting!r} is a label; kind {self.kind} needs a code")
        if self.kind == "code":
            for key, factor in self.table.items():
                if _code_key(key) == setting:
                    return factor
            assert self.divisor is not None  # checked by the validator
            if self.double_bit is None:
                return setting / self.divisor
            mantissa = setting & ((1 << self.double_bit) - 1)
            doubled = 2.0 if setting >> self.double_bit & 1 else 1.0
            return doubled * mantissa / self.divisor
        assert self.db_per_code is not None  # checked by the validator
        return float(10.0 ** ((self.db_at_zero + self.db_per_code * setting) / 20.0))


def _code_key(key: str) -> int | None:
    try:
        return int(key, 0)
    except ValueError:
        return None


class CameraProfile(BaseModel):
    """One camera's physical facts, as loaded from ``config/profiles/<name>.toml``."""

    model_config = ConfigDict(extra="forbid", frozen=True, strict=True)

    profile: str = Field(pattern=r"^[a-z0-9][a-z0-9_]*$", description="profile name (file stem)")
    description: str = Field(default="", description="one line on the camera")
    sensor: str = Field(
        pattern=r"^[a-z0-9][a-z0-9_]*$",
        description="register map of the camera's sensor (config/sensors/<sensor>.toml)",
    )
    columns: Sourced[Count] = _key("pixel array columns N (across track)", "pixel")
    rows: Sourced[Count] = _key("pixel array rows (along track)", "pixel")
    pitch_m: Sourced[Positive] = _key("pixel pitch p", "m")
    fill_factor: Sourced[Fraction] = _key(
        "photosensitive fraction of the pixel area; the aperture is a centred square of side "
        "sqrt(fill_factor) pitches",
        "1",
    )
    shutter: Sourced[Shutter] = _key(
        "rolling (row i ends its exposure i line periods after row 0), global, "
        "frame_transfer or full_frame (all rows expose together; a full-frame CCD may clock "
        "its charge along the columns during the exposure, docs/imc.md)",
        "",
    )
    adc_bits: Sourced[Bits] = _key("ADC resolution", "bit")
    output_bits: Sourced[Bits] = _key("bits per pixel sent on (the ADC's MSBs)", "bit")
    pixel_rate_hz: Sourced[Positive] = _key(
        "pixel readout rate f_s (docs/physics.md §2 eq 4)", "Hz"
    )
    row_blanking_s: Sourced[NonNegative] = _key("row blanking t_rb (docs/physics.md §2 eq 4)", "s")
    full_well_e: Sourced[Positive] = _key("full-well capacity", "e-")
    conversion_gain_uv_per_e: Sourced[Positive] = _key(
        "charge-to-voltage conversion gain at analogue gain 1", "uV/e-"
    )
    adc_full_scale_v: Sourced[Positive] = _key("ADC input full scale", "V")
    read_noise_e: Sourced[NonNegative] = _key(
        "temporal read noise (everything but shot noise and quantisation)", "e- rms"
    )
    dark_current_e_per_s: Sourced[NonNegative] = _key(
        "mean dark current at dark_reference_temp_degc", "e-/s"
    )
    dark_reference_temp_degc: Sourced[Celsius] = _key(
        "temperature at which dark_current_e_per_s and dsnu_e_per_s hold", "degC"
    )
    dark_doubling_temp_degc: Sourced[Positive] = _key(
        "temperature rise that doubles the dark current", "degC"
    )
    dsnu_e_per_s: Sourced[NonNegative] = _key(
        "dark signal non-uniformity: rms over pixels of the dark current", "e-/s rms"
    )
    prnu_fraction: Sourced[SmallFraction] = _key(
        "photo-response non-uniformity: rms over pixels of the relative response", "1 rms"
    )
    quantum_efficiency: Sourced[Fraction] = _key(
        "electrons per photon reaching the photosensitive area", "e-/photon"
    )
    black_level_dn: Sourced[NonNegative] = _key(
        "output of a dark pixel with the offset register at 0", "DN (ADC)"
    )
    offset_dn_per_code: Sourced[NonNegative] = _key(
        "black level added per step of the sensor's offset role", "DN (ADC)"
    )
    magnification: Sourced[Positive] = _key(
        "optics magnification, image size / object size (v_image = magnification * v_stage)",
        "1",
    )
    analog_gain: GainSpec = Field(
        description="gain role value -> analogue gain factor (table [analog_gain])"
    )

    @model_validator(mode="after")
    def _check(self) -> CameraProfile:
        if self.output_bits.value > self.adc_bits.value:
            raise KeyedError(
                "output_bits",
                f"output_bits {self.output_bits.value} exceeds adc_bits {self.adc_bits.value}; "
                "the output keeps the ADC's most significant bits, so lower output_bits",
            )
        return self

    # -- derived values ---------------------------------------------------------------------------

    @classmethod
    def physical_keys(cls) -> list[str]:
        """The keys that hold a ``Sourced`` value, in declaration order."""
        return [name for name in cls.model_fields if cls.unit_of(name) is not None]

    @classmethod
    def unit_of(cls, key: str) -> str | None:
        """The unit of a physical key ("" for a label or pure number), None for other keys."""
        return unit_of(cls, key)

    def sourced(self, key: str) -> Sourced[Any]:
        """The ``Sourced`` entry of a physical key."""
        entry = getattr(self, key)
        if not isinstance(entry, Sourced):
            raise KeyError(f"{key} is not a physical value of the profile")
        return entry

    @property
    def aperture(self) -> float:
        """Side of the photosensitive square in pitches, ``q = sqrt(fill_factor)``."""
        return math.sqrt(self.fill_factor.value)

    @property
    def adc_max_dn(self) -> int:
        """The ADC's largest code, ``2^adc_bits - 1``."""
        return (1 << self.adc_bits.value) - 1

    @property
    def output_shift_bits(self) -> int:
        """ADC LSBs dropped on output (``adc_bits - output_bits``; 2 on the IBIS5)."""
        return self.adc_bits.value - self.output_bits.value

    def system_gain_dn_per_e(self, analog_gain: float = 1.0) -> float:
        """System gain ``K = g_conv * G / (V_FS / 2^adc_bits)`` in ADC DN per electron.

        docs/physics.md §5 (dark noise in electrons needs the system gain): conversion gain times
        analogue gain is volts per electron at the ADC; one DN is ``V_FS / 2^bits`` volts.
        """
        return system_gain_dn_per_e(
            self.conversion_gain_uv_per_e.value,
            analog_gain,
            self.adc_full_scale_v.value,
            self.adc_bits.value,
        )

    def analog_gain_factor(self, setting: int | str | None) -> float:
        """The analogue gain for a gain role value (``SensorModel.gain``), per ``analog_gain``."""
        return self.analog_gain.factor(setting)

    def black_level_for(self, offset_setting: int | str | None) -> float:
        """Black level in ADC DN for an offset role value: ``B0 + offset_dn_per_code * code``.

        A label (an enum offset) or no offset role gives ``black_level_dn`` alone.
        """
        code = offset_setting if isinstance(offset_setting, int) else 0
        return self.black_level_dn.value + self.offset_dn_per_code.value * code

    def line_period_s(self, n_pixels: int | None = None) -> float:
        """``T_line = t_rb + n_pixels / f_s`` from the profile's values (docs/physics.md §2 eq 4)."""
        pixels = self.columns.value if n_pixels is None else n_pixels
        return rolling_line_period_s(self.row_blanking_s.value, pixels, self.pixel_rate_hz.value)


# -- loading ----------------------------------------------------------------------------------------


def profiles_dir() -> Path:
    return config_dir() / "profiles"


def list_profiles() -> list[str]:
    """Names of the shipped camera profiles."""
    return _PROFILES.names()


def load_profile(name_or_path: str | Path) -> CameraProfile:
    """Load and validate a profile by name (``hr400``) or by file path.

    Also checks the profile against its sensor's register map: the map exists, the array
    sizes agree, and every label of the map's gain enum has a factor.
    """
    return _PROFILES.find(name_or_path)


def _check_against_map(profile: CameraProfile) -> None:
    try:
        regmap = load_register_map(profile.sensor)
    except (FileNotFoundError, RegisterMapError) as exc:
        raise KeyedError("sensor", f"{exc}; name a map in config/sensors/") from None
    for key, size in (("columns", regmap.columns), ("rows", regmap.rows)):
        value = profile.sourced(key).value
        if value != size:
            raise KeyedError(
                key,
                f"{value} differs from the {profile.sensor} register map's {key} = {size}; "
                "make them agree",
            )
    enum = _gain_enum(regmap)
    gain = profile.analog_gain
    field_spec = _gain_field(regmap)
    if (
        gain.kind == "db"
        and field_spec is not None
        and field_spec.unit == "dB"
        and not math.isclose(field_spec.scale, gain.db_per_code or 0.0, rel_tol=1e-9)
    ):
        raise KeyedError(
            ("analog_gain", "db_per_code"),
            f"db_per_code = {gain.db_per_code:g} but the {profile.sensor} gain field "
            f"{regmap.role('gain')} steps {field_spec.scale:g} dB per code; make them agree",
        )
    if enum is not None:
        if gain.kind != "table":
            raise KeyedError(
                "analog_gain",
                f"the {profile.sensor} gain role is an enum ({', '.join(enum)}): use "
                'kind = "table" with a factor per label',
            )
        missing = [label for label in enum if label not in gain.table]
        if missing:
            raise KeyedError(
                ("analog_gain", "table"),
                f"no factor for gain label(s) {', '.join(missing)} of the {profile.sensor} "
                "register map; add them to `table`",
            )
    elif regmap.role("gain") is not None and gain.kind == "table":
        raise KeyedError(
            "analog_gain",
            f'the {profile.sensor} gain role is a number, not an enum: use kind = "code" or "db"',
        )


def _gain_field(regmap: RegisterMap) -> FieldSpec | None:
    name = regmap.role("gain")
    if name is None:
        return None
    target, field_spec = regmap.resolve(name)
    if not isinstance(target, RegisterSpec):
        return None
    return field_spec if field_spec is not None else target.all_fields()[0]


def _gain_enum(regmap: RegisterMap) -> dict[str, int] | None:
    spec = _gain_field(regmap)
    return None if spec is None else spec.enum


_PROFILES = DataFileKind(
    CameraProfile,
    ProfileError,
    check=_check_against_map,
    folder=profiles_dir,
    noun="camera profile",
)
