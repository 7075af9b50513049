"""``camd serve``: run the daemon in the foreground (under systemd, Type=notify).

Order of events: validate the config and the data directory (exit 2 on error), bind the listening
socket (exit 2 if the port is in use; so that it fails before anything is spawned), start the
device session (the simulator too with ``--sim``), serve HTTP with uvicorn, and once listening
print exactly one line on stdout, ``camd serving http://HOST:PORT`` with the actual port, and
send READY=1. SIGTERM or SIGINT: STOPPING=1, finish the open requests, stop the session
(terminating the simulator), exit 0.

uvicorn runs with ``TimedH11Protocol`` (a client must send each request within
``api.request_timeout_s``) and the log handlers filter every record through ``RedactSecrets``
(the token never reaches the log).
"""

from __future__ import annotations

import argparse
import asyncio
import gc
import json
import logging
import os
import re
import signal
import socket
import sqlite3
import sys
from pathlib import Path
from types import FrameType
from typing import Any, cast

import h11
import uvicorn
from uvicorn.protocols.http.h11_impl import H11Protocol

from camd.daemon import backends, heap, notify
from camd.daemon.api import create_app
from camd.daemon.config import Config, ConfigError, load_config, with_overrides
from camd.daemon.errors import SimulatorError
from camd.daemon.realtime import REALTIME
from camd.daemon.session import DeviceSession

log = logging.getLogger("camd.serve")

EXIT_OK = 0
EXIT_RUNTIME = 1  # could not start the camera session
EXIT_CONFIG = (
    2  # the config or the command line is invalid: also a port in use, an unusable data dir
)
GRACEFUL_SHUTDOWN_S = 5  # open HTTP requests get this long to finish after SIGTERM


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


def _bind(host: str, port: int) -> socket.socket:
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


class _Server(uvicorn.Server):
    """uvicorn's server, telling us when it listens and when a stop signal arrives."""

    def __init__(self, config: uvicorn.Config, session: DeviceSession, url: str) -> None:
        super().__init__(config)
        self.session = session
        self.url = url
        self.stopping_sent = False

    async def startup(self, sockets: list[socket.socket] | None = None) -> None:
        await super().startup(sockets=sockets)
        if not self.started:
            return
        # The one line on stdout that scripts and tests wait for.
        print(f"camd serving {self.url}", flush=True)
        notify.ready(f"serving {self.url}; camera {self.session.state.value}")

    def handle_exit(self, sig: int, frame: FrameType | None) -> None:
        """SIGTERM/SIGINT: uvicorn's graceful stop, plus STOPPING=1 and the session's abort."""
        super().handle_exit(sig, frame)
        if not self.stopping_sent:
            self.stopping_sent = True
            notify.stopping(f"stopping on signal {signal.Signals(sig).name}")
        self.session.abort()  # a long ping run must not hold the shutdown


class TimedH11Protocol(H11Protocol):
    """uvicorn's HTTP/1.1 protocol with a deadline on each request's arrival.

    uvicorn times out a keep-alive connection between requests, but not a request that is
    being sent: a client that sends half its headers, or a body shorter than its
    Content-Length, or nothing at all after connecting, holds its connection (and the memory
    of what it sent) for ever. Here a client has ``request_timeout_s`` (``api.request_timeout_s``)
    from the moment the daemon waits for a request (the connection opened, or the previous
    answer went out) until the request is complete, headers and body; trickling bytes does not
    extend it. Then a client that had sent part of a request gets a 408 with the API's error
    body, and the connection is closed. While the daemon works on a complete request (a stare
    may take minutes), no deadline runs. A subclass, not a middleware: the headers are the
    server's to read, and the app sees a request only once they are in.
    """

    request_timeout_s = 10.0  # set on the subclass that `timed_protocol` makes

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self._deadline: asyncio.TimerHandle | None = None
        self._seen_state: object = h11.IDLE  # the client's side of h11's state machine
        self._upgraded = False  # a WebSocket's now: no HTTP request on it to wait for
        super().connection_made(cast(asyncio.Transport, transport))  # a stream's, from asyncio
        self._watch_request()

    def data_received(self, data: bytes) -> None:
        super().data_received(data)
        self._watch_request()

    def on_response_complete(self) -> None:
        super().on_response_complete()
        self._watch_request()

    def handle_websocket_upgrade(self, event: h11.Request) -> None:
        # The WebSocket protocol takes the connection over; h11 here still waits for the
        # upgrade request's end, which never comes through this object.
        self._upgraded = True
        self._cancel_deadline()
        super().handle_websocket_upgrade(event)

    def connection_lost(self, exc: Exception | None) -> None:
        self._cancel_deadline()
        super().connection_lost(exc)

    def _cancel_deadline(self) -> None:
        if self._deadline is not None:
            self._deadline.cancel()
            self._deadline = None

    def _watch_request(self) -> None:
        """Run the deadline while the daemon waits for (the rest of) a request; a new one gets
        a fresh deadline, a complete one none."""
        if self._upgraded:
            return
        state = self.conn.their_state
        waiting = state in (h11.IDLE, h11.SEND_BODY)
        new_request = state is h11.IDLE and self._seen_state is not h11.IDLE
        self._seen_state = state
        if not waiting or new_request:
            self._cancel_deadline()
        if waiting and self._deadline is None and not self.transport.is_closing():
            self._deadline = self.loop.call_later(self.request_timeout_s, self._timed_out)

    def _timed_out(self) -> None:
        self._deadline = None
        if self.transport.is_closing():
            return
        state = self.conn.their_state
        cycle = self.cycle if state is h11.SEND_BODY else None
        if state is h11.SEND_BODY:
            partial = cycle is not None and not cycle.response_started
        else:  # between requests: part of the next one's headers, or nothing
            partial = bool(self.conn.trailing_data[0])
        if cycle is not None:
            cycle.disconnected = True  # the app's answer, if it ever comes, goes nowhere
            cycle.message_event.set()  # and a read of the body ends
        if partial:
            self.transport.write(self._timeout_answer())
        log.debug(
            "closed a connection from %s: its request was not complete within %g s",
            self.client,
            self.request_timeout_s,
        )
        self.transport.close()

    def _timeout_answer(self) -> bytes:
        body = json.dumps(
            {
                "error": f"the request was not complete within {self.request_timeout_s:g} s "
                "(api.request_timeout_s): its headers or its body stopped coming; the "
                "connection is closed",
                "code": "request_timeout",
            }
        ).encode()
        head = (
            "HTTP/1.1 408 Request Timeout\r\ncontent-type: application/json\r\n"
            f"content-length: {len(body)}\r\nconnection: close\r\n\r\n"
        )
        return head.encode() + body


def timed_protocol(request_timeout_s: float) -> type[TimedH11Protocol]:
    """The HTTP protocol class uvicorn is to use, with this request timeout."""
    return type("TimedH11Protocol", (TimedH11Protocol,), {"request_timeout_s": request_timeout_s})


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
        sock = _bind(host, port)
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
    # Said once the daemon will run: a refused start's one line of error stands alone.
    backends.log_choice(config)
    # What is loaded by now (the modules, their classes and pydantic models: most of the
    # daemon's objects) lives as long as the daemon: kept out of the collector's passes, which
    # then walk only what the daemon makes as it runs. A full pass holds every thread, the
    # link's and the stream's too; the interpreter's passes at exit took 0.5-0.9 s of each stop.
    gc.freeze()
    session = DeviceSession(config)
    try:
        session.start()
    except SimulatorError as exc:
        print(f"camd serve: cannot start the simulated camera: {exc}", file=sys.stderr)
        session.stop()
        sock.close()
        return EXIT_CONFIG if exc.usage else EXIT_RUNTIME
    except (OSError, sqlite3.Error) as exc:
        print(f"camd serve: {unusable_data_dir(config.daemon.data_dir, exc)}", file=sys.stderr)
        session.stop()
        sock.close()
        return EXIT_CONFIG

    # Campaign jobs' workers reach the API at this URL; jobs the last daemon was running when
    # it stopped run on (their workers wait until the API answers).
    session.campaigns.jobs.attach(url, config.api.token)
    session.campaigns.jobs.resume_interrupted()
    server = _Server(
        uvicorn.Config(
            create_app(session, token=config.api.token),
            http=timed_protocol(config.api.request_timeout_s),
            log_config=None,  # keep our logging setup (uvicorn's would print access logs to stdout)
            log_level=config.daemon.log_level,
            access_log=config.daemon.log_level == "debug",
            lifespan="off",
            timeout_graceful_shutdown=GRACEFUL_SHUTDOWN_S,
            # The live view's frames are noise-dominated 16-bit pixels that deflate barely
            # shrinks, and compressing each frame once per viewer cost the stream's ingest ~10 %
            # with three viewers (`camd bench live`): send them as they are.
            ws_per_message_deflate=False,
        ),
        session,
        url,
    )
    try:
        if not stop_requested:
            server.run(sockets=[sock])
    finally:
        if not server.stopping_sent:
            notify.stopping("stopping")
        session.stop()
        sock.close()
    log.info("camd stopped")
    return EXIT_OK
