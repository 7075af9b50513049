"""The daemon's configuration: one TOML file, validated by pydantic.

Every section forbids unknown keys, so a typo is an error rather than a silently ignored setting.
The defaults give a working simulated camera on 127.0.0.1:8422. ``load_config`` reports errors
with the file, the dotted key path and what is allowed; docs/config.md lists every key.

The sections live beside this module: the daemon's own ([daemon], [api], [campaigns]) in
config_sections.py, the camera's in config_camera.py; the error messages are those of every
config file (``camd.datafile.every_error``: each mistake on a line of its own, where the data
files of config/ report their first). ``Config`` assembles them, chooses the backends and
derives the paths.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from pydantic import Field, ValidationError, model_validator

from camd.daemon.config_camera import (
    DEFAULT_LIMITS,
    HOUSEKEEPING_PACKET,
    BackendChoice,
    ChannelLimits,
    LinkSection,
    MotionSection,
    SensorSection,
    SimSection,
    StageSection,
    StreamSection,
    TelemetrySection,
    UsbBackend,
    telemetry_channels,
)
from camd.daemon.config_sections import (
    TOKEN_ENV,
    ApiSection,
    CampaignsSection,
    DaemonSection,
    RealtimeSetting,
    Section,
    StoreSection,
    expanded_path,
    is_loopback,
    normal_origin,
)
from camd.datafile import DataFileError, every_error, parse_toml
from camd.paths import config_dir

# The names defined here, and the sections' names that importers took from here before the
# sections moved to config_sections.py and config_camera.py.
__all__ = [
    "DEFAULT_LIMITS",
    "HOUSEKEEPING_PACKET",
    "RECORD_DIRS_ENV",
    "TDI_WARM_UP_ENV",
    "TOKEN_ENV",
    "UNIX_SOCKET_PATH_MAX",
    "ChannelLimits",
    "Config",
    "ConfigError",
    "MotionSection",
    "RealtimeSetting",
    "TelemetrySection",
    "config_from_dict",
    "default_config_path",
    "is_loopback",
    "load_config",
    "normal_origin",
    "telemetry_channels",
    "with_overrides",
]

TDI_WARM_UP_ENV = "CAMD_TDI_WARM_UP"
"""Environment variable that supplies ``daemon.tdi_warm_up`` ("0" or "1"; it wins over the
file): the test suite's daemons, most of which never scan, set it to 0."""
RECORD_DIRS_ENV = "CAMD_RECORD_DIRS"
"""Environment variable whose directories (separated by ``:``) are added to
``daemon.record_dirs``: the test suite allows its temporary directories this way."""
UNIX_SOCKET_PATH_MAX = 100  # bytes: sun_path is 108 on Linux, 104 on BSD, NUL included


class ConfigError(ValueError):
    """The configuration is invalid; the message names the file, the key and what is allowed."""


class Config(Section):
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
    store: StoreSection = Field(default_factory=StoreSection)

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
    def link_retries(self) -> int:
        """Re-sends of a command after a timeout: ``sim.link_retries`` for the simulated camera
        (the machine it shares may hold it back: 600 ms without an answer was seen with the
        test suite's four workers on two cores), else ``link.retries``."""
        return self.sim.link_retries if self.simulated_link else self.link.retries

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
        data = parse_toml(text, path)
    except FileNotFoundError:
        raise ConfigError(f"{path}: config file not found; give an existing --config") from None
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read the config file: {exc.strerror}") from None
    except DataFileError as exc:
        raise ConfigError(str(exc)) from None
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
        if not expanded_path(Path(entry)).is_absolute():
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
        raise ConfigError(every_error(exc, source, model=Config, text=text, data=data)) from None


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
        raise ConfigError(every_error(exc, source, model=Config)) from None
