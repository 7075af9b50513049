"""Push-broom scans over the full stack, as a user drives them.

camctl scan (in process; one test as a command) -> HTTP -> camd serve -> registers for the line
period (docs/physics.md §2) -> START_STREAM -> simulated camera -> simulated FX3 -> FrameStream ->
batches -> TdiEngine -> HDF5 + PNG, read back here. The sensor's ramp test pattern makes every
frame known, so the TDI lines can be checked against eq 11 worked out here, independently of
camd.tdi.
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np
import pytest

from camd.sensor.profile import load_profile
from camd.store.tdi_recording import read_tdi_scan
from camd.tdi import bin2x2
from tests.nexus_support import nexus_plot
from tests.test_camctl import camctl, camctl_command_json, camctl_json
from tests.test_sensor_stack import serve

# Not ``exclusive`` but for the scan that runs until stopped (its length is the host's polling,
# and a late host's scan outgrows the daemon's queue): the other scans are a few hundred frames
# of a small window, which a late host receives late but whole (the simulated camera loses no
# frame for lateness: firmware_models/fx3.py). Checked beside `stress-ng --cpu 2`.

ROWS = 16
CLOCK_HZ = 25e6  # hr400 sequencer clock (config/sensors/hr400.toml)


@pytest.fixture(scope="module")
def url(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    with serve(tmp_path_factory.mktemp("camd-scan"), "fpga") as daemon:
        camctl_json(daemon.url, "reg", "write", f"WIN_ROWS={ROWS}", "EXPOSURE=4")
        yield daemon.url
    assert daemon.exit_code in (0, -15), daemon.log_path.read_text()


@pytest.fixture
def ramp(url: str) -> Iterator[None]:
    camctl_json(url, "reg", "write", "TEST_PATTERN.mode=ramp")
    try:
        yield
    finally:
        camctl_json(url, "reg", "write", "TEST_PATTERN.mode=off")


def ramp_line(stages: int, cols: int = 2048) -> np.ndarray:
    """Eq 11 on the ramp pattern (row + col) mod 4096: every frame is the same, so line k is
    the sum over stages i of (i + j) mod 4096."""
    rows = np.arange(stages)[:, None]
    return (((rows + np.arange(cols)) & 0xFFF).sum(axis=0)).astype(np.uint32)


def row_period_s(url: str) -> float:
    return float(camctl_json(url, "timing")["line_period_s"])


def test_scan_records_eq11_lines_with_flags_metadata_and_quicklook(
    url: str, ramp: None, tmp_path: Path
) -> None:
    row = row_period_s(url)
    period = 12.5 * row  # 12 rows and half a row of back path (eqs 8, 9)
    out = tmp_path / "ramp.h5"
    doc = camctl_json(
        url, "scan", "--no-stage", "--stages", "8", "--lines", "30", "--line-period-s", repr(period),
        "--out", str(out),
    )  # fmt: skip
    assert list(doc)[:5] == ["file", "lines", "complete_lines", "lost_frames", "stages"]
    assert (doc["file"], doc["lines"], doc["complete_lines"]) == (str(out), 37, 30)
    assert (doc["lost_frames"], doc["stages"], doc["state"]) == (0, 8, "done")
    timing = doc["timing"]
    assert timing["n_lines"] == 12 and timing["max_stages"] == 12
    assert timing["back_path_s"] == pytest.approx(0.5 * row, abs=1 / CLOCK_HZ)
    assert timing["tdi_line_period_s"] == pytest.approx(period, abs=1 / CLOCK_HZ)
    profile = load_profile("hr400")
    sync = profile.pitch_m.value / (profile.magnification.value * timing["tdi_line_period_s"])
    assert timing["sync_speed_m_s"] == pytest.approx(sync, rel=1e-9)
    assert timing["stage_speed_m_s"] == pytest.approx(sync, rel=1e-6)  # the sim stage tracks

    scan = read_tdi_scan(out)
    assert scan.lines.dtype == np.uint32 and scan.lines.shape == (37, 2048)
    assert scan.line_index.tolist() == list(range(37))
    assert scan.stages_used.tolist() == [*range(1, 8), *[8] * 30]
    assert scan.complete.tolist() == [False] * 7 + [True] * 30
    for k in range(37):
        assert np.array_equal(scan.lines[k], ramp_line(min(k + 1, 8))), k
    counters = scan.frame_counter.astype(np.int64)
    assert np.diff(counters).tolist() == [1] * 36
    assert scan.stage_changes.tolist() == [[0, 8]]
    assert scan.metadata["profile"]["profile"] == "hr400"
    assert scan.metadata["timing"]["n_lines"] == 12
    assert scan.metadata["scan"]["stages"] == 8 and scan.metadata["scan"]["lines"] == 30
    assert scan.metadata["counters"]["lines"] == 37
    assert scan.metadata["registers"]["WIN_ROWS"] == 12
    png = cv2.imread(str(doc["quicklook"]), cv2.IMREAD_UNCHANGED)
    assert png is not None and png.shape[:2] == (37, 2048)
    # A NeXus viewer finds the lines as an image against line index and column, and the
    # detector with the sensor and the TDI settings (docs/scan.md, "NeXus").
    nexus = nexus_plot(out)
    assert (nexus["signal"], nexus["shape"]) == ("lines", (37, 2048))
    assert nexus["axes"] == [("line_index", (37,)), ("column", (2048,))]
    assert np.array_equal(nexus["signal_values"], scan.lines)
    assert nexus["axis_values"][0].tolist() == list(range(37))
    det = nexus["detector"]
    assert nexus["tdi"] == {"stages": 8, "window_rows": 12, "mode": "sum"}
    assert det["local_name"] == ("hr400", None)
    assert det["x_pixel_size"] == (profile.pitch_m.value, "m")
    assert det["frame_time"][0] == pytest.approx(timing["tdi_line_period_s"])
    assert det["frame_time"][1] == "s"
    assert nexus["title"] == "TDI scan, hr400, M = 8, sum mode"


def test_binned_scan_sums_binned_rows_at_twice_the_synchronous_speed(
    url: str, ramp: None, tmp_path: Path
) -> None:
    row = row_period_s(url)
    doc = camctl_json(
        url, "scan", "--no-stage", "--stages", "4", "--lines", "6", "--binning", "--line-period-s",
        repr(16.5 * row), "--out", str(tmp_path / "binned.h5"), "--no-quicklook",
    )  # fmt: skip
    assert (doc["lines"], doc["complete_lines"], doc["width"]) == (9, 6, 1024)
    # docs/physics.md §3: each binned pixel is the sum of a 2x2 block of the ramp; the image must
    # move one binned row (two pitches) per line period, so the stage runs twice as fast.
    binned = bin2x2(np.add.outer(np.arange(16), np.arange(2048)) & 0xFFF)
    scan = read_tdi_scan(tmp_path / "binned.h5")
    assert np.array_equal(scan.lines[-1], binned[:4].sum(axis=0))
    profile = load_profile("hr400")
    period = doc["timing"]["tdi_line_period_s"]
    sync = 2 * profile.pitch_m.value / (profile.magnification.value * period)
    assert doc["timing"]["sync_speed_m_s"] == pytest.approx(sync, rel=1e-9)


def test_stage_speed_sets_the_line_period_by_eq5(url: str, tmp_path: Path) -> None:
    profile = load_profile("hr400")
    row = row_period_s(url)
    # A speed whose line period is 10.3 rows: 10 window rows and 0.3 rows of back path.
    speed = profile.pitch_m.value / (profile.magnification.value * 10.3 * row)
    doc = camctl_command_json(
        url, "scan", "--no-stage", "--stages", "4", "--lines", "5", "--speed-m-s", repr(speed),
        "--out", str(tmp_path / "speed.h5"), "--no-quicklook",
    )  # fmt: skip
    timing = doc["timing"]
    assert timing["n_lines"] == math.floor(10.3) == 10
    assert timing["tdi_line_period_s"] == pytest.approx(10.3 * row, abs=1 / CLOCK_HZ)
    assert timing["stage_speed_m_s"] == pytest.approx(speed, rel=1e-6)
    # The back path is whole clocks, so the period is off by < 1 clock: dV/V is that small.
    assert abs(timing["dv_over_v"]) < 1 / (CLOCK_HZ * 10.3 * row)
    assert doc["quicklook"] is None and doc["complete_lines"] == 5


@pytest.mark.exclusive
def test_stages_change_mid_scan_without_stopping_the_stream(
    url: str, ramp: None, tmp_path: Path
) -> None:
    out = tmp_path / "restage.h5"
    camctl_json(
        # 48 rows (1 kHz): the test is about the stage change, not throughput; at 12 rows
        # (4 kHz, 100 MB/s) a busy 2-core host can overrun the stream's queue.
        url, "scan", "--no-stage", "--stages", "8", "--lines", "0", "--line-period-s", repr(48 * row_period_s(url)),
        "--out", str(out), "--detach",
    )  # fmt: skip
    try:
        wait_lines(url, 40)
        changed = camctl_json(url, "stages", "4")
        assert changed["state"] == "running"
        wait_for(url, lambda doc: len(doc["stage_changes"]) == 2 and doc["lines"] > 80)
    finally:
        final = camctl_json(url, "scan", "--stop")
        camctl_json(url, "reg", "write", f"WIN_ROWS={ROWS}")  # the module's window again
    assert final["state"] == "stopped" and final["lost_frames"] == 0
    (start, m0), (at, m1) = final["stage_changes"]
    assert (start, m0, m1) == (0, 8, 4)
    scan = read_tdi_scan(out)
    assert scan.stage_changes.tolist() == [[0, 8], [at, 4]]
    used = scan.stages_used
    # Before the change: 7 filling lines, then all 8 stages. After: a new run of 4 stages.
    assert used[:at].tolist() == [*range(1, 8), *[8] * (at - 7)]
    assert used[at:].tolist() == [1, 2, 3, *[4] * (len(used) - at - 3)]
    assert scan.complete.tolist() == (used == np.where(np.arange(len(used)) < at, 8, 4)).tolist()
    assert np.array_equal(scan.lines[at - 1], ramp_line(8))
    assert np.array_equal(scan.lines[at + 1], ramp_line(2))
    assert np.array_equal(scan.lines[-1], ramp_line(4))
    # The stream was never restarted: one run of frame counters.
    assert np.diff(scan.frame_counter.astype(np.int64)).tolist() == [1] * (len(used) - 1)


def test_bad_scans_are_refused_and_leave_the_daemon_idle(url: str, tmp_path: Path) -> None:
    proc = camctl(
        url, "scan", "--no-stage", "--stages", "40", "--lines", "5", "--out", str(tmp_path / "x.h5")
    )
    assert proc.returncode == 1
    assert "stages = 40 needs 40 window rows" in proc.stderr and "choose 1.." in proc.stderr
    assert not (tmp_path / "x.h5").exists()
    proc = camctl(url, "stages", "4")
    assert proc.returncode == 1 and "no scan is running" in proc.stderr
    proc = camctl(url, "scan", "--no-stage", "--stages", "4")
    assert proc.returncode == 2 and "--lines" in proc.stderr
    existing = tmp_path / "there.h5"
    existing.write_bytes(b"")
    proc = camctl(
        url, "scan", "--no-stage", "--stages", "4", "--lines", "5", "--out", str(existing)
    )
    assert proc.returncode == 2 and "already exists" in proc.stderr
    proc = camctl(
        url, "scan", "--no-stage", "--stages", "4", "--lines", "5", "--line-period-s", "1e-6"
    )
    assert proc.returncode == 1 and "shorter than one row period" in proc.stderr
    # Stages that the window a line period leaves cannot hold: refused before any write.
    before = camctl_json(url, "timing")
    period = repr(10.5 * row_period_s(url))
    proc = camctl(
        url, "scan", "--no-stage", "--stages", "11", "--lines", "5", "--line-period-s", period
    )
    assert proc.returncode == 1 and "needs 11 window rows but the scan's frames have 10" in (
        proc.stderr
    )
    assert camctl_json(url, "timing") == before
    assert camctl_json(url, "status")["state"] == "idle"


def test_flat_field_snr_grows_as_sqrt_m(url: str, tmp_path: Path) -> None:
    """docs/physics.md §5: with independent noise per stage (shot, read, quantisation), M stages give
    M times the signal and sqrt(M) times the noise. Temporal noise is measured along the track
    (one column's lines all sum the same M pixels, so fixed pattern cancels); the signal is
    above the black level of the M summed pixels."""
    period = 12 * row_period_s(url)
    black = float(load_profile("hr400").black_level_dn.value)
    snr = {}
    for stages in (1, 4, 12):
        out = tmp_path / f"flat{stages}.h5"
        camctl_json(
            url, "scan", "--no-stage", "--stages", str(stages), "--lines", "300", "--scene",
            "flat:photons=2e5", "--line-period-s", repr(period), "--out", str(out),
            "--no-quicklook",
        )  # fmt: skip
        lines = read_tdi_scan(out).lines[stages - 1 :].astype(np.float64)
        noise = lines.std(axis=0, ddof=1).mean()
        snr[stages] = (lines.mean() - stages * black) / noise
    for stages in (4, 12):
        assert snr[stages] / snr[1] == pytest.approx(math.sqrt(stages), rel=0.06), snr


def wait_for(url: str, done: object, timeout_s: float = 60.0) -> dict[str, object]:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        doc = camctl_json(url, "scan", "--status")
        if done(doc):  # type: ignore[operator]
            return doc  # type: ignore[no-any-return]
        time.sleep(0.2)
    raise AssertionError(f"scan did not get there in {timeout_s} s: {doc}")


def wait_lines(url: str, lines: int) -> None:
    wait_for(url, lambda doc: doc["lines"] >= lines)
