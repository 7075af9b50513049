"""The stream socket of the simulated FX3: the message framing both halves speak.

The host half (``firmware_models.fx3_backend.Fx3Backend``, loaded by the daemon) reads the
socket; the device half (``firmware_models.fx3.StreamSocketServer``, in the simulator's
process) serves it. Each USB transfer is one message::

    device -> host   u8 kind, 3 zero bytes, u32 length (little-endian), then ``length`` bytes
                     kind 1 TRANSFER (the bytes of one USB transfer), 2 STALL (length 0:
                     the endpoint halted; the frame in flight is lost), 4 READY (length 0,
                     first on every connection: the device now serves this host)
    host -> device   kind 3 CLEAR_HALT (length 0): the host cleared the halt; sending resumes
                     kind 5 SET_PACKING (no bytes follow; ``length`` is the value): the host's
                     vendor request PACK_REQUEST, passed on: from now on a transfer holds
                     whole frames back to back, up to ``length`` bytes (0: one frame each)

Nothing but the standard library: both processes import it.
"""

from __future__ import annotations

import struct

MSG = struct.Struct("<BxxxI")
MSG_TRANSFER = 1
MSG_STALL = 2
MSG_CLEAR_HALT = 3
MSG_READY = 4  # device -> host, first on every connection: the device now serves this host
MSG_SET_PACKING = 5  # host -> device: pack frames into transfers of up to ``length`` bytes
# The vendor request (bmRequestType 0x40, to the device) that asks the streamer to pack whole
# frames back to back into transfers of up to wValue KiB (0: one frame per transfer, the
# default on every new connection); docs/stream.md "Packed transfers".
PACK_REQUEST = 0xB5
MAX_TRANSFER_BYTES = 1 << 30
SOCKET_BUFFER_BYTES = 4 << 20  # a few frames in flight: fewer wake-ups per frame
