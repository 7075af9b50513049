"""The MCP2210 USB-SPI bridge: the host (camd.sensor.mcp2210) against the simulated chip
(firmware_models.mcp2210_backend; the SPI socket's server end is firmware_models.usb_spi),
always through pyusb's API, in-process and across a Unix socket."""

from __future__ import annotations

import errno
import json
import os
import random
import select
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import usb.control
import usb.core
import usb.util

from camd.sensor.bridge import BridgeError
from camd.sensor.mcp2210 import Mcp2210Bridge
from camd.sensor.regmap import RegisterMap, RegisterSpec, load_register_map
from camd.sensor.spi_frame import encode_spi_frame
from firmware_models.mcp2210_backend import (
    PRODUCT_ID,
    VENDOR_ID,
    Mcp2210Backend,
    SocketSpiTarget,
    SpiLinkError,
    SpiTargetError,
    get_backend,
)
from firmware_models.sensor import SensorModel
from firmware_models.spi import SpiSlave
from firmware_models.usb_spi import SpiSocketServer

pytestmark = pytest.mark.timeout(60)

REPO = Path(__file__).resolve().parents[1]
ROUNDS = 5


# -- helpers -------------------------------------------------------------------------------------


class FakeClock:
    """A clock that moves only when told, for deterministic engine timing."""

    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now

    def advance(self, seconds: float) -> None:
        self.now += seconds


class Recorder:
    """An SPI target that records transactions and answers with the bitwise complement."""

    def __init__(self) -> None:
        self.calls: list[tuple[bytes, int]] = []

    def transfer(self, mosi: bytes, *, mode: int) -> bytes:
        self.calls.append((bytes(mosi), mode))
        return bytes(b ^ 0xFF for b in mosi)


@pytest.fixture(scope="module")
def regmap() -> RegisterMap:
    return load_register_map("hr400")


@pytest.fixture
def sensor(regmap: RegisterMap) -> SensorModel:
    return SensorModel(regmap)


@pytest.fixture
def backend(regmap: RegisterMap, sensor: SensorModel) -> Mcp2210Backend:
    return get_backend(SpiSlave(regmap.spi, sensor))


@pytest.fixture
def bridge(regmap: RegisterMap, backend: Mcp2210Backend) -> Iterator[Mcp2210Bridge]:
    with Mcp2210Bridge(regmap.spi, backend=backend) as b:
        yield b


@pytest.fixture
def short_dir() -> Iterator[Path]:
    # Unix socket paths are limited to ~107 bytes; pytest's tmp_path can be longer.
    path = Path(tempfile.mkdtemp(prefix="camd-spi-", dir="/tmp"))
    yield path
    shutil.rmtree(path, ignore_errors=True)


def random_value(reg: RegisterSpec, rng: random.Random) -> int:
    """A value valid for every field of ``reg`` (enum fields take one of their values)."""
    value = 0
    for f in reg.all_fields():
        raw = rng.choice(sorted(f.enum.values())) if f.enum else rng.randint(f.lo, f.hi)
        value = f.insert(value, raw)
    return reg.check_value(value)


def rw_registers(regmap: RegisterMap) -> list[RegisterSpec]:
    """The RW registers, the group-hold register last (while it is set, group writes latch)."""
    holds = {g.hold.partition(".")[0] for g in regmap.groups if g.hold}
    regs = [r for r in regmap.by_address() if r.access == "rw"]
    return sorted(regs, key=lambda r: r.name in holds)


def verify_every_rw_register(bridge: Mcp2210Bridge, regmap: RegisterMap, seed: int) -> int:
    """Write random in-range values to every RW register and read each back; the count."""
    rng = random.Random(seed)
    holds = [regmap.register(g.hold.partition(".")[0]) for g in regmap.groups if g.hold]
    checked = 0
    for _ in range(ROUNDS):
        for hold in holds:
            bridge.write(hold.address, 0)
        for reg in rw_registers(regmap):
            value = random_value(reg, rng)
            bridge.write(reg.address, value)
            got = bridge.read(reg.address)
            assert got == value, f"{reg.name}: wrote 0x{value:04X}, read 0x{got:04X}"
            checked += 1
    return checked


def raw_device(backend: Mcp2210Backend) -> Any:
    dev = usb.core.find(idVendor=VENDOR_ID, idProduct=PRODUCT_ID, backend=backend)
    assert dev is not None
    dev.detach_kernel_driver(0)
    return dev


def command(dev: Any, code: int, data: bytes = b"", *, byte1: int | None = None) -> bytes:
    """One raw command report through pyusb, as a host library would send it."""
    report = bytearray(64)
    report[0] = code
    report[1] = len(data) if byte1 is None else byte1
    report[4 : 4 + len(data)] = data
    assert dev.write(0x01, report, 100) == 64
    reply = bytes(dev.read(0x81, 64, 100))
    assert len(reply) == 64 and reply[0] == code
    return reply


def spi_settings(
    *, bit_rate: int = 1_000_000, cs_pin: int = 0, nbytes: int = 3, mode: int = 0
) -> bytes:
    idle, active = 0x1FF, 0x1FF & ~(1 << cs_pin)
    return (
        bit_rate.to_bytes(4, "little")
        + idle.to_bytes(2, "little")
        + active.to_bytes(2, "little")
        + bytes(6)
        + nbytes.to_bytes(2, "little")
        + bytes([mode])
    )


def set_cs_pin(dev: Any, pin: int = 0) -> None:
    chip = bytearray(command(dev, 0x20)[4:19])
    chip[pin] = 0x01
    assert command(dev, 0x21, bytes(chip), byte1=0)[1] == 0x00


# -- enumeration and descriptors through pyusb -------------------------------------------------


def test_find_by_vid_pid_and_read_descriptors() -> None:
    backend = get_backend(Recorder(), serial="0000958291")
    dev = usb.core.find(idVendor=0x04D8, idProduct=0x00DE, backend=backend)
    assert dev is not None
    assert (dev.idVendor, dev.idProduct, dev.bcdUSB, dev.bDeviceClass) == (0x04D8, 0x00DE, 0x200, 0)
    assert dev.bNumConfigurations == 1 and dev.speed == usb.util.SPEED_FULL
    cfg = dev[0]
    assert cfg.bConfigurationValue == 1 and cfg.bNumInterfaces == 1
    intf = cfg[(0, 0)]
    assert (intf.bInterfaceClass, intf.bNumEndpoints) == (0x03, 2)  # HID
    assert intf.extra_descriptors[:2] == [9, 0x21]  # the HID class descriptor
    eps = {ep.bEndpointAddress: ep for ep in intf}
    assert set(eps) == {0x01, 0x81}
    for ep in eps.values():
        assert usb.util.endpoint_type(ep.bmAttributes) == usb.util.ENDPOINT_TYPE_INTR
        assert ep.wMaxPacketSize == 64
    assert usb.util.endpoint_direction(eps[0x81].bEndpointAddress) == usb.util.ENDPOINT_IN
    # String descriptors come over control transfers (GET_DESCRIPTOR), as from the chip.
    assert dev.langids == (0x0409,)
    assert dev.serial_number == "0000958291"
    assert dev.manufacturer == "Microchip Technology Inc."
    assert dev.product == "MCP2210 USB to SPI Master"
    assert usb.util.get_string(dev, dev.iSerialNumber) == "0000958291"
    full = usb.control.get_descriptor(dev, 255, usb.util.DESC_TYPE_CONFIG, 0)
    assert len(full) == cfg.wTotalLength == 41
    str(dev)  # pyusb's full dump walks every descriptor
    assert usb.core.find(idVendor=0x04D8, idProduct=0x00DF, backend=backend) is None
    assert len(list(usb.core.find(find_all=True, backend=backend))) == 1


# -- register programming through Mcp2210Bridge ------------------------------------------------


def test_every_rw_register_round_trips_bit_exactly(
    bridge: Mcp2210Bridge, regmap: RegisterMap, sensor: SensorModel
) -> None:
    checked = verify_every_rw_register(bridge, regmap, seed=3)
    assert checked == ROUNDS * len(rw_registers(regmap)) > 0
    # The last values are in the sensor's own register file, not just echoed on the bus.
    for reg in rw_registers(regmap):
        assert sensor.spi_read(reg.address) == bridge.read(reg.address)


def test_bridge_configures_the_chip_for_the_layout(
    bridge: Mcp2210Bridge, backend: Mcp2210Backend, regmap: RegisterMap
) -> None:
    s = backend.chip.spi_settings
    assert s.mode == regmap.spi.mode
    assert s.bytes_per_transaction == regmap.spi.frame_bytes == 3
    assert s.bit_rate == bridge.bit_rate_hz == int(regmap.spi.max_clock_hz)
    assert (s.idle_cs, s.active_cs) == (0x1FF, 0x1FE)
    assert backend.chip.chip_settings.pins[0] == 0x01  # GP0 is the chip select
    assert bridge.serial_number == "0000000001"
    assert bridge.chip_status()["bus_owner"] == 0x00


def test_write_burst_is_one_transaction_per_frame(
    bridge: Mcp2210Bridge, backend: Mcp2210Backend, regmap: RegisterMap
) -> None:
    win_start, win_rows = regmap.register("WIN_START"), regmap.register("WIN_ROWS")
    before = backend.chip.counters.transactions
    bridge.write_burst([(win_start.address, 757), (win_rows.address, 534)])
    assert backend.chip.counters.transactions - before == 2
    assert (bridge.read(win_start.address), bridge.read(win_rows.address)) == (757, 534)


def test_read_of_a_write_only_register_is_zero_at_the_bus(
    bridge: Mcp2210Bridge, regmap: RegisterMap
) -> None:
    soft_reset = next(r for r in regmap.registers if r.access == "wo")
    assert bridge.read(soft_reset.address) == 0


@pytest.mark.parametrize("chip_mode", [1, 2, 3])
def test_spi_mode_mismatch_gives_wrong_data(
    regmap: RegisterMap, backend: Mcp2210Backend, chip_mode: int
) -> None:
    back_path = regmap.register("BACK_PATH")
    value = 0xA5C3  # the data MSB set: a 0 -> 2 mismatch loses exactly that bit
    with Mcp2210Bridge(regmap.spi, backend=backend) as good:
        good.write(back_path.address, value)
        assert good.read(back_path.address) == value
    wrong_layout = regmap.spi.model_copy(update={"mode": chip_mode})
    with Mcp2210Bridge(wrong_layout, backend=backend) as wrong:
        assert backend.chip.spi_settings.mode == chip_mode != regmap.spi.mode
        assert wrong.read(back_path.address) != value


def test_busy_engine_is_polled_until_finished(regmap: RegisterMap, backend: Mcp2210Backend) -> None:
    # At the chip's slowest clock a 3-byte frame takes 16 ms: the host must ask again on 0xF8.
    with Mcp2210Bridge(regmap.spi, backend=backend, bit_rate_hz=1500) as slow:
        offset = regmap.register("OFFSET")
        slow.write(offset.address, 321)
        assert slow.read(offset.address) == 321
    assert backend.chip.counters.busy_replies > 0


# -- the TRANSFER SPI DATA conversation, report by report ---------------------------------------


def test_transfer_report_sequencing_and_busy() -> None:
    clock, target = FakeClock(), Recorder()
    dev = raw_device(get_backend(target, clock=clock))
    set_cs_pin(dev)
    assert command(dev, 0x40, spi_settings(bit_rate=1500, nbytes=3, mode=1))[1] == 0x00
    got = command(dev, 0x41)
    assert (got[1], got[2], got[4:21]) == (
        0x00,
        0x11,
        spi_settings(bit_rate=1500, nbytes=3, mode=1),
    )

    first = command(dev, 0x42, b"\x12\x34\x56")
    assert first[1:4] == bytes([0x00, 0, 0x20])  # accepted, started, no data yet
    assert target.calls == [(b"\x12\x34\x56", 1)]
    # 24 bits at 1500 bit/s: 16 ms of clocking, during which the chip takes nothing.
    assert command(dev, 0x42)[1] == 0xF8
    assert command(dev, 0x40, spi_settings())[1] == 0xF8  # settings not written
    assert command(dev, 0x21, bytes(15), byte1=0)[1] == 0xF8
    assert command(dev, 0x10)[3] == 0x01  # the USB bridge owns the bus
    clock.advance(0.016 + 1e-6)
    last = command(dev, 0x42)
    assert last[1:4] == bytes([0x00, 3, 0x10])  # finished, with the 3 received bytes
    assert last[4:7] == b"\xed\xcb\xa9"
    assert command(dev, 0x10)[3] == 0x00
    assert command(dev, 0x41)[4:21] == spi_settings(bit_rate=1500, nbytes=3, mode=1)


def test_long_transaction_spans_reports() -> None:
    clock, target = FakeClock(), Recorder()
    dev = raw_device(get_backend(target, clock=clock))
    set_cs_pin(dev)
    command(dev, 0x40, spi_settings(bit_rate=12_000_000, nbytes=100))
    data = bytes(range(100))
    assert command(dev, 0x42, data[:60])[1:4] == bytes([0, 0, 0x20])
    assert target.calls == []  # the transaction is not complete yet
    clock.advance(1.0)
    second = command(dev, 0x42, data[60:])
    assert second[1:4] == bytes([0, 60, 0x30])  # not finished; the first 60 bytes received
    clock.advance(1.0)
    third = command(dev, 0x42)
    assert third[1:4] == bytes([0, 40, 0x10])
    assert second[4:64] + third[4:44] == bytes(b ^ 0xFF for b in data)
    assert target.calls == [(data, 0)]


def test_cancel_ends_a_partial_transaction() -> None:
    clock, target = FakeClock(), Recorder()
    backend = get_backend(target, clock=clock)
    dev = raw_device(backend)
    set_cs_pin(dev)
    command(dev, 0x40, spi_settings(nbytes=3))
    assert command(dev, 0x42, b"\x01\x02")[3] == 0x20  # 2 of 3 bytes: chip select stays low
    clock.advance(1.0)
    waiting = command(dev, 0x42)
    assert waiting[1:4] == bytes([0, 0, 0x30])  # the engine waits for the third byte
    cancelled = command(dev, 0x11)
    assert cancelled[1:4] == bytes([0x00, 0x01, 0x00])  # ok, no release request, no owner
    # Chip select rose after two bytes: the slave saw a short transaction.
    assert target.calls == [(b"\x01\x02", 0)]
    assert backend.chip.counters.cancelled == 1
    # A fresh transaction starts cleanly afterwards.
    assert command(dev, 0x42, b"\x0a\x0b\x0c")[3] == 0x20
    clock.advance(1.0)
    assert command(dev, 0x42)[1:7] == bytes([0, 3, 0x10, 0xF5, 0xF4, 0xF3])


def test_chip_select_must_be_designated_and_driven() -> None:
    clock, target = FakeClock(), Recorder()
    dev = raw_device(get_backend(target, clock=clock))
    command(dev, 0x40, spi_settings(nbytes=3))  # GP0 is still a GPIO at power-up
    command(dev, 0x42, b"\x01\x02\x03")
    clock.advance(1.0)
    assert command(dev, 0x42)[1:7] == bytes([0, 3, 0x10, 0, 0, 0])  # nobody drove MISO
    assert target.calls == []
    set_cs_pin(dev)
    command(dev, 0x40, spi_settings(nbytes=3, cs_pin=1))  # the transaction selects GP1 only
    command(dev, 0x42, b"\x01\x02\x03")
    clock.advance(1.0)
    command(dev, 0x42)
    assert target.calls == []


def test_unknown_command_and_chip_status() -> None:
    dev = raw_device(get_backend(Recorder()))
    assert command(dev, 0x99)[1] == 0xF9
    status = command(dev, 0x10)
    assert status[1:6] == bytes([0x00, 0x01, 0x00, 0x00, 0x00])
    chip = command(dev, 0x20)
    assert chip[1] == 0x00 and list(chip[4:13]) == [0x00] * 9  # every GP pin a GPIO


def test_one_command_at_a_time() -> None:
    dev = raw_device(get_backend(Recorder()))
    report = bytes([0x10]) + bytes(63)
    dev.write(0x01, report, 100)
    with pytest.raises(usb.core.USBTimeoutError):
        dev.write(0x01, report, 100)  # the chip NAKs until its response has been read
    assert bytes(dev.read(0x81, 64, 100))[0] == 0x10
    with pytest.raises(usb.core.USBTimeoutError):
        dev.read(0x81, 64, 100)  # nothing pending


# -- the kernel HID driver -----------------------------------------------------------------------


def test_kernel_driver_must_be_detached_first() -> None:
    backend = get_backend(Recorder())
    dev = usb.core.find(idVendor=VENDOR_ID, idProduct=PRODUCT_ID, backend=backend)
    assert dev.is_kernel_driver_active(0)
    with pytest.raises(usb.core.USBError) as busy:
        dev.write(0x01, bytes([0x10]) + bytes(63), 100)
    assert busy.value.errno == errno.EBUSY
    with pytest.raises(usb.core.USBError) as busy_config:
        dev.set_configuration()
    assert busy_config.value.errno == errno.EBUSY
    dev.detach_kernel_driver(0)
    assert not dev.is_kernel_driver_active(0)
    dev.set_configuration()
    assert command(dev, 0x10)[1] == 0x00
    with pytest.raises(usb.core.USBError):
        dev.attach_kernel_driver(0)  # our claim holds the interface
    usb.util.release_interface(dev, 0)
    dev.attach_kernel_driver(0)
    assert backend.kernel_driver_attached
    usb.util.dispose_resources(dev)


def test_bridge_detaches_and_reattaches_the_kernel_driver(
    regmap: RegisterMap, backend: Mcp2210Backend
) -> None:
    assert backend.kernel_driver_attached
    b = Mcp2210Bridge(regmap.spi, backend=backend)
    assert not backend.kernel_driver_attached
    b.close()
    assert backend.kernel_driver_attached
    b.close()  # idempotent
    with pytest.raises(BridgeError, match="closed"):
        b.read(0x10)


def test_bridge_leaves_an_unbound_interface_unbound(
    regmap: RegisterMap, backend: Mcp2210Backend
) -> None:
    backend.kernel_driver_attached = False  # e.g. a udev rule unbinds usbhid
    with Mcp2210Bridge(regmap.spi, backend=backend):
        pass
    assert not backend.kernel_driver_attached


def test_second_bridge_on_a_claimed_chip_is_refused(
    bridge: Mcp2210Bridge, regmap: RegisterMap, backend: Mcp2210Backend
) -> None:
    with pytest.raises(BridgeError, match=r"claim.*busy.*close other programs"):
        Mcp2210Bridge(regmap.spi, backend=backend)
    assert bridge.read(regmap.register("CHIP_ID").address) == regmap.register("CHIP_ID").reset


# -- errors ------------------------------------------------------------------------------------


def test_device_not_found_says_what_to_check(regmap: RegisterMap) -> None:
    backend = get_backend(Recorder(), product_id=0x00DF)
    with pytest.raises(BridgeError) as exc:
        Mcp2210Bridge(regmap.spi, backend=backend)
    message = str(exc.value)
    assert "no MCP2210" in message and "VID 0x04D8, PID 0x00DE" in message
    assert "cable" in message and "lsusb" in message and "udev" in message
    with pytest.raises(BridgeError, match="serial 123"):
        Mcp2210Bridge(regmap.spi, backend=get_backend(Recorder()), serial="123")
    with Mcp2210Bridge(regmap.spi, backend=backend, product_id=0x00DF) as b:
        assert b.name == "mcp2210"


def test_serial_selects_the_device(regmap: RegisterMap, backend: Mcp2210Backend) -> None:
    with Mcp2210Bridge(regmap.spi, backend=backend, serial="0000000001") as b:
        assert b.serial_number == "0000000001"


def test_bad_arguments_are_refused(regmap: RegisterMap, backend: Mcp2210Backend) -> None:
    with pytest.raises(ValueError, match=r"GP0 \.\. GP8"):
        Mcp2210Bridge(regmap.spi, backend=backend, cs_pin=9)
    with pytest.raises(ValueError, match=r"at most 1e\+07 Hz"):
        Mcp2210Bridge(regmap.spi, backend=backend, bit_rate_hz=11e6)
    with pytest.raises(ValueError, match="1500"):
        Mcp2210Bridge(regmap.spi, backend=backend, bit_rate_hz=1000)
    with pytest.raises(ValueError, match="timeout_s"):
        Mcp2210Bridge(regmap.spi, backend=backend, timeout_s=0)
    assert backend.kernel_driver_attached  # nothing was touched


def test_a_stuck_engine_times_out_and_is_cancelled(regmap: RegisterMap) -> None:
    clock = FakeClock()  # never advances: the engine never finishes clocking
    backend = get_backend(SpiSlave(regmap.spi, SensorModel(regmap)), clock=clock)
    with Mcp2210Bridge(regmap.spi, backend=backend, timeout_s=0.05) as b:
        with pytest.raises(BridgeError, match=r"stayed busy.*cancelled.*bit rate"):
            b.read(0x10)
        assert backend.chip.counters.cancelled == 1
        assert not backend.chip.transfer_in_progress


def test_a_transaction_that_never_finishes_is_cancelled(
    bridge: Mcp2210Bridge, backend: Mcp2210Backend, regmap: RegisterMap
) -> None:
    # Another program sets 4 bytes per transaction behind our back: the 3-byte frame leaves
    # the engine waiting for a fourth byte (0x30 with no data, forever).
    backend.chip.spi_settings.bytes_per_transaction = 4
    patient_s, bridge.timeout_s = bridge.timeout_s, 0.05
    with pytest.raises(BridgeError, match=r"did not finish.*cancelled.*another program"):
        bridge.read(0x10)
    assert backend.chip.counters.cancelled == 1
    assert not backend.chip.transfer_in_progress
    backend.chip.spi_settings.bytes_per_transaction = 3
    # The usual timeout again for a read that must succeed: on a busy machine, 50 ms can pass
    # between two of the bridge's polls of the engine.
    bridge.timeout_s = patient_s
    assert bridge.read(0x00) == regmap.register("CHIP_ID").reset


def test_unplugged_bridge_raises_bridge_error(
    bridge: Mcp2210Bridge, backend: Mcp2210Backend
) -> None:
    backend.unplug()
    with pytest.raises(BridgeError, match="disconnected; check the cable"):
        bridge.read(0x10)
    bridge.close()  # still closes cleanly


def test_chip_status_errors_say_what_to_do(
    bridge: Mcp2210Bridge, backend: Mcp2210Backend, monkeypatch: pytest.MonkeyPatch
) -> None:
    def external_master(report: bytes) -> bytes:
        return bytes([report[0], 0xF7]) + bytes(62)

    monkeypatch.setattr(backend.chip, "handle", external_master)
    with pytest.raises(BridgeError, match=r"0xF7.*external master"):
        bridge.write(0x10, 1)


def test_usb_timeout_becomes_bridge_error(
    bridge: Mcp2210Bridge, backend: Mcp2210Backend, monkeypatch: pytest.MonkeyPatch
) -> None:
    def no_answer(*args: Any) -> int:
        raise usb.core.USBTimeoutError("Operation timed out", -7, errno.ETIMEDOUT)

    monkeypatch.setattr(backend, "intr_read", no_answer)
    with pytest.raises(BridgeError, match="no answer within 1 s"):
        bridge.read(0x10)


# -- across a Unix socket ------------------------------------------------------------------------


def test_bridge_over_a_unix_socket(regmap: RegisterMap, short_dir: Path) -> None:
    path = short_dir / "spi.sock"
    sensor = SensorModel(regmap)
    with SpiSocketServer(path, SpiSlave(regmap.spi, sensor), threading.RLock()) as server:
        assert path.is_socket()
        target = SocketSpiTarget(path)
        with Mcp2210Bridge(regmap.spi, backend=get_backend(target)) as b:
            assert verify_every_rw_register(b, regmap, seed=11) > 0
            offset = regmap.register("OFFSET")
            assert sensor.spi_read(offset.address) == b.read(offset.address)
        # Several clients at once, each with its own connection.
        other = SocketSpiTarget(path)
        read_chip_id = encode_spi_frame(regmap.spi, read=True, address=0)
        assert other.transfer(read_chip_id, mode=0) == target.transfer(read_chip_id, mode=0)
        assert server.connections == 2
        target.close()
        other.close()
    assert not path.exists()


def test_socket_client_reconnects_after_a_restart(regmap: RegisterMap, short_dir: Path) -> None:
    path = short_dir / "spi.sock"
    frame = encode_spi_frame(regmap.spi, read=True, address=0)
    target = SocketSpiTarget(path, timeout_s=10.0)  # the answers' wait; no server fails at once
    with pytest.raises(SpiLinkError, match=r"no simulated camera serves SPI.*--spi-socket"):
        target.transfer(frame, mode=0)
    for _ in range(2):  # the second server is a restarted simulator at the same path
        slave = SpiSlave(regmap.spi, SensorModel(regmap))
        with SpiSocketServer(path, slave, threading.Lock()):
            assert target.transfer(frame, mode=0) == b"\x00\x04\x00"  # CHIP_ID 0x0400
            assert slave.reads == 1
    target.close()


def test_bridge_reports_a_simulator_that_is_gone(regmap: RegisterMap, short_dir: Path) -> None:
    target = SocketSpiTarget(short_dir / "nobody.sock")
    # Opening needs no SPI traffic; the first register access finds nobody on the bus.
    with (
        Mcp2210Bridge(regmap.spi, backend=get_backend(target)) as b,
        pytest.raises(BridgeError, match=r"disconnected.*no simulated camera serves SPI"),
    ):
        b.read(0x00)


def test_socket_server_reports_target_errors_and_keeps_serving(short_dir: Path) -> None:
    class Picky:
        def transfer(self, mosi: bytes, *, mode: int) -> bytes:
            if not mosi:
                raise ValueError("empty transaction")
            return mosi

    path = short_dir / "spi.sock"
    with SpiSocketServer(path, Picky(), threading.Lock()):
        target = SocketSpiTarget(path)
        with pytest.raises(SpiTargetError, match="ValueError: empty transaction"):
            target.transfer(b"", mode=0)
        assert target.transfer(b"\x01\x02", mode=3) == b"\x01\x02"
        # A malformed message gets an explanation and the connection is closed.
        raw = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        raw.settimeout(1.0)
        raw.connect(str(path))
        raw.sendall((0x7FFFFFFF).to_bytes(4, "big"))
        reply = raw.recv(1024)
        assert reply[4] == 1 and b"message length" in reply
        assert raw.recv(1) == b""
        raw.close()
        target.close()


def test_socket_path_conflicts(short_dir: Path) -> None:
    path = short_dir / "spi.sock"
    stale = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    stale.bind(str(path))  # a socket file nobody listens on: left by a dead simulator
    stale.close()
    with (
        SpiSocketServer(path, Recorder(), threading.Lock()),
        pytest.raises(OSError, match="already serves SPI"),
    ):
        SpiSocketServer(path, Recorder(), threading.Lock()).start()
    assert not path.exists()
    path.write_text("not a socket")
    with pytest.raises(FileExistsError, match="not a socket"):
        SpiSocketServer(path, Recorder(), threading.Lock()).start()


# -- the real simulator process ------------------------------------------------------------------


def test_simulator_process_serves_spi(regmap: RegisterMap, short_dir: Path) -> None:
    path = short_dir / "cam-spi.sock"
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(REPO), env.get("PYTHONPATH")) if p)
    proc = subprocess.Popen(
        [
            *(sys.executable, "-m", "firmware_models", "--json", "--hk-period-s", "0"),
            *("--spi-socket", str(path)),
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=REPO,
        env=env,
    )
    try:
        assert proc.stdout is not None
        ready, _, _ = select.select([proc.stdout], [], [], 10.0)
        assert ready, "the simulator printed nothing within 10 s"
        line = proc.stdout.readline()
        assert line, proc.communicate(timeout=5)[1]
        info = json.loads(line)
        assert info["spi_socket"] == str(path) and path.is_socket()
        target = SocketSpiTarget(info["spi_socket"])
        with Mcp2210Bridge(regmap.spi, backend=get_backend(target)) as b:
            assert b.read(regmap.register("CHIP_ID").address) == 0x0400
            assert verify_every_rw_register(b, regmap, seed=29) > 0
        target.close()
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=10) == 0
        assert not path.exists()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=5)
        for stream in (proc.stdout, proc.stderr):
            if stream is not None:
                stream.close()


def test_spi_socket_is_null_in_the_start_line_without_the_option() -> None:
    from firmware_models.cli import _start_line
    from firmware_models.inject import InjectSpec

    info = json.loads(_start_line(True, "/dev/pts/9", None, "hr400", InjectSpec()))
    assert info["spi_socket"] is None
