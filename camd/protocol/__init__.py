"""Sans-I/O core of the RS-422 command link: frame codec and command dictionary.

No sockets, no threads, no clocks: bytes in, frames out. Transports live in ``camd.link``.
"""

from camd.protocol.dictionary import (
    CommandSpec,
    Dictionary,
    DictionaryError,
    EncodeError,
    ErrorSpec,
    FieldSpec,
    PacketSpec,
    PayloadError,
    ProtocolError,
    load_dictionary,
)
from camd.protocol.frame import (
    MAX_PAYLOAD,
    OVERHEAD,
    SYNC,
    Decoder,
    DecoderStats,
    Frame,
    FrameType,
    crc16,
    encode_frame,
)

__all__ = [
    "MAX_PAYLOAD",
    "OVERHEAD",
    "SYNC",
    "CommandSpec",
    "Decoder",
    "DecoderStats",
    "Dictionary",
    "DictionaryError",
    "EncodeError",
    "ErrorSpec",
    "FieldSpec",
    "Frame",
    "FrameType",
    "PacketSpec",
    "PayloadError",
    "ProtocolError",
    "crc16",
    "encode_frame",
    "load_dictionary",
]
