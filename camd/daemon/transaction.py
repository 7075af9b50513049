"""Apply a checked plan to the device, and put back what was changed if a step fails.

A state-changing request is first planned by pure code and checked whole; only then is the
device touched, step by step, through an ``Apply``. Each step names what it changes and gives
the action that undoes it. When a later step fails (a NAK, a link loss, a full disk), the undo
actions run in reverse order and the error the client gets is the original one (same HTTP
status) with what was restored appended, e.g.::

    scan not started: ... the device refused START_STREAM (BUSY); restored: stream recording
    removed, stage stopped and back at 120.000 mm, registers WIN_ROWS, EXPOSURE, mode area

An undo that itself fails is reported in the same sentence ("could not restore ...") and logged:
the operator then knows exactly what to check.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, TypeVar

from camd.daemon.errors import SessionError, with_note

log = logging.getLogger(__name__)

T = TypeVar("T")

EventLog = Callable[[str, str, str], None]
"""``(level, source, message)``."""


@dataclass(frozen=True, slots=True)
class _Undo:
    label: str  # what undoing restores, e.g. "mode area"
    action: Callable[[], Any]


class ApplyFailed(SessionError):
    """A step failed with an error that is not a SessionError (a bug, an OSError); the message
    says what failed and what was restored (HTTP 500)."""


class Apply:
    """The undo journal of one request being applied (module docstring).

    Use ``step(label, action, undo)`` for each change, then ``done()``; or as a context
    manager, which rolls back on any exception and re-raises it with what was restored.
    """

    def __init__(self, what: str, events: EventLog, source: str = "api") -> None:
        self.what = what
        self._events = events
        self._source = source
        self._undo: list[_Undo] = []
        self._open = True

    def step(self, action: Callable[[], T], undo: Callable[[], Any] | None, label: str) -> T:
        """Run ``action``; on success remember ``undo`` (``label`` says what it restores)."""
        result = action()
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

    def rollback(self) -> str:
        """Undo every applied step, newest first; returns what was restored, in words."""
        restored: list[str] = []
        failed: list[str] = []
        while self._undo:
            undo = self._undo.pop()
            try:
                undo.action()
            except Exception as exc:  # keep undoing the rest: each is independent
                log.exception("undoing %s", undo.label)
                failed.append(f"{undo.label} ({exc})")
            else:
                restored.append(undo.label)
        self._open = False
        parts = []
        if restored:
            parts.append("restored: " + ", ".join(restored))
        if failed:
            parts.append("could NOT restore: " + "; ".join(failed) + " (check them by hand)")
        if not parts:
            return "nothing had been changed"
        return "; ".join(parts)

    def __enter__(self) -> Apply:
        return self

    def __exit__(self, kind: object, exc: BaseException | None, tb: object) -> None:
        if exc is None or not self._open:
            return
        if not isinstance(exc, Exception):  # KeyboardInterrupt, SystemExit: undo, re-raise
            self.rollback()
            return
        note = self.rollback()
        level = "error" if "could NOT" in note else "warning"
        self._events(level, self._source, f"{self.what} failed: {exc}; {note}")
        if isinstance(exc, SessionError):
            raise with_note(exc, note) from None
        raise ApplyFailed(f"{self.what} failed: {type(exc).__name__}: {exc}; {note}") from exc
