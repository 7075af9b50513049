"""The simulated FX3 (host half firmware_models.fx3_backend, device half firmware_models.fx3):
pyusb through the backend over a real Unix socket, the stream engine's transfers, pacing
bookkeeping and injected faults, and the bank source."""

from __future__ import annotations

import array
import errno
import json
import shutil
import socket
import subprocess
import sys
import tempfile
import threading
import time
import zlib
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import usb.core
import usb.util

from camd.protocol.stream import (
    HEADER_BYTES,
    FrameFlags,
    FrameHeader,
    StreamMode,
    decode_header,
    payload_ok,
)
from firmware_models import fx3
from firmware_models.fx3 import BankSource, StreamEngine, StreamSocketServer
from firmware_models.fx3_backend import (
    EP_IN,
    PRODUCT_ID,
    VENDOR_ID,
    Fx3Backend,
    StreamLinkError,
    get_backend,
)
from firmware_models.inject import InjectSpec

pytestmark = pytest.mark.timeout(60)

REPO = Path(__file__).resolve().parents[1]
ROWS, COLS = 8, 24
FRAME_BYTES = HEADER_BYTES + 2 * ROWS * COLS
BIG = 64 * 1024  # a read size larger than any frame here


@pytest.fixture
def short_dir() -> Iterator[Path]:
    # Unix socket paths are limited to ~107 bytes: pytest's tmp_path can be too long.
    d = Path(tempfile.mkdtemp(prefix="fx3-"))
    yield d
    shutil.rmtree(d, ignore_errors=True)


@pytest.fixture
def server(short_dir: Path) -> Iterator[StreamSocketServer]:
    with StreamSocketServer(short_dir / "usb.sock") as srv:
        yield srv


@pytest.fixture
def bank() -> BankSource:
    return BankSource.random(ROWS, COLS, count=3, seed=5, line_period_ns=40_000)


def open_device(backend: Fx3Backend) -> Any:
    dev = usb.core.find(idVendor=VENDOR_ID, idProduct=PRODUCT_ID, backend=backend)
    assert dev is not None
    dev.set_configuration()
    usb.util.claim_interface(dev, 0)
    return dev


# Reads that expect data wait 10 s for it: a busy machine may run the engine late. (Reads that
# expect none pass their own short timeout.)
def read_transfer(dev: Any, size: int = BIG, timeout_ms: int = 10_000) -> bytes:
    buf = array.array("B", bytes(size))
    n = dev.read(EP_IN, buf, timeout_ms)
    return buf[:n].tobytes()


def split(transfer: bytes) -> tuple[FrameHeader, np.ndarray]:
    h = decode_header(transfer)
    px = np.frombuffer(transfer, dtype="<u2", offset=HEADER_BYTES).reshape(h.rows, h.cols)
    return h, px


def wait_until(predicate: Callable[[], bool], timeout_s: float = 30.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.002)
    return True


def connected(server: StreamSocketServer) -> tuple[Fx3Backend, Any]:
    # Wait for *this* connection: the server may still hold the previous test's until it
    # notices that one closed, and frames sent meanwhile would go nowhere.
    before = server.connections_accepted
    backend = get_backend(server.path)
    deadline = time.monotonic() + 30.0
    while server.connections_accepted == before and time.monotonic() < deadline:
        time.sleep(0.001)
    assert server.connections_accepted > before and server.wait_connected(30.0)
    return backend, open_device(backend)


# -- the device through pyusb -------------------------------------------------------------------


def test_find_descriptors_and_claim(server: StreamSocketServer) -> None:
    backend = get_backend(server.path, serial="FX3-0042")
    dev = usb.core.find(idVendor=0x04B4, idProduct=0x00F1, backend=backend)
    assert dev is not None
    assert (dev.bcdUSB, dev.speed, dev.bDeviceClass) == (0x0300, usb.util.SPEED_SUPER, 0)
    assert usb.util.get_string(dev, dev.iManufacturer) == "Cypress"
    assert usb.util.get_string(dev, dev.iSerialNumber) == "FX3-0042"
    assert "FX3" in usb.util.get_string(dev, dev.iProduct)
    cfg = dev.get_active_configuration()
    intf = cfg[(0, 0)]
    assert (intf.bInterfaceClass, intf.bNumEndpoints) == (0xFF, 1)
    (ep,) = list(intf)
    assert ep.bEndpointAddress == 0x81
    assert usb.util.endpoint_type(ep.bmAttributes) == usb.util.ENDPOINT_TYPE_BULK
    assert usb.util.endpoint_direction(ep.bEndpointAddress) == usb.util.ENDPOINT_IN
    assert ep.wMaxPacketSize == 1024
    # The SuperSpeed endpoint companion follows the endpoint: bMaxBurst 15 (16 packets).
    assert list(ep.extra_descriptors) == [6, 0x30, 15, 0, 0, 0]
    full = usb.control.get_descriptor(dev, 255, usb.util.DESC_TYPE_CONFIG, 0)
    assert len(full) == cfg.wTotalLength == 9 + 9 + 7 + 6
    assert not dev.is_kernel_driver_active(0)
    dev.set_configuration()
    usb.util.claim_interface(dev, 0)
    usb.util.release_interface(dev, 0)
    usb.util.dispose_resources(dev)


def test_kernel_driver_must_be_detached_first(server: StreamSocketServer) -> None:
    backend = get_backend(server.path, kernel_driver="usbtest")
    dev = usb.core.find(idVendor=VENDOR_ID, idProduct=PRODUCT_ID, backend=backend)
    assert dev.is_kernel_driver_active(0)
    with pytest.raises(usb.core.USBError) as busy:
        usb.util.claim_interface(dev, 0)
    assert busy.value.errno == errno.EBUSY
    assert "usbtest" in str(busy.value)
    dev.detach_kernel_driver(0)
    usb.util.claim_interface(dev, 0)


def test_n_frames_in_n_out_bit_exact(server: StreamSocketServer, bank: BankSource) -> None:
    done: list[tuple[int, int]] = []
    engine = StreamEngine(bank, server=server, on_done=lambda n, nxt: done.append((n, nxt)))
    _backend, dev = connected(server)
    engine.start(12, 0.0, pace=False, first_counter=100)
    for k in range(12):
        h, px = split(read_transfer(dev))
        assert h.counter == 100 + k
        assert np.array_equal(px, bank.frames[(100 + k) % 3])
        assert payload_ok(h, px)
        assert h.timestamp_ns == (100 + k) * 40_000
        assert bool(h.flags & FrameFlags.LAST) == (k == 11)
    assert engine.wait_idle(30.0)
    assert done == [(12, 112)]
    assert engine.counters.as_dict() == {
        "produced": 12,
        "sent": 12,
        "bytes_sent": 12 * FRAME_BYTES,
        "dropped": 0,
        "corrupted": 0,
        "shortened": 0,
        "stalls": 0,
        "undelivered": 0,
    }
    assert not engine.running and engine.frames_produced == 12
    engine.close()


def test_a_stream_begins_once_its_source_is_ready_and_a_stop_meanwhile_counts_no_frame(
    server: StreamSocketServer, bank: BankSource
) -> None:
    """The source's first-frame work (``ready``: the imaging pipeline's kernels, fixed pattern
    and noise bank, up to a second cold) comes before the stream's first frame is counted. A
    stop meanwhile ends the stream with 0 frames produced, none to drain: before, the frame in
    progress was counted while it waited on that work, STOP_STREAM said 1 sent, and a host
    that heard nothing for one read timeout counted it lost."""
    done: list[tuple[int, int]] = []
    engine = StreamEngine(bank, server=server, on_done=lambda n, nxt: done.append((n, nxt)))
    _backend, dev = connected(server)
    working, release = threading.Event(), threading.Event()

    def ready() -> None:
        working.set()
        assert release.wait(30.0)

    engine.ready = ready
    engine.start(0, 0.001, first_counter=7)
    assert working.wait(30.0)
    assert engine.stop() == 0  # asked during the work: no frame counted
    release.set()
    assert engine.wait_idle(30.0)
    assert done == [(0, 7)] and engine.counters.produced == engine.counters.sent == 0
    # Ready, a stream counts and sends its frames from its first.
    engine.ready = lambda: None
    engine.start(3, 0.0, pace=False)
    assert [split(read_transfer(dev))[0].counter for _ in range(3)] == [7, 8, 9]
    assert engine.wait_idle(30.0) and done[-1] == (3, 10)
    engine.close()


def test_a_stream_the_camera_ends_early_sends_that_many_and_says_so(
    server: StreamSocketServer, bank: BankSource
) -> None:
    done: list[tuple[int, int]] = []
    engine = StreamEngine(bank, server=server, on_done=lambda n, nxt: done.append((n, nxt)))
    _backend, dev = connected(server)
    # A counted stream of 12 cut after 4 (SIM_FAIL_NEXT end_stream), then one until stopped
    # cut after 2: each ends by itself, none of its frames flagged LAST.
    engine.start(12, 0.0, pace=False, first_counter=100, end_after=4)
    headers = [split(read_transfer(dev))[0] for _ in range(4)]
    assert engine.wait_idle(30.0)
    assert [h.counter for h in headers] == [100, 101, 102, 103]
    assert not any(h.flags & FrameFlags.LAST for h in headers)
    engine.start(0, 0.0, pace=False, end_after=2)
    assert [split(read_transfer(dev))[0].counter for _ in range(2)] == [104, 105]
    assert engine.wait_idle(30.0)
    assert done == [(4, 104), (2, 106)]
    with pytest.raises(usb.core.USBTimeoutError):
        read_transfer(dev, timeout_ms=200)  # nothing more was sent
    assert engine.counters.produced == engine.counters.sent == 6
    engine.close()


def test_a_short_read_gets_the_rest_on_the_next_read(
    server: StreamSocketServer, bank: BankSource
) -> None:
    wide = BankSource.random(16, 100, count=2, seed=1)  # 3264-byte frames: several packets
    frame_bytes = HEADER_BYTES + 2 * 16 * 100
    engine = StreamEngine(wide, server=server)
    _backend, dev = connected(server)
    engine.start(2, 0.0, pace=False)
    first = read_transfer(dev, 1024)
    assert len(first) == 1024  # asked for less than the transfer: exactly that much
    second = read_transfer(dev, 1024)
    rest = read_transfer(dev, BIG)
    assert len(rest) == frame_bytes - 2048  # the rest, and not a byte of the next frame
    h, px = split(first + second + rest)
    assert h.counter == 0 and np.array_equal(px, wide.frames[0])
    whole = read_transfer(dev, frame_bytes)  # exactly the transfer: a full read
    assert decode_header(whole).counter == 1 and len(whole) == frame_bytes
    engine.close()


def test_read_times_out_without_data(server: StreamSocketServer) -> None:
    _backend, dev = connected(server)
    with pytest.raises(usb.core.USBTimeoutError) as exc:
        read_transfer(dev, timeout_ms=50)
    assert exc.value.errno == errno.ETIMEDOUT


def test_each_read_keeps_its_own_timeout(server: StreamSocketServer, bank: BankSource) -> None:
    # The backend sets the socket's receive timeout only when a read asks for another one: a
    # short timeout after a long one must still be the short one.
    _backend, dev = connected(server)
    with pytest.raises(usb.core.USBTimeoutError):
        read_transfer(dev, timeout_ms=50)
    engine = StreamEngine(bank, server=server)
    engine.start(2, 0.0, pace=False)
    assert [decode_header(read_transfer(dev, timeout_ms=20_000)).counter for _ in range(2)] == [
        0,
        1,
    ]
    t0 = time.monotonic()
    with pytest.raises(usb.core.USBTimeoutError):
        read_transfer(dev, timeout_ms=50)  # nothing more comes
    assert time.monotonic() - t0 < 10.0  # not the 20 s of the reads before
    engine.close()


def test_stall_reads_epipe_until_the_halt_is_cleared(
    server: StreamSocketServer, bank: BankSource
) -> None:
    engine = StreamEngine(bank, server=server, inject=InjectSpec(frame_stall=0.5), seed=3)
    _backend, dev = connected(server)
    engine.start(10, 0.0, pace=False)
    counters: list[int] = []
    stalls = 0
    while len(counters) + stalls < 10:
        try:
            counters.append(decode_header(read_transfer(dev)).counter)
        except usb.core.USBError as exc:
            assert exc.errno == errno.EPIPE
            assert server.halted
            with pytest.raises(usb.core.USBError) as again:  # still halted: EPIPE at once
                read_transfer(dev, timeout_ms=10)
            assert again.value.errno == errno.EPIPE
            stalls += 1
            dev.clear_halt(EP_IN)
    assert engine.wait_idle(30.0)
    assert stalls == engine.counters.stalls > 0
    assert len(counters) == engine.counters.sent == 10 - stalls
    assert counters == sorted(counters)  # the stalled frames are missing, nothing else
    assert engine.counters.undelivered == 0  # unpaced: the engine waited for the clear
    engine.close()


def test_simulator_gone_is_no_device(short_dir: Path) -> None:
    server = StreamSocketServer(short_dir / "usb.sock")
    server.start()
    backend, dev = connected(server)
    server.stop()
    with pytest.raises(usb.core.USBError) as exc:
        read_transfer(dev)
    assert exc.value.errno == errno.ENODEV
    with pytest.raises(usb.core.USBError) as again:
        read_transfer(dev)
    assert again.value.errno == errno.ENODEV
    assert usb.core.find(idVendor=VENDOR_ID, idProduct=PRODUCT_ID, backend=backend) is None
    # A simulator listening again: the device enumerates again.
    with StreamSocketServer(short_dir / "usb.sock") as server2:
        dev2 = usb.core.find(idVendor=VENDOR_ID, idProduct=PRODUCT_ID, backend=backend)
        assert dev2 is not None
        assert server2.wait_connected(30.0)


def test_no_simulator_is_a_clear_error(short_dir: Path) -> None:
    with pytest.raises(
        StreamLinkError, match=r"no simulated camera streams frames on .*--usb-socket"
    ):
        get_backend(short_dir / "nothing.sock")


def test_only_bulk_in_moves_data(server: StreamSocketServer) -> None:
    backend, dev = connected(server)
    handle = dev._ctx.handle  # the backend's own calls, which pyusb would make
    for call in (backend.bulk_write, backend.intr_write, backend.intr_read):
        with pytest.raises(usb.core.USBError) as exc:
            call(handle, 0x01, 0, array.array("B", b"x"), 100)
        assert exc.value.errno == errno.EPIPE
    with pytest.raises(usb.core.USBError) as bad:
        backend.bulk_read(handle, 0x82, 0, array.array("B", bytes(8)), 100)
    assert bad.value.errno == errno.EPIPE


def test_a_new_host_replaces_the_old_one(server: StreamSocketServer, bank: BankSource) -> None:
    engine = StreamEngine(bank, server=server)
    _old_backend, old_dev = connected(server)
    accepted = server.connections_accepted
    new_backend = get_backend(server.path)
    new_dev = open_device(new_backend)
    assert wait_until(lambda: server.connections_accepted == accepted + 1)
    engine.start(1, 0.0, pace=False)
    assert decode_header(read_transfer(new_dev)).counter == 0
    with pytest.raises(usb.core.USBError) as exc:
        read_transfer(old_dev)
    assert exc.value.errno == errno.ENODEV
    engine.close()


# -- the socket server --------------------------------------------------------------------------


def test_stale_socket_is_replaced_and_a_live_one_refused(short_dir: Path) -> None:
    path = short_dir / "usb.sock"
    stale = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    stale.bind(str(path))
    stale.close()  # the file stays, nobody listens: a simulator that died
    with StreamSocketServer(path) as server:
        assert server.path.is_socket()
        with pytest.raises(OSError, match="already serves the frame stream"):
            StreamSocketServer(path).start()
    assert not path.exists()
    path.write_text("not a socket")
    with pytest.raises(FileExistsError, match="not a socket"):
        StreamSocketServer(path).start()


# -- the engine ---------------------------------------------------------------------------------


def test_paced_frames_without_a_host_are_undelivered(
    server: StreamSocketServer, bank: BankSource
) -> None:
    engine = StreamEngine(bank, server=server)
    engine.start(5, 0.001, pace=True)
    assert engine.wait_idle(30.0)
    assert engine.counters.undelivered == 5 and engine.counters.sent == 0
    assert engine.next_counter == 5
    # The host arrives: the first frame sent says frames were dropped before it.
    _backend, dev = connected(server)
    engine.start(2, 0.001, pace=True)
    h = decode_header(read_transfer(dev))
    assert h.counter == 5 and not h.flags & FrameFlags.DEVICE_OVERFLOW
    engine.close()


def test_a_fast_paced_stream_goes_in_blocks_none_early(
    server: StreamSocketServer, bank: BankSource, monkeypatch: pytest.MonkeyPatch
) -> None:
    # Blocks of 0.2 s (BLOCK_S is 1 ms; longer here so that the times tell): 10 ms frames go
    # twenty to a block, each block sent when its last frame is due. All arrive, in order,
    # and none before its time: frame 19 (the first block's last) is due 0.19 s after the
    # start, frame 39 0.39 s (blocks sent when their first frame is due would have frame 0
    # out at once). Lower bounds only: a busy machine makes frames later, never earlier.
    monkeypatch.setattr(fx3, "BLOCK_S", 0.2)
    engine = StreamEngine(bank, server=server)
    _backend, dev = connected(server)
    started = time.monotonic()
    engine.start(40, 0.01, pace=True)
    arrived = []
    for _ in range(40):
        counter = decode_header(read_transfer(dev)).counter
        arrived.append((counter, time.monotonic() - started))
    assert [c for c, _ in arrived] == list(range(40))
    assert arrived[0][1] >= 0.19 and arrived[20][1] >= 0.39
    assert engine.wait_idle(30.0)
    assert (engine.counters.sent, engine.counters.undelivered) == (40, 0)
    engine.close()


def test_device_overflow_flag_after_undelivered_frames(
    server: StreamSocketServer, bank: BankSource
) -> None:
    engine = StreamEngine(bank, server=server)
    backend, dev = connected(server)
    engine.start(0, 0.002, pace=True)
    h0 = decode_header(read_transfer(dev))
    backend.close()  # the host goes away while the device keeps making frames
    assert not usb.core.find(idVendor=VENDOR_ID, idProduct=PRODUCT_ID, backend=backend)
    assert wait_until(lambda: engine.counters.undelivered >= 3)
    _backend2, dev2 = connected(server)
    while True:
        h = decode_header(read_transfer(dev2))
        if h.flags & FrameFlags.DEVICE_OVERFLOW:
            break
    assert h.counter > h0.counter + 3
    produced = engine.stop()
    assert engine.wait_idle(30.0)
    assert produced == engine.frames_produced == engine.counters.produced
    engine.close()


def test_stop_ends_after_the_frame_in_progress(
    server: StreamSocketServer, bank: BankSource
) -> None:
    calls = threading.Event()
    release = threading.Event()

    def slow_source(counter: int) -> tuple[FrameHeader, np.ndarray]:
        calls.set()
        release.wait(30.0)
        return bank(counter)

    done: list[tuple[int, int]] = []
    engine = StreamEngine(slow_source, server=server, on_done=lambda n, c: done.append((n, c)))
    _backend, dev = connected(server)
    engine.start(0, 0.0, pace=False, first_counter=40)
    assert calls.wait(30.0)
    assert engine.stop() == 1  # stop() does not wait for the source
    assert not engine.running
    release.set()
    assert decode_header(read_transfer(dev)).counter == 40  # the frame in progress goes out
    assert engine.wait_idle(30.0)
    assert done == [(1, 41)]
    with pytest.raises(usb.core.USBTimeoutError):
        read_transfer(dev, timeout_ms=100)
    # The next stream continues the numbering; stop(notify=False) keeps on_done quiet.
    engine.source = bank
    engine.start(0, 0.0, pace=False)
    assert decode_header(read_transfer(dev)).counter == 41
    engine.stop(notify=False)
    assert engine.wait_idle(30.0)
    assert done == [(1, 41)]
    engine.close()


def test_start_refuses_while_running_and_bad_arguments(bank: BankSource) -> None:
    engine = StreamEngine(bank)
    with pytest.raises(ValueError, match="frames = -1"):
        engine.start(-1, 0.0)
    with pytest.raises(ValueError, match="period_s"):
        engine.start(1, -1.0)
    engine.start(0, 0.01, pace=True)
    with pytest.raises(RuntimeError, match="already running"):
        engine.start(1, 0.0)
    engine.close()
    with pytest.raises(RuntimeError, match="no frame source"):
        StreamEngine().start(1, 0.0)


def _run_faults(
    server: StreamSocketServer, bank: BankSource, spec: InjectSpec, n: int, seed: int
) -> tuple[list[bytes], dict[str, int]]:
    engine = StreamEngine(bank, server=server, inject=spec, seed=seed)
    backend, dev = connected(server)
    engine.start(n, 0.0, pace=False)
    transfers: list[bytes] = []

    def all_read() -> bool:
        c = engine.counters
        return len(transfers) == c.sent + c.shortened

    # Read until the engine is done and every transfer it sent (whole or short) has been read,
    # rather than until a short read times out: a read that a busy machine starves past its
    # timeout would end the run early, or (timing out mid-transfer) split a transfer in two.
    # With all read so far, the engine is finishing, or halted until a read sees its stall.
    deadline = time.monotonic() + 60
    while not (all_read() and engine.wait_idle(0.05) and all_read()):
        assert time.monotonic() < deadline, (len(transfers), engine.counters.as_dict())
        try:
            transfers.append(read_transfer(dev))
        except usb.core.USBTimeoutError:
            continue
        except usb.core.USBError as exc:
            assert exc.errno == errno.EPIPE
            dev.clear_halt(EP_IN)
    counters = engine.counters.as_dict()
    engine.close()
    usb.util.dispose_resources(dev)
    backend.close()
    return transfers, counters


def test_injected_faults_are_counted_and_reproducible(
    server: StreamSocketServer, bank: BankSource
) -> None:
    spec = InjectSpec.parse("frame_drop=0.1,frame_corrupt=0.1,frame_short=0.1,frame_stall=0.05")
    transfers, c = _run_faults(server, bank, spec, 200, seed=11)
    assert c["produced"] == 200
    assert c["dropped"] and c["corrupted"] and c["shortened"] and c["stalls"]
    assert c["sent"] + c["shortened"] + c["dropped"] + c["stalls"] == 200
    assert c["bytes_sent"] == sum(len(t) for t in transfers)
    whole = [t for t in transfers if len(t) == FRAME_BYTES]
    short = [t for t in transfers if len(t) < FRAME_BYTES]
    assert len(whole) == c["sent"] and len(short) == c["shortened"]
    assert all(1 <= len(t) < FRAME_BYTES for t in short)
    bad_crc = sum(not payload_ok(*split(t)) for t in whole)
    # A frame both corrupted and cut short counts once, as shortened.
    assert 0 < bad_crc == c["corrupted"]
    # Same seed, same faults.
    again, c2 = _run_faults(server, bank, spec, 200, seed=11)
    assert c2 == c and again == transfers


def test_corruption_flips_one_payload_bit_of_a_copy(
    server: StreamSocketServer, bank: BankSource
) -> None:
    before = [f.copy() for f in bank.frames]
    transfers, c = _run_faults(server, bank, InjectSpec(frame_corrupt=0.3), 60, seed=2)
    assert c["sent"] == 60 and c["corrupted"] > 0
    bad_crc = 0
    for t in transfers:
        h, px = split(t)
        flipped = int(np.unpackbits((px ^ bank.frames[h.counter % 3]).view(np.uint8)).sum())
        assert flipped == (0 if payload_ok(h, px) else 1)  # the header is never touched
        bad_crc += flipped
    assert bad_crc == c["corrupted"]
    assert all(np.array_equal(a, b) for a, b in zip(before, bank.frames, strict=True))


# -- the bank source ------------------------------------------------------------------------------


def test_bank_source_headers() -> None:
    frames = [np.full((4, 6), 7, dtype=np.uint16), np.full((4, 6), 4095, dtype=np.uint16)]
    src = BankSource(frames, line_period_ns=1000, bits=12, mode=StreamMode.TDI, t0_ns=5)
    h, px = src(3)
    assert px is src.frames[1] and not px.flags.writeable
    assert (h.counter, h.timestamp_ns, h.stages, h.rows, h.cols) == (3, 3005, 4, 4, 6)
    assert h.flags == FrameFlags.SATURATED and h.payload_crc32 == zlib.crc32(frames[1].tobytes())
    h0, _ = src(0)
    assert h0.flags == FrameFlags(0) and payload_ok(h0, frames[0])
    area = BankSource(frames, line_period_ns=1000, bits=12, mode=StreamMode.AREA)
    assert area(0)[0].stages == 0
    with pytest.raises(ValueError, match="not 2-D uint16"):
        BankSource([np.zeros((2, 2), dtype=np.float32)], line_period_ns=1, bits=12, mode=0)  # type: ignore[arg-type]


# -- python -m firmware_models.fx3 ------------------------------------------------------------------


def test_streamer_process(short_dir: Path) -> None:
    path = short_dir / "usb.sock"
    proc = subprocess.Popen(
        [sys.executable, "-m", "firmware_models.fx3", "--socket", str(path), "--rows", "4",
         "--cols", "8", "--frames", "3"],
        cwd=REPO, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
    )  # fmt: skip
    assert proc.stdin is not None and proc.stdout is not None
    try:
        ready = json.loads(proc.stdout.readline())
        assert ready["socket"] == str(path) and ready["frame_bytes"] == 64 + 64
        backend = get_backend(path)
        dev = open_device(backend)
        counters = [decode_header(read_transfer(dev)).counter for _ in range(3)]
        assert counters == [0, 1, 2]
        backend.close()
        proc.stdin.close()
        final = json.loads(proc.stdout.readline())
        assert final["sent"] == 3 and final["produced"] == 3
        assert proc.wait(timeout=10) == 0
    finally:
        proc.kill()
        proc.wait()
    assert not path.exists()
