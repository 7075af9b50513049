"""systemd's sd_notify protocol, in a few lines (no libsystemd dependency).

systemd passes ``$NOTIFY_SOCKET``, an AF_UNIX datagram socket: a path, or an abstract address
written with a leading '@' (sent as a leading NUL byte). Each datagram holds newline-separated
``KEY=VALUE`` assignments. Outside systemd the variable is unset and every call is a no-op, so the
daemon calls these unconditionally.
"""

from __future__ import annotations

import logging
import os
import socket
from collections.abc import Mapping

log = logging.getLogger(__name__)


def _address(env: Mapping[str, str]) -> str | None:
    path = env.get("NOTIFY_SOCKET", "")
    if not path:
        return None
    if path.startswith("@"):
        return "\0" + path[1:]  # Linux abstract namespace
    return path


def notify(*assignments: str, env: Mapping[str, str] | None = None) -> bool:
    """Send ``assignments`` (e.g. "READY=1") in one datagram; True if sent.

    Never raises: failing to notify must not take the daemon down (systemd then times out and
    says so in its own log), so errors are logged instead.
    """
    address = _address(os.environ if env is None else env)
    if address is None or not assignments:
        return False
    data = "\n".join(assignments).encode()
    try:
        with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC) as sock:
            sock.sendto(data, address)
    except OSError as exc:
        log.warning("sd_notify to %r failed: %s", address.replace("\0", "@"), exc)
        return False
    return True


def ready(status: str | None = None) -> bool:
    """Tell systemd the service is up (Type=notify waits for this)."""
    return notify("READY=1", *([f"STATUS={status}"] if status else []))


def status(text: str) -> bool:
    """Update the one-line status shown by ``systemctl status``."""
    return notify(f"STATUS={text}")


def watchdog() -> bool:
    """Pet the watchdog (WatchdogSec=): systemd restarts the service if these stop."""
    return notify("WATCHDOG=1")


def stopping(status: str | None = None) -> bool:
    """Tell systemd the service is shutting down."""
    return notify("STOPPING=1", *([f"STATUS={status}"] if status else []))


def watchdog_interval_s(env: Mapping[str, str] | None = None) -> float | None:
    """The watchdog timeout from ``$WATCHDOG_USEC`` in seconds, or None if the watchdog is off.

    ``$WATCHDOG_PID``, when set, names the process the watchdog is meant for: another pid (a
    child that inherited the environment) must not pet it.
    """
    env = os.environ if env is None else env
    usec = env.get("WATCHDOG_USEC", "")
    if not usec:
        return None
    pid = env.get("WATCHDOG_PID", "")
    if pid:
        try:
            if int(pid) != os.getpid():
                return None
        except ValueError:
            return None
    try:
        value = int(usec)
    except ValueError:
        log.warning("ignoring WATCHDOG_USEC=%r: not an integer", usec)
        return None
    return value / 1e6 if value > 0 else None
