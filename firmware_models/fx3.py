"""The simulated EZ-USB FX3's device half: the stream engine and ``python -m firmware_models.fx3``.

Runs in the simulator's process (``python -m firmware_models``, whose FPGA model and imaging
pipeline feed the engine, or ``python -m firmware_models.fx3`` alone):

- ``StreamEngine``: the FX3 firmware's job: takes frames from a source (the camera model, or a
  ``BankSource`` of ready-made frames, ``firmware_models.fx3_bank``), paces them and sends
  them in blocks (``firmware_models.fx3_transfers``: each frame as one USB transfer, with the
  injected faults, ``InjectSpec.frame_*``);
- ``StreamSocketServer`` (``firmware_models.fx3_socket``): the simulator's end of the stream
  socket (one host at a time);
- ``python -m firmware_models.fx3 --socket PATH``: a streamer alone, for benchmarks.

The host half, the pyusb backend the daemon loads (``Fx3Backend`` / ``get_backend``), is
``firmware_models.fx3_backend``; the socket's message framing, which both halves speak, is
``firmware_models.fx3_wire``. Each frame's transfer ends with a short packet (docs/stream.md).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import FrameType

import numpy as np

from camd.protocol.stream import HEADER_BYTES, U32_WRAP, FrameHeader
from firmware_models.defects import NONE
from firmware_models.fx3_bank import BankSource
from firmware_models.fx3_socket import StreamSocketServer
from firmware_models.fx3_transfers import BlockFrame, BlockSender, StreamCounters
from firmware_models.inject import InjectSpec
from firmware_models.pacing import Pacer

__all__ = [
    "BLOCK_S",
    "MAX_BLOCK_FRAMES",
    "BankSource",
    "DoneCallback",
    "FrameSource",
    "StreamCounters",
    "StreamEngine",
    "StreamSocketServer",
    "main",
]

log = logging.getLogger(__name__)

# A paced stream makes and sends the frames due within BLOCK_S together, in one system call
# (at the hr400's fastest line rate, 41 us per frame, one call per frame would be the limit;
# the imaging pipeline renders such a block in one pass, and 2 ms rather than 1 ms took a
# quarter off a rendered frame's CPU at 164 us frames); a block goes out when its last frame
# is due, so no frame leaves early and, on schedule, none more than BLOCK_S late. An unpaced
# stream, or one catching up, sends up to MAX_BLOCK_FRAMES at a time (3 buffers each: well
# under the kernel's 1024 per sendmsg).
BLOCK_S = 2e-3
MAX_BLOCK_FRAMES = 64


# -- the stream engine ----------------------------------------------------------------------

FrameSource = Callable[[int], tuple[FrameHeader, np.ndarray]]
DoneCallback = Callable[[int, int], None]


@dataclass(slots=True)
class _Stream:
    frames: int
    period_s: float
    pace: bool
    next_counter: int  # after the stream's last frame so far
    end_after: int | None = None  # the camera ends the stream early, after this many frames
    produced: int = 0
    stop: bool = False
    done: bool = False
    notify: bool = True  # call on_done when it ends


class StreamEngine:
    """The FX3 firmware's streaming job: frames from ``source`` to the host over ``server``.

    ``start(frames, period_s, pace)`` begins a stream: the engine's thread calls
    ``source(counter)`` for counter = ``first_counter``, +1, ... (mod 2**32); the source
    returns the frame's complete header (payload CRC included) and its (rows, cols) uint16
    pixels. Each frame goes out as one transfer (header + pixels by scatter-gather, no copy).
    ``pace=True`` sends frames on a clock of ``period_s`` in wall time, by deadlines
    (``firmware_models.pacing``: frames made late are followed by the next at once until the
    stream is back on schedule, within a bound; a source slower than the clock for good just
    makes the stream slower; nothing is dropped for that). Frames due within ``BLOCK_S`` of
    each other are made and sent together when the last of them is due, in one system call
    (``MAX_BLOCK_FRAMES`` at a time unpaced, or behind the schedule): a line rate of tens of
    kHz is not a system call per frame. Frames made while no host can take them (none
    connected, or the endpoint halted) are discarded and counted ``undelivered``, and the
    next frame sent carries DEVICE_OVERFLOW. ``pace=False`` sends as
    fast as the host reads, and waits (making nothing) while no host can take frames.

    A counted stream (``frames > 0``) ends by itself after that many frames, the last one
    flagged LAST (its header CRC recomputed). ``stop()`` ends a stream after the frames in
    progress (a block: the frames already made go out). Either way ``on_done(frames_produced, next_counter)`` is called once, from the
    engine's thread, after the stream's last frame went out (unless ``stop(notify=False)``).

    Faults (``inject``, read per frame so it may be replaced at any time; rates per frame,
    drawn from a numpy Generator seeded with ``seed``): frame_drop (not sent, counter used),
    frame_corrupt (one payload bit flipped after the CRC, in a copy: the source's array is
    never written), frame_short (a random prefix of 1 .. size-1 bytes is the whole transfer),
    frame_stall (the endpoint halts: the frame is lost, nothing is sent until the host clears
    the halt).

    ``start`` and ``stop`` never wait for the engine's thread, so they may be called while
    holding a lock the source takes. One thread serves all streams of the engine's life;
    ``close()`` ends it.
    """

    def __init__(
        self,
        source: FrameSource | None = None,
        *,
        server: StreamSocketServer | None = None,
        inject: InjectSpec | None = None,
        seed: int | None = 0,
        on_done: DoneCallback | None = None,
    ) -> None:
        self.source = source
        # Told before each block which frames the source will be asked for (first counter,
        # count), so that it can make them together (the imaging pipeline renders them in
        # one go); None: the source makes each frame when asked.
        self.prepare: Callable[[int, int], None] | None = None
        # Called once as each stream begins, before its clock starts and before any frame is
        # counted: the source's first-frame work (the imaging pipeline's compiled kernels,
        # fixed pattern and noise bank, up to a second of a core when cold), so that a frame
        # in progress is never that far behind its time; a host draining a stop gives the
        # frames the camera counted one read timeout (docs/stream.md). None: nothing to do.
        self.ready: Callable[[], None] | None = None
        self.server = server
        self.inject = inject if inject is not None else InjectSpec()
        self.on_done = on_done
        self.counters = StreamCounters()
        self._sender = BlockSender(self.counters)  # the faults, the flags, the packing
        self.next_counter = 0
        self.defects = NONE  # deliberate defects (firmware_models.defects), off
        self._rng = np.random.default_rng(seed)
        self._cond = threading.Condition()
        self._pending: _Stream | None = None
        self._current: _Stream | None = None
        self._last: _Stream | None = None
        self._closing = False
        self._thread: threading.Thread | None = None

    # -- control ----------------------------------------------------------------------------------

    @property
    def running(self) -> bool:
        """A stream is on: started, not stopped, not finished."""
        with self._cond:
            s = self._pending or self._current
            return s is not None and not s.stop and not s.done

    @property
    def frames_produced(self) -> int:
        """Frames produced by the current (or last) stream, the one in progress included."""
        with self._cond:
            s = self._pending or self._current or self._last
            return s.produced if s is not None else 0

    def start(
        self,
        frames: int = 0,
        period_s: float = 0.0,
        pace: bool = True,
        *,
        first_counter: int | None = None,
        end_after: int | None = None,
    ) -> None:
        """Begin a stream of ``frames`` frames (0: until ``stop``), one per ``period_s``.

        ``first_counter`` defaults to where the previous stream ended (``next_counter``).
        ``end_after``: end the stream by itself after that many frames if it has not ended
        before, like a camera that ends a stream early (the last frame is not flagged LAST;
        ``on_done`` says how many it sent)."""
        if frames < 0:
            raise ValueError(f"frames = {frames}: give a count >= 1, or 0 to stream until stop")
        if not period_s >= 0.0:
            raise ValueError(f"period_s = {period_s} must be >= 0")
        if self.source is None:
            raise RuntimeError("the stream engine has no frame source; set engine.source")
        with self._cond:
            if self._closing:
                raise RuntimeError("the stream engine is closed")
            if self.running:
                raise RuntimeError("a stream is already running; stop() it first")
            if first_counter is not None:
                # A stopped stream finishing its frame in progress has used its last counter.
                self.next_counter = first_counter % U32_WRAP
            self._pending = _Stream(
                frames=frames,
                period_s=period_s,
                pace=pace,
                next_counter=self.next_counter,
                end_after=end_after,
            )
            if self._thread is None:
                self._thread = threading.Thread(
                    target=self._run, name="fx3-stream-engine", daemon=True
                )
                self._thread.start()
            self._cond.notify_all()

    def reseed(self, seed: int) -> None:
        """Restart the injected-fault random stream from ``seed`` (in place: a stream in
        progress draws from the restarted sequence from its next frame)."""
        with self._cond:
            self._rng.bit_generator.state = np.random.default_rng(seed).bit_generator.state

    def set_period(self, period_s: float) -> None:
        """Change the running stream's frame period from the next frame on (the sensor's line
        period was re-programmed while streaming). Harmless when not streaming or unpaced."""
        if not period_s > 0.0:
            raise ValueError(f"period_s = {period_s} must be > 0")
        with self._cond:
            s = self._pending or self._current
            if s is not None and s.period_s > 0:
                s.period_s = period_s

    def stop(self, *, notify: bool = True) -> int:
        """End the stream after the frame in progress; frames it produced (that one included).

        Does not wait for that frame to go out (see ``wait_idle``). ``notify=False``: do not
        call ``on_done`` for this stream (the caller reports the end itself)."""
        never_began = False
        with self._cond:
            s = self._pending or self._current
            if s is None:
                return self._last.produced if self._last is not None else 0
            s.stop = True
            s.notify = s.notify and notify
            if s is self._pending:
                self._pending = None
                self._last = s
                s.done = True
                never_began = True
            self._cond.notify_all()
            produced, next_counter = s.produced, s.next_counter
        if never_began and s.notify and self.on_done is not None:
            self.on_done(produced, next_counter)  # it made no frame; still, it ended
        return produced

    def wait_idle(self, timeout_s: float | None = None) -> bool:
        """Wait until no stream is in progress (the last frame is out); False on timeout."""
        with self._cond:
            return self._cond.wait_for(
                lambda: self._pending is None and self._current is None, timeout_s
            )

    def close(self, timeout_s: float = 5.0) -> None:
        """Stop any stream and end the engine's thread (an unread transfer is abandoned)."""
        with self._cond:
            self._closing = True
            for s in (self._pending, self._current):
                if s is not None:
                    s.stop = True
            self._cond.notify_all()
        if self._thread is not None:
            self._thread.join(timeout_s)

    # -- the thread -------------------------------------------------------------------------------

    def _run(self) -> None:
        while True:
            with self._cond:
                self._cond.wait_for(lambda: self._pending is not None or self._closing)
                if self._pending is None:
                    return
                stream, self._pending = self._pending, None
                self._current = stream
            try:
                self._stream(stream)
            except Exception:
                log.exception("stream engine: the stream failed")
            with self._cond:
                stream.done = True
                self._current = None
                self._last = stream
                produced, next_counter = stream.produced, stream.next_counter
                self._cond.notify_all()
            if stream.notify and self.on_done is not None:
                try:
                    self.on_done(produced, next_counter)
                except Exception:
                    log.exception("stream engine: on_done failed")

    def _abort_send(self) -> bool:
        return self._closing

    def _wait(self, stream: _Stream, timeout_s: float) -> None:
        """Sleep up to ``timeout_s``, waking early for stop/close."""
        with self._cond:
            self._cond.wait_for(lambda: stream.stop or self._closing, timeout_s)

    def _block_frames(self, stream: _Stream) -> int:
        """How many frames to make and send together: those due within BLOCK_S (at least
        one), or MAX_BLOCK_FRAMES when the host sets the pace."""
        if not stream.pace or stream.period_s <= 0:
            return MAX_BLOCK_FRAMES
        return max(1, min(MAX_BLOCK_FRAMES, int(BLOCK_S / stream.period_s)))

    def _stream(self, stream: _Stream) -> None:
        if self.ready is not None:
            try:
                self.ready()
            except Exception:  # the first frame then does the work, and fails if it must
                log.exception("stream engine: getting the source ready failed")
        pacer = Pacer(time.monotonic())  # deadlines of a paced stream (firmware_models.pacing)
        overflow = False  # frames were undelivered since the last one sent
        while True:
            if not stream.pace:
                # As fast as the host reads: with nobody to take frames, make none.
                while not stream.stop and not self._closing:
                    server = self.server
                    if server is not None and server.wait_ready(0.05):
                        break
                    if server is None:
                        self._wait(stream, 0.05)
            count = self._block_frames(stream)
            if stream.pace and stream.period_s > 0:
                # A block goes out when its last frame is due: no frame leaves before its time;
                # behind the schedule, the frames already due go at once (the stream catches up).
                now = time.monotonic()
                count = pacer.block_frames(count, stream.period_s, MAX_BLOCK_FRAMES, now_s=now)
                wait_s = pacer.wait_s(count, stream.period_s, now_s=now)
                if wait_s > 0:
                    self._wait(stream, wait_s)
            self._announce(stream, count)
            block: list[BlockFrame] = []
            ended = False
            for _ in range(count):
                with self._cond:
                    if stream.stop or self._closing:
                        ended = True
                        break
                    if stream.frames and stream.produced >= stream.frames:
                        ended = True
                        break
                    if stream.end_after is not None and stream.produced >= stream.end_after:
                        ended = True  # cut short on purpose (SIM_FAIL_NEXT end_stream)
                        break
                    counter = self.next_counter
                    self.next_counter = (counter + 1) % U32_WRAP
                    stream.next_counter = self.next_counter
                    stream.produced += 1
                    self.counters.produced += 1
                    last = stream.frames > 0 and stream.produced == stream.frames
                source = self.source
                assert source is not None
                header, pixels = source(counter)
                # On a clock, like the sensor: the sleep's wake-up latency does not accumulate.
                # Read after the source, which may have changed the period (``set_period``).
                pacer.advance(stream.period_s)
                # The faults in force when the frame was made (``inject`` may change any time).
                block.append((header, pixels, last, self.inject))
            if block:
                overflow = self._sender.send(
                    self.server,
                    block,
                    overflow,
                    rng=self._rng,
                    defects=self.defects,
                    wait_ready=not stream.pace,
                    stopped=lambda: stream.stop or self._closing,
                    abort=self._abort_send,
                )
            if ended:
                return

    def _announce(self, stream: _Stream, count: int) -> None:
        """Tell the source (``prepare``) which frames it is about to be asked for: the next
        ``count``, or fewer where the stream ends, so it may make them together."""
        if self.prepare is None:
            return
        with self._cond:
            if stream.frames:
                count = min(count, stream.frames - stream.produced)
            if stream.end_after is not None:
                count = min(count, stream.end_after - stream.produced)
            first = self.next_counter
        if count > 0:
            self.prepare(first, count)


# -- python -m firmware_models.fx3 ------------------------------------------------------------


def main(argv: Sequence[str] | None = None) -> int:
    """A simulated FX3 alone, streaming a random frame bank (for benchmarks and tests).

    Prints one JSON line when it listens, and one with the engine's counters when it ends
    (SIGTERM, SIGINT or end of standard input)."""
    p = argparse.ArgumentParser(
        prog="python -m firmware_models.fx3",
        description="A simulated FX3 frame streamer on a Unix socket, replaying random frames.",
    )
    p.add_argument("--socket", required=True, type=Path, help="Unix socket path to listen on")
    p.add_argument("--rows", type=int, default=534, help="window rows (default 534)")
    p.add_argument("--cols", type=int, default=2048, help="window columns (default 2048)")
    p.add_argument("--bits", type=int, default=12, help="significant bits (default 12)")
    p.add_argument("--bank", type=int, default=4, help="distinct frames replayed (default 4)")
    p.add_argument("--frames", type=int, default=0, help="frames to send, 0 = until stopped")
    p.add_argument(
        "--period-s", type=float, default=0.0, help="frame period; 0 = unpaced (default)"
    )
    p.add_argument("--inject", default="", help="faults, e.g. 'frame_drop=0.01'")
    p.add_argument("--seed", type=int, default=0, help="seed of the frames and the faults")
    args = p.parse_args(argv)
    if args.rows < 1 or args.cols < 1 or not 1 <= args.bits <= 16 or args.bank < 1:
        p.error("--rows/--cols/--bank must be >= 1 and --bits 1..16")
    source = BankSource.random(
        args.rows,
        args.cols,
        count=args.bank,
        bits=args.bits,
        seed=args.seed,
        line_period_ns=round(args.period_s * 1e9) if args.period_s > 0 else 25_000,
    )
    stop = threading.Event()

    def on_signal(signum: int, frame: FrameType | None) -> None:
        stop.set()

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    with StreamSocketServer(args.socket) as server:
        engine = StreamEngine(source, server=server, inject=InjectSpec.parse(args.inject))
        engine.start(args.frames, args.period_s, pace=args.period_s > 0)
        frame_bytes = HEADER_BYTES + 2 * args.rows * args.cols
        ready = {"socket": str(args.socket), "frame_bytes": frame_bytes, "pid": os.getpid()}
        print(json.dumps(ready), flush=True)
        threading.Thread(target=_wait_stdin_eof, args=(stop,), daemon=True).start()
        while not stop.wait(0.5):
            pass
        engine.close()
    print(json.dumps(engine.counters.as_dict()), flush=True)
    return 0


def _wait_stdin_eof(stop: threading.Event) -> None:
    with contextlib.suppress(OSError):
        while os.read(sys.stdin.fileno(), 4096):
            pass
    stop.set()


if __name__ == "__main__":
    sys.exit(main())
