"""The simulated FX3's transfers: a block of frames to the host, with the faults on the way.

The stream engine (``firmware_models.fx3``) makes a block of frames and hands it to
``BlockSender.send``, which sends it through the stream socket (``firmware_models.fx3_socket``)
in one ``sendmsg`` where nothing comes between the frames. On the way, frame by frame, it draws
the injected faults (``InjectSpec.frame_*``: a frame dropped, a payload bit flipped, a
transfer cut short, the endpoint halted), sets the flags the FX3 adds (DEVICE_OVERFLOW after
frames that could not be delivered, LAST on a counted stream's last frame), applies the
deliberate defects (``firmware_models.defects``), packs whole frames into one transfer as far
as the host asked, and counts what it did (``StreamCounters``, SIM_GET_STREAM_STATS).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from camd.protocol.stream import HEADER_BYTES, U32_WRAP, FrameFlags, FrameHeader, pack_header
from firmware_models.defects import COUNTER_SKIP_EVERY, Defects, crc32c
from firmware_models.fx3_socket import StreamSocketServer
from firmware_models.inject import InjectSpec

# A frame of a block: its header and pixels as the source made them, whether it is the
# stream's last, and the faults in force when it was made.
BlockFrame = tuple[FrameHeader, np.ndarray, bool, InjectSpec]


@dataclass(slots=True)
class StreamCounters:
    """What the engine did since it was made (SIM_GET_STREAM_STATS)."""

    produced: int = 0  # frames taken from the source (counters used)
    sent: int = 0  # frames sent whole (including corrupted ones)
    bytes_sent: int = 0  # bytes of every transfer, whole or short
    dropped: int = 0  # injected: not sent
    corrupted: int = 0  # injected: sent whole with one payload bit flipped
    shortened: int = 0  # injected: the transfer ended early
    stalls: int = 0  # injected: the endpoint halted; the frame in flight was lost
    undelivered: int = 0  # made while no host could take them (none connected, or halted)

    def as_dict(self) -> dict[str, int]:
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}


class BlockSender:
    """Sends blocks of frames with their faults, counting into ``counters``."""

    def __init__(self, counters: StreamCounters) -> None:
        self.counters = counters
        self._counter_skew = 0  # stream_counter_skip: counter values skipped so far

    def send(
        self,
        server: StreamSocketServer | None,
        block: list[BlockFrame],
        overflow: bool,
        *,
        rng: np.random.Generator,
        defects: Defects,
        wait_ready: bool,
        stopped: Callable[[], bool],
        abort: Callable[[], bool],
    ) -> bool:
        """Send a block of frames with the faults, in one ``sendmsg`` where nothing comes
        between them; return whether frames went undelivered since the last one sent (the
        next frame sent then carries DEVICE_OVERFLOW). ``overflow``: frames went undelivered
        before the block. ``rng`` draws the faults; ``wait_ready``: the host sets the pace,
        so a halt in the block waits for its clear (until ``stopped()``); ``abort()`` gives up
        a send the host does not read."""
        c = self.counters
        transfers: list[list[bytes | memoryview]] = []
        kinds: list[tuple[bool, bool, int]] = []  # (cut short, corrupted, bytes) per frame
        packed = 0  # bytes in the last transfer, while whole frames may join it (packing)

        def flush() -> bool:
            """Send the transfers gathered so far; count them sent, or all undelivered."""
            if not transfers:
                return True
            assert server is not None
            sent = server.send_transfers(transfers, abort=abort)
            for short, corrupted, nbytes in kinds:
                if not sent:
                    c.undelivered += 1
                    continue
                c.bytes_sent += nbytes
                # Each frame counts once: one both corrupted and cut short reaches the host short.
                if short:
                    c.shortened += 1
                else:
                    c.sent += 1
                    if corrupted:
                        c.corrupted += 1
            transfers.clear()
            kinds.clear()
            return sent

        for header, pixels, last, spec in block:
            if wait_ready and server is not None:
                # As fast as the host reads: a halt in the block (an injected stall) waits
                # for the host's clear, as it would before the next frame is made.
                while not server.wait_ready(0.05) and not stopped():
                    pass
            if server is None or not server.ready:
                c.undelivered += 1
                overflow = True
                continue
            if spec.frame_drop and rng.random() < spec.frame_drop:
                c.dropped += 1
                continue
            if spec.frame_stall and rng.random() < spec.frame_stall:
                # The frames before it go out first: the halt comes after them on the wire.
                if not flush():
                    overflow = True
                if not server.stall():
                    c.undelivered += 1
                    overflow = True
                    continue
                c.stalls += 1
                continue
            flags = header.flags
            if overflow:
                flags |= FrameFlags.DEVICE_OVERFLOW
            if last:
                flags |= FrameFlags.LAST
            if flags != header.flags:
                header = header._replace(flags=flags)
            if defects.stream_counter_skip or defects.stream_crc_polynomial:
                header = self._defective(defects, header, pixels)
            # Checked when the source made it (frame_header); the flags added are known ones.
            head = pack_header(header)
            payload = pixels.data.cast("B")
            if len(payload) != header.payload_bytes:
                raise ValueError(
                    f"the source gave {len(payload)} payload bytes for a header saying "
                    f"{header.payload_bytes} (counter {header.counter})"
                )
            corrupted = False
            if spec.frame_corrupt and rng.random() < spec.frame_corrupt:
                damaged = np.frombuffer(payload, dtype=np.uint8).copy()
                bit = int(rng.integers(0, damaged.size * 8))
                damaged[bit >> 3] ^= np.uint8(1 << (bit & 7))
                payload = damaged.data
                corrupted = True
            parts: list[bytes | memoryview] = [head, payload]
            short = False
            if spec.frame_short and rng.random() < spec.frame_short:
                total = HEADER_BYTES + len(payload)
                keep = int(rng.integers(1, total))  # 1 .. total - 1
                parts = [head[:keep], payload[: max(0, keep - HEADER_BYTES)]]
                short = True
            nbytes = sum(len(p) for p in parts)
            pack = server.pack_bytes
            if packed and not short and transfers and packed + nbytes <= pack:
                transfers[-1].extend(parts)  # packed: whole frames back to back
                packed += nbytes
            else:
                transfers.append(parts)
                packed = 0 if short or not pack else nbytes  # a cut-short frame ends its transfer
            kinds.append((short, corrupted, nbytes))
            overflow = False
        if not flush():
            overflow = True
        return overflow

    def _defective(self, defects: Defects, header: FrameHeader, pixels: np.ndarray) -> FrameHeader:
        """The header as a defective FX3 frames it (firmware_models.defects); the header CRC
        is computed afterwards, by ``pack_header``, and so stays right."""
        if defects.stream_counter_skip:
            if header.counter % COUNTER_SKIP_EVERY == COUNTER_SKIP_EVERY - 1:
                self._counter_skew += 1
            header = header._replace(counter=(header.counter + self._counter_skew) % U32_WRAP)
        if defects.stream_crc_polynomial:
            header = header._replace(payload_crc32=crc32c(pixels.data.cast("B")))
        return header
