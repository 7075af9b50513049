"""SensorRegisters over the FPGA bridge: CommandLink -> real pty -> FpgaModel -> SPI -> sensor.

The simulated FPGA runs in a thread behind a real pseudo-terminal with a lossy line; the host is
the same code the daemon runs. The point: a register write whose acknowledge is lost is retried
and answered from the device's record, so the sensor sees it exactly once.
"""

from __future__ import annotations

import random
import threading
from collections.abc import Iterator

import pytest

from camd.link import CommandLink
from camd.sensor.fpga_bridge import FpgaBridge
from camd.sensor.registers import SensorRegisters
from camd.sensor.regmap import load_register_map
from firmware_models.fpga import FpgaModel
from firmware_models.inject import FaultInjector, InjectSpec
from firmware_models.pty_server import PtyServer

HR400 = load_register_map("hr400")


class Rig:
    """An FpgaModel served on a pty in a thread, and a CommandLink + FpgaBridge to it."""

    def __init__(self, inject: str, seed: int) -> None:
        injector = FaultInjector(InjectSpec.parse(inject), seed=seed)
        self.model = FpgaModel(seed=seed, injector=injector)
        self.server = PtyServer(self.model, hk_period_s=0.0)
        tty = self.server.open()
        self.thread = threading.Thread(target=self.server.serve, daemon=True)
        self.thread.start()
        # 20 ms attempts keep injected losses cheap; 100 retries (2 s) keep a busy machine's
        # late answers from failing a command.
        self.link = CommandLink(tty, timeout_s=0.02, retries=100)
        self.link.open()
        self.link.wait_connected(5.0)
        self.bridge = FpgaBridge(self.link)
        self.registers = SensorRegisters(HR400, self.bridge)

    def close(self) -> None:
        self.link.close()
        self.server.stop()
        self.thread.join(5.0)
        self.server.close()


@pytest.fixture
def lossy() -> Iterator[Rig]:
    rig = Rig("drop=0.1", seed=11)
    yield rig
    rig.close()


def test_lost_acknowledges_are_retried_and_each_write_applied_once(lossy: Rig) -> None:
    rng = random.Random(5)
    offset = HR400.register("OFFSET")
    counts_before = lossy.model.sensor.writes[offset.address]
    values = [rng.randint(0, 1023) for _ in range(150)]
    for value in values:
        lossy.registers.write({"OFFSET": value})  # write + read-back verification
    host = lossy.link.counters()
    assert host["retries"] > 0, "the injected drops must have forced retries"
    assert lossy.model.counters.replayed > 0, "some retries must have been answered from record"
    # Each write reached the sensor exactly once, however often its frame was sent.
    assert lossy.model.sensor.writes[offset.address] - counts_before == len(values)
    assert lossy.model.sensor.register_value("OFFSET") == values[-1]


def test_group_write_is_one_burst_and_atomic(lossy: Rig) -> None:
    executed_before = lossy.model.execution_count("REG_WRITE_BURST")
    lossy.registers.write({"EXPOSURE": 0x54321})
    assert lossy.model.execution_count("REG_WRITE_BURST") == executed_before + 1
    assert lossy.model.sensor.exposure_lines == 0x54321
    assert lossy.model.sensor.value("EXPOSURE") == 0x54321
