"""Apply a checked plan to the device, and put back what was changed if a step fails.

A state-changing request is first planned by pure code and checked whole; only then is the
device touched, step by step, through an ``Apply``. Each step names what it changes and gives
the action that undoes it. When a later step fails (a NAK, a link loss, a full disk), the undo
actions run in reverse order and the error the client gets is the original one (same HTTP
status) with what was restored appended, e.g.::

    ... the device refused START_STREAM (BUSY); restored: stream recording
    removed, stage stopped and back at 120.000 mm, registers WIN_ROWS, EXPOSURE, mode area

An undo that itself fails is reported in the same sentence ("could NOT restore ...") and logged:
the operator then knows exactly what to check.

When the step failed because the link was lost or the device went silent, the undo actions need
that link: they wait first (the error's ``link_wait``, bounded by ``DeviceAccess.restore_wait_s``)
until the camera answers again. If it does not, nothing is attempted and every change is named
as not restored, with why.

Applies nest: a request applied inside another one's ``Apply`` on the same thread (a scan's
register write, its stream's start) undoes its own steps when it fails, then hands what it
restored to the enclosing one, which undoes the rest and says it all in one sentence (and
one event).
"""

from __future__ import annotations

import contextvars
import logging
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, TypeVar

from camd.daemon.errors import LinkWait, SessionError, with_note

log = logging.getLogger(__name__)

T = TypeVar("T")

EventLog = Callable[[str, str, str], None]
"""``(level, source, message)``."""

_ENCLOSING: contextvars.ContextVar[Apply | None] = contextvars.ContextVar(
    "camd_enclosing_apply", default=None
)


@dataclass(frozen=True, slots=True)
class _Undo:
    label: str  # what undoing restores, e.g. "mode area"
    action: Callable[[], Any]


@dataclass(slots=True)
class _Outcome:
    """What a rollback did, newest change first."""

    restored: list[str] = field(default_factory=list)
    failed: list[str] = field(default_factory=list)  # "label (why)"
    unreached: list[str] = field(default_factory=list)  # not tried: the camera did not answer
    problem: str | None = None  # why the camera could not be reached

    def extend(self, other: _Outcome) -> None:
        self.restored += other.restored
        self.failed += other.failed
        self.unreached += other.unreached
        self.problem = self.problem or other.problem

    def words(self) -> str:
        parts = []
        if self.restored:
            parts.append("restored: " + ", ".join(self.restored))
        if self.failed:
            parts.append("could NOT restore: " + "; ".join(self.failed) + " (check them by hand)")
        if self.unreached:
            parts.append(
                f"could NOT restore: {', '.join(self.unreached)} ({self.problem}); check them "
                "by hand once the camera answers (`camctl status`)"
            )
        return "; ".join(parts) if parts else "nothing had been changed"


class ApplyFailed(SessionError):
    """A step failed with an error that is not a SessionError (a bug, an OSError); the message
    says what failed and what was restored (HTTP 500)."""


class Apply:
    """The undo journal of one request being applied (module docstring).

    Use ``step(label, action, undo)`` for each change, then ``done()``; or as a context
    manager, which rolls back on any exception and re-raises it with what was restored.
    ``what`` names the request as a noun ("scan start", "mode change"): a failure's event
    reads "<what> failed: <why>; <what was restored>", so it is never an outcome ("scan not
    started", which would read "scan not started failed: ...").
    """

    def __init__(self, what: str, events: EventLog, source: str = "api") -> None:
        self.what = what
        self._events = events
        self._source = source
        self._undo: list[_Undo] = []
        self._open = True
        self._inner = _Outcome()  # what Applies nested in this one restored when they failed
        self._handed = 0  # how many nested Applies have failed into this one
        self._token: contextvars.Token[Apply | None] | None = None
        self._enclosing: Apply | None = None

    def step(self, action: Callable[[], T], undo: Callable[[], Any] | None, label: str) -> T:
        """Run ``action``; on success remember ``undo`` (``label`` says what it restores).

        Also when ``action`` fails on a lost link or a silent device: the answer may be what
        was lost, so the change may have been made (undoing one that was not is harmless);
        unless ``action`` applied through an ``Apply`` of its own, which has put it back."""
        handed = self._handed
        try:
            result = action()
        except SessionError as exc:
            if undo is not None and exc.link_wait is not None and self._handed == handed:
                self._undo.append(_Undo(label, undo))
            raise
        if undo is not None:
            self._undo.append(_Undo(label, undo))
        return result

    def undo_later(self, undo: Callable[[], Any], label: str) -> None:
        """Remember an undo for a change made outside ``step`` (e.g. a file created)."""
        self._undo.append(_Undo(label, undo))

    def done(self) -> None:
        """Everything applied: forget the undo actions."""
        self._undo.clear()
        self._open = False

    def rollback(self, link_wait: LinkWait | None = None) -> str:
        """Undo every applied step, newest first; returns what was restored, in words.

        ``link_wait``: the failure lost the link; wait with it until the camera answers before
        undoing (module docstring)."""
        return self._rollback(link_wait).words()

    def _rollback(self, link_wait: LinkWait | None) -> _Outcome:
        outcome = _Outcome()
        outcome.extend(self._inner)  # newer than this Apply's own steps
        self._inner = _Outcome()
        self._open = False
        if not self._undo:
            return outcome
        problem = outcome.problem  # a nested Apply already waited for the camera in vain
        if problem is None and link_wait is not None:
            problem = link_wait()
        if problem is not None:
            outcome.unreached += [undo.label for undo in reversed(self._undo)]
            outcome.problem = problem
            self._undo.clear()
            return outcome
        while self._undo:
            undo = self._undo.pop()
            try:
                undo.action()
            except Exception as exc:  # keep undoing the rest: each is independent
                log.exception("undoing %s", undo.label)
                outcome.failed.append(f"{undo.label} ({exc})")
            else:
                outcome.restored.append(undo.label)
        return outcome

    def __enter__(self) -> Apply:
        self._enclosing = _ENCLOSING.get()
        self._token = _ENCLOSING.set(self)
        return self

    def __exit__(self, kind: object, exc: BaseException | None, tb: object) -> None:
        if self._token is not None:
            _ENCLOSING.reset(self._token)
            self._token = None
        if exc is None or not self._open:
            self._log_inner()
            return
        if not isinstance(exc, Exception):  # KeyboardInterrupt, SystemExit: undo, re-raise
            self._rollback(None)
            return
        outcome = self._rollback(exc.link_wait if isinstance(exc, SessionError) else None)
        enclosing = self._enclosing
        if enclosing is not None and enclosing._open:
            # The enclosing request undoes the rest and says what was restored, once.
            enclosing._inner.extend(outcome)
            enclosing._handed += 1
            return
        note = outcome.words()
        level = "error" if "could NOT" in note else "warning"
        self._events(level, self._source, f"{self.what} failed: {exc}; {note}")
        if isinstance(exc, SessionError):
            raise with_note(exc, note) from None
        raise ApplyFailed(f"{self.what} failed: {type(exc).__name__}: {exc}; {note}") from exc

    def _log_inner(self) -> None:
        """This request went on after a nested one failed and was put back: log that."""
        inner, self._inner = self._inner, _Outcome()
        if inner.restored or inner.failed or inner.unreached:
            note = inner.words()
            level = "error" if "could NOT" in note else "warning"
            self._events(level, self._source, f"{self.what}: a part of it failed; {note}")


def apply_one(
    what: str,
    events: EventLog,
    action: Callable[[], T],
    undo: Callable[[], Any],
    label: str,
    source: str = "api",
) -> T:
    """A request that changes one thing: ``action`` as the one step of an ``Apply`` of its own
    (``what`` the request, ``undo`` what puts it back if the answer is lost, ``label`` what that
    restores); what ``action`` returns."""
    with Apply(what, events, source) as apply:
        result = apply.step(action, undo, label)
        apply.done()
    return result
