"""The simulated camera's frame source computes per-stream constants once, not per frame.

The sensor's timing is kept per register version; the stage's encoder counts are looked up
for a block of frames at once. Both must give exactly what a look-up per frame gives, also
when a command changes the registers or the stage between two frames of the block.
"""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from camd.sensor.regmap import load_register_map
from firmware_models.fpga import FpgaModel
from firmware_models.imaging import ENCODER_AHEAD_S
from firmware_models.sensor import SensorModel

ROWS = 8  # hr400 at M = 8: 164.16 us frames, twelve of them per encoder look-up
START_S = 1.0  # device time of frame 0: the stage is at speed by then


def write(sensor: SensorModel, name: str, value: int) -> None:
    sensor.spi_write(sensor.regmap.register(name).address, value)


def test_timing_follows_every_register_change_also_a_released_group_hold() -> None:
    sensor = SensorModel(load_register_map("hr400"))
    line_s = sensor.line_period_s
    write(sensor, "EXP_LO", 5)
    assert sensor.timing().exposure_s == pytest.approx(5 * line_s, rel=1e-12)
    assert sensor.timing() is sensor.timing()  # kept until the registers change
    write(sensor, "GROUP_HOLD", 1)
    write(sensor, "EXP_LO", 9)  # latched: not in force while the group is held
    assert sensor.timing().exposure_s == pytest.approx(5 * line_s, rel=1e-12)
    write(sensor, "GROUP_HOLD", 0)  # released: the latched exposure applies now
    assert sensor.timing().exposure_s == pytest.approx(9 * line_s, rel=1e-12)


@pytest.fixture
def fpga() -> Iterator[FpgaModel]:
    model = FpgaModel(seed=1)
    write(model.sensor, "WIN_ROWS", ROWS)
    model.imaging_path.engine.start = lambda **_: None  # type: ignore[method-assign]
    yield model
    model.close()


def test_block_encoder_counts_equal_one_look_up_per_frame_across_an_estop(
    fpga: FpgaModel,
) -> None:
    motor, path = fpga.motor, fpga.imaging_path
    motor.motor_enable(0.0, enable=True)
    motor.motor_set_rate(0.0, rate_hz=20000.0)  # 31 encoder counts per ms at speed
    geometry = path.start(device_time_s=START_S, mode="tdi", frames=0, stages=ROWS, binning=False)
    period_s = geometry.frame_period_s
    assert int(ENCODER_AHEAD_S / period_s) == 12
    counts = [path.frame(geometry.first_counter + k)[0].stage_position for k in range(155)]
    # Frame 154 looked up the counts of frames 144..155: the emergency stop comes before
    # frame 155 starts, after its count was looked up.
    estop_s = START_S + 154.5 * period_s
    with fpga.lock:
        motor.motor_estop(estop_s)
    counts += [path.frame(geometry.first_counter + k)[0].stage_position for k in range(155, 300)]
    # What a look-up per frame gives now, with the stop known: the stage stood from estop_s.
    # (Frame start times summed as the pipeline's clock sums them.)
    starts = [START_S]
    for _ in range(299):
        starts.append(starts[-1] + period_s)
    assert counts == [motor.encoder_count(t) for t in starts]
    assert counts[154] - counts[0] == pytest.approx(154 * period_s * 31_250, abs=2)
    assert len(set(counts[155:])) == 1  # stood still from the stop on
