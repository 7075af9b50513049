"""Who may change the camera: one controlling client at a time, everyone else observes.

Every request names its client (the ``X-Camd-Client`` header; camctl and ``CamdClient`` send
``user@host`` unless told otherwise). Reading (status, telemetry, events, files) never needs
control. A request that changes the camera is allowed when nobody holds control or when its
client is the holder; any other client gets 423 ``not_in_control`` naming the holder, since
when and why, and how to take over.

A client holds control:

- explicitly, with a lease (``POST /api/v1/control``): for ``ttl_s`` seconds, renewed by asking
  again, given back with ``DELETE``; a campaign or a script holds one for its whole run;
- implicitly, while an acquisition it started (scan, stare, stream, wheel run) runs: nobody
  else can stop or disturb it.

The holder may say what it is doing (``set_activity``: "campaign mtf: step 3/12 ...", with
steps done and in all) for observers to see; what it said is forgotten when control is given
back, expires, ends with its acquisition or is taken over.

A forced takeover (``force``) always succeeds and is logged as a warning event naming both
clients. Emergency stops (``/api/v1/estop``, ``/api/v1/motion/estop``, ``/api/v1/motion/stop``)
are never refused, whoever asks and whatever holds control.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

from camd.daemon.acquisition import AcquisitionSlot
from camd.daemon.errors import NoControl, NotInControl

ANONYMOUS = "anonymous"
DEFAULT_TTL_S = 60.0
MAX_TTL_S = 24 * 3600.0


@dataclass(frozen=True, slots=True)
class Holder:
    """Who holds control now, since when, why, and until when (None: while it runs)."""

    client: str
    since_t_s: float
    why: str  # "lease" or "a scan it started is running" ...
    expires_t_s: float | None


@dataclass(frozen=True, slots=True)
class Activity:
    """What ``client``, holding control, last said it is doing (``done`` of ``total`` steps)."""

    client: str
    text: str
    done: int | None
    total: int | None
    t_s: float


@dataclass(slots=True)
class _Lease:
    client: str
    since_t_s: float
    expires_t_s: float


def _clock(t_s: float) -> str:
    return time.strftime("%H:%M:%S", time.localtime(t_s))


class Control:
    """The controlling client (module docstring); thread-safe."""

    def __init__(
        self,
        acquisition: AcquisitionSlot,
        events: Callable[[str, str, str], None],
        clock: Callable[[], float] = time.time,
    ) -> None:
        self._acquisition = acquisition
        self._events = events
        self._clock = clock
        self._lock = threading.Lock()
        self._lease: _Lease | None = None
        self._activity: Activity | None = None

    def holder(self) -> Holder | None:
        """Who holds control now (an expired lease holds nothing)."""
        with self._lock:
            return self._holder()

    def _holder(self) -> Holder | None:
        holder = self._current_holder()
        activity = self._activity
        if activity is not None and (holder is None or holder.client != activity.client):
            self._activity = None  # given back, expired, ended or taken over: said no more
        return holder

    def _current_holder(self) -> Holder | None:
        lease = self._lease
        now = self._clock()
        if lease is not None and lease.expires_t_s <= now:
            self._lease = None
            self._events(
                "info",
                "control",
                f"control lease of {lease.client} expired; {self._after(lease.client)}",
            )
            lease = None
        if lease is not None:
            return Holder(lease.client, lease.since_t_s, "lease", lease.expires_t_s)
        running = self._acquisition.active
        if running is not None and running.client:
            return Holder(
                running.client,
                running.started_t_s,
                f"a {running.kind} it started is running",
                None,
            )
        return None

    def check(self, client: str, wanted: str) -> None:
        """Raise NotInControl unless ``client`` may change the camera now."""
        with self._lock:
            holder = self._holder()
        if holder is None or holder.client == client:
            return
        until = (
            f", lease until {_clock(holder.expires_t_s)}" if holder.expires_t_s is not None else ""
        )
        raise NotInControl(
            f"cannot {wanted}: {holder.client} holds control since {_clock(holder.since_t_s)} "
            f"({holder.why}{until}); you ({client}) may read but not change the camera. Wait, "
            "ask them, or take over with `camctl control take --force`"
        )

    def take(self, client: str, ttl_s: float, *, force: bool = False) -> Holder:
        """Take (or renew) a lease for ``client``; NotInControl if another holds control,
        unless ``force``, which takes it over and logs who from."""
        with self._lock:
            holder = self._holder()
            now = self._clock()
            if holder is not None and holder.client != client:
                if not force:
                    raise NotInControl(
                        f"{holder.client} holds control since {_clock(holder.since_t_s)} "
                        f"({holder.why}); wait, ask them, or take over with --force"
                    )
                self._events(
                    "warning",
                    "control",
                    f"control taken over by {client} from {holder.client} ({holder.why})",
                )
            since = holder.since_t_s if holder is not None and holder.client == client else now
            if holder is None or holder.client != client or holder.why != "lease":
                self._events("info", "control", f"{client} took control for {ttl_s:g} s")
            self._lease = _Lease(client, since, now + ttl_s)
            # A takeover also takes the running acquisition: its owner is the new holder.
            running = self._acquisition.active
            if running is not None:
                running.client = client
            return self._holder()  # type: ignore[return-value]

    def hand_over(self, client: str, to: str, ttl_s: float) -> None:
        """Give control to ``to`` for ``ttl_s``: ``client``'s own, or free control (a campaign
        job's worker gets its starter's); NotInControl if another client holds it."""
        with self._lock:
            holder = self._holder()
            if holder is not None and holder.client not in (client, to):
                raise NotInControl(
                    f"{holder.client} holds control since {_clock(holder.since_t_s)} "
                    f"({holder.why}); you ({client}) cannot hand it over: wait, ask them, or "
                    "take over with `camctl control take --force`"
                )
            now = self._clock()
            self._lease = _Lease(to, now, now + ttl_s)
            self._events("info", "control", f"{client} handed control to {to} for {ttl_s:g} s")

    def release(self, client: str) -> None:
        """Give back ``client``'s lease (harmless when it holds none); what it said it was
        doing goes with it."""
        with self._lock:
            lease = self._lease
            if lease is not None and lease.client == client:
                self._lease = None
                self._events("info", "control", f"{client} released control")
            if self._activity is not None and self._activity.client == client:
                self._activity = None

    def hand_back(self, to: str, before: Holder | None) -> None:
        """Undo a ``hand_over`` to ``to`` that came to nothing (its worker never started): the
        lease as ``before`` (``holder()`` before the hand-over) had it, or none."""
        with self._lock:
            lease = self._lease
            if lease is None or lease.client != to:
                return
            if before is not None and before.why == "lease" and before.expires_t_s is not None:
                self._lease = _Lease(before.client, before.since_t_s, before.expires_t_s)
            else:
                self._lease = None
            self._events(
                "info",
                "control",
                f"control back from {to} (it did not start); {self._after(to) if self._lease is None else f'{self._lease.client} holds it again'}",
            )

    def revoke(self, client: str, why: str) -> None:
        """End ``client``'s lease because its holder's life ended (a campaign job's worker
        exited, or an emergency stop paused its job); harmless when it holds none."""
        with self._lock:
            lease = self._lease
            if lease is not None and lease.client == client:
                self._lease = None
                self._events(
                    "info", "control", f"control of {client} ended ({why}); {self._after(client)}"
                )
            if self._activity is not None and self._activity.client == client:
                self._activity = None

    def _after(self, client: str) -> str:
        """Who holds control once ``client``'s lease has gone, in words (the lock held)."""
        running = self._acquisition.active
        if running is not None and running.client:
            return f"{running.client} still holds control while the {running.kind} it started runs"
        return "control is free"

    def activity(self) -> Activity | None:
        """What the holder last said it is doing (None: nothing, or no longer the holder)."""
        with self._lock:
            self._holder()
            return self._activity

    def set_activity(
        self, client: str, text: str, done: int | None = None, total: int | None = None
    ) -> Activity:
        """Record what ``client`` is doing; only the holder may: NoControl while nobody
        holds control, NotInControl (naming the holder) while another client does."""
        with self._lock:
            holder = self._holder()
            if holder is not None and holder.client == client:
                self._activity = Activity(client, text, done, total, self._clock())
                return self._activity
        if holder is not None:
            self.check(client, "set the activity")  # NotInControl, naming the holder
        raise NoControl(
            "cannot set the activity: nobody holds control; take it first (POST "
            "/api/v1/control, `camctl control take`), then say what you are doing"
        )
