"""The daemon from its camera session's start to its stop: the session, the API served by
uvicorn, the ordered shutdown (``camd serve``'s second half, camd/daemon/serve.py).

Imported by ``camd serve`` only after it has spawned the simulated camera: this module brings
in the session, the API and uvicorn (most of the daemon's import time), whose loading then runs
beside the simulator's start.

uvicorn runs with ``TimedH11Protocol`` (a client must send each request within
``api.request_timeout_s``); ``AnnouncingServer`` prints the ``camd serving`` line once it
listens.
"""

from __future__ import annotations

import asyncio
import gc
import json
import logging
import signal
import socket
from types import FrameType
from typing import cast

import h11
import uvicorn
from uvicorn.protocols.http.h11_impl import H11Protocol

from camd.daemon import backends, notify
from camd.daemon.api import create_app
from camd.daemon.config import Config
from camd.daemon.session import DeviceSession
from camd.daemon.simulator import SimulatorProcess

log = logging.getLogger("camd.serve")

GRACEFUL_SHUTDOWN_S = 5  # open HTTP requests get this long to finish after SIGTERM


class AnnouncingServer(uvicorn.Server):
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


def start_session(config: Config, simulator: SimulatorProcess | None) -> DeviceSession:
    """The camera session, started (on ``simulator`` when given, already spawned). On failure
    it is stopped and the error raised: SimulatorError if the simulator does not start,
    OSError or sqlite3.Error if the data directory or the archive cannot be written."""
    # Said once the daemon will run: a refused start's one line of error stands alone.
    backends.log_choice(config)
    # What is loaded by now (the modules, their classes and pydantic models: most of the
    # daemon's objects) lives as long as the daemon: kept out of the collector's passes, which
    # then walk only what the daemon makes as it runs. A full pass holds every thread, the
    # link's and the stream's too; the interpreter's passes at exit took 0.5-0.9 s of each stop.
    gc.freeze()
    session: DeviceSession | None = None
    try:
        session = DeviceSession(config, simulator=simulator)
        session.start()
    except BaseException:
        if session is not None:
            session.stop()
        if simulator is not None:  # a session that failed early had not reached it yet
            simulator.stop()
        raise
    return session


def serve_api(
    session: DeviceSession, config: Config, sock: socket.socket, url: str, stop_requested: bool
) -> None:
    """Serve the API on ``sock`` (announced at ``url``) until SIGTERM/SIGINT, or not at all if
    a stop was requested during the start; then stop the session in order."""
    # Campaign jobs' workers reach the API at this URL; jobs the last daemon was running when
    # it stopped run on (their workers wait until the API answers).
    session.campaigns.jobs.attach(url, config.api.token)
    session.campaigns.jobs.resume_interrupted()
    server = AnnouncingServer(
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
            # A viewer's messages are its transport settings (tens of bytes): a message longer
            # than a request body may be closes its socket (1009), unread.
            ws_max_size=config.api.max_body_bytes,
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
