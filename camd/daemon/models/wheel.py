"""Bodies of the filter wheel's routes (docs/wheel.md)."""

from __future__ import annotations

from pydantic import BaseModel, Field

from camd.daemon.models.common import _Request
from camd.daemon.models.stream import StreamResponse


class WheelChannelInfo(BaseModel):
    """One channel of the wheel (config/wheel.toml)."""

    channel: int = Field(description="index, 0 .. channel_count - 1")
    name: str
    band: str
    centre_deg: float = Field(description="wheel angle of the channel centre")
    polarizer_deg: float | None = Field(
        description="transmission axis of its polariser when centred; null: no polariser"
    )


class WheelExposureInfo(BaseModel):
    """camd's computation for one exposure through the wheel (docs/physics.md §4 eqs 1, 4-6, 8)."""

    exposure_s: float = Field(description="T_exp = n T_line")
    exposure_lines: int = Field(description="n")
    window_rows: int = Field(description="k")
    line_period_s: float = Field(description="T_line")
    frame_time_s: float = Field(description="T_frame = (n + k + 1) T_line (eq 6)")
    delay_s: float = Field(
        description="T_delay = T_center - T_frame / 2 (eq 5), negative when it cannot be centred"
    )
    compensated: bool = Field(description="whether the delay is applied")
    fits: bool = Field(description="the frame fits the light window (and T_delay >= 0 if on)")
    refusal: str | None = Field(description="why it does not fit, with the numbers; else null")
    applied_delay_s: float | None = Field(
        description="delay waited after each entry pulse: T_delay on, 0 off; null if no fit"
    )
    centre_offset_deg: float | None = Field(
        description="imaging centre minus channel centre (eq 4; eq 1 without compensation)"
    )
    centre_error_deg: float | None = Field(description="its uncertainty (eq 8)")


class WheelStatus(BaseModel):
    """GET /api/v1/wheel and the answers of PUT /wheel/speed and /wheel/compensation."""

    wheel: str = Field(description="config/wheel.toml's wheel name")
    speed_deg_s: float = Field(description="angular speed now (0: stopped)")
    nominal_speed_deg_s: float = Field(description="the wheel file's w, for which T_center holds")
    period_s: float | None = Field(description="time per revolution; null when stopped")
    angle_deg: float = Field(description="wheel angle from channel 0's centre, 0 .. 360")
    channel: int | None = Field(description="channel whose light window is in front; else null")
    compensation: bool = Field(description="exposure delay compensation on")
    t_center_s: float = Field(description="entry pulse to channel centre")
    window_s: float = Field(description="light window of a channel")
    device_frame_time_s: float = Field(description="T_frame as the FPGA computes it")
    device_delay_s: float = Field(description="T_delay as the FPGA computes it")
    exposure: WheelExposureInfo = Field(description="camd's numbers for the registers now")
    channels: list[WheelChannelInfo]
    time_s: float = Field(description="device time of the reading")


class WheelSpeedRequest(_Request):
    """PUT /api/v1/wheel/speed."""

    speed_deg_s: float = Field(ge=0.0, le=360.0, description="angular speed, deg/s; 0 stops")


class WheelCompensationRequest(_Request):
    """PUT /api/v1/wheel/compensation."""

    on: bool = Field(description="exposure delay compensation on (true) or off (false)")


class WheelRegion(_Request):
    """A rectangle of the frame whose mean is reported (rows and columns from 0)."""

    row: int = Field(default=0, ge=0, le=4095, description="first row")
    rows: int = Field(ge=1, le=4096, description="rows")
    col: int = Field(default=0, ge=0, le=4095, description="first column")
    cols: int = Field(ge=1, le=4096, description="columns")


class WheelAcquireRequest(_Request):
    """POST /api/v1/wheel/acquire: one frame per channel per pass (docs/wheel.md)."""

    channels: list[int] = Field(
        min_length=1, max_length=13, description="channels in acquisition order, 0 .. 12"
    )
    passes: int = Field(default=1, ge=1, le=1000, description="times through the channel list")
    exposure_s: float | None = Field(
        default=None,
        gt=0.0,
        le=30.0,
        description="set this exposure first (whole lines: round(T_exp / T_line)); null keeps "
        "the registers'",
    )
    compensated: bool | None = Field(
        default=None, description="set compensation first; null keeps the wheel's setting"
    )
    record: str | None = Field(
        default=None,
        description="new HDF5 file for the frames, on the daemon's host: relative = in "
        "<data_dir>/recordings; absolute = inside the data directory or daemon.record_dirs "
        "(docs/api.md, Files); null: none",
    )
    region: WheelRegion | None = Field(
        default=None, description="report the mean of this region; null: of the whole frame"
    )
    timeout_s: float | None = Field(
        default=None,
        gt=0,
        le=86_400,
        description="give up after this long (default: twice a revolution per frame + 10 s)",
    )


class WheelFrame(BaseModel):
    """One frame of a wheel acquisition."""

    counter: int = Field(description="frame counter")
    channel: int
    name: str = Field(description="channel name")
    start_angle_deg: float = Field(
        description="wheel angle at the exposure start, from the frame header (1e-4 deg)"
    )
    centre_deg: float = Field(
        description="predicted imaging-centre angle: channel centre + centre_offset_deg"
    )
    centre_offset_deg: float = Field(description="imaging centre minus channel centre (eq 4)")
    centre_error_deg: float = Field(description="uncertainty of the imaging centre (eq 8)")
    header_centre_deg: float = Field(
        description="imaging centre from the header: start angle + w T_frame / 2"
    )
    mean: float = Field(description="mean signal of the frame (or region), DN")
    timestamp_s: float = Field(description="device time at the end of row 0's exposure")


class WheelAcquireResponse(BaseModel):
    """POST /api/v1/wheel/acquire: per frame, where it was taken and its mean signal."""

    channels: list[int]
    passes: int
    speed_deg_s: float = Field(description="wheel speed during the acquisition")
    exposure: WheelExposureInfo = Field(description="the exposure the frames were taken with")
    device_frame_time_s: float | None = Field(
        description="T_frame as the FPGA computes it (WHEEL_GET after the frames; null if unread)"
    )
    device_delay_s: float | None = Field(
        description="delay the FPGA applies after each entry pulse (0 with compensation off)"
    )
    region: WheelRegion | None
    frames: list[WheelFrame] = Field(description="the frames received, in order")
    stream: StreamResponse = Field(description="the stream document: counters, recording")
