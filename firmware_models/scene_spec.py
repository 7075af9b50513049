"""What a scene is, as text and as a checked model: ``SceneSpec`` (``"kind:key=value,..."``,
the built-in kinds and their keys, the file:line-free errors of a bad spec), and the photometry a
level in lux needs (``lux_to_photons_per_pixel_s``). ``firmware_models.scene`` renders it; the
kinds themselves are described there.
"""

from __future__ import annotations

import math
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from firmware_models.spec_text import key_values

PLANCK_J_S = 6.62607015e-34
SPEED_OF_LIGHT_M_S = 299_792_458.0
PEAK_LUMINOUS_EFFICACY_LM_PER_W = 683.0
EQUIVALENT_WAVELENGTH_M = 555e-9

BAR_FREQUENCIES_CY_PER_PX = (0.05, 0.1, 0.2, 0.25, 0.3, 0.4, 0.5)
"""Spatial frequencies of the bar groups, up to Nyquist (0.5 cycles per pixel)."""

BAR_BAND_ROWS = 32
"""Rows of one group's band in the ``across`` orientation of the bar target."""


def lux_to_photons_per_pixel_s(
    lux: float, pitch_m: float, wavelength_m: float = EQUIVALENT_WAVELENGTH_M
) -> float:
    """Photons per pixel per second for a focal-plane illuminance, at one equivalent wavelength.

        N = E_v / 683 lm/W * lambda / (h c) * p^2

    ``E_v`` (lux = lm/m^2) over the peak luminous efficacy 683 lm/W is the irradiance in W/m^2
    of light at 555 nm (where 683 lm/W holds exactly); ``lambda / (h c)`` photons per joule;
    ``p^2`` the pixel area. Using this at another ``wavelength_m`` treats the light as if it
    had the luminous efficacy of 555 nm light: an equivalent, not a spectral model. 1 lux on
    an 11 um pixel is about 4.95e5 photons/s.
    """
    if not (lux >= 0.0 and pitch_m > 0.0 and wavelength_m > 0.0):
        raise ValueError(f"need lux >= 0, pitch_m > 0, wavelength_m > 0; got {lux}, {pitch_m}")
    irradiance_w_m2 = lux / PEAK_LUMINOUS_EFFICACY_LM_PER_W
    photons_per_j = wavelength_m / (PLANCK_J_S * SPEED_OF_LIGHT_M_S)
    return irradiance_w_m2 * photons_per_j * pitch_m**2


# -- the spec ---------------------------------------------------------------------------------------


class SceneSpecError(ValueError):
    """A scene text or value is invalid; the message names the key and what is allowed."""


SceneKind = Literal["flat", "bars", "edge", "star", "ramp", "natural", "image"]
SCENE_KINDS: tuple[str, ...] = ("flat", "bars", "edge", "star", "ramp", "natural", "image")

_COMMON = (
    "photons",
    "lux",
    "drift_deg",
    "blur_px",
    "magnification_error",
    "rotation_deg",
    "yaw_deg_per_m",
)
_KIND_KEYS: dict[str, tuple[str, ...]] = {
    "flat": _COMMON,
    "bars": (*_COMMON, "contrast", "oversample", "orientation", "period"),
    "edge": (
        *_COMMON,
        "contrast",
        "oversample",
        "angle_deg",
        "period",
        "x_oversample",
        "seed",
        "texture_cols",
    ),
    "star": (*_COMMON, "contrast", "oversample", "spokes", "size"),
    "ramp": (*_COMMON, "contrast", "oversample", "period"),
    "natural": (*_COMMON, "contrast", "period", "seed"),
    "image": (*_COMMON, "contrast", "path"),
}
_DEFAULT_PERIOD_ROWS = {"bars": 40, "edge": 64, "ramp": 256, "natural": 256}


class SceneSpec(BaseModel):
    """What to show: a built-in target or an image file, its level, contrast and drift.

    Text form (``parse`` / ``describe``): ``kind`` or ``kind:key=value,key=value``, e.g.
    ``bars:lux=3,contrast=0.8,drift_deg=0.5``. Keys that do not apply to the kind are refused.
    Without ``photons`` or ``lux`` the camera chooses a moderate level.
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    kind: SceneKind = Field(
        default="flat", description="flat, bars, edge, star, ramp, natural or image"
    )
    photons: float | None = Field(
        default=None, gt=0, le=1e13, description="bright level, photons per pixel per second"
    )
    lux: float | None = Field(
        default=None, gt=0, le=1e7, description="bright level as focal-plane illuminance, lux"
    )
    contrast: float = Field(
        default=1.0, ge=0, le=1, description="Michelson contrast of the target's pattern"
    )
    drift_deg: float = Field(
        default=0.0,
        ge=-45,
        le=45,
        description="drift angle: the image moves tan(drift) columns per row along track",
    )
    blur_px: float = Field(
        default=0.0,
        ge=0,
        le=64,
        description="Gaussian sigma of the optics' blur in pixels (0: best focus), applied to "
        "the scene's radiance so that every acquisition sees it",
    )
    # The image motion errors the encoder cannot see (firmware_models.image_errors; the
    # limits are that module's): keys of the scene, like drift_deg, so that one spec says
    # where the image goes.
    magnification_error: float = Field(
        default=0.0,
        ge=-0.1,
        le=0.1,
        description="the optics' magnification error e: the image moves (1 + e) times as far "
        "as the encoder's travel at the nominal magnification",
    )
    rotation_deg: float = Field(
        default=0.0,
        ge=-10,
        le=10,
        description="camera rotation about the optical axis: tan(rotation) columns across "
        "track per row of along-track motion",
    )
    yaw_deg_per_m: float = Field(
        default=0.0,
        ge=-100,
        le=100,
        description="stage yaw: the direction of travel turns this much per metre of travel",
    )
    oversample: int = Field(
        default=4, ge=1, le=16, description="cells per pixel along and across track"
    )
    x_oversample: int | None = Field(
        default=None,
        ge=1,
        le=16,
        description="edge: cells per pixel across track (default: oversample); 1 makes each "
        "column a 1-D edge at its centre and keeps fine cells along track cheap",
    )
    texture_cols: int = Field(
        default=0,
        ge=0,
        le=65536,
        description="edge: the central columns that show the natural texture (seed `seed`) "
        "instead of edges, for the image motion monitor: a straight edge shows only the motion "
        "across it (0: none)",
    )
    period: int | None = Field(
        default=None,
        ge=2,
        le=65536,
        description="along-track period in rows (bars 40, edge 64, ramp 256, natural 256)",
    )
    orientation: Literal["along", "across"] = Field(
        default="along",
        description="bars: along = bars vary along track (groups across the columns); "
        "across = bars vary across track (groups in bands along track)",
    )
    angle_deg: float = Field(
        default=5.0, gt=-45, lt=45, description="edge: angle of the edge to the rows"
    )
    spokes: int = Field(default=36, ge=4, le=720, description="star: number of spoke pairs")
    size: int = Field(default=256, ge=16, le=4096, description="star: tile size in pixels")
    path: str | None = Field(default=None, description="image: greyscale image file (cv2)")
    seed: int = Field(
        default=1,
        ge=0,
        le=2**32 - 1,
        description="natural, edge texture_cols: the texture's random seed",
    )

    @model_validator(mode="after")
    def _check(self) -> SceneSpec:
        if self.photons is not None and self.lux is not None:
            raise ValueError("give the level as photons or lux, not both")
        allowed = set(_KIND_KEYS[self.kind]) | {"kind"}
        for key in self.model_fields_set - allowed:
            raise ValueError(
                f"key {key!r} does not apply to a {self.kind} scene; "
                f"keys for {self.kind}: {', '.join(_KIND_KEYS[self.kind])}"
            )
        if self.kind == "image" and not self.path:
            raise ValueError("an image scene needs path=FILE")
        if self.kind == "bars" and self.orientation == "along":
            period = self.period_rows
            for f in BAR_FREQUENCIES_CY_PER_PX:
                if not math.isclose(period * f, round(period * f), abs_tol=1e-9):
                    raise ValueError(
                        f"bars: period {period} rows holds no whole number of cycles at "
                        f"{f} cy/pixel; use a multiple of 20 rows"
                    )
        return self

    @property
    def period_rows(self) -> int:
        """The along-track period the kind uses (explicit ``period`` or the kind's default)."""
        if self.period is not None:
            return self.period
        if self.kind == "bars" and self.orientation == "across":
            return BAR_BAND_ROWS * len(BAR_FREQUENCIES_CY_PER_PX)
        if self.kind == "star":
            return self.size
        return _DEFAULT_PERIOD_ROWS.get(self.kind, 1)

    @classmethod
    def known_keys(cls, kind: str | None = None) -> list[str]:
        """The keys ``parse`` accepts (for one kind, or all)."""
        if kind is None:
            return [k for k in cls.model_fields if k != "kind"]
        return list(_KIND_KEYS[kind])

    @classmethod
    def parse(cls, text: str) -> SceneSpec:
        """Parse ``"bars:lux=3,contrast=0.8"``; a blank text is the default (flat) scene.

        Raises SceneSpecError naming the kind or key at fault and what is allowed.
        """
        text = text.strip()
        if not text:
            return cls()
        kind, sep, rest = text.partition(":")
        kind = kind.strip()
        if not sep and "=" in kind:
            raise SceneSpecError(
                f"scene {text!r} has no kind; write e.g. 'bars:lux=3' "
                f"(kinds: {', '.join(SCENE_KINDS)})"
            )
        if kind not in SCENE_KINDS:
            raise SceneSpecError(f"unknown scene kind {kind!r}; kinds: {', '.join(SCENE_KINDS)}")
        values: dict[str, Any] = {"kind": kind}
        items = key_values(
            rest,
            what="scene",
            example=f"{kind}:photons=1e6",
            keys_note=f"keys for {kind}: {', '.join(_KIND_KEYS[kind])}",
            error=SceneSpecError,
        )
        for key, raw in items:
            if key not in _KIND_KEYS[kind]:
                raise SceneSpecError(
                    f"unknown scene key {key!r} for {kind}; keys for {kind}: "
                    f"{', '.join(_KIND_KEYS[kind])}"
                )
            values[key] = raw
        try:
            return cls.model_validate(values)
        except ValidationError as exc:
            raise SceneSpecError(_describe_error(exc, values)) from None

    def describe(self) -> str:
        """The spec as text that ``parse`` reads back (only keys that differ from defaults)."""
        parts = []
        for key in _KIND_KEYS[self.kind]:
            value = getattr(self, key)
            if value == type(self).model_fields[key].default:
                continue
            parts.append(f"{key}={value:g}" if isinstance(value, float) else f"{key}={value}")
        return self.kind + (":" + ",".join(parts) if parts else "")


def _describe_error(exc: ValidationError, values: dict[str, Any]) -> str:
    first = exc.errors()[0]
    loc = [str(part) for part in first["loc"]]
    message = str(first["msg"]).removeprefix("Value error, ")
    if not loc:
        return f"scene: {message}"
    key = loc[0]
    info = SceneSpec.model_fields.get(key)
    meaning = f" ({info.description})" if info is not None and info.description else ""
    return f"scene {key}={values.get(key)!s} is invalid: {key}{meaning}: {message}"


# -- the scene --------------------------------------------------------------------------------------
