"""``camd serve``: run the daemon in the foreground (under systemd, Type=notify).

Order of events: validate the config and the data directory (exit 2 on error), bind the listening
socket (exit 2 if the port is in use; so that it fails before anything is spawned), start the
simulator with ``--sim`` (spawned at once, waited for by the session), import and start the
device session, serve HTTP with uvicorn (camd/daemon/server.py), and once listening print exactly
one line on stdout, ``camd serving http://HOST:PORT`` with the actual port, and send READY=1.
SIGTERM or SIGINT: STOPPING=1, finish the open requests, stop the session (terminating the
simulator), exit 0.

The log handlers filter every record through ``RedactSecrets`` (the token never reaches the
log).
"""

from __future__ import annotations

import argparse
import logging
import os
import re
import signal
import socket
import sqlite3
import sys
from pathlib import Path
from types import FrameType
from typing import Any

# Light on purpose: the session, the API and uvicorn (camd/daemon/server.py) are imported in
# run(), once the simulated camera is spawned, so that its start runs beside their loading.
from camd.daemon import heap
from camd.daemon.config import Config, ConfigError, load_config, with_overrides
from camd.daemon.errors import SimulatorError
from camd.daemon.realtime import REALTIME
from camd.daemon.simulator import SimulatorProcess

log = logging.getLogger("camd.serve")

EXIT_OK = 0
EXIT_RUNTIME = 1  # could not start the camera session
EXIT_CONFIG = (
    2  # the config or the command line is invalid: also a port in use, an unusable data dir
)


def add_parser(sub: Any) -> None:
    """Register ``camd serve`` and its options."""
    p: argparse.ArgumentParser = sub.add_parser(
        "serve",
        help="run the daemon in the foreground",
        description="Run the camd daemon in the foreground: own the camera's command link, "
        "archive telemetry and serve the HTTP API. Flags override the config file.",
    )
    p.add_argument(
        "--config",
        type=Path,
        metavar="FILE",
        help="TOML config file (default: the shipped config/camd.toml; see docs/config.md)",
    )
    p.add_argument("--host", help="address to bind (api.host); non-loopback needs api.token")
    p.add_argument(
        "--port", type=int, metavar="P", help="TCP port (api.port); 0 picks any free port"
    )
    p.add_argument("--data-dir", type=Path, metavar="DIR", help="data directory (daemon.data_dir)")
    p.add_argument(
        "--record-dir",
        type=Path,
        action="append",
        metavar="DIR",
        help="also let clients record into DIR (added to daemon.record_dirs; repeatable)",
    )
    device = p.add_mutually_exclusive_group()
    device.add_argument(
        "--sim", action="store_true", help="spawn and use the simulated camera (link.device=sim)"
    )
    device.add_argument(
        "--serial", metavar="PORT", help="use the camera on this serial port or pyserial URL"
    )
    p.add_argument(
        "--hardware",
        action="store_true",
        help="real hardware throughout: the command link on --serial PORT (or link.device), the "
        "frame stream and the USB-SPI bridge through libusb, whatever the config says",
    )
    p.add_argument(
        "--inject",
        metavar="SPEC",
        help="simulator line faults, e.g. 'ber=1e-4,drop=0.01' (sim.inject)",
    )


def build_config(args: argparse.Namespace) -> Config:
    """The config file with the command line's overrides applied; ConfigError if invalid."""
    config = load_config(args.config)
    device = "sim" if args.sim else args.serial
    if args.hardware:
        if args.sim:
            raise ConfigError("--hardware and --sim exclude each other; give one")
        config = with_overrides(
            config,
            {"stream.backend": "libusb", "sensor.usb_spi.backend": "libusb"},
            source="--hardware",
        )
        if (device or config.link.device) == "sim":
            raise ConfigError(
                "--hardware needs the camera's serial port: give --serial PORT (e.g. "
                "/dev/ttyUSB0) or set link.device in the config"
            )
    return with_overrides(
        config,
        {
            "api.host": args.host,
            "api.port": args.port,
            "daemon.data_dir": args.data_dir,
            "daemon.record_dirs": (
                [*config.daemon.record_dirs, *args.record_dir] if args.record_dir else None
            ),
            "link.device": device,
            "sim.inject": args.inject,
        },
    )


def bind_listening_socket(host: str, port: int) -> socket.socket:
    """A listening TCP socket on host:port (IPv4 or IPv6, as the host resolves)."""
    candidates = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
    # "localhost" may resolve to ::1 first; clients mostly try 127.0.0.1, so prefer IPv4.
    candidates.sort(key=lambda info: info[0] != socket.AF_INET)
    family, type_, proto, _, address = candidates[0]
    sock = socket.socket(family, type_, proto)
    try:
        # A restarted daemon must not wait for the old connections' TIME_WAIT to expire.
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind(address)
        sock.listen(128)
        sock.set_inheritable(False)  # the simulator child must not hold our port
    except OSError:
        sock.close()
        raise
    return sock


def url_host(host: str) -> str:
    """``host`` as written in a URL (IPv6 literals in brackets)."""
    return f"[{host}]" if ":" in host and not host.startswith("[") else host


# A token in a logged URL (?token=, the camd_token cookie) or header (Bearer): uvicorn logs each
# WebSocket's path and query at INFO, and each request's at DEBUG.
_SECRET_IN_TEXT = re.compile(r"(token=)[^&\s\"';]+|(bearer\s+)[^\s\"',;]+", re.IGNORECASE)
REDACTED = "***"
TOKEN_LITERAL_MIN = 4  # characters: a token this long is also redacted wherever it appears


class RedactSecrets(logging.Filter):
    """Replaces tokens in every record a handler emits with ``***``: ``token=`` values, Bearer
    values, and the daemon's own token wherever it appears."""

    def __init__(self, token: str = "") -> None:
        super().__init__()
        self.token = token

    def redact(self, text: str) -> str:
        """``text`` with every secret replaced."""
        text = _SECRET_IN_TEXT.sub(lambda m: (m.group(1) or m.group(2)) + REDACTED, text)
        if len(self.token) < TOKEN_LITERAL_MIN:
            return text  # a one-letter token replaced everywhere would garble the log
        return text.replace(self.token, REDACTED)

    def filter(self, record: logging.LogRecord) -> bool:
        try:
            message = record.getMessage()
        except Exception:  # a bad format: the handler reports it as it would have
            return True
        redacted = self.redact(message)
        if redacted != message:
            record.msg, record.args = redacted, None
        if record.exc_info and not record.exc_text:
            record.exc_text = logging.Formatter().formatException(record.exc_info)
        if record.exc_text:
            record.exc_text = self.redact(record.exc_text)
        if record.stack_info:
            record.stack_info = self.redact(record.stack_info)
        return True


def _setup_logging(level: str, token: str) -> None:
    # Everything on stderr: stdout carries only the `camd serving` line.
    logging.basicConfig(
        level=level.upper(),
        stream=sys.stderr,
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
    )
    # On the handlers, not a logger: every logger's records (uvicorn's, the libraries') pass.
    for handler in logging.getLogger().handlers:
        handler.addFilter(RedactSecrets(token))


def data_dir_problem(path: Path) -> str | None:
    """Why the data directory cannot be used (None if it can): checked before anything is bound
    or spawned. A missing directory whose nearest existing parent is writable is fine (the
    session creates it)."""
    existing = path
    while not existing.exists() and existing != existing.parent:
        existing = existing.parent
    if not existing.is_dir():
        return f"cannot use the data directory {path}: {existing} is not a directory"
    if not os.access(existing, os.W_OK | os.X_OK):
        what = "the data directory" if existing == path else f"its parent {existing}"
        return f"cannot use the data directory {path}: {what} is not writable"
    return None


def unusable_data_dir(path: Path, exc: BaseException) -> str:
    """The refusal of a data directory that could not be made or used."""
    why = getattr(exc, "strerror", None) or exc
    return f"cannot use the data directory {path}: {why}; make it writable or choose another with --data-dir"


def run(args: argparse.Namespace) -> int:
    """Run the daemon until SIGTERM/SIGINT; return the exit status."""
    try:
        config = build_config(args)
    except ConfigError as exc:
        print(f"camd serve: invalid configuration:\n{exc}", file=sys.stderr)
        return EXIT_CONFIG
    _setup_logging(config.daemon.log_level, config.api.token)

    # Until uvicorn takes the signals over, a stop request just ends the start-up early; and
    # after it hands them back it re-raises what it caught, which must then be harmless.
    stop_requested: list[int] = []

    def early_stop(sig: int, frame: FrameType | None) -> None:
        """Remember the signal; run() then skips serving and exits 0."""
        stop_requested.append(sig)

    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, early_stop)

    problem = data_dir_problem(config.daemon.data_dir)
    if problem:
        print(f"camd serve: {problem}; choose another with --data-dir", file=sys.stderr)
        return EXIT_CONFIG
    host, port = config.api.host, config.api.port
    try:
        sock = bind_listening_socket(host, port)
    except OSError as exc:
        print(
            f"camd serve: cannot listen on {host}:{port}: {exc.strerror or exc}; stop the other "
            "process using the port or choose another with --port (0 = any free port)",
            file=sys.stderr,
        )
        return EXIT_CONFIG
    url = f"http://{url_host(host)}:{sock.getsockname()[1]}"
    # Made here, before anything logs: a directory the checks above could not foresee (under
    # /proc, a read-only mount) is refused with its one line of error, as a bad one is.
    try:
        config.daemon.data_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        print(f"camd serve: {unusable_data_dir(config.daemon.data_dir, exc)}", file=sys.stderr)
        sock.close()
        return EXIT_CONFIG

    # Before any thread starts: arenas made before the limit stay (camd/daemon/heap.py).
    heap.limit_arenas(config.daemon.malloc_arenas)
    daemon = config.daemon
    refusal = REALTIME.configure(daemon.realtime, daemon.rt_priority, daemon.fallback_nice)
    if refusal:
        print(f"camd serve: {refusal}", file=sys.stderr)
        sock.close()
        return EXIT_CONFIG
    # The simulated camera starts now, beside the import of the daemon's heavy half (the
    # session, the API, uvicorn: camd/daemon/server.py), not after it.
    simulator = SimulatorProcess.for_config(config)
    try:
        if simulator is not None:
            simulator.spawn()
        from camd.daemon import server

        session = server.start_session(config, simulator)
    except SimulatorError as exc:
        print(f"camd serve: cannot start the simulated camera: {exc}", file=sys.stderr)
        sock.close()
        return EXIT_CONFIG if exc.usage else EXIT_RUNTIME
    except (OSError, sqlite3.Error) as exc:
        print(f"camd serve: {unusable_data_dir(config.daemon.data_dir, exc)}", file=sys.stderr)
        sock.close()
        return EXIT_CONFIG
    try:
        server.serve_api(session, config, sock, url, bool(stop_requested))
    finally:
        sock.close()
    log.info("camd stopped")
    return EXIT_OK
