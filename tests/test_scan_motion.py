"""A scan's motion (camd.daemon.scan_motion) on its narrow stage drive (camd.daemon.stage_drive).

``ScanMotion`` knows the stage only through a ``StageDrive``: brake, program limits, go to, run at a
speed (the ramp's duration back), trim, stop, release. Here the drive's ``FpgaStage`` sends its
MOTOR_* commands straight to the simulated FPGA's stepper controller
(``firmware_models.motor.MotorController``) on a lock, at wall-clock time since the harness
started: no daemon, no link, no motion service. Rail numbers by hand
(config/stages/linear_rail.toml): 640000 microsteps/m, 1e6 encoder counts/m, travel 1.2 m,
0.1 m/s and 0.5 m/s^2 at most.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Mapping
from typing import Any

import pytest

from camd.daemon.config import MotionSection
from camd.daemon.errors import BadRequest
from camd.daemon.scan_motion import ScanMotion
from camd.daemon.scan_plan import StagePlan
from camd.daemon.stage_drive import StageDrive
from camd.motion.stage import FpgaStage, StageLimits
from camd.motion.stage_profile import load_stage_profile
from firmware_models.motor import MotorController

RAIL = load_stage_profile("linear_rail")
ROW_S = 513 / 25e6  # hr400's row period (docs/physics.md §3)
PITCH_M = 11e-6
SCALE = 0.1  # the rail carries the target: the camera's magnification
# Narrower than the driver's own maxima, so that programming them is seen (and undoing it).
SCAN_LIMITS = StageLimits(low_m=0.0, high_m=1.2, max_speed_m_s=0.08, accel_m_s2=0.5)


class Harness:
    """A StageDrive whose FpgaStage talks to a MotorController in this process."""

    def __init__(self) -> None:
        self.motor = MotorController(RAIL, seed=1)
        self.events: list[tuple[str, str]] = []
        self.taken = 0
        self.commands: list[str] = []
        self.rates_hz: list[int] = []  # every MOTOR_SET_RATE's rate, in order
        self._lock = threading.Lock()
        self._t0 = time.monotonic()
        self.drive = StageDrive(
            FpgaStage(RAIL, self.request), on_take=self.take, events=self.log_event
        )

    def request(self, command: str, **fields: Any) -> Mapping[str, Any]:
        with self._lock:
            self.commands.append(command)
            if command == "MOTOR_SET_RATE":
                self.rates_hz.append(int(fields["rate_hz"]))
            return self.motor.handle(command, time.monotonic() - self._t0, fields)

    def take(self) -> None:
        self.taken += 1

    def log_event(self, level: str, message: str) -> None:
        self.events.append((level, message))


def stage_plan(speed_m_s: float, *, rewind_to_m: float | None, loop_mode: str) -> StagePlan:
    return StagePlan(
        speed_m_s=speed_m_s,
        loop_mode=loop_mode,
        pixel_pitch_m=PITCH_M,
        row_time_s=ROW_S,
        stages=4,
        max_lines=16,
        offset=0.0,
        duration_s=1.0,
        travel_m=0.02,
        rewind_to_m=rewind_to_m,
        counts_per_pixel=1e6 * PITCH_M / SCALE,
        must_brake=False,
        limits=SCAN_LIMITS,
        image_scale=SCALE,
        encoder_counts_per_m=RAIL.encoder_counts_per_m,
    )


def test_a_scans_motion_rewinds_runs_and_is_put_back_through_the_drive_alone() -> None:
    rig = Harness()
    drive = rig.drive
    # The operator left the released stage 30 mm from the low end.
    drive.go_to(0.03)
    drive.release()
    stood = drive.read()
    assert (stood.state, stood.position_m) == ("disabled", pytest.approx(0.03, abs=1e-9))
    limits_before = drive.limits()
    assert limits_before.max_speed_m_s == pytest.approx(0.1)  # the driver's own maximum

    # 10 mm/s forwards, 1e-2 x 640000 = 6400 microsteps/s; rewound to the low limit first.
    motion = ScanMotion(
        drive, stage_plan(0.01, rewind_to_m=0.0, loop_mode="step_rate"), MotionSection()
    )
    motion.start()
    try:
        running = drive.read()
        assert running.state == "running"
        assert rig.rates_hz[0] == 6400  # the run itself; then the closed loop's trims
        # Read back: 6400 Hz, or already trimmed by the closed loop (its first poll may come
        # first on a busy machine: 0.0100446 m/s was read once), within its largest trim.
        assert round(running.speed_m_s * 640_000) in rig.rates_hz  # a rate it was sent
        assert running.speed_m_s == pytest.approx(0.01, rel=MotionSection().max_trim)
        assert drive.limits() == SCAN_LIMITS  # programmed whole (exact in microsteps)
        assert 0.0 < running.position_m < 0.01  # from the low end, after the ramp and settle
        assert rig.taken == 1  # the motion service's move/homing is forgotten once
        # The closed loop polls the encoder (every 20 ms by default): let it take some.
        deadline = time.monotonic() + 30.0
        while len(motion.record.time_s) < 5:
            assert time.monotonic() < deadline, "the closed loop took no samples"
            time.sleep(0.05)
    finally:
        motion.finish()
    assert motion.error is None
    assert rig.events[0] == ("info", "rewinding the stage to 0.0 mm: 20.0 mm of travel needed")

    # A scan that could not start: stopped, back where it stood, limits and motor as they were.
    motion.restore(0.03)
    after = drive.read()
    assert after.state == "disabled"
    assert after.position_m == pytest.approx(0.03, abs=1e-9)
    assert drive.limits() == limits_before
    # The closed loop's trims are MOTOR_SET_RATEs too; before them the ramp to speed was one.
    assert "MOTOR_SET_RATE" in rig.commands


def test_a_run_beyond_the_stage_is_refused_with_its_limits_words() -> None:
    rig = Harness()
    rig.drive.go_to(0.5)
    # 0.2 m/s is above the rail's 0.1 m/s: the stage refuses before anything is sent.
    sent = len(rig.commands)
    with pytest.raises(BadRequest) as info:
        rig.drive.run(0.2)
    assert str(info.value).startswith("stage speed 200 mm/s is above the linear_rail")
    assert rig.commands[sent:] == ["MOTOR_ENABLE"]
    assert rig.drive.read().state == "idle"
