"""The config's sections about the camera: [link], [sim], [sensor], [stream], [stage], [motion]
and [telemetry] with its channel limits.

camd/daemon/config.py assembles them into ``Config``; docs/config.md lists every key.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any, Literal

from pydantic import Field, StrictFloat, field_validator, model_validator

from camd.daemon.config_sections import Section
from camd.protocol import load_dictionary
from camd.sensor.profile import list_profiles
from camd.sensor.regmap import list_sensors

HOUSEKEEPING_PACKET = "HOUSEKEEPING"
"""The telemetry packet whose channels the limits apply to."""

BackendChoice = Literal["auto", "sim", "libusb"]
"""How a USB device of the camera (the frame stream, the USB-SPI bridge) is reached: "auto"
follows the command link (the simulator's with ``link.device = "sim"``, else real hardware)."""
UsbBackend = Literal["sim", "libusb"]


class LinkSection(Section):
    """[link]: the RS-422 command link."""

    device: str = Field(
        default="sim",
        min_length=1,
        description="'sim' (spawn the simulated camera) or a serial device path / pyserial URL",
    )
    baudrate: int = Field(default=921_600, gt=0, le=20_000_000, description="line rate, bit/s")
    timeout_s: float = Field(default=0.1, gt=0, le=60, description="wait for each attempt")
    retries: int = Field(default=5, ge=0, le=100, description="re-sends after a timeout")
    reconnect_min_s: float = Field(default=0.1, gt=0, le=60, description="first reopen backoff")
    reconnect_max_s: float = Field(default=2.0, gt=0, le=600, description="longest reopen backoff")

    @model_validator(mode="after")
    def _backoff_order(self) -> LinkSection:
        if self.reconnect_min_s > self.reconnect_max_s:
            raise ValueError(
                f"reconnect_min_s ({self.reconnect_min_s}) is above reconnect_max_s "
                f"({self.reconnect_max_s}); make reconnect_min_s <= reconnect_max_s"
            )
        return self


class SimSection(Section):
    """[sim]: the simulated camera spawned when ``link.device = "sim"``."""

    inject: str = Field(
        default="", description="line faults, e.g. 'ber=1e-4,drop=0.01'; empty = perfect line"
    )
    hk_period_s: float = Field(
        default=1.0, gt=0, le=3600, description="period of unsolicited housekeeping"
    )
    seed: int = Field(default=0, ge=0, description="random seed of the simulator (noise, faults)")
    link_retries: int = Field(
        default=20,
        ge=0,
        le=100,
        description="re-sends of a command to the simulated camera, in place of link.retries: "
        "a process on this host, which a busy host holds back for hundreds of milliseconds",
    )
    profile: str = Field(
        default="hr400", pattern=r"^[a-z0-9_]+$", description="camera profile to simulate"
    )

    @field_validator("profile", mode="after")
    @classmethod
    def _known_profile(cls, value: str) -> str:
        known = list_profiles()
        if value not in known:
            raise ValueError(
                f"no camera profile {value!r} (config/profiles/); give one of {', '.join(known)}"
            )
        return value

    scene: str = Field(
        default="",
        max_length=240,  # as the API's scene: a spec, not a payload for the simulator's argv
        description="scene in front of the simulated camera, e.g. 'bars:lux=3'; empty = the "
        "simulator's default flat field (docs/simulator.md lists the scene specs)",
    )
    defects: list[str] = Field(
        default_factory=list,
        description="deliberate defects of the simulated camera, to prove the conformance "
        "checks can fail (docs/conformance.md lists them and the checks each fails); empty = "
        "a conforming camera",
    )
    frame_bank: int = Field(
        default=0,
        ge=0,
        le=4096,
        description="render only the first K frames of each stream and replay them (fresh "
        "headers): line-rate throughput tests on machines too small to render in real time; "
        "0 = render every frame",
    )
    restart: bool = Field(
        default=True,
        description="restart the simulated camera when it dies (with backoff); false: leave it "
        "dead, `camd sim --link PATH` reconnects one by hand",
    )
    restart_backoff_min_s: float = Field(
        default=0.5, gt=0, le=60, description="wait before the first restart; doubles per failure"
    )
    restart_backoff_max_s: float = Field(
        default=30.0, gt=0, le=3600, description="longest wait between restarts"
    )
    restart_stable_s: float = Field(
        default=60.0,
        gt=0,
        le=86400,
        description="a simulator up this long before it died was stable: the backoff and the "
        "count of failures in a row start afresh",
    )
    restart_limit: int = Field(
        default=5,
        ge=1,
        le=1000,
        description="restarts in a row (each simulator dying or failing to start within "
        "restart_stable_s) before the daemon gives up",
    )

    @model_validator(mode="after")
    def _restart_backoff_order(self) -> SimSection:
        if self.restart_backoff_min_s > self.restart_backoff_max_s:
            raise ValueError(
                f"restart_backoff_min_s ({self.restart_backoff_min_s}) is above "
                f"restart_backoff_max_s ({self.restart_backoff_max_s}); make "
                "restart_backoff_min_s <= restart_backoff_max_s"
            )
        return self


class UsbSpiSection(Section):
    """[sensor.usb_spi]: the USB-SPI bridge chip (MCP2210) used with ``sensor.bridge = "usb-spi"``."""

    backend: BackendChoice = Field(
        default="auto",
        description="'auto': as the command link ('sim' with link.device = 'sim', else "
        "'libusb'); 'sim': the simulated chip wired to the simulated camera's SPI bus; "
        "'libusb': real hardware through pyusb's default backend",
    )
    vendor_id: int = Field(default=0x04D8, ge=0, le=0xFFFF, description="USB vendor id")
    product_id: int = Field(default=0x00DE, ge=0, le=0xFFFF, description="USB product id")
    serial: str = Field(default="", description="USB serial number to pick one of several chips")
    cs_pin: int = Field(
        default=0, ge=0, le=8, description="MCP2210 GP pin wired to the sensor's CS"
    )


class SensorSection(Section):
    """[sensor]: the image sensor behind the FPGA and how its registers are reached."""

    name: str = Field(
        default="hr400",
        pattern=r"^[a-z0-9_]+$",
        description="register map config/sensors/<name>.toml; must match the camera's sensor",
    )
    bridge: Literal["fpga", "usb-spi"] = Field(
        default="fpga",
        description="'fpga': REG_* commands over the RS-422 link; 'usb-spi': a USB-SPI bridge",
    )
    train_on_connect: bool = Field(
        default=True, description="train the sensor's LVDS link whenever the camera (re)connects"
    )
    usb_spi: UsbSpiSection = Field(default_factory=UsbSpiSection)

    @field_validator("name", mode="after")
    @classmethod
    def _known_sensor(cls, value: str) -> str:
        known = list_sensors()
        if value not in known:
            raise ValueError(f"no register map for sensor {value!r}; known: {', '.join(known)}")
        return value


class StreamSection(Section):
    """[stream]: the USB bulk frame stream (docs/stream.md)."""

    backend: BackendChoice = Field(
        default="auto",
        description="'auto': as the command link ('sim' with link.device = 'sim', else "
        "'libusb'); 'sim': the simulated FX3 wired to the simulated camera's stream socket; "
        "'libusb': real hardware through pyusb's default backend",
    )
    vendor_id: int = Field(default=0x04B4, ge=0, le=0xFFFF, description="USB vendor id")
    product_id: int = Field(default=0x00F1, ge=0, le=0xFFFF, description="USB product id")
    queue_mb: float = Field(
        default=256.0,
        gt=0,
        le=65536,
        description="memory budget, MB (1e6 bytes), of the frames buffered between the reader "
        "and consumers; it is taken only while a consumer falls behind",
    )
    queue_frames: int = Field(
        default=4096,
        ge=2,
        le=65536,
        description="most frames buffered between the reader and consumers, whatever queue_mb "
        "would hold",
    )
    overflow: Literal["drop_newest", "drop_oldest"] = Field(
        default="drop_newest",
        description="when the queue is full: drop the arriving frame or the oldest queued one",
    )
    read_bytes: int = Field(
        default=0,
        ge=0,
        le=1 << 30,
        description="bytes per bulk read; 0 = one whole frame per read",
    )
    timeout_s: float = Field(
        default=0.2,
        gt=0,
        le=60,
        description="bulk read timeout; the reader counts it and reads again. It bounds how "
        "long stopping a stream waits for the reader",
    )


class StageSection(Section):
    """The scan stage (docs/motion.md): its mechanics and the limits camd enforces."""

    profile: str = Field(
        default="linear_rail",
        min_length=1,
        description="stage mechanics: config/stages/<profile>.toml (the simulator uses it too)",
    )
    max_speed_m_s: float = Field(
        default=0.0, ge=0, description="speed limit, m/s; 0 = the profile's maximum"
    )
    max_accel_m_s2: float = Field(
        default=0.0, ge=0, description="ramp acceleration, m/s^2; 0 = the profile's maximum"
    )
    low_limit_m: float | None = Field(
        default=None, description="low soft limit from home, m; none = the low end of travel"
    )
    high_limit_m: float | None = Field(
        default=None, description="high soft limit from home, m; none = the high end of travel"
    )

    @model_validator(mode="after")
    def _limits_ordered(self) -> StageSection:
        low, high = self.low_limit_m, self.high_limit_m
        if low is not None and high is not None and not low < high:
            raise ValueError(
                f"low_limit_m = {low} is not below high_limit_m = {high}: swap or widen them"
            )
        return self


class MotionSection(Section):
    """Scan synchronisation (docs/motion.md): closed loop and mismatch monitoring."""

    closed_loop: Literal["auto", "on", "off"] = Field(
        default="auto",
        description="correct the scan from the encoder: auto = whenever the stage has one",
    )
    correct: Literal["step_rate", "line_period"] = Field(
        default="step_rate",
        description="what the closed loop trims: the stepper's rate or the TDI line period",
    )
    poll_period_s: float = Field(
        default=0.01, gt=0, le=1, description="closed-loop encoder poll period, s"
    )
    gain: float = Field(
        default=1.0, gt=0, le=1, description="closed-loop gain per sample (1 = dead-beat)"
    )
    speed_window_s: float = Field(
        default=0.005,
        gt=0,
        le=1,
        description="the speed is estimated over at least this span of encoder readings (s)",
    )
    speed_window_counts: float = Field(
        default=500.0,
        ge=0,
        description="...and at least this many encoder counts of travel (coarse encoders)",
    )
    predict: bool = Field(
        default=True, description="extrapolate the speed ratio one poll ahead (less lag)"
    )
    max_trim: float = Field(
        default=0.1, gt=0, lt=1, description="largest relative correction the loop may apply"
    )
    settle_s: float = Field(
        default=0.05, ge=0, le=10, description="wait after the stage reaches speed, s"
    )
    yellow: float = Field(default=1.0, gt=0, description="M |dV/V| yellow limit (pixels of smear)")
    red: float = Field(default=2.0, gt=0, description="M |dV/V| red limit (docs/physics.md §6: 2)")
    stop_on_red: bool = Field(default=False, description="stop a scan whose mismatch goes red")
    image_measure: bool = Field(
        default=True,
        description="measure the image's motion from blocks of every stream's TDI windows",
    )
    image_frames_per_block: int = Field(
        default=16, ge=3, le=256, description="consecutive TDI windows per measured block"
    )
    image_columns_max: int = Field(
        default=512, ge=16, le=65535, description="central columns of each window measured"
    )
    image_cpu_fraction: float = Field(
        default=0.25, gt=0, le=1, description="the most of one core the measurement may use"
    )
    image_loop: bool = Field(
        default=False,
        description="scans trim the line period and the drift taps from the image's motion",
    )
    image_loop_gain: float = Field(
        default=0.6, gt=0, le=1, description="the image loop's gain per block (1 = dead-beat)"
    )
    image_max_cols_per_line: float = Field(
        default=0.2, gt=0, le=2, description="the most drift the image loop may set, columns/line"
    )

    @model_validator(mode="after")
    def _levels_ordered(self) -> MotionSection:
        if not self.yellow < self.red:
            raise ValueError(
                f"yellow = {self.yellow} must be below red = {self.red}: the yellow limit warns "
                "before the red one"
            )
        return self


class ChannelLimits(Section):
    """Yellow (warning) and red (alarm) ranges of one telemetry channel; inside = ok."""

    yellow: tuple[StrictFloat, StrictFloat] = Field(strict=False)
    red: tuple[StrictFloat, StrictFloat] = Field(strict=False)

    @model_validator(mode="after")
    def _ranges(self) -> ChannelLimits:
        for name, (lo, hi) in (("yellow", self.yellow), ("red", self.red)):
            if not (math.isfinite(lo) and math.isfinite(hi)):
                raise ValueError(f"{name} = [{lo}, {hi}] must be finite numbers")
            if lo > hi:
                raise ValueError(f"{name} = [{lo}, {hi}] has lo > hi; write [lo, hi]")
        if not (self.red[0] <= self.yellow[0] and self.yellow[1] <= self.red[1]):
            raise ValueError(
                f"red = [{self.red[0]}, {self.red[1]}] must contain yellow = "
                f"[{self.yellow[0]}, {self.yellow[1]}] (red lo <= yellow lo, yellow hi <= red hi)"
            )
        return self


DEFAULT_LIMITS: dict[str, ChannelLimits] = {
    # Commercial-grade FPGA die: rated 0..85 degC junction; warn well before the rating.
    "fpga_temp_degc": ChannelLimits(yellow=(0.0, 70.0), red=(-20.0, 85.0)),
    # sCMOS dark current doubles every ~7 K: image quality, not survival, sets these.
    "sensor_temp_degc": ChannelLimits(yellow=(0.0, 45.0), red=(-20.0, 60.0)),
    # Supplies: yellow at +-3 %, red at +-5 % of nominal (1.0 V core, 3.3 V I/O and sensor).
    "vcc_core_v": ChannelLimits(yellow=(0.97, 1.03), red=(0.95, 1.05)),
    "vcc_io_v": ChannelLimits(yellow=(3.2, 3.4), red=(3.135, 3.465)),
    "vcc_sensor_v": ChannelLimits(yellow=(3.2, 3.4), red=(3.135, 3.465)),
    # Input current: too little means a dead board, too much a short or latch-up.
    "supply_current_a": ChannelLimits(yellow=(0.2, 1.5), red=(0.05, 2.0)),
}


def telemetry_channels() -> dict[str, str]:
    """The numeric channels of the HOUSEKEEPING packet, name -> unit, from the dictionary."""
    packet = load_dictionary().telemetry_packet(HOUSEKEEPING_PACKET)
    return {f.name: f.unit for f in packet.fields if f.type not in ("bytes", "str")}


class TelemetrySection(Section):
    """[telemetry]: housekeeping polling and limits."""

    poll_period_s: float = Field(
        default=1.0, gt=0, le=3600, description="period of GET_HOUSEKEEPING polls"
    )
    red_is_fault: bool = Field(default=True, description="a red limit puts the daemon in fault")
    retention_days: float = Field(
        default=30.0,
        ge=0,
        description="archived samples older than this are deleted (checked hourly); 0 keeps all",
    )
    limits: dict[str, ChannelLimits] = Field(
        default_factory=lambda: dict(DEFAULT_LIMITS),
        description="per-channel yellow/red ranges; merged over the defaults",
    )

    @field_validator("limits", mode="before")
    @classmethod
    def _merge_defaults(cls, value: Any) -> Any:
        # A file that sets one channel keeps the defaults of the others.
        if isinstance(value, Mapping):
            return {**DEFAULT_LIMITS, **value}
        return value

    @field_validator("limits", mode="after")
    @classmethod
    def _known_channels(cls, value: dict[str, ChannelLimits]) -> dict[str, ChannelLimits]:
        channels = telemetry_channels()
        unknown = sorted(set(value) - set(channels))
        if unknown:
            raise ValueError(
                f"unknown channel(s) {', '.join(unknown)}; the {HOUSEKEEPING_PACKET} packet has: "
                + ", ".join(channels)
            )
        return value
