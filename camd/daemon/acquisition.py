"""One acquisition at a time: scans, stares, streams and wheel runs share one slot.

Whatever takes frames from the camera claims the slot before it touches the device, and
releases it once its data are safe (the stream drained, the file closed). While the slot is
held, any request that would disturb it is refused with ``Busy``, whose message names what is
running (and since when) and the command that stops it; a refused request never replaces the
running acquisition, so ``status`` always describes the running or the last started one.
"""

from __future__ import annotations

import contextlib
import contextvars
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field

from camd.daemon.errors import Busy

STOP_COMMANDS: dict[str, str] = {
    "scan": "`camctl scan --stop`",
    "stare": "`camctl stream --stop`",
    "stream": "`camctl stream --stop`",
    "wheel": "`camctl stream --stop`",
}
START_WORDS: dict[str, str] = {
    # A stare is what `camctl stream --frames N` starts: name what the user typed.
    "stare": "take frames (`camctl stream --frames N`, `camctl stare`)",
}


@dataclass(slots=True)
class Acquisition:
    """What holds (or last held) the slot."""

    kind: str  # "scan", "stare", "stream" or "wheel"
    description: str  # e.g. "M = 8, 500 lines to /data/bars.h5"
    client: str = ""  # who started it (holds control while it runs); "" for the daemon itself
    started_t_s: float = field(default_factory=time.time)
    ended_t_s: float | None = None

    @property
    def active(self) -> bool:
        return self.ended_t_s is None

    def busy_message(self, wanted: str) -> str:
        since = time.strftime("%H:%M:%S", time.localtime(self.started_t_s))
        by = f" by {self.client}" if self.client else ""
        return (
            f"cannot {wanted}: a {self.kind} is running ({self.description}, started{by} at "
            f"{since}); wait for it to end or stop it with {STOP_COMMANDS[self.kind]}"
        )


_APPLYING: contextvars.ContextVar[Acquisition | None] = contextvars.ContextVar(
    "camd_applying_acquisition", default=None
)
_CLIENT: contextvars.ContextVar[str] = contextvars.ContextVar("camd_client", default="")


@contextlib.contextmanager
def acting_as(client: str) -> Iterator[None]:
    """Requests made inside (on this thread) are ``client``'s: an acquisition it starts is
    owned by it (``camd.daemon.control``)."""
    token = _CLIENT.set(client)
    try:
        yield
    finally:
        _CLIENT.reset(token)


class AcquisitionSlot:
    """The one acquisition slot (module docstring); thread-safe."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._current: Acquisition | None = None
        self._previous: Acquisition | None = None

    @property
    def current(self) -> Acquisition | None:
        """The running acquisition, or the last one (None before the first)."""
        return self._current

    @property
    def active(self) -> Acquisition | None:
        """The running acquisition, or None."""
        current = self._current
        return current if current is not None and current.active else None

    def claim(self, kind: str, description: str) -> Acquisition:
        """Take the slot for a new acquisition; Busy (naming the running one) if it is held."""
        with self._lock:
            running = self.active
            if running is not None:
                raise Busy(running.busy_message(START_WORDS.get(kind, f"start a {kind}")))
            acquisition = Acquisition(kind, description, _CLIENT.get())
            self._previous = self._current
            self._current = acquisition
            return acquisition

    def abandon(self, acquisition: Acquisition) -> None:
        """The acquisition never started (refused, or put back after a failure): the slot
        describes the one before it again."""
        with self._lock:
            if self._current is acquisition:
                self._current = self._previous

    def release(self, acquisition: Acquisition) -> None:
        """The acquisition has ended (its data are safe); harmless twice."""
        with self._lock:
            if acquisition.ended_t_s is None:
                acquisition.ended_t_s = time.time()

    @contextlib.contextmanager
    def applying(self, acquisition: Acquisition) -> Iterator[None]:
        """While the acquisition sets itself up on this thread (mode, registers, stage), its
        own requests are not refused as disturbing it."""
        token = _APPLYING.set(acquisition)
        try:
            yield
        finally:
            _APPLYING.reset(token)

    @staticmethod
    def applying_now() -> Acquisition | None:
        """The acquisition setting itself up on this thread, if any."""
        return _APPLYING.get()

    def check_free(self, wanted: str) -> None:
        """Raise Busy (naming the running acquisition) if one runs and this is not its own
        set-up; ``wanted`` is what the refused request would have done, e.g. "change the
        imaging mode"."""
        running = self.active
        if running is not None and _APPLYING.get() is not running:
            raise Busy(running.busy_message(wanted))
