"""Transports: the RS-422 command link over pyserial (frames over USB bulk arrive in a later issue)."""

from camd.link.command_link import (
    CommandLink,
    CommandRejected,
    CommandTimeout,
    ConnectionChange,
    LinkCounters,
    LinkDown,
    LinkError,
    Message,
    Response,
    Unsolicited,
)

__all__ = [
    "CommandLink",
    "CommandRejected",
    "CommandTimeout",
    "ConnectionChange",
    "LinkCounters",
    "LinkDown",
    "LinkError",
    "Message",
    "Response",
    "Unsolicited",
]
