"""The stepper stage model: stage profiles, kinematics, each imperfection measured back.

Expected values are hand-computed from the profile (5 mm lead / (200 x 16) = 1.5625 um per
microstep on the rail; 2 pi 0.1 m / (200 x 16 x 180) per microstep of arc on the turntable) and
from the model's definitions (docs/motion.md), never read back from the simulator alone.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from camd.motion.stage_profile import (
    StageProfile,
    StageProfileError,
    list_stage_profiles,
    load_stage_profile,
)
from firmware_models.stage import (
    JITTER_MODES,
    LinearStage,
    Segment,
    Stage,
    StageFaults,
    StepperStage,
)
from firmware_models.stage_kinematics import ripple_u, ripple_x

ROOT = Path(__file__).resolve().parents[1]
STAGES = ROOT / "config" / "stages"
RAIL = load_stage_profile("linear_rail")
TABLE = load_stage_profile("turntable")
D = 0.005 / 3200  # rail: metres per microstep, by hand
RATE = 35840.0  # microsteps/s: 56 mm/s on the rail


def jog(stage: StepperStage, t_s: float, rate: float) -> float:
    """Command a constant ``rate`` from ``t_s`` (no ramp); return the commanded position."""
    p, _ = stage.commanded_at(t_s)
    stage.set_profile(t_s, [Segment(t_s, p, rate, 0.0)])
    return p


def velocities(stage: StepperStage, t0: float, t1: float) -> tuple[np.ndarray, np.ndarray]:
    """Per-grid-cell mean velocity between t0 and t1 (grid aligned), and the cells' mid x."""
    n = round((t1 - t0) / stage.grid_s)
    times = t0 + np.arange(n + 1) * stage.grid_s
    x = stage.position_m(times)
    return np.diff(x) / stage.grid_s, 0.5 * (x[1:] + x[:-1])


# -- profiles -------------------------------------------------------------------------------------


def test_both_profiles_ship_with_hand_checked_derived_values() -> None:
    assert {"linear_rail", "turntable"} <= set(list_stage_profiles())
    assert RAIL.kind == "linear" and TABLE.kind == "turntable"
    assert RAIL.metres_per_microstep == pytest.approx(1.5625e-6, rel=1e-15)
    assert RAIL.microsteps_per_m == 640000.0
    assert RAIL.encoder_counts_per_m == 1e6
    assert RAIL.travel_microsteps == 768000
    assert RAIL.max_rate_hz == pytest.approx(64000.0)  # 0.1 m/s
    arc = 2 * math.pi * 0.1 / (200 * 16 * 180)
    assert TABLE.metres_per_microstep == pytest.approx(arc, rel=1e-14)
    assert TABLE.microsteps_per_m * TABLE.metres_per_microstep == pytest.approx(1.0, rel=1e-14)
    assert TABLE.encoder_counts_per_m == pytest.approx(2**20 / (2 * math.pi * 0.1), rel=1e-14)
    assert TABLE.travel_microsteps is None
    # Image scale: the rail's carriage carries the target (m); the table carries the sensor (1).
    assert RAIL.image_scale(0.1) == 0.1
    assert TABLE.image_scale(0.1) == 1.0
    # The default rail allows a 10 s scan at 56 mm/s from the middle, ramps included.
    ramp = 0.056**2 / RAIL.max_accel_m_s2.value
    assert RAIL.travel_m is not None and RAIL.travel_m.value / 2 > 0.56 + ramp


def test_profile_loads_by_path_and_every_value_has_a_provenance() -> None:
    for name in ("linear_rail", "turntable"):
        profile = load_stage_profile(STAGES / f"{name}.toml")
        assert profile == load_stage_profile(name)
        for key, value in profile:
            if hasattr(value, "provenance"):
                assert value.provenance.split(": ", 1)[1].strip(), key


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "stage.toml"
    path.write_text(text, encoding="utf-8")
    return path


RAIL_TEXT = (STAGES / "linear_rail.toml").read_text(encoding="utf-8")


@pytest.mark.parametrize(
    ("old", "new", "expected"),
    [
        (
            'lead_m_per_rev = { value = 0.005, assumed = "5 mm ball-screw lead, common on bench rails" }\n',
            "",
            'needs lead_m_per_rev (m/rev); add `lead_m_per_rev = { value = ..., source = "..." }`',
        ),
        (
            'kind = "linear"',
            'kind = "linear"\ngear_ratio = { value = 3, assumed = "x" }',
            'gear_ratio: kind = "linear" does not use gear_ratio; remove it',
        ),
        (
            "max_speed_m_s = { value = 0.1,",
            "max_speed_m_s = { value = 0.9,",
            "max_speed_m_s: 0.9 m/s needs 576000 microsteps/s, above driver_max_rate_hz = 400000; "
            "lower max_speed_m_s to at most 0.625",
        ),
        ("microsteps = { value = 16,", "microsteps = { value = 512,", "microsteps.value"),
        ("[sim]", "[sim]\nbogus = 1", "sim.bogus: unknown key; known keys:"),
        (
            'travel_m = { value = 1.2, assumed = "room',
            'travel_m = { value = 1.2, source = "x", assumed = "room',
            "travel_m: give exactly one of `source`",
        ),
        ("home_speed_m_s = { value = 0.02,", "home_speed_m_s = { value = 0.2,", "lower it"),
    ],
)
def test_bad_profiles_say_what_to_change(tmp_path: Path, old: str, new: str, expected: str) -> None:
    assert old in RAIL_TEXT
    path = _write(tmp_path, RAIL_TEXT.replace(old, new, 1))
    with pytest.raises(StageProfileError) as info:
        load_stage_profile(path)
    message = str(info.value)
    assert message.startswith(f"{path}:")
    assert expected in message


def test_unknown_profile_name_lists_the_known_ones() -> None:
    with pytest.raises(FileNotFoundError, match=r"known: .*linear_rail.*turntable"):
        load_stage_profile("conveyor")


# -- kinematics of a perfect stage ----------------------------------------------------------------


def test_stepper_stage_is_a_stage_for_the_camera() -> None:
    stages: list[Stage] = [StepperStage(RAIL), LinearStage(0.01)]
    for stage in stages:
        assert stage.position_m(np.array([0.0, 1.0])).shape == (2,)


def test_power_on_position_is_mid_travel_and_half_a_turn() -> None:
    assert StepperStage(RAIL).position_m(np.array([0.0]))[0] == pytest.approx(0.6)
    table = StepperStage(TABLE)
    assert table.position_m(np.array([0.0]))[0] == pytest.approx(math.pi * 0.1)


@given(
    rate=st.floats(-64000.0, 64000.0).filter(lambda r: abs(r) > 1.0),
    start=st.floats(0.0, 3.0),
    span=st.floats(0.01, 1.5),
    offset=st.floats(0.0, 0.5),
)
def test_a_perfect_stage_moves_rate_times_step_length(
    rate: float, start: float, span: float, offset: float
) -> None:
    stage = StepperStage(RAIL)
    jog(stage, start, rate)
    t0 = start + offset
    x0, x1 = stage.position_m(np.array([t0, t0 + span]))
    assert (x1 - x0) == pytest.approx(rate * D * span, rel=1e-9)
    v = stage.velocity_m_s(np.array([t0 + 0.5 * span]))[0]
    assert v == pytest.approx(rate * D, rel=1e-9)


def test_positions_follow_a_ramp_between_grid_points() -> None:
    """During a ramp ``x = x0 + d (v0 tau + a tau^2 / 2)`` at any time, not only on the grid."""
    stage = StepperStage(RAIL)
    p0, _ = stage.commanded_at(1.0)
    accel = 320000.0
    stage.set_profile(1.0, [Segment(1.0, p0, 0.0, accel), Segment(1.2, p0 + 6400.0, 64000.0)])
    taus = np.array([0.0, 1.234567e-5, 0.0375, 0.1111111, 0.19999, 0.2, 0.35])
    x = stage.position_m(1.0 + taus)
    expected = (
        np.where(taus <= 0.2, 0.5 * accel * taus**2, 6400.0 + 64000.0 * (taus - 0.2)) * D + p0 * D
    )
    np.testing.assert_allclose(x, expected, rtol=0, atol=1e-12)


def test_turntable_positions_are_arc_at_the_sensor_radius() -> None:
    stage = StepperStage(TABLE, position_m=0.0)
    turn = 200 * 16 * 180  # microsteps per table revolution
    stage.set_profile(0.0, [Segment(0.0, 0.0, turn / 10.0), Segment(10.0, float(turn))])
    x = stage.position_m(np.array([10.0, 20.0]))
    np.testing.assert_allclose(x, 2 * math.pi * 0.1, rtol=1e-12)  # one turn: 2 pi l of arc
    counts = stage.encoder_counts(np.array([10.0]))
    assert counts[0] == 2**20  # the table encoder: 2^20 counts per revolution


# -- imperfections ----------------------------------------------------------------------------


def test_step_rate_error_gives_exactly_that_speed_error() -> None:
    stage = StepperStage(RAIL, faults=StageFaults(error=0.005))
    jog(stage, 1.0, RATE)
    x0, x1 = stage.position_m(np.array([2.0, 7.0]))
    assert (x1 - x0) / (5.0 * RATE * D) == pytest.approx(1.005, rel=1e-12)


def _fit_ripple(v_rel: np.ndarray, x: np.ndarray, period: float) -> tuple[float, float]:
    """Least-squares amplitude of ``v_rel = c + A sin(2 pi x / period + phase)``."""
    k = 2 * math.pi / period
    design = np.column_stack([np.sin(k * x), np.cos(k * x), np.ones_like(x)])
    coef, residual, *_ = np.linalg.lstsq(design, v_rel, rcond=None)
    return float(math.hypot(coef[0], coef[1])), float(residual[0]) if residual.size else 0.0


@pytest.mark.parametrize("ripple", [0.01, 0.15])
def test_ripple_amplitude_and_period_are_measured_back(ripple: float) -> None:
    stage = StepperStage(RAIL, seed=3, faults=StageFaults(ripple=ripple))
    jog(stage, 1.0, RATE)
    v, x = velocities(stage, 1.0, 11.0)  # 0.56 m: 22 ripple periods
    v_rel = v / (RATE * D) - 1.0
    # The period: the best sinusoidal fit over candidate periods, then refined.
    candidates = np.linspace(0.015, 0.035, 401)
    residuals = [_fit_ripple(v_rel[::20], x[::20], c)[1] for c in candidates]
    best = float(candidates[int(np.argmin(residuals))])
    fine = np.linspace(best - 1e-4, best + 1e-4, 201)
    residuals = [_fit_ripple(v_rel[::20], x[::20], c)[1] for c in fine]
    period = float(fine[int(np.argmin(residuals))])
    amplitude, _ = _fit_ripple(v_rel, x, period)
    assert period == pytest.approx(0.025, rel=2e-3)
    assert amplitude == pytest.approx(ripple, rel=5e-3)
    # The model's phase: v = v0 (1 + R sin(2 pi x / lambda + phi)), exactly (to the grid).
    k = 2 * math.pi / 0.025
    np.testing.assert_allclose(
        v_rel, ripple * np.sin(k * x + stage.ripple_phase_rad), atol=ripple * 2e-3
    )


@given(
    x=st.floats(-2.0, 2.0),
    r=st.floats(0.0, 0.2),
    phase=st.floats(0.0, 2 * math.pi),
)
def test_ripple_map_inverts(x: float, r: float, phase: float) -> None:
    k = 2 * math.pi / 0.025
    arr = np.array([x])
    back = ripple_x(ripple_u(arr, r, k, phase), r, k, phase)
    assert back[0] == pytest.approx(x, abs=1e-12)


def test_jitter_rms_and_correlation_time_match_the_setting() -> None:
    jitter = 0.02
    stage = StepperStage(RAIL, seed=5, faults=StageFaults(jitter=jitter))
    jog(stage, 1.0, RATE)
    v, _ = velocities(stage, 1.0, 31.0)
    v_rel = v / (RATE * D) - 1.0
    assert abs(float(v_rel.mean())) < 0.1 * jitter
    assert float(v_rel.std()) == pytest.approx(jitter, rel=0.1)
    # Correlation over jitter_corr_s = 5 ms: exp(-1) at that lag (100 grid cells).
    lag = round(RAIL.sim.jitter_corr_s.value / stage.grid_s)
    z = (v_rel - v_rel.mean()) / v_rel.std()
    rho = float(np.mean(z[:-lag] * z[lag:]))
    assert rho == pytest.approx(math.exp(-1.0), abs=0.1)


def test_jitter_noise_is_unit_variance_by_construction() -> None:
    stage = StepperStage(RAIL, seed=8)
    n = stage.jitter_noise(np.arange(0.0, 200.0, 1e-3))
    assert float(n.std()) == pytest.approx(1.0, rel=0.1)
    assert JITTER_MODES == 64


def test_drift_grows_speed_with_running_time_and_restarts_after_a_stop() -> None:
    drift = 0.01  # per second
    stage = StepperStage(RAIL, faults=StageFaults(drift=drift))
    jog(stage, 1.0, RATE)
    # x(T) = v (T + drift T^2 / 2) for a run starting at rest at 1.0 s.
    x0, x2 = stage.position_m(np.array([1.0, 3.0]))
    assert (x2 - x0) == pytest.approx(RATE * D * (2.0 + drift * 2.0**2 / 2), rel=1e-9)
    v = stage.velocity_m_s(np.array([3.0]))[0]
    assert v == pytest.approx(RATE * D * (1 + drift * 2.0), rel=1e-6)
    jog(stage, 4.0, 0.0)
    jog(stage, 5.0, RATE)
    v = stage.velocity_m_s(np.array([5.5]))[0]
    assert v == pytest.approx(RATE * D * (1 + drift * 0.5), rel=1e-6)


def test_pull_out_torque_curve() -> None:
    """Overloaded where load + 0.2 |a| / a_max exceeds min(1, v_c / |v|), v_c = 0.05 m/s."""
    stage = StepperStage(RAIL)
    corner = 0.05 * 640000  # 32000 microsteps/s
    rates = np.array([1000.0, corner, 40000.0, 64000.0, -64000.0, 0.0])
    assert stage.overloaded(StageFaults(load=0.0), rates, 0.0).tolist() == [False] * 6
    # load 0.6: the motor delivers 32000 / |r| > 0.6 up to |r| = 53333 microsteps/s.
    over = stage.overloaded(StageFaults(load=0.6), rates, 0.0).tolist()
    assert over == [False, False, False, True, True, False]
    # Accelerating at the full 320000 microsteps/s^2 needs 0.2 more: 0.8 at 40000 (avail 0.8).
    assert not stage.overloaded(StageFaults(load=0.6), np.array([39999.0]), 320000.0)[0]
    assert stage.overloaded(StageFaults(load=0.6), np.array([40001.0]), 320000.0)[0]
    # Above 1 the motor cannot move the load at any speed.
    assert stage.overloaded(StageFaults(load=1.01), np.array([1.0]), 0.0)[0]


def test_missed_steps_under_overload_and_the_lag_after() -> None:
    stage = StepperStage(RAIL, faults=StageFaults(load=0.6), position_m=0.3)
    p0 = 0.3 / D
    # 1 s at 64000 microsteps/s (overloaded), then 1 s at 30000 (the motor follows again).
    stage.set_profile(
        1.0,
        [
            Segment(1.0, p0, 64000.0),
            Segment(2.0, p0 + 64000.0, 30000.0),
            Segment(3.0, p0 + 94000.0),
        ],
    )
    x = stage.position_m(np.array([1.0, 2.0, 3.0, 4.0]))
    missed = stage.missed_microsteps(np.array([1.5, 2.0, 4.0]))
    np.testing.assert_allclose(missed, [32000.0, 64000.0, 64000.0], rtol=1e-9)
    assert x[1] == pytest.approx(0.3, abs=1e-12)  # the carriage stood still
    assert x[3] - x[0] == pytest.approx(30000.0 * D, rel=1e-9)
    commanded, _ = stage.commanded_at(4.0)
    assert commanded * D - x[3] == pytest.approx(64000.0 * D, rel=1e-9)  # the lag


@given(x=st.floats(0.0, 1.2), ref=st.floats(-0.01, 0.01))
def test_encoder_is_the_floor_of_position_times_resolution(x: float, ref: float) -> None:
    stage = StepperStage(RAIL, position_m=x)
    counts = stage.encoder_counts(np.array([0.0, 1.0]), reference_m=ref, counts_at_reference=7)
    expected = math.floor((x - ref) * 1e6 + 1e-6) + 7
    assert counts.tolist() == [expected, expected]


def test_encoder_quantises_a_slow_move_in_whole_counts() -> None:
    stage = StepperStage(RAIL, position_m=0.5)
    jog(stage, 0.0, 64.0)  # 100 um/s: one count (1 um) per 10 ms
    times = np.arange(0.0, 1.0, 1e-4)
    counts = stage.encoder_counts(times)
    x = stage.position_m(times)
    np.testing.assert_array_equal(counts, np.floor(x * 1e6 + 1e-6).astype(np.int64))
    assert set(np.diff(counts).tolist()) == {0, 1}
    assert counts[-1] - counts[0] == 99


# -- history --------------------------------------------------------------------------------------


def test_history_in_the_past_survives_later_commands() -> None:
    stage = StepperStage(RAIL, faults=StageFaults(ripple=0.02, jitter=0.01), seed=2)
    jog(stage, 1.0, RATE)
    past = np.linspace(1.0, 6.0, 1001)
    before = stage.position_m(past)
    jog(stage, 6.0, -RATE)  # a later command, after the camera rendered up to 6 s
    stage.set_faults(6.5, StageFaults(error=0.05))
    stage.position_m(np.array([9.0]))
    np.testing.assert_array_equal(stage.position_m(past), before)


def test_a_command_earlier_than_the_integrated_time_rewrites_only_the_future() -> None:
    stage = StepperStage(RAIL)
    jog(stage, 1.0, RATE)
    stage.position_m(np.array([5.0]))  # integrated ahead to 5 s
    jog(stage, 3.0, 0.0)  # the command arrives for 3 s
    x = stage.position_m(np.array([2.0, 3.0, 5.0]))
    assert x[1] - x[0] == pytest.approx(RATE * D, rel=1e-9)
    assert x[2] == x[1]


def test_old_history_is_pruned_with_a_clear_error() -> None:
    stage = StepperStage(RAIL, history_s=1.0)
    jog(stage, 0.0, RATE)
    stage.position_m(np.array([3.0]))
    with pytest.raises(ValueError, match="older than the kept history"):
        stage.position_m(np.array([0.5]))
    assert stage.kept_from_s > 0.5


def test_idle_hours_cost_nothing() -> None:
    stage = StepperStage(RAIL, faults=StageFaults(jitter=0.05))
    jog(stage, 1.0, RATE)
    jog(stage, 2.0, 0.0)
    x = stage.position_m(np.array([2.0, 3600.0 * 5]))
    assert x[1] == x[0]
    assert x[0] == pytest.approx(0.6 + RATE * D, rel=0.01)


@pytest.mark.parametrize("seed", [0, 1])
def test_deterministic_for_a_seed(seed: int) -> None:
    def run(s: int) -> np.ndarray:
        stage = StepperStage(RAIL, seed=s, faults=StageFaults(ripple=0.02, jitter=0.02))
        jog(stage, 0.5, RATE)
        stage.set_faults(1.5, StageFaults(jitter=0.05, load=0.9))
        return stage.position_m(np.linspace(0.0, 3.0, 3001))

    a, b = run(seed), run(seed)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, run(seed + 10))


def test_fault_values_are_checked() -> None:
    with pytest.raises(ValueError, match=r"ripple = 0\.3 is out of range.*from 0 to 0\.2"):
        StageFaults(ripple=0.3)
    assert StageFaults.from_profile(RAIL) == StageFaults()


def test_profile_keys_are_documented() -> None:
    text = (ROOT / "docs" / "motion.md").read_text(encoding="utf-8")
    for key in StageProfile.model_fields:
        if key != "sim":
            assert f"`{key}`" in text, key
    for key in type(RAIL.sim).model_fields:
        assert f"`{key}`" in text, key
