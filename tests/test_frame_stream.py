"""FrameStream (camd.link.frame_stream) against the simulated FX3 over a real Unix socket.

The engine runs in this process (its own thread) and the host reads through pyusb and the
Fx3Backend, as the daemon does; faults come from seeded InjectSpec rates, so every count is
checked exactly against what the engine did.
"""

from __future__ import annotations

import dataclasses
import shutil
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest

from camd.link import FrameStream, ReceivedFrame, StreamError, StreamStats
from camd.link.packed import FrameBatch
from camd.protocol.stream import (
    HEADER_BYTES,
    U32_WRAP,
    FrameFlags,
    FrameHeader,
    encode_header,
    payload_ok,
)
from firmware_models.fx3 import BankSource, StreamEngine, StreamSocketServer
from firmware_models.fx3_backend import Fx3Backend, get_backend
from firmware_models.inject import InjectSpec
from firmware_models.usb_device import SimulatedUsbDevice

pytestmark = pytest.mark.timeout(60)

ROWS, COLS = 16, 100
FRAME_BYTES = HEADER_BYTES + 2 * ROWS * COLS  # 3264: several 1024-byte packets


@dataclasses.dataclass
class Got:
    """What a consumer saw: copies, as consumers must make."""

    counter: int
    pixels: np.ndarray
    gap_before: int
    index: int
    flags: FrameFlags
    ok: bool


class Rig:
    """A stream socket server, an engine on it, and a FrameStream reading it."""

    def __init__(self, path: Path, bank: BankSource, **stream_kwargs: object) -> None:
        self.server = StreamSocketServer(path)
        self.server.start()
        self.engine = StreamEngine(bank, server=self.server)
        self.bank = bank
        # A queue deeper than any run's frames: these tests count the faults injected, and a
        # consumer starved on a busy machine would add overruns to them (the fourth loaded run
        # saw 26 in 300 frames at the default 32). The overrun test sets its own small queue.
        kwargs: dict[str, object] = {"timeout_s": 0.2, "queue_frames": 1024, **stream_kwargs}
        self.stream = FrameStream(backend=get_backend(path), **kwargs)  # type: ignore[arg-type]
        self.stream.open()
        # Frames made before the server has taken this host's connection would go nowhere
        # (counted undelivered by the engine, unknown to the host): wait for it.
        assert wait_until(lambda: self.server.connections_accepted == 1 and self.server.connected)
        self.got: list[Got] = []
        self.stream.add_consumer(self.record)

    def record(self, frame: ReceivedFrame) -> None:
        self.got.append(
            Got(
                frame.header.counter,
                frame.pixels.copy(),
                frame.gap_before,
                frame.index,
                frame.header.flags,
                payload_ok(frame.header, frame.pixels),
            )
        )

    def run(self, frames: int, *, spec: InjectSpec | None = None, seed: int = 0) -> StreamStats:
        """Stream ``frames`` frames unpaced, tell the host where it ended, drain; the stats."""
        if spec is not None:
            self.engine.inject = spec
        self.engine._rng = np.random.default_rng(seed)
        self.stream.start(max_frame_bytes=FRAME_BYTES)
        if self.stream.packed:
            # The device's socket thread takes the packing request in its own time: frames sent
            # before it did go one a transfer (a busy machine's run read 400 frames in 400
            # reads). The daemon asks before START_STREAM, over another line; here, wait.
            asked = self.stream.pack_bytes
            assert wait_until(lambda: self.server.pack_bytes == asked)
        self.engine.start(frames, 0.0, pace=False)
        assert self.engine.wait_idle(30.0)
        self.stream.expect_end(self.engine.next_counter)
        assert self.stream.wait_drained(30.0)
        self.stream.stop()
        return self.stream.stats()

    def bit_exact(self) -> bool:
        return all(np.array_equal(g.pixels, self.bank.frames[g.counter % 3]) for g in self.got)

    def close(self) -> None:
        self.stream.close()
        self.engine.close()
        self.server.stop()


@pytest.fixture
def sock_path() -> Iterator[Path]:
    d = Path(tempfile.mkdtemp(prefix="fs-"))
    yield d / "usb.sock"
    shutil.rmtree(d, ignore_errors=True)


@pytest.fixture
def bank() -> BankSource:
    return BankSource.random(ROWS, COLS, count=3, seed=7)


@pytest.fixture
def rig(sock_path: Path, bank: BankSource) -> Iterator[Rig]:
    r = Rig(sock_path, bank)
    yield r
    r.close()


def wait_until(predicate: Callable[[], bool], timeout_s: float = 10.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.002)
    return True


# -- the clean path -------------------------------------------------------------------------------


def test_n_frames_in_n_out_bit_exact_and_in_order(rig: Rig) -> None:
    stats = rig.run(150)
    assert [g.counter for g in rig.got] == list(range(150))
    assert [g.index for g in rig.got] == list(range(150))
    assert all(g.gap_before == 0 and g.ok for g in rig.got)
    assert rig.bit_exact()
    assert rig.got[-1].flags & FrameFlags.LAST
    assert (stats.frames, stats.bytes, stats.first_counter, stats.last_counter) == (
        150,
        150 * FRAME_BYTES,
        0,
        149,
    )
    assert stats.lost == stats.corrupt == stats.short == stats.overruns == stats.out_of_order == 0
    assert stats.reads == 150  # one read per frame: whole frames land in place
    assert stats.mbyte_per_s > 0 and stats.mpix_per_s > 0 and stats.elapsed_s > 0
    assert set(stats.as_dict()) >= {
        "frames", "bytes", "lost", "corrupt", "short", "overruns", "stalls", "timeouts",
        "out_of_order", "reads", "first_counter", "last_counter", "elapsed_s", "mpix_per_s",
        "mbyte_per_s",
    }  # fmt: skip


def test_pixels_are_a_read_only_view_into_a_slot(rig: Rig) -> None:
    seen: list[tuple[bool, bool, int]] = []

    def inspect(frame: ReceivedFrame) -> None:
        address = frame.pixels.__array_interface__["data"][0]
        slots = [s.buf.buffer_info()[0] + HEADER_BYTES for s in rig.stream._queue.slots]
        seen.append(
            (frame.pixels.flags.writeable, frame.pixels.flags.owndata, slots.index(address))
        )

    rig.stream.add_consumer(inspect)
    rig.run(5)
    assert len(seen) == 5
    assert all(not writeable and not owndata for writeable, owndata, _ in seen)


def test_start_and_stop_repeat_on_one_open_stream(rig: Rig) -> None:
    first = rig.run(10)
    second = rig.run(10)  # counters continue from 10
    assert first.frames == second.frames == 10
    assert (second.first_counter, second.last_counter) == (10, 19)
    assert [g.index for g in rig.got] == list(range(10)) * 2


def test_frames_spanning_several_reads(sock_path: Path, bank: BankSource) -> None:
    rig = Rig(sock_path, bank, read_bytes=1024)
    try:
        stats = rig.run(60)
        assert [g.counter for g in rig.got] == list(range(60)) and rig.bit_exact()
        assert stats.reads == 60 * 4  # 3264 bytes: 1024 + 1024 + 1024 + 192
        # Cut-short transfers mid-reassembly: counted, never delivered, the rest intact.
        rig.got.clear()
        stats = rig.run(200, spec=InjectSpec(frame_short=0.2), seed=4)
        assert stats.short == rig.engine.counters.shortened > 0
        assert stats.lost == stats.corrupt == 0
        assert stats.frames == 200 - stats.short
        assert rig.bit_exact() and all(g.ok for g in rig.got)
    finally:
        rig.close()


def test_read_bytes_must_be_whole_packets(sock_path: Path) -> None:
    with StreamSocketServer(sock_path):
        stream = FrameStream(backend=get_backend(sock_path), read_bytes=1000)
        with pytest.raises(ValueError, match="not a multiple of the endpoint's 1024-byte packets"):
            stream.open()


# -- faults -----------------------------------------------------------------------------------------


def gaps_add_up(rig: Rig, stats: StreamStats) -> None:
    """Every counter from the first to the last is delivered or counted, once."""
    missing = stats.lost + stats.corrupt + stats.short + stats.overruns
    assert sum(g.gap_before for g in rig.got) == missing
    for a, b in zip(rig.got, rig.got[1:], strict=False):
        assert b.gap_before == (b.counter - a.counter - 1) % U32_WRAP


def test_injected_drops_are_lost_exactly(rig: Rig) -> None:
    stats = rig.run(400, spec=InjectSpec(frame_drop=0.1), seed=1)
    c = rig.engine.counters
    assert c.dropped > 20
    assert rig.got[0].counter == 0  # (seed 1 keeps frame 0; earlier ones could not be known)
    assert stats.lost == c.dropped
    assert stats.frames == 400 - c.dropped == c.sent
    assert rig.bit_exact()
    gaps_add_up(rig, stats)


def test_drops_at_the_end_count_through_expect_end(rig: Rig) -> None:
    plain = rig.bank

    def source(counter: int) -> tuple[FrameHeader, np.ndarray]:
        if counter >= 27:
            # A rate of 1 (beyond --inject's 0.5 limit) drops the last three frames for sure.
            rig.engine.inject = InjectSpec.model_construct(frame_drop=1.0)
        return plain(counter)

    rig.engine.source = source
    stats = rig.run(30, spec=InjectSpec())
    assert rig.engine.counters.dropped == 3
    assert [g.counter for g in rig.got] == list(range(27))
    assert not any(g.flags & FrameFlags.LAST for g in rig.got)  # the LAST frame was dropped
    assert stats.lost == 3


def test_expect_end_before_the_last_frames_arrive_waits_for_them(
    sock_path: Path, bank: BankSource
) -> None:
    # Frames keep coming after expect_end: none counts as lost while they do (a read timeout,
    # the sign that nothing more is coming, is made long so that a loaded machine's pauses
    # between frames are not taken for the end).
    rig = Rig(sock_path, bank, timeout_s=5.0)
    try:
        rig.stream.start(max_frame_bytes=FRAME_BYTES)
        rig.engine.start(40, 0.002, pace=True)
        assert rig.stream.wait_frames(1, 10.0)
        rig.stream.expect_end(40)  # told early
        assert rig.stream.wait_drained(30.0)
        stats = rig.stream.stats()
        assert (stats.frames, stats.lost) == (40, 0)
    finally:
        rig.close()


def test_corrupt_frames_are_counted_and_never_delivered(rig: Rig) -> None:
    stats = rig.run(300, spec=InjectSpec(frame_corrupt=0.1), seed=2)
    c = rig.engine.counters
    assert stats.corrupt == c.corrupted > 10
    assert stats.frames == 300 - c.corrupted and stats.lost == 0
    assert all(g.ok for g in rig.got) and rig.bit_exact()
    gaps_add_up(rig, stats)


def test_short_frames_are_counted_and_never_delivered(rig: Rig) -> None:
    stats = rig.run(300, spec=InjectSpec(frame_short=0.1), seed=3)
    c = rig.engine.counters
    assert stats.short == c.shortened > 10
    assert stats.frames == 300 - c.shortened and stats.lost == stats.corrupt == 0
    assert rig.bit_exact()
    gaps_add_up(rig, stats)


def test_stalls_are_cleared_and_the_stream_goes_on(rig: Rig) -> None:
    stats = rig.run(300, spec=InjectSpec(frame_stall=0.05, frame_drop=0.05), seed=5)
    c = rig.engine.counters
    assert stats.stalls == c.stalls > 5
    assert stats.lost == c.stalls + c.dropped  # a stalled frame is lost with the halt
    assert stats.frames == c.sent == 300 - c.stalls - c.dropped
    assert rig.bit_exact()
    gaps_add_up(rig, stats)


def test_every_fault_at_once_adds_up(rig: Rig) -> None:
    spec = InjectSpec.parse("frame_drop=0.05,frame_corrupt=0.05,frame_short=0.05,frame_stall=0.03")
    stats = rig.run(400, spec=spec, seed=9)
    c = rig.engine.counters
    assert rig.got[0].counter == 0  # (seed 9 keeps frame 0: earlier ones could not be known)
    assert stats.frames + stats.lost + stats.corrupt + stats.short == 400
    assert stats.stalls == c.stalls and stats.short == c.shortened
    assert stats.lost == c.dropped + c.stalls
    assert all(g.ok for g in rig.got) and rig.bit_exact()
    assert [g.counter for g in rig.got] == sorted({g.counter for g in rig.got})


# -- the queue ------------------------------------------------------------------------------------


class StallThenBurst:
    """A consumer stuck in frame 0's callback until ``release`` is set; ``burst()`` starts
    the stream, sends frame 0, then 19 more at once, and waits until 15 were overruns (a
    4-frame queue is full)."""

    def __init__(self, rig: Rig, release: threading.Event) -> None:
        self.rig, self.release = rig, release
        self.entered = threading.Event()
        self.slots_at_start = 0
        rig.stream.add_consumer(self.consume)

    def consume(self, frame: ReceivedFrame) -> None:
        self.entered.set()
        assert self.release.wait(10.0)

    def burst(self) -> None:
        rig = self.rig
        rig.stream.start(max_frame_bytes=FRAME_BYTES)
        self.slots_at_start = rig.stream.allocated_slots
        rig.engine.start(1, 0.0, pace=False)
        assert self.entered.wait(10.0)  # the dispatcher is stuck in frame 0's callbacks
        assert rig.engine.wait_idle(10.0)
        rig.engine.start(19, 0.0, pace=False)
        assert rig.engine.wait_idle(10.0)
        assert wait_until(lambda: rig.stream.stats().overruns == 15)


@pytest.mark.parametrize(
    ("policy", "delivered", "gaps"),
    [
        ("drop_newest", [0, 1, 2, 3, 4], [0, 0, 0, 0, 0]),
        ("drop_oldest", [0, 16, 17, 18, 19], [0, 15, 0, 0, 0]),
    ],
)
def test_overruns_with_a_slow_consumer(
    sock_path: Path, bank: BankSource, policy: str, delivered: list[int], gaps: list[int]
) -> None:
    rig = Rig(sock_path, bank, queue_frames=4, overflow=policy, overflow_wait_s=0.001)
    release = threading.Event()
    slow = StallThenBurst(rig, release)
    try:
        slow.burst()
        release.set()
        rig.stream.expect_end(20)
        assert rig.stream.wait_drained(10.0)
        stats = rig.stream.stats()
        assert [g.counter for g in rig.got] == delivered
        assert [g.gap_before for g in rig.got] == gaps
        assert [g.index for g in rig.got] == [0, 1, 2, 3, 4]
        assert (stats.overruns, stats.lost, stats.frames) == (15, 0, 5)
        assert rig.bit_exact()
    finally:
        release.set()
        rig.close()


SLOT_BYTES = 4096  # FRAME_BYTES + 1, rounded up to whole 1024-byte packets


def test_queue_bytes_caps_the_queue_to_the_slots_that_fit() -> None:
    stream = FrameStream(queue_frames=65536, queue_bytes=256_000_000)
    assert stream.queue_capacity(33_792) == 7575  # hr400, 8 stages: 256 MB // 33 KiB slots
    assert stream.queue_capacity(4096) == 62500
    capped = FrameStream(queue_frames=4096, queue_bytes=256_000_000)
    assert capped.queue_capacity(33_792) == 4096  # the daemon's defaults: queue_frames caps
    assert stream.queue_capacity(1 << 30) == 2  # a frame bigger than the budget: still 2
    assert FrameStream(queue_frames=32).queue_capacity(1 << 30) == 32  # no budget: frames
    with pytest.raises(ValueError, match="queue_bytes = 0 must be at least 1"):
        FrameStream(queue_bytes=0)


def test_slots_are_allocated_as_the_queue_grows_and_given_back_at_stop(
    sock_path: Path, bank: BankSource
) -> None:
    # A byte budget of 4.5 slots: a queue of 4 frames, whatever queue_frames allows.
    rig = Rig(
        sock_path,
        bank,
        queue_frames=1024,
        queue_bytes=SLOT_BYTES * 4 + SLOT_BYTES // 2,
        overflow_wait_s=0.001,
    )
    release = threading.Event()
    slow = StallThenBurst(rig, release)
    try:
        slow.burst()
        assert slow.slots_at_start == 3  # the reader's, the dispatcher's, one queued
        assert rig.stream._queue.slot_bytes == SLOT_BYTES
        # 4 queued + the dispatcher's + the reader's: the queue's length plus two, no more.
        assert rig.stream.allocated_slots == 6
        release.set()
        rig.stream.expect_end(20)
        assert rig.stream.wait_drained(10.0)
        assert [g.counter for g in rig.got] == [0, 1, 2, 3, 4]
        assert rig.bit_exact()
        rig.stream.stop()
        assert rig.stream.allocated_slots == 3  # the burst's three went back
        # The next run starts from the kept three and streams as before.
        rig.stream.remove_consumer(slow.consume)
        rig.got.clear()
        stats = rig.run(50)
        # (Through the same 4-frame queue: a consumer starved on a busy machine may still
        # overrun it, which is counted, never lost.)
        assert (stats.frames + stats.overruns, stats.lost) == (50, 0)
        assert rig.bit_exact()
        assert rig.stream.allocated_slots == 3
    finally:
        release.set()
        rig.close()


def test_a_failing_consumer_does_not_stop_the_others(rig: Rig) -> None:
    def broken(frame: ReceivedFrame) -> None:
        raise RuntimeError("consumer bug")

    rig.stream.remove_consumer(rig.record)
    rig.stream.add_consumer(broken)
    rig.stream.add_consumer(rig.record)
    stats = rig.run(5)
    assert stats.consumer_errors == 5 and len(rig.got) == 5
    rig.stream.remove_consumer(broken)
    rig.stream.remove_consumer(broken)  # unknown: ignored
    assert rig.run(3).consumer_errors == 0


# -- transfers the engine never makes -------------------------------------------------------------


def raw_frame(bank: BankSource, counter: int) -> list[bytes | memoryview]:
    header, pixels = bank(counter % U32_WRAP)
    return [encode_header(header), pixels.data.cast("B")]


def raw_rig(sock_path: Path, bank: BankSource) -> Rig:
    rig = Rig(sock_path, bank)
    rig.stream.start(max_frame_bytes=FRAME_BYTES)
    assert rig.server.wait_connected(5.0)
    return rig


def finish(rig: Rig, n_delivered: int) -> StreamStats:
    assert rig.stream.wait_frames(n_delivered, 10.0)
    assert rig.stream.wait_drained(10.0)
    rig.stream.stop()
    return rig.stream.stats()


def test_bad_headers_oversize_and_counters_going_back(sock_path: Path, bank: BankSource) -> None:
    rig = raw_rig(sock_path, bank)
    try:
        send = rig.server.send_transfer
        assert send(raw_frame(bank, 0))
        garbage = bytearray(b"".join(bytes(p) for p in raw_frame(bank, 1)))
        garbage[10] ^= 0xFF  # inside the header: its CRC fails
        assert send([bytes(garbage)])  # stands for frame 1
        assert send(raw_frame(bank, 2))
        assert send([bytes(FRAME_BYTES * 3)])  # longer than any frame: overflows the slot
        assert send(raw_frame(bank, 4))
        assert send(raw_frame(bank, 4))  # a repeat
        assert send(raw_frame(bank, 3))  # going back
        assert send([b"CAMF"])  # shorter than a header
        assert send(raw_frame(bank, 6))
        stats = finish(rig, 4)
        assert [g.counter for g in rig.got] == [0, 2, 4, 6]
        assert [g.gap_before for g in rig.got] == [0, 1, 1, 1]
        assert (stats.corrupt, stats.short, stats.out_of_order, stats.lost) == (2, 1, 2, 0)
        assert rig.stream.problem  # the last thing that went wrong, in words
    finally:
        rig.close()


def test_a_zero_length_packet_ends_a_skipped_transfer(sock_path: Path, bank: BankSource) -> None:
    rig = raw_rig(sock_path, bank)
    try:
        read_size = rig.stream._queue.slot_bytes  # 4096: one frame + 1 byte, in whole packets
        assert rig.server.send_transfer(raw_frame(bank, 0))
        # Too long, and a whole number of reads: the device ends it with a zero-length packet.
        assert rig.server.send_transfer([bytes(2 * read_size)])
        assert rig.server.send_transfer([])
        assert rig.server.send_transfer(raw_frame(bank, 2))
        stats = finish(rig, 2)
        assert [g.counter for g in rig.got] == [0, 2]
        assert (stats.corrupt, stats.lost) == (1, 0)
        assert "longer than max_frame_bytes=3264" in (rig.stream.problem or "")
    finally:
        rig.close()


def test_counters_wrap_at_2_to_the_32(sock_path: Path, bank: BankSource) -> None:
    rig = raw_rig(sock_path, bank)
    try:
        for counter in (U32_WRAP - 2, U32_WRAP - 1, 0, 2):
            assert rig.server.send_transfer(raw_frame(bank, counter))
        stats = finish(rig, 4)
        assert [g.counter for g in rig.got] == [U32_WRAP - 2, U32_WRAP - 1, 0, 2]
        assert [g.gap_before for g in rig.got] == [0, 0, 0, 1]
        assert stats.lost == 1 and stats.out_of_order == 0
    finally:
        rig.close()


# -- errors ---------------------------------------------------------------------------------------


def test_no_device_is_a_clear_error(sock_path: Path) -> None:
    with StreamSocketServer(sock_path):
        stream = FrameStream(backend=get_backend(sock_path), product_id=0x1234)
        with pytest.raises(StreamError, match=r"no USB frame-stream device 04b4:1234 found.*lsusb"):
            stream.open()
        with pytest.raises(StreamError, match="not open"):
            stream.start(max_frame_bytes=FRAME_BYTES)


def test_simulator_gone_ends_the_reader_with_an_error(sock_path: Path, bank: BankSource) -> None:
    rig = raw_rig(sock_path, bank)
    try:
        assert rig.server.send_transfer(raw_frame(bank, 0))
        assert rig.stream.wait_frames(1, 10.0)
        rig.server.stop()
        assert not rig.stream.wait_frames(2, 10.0)  # returns as soon as the reader gave up
        assert rig.stream.error is not None
        assert "disconnected" in str(rig.stream.error) and "04b4:00f1" in str(rig.stream.error)
    finally:
        rig.close()


def test_bad_arguments() -> None:
    with pytest.raises(ValueError, match="queue_frames"):
        FrameStream(queue_frames=0)
    with pytest.raises(ValueError, match="overflow"):
        FrameStream(overflow="drop_all")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="timeout_s"):
        FrameStream(timeout_s=0)


def test_frames_lost_before_the_first_one_received_are_counted(rig: Rig) -> None:
    # The device says its stream starts at counter 7 (START_STREAM's answer) but the first
    # three frames never arrive: the engine really starts at 10.
    rig.stream.start(max_frame_bytes=FRAME_BYTES)
    rig.stream.expect_first(7)
    rig.engine.start(5, 0.0, pace=False, first_counter=10)
    assert rig.engine.wait_idle(30.0)
    rig.stream.expect_end(15)
    assert rig.stream.wait_drained(30.0)
    stats = rig.stream.stats()
    assert (stats.frames, stats.lost) == (5, 3)
    assert [g.counter for g in rig.got] == [10, 11, 12, 13, 14]
    assert [g.gap_before for g in rig.got] == [3, 0, 0, 0, 0]


def test_expect_first_after_the_first_frame_still_counts_the_missing_ones(rig: Rig) -> None:
    # The answer to START_STREAM can come after the first frame: same count.
    rig.stream.start(max_frame_bytes=FRAME_BYTES)
    rig.engine.start(5, 0.0, pace=False, first_counter=20)
    assert rig.engine.wait_idle(30.0)
    assert rig.stream.wait_frames(5, 30.0)
    rig.stream.expect_first(18)
    rig.stream.expect_end(25)
    assert rig.stream.wait_drained(30.0)
    assert (rig.stream.stats().frames, rig.stream.stats().lost) == (5, 2)


# -- packed transfers (several frames per transfer, docs/stream.md "Packed transfers") ------------

PACK_BYTES = 64 << 10  # 20 of these 3264-byte frames per transfer


@pytest.mark.parametrize("pack_bytes", [PACK_BYTES, 16 << 10], ids=["20 a transfer", "5"])
def test_packed_transfers_deliver_every_frame_bit_exact_in_few_reads(
    sock_path: Path, bank: BankSource, pack_bytes: int
) -> None:
    # 20 frames a transfer are checked in one numpy pass, 5 by decode_header (VECTOR_MIN_FRAMES)
    per_transfer = pack_bytes // FRAME_BYTES
    rig = Rig(sock_path, bank, pack_bytes=pack_bytes)
    batches: list[int] = []

    class Batches:
        """A consumer taking runs of frames (``on_batch``) besides the per-frame one."""

        def __call__(self, frame: ReceivedFrame) -> None:
            raise AssertionError("a consumer with on_batch gets batches")

        def on_batch(self, batch: FrameBatch) -> None:
            assert not batch.pixels.flags.writeable
            assert batch.counters.tolist() == list(
                range(int(batch.counters[0]), int(batch.counters[0]) + batch.count)
            )
            batches.append(batch.count)

    rig.stream.add_consumer(Batches())
    try:
        stats = rig.run(400)
        # stop() asked the device to go back to one frame per transfer (its thread reads it)
        assert wait_until(lambda: rig.server.pack_bytes == 0)
        assert [g.counter for g in rig.got] == list(range(400))
        assert [g.index for g in rig.got] == list(range(400))
        assert all(g.gap_before == 0 and g.ok for g in rig.got) and rig.bit_exact()
        assert rig.got[-1].flags & FrameFlags.LAST
        assert (stats.frames, stats.bytes, stats.first_counter, stats.last_counter) == (
            400,
            400 * FRAME_BYTES,
            0,
            399,
        )
        assert stats.lost == stats.corrupt == stats.short == stats.overruns == 0
        # Transfers at least half full on average (the engine packs the blocks it sends).
        assert stats.reads < 400 // (per_transfer // 2)
        assert sum(batches) == 400 and max(batches) == per_transfer
        assert [h.counter for h, _ in rig.stream.header_log()] == list(range(256))
    finally:
        rig.close()


def test_packed_transfers_count_every_fault_as_one_frame_per_transfer_does(
    sock_path: Path, bank: BankSource
) -> None:
    # The same seeded faults through both framings: the same counts, frame for frame.
    spec = InjectSpec.parse("frame_drop=0.05,frame_corrupt=0.05,frame_short=0.05,frame_stall=0.03")
    counts: dict[int, tuple[int, ...]] = {}
    for pack_bytes in (0, PACK_BYTES):
        rig = Rig(sock_path, bank, pack_bytes=pack_bytes)
        try:
            stats = rig.run(400, spec=spec, seed=9)
            c = rig.engine.counters
            assert stats.frames + stats.lost + stats.corrupt + stats.short == 400
            assert stats.stalls == c.stalls and stats.short == c.shortened
            assert stats.corrupt == c.corrupted and stats.lost == c.dropped + c.stalls
            assert all(g.ok for g in rig.got) and rig.bit_exact()
            gaps_add_up(rig, stats)
            assert (stats.reads < 300) == bool(pack_bytes)
            counts[pack_bytes] = (stats.frames, stats.lost, stats.corrupt, stats.short,
                                  stats.stalls, stats.out_of_order)  # fmt: skip
        finally:
            rig.close()
    assert counts[0] == counts[PACK_BYTES]


def packed(*frames: list[bytes | memoryview]) -> list[bytes]:
    """Frames back to back in one transfer."""
    return [b"".join(bytes(p) for p in parts) for parts in frames]


def test_a_packed_transfer_counts_crc_bad_lost_repeated_and_going_back_frames_exactly(
    sock_path: Path, bank: BankSource
) -> None:
    rig = Rig(sock_path, bank, pack_bytes=PACK_BYTES)
    rig.stream.start(max_frame_bytes=FRAME_BYTES)
    assert rig.stream.packed
    try:
        send = rig.server.send_transfer
        bad_crc = bytearray(b"".join(bytes(p) for p in raw_frame(bank, 1)))
        bad_crc[HEADER_BYTES + 7] ^= 0x10  # a payload bit: the header is fine
        f = {k: raw_frame(bank, k) for k in range(12)}
        # 0, 1 (payload CRC bad), 2, 4 (3 lost), 4 again (a repeat), 5
        assert send(packed(f[0], [bytes(bad_crc)], f[2], f[4], f[4], f[5]))
        bad_header = bytearray(b"".join(bytes(p) for p in f[7]))
        bad_header[10] ^= 0xFF  # its header CRC fails: the rest of the transfer is unframed
        # 3 (going back), 6, 7 (bad header: corrupt), 8 (after it: lost with the rest)
        assert send(packed(f[3], f[6], [bytes(bad_header)], f[8]))
        cut = b"".join(bytes(p) for p in f[10])[: FRAME_BYTES // 2]
        assert send(packed(f[9], [cut]))  # 9, then 10 cut short (its header intact)
        assert send(packed(f[11]))
        stats = finish(rig, 7)
        assert [g.counter for g in rig.got] == [0, 2, 4, 5, 6, 9, 11]
        assert [g.gap_before for g in rig.got] == [0, 1, 1, 0, 0, 2, 1]
        assert (stats.corrupt, stats.lost, stats.short, stats.out_of_order) == (2, 2, 1, 2)
        assert stats.frames == 7 and stats.reads == 4 and rig.bit_exact()
        assert all(g.ok for g in rig.got)
    finally:
        rig.close()


def test_a_device_that_does_not_pack_is_read_one_frame_per_transfer(
    sock_path: Path, bank: BankSource
) -> None:
    class OneFramePerTransfer(Fx3Backend):
        """An FX3 whose firmware does not know the packing request: it stalls it, as a
        device stalls any request it does not know."""

        ctrl_transfer = SimulatedUsbDevice.ctrl_transfer

    server = StreamSocketServer(sock_path)
    server.start()
    engine = StreamEngine(bank, server=server)
    stream = FrameStream(backend=OneFramePerTransfer(sock_path), pack_bytes=PACK_BYTES)
    got: list[int] = []
    stream.add_consumer(lambda frame: got.append(frame.header.counter))
    try:
        stream.open()
        assert wait_until(lambda: server.connected)
        stream.start(max_frame_bytes=FRAME_BYTES)
        assert not stream.packed and server.pack_bytes == 0
        engine.start(50, 0.0, pace=False)
        assert engine.wait_idle(30.0)
        stream.expect_end(engine.next_counter)
        assert stream.wait_drained(30.0)
        stream.stop()
        stats = stream.stats()
        assert got == list(range(50)) and stats.reads == stats.frames == 50
    finally:
        stream.close()
        engine.close()
        server.stop()


def test_pack_bytes_must_be_whole_kib_with_whole_reads() -> None:
    with pytest.raises(ValueError, match="pack_bytes = 1000 must be a whole number of KiB"):
        FrameStream(pack_bytes=1000)
    with pytest.raises(ValueError, match="pack_bytes needs whole-transfer reads"):
        FrameStream(pack_bytes=PACK_BYTES, read_bytes=1024)


def test_frames_the_device_sent_after_its_reader_failed_are_lost_once_it_stops(
    sock_path: Path, bank: BankSource
) -> None:
    # The reader gave up (its device went away: a handle to a camera that restarted) and the
    # device then says it sent counters 0..2 (START_STREAM's answer, then STREAM_DONE): none
    # can arrive any more, so once the reader is stopped the three count as lost, not as
    # nothing. Before, an acquisition could answer 3 frames asked, 0 delivered and 0 lost.
    rig = Rig(sock_path, bank)
    try:
        rig.stream.start(max_frame_bytes=FRAME_BYTES)
        rig.server.stop()
        assert wait_until(lambda: rig.stream.error is not None)
        rig.stream.expect_first(0)
        rig.stream.expect_end(3)
        rig.stream.stop()
        stats = rig.stream.stats()
        assert (stats.frames, stats.lost) == (0, 3)
    finally:
        rig.close()


@pytest.mark.parametrize("pack_bytes", [0, PACK_BYTES], ids=["a frame a transfer", "packed"])
def test_frames_of_a_stream_that_arrive_after_it_ended_are_not_the_next_streams(
    sock_path: Path, bank: BankSource, pack_bytes: int
) -> None:
    # A loaded camera (the simulator starved of CPU) acknowledges a stop with frames counted
    # that it has not sent yet (those of its block in progress); the host's line goes quiet for
    # a read timeout, so the end is accounted with them lost and the reader stops. They go out
    # later, into the next stream's reader, ahead of that stream's own frames and of START_STREAM's
    # answer. They belong to the stream before: the next one's counts, consumers and recording
    # are its own (a CI run's 3-frame stare answered 45 frames: 42 late ones of the stare before).
    rig = Rig(sock_path, bank, pack_bytes=pack_bytes)
    making, gate = threading.Event(), threading.Event()

    def source(counter: int) -> tuple[FrameHeader, np.ndarray]:
        if counter == 7:
            making.set()
            gate.wait(30.0)  # frame 7 takes its time: the stop comes meanwhile
        return bank(counter)

    rig.engine.source = source
    try:
        rig.stream.start(max_frame_bytes=FRAME_BYTES)
        rig.engine.start(0, 0.0, pace=False)  # unpaced: counters 0..63 made as one block
        rig.stream.expect_first(0)
        assert making.wait(10.0)
        assert rig.engine.stop() == 8  # the device's answer: 0..7 sent, 8 next
        rig.stream.expect_end(rig.engine.next_counter)
        assert rig.stream.wait_drained(10.0)  # the line went quiet: none of them came
        rig.stream.stop()
        before = rig.stream.stats()
        assert (before.frames, before.lost) == (0, 8)

        rig.stream.start(max_frame_bytes=FRAME_BYTES)
        if pack_bytes:
            assert wait_until(lambda: rig.server.pack_bytes == pack_bytes)
        gate.set()  # the stopped stream's block goes out now
        assert rig.engine.wait_idle(10.0)
        assert wait_until(lambda: rig.stream.stats().reads >= (1 if pack_bytes else 8))
        rig.engine.start(5, 0.0, pace=False)
        rig.stream.expect_first(8)  # START_STREAM's answer comes after the late frames
        assert rig.engine.wait_idle(10.0)
        rig.stream.expect_end(rig.engine.next_counter)
        assert rig.stream.wait_drained(10.0)
        rig.stream.stop()
        stats = rig.stream.stats()
        assert [g.counter for g in rig.got] == [8, 9, 10, 11, 12]
        assert [g.gap_before for g in rig.got] == [0] * 5 and rig.bit_exact()
        assert (stats.frames, stats.lost, stats.out_of_order) == (5, 0, 0)
        assert (stats.first_counter, stats.last_counter) == (8, 12)
        assert rig.stream.late_frames == 8  # set aside, said
    finally:
        gate.set()
        rig.close()


def test_frames_the_device_counted_are_waited_for_while_the_line_is_quiet_under_end_quiet_s(
    sock_path: Path, bank: BankSource
) -> None:
    # The same slow frame in progress, with the daemon's patience (end_quiet_s): read timeouts
    # with nothing coming do not count the frames the device said it sent as lost; they are
    # delivered to their own stream when they come. (end_quiet_s = 0, one read timeout, lost
    # them: the test above.)
    rig = Rig(sock_path, bank, end_quiet_s=60.0)
    making, gate = threading.Event(), threading.Event()

    def source(counter: int) -> tuple[FrameHeader, np.ndarray]:
        if counter == 7:
            making.set()
            gate.wait(30.0)
        return bank(counter)

    rig.engine.source = source
    try:
        rig.stream.start(max_frame_bytes=FRAME_BYTES)
        rig.engine.start(0, 0.0, pace=False)
        rig.stream.expect_first(0)
        assert making.wait(10.0)
        assert rig.engine.stop() == 8
        rig.stream.expect_end(rig.engine.next_counter)
        timeouts = rig.stream.stats().timeouts
        assert wait_until(lambda: rig.stream.stats().timeouts >= timeouts + 3, 30.0)
        assert not rig.stream.wait_drained(0.0)
        assert rig.stream.stats().lost == 0
        gate.set()
        assert rig.stream.wait_drained(30.0)
        rig.stream.stop()
        stats = rig.stream.stats()
        assert (stats.frames, stats.lost, stats.out_of_order) == (8, 0, 0)
        assert [g.counter for g in rig.got] == list(range(8)) and rig.bit_exact()
    finally:
        gate.set()
        rig.close()


@pytest.mark.parametrize("tail_bytes", [1000, 10], ids=["corrupt", "short"])
@pytest.mark.parametrize("answer_first", [True, False], ids=["answer first", "frames first"])
def test_the_rest_of_an_earlier_runs_frame_is_not_a_broken_frame_of_the_next(
    sock_path: Path, bank: BankSource, tail_bytes: int, answer_first: bool
) -> None:
    # A run stopped in the middle of a frame's transfer (its read timed out with part of it in,
    # which pyusb gives up) leaves the rest of that transfer to the next run's first read: a
    # transfer with no header to say whose it is. No counter is missing before the next run's
    # first (START_STREAM's answer, before or after its frames): it stands for no frame of that
    # run, so it is the run before's, set aside; the next run counts nothing broken.
    rig = raw_rig(sock_path, bank)
    try:
        send = rig.server.send_transfer
        if answer_first:
            rig.stream.expect_first(8)
        assert send([bytes(tail_bytes)])  # the rest of frame 7
        for counter in range(8, 13):
            assert send(raw_frame(bank, counter))
        assert rig.stream.wait_frames(5, 10.0)
        if not answer_first:
            rig.stream.expect_first(8)
        rig.stream.expect_end(13)
        stats = finish(rig, 5)
        assert [g.counter for g in rig.got] == [8, 9, 10, 11, 12]
        assert [g.gap_before for g in rig.got] == [0] * 5
        assert (stats.frames, stats.corrupt, stats.short, stats.lost) == (5, 0, 0, 0)
        assert rig.stream.late_frames == 1
    finally:
        rig.close()
