"""The command link's serial port and its reader thread (camd.link.command_link sends the
requests).

One reader thread owns the port's input: it opens the port (and reopens it with exponential
backoff when it is lost), feeds the sans-I/O ``Decoder``, hands ACK/NAK frames to the waiting
request (``Pending``), and delivers unsolicited telemetry and events, and every connection
change, to subscribers. Writes go out from the requesting thread. Nothing here raises out of
the reader thread.
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from typing import Self, TypedDict

import serial

from camd.protocol import (
    MAX_PAYLOAD,
    OVERHEAD,
    Decoder,
    Dictionary,
    Frame,
    FrameType,
    PayloadError,
    load_dictionary,
)
from camd.protocol.dictionary import FieldValue

# The logger keeps the name it had when this was part of camd.link.command_link.
log = logging.getLogger("camd.link.command_link")

_READ_POLL_S = 0.01  # how long a read waits for a first byte: bounds expiry and stop latency


class LinkError(Exception):
    """Base of the command link's errors; the message says what happened and what to check."""


class LinkDown(LinkError):
    """The port is not open (absent, unplugged, or being reconnected)."""


@dataclass(frozen=True, slots=True)
class Unsolicited:
    """A telemetry packet or an event from the device."""

    kind: FrameType  # TELEMETRY or EVENT
    name: str
    values: dict[str, FieldValue]
    t_s: float  # host wall-clock time of arrival (time.time())


@dataclass(frozen=True, slots=True)
class ConnectionChange:
    """The port opened or was lost."""

    connected: bool
    reason: str
    t_s: float


Message = Unsolicited | ConnectionChange
Subscriber = Callable[[Message], None]


@dataclass(slots=True)
class LinkCounters:
    """Host-side counters of the command link (the decoder keeps its own; ``counters()``
    reports both)."""

    sent: int = 0  # command frames written, retries included
    acked: int = 0
    nacked: int = 0
    retries: int = 0
    timeouts: int = 0  # attempts that got no answer in time
    failed: int = 0  # commands that got no answer at all (timeouts exhausted or link down)
    stale: int = 0  # answers to an earlier attempt that came too late
    undecodable: int = 0  # valid frames whose payload did not match the dictionary
    telemetry: int = 0
    events: int = 0
    reconnects: int = 0


@dataclass(slots=True)
class Pending:
    """The request waiting for its answer: the reader thread fills in ``frame`` and sets
    ``done`` (or sets ``done`` alone when the link is lost)."""

    seq: int
    opcode: int
    done: threading.Event = field(default_factory=threading.Event)
    frame: Frame | None = None


class LinkPortOptions(TypedDict, total=False):
    """``LinkPort``'s keyword arguments, for a subclass that passes them on
    (``CommandLink(port, **options)``): each default stays written once, in ``LinkPort``."""

    dictionary: Dictionary | None
    baudrate: int
    reconnect_min_s: float
    reconnect_max_s: float
    frame_timeout_s: float | None
    thread_start: Callable[[str], object] | None
    may_open: Callable[[], str | None] | None


class LinkPort:
    """The serial port of a command link to one camera, kept open by a reader thread.

    ``port`` is anything pyserial opens: a device path (``/dev/ttyUSB0``, a symlink to a pty) or
    a pyserial URL. ``CommandLink`` (camd.link.command_link) is a ``LinkPort`` that sends
    requests over it.
    """

    def __init__(
        self,
        port: str,
        *,
        dictionary: Dictionary | None = None,
        baudrate: int = 921_600,
        reconnect_min_s: float = 0.1,
        reconnect_max_s: float = 2.0,
        frame_timeout_s: float | None = None,
        thread_start: Callable[[str], object] | None = None,
        may_open: Callable[[], str | None] | None = None,
    ) -> None:
        self.port = port
        self.dictionary = dictionary or load_dictionary()
        self.baudrate = baudrate
        self.reconnect_min_s = reconnect_min_s
        self.reconnect_max_s = reconnect_max_s
        # Called as ``thread_start("command_link")`` from inside the reader thread when it
        # starts: how the daemon gives it real-time scheduling (camd/daemon/realtime.py).
        self.thread_start = thread_start
        # Asked before each attempt to open the port: None lets it open, a reason keeps it shut
        # (and becomes last_error). The daemon's own simulator's link is a symlink to a pty
        # that dies with it; the pty's number is soon another process's, so the link must not
        # be opened again until the restarted simulator has pointed it at its own pty.
        self.may_open = may_open
        # Longest frame at 10 bits per byte, plus USB-serial adapter latency (FTDI: 16 ms).
        self.frame_timeout_s = (
            frame_timeout_s
            if frame_timeout_s is not None
            else 0.03 + (MAX_PAYLOAD + OVERHEAD) * 10 / baudrate
        )

        self._counters = LinkCounters()
        self._serial: serial.SerialBase | None = None
        self._state_lock = threading.Lock()  # guards _serial, _pending, _subscribers
        self._pending: Pending | None = None
        self._subscribers: list[Subscriber] = []
        self._last_error: str | None = "not opened yet"
        self._stop = threading.Event()
        self._connected = threading.Event()
        self._thread: threading.Thread | None = None
        self._decoder = Decoder()
        self._opened_before = False

    # -- lifecycle ------------------------------------------------------------------------------

    def open(self) -> None:
        """Start the reader thread; it opens the port and keeps it open (never raises)."""
        if self._thread is not None:
            return
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name=f"link:{self.port}", daemon=True)
        self._thread.start()

    def close(self) -> None:
        """Stop the reader thread and close the port."""
        self._stop.set()
        self._close_port()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None

    def __enter__(self) -> Self:
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def connected(self) -> bool:
        return self._connected.is_set()

    @property
    def last_error(self) -> str | None:
        """Why the port is not open, or None while it is."""
        return self._last_error

    def wait_connected(self, timeout_s: float) -> bool:
        """Block until the port is open; False if ``timeout_s`` passed first."""
        return self._connected.wait(timeout_s)

    def subscribe(self, callback: Subscriber) -> Callable[[], None]:
        """Call ``callback`` (from the reader thread; keep it quick) for every telemetry packet,
        event and connection change. Returns a function that unsubscribes."""
        with self._state_lock:
            self._subscribers.append(callback)

        def unsubscribe() -> None:
            with self._state_lock:
                if callback in self._subscribers:
                    self._subscribers.remove(callback)

        return unsubscribe

    def counters(self) -> dict[str, int]:
        """A snapshot of the host-side counters (decoder errors included)."""
        stats = self._decoder.stats
        return {
            **asdict(self._counters),
            "crc_errors": stats.crc_errors,
            "resyncs": stats.resyncs,
            "bytes_dropped": stats.bytes_dropped,
        }

    def _write(self, data: bytes) -> None:
        with self._state_lock:
            port = self._serial
        if port is None:
            raise LinkDown(self._down_message())
        try:
            port.write(data)
            self._counters.sent += 1
        except (serial.SerialException, OSError) as exc:
            self._lost(f"write failed: {exc}")
            raise LinkDown(self._down_message()) from None
        except (TypeError, ValueError):
            # The reader thread lost the link and closed this port between the check above and
            # the write: pyserial's close sets the descriptor to None before it marks the port
            # closed, and its write then fails in select(). The link is down, not broken.
            with self._state_lock:
                closed = self._serial is not port or getattr(port, "fd", 0) is None
            if not closed:
                raise
            raise LinkDown(self._down_message()) from None

    def _down_message(self) -> str:
        return (
            f"no camera on {self.port} ({self._last_error}); check the cable, the port name "
            "and that the camera (or `camd sim`) is running"
        )

    # -- reader thread --------------------------------------------------------------------------

    def _run(self) -> None:
        if self.thread_start is not None:
            self.thread_start("command_link")
        backoff_s = self.reconnect_min_s
        while not self._stop.is_set():
            if not self._try_open():
                self._stop.wait(backoff_s)
                backoff_s = min(backoff_s * 2, self.reconnect_max_s)
                continue
            backoff_s = self.reconnect_min_s
            self._read_until_lost()

    def _try_open(self) -> bool:
        refused = self.may_open() if self.may_open is not None else None
        if refused is not None:
            self._last_error = refused
            return False
        try:
            port = serial.serial_for_url(
                self.port, baudrate=self.baudrate, timeout=_READ_POLL_S, exclusive=True
            )
        except (serial.SerialException, OSError, ValueError) as exc:
            self._last_error = str(exc)
            return False
        self._decoder = _carry_stats(self._decoder)
        with self._state_lock:
            self._serial = port
        if self._opened_before:
            self._counters.reconnects += 1
        self._opened_before = True
        self._last_error = None
        self._connected.set()
        log.info("link open on %s", self.port)
        self._publish(ConnectionChange(True, f"opened {self.port}", time.time()))
        return True

    def _read_until_lost(self) -> None:
        while not self._stop.is_set():
            with self._state_lock:
                port = self._serial
            if port is None:
                return
            try:
                # Read what is there, or wait for one byte: a fixed large read would sit out the
                # whole timeout on every short answer. (in_waiting is not on SerialBase's stub.)
                chunk = port.read(max(1, int(getattr(port, "in_waiting", 0))))
            except (serial.SerialException, OSError, TypeError) as exc:
                # TypeError: pyserial reading a port closed under it by close().
                if not self._stop.is_set():
                    self._lost(f"read failed: {exc}")
                return
            now_s = time.monotonic()
            frames = self._decoder.feed(chunk, now_s) if chunk else []
            # A candidate frame older than a whole frame's transfer time is a corrupted length
            # field, not a slow sender.
            frames += self._decoder.expire(now_s, self.frame_timeout_s)
            for frame in frames:
                self._dispatch(frame)

    def _dispatch(self, frame: Frame) -> None:
        if frame.type in (FrameType.ACK, FrameType.NAK):
            with self._state_lock:
                pending = self._pending
                if (
                    pending is not None
                    and pending.frame is None
                    and pending.seq == frame.seq
                    and pending.opcode == frame.opcode
                ):
                    pending.frame = frame
                    pending.done.set()
                    return
            self._counters.stale += 1
            return
        if frame.type in (FrameType.TELEMETRY, FrameType.EVENT):
            is_tlm = frame.type == FrameType.TELEMETRY
            try:
                spec = (
                    self.dictionary.telemetry_packet(frame.opcode)
                    if is_tlm
                    else self.dictionary.event(frame.opcode)
                )
                values = spec.decode(frame.payload)
            except (KeyError, PayloadError):
                self._counters.undecodable += 1
                return
            if is_tlm:
                self._counters.telemetry += 1
            else:
                self._counters.events += 1
            self._publish(Unsolicited(frame.type, spec.name, values, time.time()))
            return
        # A COMMAND frame coming back is our own bytes echoed by a misconfigured line.
        self._counters.undecodable += 1

    def _publish(self, message: Message) -> None:
        with self._state_lock:
            subscribers = list(self._subscribers)
        for callback in subscribers:
            try:
                callback(message)
            except Exception:
                log.exception("link subscriber %r failed on %r", callback, message)

    def _lost(self, reason: str) -> None:
        self._last_error = reason
        was_connected = self._connected.is_set()
        self._connected.clear()
        self._close_port()
        with self._state_lock:
            pending = self._pending
        if pending is not None:
            pending.done.set()  # wake the waiting request; it sees the link down
        if was_connected:
            log.warning("link on %s lost: %s", self.port, reason)
            self._publish(ConnectionChange(False, reason, time.time()))

    def _close_port(self) -> None:
        with self._state_lock:
            port, self._serial = self._serial, None
        if port is not None:
            with contextlib.suppress(serial.SerialException, OSError):
                port.close()


def _carry_stats(old: Decoder) -> Decoder:
    """A fresh decoder for a new connection (stale partial bytes must not leak across), keeping
    the cumulative statistics."""
    return Decoder(max_payload=old.max_payload, stats=old.stats)
