"""Sans-I/O core of the RS-422 command link (frame codec, command dictionary), and the format
of the USB frame stream (``camd.protocol.stream``).

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
from camd.protocol.stream import (
    HEADER_BYTES,
    FrameFlags,
    FrameHeader,
    StreamFormatError,
    StreamMode,
    decode_header,
    encode_header,
    frame_header,
    payload_ok,
)

__all__ = [
    "HEADER_BYTES",
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
    "FrameFlags",
    "FrameHeader",
    "FrameType",
    "PacketSpec",
    "PayloadError",
    "ProtocolError",
    "StreamFormatError",
    "StreamMode",
    "crc16",
    "decode_header",
    "encode_frame",
    "encode_header",
    "frame_header",
    "load_dictionary",
    "payload_ok",
]
