"""Transports: the RS-422 command link over pyserial, the frame stream over USB bulk (pyusb)."""

from camd.link.command_link import (
    CommandLink,
    CommandRejected,
    CommandTimeout,
    ConnectionChange,
    LinkCounters,
    LinkDown,
    LinkError,
    Message,
    RawExchange,
    Response,
    Unsolicited,
)
from camd.link.frame_stream import (
    FrameStream,
    ReceivedFrame,
    StreamError,
    StreamStats,
)

__all__ = [
    "CommandLink",
    "CommandRejected",
    "CommandTimeout",
    "ConnectionChange",
    "FrameStream",
    "LinkCounters",
    "LinkDown",
    "LinkError",
    "Message",
    "RawExchange",
    "ReceivedFrame",
    "Response",
    "StreamError",
    "StreamStats",
    "Unsolicited",
]
