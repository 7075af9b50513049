"""The errors a daemon operation raises; the API maps each to an HTTP status (docs/api.md).

Every message says what went wrong and what to change. They live apart from the session and
the services so that any of them can raise them without importing the others.
"""

from __future__ import annotations

from collections.abc import Callable

LinkWait = Callable[[], str | None]
"""Wait (bounded) until the camera answers again: None once it does, else why it does not."""


class SessionError(Exception):
    """Base of the errors a session operation raises; str() says what to change.

    ``link_wait`` is set on the errors of a lost link or a silent device (``Disconnected``,
    ``DeviceTimeout`` raised by ``DeviceAccess``): putting back what a failed request changed
    needs the link, so the undo waits with it first (``camd.daemon.transaction``).
    """

    link_wait: LinkWait | None = None


class Disconnected(SessionError):
    """No camera on the link (HTTP 503)."""


class NoFrameDevice(SessionError):
    """The camera's USB frame stream cannot be opened (HTTP 503, code ``no_frame_device``): no
    device with the configured VID:PID, no permission, no USB library, or no simulated camera on
    the stream socket. The serial link may be fine; the message names what was looked for and
    what to check."""


class DeviceTimeout(SessionError):
    """The device did not answer after every retry (HTTP 504)."""


class DeviceRejected(SessionError):
    """The device refused the command (NAK) or answered something undecodable (HTTP 502)."""

    def __init__(self, message: str, name: str = "") -> None:
        super().__init__(message)
        self.name = name


class EndedEarly(SessionError):
    """An acquisition ended before all its frames came: the camera ended the stream early
    (HTTP 502, code ``ended_early``); the message says after how many frames, why, and what the
    recording keeps."""


class StorageFull(SessionError):
    """An acquisition's recording could not be written (a full disk) and the acquisition was
    stopped (HTTP 507, code ``insufficient_storage``); the message says what the file keeps."""


class BadRequest(SessionError, ValueError):
    """A parameter is invalid (HTTP 400)."""


class NotFound(SessionError, LookupError):
    """What the request names does not exist (HTTP 404); the message lists what does."""


class WrongState(SessionError):
    """The request does not fit what its target is doing (HTTP 409): resuming a job that
    runs, pausing one that has ended; the message says what would fit."""


class LinkUntrained(SessionError):
    """Imaging refused: the sensor's LVDS link is not trained (HTTP 409)."""


class SensorMismatch(SessionError):
    """The camera reports another sensor than the daemon's ``sensor.name`` (HTTP 409): its
    registers, training and imaging are refused; the message says what to change."""


class ArchiveUnreadable(SessionError):
    """The telemetry archive cannot be read (a corrupt file) (HTTP 503); its writes go on
    failing quietly, the limits are still checked (camd.daemon.telemetry.GuardedArchive)."""


class EstopLatched(SessionError):
    """Motion or acquisition refused: the emergency stop is latched until a client with
    control releases it (HTTP 409; camd.daemon.estop)."""


class Busy(SessionError):
    """Refused because an acquisition (scan, stare, stream, wheel run) is running (HTTP 409);
    the message names it and the command that stops it."""


class NotInControl(SessionError):
    """A state-changing request from a client that does not hold control (HTTP 423); the
    message names the holder and how to take control."""


class NoControl(SessionError):
    """A request only the controlling client may make, while nobody holds control (HTTP 409);
    the message says to take control first."""


class SimulatorError(SessionError):
    """The simulated camera could not be started; ``usage`` is True for bad arguments."""

    def __init__(self, message: str, usage: bool = False) -> None:
        super().__init__(message)
        self.usage = usage


def with_note(exc: SessionError, note: str) -> SessionError:
    """The same kind of error (so the same HTTP status) with ``note`` appended to its message,
    e.g. what was restored after a request failed part-way."""
    message = f"{exc}; {note}"
    noted: SessionError
    if isinstance(exc, DeviceRejected):
        noted = DeviceRejected(message, exc.name)
    elif isinstance(exc, SimulatorError):
        noted = SimulatorError(message, exc.usage)
    else:
        noted = type(exc)(message)
    noted.link_wait = exc.link_wait  # an enclosing request's undo needs the link too
    return noted


def unreachable(exc: BaseException) -> str:
    """Why a step of the shutdown could not be done, in a few words: "the camera is gone" for
    a lost link, "the camera did not answer" for a silent one (both expected when the camera
    stopped first), else the error itself."""
    if isinstance(exc, Disconnected):
        return "the camera is gone"
    if isinstance(exc, DeviceTimeout):
        return "the camera did not answer"
    return str(exc)
