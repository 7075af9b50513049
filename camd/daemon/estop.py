"""The emergency-stop latch: an emergency stop is a state of the whole instrument, not a request
to one acquisition (docs/api.md, "Emergency stop").

Once latched (``engage``), nothing moves or acquires until a client with control releases it
(``release``): the requests that would (a stream, stare, scan or wheel acquisition, moving or
enabling the stage, turning the filter wheel) are refused with 409 ``estop_latched`` before
anything is touched (``check``), and, as a backstop for a request already past its checks when
the stop came, every command that starts motion or acquisition is refused on its way to the
camera (``check_command``): so a scan being set up, a closed loop's speed trim or a campaign's
closing "restore settings" cannot start anything again. Stopping is never refused.

The latch is kept on disk (``<data_dir>/estop.json``, rewritten atomically), so a daemon that
restarts (or a camera that reboots and turns its wheel again) is stopped again, not released.
A file that cannot be read counts as latched: the safe side.
"""

from __future__ import annotations

import contextlib
import json
import os
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from camd.daemon.errors import EstopLatched

__all__ = ["MAY_MOVE", "RELEASE_HINT", "EstopLatch", "EstopRecord", "moves"]

RELEASE_HINT = (
    "check the rig, then release it with `camctl estop release` (needs control; "
    "POST /api/v1/estop/release)"
)
FILE_FORMAT = "camd-estop"
FILE_VERSION = 1


MAY_MOVE = frozenset(
    {
        "START_STREAM",
        "WHEEL_ACQUIRE",
        "MOTOR_MOVE",
        "MOTOR_HOME",
        "MOTOR_ENABLE",
        "MOTOR_SET_RATE",
        "WHEEL_SET_SPEED",
    }
)
"""The camera commands that can start motion or acquisition, whatever their fields."""


def moves(command: str, fields: Mapping[str, Any]) -> bool:
    """True if the camera command ``command`` with ``fields`` starts motion or acquisition
    (what the latch refuses); stopping, reading and configuring are not."""
    if command in ("START_STREAM", "WHEEL_ACQUIRE", "MOTOR_MOVE", "MOTOR_HOME"):
        return True
    if command == "MOTOR_ENABLE":
        return fields.get("enable") == "on"
    if command == "MOTOR_SET_RATE":
        return float(fields.get("rate_hz", 0.0)) != 0.0
    if command == "WHEEL_SET_SPEED":
        return float(fields.get("speed_deg_s", 0.0)) != 0.0
    return False


@dataclass(slots=True)
class EstopRecord:
    """The latch as the API shows it and estop.json keeps it."""

    latched: bool = False
    since_t_s: float | None = None  # the first stop of this latch
    by: str | None = None  # who asked for it
    last_t_s: float | None = None  # the newest stop (a latched instrument may be stopped again)
    stopped: list[str] = field(default_factory=list)  # what the newest stop stopped
    failed: list[str] = field(default_factory=list)  # what it could not stop, with why
    count: int = 0  # stops asked for since the file was made
    released_t_s: float | None = None
    released_by: str | None = None


class EstopLatch:
    """The latch (module docstring); thread-safe."""

    def __init__(self, path: Path, events: Callable[[str, str, str], None] | None = None) -> None:
        self.path = path
        self._events = events
        self._lock = threading.Lock()
        self._record = self._load()

    @property
    def latched(self) -> bool:
        return self._record.latched

    def record(self) -> EstopRecord:
        """A copy of the latch's state."""
        with self._lock:
            return EstopRecord(**asdict(self._record))

    def engage(self, by: str) -> None:
        """Latch, before anything is stopped: a request racing the stop is refused from here."""
        with self._lock:
            now = time.time()
            r = self._record
            if not r.latched:
                r.latched, r.since_t_s, r.by = True, now, by
                r.released_t_s = r.released_by = None
            r.last_t_s, r.count = now, r.count + 1
            r.stopped, r.failed = [], []
            self._save()

    def stopped(self, stopped: list[str], failed: list[str]) -> None:
        """What the newest stop did, for the record."""
        with self._lock:
            self._record.stopped, self._record.failed = list(stopped), list(failed)
            self._save()

    def release(self, by: str) -> bool:
        """Lift the latch; False (and nothing changed) if it was not latched."""
        with self._lock:
            r = self._record
            if not r.latched:
                return False
            r.latched, r.released_t_s, r.released_by = False, time.time(), by
            self._save()
            return True

    def check(self, wanted: str) -> None:
        """EstopLatched (409) while latched, naming what was refused."""
        with self._lock:
            r = self._record
            if not r.latched:
                return
            since = "" if r.since_t_s is None else f" since {_clock(r.since_t_s)}"
            by = f" (asked by {r.by})" if r.by else ""
        raise EstopLatched(
            f"cannot {wanted}: the emergency stop is latched{since}{by}; nothing moves or "
            f"acquires until it is released: {RELEASE_HINT}"
        )

    def check_command(self, command: str, fields: Mapping[str, Any]) -> None:
        """The backstop: EstopLatched for a command that starts motion or acquisition."""
        if self._record.latched and moves(command, fields):
            self.check(f"send {command} to the camera")

    def check_raw(self, command: str | None) -> None:
        """EstopLatched for a raw frame (conformance) that may move: one of ``MAY_MOVE``, or an
        opcode the dictionary does not know (what it does cannot be told)."""
        if self._record.latched and (command is None or command in MAY_MOVE):
            self.check(f"send {command or 'an unknown opcode'} to the camera")

    # -- estop.json ----------------------------------------------------------------------------

    def _load(self) -> EstopRecord:
        try:
            doc = json.loads(self.path.read_text(encoding="utf-8"))
            if doc.get("format") != FILE_FORMAT or doc.get("version") != FILE_VERSION:
                raise ValueError(f"not a {FILE_FORMAT} file of version {FILE_VERSION}")
            return EstopRecord(**doc["latch"])
        except FileNotFoundError:
            return EstopRecord()
        except (OSError, ValueError, TypeError, KeyError) as exc:
            # The safe side: a latch we cannot read is a latch.
            if self._events is not None:
                self._events(
                    "error",
                    "estop",
                    f"{self.path} cannot be read ({exc}): the emergency stop counts as latched; "
                    + RELEASE_HINT,
                )
            return EstopRecord(latched=True, since_t_s=time.time(), by="camd (unreadable file)")

    def _save(self) -> None:
        doc = {"format": FILE_FORMAT, "version": FILE_VERSION, "latch": asdict(self._record)}
        tmp = self.path.with_suffix(".json.tmp")
        # A full disk must not undo a stop: the latch holds in memory whatever the file does.
        with contextlib.suppress(OSError):
            self.path.parent.mkdir(parents=True, exist_ok=True)
            tmp.write_text(json.dumps(doc, indent=1) + "\n", encoding="utf-8")
            os.replace(tmp, self.path)


def _clock(t_s: float) -> str:
    return time.strftime("%H:%M:%S", time.localtime(t_s))
