"""The config's section base, and the sections about the daemon itself: [daemon], [api],
[store] and [campaigns].

``Section`` is what every table of the config is: strict and closed, so that a typo is an error
rather than a silently ignored setting. Of the helpers here (absolute directories, loopback
hosts, web origins), ``normal_origin`` is shared with the daemon's request guard.
camd/daemon/config.py assembles the sections into ``Config``; docs/config.md lists every key.
"""

from __future__ import annotations

import ipaddress
import os
from pathlib import Path
from typing import Annotated, Literal
from urllib.parse import urlsplit

from pydantic import (
    AfterValidator,
    BaseModel,
    ConfigDict,
    Field,
    Strict,
    ValidationInfo,
    field_validator,
    model_validator,
)

from camd.store.compression import (
    DEFAULT,
    FILTERS,
    OFF,
    Compression,
    check_level,
    check_name,
)

TOKEN_ENV = "CAMD_TOKEN"
"""Environment variable that supplies ``api.token`` (it wins over the file)."""

LogLevel = Literal["debug", "info", "warning", "error", "critical"]
RealtimeSetting = Literal["auto", "off", "required"]
RT_PRIORITY_MAX = 49
"""Highest ``daemon.rt_priority``: the kernel's threaded interrupt handlers run at 50, and the
USB controller's must stay ahead of the frame reader that waits for it."""


def absolute_dirs(value: list[Path]) -> list[Path]:
    """Directories a config key names, ``~`` and ``$VARIABLES`` expanded; ValueError naming an
    entry that is not absolute (it would depend on the daemon's working directory: an operator
    allows a directory they can name)."""
    expanded = [expanded_path(path) for path in value]
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


class Section(BaseModel):
    """A table of the config: unknown keys refused, values frozen, defaults validated too."""

    # Strict: port = "8423" is a string, not a port (as the API refuses "10"); a TOML array
    # becomes a tuple and a string a path only where a field says so (Field(strict=False)).
    model_config = ConfigDict(extra="forbid", frozen=True, validate_default=True, strict=True)


def expanded_path(path: Path) -> Path:
    """``path`` with ``~`` and ``$VARIABLES`` expanded."""
    return Path(os.path.expandvars(os.path.expanduser(str(path))))


class DaemonSection(Section):
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
        description="load the TDI kernels and the image motion measurement (OpenCV) when the "
        "daemon starts, so that the first scan does not wait for them (about a second of one "
        "core) and its closed loop is not held up by their loading; false: at the first scan",
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
        return expanded_path(value).absolute()

    @field_validator("record_dirs", mode="after")
    @classmethod
    def _absolute_dirs(cls, value: list[Path]) -> list[Path]:
        return absolute_dirs(value)


def _level_of_the_filter(level: int | None, info: ValidationInfo) -> int | None:
    """A ``compression_level`` checked against the ``compression`` of the same table or
    request (validated before it)."""
    if "compression" not in info.data:
        return level  # the filter was refused: its error says why
    return check_level(info.data["compression"], level)


# A compression filter's name and level, checked (camd.store.compression), wherever a config
# table or a request takes them: the [store] table, a record's or a scan's request.
CompressionName = Annotated[str, AfterValidator(check_name)]
CompressionLevel = Annotated[int | None, AfterValidator(_level_of_the_filter)]


class StoreSection(Section):
    """[store]: how recordings and scans are stored (docs/stream.md, "Compression")."""

    compression: CompressionName = Field(
        default=DEFAULT.filter,
        description="the lossless filter each chunk of frames (lines) is compressed with, or "
        f"off: one of {', '.join(FILTERS)}",
    )
    compression_level: CompressionLevel = Field(
        default=None,
        description="the filter's level, for those that have levels; absent = its default",
    )
    scan_compression_max_mbyte_s: float = Field(
        default=100.0,
        ge=0.0,
        le=1e6,
        description="a scan whose lines come faster than this (MB/s of stored lines) is not "
        "compressed unless its request names a compression: the filter's CPU would slow the "
        "fastest scans' host path below the line rate",
    )

    def compression_for(
        self, name: str | None, level: int | None, *, mbyte_s: float = 0.0
    ) -> Compression:
        """A request's compression (``name`` and ``level``, checked by its model), or, when
        the request names none, this section's; off for a scan whose lines come at more than
        ``scan_compression_max_mbyte_s`` (``mbyte_s``: their rate)."""
        if name is not None:
            return Compression.of(name, level)
        if mbyte_s > self.scan_compression_max_mbyte_s:
            return Compression.of(OFF)
        return Compression.of(self.compression, self.compression_level)


class ApiSection(Section):
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


class CampaignsSection(Section):
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
