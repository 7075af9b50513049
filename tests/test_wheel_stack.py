"""The filter wheel over the full stack (docs/physics.md §4, docs/wheel.md), as a user drives it.

CamdClient over real HTTP, or camctl (in process; one test as a command) -> camd serve -> WHEEL_*
commands over the pty -> the simulated FPGA's wheel -> frames over the simulated FX3 -> FrameStream
-> the wheel service. Every expected number is worked out here from docs/physics.md §4 and the
instrument values (config/wheel.toml), not taken from camd.timing:

    T_line = 513 / 25 MHz = 20.52 us, T_frame = (n + k + 1) T_line             eq 6
    T_delay = T_center - T_frame / 2, T_center = 60 ms                          eq 5
    centre - channel centre = w (T_delay + T_frame / 2) - w T_center            eqs 1, 4
    dP = sqrt(dP_entry^2 + (T dw)^2 + (w 20e-6 T)^2), T pulse to frame centre    eq 8

with w = 73.245 deg/s, dP_entry = 0.087 deg, dw = 0.03 deg/s. A 16-row window keeps the frames
small; T_frame depends on it (k = 16), the azimuth spread does not.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from pathlib import Path

import pytest

from camd.client import CamdClient, CamdError
from camd.store.recording_reading import read_recording
from tests.test_camctl import camctl, camctl_command, camctl_json
from tests.test_sensor_stack import serve

# Not ``exclusive``: every angle and time checked is the simulated FPGA's own (the headers'
# angles, the device's delay), not the host's clock, and each acquisition is a few frames.
# Checked beside `stress-ng --cpu 2`.

T_LINE_S = 513 / 25e6  # hr400: 513 sequencer clocks at 25 MHz
ROWS = 16  # k
W_DEG_S = 73.245
T_CENTER_S = 0.060
WINDOW_S = 0.120
ENTRY_ERROR_DEG = 0.087
SPEED_ERROR_DEG_S = 0.03
CLOCK_STABILITY = 20e-6
SPACING_DEG = 360 / 13
POLARIZER_DEG = {10: 0.0, 11: 60.0, 12: 120.0}
# round(T_exp / T_line) for 1, 3, 15 and 60 ms (docs/wheel.md's table).
LINES = {0.001: 49, 0.003: 146, 0.015: 731, 0.060: 2924}
HEADER_ANGLE_STEP_DEG = 1e-4  # the header's stage_position unit for wheel frames
SCENE = "flat:photons=1.2e6"  # a 60 ms frame about half full: the fit is precise, none saturate


def frame_time_s(lines: int) -> float:
    return (lines + ROWS + 1) * T_LINE_S


def eq8_deg(pulse_to_centre_s: float) -> float:
    return math.sqrt(
        ENTRY_ERROR_DEG**2
        + (pulse_to_centre_s * SPEED_ERROR_DEG_S) ** 2
        + (W_DEG_S * CLOCK_STABILITY * pulse_to_centre_s) ** 2
    )


def wrap180(angle_deg: float) -> float:
    return (angle_deg + 180.0) % 360.0 - 180.0


@pytest.fixture(scope="module")
def url(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    with serve(tmp_path_factory.mktemp("camd-wheel"), "fpga") as daemon:
        camctl_json(daemon.url, "reg", "write", f"WIN_ROWS={ROWS}")
        camctl_json(daemon.url, "sim", "scene", SCENE)
        yield daemon.url
    assert daemon.exit_code in (0, -15), daemon.log_path.read_text()


@pytest.fixture
def client(url: str) -> Iterator[CamdClient]:
    with CamdClient(url, timeout_s=60) as cam:
        yield cam


def test_status_gives_the_wheel_and_camds_numbers_for_the_registers(client: CamdClient) -> None:
    doc = client.wheel()
    assert (doc["wheel"], doc["speed_deg_s"], doc["nominal_speed_deg_s"]) == (
        "ye23",
        W_DEG_S,
        W_DEG_S,
    )
    assert doc["period_s"] == pytest.approx(360 / W_DEG_S, rel=1e-12)
    assert (doc["t_center_s"], doc["window_s"]) == (T_CENTER_S, WINDOW_S)
    assert [c["channel"] for c in doc["channels"]] == list(range(13))
    assert [c["centre_deg"] for c in doc["channels"]] == pytest.approx(
        [i * SPACING_DEG for i in range(13)], abs=1e-12
    )
    assert {
        c["channel"]: c["polarizer_deg"] for c in doc["channels"] if c["polarizer_deg"] is not None
    } == POLARIZER_DEG
    exposure = doc["exposure"]
    lines = exposure["exposure_lines"]
    frame = frame_time_s(lines)
    assert exposure["window_rows"] == ROWS
    assert exposure["frame_time_s"] == pytest.approx(frame, abs=1e-15)
    assert exposure["delay_s"] == pytest.approx(T_CENTER_S - frame / 2, abs=1e-15)
    assert exposure["fits"] and exposure["refusal"] is None
    # The FPGA computes the same T_frame and T_delay (to its 1 ns fields).
    assert doc["device_frame_time_s"] == pytest.approx(frame, abs=1e-9)
    assert doc["device_delay_s"] == pytest.approx(T_CENTER_S - frame / 2, abs=1e-9)


@pytest.mark.parametrize("exposure_s", sorted(LINES))
def test_imaging_centre_is_the_channel_centre_with_compensation_and_drifts_without(
    client: CamdClient, exposure_s: float
) -> None:
    lines = LINES[exposure_s]
    frame = frame_time_s(lines)
    channels = [0, 4, 8, 10, 12]
    on = client.wheel_acquire(channels, exposure_s=exposure_s, compensated=True)
    off = client.wheel_acquire(channels, exposure_s=exposure_s, compensated=False)
    for doc, compensated in ((on, True), (off, False)):
        e = doc["exposure"]
        assert (e["exposure_lines"], e["window_rows"], e["compensated"]) == (
            lines,
            ROWS,
            compensated,
        )
        assert e["exposure_s"] == pytest.approx(lines * T_LINE_S, abs=1e-15)
        assert e["frame_time_s"] == pytest.approx(frame, abs=1e-15)
        assert e["delay_s"] == pytest.approx(T_CENTER_S - frame / 2, abs=1e-15)
        delay = T_CENTER_S - frame / 2 if compensated else 0.0
        assert e["applied_delay_s"] == pytest.approx(delay, abs=1e-15)
        assert doc["device_delay_s"] == pytest.approx(delay, abs=1e-9)
        # eq 4 (eq 1 without the delay): the centre is w (delay + T_frame / 2) past the entry
        # point, which is w T_center before the channel centre.
        offset = W_DEG_S * (delay + frame / 2) - W_DEG_S * T_CENTER_S
        error = eq8_deg(delay + frame / 2)
        assert e["centre_offset_deg"] == pytest.approx(offset, abs=1e-9)
        assert e["centre_error_deg"] == pytest.approx(error, rel=1e-12)
        assert [f["channel"] for f in doc["frames"]] == channels
        assert doc["stream"]["stats"]["lost"] == 0 and doc["stream"]["frames_sent"] == len(channels)
        for f in doc["frames"]:
            centre = f["channel"] * SPACING_DEG
            entry = centre - W_DEG_S * T_CENTER_S
            # The header's angle at exposure start is the entry angle + w T_delay ...
            assert wrap180(f["start_angle_deg"] - (entry + W_DEG_S * delay)) == pytest.approx(
                0.0, abs=HEADER_ANGLE_STEP_DEG / 2 + 1e-9
            )
            # ... so the frame's centre, half a frame later, is where camd predicts it.
            assert wrap180(f["centre_deg"] - (centre + offset)) == pytest.approx(0.0, abs=1e-9)
            assert wrap180(f["header_centre_deg"] - f["centre_deg"]) == pytest.approx(
                0.0, abs=HEADER_ANGLE_STEP_DEG / 2 + 1e-9
            )
            assert f["centre_error_deg"] == pytest.approx(error, rel=1e-12)
        if compensated:
            # On the channel centre whatever the exposure, well within the eq-8 uncertainty.
            assert e["centre_offset_deg"] == pytest.approx(0.0, abs=1e-9)
            assert error == pytest.approx(0.0870187, abs=1e-7)
    # Without compensation the centre drifts as w T_frame / 2 from the entry point.
    drift = off["exposure"]["centre_offset_deg"] - on["exposure"]["centre_offset_deg"]
    assert drift == pytest.approx(W_DEG_S * (frame / 2 - T_CENTER_S), abs=1e-9)
    assert client.status()["state"] == "idle"


def test_off_nominal_speed_misplaces_a_compensated_frame_by_dw_t_center(
    client: CamdClient,
) -> None:
    # The entry point is a mark on the wheel, w0 T_center before the centre; the FPGA still
    # waits T_center - T_frame / 2 after it, so at 80 deg/s the centre lands (80 - w0) T_center
    # = 0.4053 deg late: the T_center dw term of eq 8 (docs/wheel.md).
    assert client.set_wheel_speed(80.0)["period_s"] == pytest.approx(4.5)
    try:
        doc = client.wheel_acquire([2, 7], exposure_s=0.015, compensated=True)
    finally:
        client.set_wheel_speed(W_DEG_S)
    frame = frame_time_s(LINES[0.015])
    offset = (80.0 - W_DEG_S) * T_CENTER_S
    assert doc["speed_deg_s"] == 80.0
    assert doc["exposure"]["centre_offset_deg"] == pytest.approx(offset, abs=1e-9)
    for f in doc["frames"]:
        centre = f["channel"] * SPACING_DEG
        entry = centre - W_DEG_S * T_CENTER_S
        start = entry + 80.0 * (T_CENTER_S - frame / 2)
        assert wrap180(f["start_angle_deg"] - start) == pytest.approx(0.0, abs=0.5e-4 + 1e-9)
        assert wrap180(f["header_centre_deg"] - (centre + offset)) == pytest.approx(
            0.0, abs=0.5e-4 + 1e-9
        )


def registers(client: CamdClient) -> dict[str, int]:
    return {r["name"]: r["value"] for r in client.registers()["registers"]}


def test_an_exposure_that_does_not_fit_is_refused_with_the_numbers_and_nothing_changes(
    client: CamdClient, url: str
) -> None:
    # The longest frame that fits 120 ms: n + 17 <= 120 ms / 20.52 us = 5847.95, n = 5830.
    longest = 5830 * T_LINE_S
    doc = client.wheel_acquire([11], exposure_s=longest, compensated=True)
    assert doc["exposure"]["exposure_lines"] == 5830 and doc["exposure"]["fits"]
    assert doc["exposure"]["delay_s"] == pytest.approx(T_CENTER_S - frame_time_s(5830) / 2)
    before, wheel_before = registers(client), client.wheel()
    for compensated in (True, False):
        with pytest.raises(CamdError) as info:
            client.wheel_acquire([11], exposure_s=5831 * T_LINE_S, compensated=compensated)
        assert info.value.http_status == 400 and info.value.code == "bad_request"
        message = info.value.message
        # T_frame = 5848 x 20.52 us = 120.00096 ms, 0.00096 ms over the window.
        assert "nothing changed" in message and "5831 lines" in message
        assert "T_frame = (n + k + 1) T_line = 120.001 ms" in message
        assert "light window of 120 ms" in message and "0.00096 ms" in message
    with pytest.raises(CamdError) as info:
        client.wheel_acquire([0, 4], exposure_s=0.2)
    assert "200.357 ms" in info.value.message  # (9747 + 17) x 20.52 us
    assert registers(client) == before
    after = client.wheel()
    assert after["compensation"] == wheel_before["compensation"]
    assert after["exposure"] == wheel_before["exposure"]
    assert client.status()["state"] == "idle"
    # camctl says the same on stderr, exit status 1.
    proc = camctl_command(url, "wheel", "acquire", "--channels", "11", "--exposure-ms", "120")
    assert proc.returncode == 1 and "light window of 120 ms" in proc.stderr
    assert registers(client) == before


def test_compensation_refused_when_the_registers_exposure_cannot_be_centred(
    client: CamdClient,
) -> None:
    client.set_wheel_compensation(False)
    client.write_registers({"EXPOSURE": 5831})  # written directly: no wheel check there
    try:
        doc = client.wheel()
        assert not doc["exposure"]["fits"]
        assert "120.001 ms" in str(doc["exposure"]["refusal"])
        assert doc["exposure"]["delay_s"] == pytest.approx(T_CENTER_S - frame_time_s(5831) / 2)
        assert doc["exposure"]["delay_s"] < 0  # the window is 2 T_center: both checks fail
        with pytest.raises(CamdError) as info:
            client.set_wheel_compensation(True)
        assert info.value.http_status == 400
        assert "not switched on" in info.value.message and "5831 lines" in info.value.message
        assert "120.001 ms" in info.value.message
        assert client.wheel()["compensation"] is False
    finally:
        client.write_registers({"EXPOSURE": LINES[0.003]})
    assert client.set_wheel_compensation(True)["compensation"] is True
    assert client.set_wheel_compensation(False)["compensation"] is False


def test_bad_requests_are_refused_before_anything_is_written(client: CamdClient) -> None:
    before = registers(client)
    cases = [
        ({"channels": [13]}, "channel 13 does not exist"),
        ({"channels": [2, -1]}, "channel -1 does not exist"),
        ({"channels": [1], "exposure_s": 0.005, "region": {"row": 10, "rows": 10, "cols": 4}},
         "does not fit the 16 x 2048 frame"),
        ({"channels": [1], "exposure_s": 0.005, "record": "/etc/camd-test-never.h5"},
         "is outside the directories the daemon may write"),
    ]  # fmt: skip
    for body, words in cases:
        with pytest.raises(CamdError) as info:
            client.wheel_acquire(**body)  # type: ignore[arg-type]
        assert info.value.http_status == 400 and words in info.value.message, info.value.message
    with pytest.raises(CamdError) as info:
        client.wheel_acquire([])
    assert info.value.http_status == 400 and "channels" in info.value.message
    client.set_wheel_speed(0.0)
    try:
        stopped = client.wheel()
        assert stopped["speed_deg_s"] == 0.0 and stopped["period_s"] is None
        with pytest.raises(CamdError) as info:
            client.wheel_acquire([1], exposure_s=0.005)
        assert info.value.http_status == 400 and "stopped" in info.value.message
        assert "camctl wheel speed 73.245" in info.value.message
    finally:
        client.set_wheel_speed(W_DEG_S)
    assert registers(client) == before
    with pytest.raises(CamdError) as info:
        client.set_wheel_speed(400.0)
    assert info.value.http_status == 400 and "use a number in 0..360" in info.value.message


def test_a_wheel_acquisition_streams_like_a_counted_stream(
    client: CamdClient, tmp_path: Path
) -> None:
    out = tmp_path / "wheel.h5"
    doc = client.wheel_acquire(
        [12, 10, 11], passes=2, exposure_s=0.003, compensated=True, record=str(out),
        region={"row": 4, "rows": 8, "col": 512, "cols": 1024},
    )  # fmt: skip
    assert doc["stream"]["recording"] == str(out) and doc["stream"]["frames_requested"] == 6
    assert [f["channel"] for f in doc["frames"]] == [12, 10, 11, 12, 10, 11]
    recording = read_recording(out)
    assert recording.frames.shape == (6, ROWS, 2048)
    assert list(recording.columns["frame_counter"]) == [f["counter"] for f in doc["frames"]]
    angles = [round(f["start_angle_deg"] / HEADER_ANGLE_STEP_DEG) for f in doc["frames"]]
    assert list(recording.columns["stage_position"]) == angles
    stream = recording.metadata["stream"]
    assert stream["start_command"] == "WHEEL_ACQUIRE" and stream["channels"] == [12, 10, 11]
    assert stream["compensation"] == "on" and stream["passes"] == 2
    means = [float(recording.frames[i, 4:12, 512:1536].mean()) for i in range(6)]
    assert [f["mean"] for f in doc["frames"]] == pytest.approx(means, rel=1e-12)
    # The state machine went to streaming for it and back, as for START_STREAM.
    messages = [e["message"] for e in client.events(limit=50)["events"]]
    started = [m for m in messages if "idle -> streaming: WHEEL_ACQUIRE, 6 frames" in m]
    assert started and any("streaming -> idle" in m for m in messages)
    assert client.status()["state"] == "idle"


def test_wheel_settings_are_refused_while_streaming(client: CamdClient) -> None:
    client.start_stream(0)
    try:
        assert client.wheel()["speed_deg_s"] == W_DEG_S  # reading is harmless
        for call in (
            lambda: client.set_wheel_speed(10.0),
            lambda: client.set_wheel_compensation(True),
            lambda: client.wheel_acquire([1]),
        ):
            with pytest.raises(CamdError) as info:
                call()
            # The busy error names what runs and the command that stops it.
            assert info.value.code == "busy", info.value.message
            assert "a stream is running (until stopped" in info.value.message
            assert "stop it with `camctl stream --stop`" in info.value.message
    finally:
        client.stop_stream()
    assert client.status()["state"] == "idle"


def test_camctl_wheel_commands(url: str) -> None:
    status = camctl_json(url, "wheel")
    assert status["speed_deg_s"] == W_DEG_S and len(status["channels"]) == 13
    assert camctl_json(url, "wheel", "compensation", "on")["compensation"] is True
    doc = camctl_json(
        url, "wheel", "acquire", "--channels", "3,5", "--exposure-ms", "15", "--passes", "2"
    )
    assert [f["channel"] for f in doc["frames"]] == [3, 5, 3, 5]
    assert doc["exposure"]["exposure_lines"] == LINES[0.015] and doc["exposure"]["compensated"]
    assert camctl_json(url, "wheel", "compensation", "off")["compensation"] is False
    text = camctl(url, "wheel", "acquire", "--channels", "10", "--compensation", "off")
    assert text.returncode == 0, text.stderr
    assert "P000" in text.stdout and "+-" in text.stdout and "1 of 1 frames" in text.stdout
    assert camctl_json(url, "wheel", "polarizer", "30") == {"polarizer_deg": 30.0}
    assert camctl_json(url, "wheel", "polarizer", "off") == {"polarizer_deg": None}
    speed = camctl_json(url, "wheel", "speed", str(W_DEG_S))
    assert speed["speed_deg_s"] == W_DEG_S
    bad = camctl(url, "wheel", "acquire", "--channels", "1,x")
    assert bad.returncode == 2 and "comma-separated" in bad.stderr


def test_polarisation_azimuth_is_independent_of_exposure_only_with_compensation(
    url: str, client: CamdClient
) -> None:
    # From a known state: under xdist another test of this module may have run on this
    # worker's daemon and left compensation on (each switches it as it needs).
    client.set_wheel_compensation(False)
    doc = camctl_json(url, "wheel", "azimuth", "--exposures-ms", "3,15,60", "--step-deg", "30")
    assert doc["channels"] == [10, 11, 12] and doc["exposure_ms"] == [3.0, 15.0, 60.0]
    assert doc["reference_deg"] == [30.0 * i for i in range(12)]
    frames = [frame_time_s(LINES[e]) for e in (0.003, 0.015, 0.060)]
    assert doc["frame_time_s"] == pytest.approx(frames, abs=1e-15)
    # Compensated: each channel measures its own polariser's axis at every exposure.
    for channel, axis in POLARIZER_DEG.items():
        for azimuth in doc["azimuth_deg"]["compensated"][str(channel)]:
            assert abs((azimuth - axis + 90) % 180 - 90) < 0.02
        # Without: the axis turned by w (T_frame / 2 - T_center) when the frame was centred.
        shifts = doc["shift_deg"]["uncompensated"][str(channel)]
        expected = [W_DEG_S * (f / 2 - T_CENTER_S) for f in frames]
        assert shifts == pytest.approx(expected, abs=0.02)
    predicted = W_DEG_S * (frames[2] - frames[0]) / 2  # 2.08765 deg: (2924 - 146) lines
    assert predicted == pytest.approx(2.08765, abs=1e-5)
    assert doc["predicted_spread_deg"]["uncompensated"] == pytest.approx(predicted, abs=1e-9)
    assert doc["spread_deg"]["compensated"] < 0.05
    assert doc["spread_deg"]["uncompensated"] == pytest.approx(predicted, abs=0.02)
    # The run leaves the polariser out and compensation as it found it (off).
    assert client.wheel()["compensation"] is False
