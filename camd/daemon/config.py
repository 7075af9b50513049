"""The daemon's configuration: one TOML file, validated by pydantic.

Every section forbids unknown keys, so a typo is an error rather than a silently ignored setting.
The defaults give a working simulated camera on 127.0.0.1:8422. ``load_config`` reports errors
with the file, the dotted key path and what is allowed; docs/config.md lists every key.
"""

from __future__ import annotations

import hashlib
import ipaddress
import math
import os
import tempfile
import tomllib
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Annotated, Any, Literal
from urllib.parse import urlsplit

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    Strict,
    StrictFloat,
    ValidationError,
    field_validator,
    model_validator,
)

from camd.datafile import cut, line_of, wrong_type
from camd.paths import config_dir
from camd.protocol import load_dictionary
from camd.sensor.profile import list_profiles
from camd.sensor.regmap import list_sensors

TOKEN_ENV = "CAMD_TOKEN"
TDI_WARM_UP_ENV = "CAMD_TDI_WARM_UP"
"""Environment variable that supplies ``daemon.tdi_warm_up`` ("0" or "1"; it wins over the
file): the test suite's daemons, most of which never scan, set it to 0."""
RECORD_DIRS_ENV = "CAMD_RECORD_DIRS"
"""Environment variable whose directories (separated by ``:``) are added to
``daemon.record_dirs``: the test suite allows its temporary directories this way."""
UNIX_SOCKET_PATH_MAX = 100  # bytes: sun_path is 108 on Linux, 104 on BSD, NUL included
"""Environment variable that supplies ``api.token`` (it wins over the file)."""

HOUSEKEEPING_PACKET = "HOUSEKEEPING"
"""The telemetry packet whose channels the limits apply to."""

LogLevel = Literal["debug", "info", "warning", "error", "critical"]
BackendChoice = Literal["auto", "sim", "libusb"]
"""How a USB device of the camera (the frame stream, the USB-SPI bridge) is reached: "auto"
follows the command link (the simulator's with ``link.device = "sim"``, else real hardware)."""
UsbBackend = Literal["sim", "libusb"]
RealtimeSetting = Literal["auto", "off", "required"]
RT_PRIORITY_MAX = 49
"""Highest ``daemon.rt_priority``: the kernel's threaded interrupt handlers run at 50, and the
USB controller's must stay ahead of the frame reader that waits for it."""


class ConfigError(ValueError):
    """The configuration is invalid; the message names the file, the key and what is allowed."""


def absolute_dirs(value: list[Path]) -> list[Path]:
    """Directories a config key names, ``~`` and ``$VARIABLES`` expanded; ValueError naming an
    entry that is not absolute (it would depend on the daemon's working directory: an operator
    allows a directory they can name)."""
    expanded = [_expanded(path) for path in value]
    for index, path in enumerate(expanded):
        if not path.is_absolute():
            raise ValueError(
                f"entry {index} ({str(value[index])!r}) is not an absolute path; give one "
                "starting with / (or ~)"
            )
    return expanded


def is_loopback(host: str) -> bool:
    """True if ``host`` only accepts connections from this machine."""
    if host.lower() == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False  # a host name other than localhost may resolve to anything


def normal_origin(origin: str) -> str:
    """A web origin as browsers write it in the Origin header (``http://host:port``, lower case,
    the default port left out); ValueError naming what is wrong if ``origin`` is not one."""
    example = "write it as a browser's Origin header does, e.g. http://lab-pc:8080"
    try:
        parts = urlsplit(origin.strip())
        port = parts.port
    except ValueError:
        raise ValueError(f"{origin!r} is not an origin; {example}") from None
    if parts.scheme not in ("http", "https") or not parts.hostname:
        raise ValueError(f"{origin!r} is not an origin (http or https and a host); {example}")
    if parts.path not in ("", "/") or parts.query or parts.fragment or parts.username:
        raise ValueError(f"{origin!r} has more than scheme, host and port; {example}")
    host = f"[{parts.hostname}]" if ":" in parts.hostname else parts.hostname
    default = {"http": 80, "https": 443}[parts.scheme]
    return f"{parts.scheme}://{host}" + (f":{port}" if port not in (None, default) else "")


class _Section(BaseModel):
    # Strict: port = "8423" is a string, not a port (as the API refuses "10"); a TOML array
    # becomes a tuple and a string a path only where a field says so (Field(strict=False)).
    model_config = ConfigDict(extra="forbid", frozen=True, validate_default=True, strict=True)


def _expanded(path: Path) -> Path:
    """``path`` with ``~`` and ``$VARIABLES`` expanded."""
    return Path(os.path.expandvars(os.path.expanduser(str(path))))


class DaemonSection(_Section):
    """[daemon]: where the daemon keeps its files and how much it logs."""

    data_dir: Annotated[Path, Strict(False)] = Field(
        default=Path("~/.local/share/camd"),
        description="directory for the telemetry archive and the simulator's link (~ is expanded)",
    )
    log_level: LogLevel = Field(default="info", description="logging threshold")
    malloc_arenas: int = Field(
        default=2,
        ge=0,
        le=64,
        description="glibc malloc arenas at most (0 = glibc's default, 8 per core): few keep a "
        "long-running daemon's memory from fragmenting",
    )

    tdi_warm_up: bool = Field(
        default=True,
        description="load the TDI kernels when the daemon starts, so that the first scan does "
        "not wait for them (about a second of one core); false: at the first scan",
    )

    record_dirs: list[Annotated[Path, Strict(False)]] = Field(
        default_factory=list,
        description="directories outside data_dir where clients may have the daemon write "
        "recordings, scans and campaign output (absolute; ~ and $VARIABLES expanded)",
    )

    realtime: RealtimeSetting = Field(
        default="auto",
        description="real-time scheduling of the threads the hardware waits on (frame reader, "
        "command link, closed loop, service loop): auto (when allowed, else a raised priority), "
        "off, required (refuse to start without it)",
    )
    rt_priority: int = Field(
        default=10,
        ge=1,
        le=RT_PRIORITY_MAX,
        description="their SCHED_RR priority (1..49: under the kernel's interrupt threads at 50)",
    )
    fallback_nice: int = Field(
        default=-5,
        ge=-20,
        le=0,
        description="their nice value where real time is not allowed (if the nice limit allows it)",
    )

    @field_validator("data_dir", mode="after")
    @classmethod
    def _expand(cls, value: Path) -> Path:
        # Expanded here so that every user of the config sees one absolute path.
        return _expanded(value).absolute()

    @field_validator("record_dirs", mode="after")
    @classmethod
    def _absolute_dirs(cls, value: list[Path]) -> list[Path]:
        return absolute_dirs(value)


class ApiSection(_Section):
    """[api]: the HTTP server."""

    host: str = Field(default="127.0.0.1", min_length=1, description="address to bind")
    port: int = Field(default=8422, ge=0, le=65535, description="TCP port; 0 picks a free one")
    token: str = Field(
        default="", description="bearer token required from clients; empty = none (loopback only)"
    )
    allowed_origins: list[str] = Field(
        default_factory=list,
        description="web pages of other origins (scheme://host[:port]) that may use the API and "
        "the live WebSocket from a browser; the daemon's own pages always may",
    )
    max_body_bytes: int = Field(
        default=65536,
        ge=1024,
        le=1 << 30,
        description="largest request body taken, bytes; a longer one is refused (413) unread",
    )
    request_timeout_s: float = Field(
        default=10.0,
        gt=0,
        le=3600,
        description="a request's headers and body must arrive within this; a client that sends "
        "half a request is disconnected then",
    )

    @field_validator("allowed_origins", mode="after")
    @classmethod
    def _origins(cls, value: list[str]) -> list[str]:
        # Compared with what browsers send in Origin: scheme, host and port only, lower case.
        return [normal_origin(origin) for origin in value]

    @model_validator(mode="after")
    def _token_for_remote(self) -> ApiSection:
        # Anyone on the network could drive the camera otherwise.
        if not is_loopback(self.host) and not self.token:
            raise ValueError(
                f"host = {self.host!r} is not a loopback address and no token is set; "
                f"set api.token (or ${TOKEN_ENV}) or bind 127.0.0.1"
            )
        return self


class LinkSection(_Section):
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


class SimSection(_Section):
    """[sim]: the simulated camera spawned when ``link.device = "sim"``."""

    inject: str = Field(
        default="", description="line faults, e.g. 'ber=1e-4,drop=0.01'; empty = perfect line"
    )
    hk_period_s: float = Field(
        default=1.0, gt=0, le=3600, description="period of unsolicited housekeeping"
    )
    seed: int = Field(default=0, ge=0, description="random seed of the simulator (noise, faults)")
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


class UsbSpiSection(_Section):
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


class SensorSection(_Section):
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


class StreamSection(_Section):
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


class StageSection(_Section):
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


class MotionSection(_Section):
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

    @model_validator(mode="after")
    def _levels_ordered(self) -> MotionSection:
        if not self.yellow < self.red:
            raise ValueError(
                f"yellow = {self.yellow} must be below red = {self.red}: the yellow limit warns "
                "before the red one"
            )
        return self


class ChannelLimits(_Section):
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


class TelemetrySection(_Section):
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


class CampaignsSection(_Section):
    """[campaigns]: where the daemon's campaign jobs come from."""

    dirs: list[Annotated[Path, Strict(False)]] = Field(
        default_factory=list,
        description="directories of the operator's own campaigns (YAML files and Python plans), "
        "searched in order before the shipped ones; a campaign job names a campaign found "
        "here (or a shipped one) by its name, never by a path (~ is expanded; absolute)",
    )

    @field_validator("dirs", mode="after")
    @classmethod
    def _absolute_dirs(cls, value: list[Path]) -> list[Path]:
        return absolute_dirs(value)


class Config(_Section):
    """The whole daemon configuration."""

    daemon: DaemonSection = Field(default_factory=DaemonSection)
    api: ApiSection = Field(default_factory=ApiSection)
    link: LinkSection = Field(default_factory=LinkSection)
    sim: SimSection = Field(default_factory=SimSection)
    sensor: SensorSection = Field(default_factory=SensorSection)
    stream: StreamSection = Field(default_factory=StreamSection)
    telemetry: TelemetrySection = Field(default_factory=TelemetrySection)
    stage: StageSection = Field(default_factory=StageSection)
    motion: MotionSection = Field(default_factory=MotionSection)
    campaigns: CampaignsSection = Field(default_factory=CampaignsSection)

    @model_validator(mode="after")
    def _sim_matches_sensor(self) -> Config:
        # The simulator models one sensor; a map for another would program the wrong registers.
        if self.link.device == "sim" and self.sim.profile != self.sensor.name:
            raise ValueError(
                f"sim.profile = {self.sim.profile!r} but sensor.name = {self.sensor.name!r}; "
                "the simulated camera's sensor must be the one the register map describes: "
                "set both to the same name"
            )
        return self

    @property
    def simulated_link(self) -> bool:
        """True when the command link is the spawned simulator's (``link.device = "sim"``)."""
        return self.link.device == "sim"

    @property
    def stream_backend(self) -> UsbBackend:
        """``stream.backend`` with "auto" resolved: the simulated FX3 with the simulated link,
        libusb (real hardware) with a serial port."""
        return _resolved(self.stream.backend, self.simulated_link)

    @property
    def usb_spi_backend(self) -> UsbBackend:
        """``sensor.usb_spi.backend`` with "auto" resolved, as ``stream_backend``."""
        return _resolved(self.sensor.usb_spi.backend, self.simulated_link)

    @property
    def sim_socket_dir(self) -> Path:
        """Where the spawned simulator's Unix sockets go: ``data_dir/sim``, or, when a socket
        there would have a path too long for a socket address (108 bytes on Linux, 104 on
        BSD), ``camd-sim-<hash of data_dir>`` in the system's temporary directory."""
        local = self.daemon.data_dir / "sim"
        if len(str(local.resolve() / "spi.sock").encode()) <= UNIX_SOCKET_PATH_MAX:
            return local
        digest = hashlib.sha256(str(self.daemon.data_dir.resolve()).encode()).hexdigest()
        return Path(tempfile.gettempdir()) / f"camd-sim-{digest[:16]}"

    @property
    def sim_spi_socket(self) -> Path:
        """Where the spawned simulator serves its SPI bus for the simulated USB-SPI bridge."""
        return self.sim_socket_dir / "spi.sock"

    @property
    def sim_usb_socket(self) -> Path:
        """Where the spawned simulator serves its USB bulk stream for the simulated FX3."""
        return self.sim_socket_dir / "usb.sock"

    @property
    def sim_link_path(self) -> Path:
        """Where the spawned simulator puts its pty symlink."""
        return self.daemon.data_dir / "sim" / "camera.tty"

    @property
    def archive_path(self) -> Path:
        """The SQLite telemetry archive."""
        return self.daemon.data_dir / "telemetry.sqlite"


def _resolved(choice: BackendChoice, simulated_link: bool) -> UsbBackend:
    # "auto" is resolved when asked, never stored: a --serial given after the file was read
    # must turn an "auto" stream to hardware too.
    if choice == "auto":
        return "sim" if simulated_link else "libusb"
    return choice


def default_config_path() -> Path:
    """The shipped config/camd.toml."""
    return config_dir() / "camd.toml"


def load_config(path: Path | None = None, *, env: Mapping[str, str] | None = None) -> Config:
    """Read and validate a config file (None = the shipped config/camd.toml).

    ``$CAMD_TOKEN`` (from ``env``, default os.environ) replaces ``api.token`` when set,
    ``$CAMD_TDI_WARM_UP`` (0 or 1) ``daemon.tdi_warm_up``, and the directories of
    ``$CAMD_RECORD_DIRS`` are added to ``daemon.record_dirs``.
    Raises ConfigError naming the file, the key path and what is allowed.
    """
    path = default_config_path() if path is None else Path(path)
    try:
        text = path.read_text()
        data = tomllib.loads(text)
    except FileNotFoundError:
        raise ConfigError(f"{path}: config file not found; give an existing --config") from None
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read the config file: {exc.strerror}") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML: {exc}") from None
    return config_from_dict(data, source=str(path), env=env, text=text)


def config_from_dict(
    data: Mapping[str, Any],
    *,
    source: str = "config",
    env: Mapping[str, str] | None = None,
    text: str | None = None,
) -> Config:
    """Validate a config given as nested dicts (as read from TOML); see ``load_config``. With
    the file's ``text``, each error names its line (``source:line: key: ...``)."""
    env = os.environ if env is None else env
    merged: dict[str, Any] = {k: dict(v) if isinstance(v, Mapping) else v for k, v in data.items()}
    token = env.get(TOKEN_ENV, "")
    if token:
        api = merged.get("api", {})
        if isinstance(api, dict):
            merged["api"] = {**api, "token": token}
    warm_up = env.get(TDI_WARM_UP_ENV, "")
    if warm_up:
        if warm_up not in ("0", "1"):
            raise ConfigError(f"${TDI_WARM_UP_ENV}={warm_up!r}: give 0 or 1 (or unset it)")
        daemon = merged.get("daemon", {})
        if isinstance(daemon, dict):
            merged["daemon"] = {**daemon, "tdi_warm_up": warm_up == "1"}
    extra_dirs = [entry for entry in env.get(RECORD_DIRS_ENV, "").split(os.pathsep) if entry]
    for entry in extra_dirs:
        if not _expanded(Path(entry)).is_absolute():
            raise ConfigError(
                f"${RECORD_DIRS_ENV}: {entry!r} is not an absolute path; give absolute "
                f"directories separated by {os.pathsep!r} (or unset it)"
            )
    if extra_dirs:
        daemon = merged.get("daemon", {})
        if isinstance(daemon, dict):
            listed = daemon.get("record_dirs", [])
            if isinstance(listed, list):  # anything else is the file's error, reported below
                merged["daemon"] = {**daemon, "record_dirs": [*listed, *extra_dirs]}
    try:
        return Config.model_validate(merged)
    except ValidationError as exc:
        where = None if text is None else (lambda loc: line_of(text, data, loc))
        raise ConfigError(format_errors(exc, source, where)) from None


def with_overrides(
    config: Config, changes: Mapping[str, Any], *, source: str = "command line"
) -> Config:
    """A copy of ``config`` with dotted keys replaced (``{"api.port": 0}``), re-validated.

    Values of None are skipped, so unset command-line flags leave the file's values alone.
    """
    data = config.model_dump()
    for dotted, value in changes.items():
        if value is None:
            continue
        *tables, key = dotted.replace("__", ".").split(".")
        table = data
        for name in tables:  # "sensor.usb_spi.backend": a table inside a section
            table = table[name]
        table[key] = value
    try:
        return Config.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(format_errors(exc, source)) from None


def _model_at(loc: tuple[int | str, ...]) -> type[BaseModel] | None:
    """The model class that validates the table at ``loc`` (None if it is not a table)."""
    model: type[BaseModel] = Config
    parts = [str(p) for p in loc]
    while parts:
        part = parts.pop(0)
        if model is TelemetrySection and part == "limits":
            if not parts:
                return None  # the limits table itself takes channel names, not fixed keys
            parts.pop(0)  # the channel name
            model = ChannelLimits
            continue
        field = model.model_fields.get(part)
        annotation = None if field is None else field.annotation
        if not (isinstance(annotation, type) and issubclass(annotation, BaseModel)):
            return None
        model = annotation
    return model


_BOUND_ERRORS = frozenset({"greater_than", "greater_than_equal", "less_than", "less_than_equal"})


def _allowed_range(loc: tuple[int | str, ...]) -> str:
    """``"0 <= x <= 65535"``-style text from the field's constraints at ``loc``."""
    parent = _model_at(loc[:-1])
    field = None if parent is None else parent.model_fields.get(str(loc[-1]))
    if field is None:
        return ""
    lo = hi = ""
    for meta in field.metadata:
        if getattr(meta, "ge", None) is not None:
            lo = f"{meta.ge} <= "
        if getattr(meta, "gt", None) is not None:
            lo = f"{meta.gt} < "
        if getattr(meta, "le", None) is not None:
            hi = f" <= {meta.le}"
        if getattr(meta, "lt", None) is not None:
            hi = f" < {meta.lt}"
    return f"{lo}{loc[-1]}{hi}" if lo or hi else ""


def format_errors(
    exc: ValidationError,
    source: str,
    line: Callable[[tuple[int | str, ...]], int | None] | None = None,
) -> str:
    """One line per error: ``source[:line]: key.path: what is wrong; what is allowed`` (the
    line of the key, when ``line`` finds it in the file)."""
    lines = []
    for err in exc.errors():
        loc = tuple(err["loc"])
        number = None if line is None or not loc else line(loc)
        where = source if number is None else f"{source}:{number}"
        key = ".".join(str(p) for p in loc) or "(top level)"
        kind = err["type"]
        if kind == "extra_forbidden":
            parent = _model_at(loc[:-1])
            allowed = list(parent.model_fields) if parent is not None else []
            hint = f"; allowed keys here: {', '.join(allowed)}" if allowed else ""
            lines.append(f"{where}: {key}: unknown key (a typo?){hint}")
            continue
        msg = str(err["msg"]).removeprefix("Value error, ")
        ctx = err.get("ctx", {})
        strict = wrong_type(kind, err["input"])
        if strict is not None:
            msg = strict
        elif kind == "literal_error" and "expected" in ctx:
            msg = f"{cut(repr(err['input']))} is not allowed; use {ctx['expected']}"
        elif kind in _BOUND_ERRORS:
            bounds = _allowed_range(loc)
            msg = f"{cut(repr(err['input']))} is out of range; allowed: {bounds or msg}"
        elif kind not in ("value_error", "missing"):
            msg = f"{msg} (got {cut(repr(err['input']))})"
        lines.append(f"{where}: {key}: {msg}")
    return "\n".join(lines)
