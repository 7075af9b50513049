"""The filter wheel as data: ``config/wheel.toml``, validated by pydantic.

docs/physics.md §4 [YE23 §3.1, §3.3, §4]: 13 channels on a wheel turning at constant ``w``
(73.245 deg/s), an entry-point pulse ``T_center`` = 60 ms before each channel centre, a light
window of 120 ms per channel, three polarising channels 60 deg apart, and the error sources of
eq 8 (entry angle, speed, clock stability). The daemon (wheel sequencing) and the simulated
wheel (``firmware_models.wheel``) read the same file, so this module imports only pydantic, the
standard library, ``camd.paths`` and ``camd.timing``.

Every physical value is an inline table with its provenance, exactly one of ``source`` (where
the number comes from) or ``assumed`` (why this value was chosen)::

    speed_deg_s = { value = 73.245, source = "YE23 §4 / docs/physics.md §4" }

Channel centres are equally spaced (``centres = "equal"``: channel ``i`` at ``i * 360 / N``
deg, channel 0 at 0 deg, the origin of wheel angles). The window and the entry pulse are times
at ``speed_deg_s``; on the wheel they are the angles ``window_half_angle_deg`` and
``entry_lead_deg``. A file that does not validate raises ``WheelProfileError`` naming the file,
the line of the key and what to change.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from camd.datafile import (
    Count,
    DataFileError,
    DataFileKind,
    KeyedError,
    NonNegative,
    Positive,
    Sourced,
)
from camd.paths import config_dir
from camd.timing.wheel import WheelExposure, wheel_exposure

AxisDeg = Annotated[float, Field(ge=0, lt=180)]
Stability = Annotated[float, Field(ge=0, lt=1)]


class WheelProfileError(DataFileError):
    """A wheel file is invalid; the message starts with ``file:line:`` (or ``file:``)."""


class WheelChannel(BaseModel):
    """One channel of the wheel: a name, its band, and a polariser axis if it has one."""

    model_config = ConfigDict(extra="forbid", frozen=True, strict=True)

    name: str = Field(pattern=r"^[A-Za-z0-9][A-Za-z0-9_.-]*$", description="channel name")
    band: Sourced[str] = Field(description="band / filter, as text")
    polarizer_deg: Sourced[AxisDeg] | None = Field(
        default=None,
        description="transmission axis of the channel's linear polariser when the channel is "
        "centred, 0 <= deg < 180 (absent: no polariser)",
    )

    @property
    def polarizing(self) -> bool:
        return self.polarizer_deg is not None


class WheelProfile(BaseModel):
    """The filter wheel, as loaded from ``config/wheel.toml`` (docs/physics.md §4)."""

    model_config = ConfigDict(extra="forbid", frozen=True, strict=True)

    wheel: str = Field(pattern=r"^[a-z0-9][a-z0-9_]*$", description="wheel name")
    description: str = Field(default="", description="one line on the wheel")
    channel_count: Sourced[Count] = Field(description="channels on the wheel (13)")
    centres: Sourced[Literal["equal"]] = Field(
        description='"equal": channel i centred at i * 360 / channel_count deg'
    )
    speed_deg_s: Sourced[Positive] = Field(description="nominal angular speed w, deg/s")
    t_center_s: Sourced[Positive] = Field(
        description="T_center: entry pulse to channel centre at speed_deg_s, s"
    )
    window_s: Sourced[Positive] = Field(
        description="light window of a channel at speed_deg_s, centred on its centre, s"
    )
    entry_angle_error_deg: Sourced[NonNegative] = Field(
        description="dP_entry of eq 8: wheel angle error at the entry pulse, deg"
    )
    speed_error_deg_s: Sourced[NonNegative] = Field(description="dw of eq 8, deg/s")
    clock_stability: Sourced[Stability] = Field(
        description="relative clock stability; dT_center = clock_stability * T_center"
    )
    channels: list[WheelChannel] = Field(description="the channels in wheel order")

    @model_validator(mode="after")
    def _check(self) -> WheelProfile:
        count = self.channel_count.value
        if len(self.channels) != count:
            raise KeyedError(
                "channel_count",
                f"channel_count is {count} but {len(self.channels)} [[channels]] tables are "
                "given; make them agree",
            )
        names = [c.name for c in self.channels]
        repeated = sorted({n for n in names if names.count(n) > 1})
        if repeated:
            raise KeyedError(
                "channels", f"channel names must be unique; repeated: {', '.join(repeated)}"
            )
        aperture = 2.0 * self.window_half_angle_deg
        if aperture >= self.spacing_deg:
            raise KeyedError(
                "window_s",
                f"the light window speed_deg_s * window_s = {self.speed_deg_s.value:g} deg/s x "
                f"{self.window_s.value:g} s = {aperture:.6g} deg is not narrower than the "
                f"channel spacing 360 / {count} = {self.spacing_deg:.6g} deg, so neighbouring "
                "windows would overlap; shorten window_s",
            )
        return self

    # -- derived values ---------------------------------------------------------------------------

    @property
    def spacing_deg(self) -> float:
        """Angle between neighbouring channel centres, ``360 / channel_count``."""
        return 360.0 / self.channel_count.value

    @property
    def window_half_angle_deg(self) -> float:
        """Half the light window as a wheel angle, ``w window / 2`` (4.3947 deg on YE23)."""
        return self.speed_deg_s.value * self.window_s.value / 2.0

    @property
    def entry_lead_deg(self) -> float:
        """Wheel angle from the entry point to the channel centre, ``w T_center`` (4.3947 deg)."""
        return self.speed_deg_s.value * self.t_center_s.value

    @property
    def t_center_error_s(self) -> float:
        """``dT_center = clock_stability * T_center`` of eq 8 (1.2 us on YE23)."""
        return self.clock_stability.value * self.t_center_s.value

    @property
    def polarizing_channels(self) -> tuple[int, ...]:
        """Indices of the channels that carry a polariser."""
        return tuple(i for i, c in enumerate(self.channels) if c.polarizing)

    def check_channel(self, channel: int) -> int:
        """``channel`` if it is a valid channel index, else a ValueError saying the range."""
        if isinstance(channel, bool) or not isinstance(channel, int):
            raise ValueError(f"channel must be an integer, got {channel!r}")
        if not 0 <= channel < self.channel_count.value:
            raise ValueError(
                f"channel {channel} does not exist: the {self.wheel} wheel has channels "
                f"0 .. {self.channel_count.value - 1}"
            )
        return channel

    def centre_deg(self, channel: int) -> float:
        """Wheel angle of a channel's centre, ``channel * 360 / channel_count`` (0 <= deg < 360)."""
        return self.check_channel(channel) * self.spacing_deg

    def exposure(self, frame_time_s: float, *, compensated: bool) -> WheelExposure:
        """``camd.timing.wheel.wheel_exposure`` with this wheel's values (docs/physics.md §4).

        Refuses a frame that does not fit the light window (and, compensated, T_delay < 0).
        """
        return wheel_exposure(
            frame_time_s,
            speed_deg_s=self.speed_deg_s.value,
            t_center_s=self.t_center_s.value,
            window_s=self.window_s.value,
            compensated=compensated,
            entry_angle_error_deg=self.entry_angle_error_deg.value,
            speed_error_deg_s=self.speed_error_deg_s.value,
            clock_stability=self.clock_stability.value,
        )


# -- loading ----------------------------------------------------------------------------------------


def default_wheel_path() -> Path:
    """``config/wheel.toml`` of the shipped config."""
    return config_dir() / "wheel.toml"


def load_wheel_profile(path: Path | str | None = None) -> WheelProfile:
    """Load and validate the wheel file (``config/wheel.toml`` when ``path`` is None)."""
    file = default_wheel_path() if path is None else Path(path)
    try:
        return _WHEEL.shipped(file) if path is None else _WHEEL.load(file)
    except FileNotFoundError:
        raise FileNotFoundError(
            f"no wheel file {file}; give the path of a wheel TOML file (see config/wheel.toml)"
        ) from None


_WHEEL = DataFileKind(WheelProfile, WheelProfileError)
