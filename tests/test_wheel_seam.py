"""The filter wheel's device seam (camd.motion.wheel): the interface checks, the FPGA implements.

``FpgaWheel`` runs over a real pty to the simulated FPGA (CommandLink -> FpgaModel), the same
path the daemon takes; the interface's checks are shown on a minimal implementation that records
what reaches its ``_do_*`` hooks.
"""

from __future__ import annotations

import struct
import threading
from collections.abc import Iterator
from typing import Any

import pytest

from camd.link import CommandLink
from camd.motion.wheel import FilterWheel, FpgaWheel, WheelReading, WheelSpeedError
from camd.motion.wheel_profile import load_wheel_profile
from camd.protocol.dictionary import f32_decimal
from firmware_models.fpga import FpgaModel
from firmware_models.pty_server import PtyServer

PROFILE = load_wheel_profile()


class RecordingWheel(FilterWheel):
    """A wheel that only records the calls reaching its hooks."""

    def __init__(self) -> None:
        self.calls: list[tuple[str, Any]] = []

    def _do_set_speed(self, speed_deg_s: float) -> None:
        self.calls.append(("speed", speed_deg_s))

    def _do_set_compensation(self, on: bool) -> None:
        self.calls.append(("compensation", on))

    def _do_read(self) -> WheelReading:
        raise NotImplementedError


@pytest.mark.parametrize("speed_deg_s", [-1.0, 360.5, float("nan"), float("inf")])
def test_a_speed_outside_the_range_never_reaches_the_device(speed_deg_s: float) -> None:
    wheel = RecordingWheel()
    with pytest.raises(WheelSpeedError, match=r"is outside 0 \.\. 360 deg/s \(0 stops the wheel\)"):
        wheel.set_speed(speed_deg_s)
    assert wheel.calls == []


def test_stop_is_never_refused() -> None:
    wheel = RecordingWheel()
    wheel.set_speed(360.0)
    wheel.stop()
    assert wheel.calls == [("speed", 360.0), ("speed", 0.0)]


def test_f32_decimal_undoes_the_wires_rounding() -> None:
    sent = 73.245
    on_wire = struct.unpack(">f", struct.pack(">f", sent))[0]
    assert on_wire != sent
    assert f32_decimal(on_wire) == sent


@pytest.fixture
def fpga_wheel() -> Iterator[FpgaWheel]:
    server = PtyServer(FpgaModel(seed=3), hk_period_s=0.0)
    tty = server.open()
    thread = threading.Thread(target=server.serve, daemon=True)
    thread.start()
    link = CommandLink(tty, timeout_s=0.5, retries=5)
    link.open()
    link.wait_connected(10.0)
    try:
        yield FpgaWheel(PROFILE, lambda command, **fields: link.request(command, **fields).values)
    finally:
        link.close()
        server.stop()
        thread.join(5.0)
        server.close()


def test_the_fpga_wheel_turns_and_reads_back(fpga_wheel: FpgaWheel) -> None:
    speed = PROFILE.speed_deg_s.value
    fpga_wheel.set_speed(speed)
    reading = fpga_wheel.read()
    assert reading.speed_deg_s == speed  # the decimal sent, not its f32 neighbour
    assert 0.0 <= reading.angle_deg < 360.0
    count = PROFILE.channel_count.value
    assert reading.channel is None or 0 <= reading.channel < count
    assert reading.compensation is False
    fpga_wheel.stop()
    assert fpga_wheel.read().speed_deg_s == 0.0
