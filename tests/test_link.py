"""CommandLink over a real pty against a scripted byte-level peer.

The peer is the test's own device: it decodes frames with the protocol codec and answers as each
test scripts (drop the first N answers, NAK, answer late, send garbage or telemetry in between).
That pins down the link's retry and dispatch rules exactly; the simulated FPGA is exercised
against the link in test_link_sim.py.
"""

from __future__ import annotations

import contextlib
import os
import re
import select
import threading
import time
import tty
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from camd.link import (
    CommandLink,
    CommandRejected,
    CommandTimeout,
    ConnectionChange,
    LinkDown,
    Message,
    Unsolicited,
)
from camd.protocol import Decoder, EncodeError, Frame, FrameType, encode_frame, load_dictionary

D = load_dictionary()
PING = D.command("PING").opcode

Answer = Callable[
    [Frame, int], list[bytes]
]  # (command frame, how many times seen) -> bytes to send


class Peer:
    """A pty whose master end is driven by ``answer``; the slave path is what the link opens."""

    def __init__(self, answer: Answer, tmp_path: Path) -> None:
        self.master, slave = os.openpty()
        tty.setraw(slave)  # no echo: the line discipline must not mangle binary frames
        self.slave_fd = slave
        self.link_path = tmp_path / "peer.tty"
        self.link_path.symlink_to(os.ttyname(slave))
        self.answer = answer
        self.received: list[Frame] = []
        self.seen: dict[bytes, int] = {}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def send(self, data: bytes) -> None:
        os.write(self.master, data)

    def _run(self) -> None:
        decoder = Decoder()
        while not self._stop.is_set():
            ready, _, _ = select.select([self.master], [], [], 0.02)
            if not ready:
                continue
            try:
                chunk = os.read(self.master, 4096)
            except OSError:
                return
            for frame in decoder.feed(chunk):
                self.received.append(frame)
                key = frame.encode()
                self.seen[key] = self.seen.get(key, 0) + 1
                for out in self.answer(frame, self.seen[key]):
                    os.write(self.master, out)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=1)
        for fd in (self.master, self.slave_fd):
            with contextlib.suppress(OSError):
                os.close(fd)


def wait_until(predicate: Callable[[], bool], timeout_s: float = 30.0) -> None:
    """Poll ``predicate`` until true; fail after ``timeout_s`` (generous: the machine is busy)."""
    deadline = time.monotonic() + timeout_s
    while not predicate():
        assert time.monotonic() < deadline, f"gave up after {timeout_s} s"
        time.sleep(0.01)


def ack(frame: Frame, payload: bytes | None = None) -> bytes:
    body = frame.payload if payload is None else payload
    return encode_frame(FrameType.ACK, frame.seq, frame.opcode, body)


@pytest.fixture
def make_link(tmp_path: Path) -> Iterator[Callable[..., tuple[CommandLink, Peer]]]:
    made: list[tuple[CommandLink, Peer]] = []

    def make(answer: Answer, **kwargs: object) -> tuple[CommandLink, Peer]:
        peer = Peer(answer, tmp_path)
        # A 5 s attempt: the peer thread answers within it however busy the machine, so an
        # answered command takes one attempt. Tests of timeouts pass their own timeout_s.
        opts: dict[str, object] = {"timeout_s": 5.0, "retries": 3, "reconnect_min_s": 0.02}
        opts.update(kwargs)
        link = CommandLink(str(peer.link_path), **opts)  # type: ignore[arg-type]
        link.open()
        assert link.wait_connected(30.0), link.last_error
        made.append((link, peer))
        return link, peer

    yield make
    for link, peer in made:
        link.close()
        peer.close()


def test_ping_echo_and_counters(make_link: Callable[..., tuple[CommandLink, Peer]]) -> None:
    link, peer = make_link(lambda f, n: [ack(f)])
    r = link.request("PING", data=b"\x00\xeb\x90hello")
    assert r.values == {"data": b"\x00\xeb\x90hello"}
    assert r.attempts == 1
    c = link.counters()
    assert (c["sent"], c["acked"], c["retries"], c["timeouts"], c["failed"]) == (1, 1, 0, 0, 0)
    # The bytes on the wire are exactly the spec's frame for this sequence number.
    assert peer.received[0].encode() == encode_frame(
        FrameType.COMMAND, r.seq, PING, b"\x00\xeb\x90hello"
    )


def test_retry_resends_identical_frame(make_link: Callable[..., tuple[CommandLink, Peer]]) -> None:
    # Answer only the third copy: the link must have sent the same bytes three times.
    # 1 s attempts: the two unanswered ones time out, and the peer thread has a whole second
    # to answer the third, however busy the machine (a later answer would mean a 4th attempt).
    link, peer = make_link(lambda f, n: [ack(f)] if n == 3 else [], timeout_s=1.0)
    r = link.request("PING", data=b"x")
    assert r.attempts == 3
    assert len(peer.received) == 3 and len({f.encode() for f in peer.received}) == 1
    c = link.counters()
    assert (c["sent"], c["retries"], c["timeouts"], c["acked"]) == (3, 2, 2, 1)


def test_timeout_after_all_retries(make_link: Callable[..., tuple[CommandLink, Peer]]) -> None:
    link, peer = make_link(lambda f, n: [], timeout_s=0.05, retries=2)
    with pytest.raises(CommandTimeout, match=r"PING: no answer .* after 3 attempt\(s\) of 50 ms"):
        link.request("PING", data=b"")
    # The last copy was written 50 ms before the give-up; the peer thread may read it later.
    wait_until(lambda: len(peer.received) >= 3)
    assert len(peer.received) == 3
    c = link.counters()
    assert (c["failed"], c["timeouts"], c["retries"]) == (1, 3, 2)


def test_nak_carries_error_in_words(make_link: Callable[..., tuple[CommandLink, Peer]]) -> None:
    nak = D.encode_nak("OUT_OF_RANGE", "mode raw 7")
    link, _ = make_link(lambda f, n: [encode_frame(FrameType.NAK, f.seq, f.opcode, nak)])
    with pytest.raises(CommandRejected) as info:
        link.request("SET_MODE", mode="tdi")
    assert info.value.code == 3 and info.value.name == "OUT_OF_RANGE"
    assert str(info.value) == (
        "SET_MODE refused by the device: OUT_OF_RANGE (3): a parameter is outside its valid "
        "range: mode raw 7"
    )
    assert link.counters()["nacked"] == 1


def test_bad_values_refused_before_sending(
    make_link: Callable[..., tuple[CommandLink, Peer]],
) -> None:
    link, peer = make_link(lambda f, n: [ack(f)])
    with pytest.raises(
        EncodeError, match=re.escape("SET_MODE.mode: 'staring' is not valid; use one of area, tdi")
    ):
        link.request("SET_MODE", mode="staring")
    with pytest.raises(EncodeError, match=re.escape("PING.data: 257 bytes is too long")):
        link.request("PING", data=bytes(257))
    assert link.counters()["sent"] == 0
    # A PING after the refusals: once it is answered, anything sent before it has been read
    # by the peer (the pty keeps order), so "nothing else sent" needs no waiting window.
    r = link.request("PING", data=b"after")
    assert [f.encode() for f in peer.received] == [
        encode_frame(FrameType.COMMAND, r.seq, PING, b"after")
    ]
    assert link.counters()["sent"] == 1


def test_stale_answer_is_not_taken_for_the_next_command(
    make_link: Callable[..., tuple[CommandLink, Peer]],
) -> None:
    # The peer answers every command twice: the duplicate of command k arrives while command
    # k+1 waits; it must be ignored (wrong seq), not returned as k+1's answer.
    link, _ = make_link(lambda f, n: [ack(f), ack(f)])
    for i in range(20):
        assert link.request("PING", data=bytes([i])).values["data"] == bytes([i])
    # The last duplicate may come in after its command returned: wait for it.
    wait_until(lambda: link.counters()["stale"] >= 20)
    assert link.counters()["stale"] == 20


def test_garbage_and_telemetry_interleave(
    make_link: Callable[..., tuple[CommandLink, Peer]],
) -> None:
    hk = D.telemetry_packet("HOUSEKEEPING")
    values = {f.name: 1 for f in hk.fields}
    tlm = encode_frame(FrameType.TELEMETRY, 0, hk.opcode, hk.encode(**values))
    evt = encode_frame(FrameType.EVENT, 0, D.event("MODE_CHANGED").opcode, b"\x01")
    # The answer comes in two writes; a busy machine may hold the peer thread between them
    # longer than the default 33 ms frame timeout, which would flush the half-answer. A 5 s
    # frame timeout keeps this test about the interleaving (the flush is tested below).
    link, _ = make_link(
        lambda f, n: [b"\xeb\x90\x07junk", tlm, ack(f)[:5], ack(f)[5:] + evt],
        frame_timeout_s=5.0,
    )
    got: list[Message] = []
    link.subscribe(got.append)
    for i in range(5):
        assert link.request("PING", data=bytes([i])).attempts == 1
    # The last event follows the last answer: wait for it rather than for a fixed time.
    wait_until(lambda: link.counters()["events"] >= 5)
    unsolicited = [m for m in got if isinstance(m, Unsolicited)]
    assert [m.name for m in unsolicited] == ["HOUSEKEEPING", "MODE_CHANGED"] * 5
    assert unsolicited[1].values == {"mode": "tdi"}
    assert link.counters()["telemetry"] == 5 and link.counters()["events"] == 5
    assert link.counters()["resyncs"] >= 5


def test_stalled_length_field_is_flushed(
    make_link: Callable[..., tuple[CommandLink, Peer]],
) -> None:
    # A header whose length field says 1000 bytes, then silence: the idle flush must drop it
    # and the real answer that follows must still be found, on the first attempt.
    fake = b"\xeb\x90\x02\x00\x01\x03\xe8"
    # The flush comes after the 33 ms frame timeout, whenever the reader thread gets to it; a
    # 5 s attempt keeps a busy machine's late flush from costing a second attempt.
    link, _ = make_link(lambda f, n: [fake + ack(f)], timeout_s=5.0)
    r = link.request("PING", data=b"after")
    assert r.values["data"] == b"after" and r.attempts == 1


def test_port_loss_is_reported_and_reopened(tmp_path: Path) -> None:
    peer = Peer(lambda f, n: [ack(f)], tmp_path)
    link = CommandLink(str(peer.link_path), timeout_s=0.05, retries=40, reconnect_min_s=0.02)
    changes: list[ConnectionChange] = []
    link.subscribe(lambda m: changes.append(m) if isinstance(m, ConnectionChange) else None)
    link.open()
    try:
        assert link.wait_connected(2.0)
        link.request("PING", data=b"1")
        peer.close()  # the device goes away: master and slave closed
        deadline = time.monotonic() + 3
        while len(changes) < 2 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert not link.connected
        with pytest.raises(LinkDown, match=r"no camera on .*peer\.tty"):
            link.request("PING", data=b"2")
        assert [c.connected for c in changes] == [True, False]
        # A new device appears behind the same path.
        peer.link_path.unlink()
        peer2 = Peer(lambda f, n: [ack(f)], tmp_path)
        try:
            assert link.wait_connected(3.0), link.last_error
            assert link.request("PING", data=b"3").values["data"] == b"3"
            assert link.counters()["reconnects"] == 1
            assert [c.connected for c in changes] == [True, False, True]
        finally:
            peer2.close()
    finally:
        link.close()


def test_absent_port_reports_down_without_raising_on_open(tmp_path: Path) -> None:
    link = CommandLink(str(tmp_path / "nothing.tty"), reconnect_min_s=0.01)
    link.open()
    try:
        assert not link.wait_connected(0.1)
        assert link.last_error is not None and "nothing.tty" in link.last_error
        with pytest.raises(LinkDown, match="check the cable"):
            link.request("GET_STATUS")
        assert link.counters()["failed"] == 1
    finally:
        link.close()


def test_a_port_closed_under_a_write_is_a_link_down(tmp_path: Path) -> None:
    """The reader thread closes the port when the link is lost; a request writing at that
    moment meets pyserial half-way through close() (descriptor None, port still marked open),
    whose write then fails in select() with a TypeError. That is the link going down (seen as
    a 500 on GET /status under load), not an internal error."""
    import serial

    master, slave = os.openpty()
    tty.setraw(slave)
    port = serial.Serial(os.ttyname(slave), timeout=0.1)
    link = CommandLink(str(tmp_path / "never-opened.tty"), timeout_s=0.1, retries=0)
    try:
        with link._state_lock:
            link._serial = port
        os.close(port.fd)
        port.fd = None  # as serialposix.Serial.close leaves it before is_open goes False
        assert port.is_open
        with pytest.raises(LinkDown, match="check the cable"):
            link.request("PING", data=b"x")
        assert link.counters()["failed"] == 1
    finally:
        port.is_open = False
        os.close(master)
        os.close(slave)
