"""The simulator as a host sees it: a subprocess serving a real pty, spoken to with pyserial."""

from __future__ import annotations

import json
import os
import re
import select
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
import serial

from camd.protocol import Decoder, Dictionary, Frame, FrameType, encode_frame, load_dictionary
from camd.protocol.dictionary import FieldValue
from firmware_models import cli
from firmware_models.fpga import FpgaModel
from firmware_models.pty_server import PtyServer

pytestmark = pytest.mark.timeout(30)

REPO = Path(__file__).resolve().parents[1]
START_TIMEOUT_S = 10.0
ANSWER_TIMEOUT_S = 2.0


class Sim:
    """A simulator subprocess and its start line."""

    def __init__(self, *args: str) -> None:
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join(p for p in (str(REPO), env.get("PYTHONPATH")) if p)
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "firmware_models", *args],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            cwd=REPO,
            env=env,
        )
        self.line = self._read_start_line()

    def _read_start_line(self) -> str:
        assert self.proc.stdout is not None
        ready, _, _ = select.select([self.proc.stdout], [], [], START_TIMEOUT_S)
        if not ready:
            self.kill()
            pytest.fail(f"simulator printed nothing within {START_TIMEOUT_S} s")
        line = self.proc.stdout.readline()
        if not line:
            _, err = self.proc.communicate(timeout=5)
            pytest.fail(f"simulator exited with {self.proc.returncode}: {err}")
        return line.rstrip("\n")

    @property
    def info(self) -> dict[str, Any]:
        info: dict[str, Any] = json.loads(self.line)
        return info

    def signal_and_wait(self, sig: int = signal.SIGTERM) -> int:
        self.proc.send_signal(sig)
        return self.proc.wait(timeout=5)

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(timeout=5)
        for stream in (self.proc.stdout, self.proc.stderr):
            if stream is not None:
                stream.close()


class Host:
    """The host end of the line: raw frames over pyserial, with frame collection."""

    def __init__(self, path: str, dictionary: Dictionary) -> None:
        self.port = serial.serial_for_url(path, timeout=0.02)
        self.dictionary = dictionary
        self.decoder = Decoder()
        self.received: list[Frame] = []  # every frame seen, in order

    def close(self) -> None:
        self.port.close()

    def send(self, frame: Frame) -> None:
        self.port.write(frame.encode())
        self.port.flush()

    def wait_for(
        self, predicate: Callable[[Frame], bool], timeout_s: float = ANSWER_TIMEOUT_S
    ) -> Frame:
        deadline = time.monotonic() + timeout_s
        seen = len(self.received)
        while True:
            for frame in self.received[seen:]:
                if predicate(frame):
                    return frame
            seen = len(self.received)
            if time.monotonic() > deadline:
                pytest.fail(f"no matching frame within {timeout_s} s; got {self.received[-5:]}")
            self.received += self.decoder.feed(self.port.read(4096))

    def drain(self, duration_s: float) -> list[Frame]:
        start = len(self.received)
        deadline = time.monotonic() + duration_s
        while time.monotonic() < deadline:
            self.received += self.decoder.feed(self.port.read(4096))
        return self.received[start:]

    def command_frame(self, name: str, seq: int, **values: Any) -> Frame:
        spec = self.dictionary.command(name)
        return Frame(FrameType.COMMAND, seq, spec.opcode, spec.encode_request(**values))

    def answer_to(self, frame: Frame) -> Frame:
        self.send(frame)
        return self.wait_for(
            lambda f: f.type in (FrameType.ACK, FrameType.NAK) and f.seq == frame.seq
        )

    def call(self, name: str, seq: int, **values: Any) -> dict[str, FieldValue]:
        answer = self.answer_to(self.command_frame(name, seq, **values))
        assert answer.type == FrameType.ACK, self.dictionary.describe_error(
            *self.dictionary.decode_nak(answer.payload)
        )
        return self.dictionary.command(name).decode_response(answer.payload)


@pytest.fixture(scope="module")
def dictionary() -> Dictionary:
    return load_dictionary()


@pytest.fixture(scope="module")
def sim(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Sim]:
    link = tmp_path_factory.mktemp("sim") / "cam.tty"
    s = Sim("--json", "--link", str(link), "--inject", "delay_ms=5", "--hk-period-s", "0.1")
    yield s
    s.kill()


@pytest.fixture
def host(sim: Sim, dictionary: Dictionary) -> Iterator[Host]:
    h = Host(sim.info["link"], dictionary)
    yield h
    h.close()


# -- one simulator, many exchanges -----------------------------------------------------------


def test_json_start_line(sim: Sim) -> None:
    info = sim.info
    assert set(info) == {"tty", "link", "pid", "profile", "inject", "spi_socket", "usb_socket"}
    assert re.fullmatch(r"/dev/pts/\d+", info["tty"])
    assert info["link"].endswith("cam.tty") and os.path.isabs(info["link"])
    assert os.readlink(info["link"]) == info["tty"]
    assert info["pid"] == sim.proc.pid
    assert info["profile"] == "hr400"
    assert info["inject"] == {
        "ber": 0.0,
        "drop": 0.0,
        "garbage": 0.0,
        "delay_ms": 5.0,
        "frame_drop": 0.0,
        "frame_corrupt": 0.0,
        "frame_short": 0.0,
        "frame_stall": 0.0,
        "stage_error": 0.0,
        "stage_ripple": 0.0,
        "stage_jitter": 0.0,
        "stage_drift": 0.0,
        "stage_load": 0.0,
    }
    assert info["usb_socket"] is None and info["spi_socket"] is None


def test_ping_round_trip(host: Host) -> None:
    # Every byte value, so CR/LF, XON/XOFF, ^C, ^D and sync bytes must all pass untouched.
    frame = host.command_frame("PING", 11, data=bytes(range(256)))
    start_s = time.monotonic()
    answer = host.answer_to(frame)
    assert time.monotonic() - start_s >= 0.005  # delay_ms=5 is applied
    assert answer == Frame(FrameType.ACK, 11, frame.opcode, frame.payload)


def test_housekeeping_telemetry_arrives_and_changes(host: Host, dictionary: Dictionary) -> None:
    packet = dictionary.telemetry_packet("HOUSEKEEPING")
    samples = []
    for _ in range(3):
        frame = host.wait_for(lambda f: f.type == FrameType.TELEMETRY and f.opcode == packet.opcode)
        samples.append(packet.decode(frame.payload))
    uptimes = [float(s["uptime_s"]) for s in samples]
    assert uptimes == sorted(uptimes) and uptimes[0] < uptimes[-1]
    assert 0.05 < uptimes[1] - uptimes[0] < 0.5
    assert len({s["fpga_temp_degc"] for s in samples}) > 1
    for s in samples:
        assert 15.0 < float(s["fpga_temp_degc"]) < 60.0
        assert abs(float(s["vcc_io_v"]) - 3.3) < 0.05


def test_resent_identical_frame_is_replayed(host: Host, dictionary: Dictionary) -> None:
    before = host.call("GET_LINK_STATS", 20)
    mode = host.call("GET_STATUS", 21)["mode"]
    other = "tdi" if mode == "area" else "area"
    set_mode = host.command_frame("SET_MODE", 22, mode=other)
    first = host.answer_to(set_mode)
    second = host.answer_to(set_mode)  # as if the first ACK had been lost
    assert first.encode() == second.encode()
    assert dictionary.command("SET_MODE").decode_response(first.payload) == {"mode": other}
    changed = dictionary.event("MODE_CHANGED").opcode

    def mode_changed(f: Frame) -> bool:
        return f.type == FrameType.EVENT and f.opcode == changed

    # The event may be in before the ACK or later; wait for it however late a busy machine
    # delivers it, then a while for a second one.
    if not any(mode_changed(f) for f in host.received):
        host.wait_for(mode_changed)
    host.drain(0.3)
    mode_events = [f for f in host.received if mode_changed(f)]
    assert len(mode_events) == 1  # executed once, so one event (the counters below prove it)

    after = host.call("GET_LINK_STATS", 23)
    assert int(after["replayed"]) - int(before["replayed"]) == 1
    assert int(after["executed"]) - int(before["executed"]) == 3  # GET_STATUS, SET_MODE, this


def test_a_silence_sends_nothing_then_the_device_answers_again(
    host: Host, dictionary: Dictionary
) -> None:
    ping = dictionary.command("PING").opcode
    # 3 s of silence around a 0.5 s listen: the listen stays inside it on a busy machine.
    host.call("SIM_FAIL_NEXT", 50, action="silence", opcode=ping, skip=0, error_code=0,
              duration_s=3.0, frames=0)  # fmt: skip
    lost = host.command_frame("PING", 51, data=b"lost")
    host.send(lost)
    heard = host.drain(0.5)
    assert not [f for f in heard if f.type in (FrameType.ACK, FrameType.NAK)]
    # Telemetry comes every 0.1 s; at most one frame was already on its way.
    assert len([f for f in heard if f.type == FrameType.TELEMETRY]) <= 1
    # The line comes back: telemetry again, and commands are answered.
    host.wait_for(lambda f: f.type == FrameType.TELEMETRY, timeout_s=15.0)
    assert host.call("PING", 52, data=b"back")["data"] == b"back"


def test_delay_is_counted(host: Host) -> None:
    host.call("PING", 29, data=b"delayed")  # one answer delayed, whichever test ran before
    injected = host.call("SIM_GET_INJECTED", 30)
    assert int(injected["delayed"]) > 0
    assert injected["bit_errors"] == injected["dropped_rx"] == injected["dropped_tx"] == 0


def test_garbage_and_a_stalled_length_field_are_survived(host: Host) -> None:
    before = host.call("GET_LINK_STATS", 40)
    # A false frame start claiming 1000 payload bytes would swallow the PING behind it; the
    # simulator's inter-byte idle flush gives up on it and finds the PING.
    bogus = encode_frame(FrameType.COMMAND, 0, 0x01, bytes(1000))[:7]
    ping = host.command_frame("PING", 41, data=b"still here")
    host.port.write(b"\x00\xff\x13" + bogus + ping.encode())
    answer = host.wait_for(lambda f: f.type == FrameType.ACK and f.seq == 41)
    assert answer.payload == b"still here"
    after = host.call("GET_LINK_STATS", 42)
    assert int(after["bytes_dropped"]) - int(before["bytes_dropped"]) == 3 + 7
    assert int(after["resyncs"]) > int(before["resyncs"])


def test_host_can_close_and_reopen_the_port(sim: Sim, dictionary: Dictionary) -> None:
    for seq in (50, 51):
        h = Host(sim.info["link"], dictionary)
        try:
            assert h.call("PING", seq, data=bytes([seq])) == {"data": bytes([seq])}
        finally:
            h.close()


def call_with_retries(host: Host, frame: Frame, timeout_s: float = 0.05) -> Frame:
    """Stop-and-wait as the real host does it: resend the identical frame until answered."""
    for _ in range(100):
        host.send(frame)
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            host.received += host.decoder.feed(host.port.read(4096))
            for f in host.received:
                if f.type in (FrameType.ACK, FrameType.NAK) and f.seq == frame.seq:
                    host.received.clear()
                    return f
        while host.decoder.pending:  # the host's own inter-byte timeout
            host.received += host.decoder.flush_partial()
    pytest.fail(f"no answer to {frame} after 100 tries")


N_PINGS = 12


def test_retries_get_through_a_noisy_line(tmp_path: Path, dictionary: Dictionary) -> None:
    s = Sim("--json", "--inject", "ber=5e-4,drop=0.05", "--hk-period-s", "0", "--seed", "5")
    try:
        host = Host(s.info["tty"], dictionary)
        try:
            for seq in range(N_PINGS):
                ping = host.command_frame("PING", seq, data=bytes([seq]) * 40)
                answer = call_with_retries(host, ping)
                assert (answer.type, answer.payload) == (FrameType.ACK, ping.payload)
            spec = dictionary.command("SIM_GET_INJECTED")
            injected = spec.decode_response(
                call_with_retries(host, host.command_frame("SIM_GET_INJECTED", 100)).payload
            )
            spec = dictionary.command("GET_LINK_STATS")
            stats = spec.decode_response(
                call_with_retries(host, host.command_frame("GET_LINK_STATS", 101)).payload
            )
        finally:
            host.close()
    finally:
        s.kill()
    assert int(injected["bit_errors"]) > 0
    assert int(stats["crc_errors"]) > 0
    # Each command executed exactly once, however many times it had to be sent.
    assert int(stats["executed"]) == N_PINGS + 2
    assert int(stats["nacked"]) == 0


def ping_without_termios_setup(path: str, dictionary: Dictionary) -> None:
    """PING over a plain open() of the port, which (unlike pyserial) leaves termios alone."""
    fd = os.open(path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    try:
        spec = dictionary.command("PING")
        ping = Frame(FrameType.COMMAND, 60, spec.opcode, bytes(range(256)))
        os.write(fd, ping.encode())
        decoder = Decoder()
        deadline = time.monotonic() + ANSWER_TIMEOUT_S
        answers: list[Frame] = []
        while not answers and time.monotonic() < deadline:
            if select.select([fd], [], [], 0.05)[0]:
                frames = decoder.feed(os.read(fd, 4096))
                answers = [f for f in frames if f.type == FrameType.ACK and f.seq == 60]
        assert answers, "no ACK: the pty mangled the frame or echoed it"
        assert answers[0].payload == ping.payload
    finally:
        os.close(fd)


# -- lifecycle -------------------------------------------------------------------------------


def test_raw_pty_then_sigterm_exits_zero_and_removes_the_link(tmp_path: Path) -> None:
    link = tmp_path / "cam.tty"
    s = Sim("--json", "--link", str(link), "--hk-period-s", "0")
    try:
        assert link.is_symlink()
        # First opener of a fresh simulator, so only the simulator's own raw setup applies:
        # no echo, no CR/LF translation, no XON/XOFF, no signals on ^C.
        ping_without_termios_setup(str(link), load_dictionary())
        assert s.signal_and_wait(signal.SIGTERM) == 0
        assert not link.exists() and not link.is_symlink()
    finally:
        s.kill()


def test_second_simulator_repoints_the_link(tmp_path: Path, dictionary: Dictionary) -> None:
    link = tmp_path / "cam.tty"
    first = Sim("--json", "--link", str(link), "--hk-period-s", "0")
    second = None
    try:
        second = Sim("--json", "--link", str(link), "--hk-period-s", "0", "--inject", "delay_ms=1")
        assert second.info["tty"] != first.info["tty"]
        assert os.readlink(link) == second.info["tty"]
        h = Host(str(link), dictionary)
        try:
            # delay_ms=1 tells the second simulator from the first.
            assert h.call("SIM_GET_INJECTED", 1)["delayed"] == 0
            assert int(h.call("SIM_GET_INJECTED", 2)["delayed"]) >= 1
        finally:
            h.close()
        # The first one exits without removing a link that is no longer its own.
        assert first.signal_and_wait() == 0
        assert os.readlink(link) == second.info["tty"]
        assert second.signal_and_wait() == 0
        assert not link.is_symlink()
    finally:
        first.kill()
        if second is not None:
            second.kill()


def test_readable_start_line_and_ctrl_c(tmp_path: Path) -> None:
    link = tmp_path / "camera.tty"
    s = Sim("--link", str(link), "--inject", "ber=1e-4,drop=0.01", "--hk-period-s", "0")
    try:
        pattern = (
            r"simulated camera \(profile hr400\) listening on /dev/pts/\d+ "
            rf"\(link {re.escape(str(link))}\); inject ber=0\.0001 drop=0\.01; Ctrl-C to stop"
        )
        assert re.fullmatch(pattern, s.line)
        assert s.signal_and_wait(signal.SIGINT) == 0
    finally:
        s.kill()


def test_bad_inject_exits_2_with_the_known_keys() -> None:
    result = subprocess.run(
        [sys.executable, "-m", "firmware_models", "--inject", "ber=1e-4,bogus=1"],
        capture_output=True,
        text=True,
        cwd=REPO,
        env={**os.environ, "PYTHONPATH": str(REPO)},
        timeout=10,
    )
    assert result.returncode == 2
    assert result.stdout == ""
    assert "unknown --inject key 'bogus'; known keys: ber, drop, garbage, delay_ms" in result.stderr


def test_unread_output_is_bounded_by_shedding_telemetry() -> None:
    # No host reads the port: the kernel's pty buffer fills, then the server's own buffer
    # must stay bounded by discarding the oldest telemetry instead of growing.
    limit_bytes = 2048
    model = FpgaModel(seed=0, power_on_s=time.monotonic())
    server = PtyServer(model, hk_period_s=0.0005, tx_buffer_limit_bytes=limit_bytes)
    with server:
        thread = threading.Thread(target=server.serve, daemon=True)
        thread.start()
        try:
            deadline = time.monotonic() + 10.0
            while server.counters.tx_overflow_dropped == 0 and time.monotonic() < deadline:
                time.sleep(0.05)
        finally:
            server.stop()
            thread.join(timeout=5)
        assert not thread.is_alive()
        assert server.counters.tx_overflow_dropped > 0
        assert 0 < server.tx_buffered_bytes <= limit_bytes


def test_main_returns_status_instead_of_exiting(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # camd sim calls main(argv) in-process: usage errors must come back as a status.
    assert cli.main(["--inject", "drop=0.9"]) == 2
    err = capsys.readouterr().err
    assert "--inject drop=0.9 is invalid" in err and "from 0 to 0.5" in err
    assert cli.main(["--hk-period-s", "-1"]) == 2
    assert "give a number >= 0" in capsys.readouterr().err
    assert cli.main(["--link", str(tmp_path / "no" / "such" / "dir" / "cam.tty")]) == 1
    assert "cannot create the link" in capsys.readouterr().err
