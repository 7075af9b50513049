"""The scan stage and scan synchronisation over the full stack, as a user drives them.

camctl (in process; one test as a command) or the client -> HTTP -> camd serve -> MOTOR_* commands
over the pty -> the simulated stepper stage (firmware_models.motor / stage), whose true position
moves the scene -> frames with the encoder latched in their headers -> TDI -> HDF5. The numbers are
checked against docs/physics.md §2 and §6 worked out here.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from pathlib import Path

import h5py
import httpx
import numpy as np
import pytest

from camd.analysis.mtf import periodic_edge_mtf
from camd.cli._daemon_proc import DaemonProcess
from camd.client import CamdClient
from camd.sensor.profile import load_profile
from camd.store.tdi_recording import read_tdi_scan
from tests.nexus_support import nxcheck
from tests.realtime_support import WARM_UP_AS_SHIPPED, as_the_unit
from tests.test_camctl import NO_TOKEN, camctl, camctl_command, camctl_command_json, camctl_json

# The scans whose closed loop is measured (the mismatch, the MTF at the smears the lines had)
# are ``exclusive``: alone under xdist (tests/cpu_share.py), a busy machine's late corrections
# being no loop's fault. The equations, the stage's moves and the refusals are not timed.

T_ROW_S = 513 / 25e6  # hr400 row time: 513 sequencer clocks at 25 MHz (docs/physics.md §3)
ROWS = 100  # the scans' window: T_line,TDI = 100 rows = 2.052 ms
T_LINE_S = ROWS * T_ROW_S
STAGES = 96
PITCH_M = 11e-6
MAGNIFICATION = 0.1  # config/profiles/hr400.toml (1:10 bench objective)
UM_PER_MICROSTEP = 5e-3 / 3200  # config/stages/linear_rail.toml: 5 mm lead, 200 x 16
SYNC_M_S = PITCH_M / (MAGNIFICATION * T_LINE_S)  # docs/physics.md §6 eq 9: 53.606 mm/s
DISTURBANCE = {"error": -0.005, "ripple": 0.01}  # a clock 0.5 % slow and 1 % speed ripple
SCENE = "edge:angle_deg=5"
STEP = "campaign motion: step 1/1 acquire closed_loop"


def start_daemon(tmp: Path, config_text: str = "") -> DaemonProcess:
    config = tmp / "camd.toml"
    config.write_text(config_text)
    # As systemd/camd.service starts it: the closed loop's threads real-time, the rest nice;
    # its first scan's work done at start (tests/realtime_support.py).
    return DaemonProcess(
        tmp,
        extra_args=["--config", str(config)],
        env={**NO_TOKEN, **WARM_UP_AS_SHIPPED},
        wrapper=as_the_unit(),
    )


@pytest.fixture(scope="module")
def daemon(tmp_path_factory: pytest.TempPathFactory) -> Iterator[DaemonProcess]:
    with start_daemon(tmp_path_factory.mktemp("camd-motion")) as d:
        with CamdClient(d.url) as client:
            client.wait_ready(60)
            client.set_scene(SCENE)
        yield d
    assert d.exit_code in (0, -15), d.log_path.read_text()


@pytest.fixture
def client(daemon: DaemonProcess) -> Iterator[CamdClient]:
    with CamdClient(daemon.url, timeout_s=60) as c:
        yield c
        c.set_stage_faults()


def scan(
    client: CamdClient, out: Path, *, lines: int = 400, **options: object
) -> dict[str, object]:
    client.start_scan(STAGES, lines, out=str(out), line_period_s=T_LINE_S, **options)  # type: ignore[arg-type]
    doc = dict(client.wait_scan(timeout_s=300))
    assert doc["state"] == "done", doc["error"]
    assert doc["lost_frames"] == 0
    return doc


def edge_mtf(path: Path) -> tuple[float, float, float]:
    """(MTF at Nyquist, its standard error, 10-90 % edge width) of a scan of the edge scene,
    along track, over complete lines and the first 768 columns (enough edges, quick)."""
    tdi = read_tdi_scan(path)
    result = periodic_edge_mtf(tdi.lines[tdi.complete][:, :768].astype(np.float64))
    error = result.mtf_nyquist_std / math.sqrt(result.regions)
    return result.mtf_nyquist, error, result.edge_width_px


def eq8_at_the_lines(path: Path) -> tuple[float, float]:
    """(eq 8's MTF factor at Nyquist, mean smear in pixels) over the complete lines of a scan,
    at the smear each line really had: its M dV/V (from the encoder in the frame headers) plus
    the rolling shutter's M T_row / T (docs/physics.md §6, docs/motion.md). On a busy machine
    the closed loop's corrections come later and the lines' smears stray further from the one
    asked for; the images follow the smears they had, which is what the MTF checks compare."""
    tdi = read_tdi_scan(path)
    seen = tdi.m_dv_over_v[tdi.complete].astype(np.float64)
    seen = seen[np.isfinite(seen)]
    assert seen.size > 100
    smear = seen + STAGES * T_ROW_S / T_LINE_S
    return float(np.mean(np.sinc(smear / 2))), float(np.mean(smear))


# -- open loop: the equations ---------------------------------------------------------------------


def test_sync_prints_the_contract_keys_with_the_equations_values(daemon: DaemonProcess) -> None:
    doc = camctl_command_json(
        daemon.url, "sync", "--line-period-s", repr(T_LINE_S), "--stages", str(STAGES)
    )
    assert list(doc)[:10] == [
        "line_period_s", "row_time_s", "n_lines", "back_path_s", "m0", "stages", "sync_speed",
        "step_rate_hz", "dv_over_v", "m_dv_over_v",
    ]  # fmt: skip
    assert doc["line_period_s"] == pytest.approx(T_LINE_S, rel=1e-12)
    assert doc["row_time_s"] == pytest.approx(T_ROW_S, rel=1e-12)
    # eqs 8, 9, 13: exactly 100 rows, no back path, M0 = 100.
    assert (doc["n_lines"], doc["back_path_s"], doc["m0"], doc["stages"]) == (100, 0.0, 100, 96)
    # §6 eq 9: V = p / (m T) = 11 um / (0.1 x 2.052 ms) = 53.606 mm/s; F = V / 1.5625 um.
    assert doc["sync_speed"] == pytest.approx(0.053606238, rel=1e-8)
    assert doc["step_rate_hz"] == pytest.approx(0.053606238 / UM_PER_MICROSTEP, rel=1e-8)
    assert doc["dv_over_v"] == 0.0 and doc["m_dv_over_v"] == 0.0

    # A stage 1 % slow against that line period: dV/V = +0.01, M dV/V = 0.96 (§6).
    slow = camctl_command_json(
        daemon.url, "sync", "--line-period-s", repr(T_LINE_S), "--stages", str(STAGES),
        "--with-speed-m-s", repr(0.99 * SYNC_M_S),
    )  # fmt: skip
    assert slow["dv_over_v"] == pytest.approx(0.01, rel=1e-9)
    assert slow["m_dv_over_v"] == pytest.approx(0.96, rel=1e-9)
    assert slow["tolerance_ok"] is True

    # From a stage speed instead: T = p / (m V) (§2 eq 5 general form).
    by_speed = camctl_command_json(daemon.url, "sync", "--speed-m-s", "0.05")
    assert by_speed["line_period_s"] == pytest.approx(PITCH_M / (MAGNIFICATION * 0.05))
    assert by_speed["n_lines"] == math.floor(by_speed["line_period_s"] / T_ROW_S)

    too_many = camctl_command(
        daemon.url, "sync", "--line-period-s", repr(T_LINE_S), "--stages", "101"
    )
    assert too_many.returncode == 1
    assert "use at most 100 stages or a longer line period" in too_many.stderr


def test_stage_moves_homes_stops_and_refuses_with_reasons(
    daemon: DaemonProcess, client: CamdClient
) -> None:
    url = daemon.url
    doc = camctl_json(url, "stage", "enable")
    assert doc["reading"]["state"] == "idle"
    assert doc["limits"] == {"low_m": 0.0, "high_m": 1.2, "max_speed_m_s": 0.1, "accel_m_s2": 0.5}
    moved = camctl_json(url, "stage", "move", "0.01")
    assert moved["reading"]["state"] == "idle"
    assert moved["reading"]["position_m"] == pytest.approx(0.01, abs=UM_PER_MICROSTEP)
    assert moved["reading"]["encoder_m"] == pytest.approx(0.01, abs=2e-6)  # 1 um encoder
    homed = camctl_json(url, "stage", "home")
    assert homed["reading"]["homed"] is True
    assert homed["reading"]["position_m"] == 0.0 and homed["reading"]["encoder_m"] == 0.0

    fast = camctl(url, "stage", "run", "0.3")
    assert fast.returncode == 1
    assert "300 mm/s is above the limit 100 mm/s" in fast.stderr
    outside = camctl(url, "stage", "move", "1.5")
    assert outside.returncode == 1
    assert "outside the soft limits [0.0, 1.2] m" in outside.stderr

    camctl_json(url, "stage", "run", "0.02")
    stopped = camctl_json(url, "stage", "estop")
    assert stopped["reading"]["state"] == "estop"
    refused = camctl(url, "stage", "run", "0.02")
    assert refused.returncode == 1
    assert "emergency stop; check it, then `camctl stage enable` clears it" in refused.stderr
    assert camctl_json(url, "stage", "enable")["reading"]["state"] == "idle"
    camctl_json(url, "stage", "move", "0.6")


# -- scans: open loop blurs, closed loop holds (docs/physics.md §6) -------------------------------------


@pytest.mark.exclusive
def test_disturbed_stage_open_loop_blurs_closed_loop_holds(
    client: CamdClient, tmp_path: Path
) -> None:
    perfect = scan(client, tmp_path / "perfect.h5", closed_loop=False)
    client.set_stage_faults(**DISTURBANCE)
    opened = scan(client, tmp_path / "open.h5", closed_loop=False)
    # As a campaign's step: the client in control says what it does, and the file keeps it.
    with client.holding_control():
        client.set_activity(STEP, 0, 1)
        closed = scan(client, tmp_path / "closed.h5", closed_loop=True)

    # A perfect stage run open loop: the image moves exactly as the equations say.
    assert perfect["mismatch_max"] == pytest.approx(0.0, abs=0.02)
    # Open loop on the disturbed stage: the 0.5 % clock error alone is M dV/V = 0.48, the
    # ripple adds up to 0.96 more: beyond the yellow limit 1 (MTF at Nyquist 0.64).
    assert opened["mismatch_max"] > 1.0 and opened["mismatch_level"] == "yellow"
    assert opened["motion"]["closed_loop"] == "off"
    # Closed loop: inside the tolerance (level ok: every line under the yellow limit 1), the
    # RMS under the 0.2 target (|dV/V| < 0.2 %) and the worst line at most half the open
    # loop's. Not the worst line under 0.2: that one line is where a late correction shows,
    # and a busy host's come late (quiet 0.10-0.16, RMS 0.04-0.07 under stress-ng; one loaded
    # suite run's worst line was 0.29).
    assert closed["mismatch_level"] == "ok"
    assert closed["mismatch_rms"] < 0.2
    assert closed["mismatch_max"] < 0.5 * opened["mismatch_max"]
    assert closed["motion"]["closed_loop"] == "step_rate"
    assert closed["motion"]["loop_samples"] > 100 and closed["motion"]["loop_error"] is None
    events = [e["message"] for e in client.events(limit=200)["events"]]
    assert any("velocity mismatch yellow" in m for m in events)
    metrics = httpx.get(f"{client.url}/metrics", timeout=10).text
    assert f'camd_scan_m_dv_over_v{{stat="max"}} {closed["mismatch_max"]}' in metrics

    mtf_perfect, err_perfect, width_perfect = edge_mtf(tmp_path / "perfect.h5")
    mtf_open, _, width_open = edge_mtf(tmp_path / "open.h5")
    mtf_closed, err_closed, width_closed = edge_mtf(tmp_path / "closed.h5")
    assert mtf_open < mtf_perfect - 0.05 and width_open > width_perfect + 0.1
    # Closed loop: as sharp as eq 8 says at the smears its lines had, within the measurement
    # noise (4 standard errors). Near the rolling shutter's 0.96 pixel of smear the MTF at
    # Nyquist is steep (0.1 pixel more costs 10 %), so "as sharp as the perfect stage" holds
    # only while the loop's corrections are prompt: a busy machine's late ones left 0.055
    # pixel more on average (0.418 against 0.443), with M |dV/V| still under 0.2.
    eq8_perfect, smear_perfect = eq8_at_the_lines(tmp_path / "perfect.h5")
    eq8_closed, smear_closed = eq8_at_the_lines(tmp_path / "closed.h5")
    expected = mtf_perfect * eq8_closed / eq8_perfect
    assert abs(mtf_closed - expected) < 4 * math.hypot(err_perfect, err_closed) + 0.01
    assert mtf_closed > mtf_open + 0.05
    # The edge widens by at most 0.8 of the extra smear (a box of width s has a 10-90 % width
    # of 0.8 s), and by nothing more.
    extra = abs(smear_closed - smear_perfect)
    assert abs(width_closed - width_perfect) < 0.05 + 0.8 * extra

    # The file keeps the motion: encoder per line, M dV/V per line, the loop's polls.
    tdi = read_tdi_scan(tmp_path / "closed.h5")
    complete = tdi.complete
    assert np.isfinite(tdi.m_dv_over_v[complete]).all()
    assert np.abs(tdi.m_dv_over_v[complete]).max() == pytest.approx(
        closed["mismatch_max"], rel=1e-5
    )
    counts_per_line = np.diff(tdi.stage_position.astype(np.int64))
    # 1 um encoder, 5.36 um of stage per line at the synchronous speed.
    assert np.median(counts_per_line) == pytest.approx(SYNC_M_S * T_LINE_S * 1e6, abs=1.5)
    assert tdi.metadata["motion"]["closed_loop"] == "step_rate"
    assert tdi.metadata["motion"]["mismatch_level"] == "ok"
    with h5py.File(tmp_path / "closed.h5", "r") as f:
        loop = f["motion_loop"]
        assert set(loop) >= {"time_s", "encoder_m", "measured_m_s", "command_m_s"}
        assert loop["time_s"].shape[0] == closed["motion"]["loop_samples"]
        # Its NeXus entry (docs/scan.md, "NeXus"): the stage as an NXpositioner, its position
        # in m from the 1 um encoder; the scene as the NXsample; the step as an NXnote.
        stage = f["entry/instrument/stage"]
        assert stage.attrs["NX_class"] == "NXpositioner"
        assert np.array_equal(stage["raw_value"][()], tdi.stage_position)
        assert stage["value"].attrs["units"] == "m"
        assert np.allclose(stage["value"][()], tdi.stage_position * 1e-6, rtol=1e-12)
        assert stage["velocity"][()] == pytest.approx(SYNC_M_S, rel=0.01)
        assert f["entry/sample/name"][()].decode() == SCENE
        assert f["entry/campaign_step/description"][()].decode() == STEP
        assert f["entry/campaign_step/sequence_index"][()] == 1
    assert tdi.metadata["activity"]["text"] == STEP
    # Written by the daemon with the camera's whole profile: nothing in the entry for a NeXus
    # validator to report, only camd's root layout (tests/test_nexus.py lists it).
    found = nxcheck(tmp_path / "closed.h5")
    assert found["error"] == []
    assert all(w.startswith(("/: ", "/lines", "/line_index", "/frame_counter", "/stage",
                             "/complete", "/m_dv_over_v", "/lines_flushed")) for w in found["warning"])  # fmt: skip


@pytest.mark.exclusive
def test_mtf_at_nyquist_follows_the_smear_model(client: CamdClient, tmp_path: Path) -> None:
    """MTF at Nyquist for smears of 0, 1 and 2 pixels over M stages (docs/physics.md §6 eq 8:
    sinc(p f M dV/V) = sinc(smear / 2) at Nyquist) times the detector terms (eq 3).

    The rolling shutter reads row i of a frame i row times after row 0, so at the synchronous
    speed of §6 the image moves 1 - T_row / T rows between stages: M T_row / T = 0.96 pixel of
    smear already (docs/motion.md). A stage speed off by dV/V adds M dV/V, so a total smear s
    needs dV/V = s / M - T_row / T."""
    skew = T_ROW_S / T_LINE_S
    measured = {}
    eq8 = {}
    for smear in (0, 1, 2):
        path = tmp_path / f"smear{smear}.h5"
        doc = scan(client, path, lines=300, closed_loop=True, dv_over_v=smear / STAGES - skew)
        # The monitor reports M dV/V against the synchronous speed: s - M T_row / T.
        assert doc["mismatch_rms"] == pytest.approx(abs(smear - STAGES * skew), abs=0.1)
        measured[smear] = edge_mtf(path)
        # Eq 8 at the smear each line really had, not the one asked for: on a busy machine a
        # line's smear can be 1.07 pixels where 1 was asked (sinc(0.535) = 0.60, not 0.64).
        # The loop's own accuracy is the mismatch check above.
        eq8[smear] = eq8_at_the_lines(path)[0]
    mtf0, err0, _ = measured[0]
    # Eq 8 alone, as a ratio (the detector and scene terms cancel): 0.637 and 0 at the smears
    # asked for, and the lines' own smears must give about that.
    assert eq8[1] / eq8[0] == pytest.approx(2 / math.pi, abs=0.05)
    assert measured[1][0] / mtf0 == pytest.approx(eq8[1] / eq8[0], abs=0.03)
    assert measured[2][0] / mtf0 < 0.05
    # Eq 3 at Nyquist: sinc(q / 2p) (q = sqrt(fill factor) pixels), sinc(T_int / 2 T_L) (the
    # image moves during each frame's exposure), times the simulated scene's own cells (1/4
    # pixel: sinc(1/8)^2, docs/mtf.md).
    profile = load_profile("hr400")
    exposure_s = float(client.timing()["exposure_s"])
    q = math.sqrt(profile.fill_factor.value)
    model = np.sinc(q / 2) * np.sinc(exposure_s / T_LINE_S / 2) * np.sinc(1 / 8) ** 2
    assert mtf0 == pytest.approx(model, rel=0.04)
    assert err0 < 0.01


def test_scans_beyond_the_stage_are_refused_before_anything_is_written(
    daemon: DaemonProcess, tmp_path: Path
) -> None:
    before = camctl_json(daemon.url, "timing")
    fast = camctl(
        daemon.url, "scan", "--stages", "8", "--lines", "50", "--line-period-s",
        repr(12 * T_ROW_S), "--out", str(tmp_path / "fast.h5"),
    )  # fmt: skip
    assert fast.returncode == 1
    assert "446.719 mm/s is above the limit 100 mm/s" in fast.stderr
    far = camctl(
        daemon.url, "scan", "--stages", "8", "--lines", "200000", "--line-period-s",
        repr(T_LINE_S), "--out", str(tmp_path / "far.h5"),
    )  # fmt: skip
    assert far.returncode == 1
    assert "mm of travel at 53.61 mm/s but the soft limits leave 1200.0 mm" in far.stderr
    # A mismatch the stepper cannot run (1.6 x synchronous): only the ideal stage takes it.
    wild = camctl(
        daemon.url, "scan", "--stages", "8", "--lines", "50", "--line-period-s",
        repr(T_LINE_S), "--dv-over-v", "-0.6", "--out", str(tmp_path / "wild.h5"),
    )  # fmt: skip
    assert wild.returncode == 1
    assert "dv_over_v = -0.6 with the stage driven: it takes -0.5 .. 0.5" in wild.stderr
    assert camctl_json(daemon.url, "timing") == before
    for name in ("fast.h5", "far.h5", "wild.h5"):
        assert not (tmp_path / name).exists()
    assert camctl_json(daemon.url, "status")["state"] == "idle"


@pytest.mark.exclusive
def test_line_period_correction_follows_the_stage(tmp_path: Path) -> None:
    """The other closed loop (TAO12): the line period follows the stage, coarse by window
    rows, fine by the back path (docs/physics.md §2 eqs 8-9)."""
    with (
        start_daemon(tmp_path, '[motion]\ncorrect = "line_period"\n') as d,
        CamdClient(d.url) as client,
    ):
        client.wait_ready(60)
        client.set_scene(SCENE)
        client.set_stage_faults(**DISTURBANCE)
        opened = scan(client, tmp_path / "open.h5", closed_loop=False)
        closed = scan(client, tmp_path / "closed.h5", closed_loop=True)
        assert opened["mismatch_max"] > 1.0
        assert closed["motion"]["closed_loop"] == "line_period"
        # A register write per correction, applied at the next frame: slower than the step
        # rate's loop, and a busy host shows. Quiet: max 0.16-0.22 px, RMS 0.13-0.14 against
        # the open loop's 1.19 and 0.72. With both cores hogged (stress-ng --cpu 2), 14 scans:
        # max 0.20-0.96, RMS 0.12-0.40; in two fresh-clone suite runs (one at load 10, one with
        # a test beside it) one late correction gave a max of 1.25-1.29, the RMS still low. So
        # the bound is on the RMS only, with room for a busy host; the periods below show the
        # loop following the stage whatever the load.
        assert closed["mismatch_rms"] < 0.75 * opened["mismatch_rms"]
        with h5py.File(tmp_path / "closed.h5", "r") as f:
            periods = f["motion_loop/line_period_s"][...]
        periods = periods[np.isfinite(periods)]
        # The stage runs 0.5 % slow, so the line period stretches by about 0.5 %, with the
        # ripple's +-1 % on top; each period is whole rows plus a back path (eqs 8, 9).
        assert np.median(periods) / T_LINE_S == pytest.approx(1.005, abs=0.004)
        assert periods.max() > periods.min() * 1.005


@pytest.fixture(scope="module")
def turntable(tmp_path_factory: pytest.TempPathFactory) -> Iterator[DaemonProcess]:
    """A daemon whose stage is a turntable (TAO12's rig, docs/physics.md §2 eq 5)."""
    tmp = tmp_path_factory.mktemp("camd-turntable")
    daemon = start_daemon(tmp, '[stage]\nprofile = "turntable"\n')
    with daemon as d, CamdClient(d.url) as client:
        client.wait_ready(60)
        client.set_scene(SCENE)
        yield d
    assert daemon.exit_code in (0, -15), daemon.log_path.read_text()


def turntable_sync(daemon: DaemonProcess) -> dict[str, object]:
    return camctl_json(daemon.url, "sync", "--line-period-s", repr(T_LINE_S))


def test_turntable_carries_the_sensor_eq5(turntable: DaemonProcess) -> None:
    """A turntable (TAO12's rig, docs/physics.md §2 eq 5): the sensor rides at l = 0.1 m, the image
    moves with the arc (image scale 1), T = a / (w l). (Its scan, closed loop, is the next
    test: that one needs the machine alone, this one does not.)"""
    doc = turntable_sync(turntable)
    # w = a / (T l) = 11 um / (2.052 ms x 0.1 m) = 0.053606 rad/s; arc speed w l.
    assert doc["angular_velocity_rad_s"] == pytest.approx(0.0536062378, rel=1e-8)
    assert doc["image_scale"] == 1.0
    assert doc["sync_speed"] == pytest.approx(0.00536062378, rel=1e-8)
    arc_per_microstep = 2 * math.pi * 0.1 / (200 * 16 * 180)  # 180:1 worm gear
    assert doc["step_rate_hz"] == pytest.approx(0.00536062378 / arc_per_microstep, rel=1e-8)


@pytest.mark.exclusive
def test_turntable_scan_holds_the_arc_speed_closed_loop(
    turntable: DaemonProcess, tmp_path: Path
) -> None:
    with CamdClient(turntable.url) as client:
        sync_speed = turntable_sync(turntable)["sync_speed"]
        result = scan(client, tmp_path / "table.h5", lines=150, closed_loop=True)
        assert result["motion"]["stage_speed_m_s"] == pytest.approx(sync_speed)
        assert result["mismatch_max"] < 0.2
