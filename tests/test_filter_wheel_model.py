"""The wheel file (camd.motion.wheel_profile) and the simulated wheel (firmware_models.wheel).

docs/physics.md §4 [YE23]: 13 channels, w = 73.245 deg/s, entry pulse T_center = 60 ms before each
channel centre, a 120 ms light window, three polarising channels 60 deg apart. The polarisation
experiment of YE23 §4 is run through the model: a reference polariser at 0 .. 360 deg in 15 deg
steps, a frame per step through each polarising channel, the azimuth from the least-squares
sinusoid (camd.analysis.polarization). Frames are HR400 rolling-shutter frames: k = 534 rows,
T_line = 20.52 us, and since each line period reads and then resets, row r (reset in line r)
exposes from the end of line r for n lines: [t0 + (r + 1) T_line, t0 + (r + 1 + n) T_line].
The exposure of the whole frame is then centred on t0 + (n + k + 1) T_line / 2 = t0 + T_frame / 2
(eq 6). Expected numbers are worked out by hand in the comments.
"""

from __future__ import annotations

import math
import re
import tomllib
from pathlib import Path

import numpy as np
import pytest

from camd.analysis.polarization import azimuth_spread_deg, fit_polarization
from camd.motion.wheel_profile import (
    WheelProfile,
    WheelProfileError,
    default_wheel_path,
    load_wheel_profile,
)
from camd.timing import sequencer_frame_time_s, sequencer_line_period_s
from firmware_models.wheel import FilterWheel

ROOT = Path(__file__).resolve().parents[1]
W = 73.245
T_CENTER = 0.060
WINDOW = 0.120
T_LINE = 20.52e-6  # 513 clocks / 25 MHz
K = 534
SPACING = 360.0 / 13  # 27.692307... deg
REFERENCE_DEG = np.arange(0.0, 360.0 + 1e-9, 15.0)
# Exposure lines for ~1, 3, 15, 60 ms: n = round(T_exp / 20.52 us).
EXPOSURE_LINES = {1: 49, 3: 146, 15: 731, 60: 2924}
# w (T_frame / 2 - T_center) for those, T_frame = (n + 535) x 20.52 us (test_wheel_timing.py):
DRIFT_DEG = {1: -3.9558276792, 3: -3.8829327903, 15: -3.4433089758, 60: -1.7952832917}


@pytest.fixture(scope="module")
def profile() -> WheelProfile:
    return load_wheel_profile()


def axial_difference(a: float, b: float) -> float:
    return (a - b + 90.0) % 180.0 - 90.0


def frame_rows(t0_s: float, n: int) -> tuple[np.ndarray, np.ndarray]:
    start = t0_s + (np.arange(K) + 1) * T_LINE
    return start, start + n * T_LINE


def frame_azimuth(wheel: FilterWheel, channel: int, t0_s: float, n: int) -> float:
    """The azimuth the reference-polariser scan measures on one frame's mean signal."""
    start, end = frame_rows(t0_s, n)
    signal = [wheel.row_transmission(channel, start, end, ref).mean() for ref in REFERENCE_DEG]
    fit = fit_polarization(REFERENCE_DEG, signal)
    assert fit.residual_rms < 1e-12  # the frame mean is an exact sinusoid
    return fit.azimuth_deg


# -- the wheel file ----------------------------------------------------------------------------------


def test_the_shipped_wheel(profile: WheelProfile) -> None:
    assert profile.wheel == "ye23"
    assert profile.channel_count.value == 13 and len(profile.channels) == 13
    assert profile.speed_deg_s.value == W
    assert profile.t_center_s.value == T_CENTER
    assert profile.window_s.value == WINDOW
    assert profile.entry_angle_error_deg.value == 0.087
    assert profile.speed_error_deg_s.value == 0.03
    assert profile.clock_stability.value == 20e-6
    assert profile.t_center_error_s == pytest.approx(1.2e-6, rel=1e-12)
    assert profile.spacing_deg == pytest.approx(SPACING, rel=1e-15)
    assert profile.centre_deg(0) == 0.0
    assert profile.centre_deg(12) == pytest.approx(12 * SPACING, rel=1e-15)
    # 73.245 deg/s x 60 ms = 4.3947 deg, both the entry lead and the window's half-width
    assert profile.entry_lead_deg == pytest.approx(4.3947, rel=1e-12)
    assert profile.window_half_angle_deg == pytest.approx(4.3947, rel=1e-12)
    assert profile.polarizing_channels == (10, 11, 12)
    axes = [profile.channels[c].polarizer_deg for c in profile.polarizing_channels]
    assert [a.value for a in axes if a is not None] == [0.0, 60.0, 120.0]
    assert all(a is not None and a.is_assumed for a in axes)  # which channels: an assumption
    for key in ("speed_deg_s", "t_center_s", "window_s", "entry_angle_error_deg"):
        assert "YE23" in getattr(profile, key).provenance
    assert profile.centres.is_assumed
    assert load_wheel_profile(default_wheel_path()) == profile


def test_every_physical_value_has_source_xor_assumed() -> None:
    raw = tomllib.loads((ROOT / "config" / "wheel.toml").read_text(encoding="utf-8"))
    entries = [v for v in raw.values() if isinstance(v, dict)]
    entries += [v for c in raw["channels"] for v in c.values() if isinstance(v, dict)]
    assert len(entries) == 8 + 13 + 3
    for entry in entries:
        assert set(entry) in ({"value", "source"}, {"value", "assumed"}), entry


def write_variant(tmp_path: Path, old: str, new: str, count: int = 1) -> Path:
    text = (ROOT / "config" / "wheel.toml").read_text(encoding="utf-8")
    assert old in text
    path = tmp_path / "wheel.toml"
    path.write_text(text.replace(old, new, count), encoding="utf-8")
    return path


def line_of(path: Path, needle: str, occurrence: int = 1) -> int:
    lines = path.read_text(encoding="utf-8").splitlines()
    hits = [i + 1 for i, line in enumerate(lines) if needle in line]
    return hits[occurrence - 1]


def test_bad_wheel_files_name_the_line_and_the_fix(tmp_path: Path) -> None:
    path = write_variant(tmp_path, "speed_deg_s = { value = 73.245,", "speed_deg_s = { value = -1,")
    with pytest.raises(WheelProfileError) as info:
        load_wheel_profile(path)
    assert str(info.value).startswith(f"{path}:{line_of(path, 'speed_deg_s =')}: speed_deg_s.value")
    assert "-1 is out of range; allowed: 0 < value" in str(info.value)

    path = write_variant(
        tmp_path,
        'window_s = { value = 0.120, source = "',
        'window_s = { value = 0.120, assumed = "x", source = "',
    )
    with pytest.raises(
        WheelProfileError, match=r"window_s: give exactly one of `source`.*not both"
    ):
        load_wheel_profile(path)

    path = write_variant(tmp_path, 'wheel = "ye23"', 'wheel = "ye23"\ncolour = "red"')
    with pytest.raises(WheelProfileError, match=r":13: colour: unknown key; known keys: wheel,"):
        load_wheel_profile(path)

    path = write_variant(tmp_path, 'name = "B03"', 'name = "B03"\nfilter = "x"')
    expected = line_of(path, 'filter = "x"')
    with pytest.raises(
        WheelProfileError, match=rf":{expected}: channels.2.filter: .*known keys: name, band"
    ):
        load_wheel_profile(path)

    path = write_variant(
        tmp_path, "polarizer_deg = { value = 120.0,", "polarizer_deg = { value = 180.0,"
    )
    expected = line_of(path, "polarizer_deg = { value = 180.0")
    with pytest.raises(
        WheelProfileError,
        match=rf":{expected}: channels.12.polarizer_deg.value: 180.0 is out of range; "
        r"allowed: 0 <= value < 180",
    ):
        load_wheel_profile(path)

    path = write_variant(tmp_path, "channel_count = { value = 13,", "channel_count = { value = 12,")
    with pytest.raises(
        WheelProfileError, match=r"channel_count is 12 but 13 \[\[channels\]\] tables"
    ):
        load_wheel_profile(path)

    # 0.4 s x 73.245 deg/s = 29.3 deg > 27.69 deg spacing
    path = write_variant(tmp_path, "window_s = { value = 0.120,", "window_s = { value = 0.4,")
    with pytest.raises(WheelProfileError) as info:
        load_wheel_profile(path)
    assert f":{line_of(path, 'window_s = { value')}: window_s:" in str(info.value)
    assert "29.298 deg is not narrower than the channel spacing 360 / 13 = 27.6923 deg" in str(
        info.value
    )

    path = write_variant(tmp_path, 'name = "B02"', 'name = "B01"')
    with pytest.raises(WheelProfileError, match="unique; repeated: B01"):
        load_wheel_profile(path)

    path = write_variant(tmp_path, 'name = "B02"\n', "")
    with pytest.raises(
        WheelProfileError, match=r"channels.1.name: missing key; add `name = \.\.\.`"
    ):
        load_wheel_profile(path)

    with pytest.raises(FileNotFoundError, match="no wheel file"):
        load_wheel_profile(tmp_path / "missing.toml")


def test_channel_index_is_checked(profile: WheelProfile) -> None:
    with pytest.raises(
        ValueError,
        match=re.escape("channel 13 does not exist: the ye23 wheel has channels 0 .. 12"),
    ):
        profile.centre_deg(13)
    with pytest.raises(ValueError, match="channel must be an integer"):
        profile.centre_deg(True)


# -- angle and speed ---------------------------------------------------------------------------------


def test_angle_is_continuous_across_speed_changes(profile: WheelProfile) -> None:
    wheel = FilterWheel(profile)
    assert wheel.angle_deg(1.0) == pytest.approx(73.245, abs=1e-12)
    wheel.set_speed(10.0, 2.0)  # at t = 2 s the angle is 146.49 deg
    wheel.set_speed(0.0, 3.0)  # 156.49 deg, then stopped
    wheel.set_speed(100.0, 5.0)  # still 156.49 at 5 s
    for t, expected in [(2.0, 146.49), (2.5, 151.49), (3.0, 156.49), (4.0, 156.49), (5.5, 206.49)]:
        assert wheel.angle_deg(t) == pytest.approx(expected, abs=1e-9)
    for change in (2.0, 3.0, 5.0):
        before, after = wheel.angle_deg(np.array([change - 1e-9, change + 1e-9]))
        assert abs(after - before) < 1e-6
    assert wheel.speed_deg_s(4.0) == 0.0 and wheel.speed_deg_s(6.0) == 100.0
    # 5.5 s: 206.49; 8 s: 156.49 + 300 = 456.49 -> 96.49 (reported 0 .. 360)
    angles = wheel.angle_deg(np.array([5.5, 8.0]))
    np.testing.assert_allclose(angles, [206.49, 96.49], atol=1e-9)


def test_bad_speed_changes_are_refused(profile: WheelProfile) -> None:
    wheel = FilterWheel(profile)
    wheel.set_speed(20.0, 1.0)
    with pytest.raises(
        ValueError, match=r"set_speed at t = 0.5 s is before the last speed change at 1 s"
    ):
        wheel.set_speed(30.0, 0.5)
    with pytest.raises(ValueError, match="speed_deg_s must be >= 0"):
        wheel.set_speed(-1.0, 2.0)
    with pytest.raises(ValueError, match="speed_deg_s must be a finite number"):
        wheel.set_speed(math.nan, 2.0)
    wheel.set_speed(40.0, 1.0)  # same time: the last change is replaced
    assert wheel.angle_deg(2.0) == pytest.approx(73.245 + 40.0, abs=1e-12)


# -- entry pulses and light windows ------------------------------------------------------------------


@pytest.mark.parametrize("channel", range(13))
def test_entry_pulse_comes_60_ms_before_the_centre(profile: WheelProfile, channel: int) -> None:
    wheel = FilterWheel(profile)
    entry = wheel.next_entry_s(channel, 0.1)
    centre = wheel.next_centre_s(channel, entry)
    assert centre - entry == pytest.approx(T_CENTER, abs=1e-12)
    # the centre of channel c passes at c x 27.6923 / 73.245 s (+ a revolution for channel 0)
    revolution = 360.0 / W  # 4.91501 s
    expected = channel * SPACING / W if channel else revolution
    assert centre == pytest.approx(expected, abs=1e-12)
    assert wheel.angle_deg(centre) == pytest.approx(profile.centre_deg(channel), abs=1e-9)
    assert wheel.next_entry_s(channel, entry + 1e-6) == pytest.approx(entry + revolution, abs=1e-9)
    assert wheel.next_entry_s(channel, entry) == pytest.approx(entry, abs=1e-12)  # at or after


def test_light_windows_last_120_ms_around_each_centre(profile: WheelProfile) -> None:
    wheel = FilterWheel(profile)
    for channel in range(13):
        centre = wheel.next_centre_s(channel, 1.0)
        assert wheel.channel_at(centre) == channel
        assert wheel.channel_at(centre - 0.0599) == channel
        assert wheel.channel_at(centre + 0.0599) == channel
        assert wheel.channel_at(centre - 0.0601) is None
        assert wheel.channel_at(centre + 0.0601) is None
    # between windows: half-way between channel 3 and 4
    assert wheel.channel_at(3.5 * SPACING / W) is None


def test_a_stopped_wheel_sends_no_pulse(profile: WheelProfile) -> None:
    wheel = FilterWheel(profile, speed_deg_s=0.0, angle_deg=2.0)
    assert wheel.channel_at(10.0) == 0  # parked inside channel 0's window
    with pytest.raises(
        ValueError,
        match=r"the wheel is stopped \(speed 0 since t = 0 s\): channel 5's entry pulse never comes",
    ):
        wheel.next_entry_s(5, 1.0)
    # from 2 deg at 3 s at 10 deg/s: channel 1's entry is at 27.6923 - 4.3947 = 23.2976 deg
    wheel.set_speed(10.0, 3.0)
    assert wheel.next_entry_s(1, 0.0) == pytest.approx(3.0 + (23.2976077 - 2.0) / 10.0, abs=1e-6)
    moving = FilterWheel(profile)
    # stops at 73.245 deg at 1 s: channel 2's entry (50.99 deg) passed at 0.696 s
    moving.set_speed(0.0, 1.0)
    with pytest.raises(ValueError, match="stopped"):
        moving.next_entry_s(2, 0.9)
    assert moving.next_entry_s(2, 0.0) == pytest.approx((2 * SPACING - 4.3947) / W, abs=1e-12)


def test_polarizer_turns_with_the_wheel(profile: WheelProfile) -> None:
    wheel = FilterWheel(profile)
    centre = wheel.next_centre_s(11, 0.0)
    assert wheel.polarizer_azimuth_deg(11, centre) == pytest.approx(60.0, abs=1e-9)
    # 10 ms later the wheel has turned 0.73245 deg
    assert wheel.polarizer_azimuth_deg(11, centre + 0.01) == pytest.approx(60.73245, abs=1e-9)
    np.testing.assert_allclose(
        wheel.polarizer_azimuth_deg(12, wheel.next_centre_s(12, 0.0) + np.array([-0.06, 0.06])),
        [120.0 - 4.3947, 120.0 + 4.3947],
        atol=1e-9,
    )
    with pytest.raises(
        ValueError, match=r"channel 4 \(B05\) has no polariser; polarising channels: 10, 11, 12"
    ):
        wheel.polarizer_azimuth_deg(4, 0.0)


# -- transmission ------------------------------------------------------------------------------------


def brute_force(
    wheel: FilterWheel,
    channel: int,
    start: float,
    end: float,
    reference: float | None,
    samples: int = 400_000,
) -> float:
    """Midpoint-rule time average of the instantaneous transmission (Malus, window)."""
    profile = wheel.profile
    t = start + (np.arange(samples) + 0.5) * (end - start) / samples
    angle = wheel.angle_deg(t)
    offset = (angle - profile.centre_deg(channel) + 180.0) % 360.0 - 180.0
    in_window = np.abs(offset) <= profile.window_half_angle_deg
    if profile.channels[channel].polarizer_deg is None:
        value = np.ones_like(t)
    elif reference is None:
        value = np.full_like(t, 0.5)
    else:
        value = np.cos(np.deg2rad(reference - wheel.polarizer_azimuth_deg(channel, t))) ** 2
    return float(np.mean(np.where(in_window, value, 0.0)))


@pytest.mark.parametrize("reference", [0.0, 22.5, 45.0, 77.0, 150.0])
@pytest.mark.parametrize(
    ("offset_s", "duration_s"), [(-0.05, 0.1), (-0.035, 0.071), (0.0, 0.002), (0.01, 0.04)]
)
def test_transmission_closed_form_against_brute_force(
    profile: WheelProfile, reference: float, offset_s: float, duration_s: float
) -> None:
    wheel = FilterWheel(profile)
    centre = wheel.next_centre_s(10, 0.0)
    start = centre + offset_s
    closed = float(wheel.row_transmission(10, start, start + duration_s, reference))
    assert closed == pytest.approx(
        brute_force(wheel, 10, start, start + duration_s, reference), abs=1e-9
    )


def test_transmission_across_a_speed_change(profile: WheelProfile) -> None:
    wheel = FilterWheel(profile)
    centre = wheel.next_centre_s(11, 0.0)
    wheel.set_speed(20.0, centre - 0.02)
    start, end = centre - 0.05, centre + 0.1  # all inside: 4.3947 deg at 20 deg/s lasts 0.22 s
    closed = float(wheel.row_transmission(11, start, end, 100.0))
    assert closed == pytest.approx(brute_force(wheel, 11, start, end, 100.0), abs=1e-9)


def test_vignetting_clips_the_exposure_exactly(profile: WheelProfile) -> None:
    wheel = FilterWheel(profile)
    centre = wheel.next_centre_s(12, 0.0)
    opens, closes = centre - 0.06, centre + 0.06
    # 40 ms exposure, the first 10 ms before the window opens: 3/4 of it transmits
    start, end = opens - 0.01, opens + 0.03
    inside = float(wheel.row_transmission(12, opens, end, 33.0))
    assert float(wheel.row_transmission(12, start, end, 33.0)) == pytest.approx(
        0.75 * inside, abs=1e-12
    )
    assert float(wheel.row_transmission(12, start, end, None)) == pytest.approx(
        0.75 * 0.5, abs=1e-12
    )
    assert float(wheel.row_transmission(3, start - 0.5, end - 0.5, 33.0)) == 0.0  # between windows
    # a 200 ms exposure over the whole window: 120 ms of light for a channel without a polariser
    assert float(wheel.row_transmission(0, -0.1, 0.1, None)) == pytest.approx(0.6, abs=1e-12)
    assert float(wheel.row_transmission(0, -0.1, 0.1, 10.0)) == pytest.approx(0.6, abs=1e-12)
    # the brute force agrees to its resolution (1 sample in 400 000 at each edge)
    brute = brute_force(wheel, 12, start, closes + 0.01, 33.0)
    assert float(wheel.row_transmission(12, start, closes + 0.01, 33.0)) == pytest.approx(
        brute, abs=5e-6
    )


def test_instantaneous_rows_and_unpolarised_light(profile: WheelProfile) -> None:
    wheel = FilterWheel(profile)
    centre = wheel.next_centre_s(11, 0.0)
    times = centre + np.array([-0.07, -0.06, 0.0, 0.02])
    got = wheel.row_transmission(11, times, times, 60.0)
    # outside, on the edge (cos^2 4.3947 deg), centre (1), 20 ms later (cos^2 1.4649 deg)
    expected = [0.0, math.cos(math.radians(4.3947)) ** 2, 1.0, math.cos(math.radians(1.4649)) ** 2]
    np.testing.assert_allclose(got, expected, atol=1e-12)
    np.testing.assert_allclose(
        wheel.row_transmission(11, times, times + 0.01, None), [0.0, 0.5, 0.5, 0.5], atol=1e-12
    )
    # Malus at the centre: reference 60 + 90 blocks, 60 + 45 passes half
    assert float(wheel.row_transmission(11, centre, centre, 150.0)) == pytest.approx(0.0, abs=1e-12)
    assert float(wheel.row_transmission(11, centre, centre, 105.0)) == pytest.approx(0.5, abs=1e-12)


def test_transmission_refuses_bad_rows(profile: WheelProfile) -> None:
    wheel = FilterWheel(profile)
    with pytest.raises(ValueError, match=r"row 1 starts at 2 s and ends at 1 s"):
        wheel.row_transmission(10, [0.0, 2.0], [1.0, 1.0], 0.0)
    with pytest.raises(ValueError, match="must be finite"):
        wheel.row_transmission(10, [0.0], [math.inf], 0.0)
    with pytest.raises(ValueError, match="channel 13 does not exist"):
        wheel.row_transmission(13, [0.0], [1.0], 0.0)


# -- the polarisation experiment ---------------------------------------------------------------------


@pytest.mark.parametrize("exposure_ms", [1, 3, 15, 60])
@pytest.mark.parametrize("channel", [10, 11, 12])
def test_compensated_frames_measure_the_polarizer_axis(
    profile: WheelProfile, channel: int, exposure_ms: int
) -> None:
    wheel = FilterWheel(profile)
    n = EXPOSURE_LINES[exposure_ms]
    frame = sequencer_frame_time_s(n, K, sequencer_line_period_s(25e6))
    t0 = wheel.exposure_schedule(channel, 0.0, frame, compensated=True)
    assert t0 + frame / 2 == pytest.approx(wheel.next_centre_s(channel, 0.0), abs=1e-12)
    axis = profile.channels[channel].polarizer_deg
    assert axis is not None
    assert axial_difference(frame_azimuth(wheel, channel, t0, n), axis.value) == pytest.approx(
        0.0, abs=1e-9
    )


@pytest.mark.parametrize("exposure_ms", [1, 3, 15, 60])
@pytest.mark.parametrize("channel", [10, 11, 12])
def test_frames_started_at_the_pulse_measure_a_shifted_axis(
    profile: WheelProfile, channel: int, exposure_ms: int
) -> None:
    wheel = FilterWheel(profile)
    n = EXPOSURE_LINES[exposure_ms]
    frame = sequencer_frame_time_s(n, K, T_LINE)
    t0 = wheel.exposure_schedule(channel, 0.0, frame, compensated=False)
    assert t0 == wheel.next_entry_s(channel, 0.0)
    axis = profile.channels[channel].polarizer_deg
    assert axis is not None
    shift = axial_difference(frame_azimuth(wheel, channel, t0, n), axis.value)
    # measured shift = w (T_frame / 2 - T_center), the hand numbers of the module doc
    assert shift == pytest.approx(DRIFT_DEG[exposure_ms], abs=1e-9)
    assert shift == pytest.approx(W * (frame / 2 - T_CENTER), abs=1e-9)


def test_azimuth_spread_over_3_15_60_ms(profile: WheelProfile) -> None:
    """With compensation the azimuth does not move with the exposure; without, by w dT_frame / 2.

    3 -> 60 ms: T_frame 13.97412 -> 70.97868 ms, so 73.245 x (70.97868 - 13.97412) / 2 ms
    = 73.245 x 28.50228 ms = 2.0876495 deg.
    """
    for channel in profile.polarizing_channels:
        spreads = {}
        for compensated in (True, False):
            azimuths = []
            for exposure_ms in (3, 15, 60):
                wheel = FilterWheel(profile)
                n = EXPOSURE_LINES[exposure_ms]
                frame = sequencer_frame_time_s(n, K, T_LINE)
                t0 = wheel.exposure_schedule(channel, 0.0, frame, compensated)
                azimuths.append(frame_azimuth(wheel, channel, t0, n))
            spreads[compensated] = azimuth_spread_deg(azimuths)
        assert spreads[True] == pytest.approx(0.0, abs=1e-9)
        assert spreads[False] == pytest.approx(2.0876495, abs=1e-7)


def test_off_nominal_speed_shows_the_t_center_dw_term(profile: WheelProfile) -> None:
    """At 80 deg/s the pulse still marks the entry angle, so the FPGA's 60 ms lands late.

    The centre is reached (4.3947 deg / 80 deg/s) = 54.934 ms after the pulse; the frame is
    centred 60 ms after it, (80 - 73.245) x 60 ms = 0.4053 deg past the channel centre: the
    T_center dw term of eq 8 (dw = 6.755 deg/s here, 0.03 deg/s on the instrument).
    """
    wheel = FilterWheel(profile, speed_deg_s=80.0)
    entry = wheel.next_entry_s(11, 0.0)
    assert wheel.next_centre_s(11, entry) - entry == pytest.approx(4.3947 / 80.0, abs=1e-12)
    n = EXPOSURE_LINES[15]
    frame = sequencer_frame_time_s(n, K, T_LINE)
    t0 = wheel.exposure_schedule(11, 0.0, frame, compensated=True)
    shift = axial_difference(frame_azimuth(wheel, 11, t0, n), 60.0)
    assert shift == pytest.approx((80.0 - W) * T_CENTER, abs=1e-9)


def test_exposures_that_do_not_fit_are_refused(profile: WheelProfile) -> None:
    wheel = FilterWheel(profile)
    too_long = sequencer_frame_time_s(5313, K, T_LINE)  # 120.00096 ms
    for compensated in (True, False):
        with pytest.raises(
            ValueError,
            match=re.escape(
                "T_frame = (n + k + 1) T_line = 120.001 ms exceeds the channel's light window of 120 ms"
            ),
        ):
            wheel.exposure_schedule(10, 0.0, too_long, compensated)
    fits = sequencer_frame_time_s(5312, K, T_LINE)  # 119.98044 ms: 9.78 us of delay
    t0 = wheel.exposure_schedule(10, 0.0, fits, compensated=True)
    assert t0 - wheel.next_entry_s(10, 0.0) == pytest.approx(9.78e-6, abs=1e-12)
    start, end = frame_rows(t0, 5312)
    assert wheel.row_transmission(10, start, end, None) == pytest.approx(np.full(K, 0.5), abs=1e-12)
