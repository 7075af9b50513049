"""The pure scan planner (camd.daemon.scan_plan) and the undo journal (camd.daemon.transaction).

The plan is checked against the equations of docs/physics.md §2 and §6 worked out here, on the
hr400's real register map and register layer (the preview sends nothing, so no bridge is
needed), with the registers at their reset values.
"""

from __future__ import annotations

import dataclasses
import datetime as dt
import math
from pathlib import Path
from typing import Any

import pytest

from camd.daemon.errors import BadRequest, DeviceRejected
from camd.daemon.models import ScanRequest, TimingResponse
from camd.daemon.scan_plan import (
    ScanContext,
    StageContext,
    plan_scan,
    scan_path,
    travel_needed_m,
)
from camd.daemon.sensor_service import RegisterSnapshot
from camd.daemon.transaction import Apply, ApplyFailed
from camd.motion.stage import StageLimits
from camd.sensor.profile import load_profile
from camd.sensor.registers import SensorRegisters
from camd.sensor.regmap import load_register_map
from camd.sensor.timing_view import reset_timing

REGMAP = load_register_map("hr400")
CAMERA = load_profile("hr400")
PITCH_M = CAMERA.pitch_m.value
MAG = CAMERA.magnification.value
ROW_S = 513 / 25e6  # hr400: 513 sequencer clocks of 25 MHz per row (docs/physics.md §3)
NOW = dt.datetime(2026, 11, 25, 12, 0, 0, tzinfo=dt.UTC)
LIMITS = StageLimits(low_m=0.0, high_m=1.2, max_speed_m_s=0.1, accel_m_s2=0.5)


def _context(
    tmp_path: Path, *, stage: StageContext | None = None, ideal: bool = False
) -> ScanContext:
    registers = SensorRegisters(REGMAP, bridge=None)  # type: ignore[arg-type]
    snapshot = RegisterSnapshot(REGMAP, registers, {r.name: r.reset for r in REGMAP.registers})
    return ScanContext(
        timing=TimingResponse.model_validate(reset_timing(REGMAP).as_dict()),
        preview=snapshot.preview,
        regmap=REGMAP,
        columns=REGMAP.columns,
        pixel_pitch_m=PITCH_M,
        magnification=MAG,
        stage=stage,
        ideal_stage=ideal,
        path=scan_path(None, tmp_path, NOW),
    )


def _stage(position_m: float = 0.6, state: str = "idle") -> StageContext:
    return StageContext(
        kind="linear",
        limits=LIMITS,
        position_m=position_m,
        state=state,
        loop_mode="step_rate",
        image_scale=MAG,
        encoder_counts_per_m=1e6,
    )


def test_line_period_sets_window_rows_and_back_path_by_eqs_8_9(tmp_path: Path) -> None:
    period = 10.25 * ROW_S  # 10 rows and a quarter-row back path
    plan = plan_scan(
        ScanRequest(stages=8, lines=100, line_period_s=period, drive_stage=False),
        _context(tmp_path),
    )
    window = REGMAP.role("window_rows")
    back = REGMAP.role("back_path")
    assert window is not None and back is not None
    # eq 8: n = floor(T / T_row) = 10; eq 9: T_back = T - 10 T_row, in whole 25 MHz clocks.
    assert plan.timing.n_lines == 10
    assert plan.register_writes[back] == round(0.25 * 513)
    assert plan.timing.back_path_s == pytest.approx(round(0.25 * 513) / 25e6, rel=1e-12)
    assert plan.timing.tdi_line_period_s == pytest.approx(
        10 * ROW_S + round(0.25 * 513) / 25e6, rel=1e-12
    )
    # eq 3: the exposure shrinks to at most n - 1 rows only if it was longer.
    assert plan.timing.exposure_s <= 9 * ROW_S + 1e-12
    assert plan.frames == 100 + 8 - 1
    assert plan.path == tmp_path / "scans" / "scan-20261125T120000.000000Z.h5"


def test_stage_speed_sets_the_period_and_the_driven_stage_runs_synchronous(tmp_path: Path) -> None:
    # T_line,TDI = p / (m v) (general eq 5); the stage then runs at p / (m T_realised).
    speed = PITCH_M / (MAG * 100.4 * ROW_S)  # a 100.4-row line period (26.7 mm/s)
    plan = plan_scan(
        ScanRequest(stages=4, lines=50, speed_m_s=speed, dv_over_v=0.1),
        _context(tmp_path, stage=_stage()),
    )
    wanted = PITCH_M / (MAG * speed)
    assert plan.timing.n_lines == math.floor(wanted / ROW_S) == 100
    realised = plan.timing.tdi_line_period_s
    assert abs(realised - wanted) < 1 / 25e6  # whole clocks of the back path
    sync = PITCH_M / (MAG * realised)
    assert plan.timing.sync_speed_m_s == pytest.approx(sync, rel=1e-12)
    assert plan.stage is not None
    assert plan.stage.speed_m_s == pytest.approx(sync * 0.9, rel=1e-12)  # (1 - dV/V) V
    assert plan.timing.dv_over_v == pytest.approx(0.1, rel=1e-9)
    assert plan.stage.rewind_to_m is None  # 0.6 m ahead is plenty
    duration = (50 + 3) * realised + 2.0
    assert plan.stage.travel_m == pytest.approx(travel_needed_m(sync * 0.9, duration, LIMITS))


def test_a_scan_that_does_not_fit_ahead_rewinds_and_one_beyond_the_limits_is_refused(
    tmp_path: Path,
) -> None:
    request = ScanRequest(stages=4, lines=2000, speed_m_s=0.05)
    plan = plan_scan(request, _context(tmp_path, stage=_stage(position_m=1.15)))
    assert plan.stage is not None and plan.stage.rewind_to_m == 0.0
    with pytest.raises(BadRequest, match=r"mm of travel .* soft limits leave 1200.0 mm"):
        plan_scan(
            ScanRequest(stages=4, lines=200_000, speed_m_s=0.05),
            _context(tmp_path, stage=_stage()),
        )
    with pytest.raises(BadRequest, match=r"above the limit 100 mm/s"):
        plan_scan(
            ScanRequest(stages=4, lines=10, speed_m_s=0.2), _context(tmp_path, stage=_stage())
        )
    with pytest.raises(BadRequest, match="emergency stop"):
        plan_scan(request, _context(tmp_path, stage=_stage(state="estop")))


@pytest.mark.parametrize(
    ("fields", "message"),
    [
        ({"speed_m_s": 1e-3, "line_period_s": 1e-3}, "either speed_m_s or line_period_s"),
        ({"dv_over_v": 0.7}, r"dv_over_v = 0.7 with the stage driven: it takes -0.5 .. 0.5"),
        (
            {"stages": 11, "drive_stage": False, "line_period_s": 10.5 * ROW_S},
            r"needs 11 window rows but the scan's frames have 10 .* choose 1..10 stages",
        ),
        ({"line_period_s": 1e-6, "drive_stage": False}, "shorter than one row period"),
    ],
)
def test_refusals_say_what_to_change(tmp_path: Path, fields: dict[str, Any], message: str) -> None:
    request = ScanRequest.model_validate({"stages": 4, "lines": 5, **fields})
    with pytest.raises(BadRequest, match=message):
        plan_scan(request, _context(tmp_path, stage=_stage()))


def test_the_file_is_confined_or_time_stamped_in_the_data_dir(tmp_path: Path) -> None:
    data, extra = tmp_path / "data", tmp_path / "extra"
    assert scan_path(None, data, NOW) == data / "scans/scan-20261125T120000.000000Z.h5"
    assert scan_path("x.h5", data, NOW) == data / "scans/x.h5"  # relative: in the scans folder
    assert scan_path(str(data / "x.h5"), data, NOW) == data / "x.h5"
    assert scan_path(str(extra / "x.h5"), data, NOW, [extra]) == extra / "x.h5"
    with pytest.raises(BadRequest, match=r"out '/data/x\.h5' is outside the directories the "):
        scan_path("/data/x.h5", data, NOW)
    with pytest.raises(BadRequest, match=r"resolves to '/etc/x\.h5', outside the directories"):
        scan_path("../" * 40 + "etc/x.h5", data, NOW)


def test_the_ideal_stage_takes_any_mismatch(tmp_path: Path) -> None:
    plan = plan_scan(
        ScanRequest(stages=4, lines=5, drive_stage=False, dv_over_v=-1.25),
        _context(tmp_path, ideal=True),
    )
    sync = PITCH_M / (MAG * plan.timing.tdi_line_period_s)
    assert plan.stage is None
    assert plan.ideal_stage_speed_m_s == pytest.approx(2.25 * sync, rel=1e-12)


# -- the undo journal -----------------------------------------------------------------------


def test_apply_undoes_newest_first_and_names_what_it_restored() -> None:
    done: list[str] = []
    events: list[tuple[str, str, str]] = []

    def nak() -> None:
        raise DeviceRejected("the device refused REG_WRITE_BURST (OUT_OF_RANGE)", "OUT_OF_RANGE")

    with (
        pytest.raises(DeviceRejected) as info,
        Apply("scan start", lambda *e: events.append(e)) as apply,
    ):
        apply.step(lambda: done.append("mode tdi"), lambda: done.append("mode area"), "mode area")
        apply.step(lambda: done.append("scene"), lambda: done.append("scene back"), "scene flat")
        apply.step(nak, lambda: done.append("never"), "registers")
    assert done == ["mode tdi", "scene", "scene back", "mode area"]
    assert info.value.name == "OUT_OF_RANGE"  # the same kind of error: the same HTTP status
    assert str(info.value) == (
        "the device refused REG_WRITE_BURST (OUT_OF_RANGE); restored: scene flat, mode area"
    )
    assert events == [
        (
            "warning",
            "api",
            "scan start failed: the device refused REG_WRITE_BURST (OUT_OF_RANGE); "
            "restored: scene flat, mode area",
        )
    ]


def test_apply_reports_an_undo_that_fails_and_wraps_unexpected_errors() -> None:
    def lost() -> None:
        raise OSError("no space left on device")

    def cannot() -> None:
        raise DeviceRejected("link down", "")

    with pytest.raises(ApplyFailed) as info, Apply("stare start", lambda *e: None) as apply:
        apply.step(lambda: None, cannot, "mode area")
        apply.step(lost, None, "file")
    assert str(info.value) == (
        "stare start failed: OSError: no space left on device; could NOT restore: "
        "mode area (link down) (check them by hand)"
    )


def test_a_driven_scan_until_stopped_runs_until_the_travel_ends(tmp_path: Path) -> None:
    """issue 31: `scan --lines 0` (documented "until stopped") was refused as needing 2389.8 mm
    of travel (a minute planned); it now takes the frames the travel between the soft limits
    holds, and says so: it ends done there unless stopped first."""
    period = 3e-3
    plan = plan_scan(
        ScanRequest(stages=4, lines=0, line_period_s=period), _context(tmp_path, stage=_stage())
    )
    speed = PITCH_M / (MAG * plan.timing.tdi_line_period_s)
    ramps = speed**2 / LIMITS.accel_m_s2
    frames = math.floor(((1.2 / 1.05 - ramps) / speed - 2.0) / plan.timing.tdi_line_period_s)
    assert plan.frames == frames > 9000
    assert plan.stage is not None and plan.stage.travel_m <= 1.2
    assert plan.stage.rewind_to_m == 0.0  # from the low end: the whole travel
    assert plan.notes[-1] == (
        f"until stopped: the stage's travel (1200.0 mm between the soft limits, at "
        f"{speed * 1e3:.6g} mm/s) holds {frames - 3} lines; the scan ends there (state done) "
        "unless it is stopped first (state stopped)"
    )
    # Without a driven stage it runs until stopped, as before.
    free = plan_scan(
        ScanRequest(stages=4, lines=0, line_period_s=period, drive_stage=False), _context(tmp_path)
    )
    assert free.frames == 0


def test_a_scan_until_stopped_with_travel_for_no_line_is_refused(tmp_path: Path) -> None:
    short = StageContext(kind="linear", position_m=0.01, state="idle", loop_mode="step_rate",
                         limits=StageLimits(low_m=0.0, high_m=0.05, max_speed_m_s=0.1,
                                            accel_m_s2=0.5),
                         image_scale=MAG, encoder_counts_per_m=1e6)  # fmt: skip
    with pytest.raises(BadRequest) as info:
        plan_scan(ScanRequest(stages=4, lines=0, line_period_s=3e-3),
                  _context(tmp_path, stage=short))  # fmt: skip
    assert str(info.value) == (
        "a scan until stopped at 36.67 mm/s: the soft limits leave 50.0 mm of travel, not enough "
        "for one complete line of 4 stages; scan slower (a longer line period), or widen "
        "stage.low_limit_m / high_limit_m"
    )


def test_the_image_loop_is_planned_or_refused_with_what_to_change(tmp_path: Path) -> None:
    period = 100 * ROW_S
    request = ScanRequest(stages=4, lines=50, line_period_s=period, image_loop=True)
    plan = plan_scan(request, _context(tmp_path, stage=_stage()))
    # the loop trims the line period: the frames may have from M to the planned rows, the
    # engine keeps its own
    assert plan.image_loop and plan.max_lines == 100 and plan.rows == 4
    # config motion.image_loop is the default; the request overrides it
    default = dataclasses.replace(_context(tmp_path, stage=_stage()), image_loop=True)
    assert plan_scan(request.model_copy(update={"image_loop": None}), default).image_loop
    assert not plan_scan(request.model_copy(update={"image_loop": False}), default).image_loop
    assert not plan_scan(
        request.model_copy(update={"image_loop": None}), _context(tmp_path)
    ).image_loop
    line_period = dataclasses.replace(_stage(), loop_mode="line_period")
    with pytest.raises(BadRequest, match=r'set motion\.correct = "step_rate"'):
        plan_scan(request, _context(tmp_path, stage=line_period))
    unmeasured = dataclasses.replace(_context(tmp_path, stage=_stage()), image_measure=False)
    with pytest.raises(BadRequest, match=r"set motion\.image_measure = true"):
        plan_scan(request, unmeasured)
