"""Ready-made frames for the simulated FX3's stream engine (benchmarks, tests).

``BankSource`` is a frame source (``firmware_models.fx3.FrameSource``) that replays a bank of
frames with fresh headers, so that a stream costs the simulator no rendering: what
``python -m firmware_models.fx3`` streams, and what the USB and host-pipeline benchmarks read.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from camd.protocol.stream import FrameFlags, FrameHeader, StreamMode, crc32


class BankSource:
    """A frame source replaying a bank of ready-made frames (benchmarks, tests).

    Frame ``counter`` is bank frame ``counter % len(frames)`` with a fresh counter and
    timestamp (``t0_ns + counter * line_period_ns``); payload CRCs and the SATURATED flag
    (some pixel at 2**bits - 1) are computed once per bank frame, so a frame costs the source
    no pass over its pixels. ``stages`` defaults to the rows in TDI mode, 0 in area mode.
    """

    def __init__(
        self,
        frames: Sequence[np.ndarray],
        *,
        line_period_ns: int,
        bits: int,
        mode: StreamMode,
        stages: int | None = None,
        t0_ns: int = 0,
    ) -> None:
        if not frames:
            raise ValueError("a bank source needs at least one frame")
        self.line_period_ns = line_period_ns
        self.bits = bits
        self.mode = StreamMode(mode)
        self.t0_ns = t0_ns
        self.frames: list[np.ndarray] = []
        self._crc: list[int] = []
        self._flags: list[FrameFlags] = []
        adc_max = (1 << bits) - 1
        for i, frame in enumerate(frames):
            if frame.ndim != 2 or frame.dtype != np.dtype("<u2"):
                raise ValueError(f"bank frame {i} is {frame.ndim}-D {frame.dtype}, not 2-D uint16")
            frame = np.ascontiguousarray(frame)
            frame.flags.writeable = False  # shared by every replay: nobody may change it
            self.frames.append(frame)
            self._crc.append(crc32(frame.data))
            saturated = bool((frame >= adc_max).any())
            self._flags.append(FrameFlags.SATURATED if saturated else FrameFlags(0))
        rows = self.frames[0].shape[0]
        self.stages = stages if stages is not None else (rows if mode == StreamMode.TDI else 0)

    @classmethod
    def random(
        cls,
        rows: int,
        cols: int,
        *,
        count: int = 4,
        bits: int = 12,
        seed: int = 0,
        line_period_ns: int = 25_000,
        mode: StreamMode = StreamMode.TDI,
    ) -> BankSource:
        """``count`` frames of uniform random ``bits``-bit pixels."""
        rng = np.random.default_rng(seed)
        bank = [
            rng.integers(0, 1 << bits, size=(rows, cols), dtype=np.uint16) for _ in range(count)
        ]
        return cls(bank, line_period_ns=line_period_ns, bits=bits, mode=mode)

    def __call__(self, counter: int) -> tuple[FrameHeader, np.ndarray]:
        i = counter % len(self.frames)
        frame = self.frames[i]
        rows, cols = frame.shape
        header = FrameHeader(
            counter=counter,
            timestamp_ns=(self.t0_ns + counter * self.line_period_ns) % (1 << 64),
            line_period_ns=self.line_period_ns,
            rows=rows,
            cols=cols,
            bits=self.bits,
            mode=self.mode,
            stages=self.stages,
            stage_position=0,
            flags=self._flags[i],
            payload_bytes=frame.nbytes,
            payload_crc32=self._crc[i],
        )
        return header, frame
