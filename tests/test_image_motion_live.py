"""The image's motion measured live (issue 35 item 2) over the full stack, as a user sees it.

A daemon on the simulated hr400 scans a natural texture whose optics carry a magnification error
and whose camera is turned on its mount (firmware_models.image_errors): the simulator's ideal
stage moves at the synchronous speed, so the image runs ``1 + e`` rows per line and drifts
``tan(r)`` columns per row. The monitor measures blocks of the scan's frames on its own thread
(camd.pipeline.image_motion); the figures reach the scan's status, ``camctl scan --status``,
``GET /api/v1/live/motion`` and the scan file's ``/image_motion`` group.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from pathlib import Path

import h5py
import numpy as np
import pytest

from camd.cli._daemon_proc import DaemonProcess
from camd.client import CamdClient
from tests.realtime_support import as_the_unit
from tests.test_camctl import NO_TOKEN, camctl

MAGNIFICATION_ERROR = 0.01
ROTATION_DEG = 0.5
STAGES = 32
LINES = 1500
LINE_PERIOD_S = 2e-3
SCENE = f"natural:photons=1e9,magnification_error={MAGNIFICATION_ERROR},rotation_deg={ROTATION_DEG}"


T_ROW_S = 513 / 25e6  # hr400's row time


@pytest.fixture(scope="module")
def daemon(tmp_path_factory: pytest.TempPathFactory) -> Iterator[DaemonProcess]:
    tmp = tmp_path_factory.mktemp("camd-image-motion")
    config = tmp / "camd.toml"
    # half a core for the measurement: more blocks in a short scan, the loop more updates
    config.write_text('[sensor]\nname = "hr400"\n[motion]\nimage_cpu_fraction = 0.5\n')
    with DaemonProcess(
        tmp, extra_args=["--config", str(config)], env=NO_TOKEN, wrapper=as_the_unit()
    ) as d:
        with CamdClient(d.url) as client:
            client.wait_ready(60)
        yield d
    assert d.exit_code in (0, -15), d.log_path.read_text()


def test_a_scan_measures_the_magnification_error_and_the_rotation(
    daemon: DaemonProcess, tmp_path: Path
) -> None:
    out = tmp_path / "scan.h5"
    with CamdClient(daemon.url, timeout_s=60) as client:
        client.start_scan(
            STAGES, LINES, out=str(out), scene=SCENE, line_period_s=LINE_PERIOD_S,
            drive_stage=False,
        )  # fmt: skip
        doc = client.wait_scan(timeout_s=300)
        live = client.image_motion(history=1024)
    assert doc["state"] == "done", doc["error"]
    image = doc["image_motion"]
    assert image is not None
    # The image runs ahead by the magnification error: dV/V = -e (docs/physics.md §10).
    assert image["measurable_blocks"] >= 1
    dv = image["dv_over_v_mean"]
    theta = image["theta_deg_mean"]
    assert dv is not None and theta is not None
    assert dv == pytest.approx(-MAGNIFICATION_ERROR, abs=0.5 * MAGNIFICATION_ERROR)
    assert image["m_dv_over_v_mean"] == pytest.approx(STAGES * dv, rel=1e-9)
    assert theta == pytest.approx(ROTATION_DEG, abs=0.15)
    # The rolling shutter's lag the frames' step was turned with: hr400's row time over the
    # line period (docs/physics.md §10)
    assert image["latest"]["row_lag_lines"] == pytest.approx(T_ROW_S / LINE_PERIOD_S, rel=1e-3)
    # What the monitor saw: every TDI frame of the scan, the blocks it measured among them.
    assert live["tdi_frames_seen"] >= doc["lines"]
    assert live["blocks_measured"] >= image["blocks"]
    assert live["latest"] == image["latest"]

    with h5py.File(out, "r") as f:
        group = f["image_motion"]
        blocks = int(group.attrs["blocks"])
        assert blocks == image["blocks"]
        first = np.asarray(group["counter_first"])
        lines_first = np.asarray(group["line_first"])
        counters = np.asarray(f["frame_counter"])
        # a block's first line is the line of its first frame
        for c, line in zip(first, lines_first, strict=True):
            assert counters[line] == c
        dvs = np.asarray(group["dv_over_v"])
        assert float(np.nanmean(dvs)) == pytest.approx(dv, rel=1e-9)

    status = camctl(daemon.url, "scan", "--status")
    assert status.returncode == 0, status.stderr
    assert f"image motion ({image['measurable_blocks']} of {blocks} blocks measurable)" in (
        status.stdout
    )
    assert math.isfinite(dv)


def test_the_image_loop_steps_the_frames_one_row_a_line_and_follows_the_drift(
    daemon: DaemonProcess, tmp_path: Path
) -> None:
    # 0.5 % magnification error, camera turned 0.3 degree; the ideal stage at the planned line
    # period's synchronous speed: the image runs 1.005 rows a planned period, and the rolling
    # shutter makes the frames step 1.005 / (1 + 1.005 T_row / T) = 0.995 of a row
    error, rotation_deg, planned_s = 0.005, 0.3, 2e-3
    out = tmp_path / "loop.h5"
    with CamdClient(daemon.url, timeout_s=60) as client:
        client.start_scan(
            96, 3000, out=str(out), line_period_s=planned_s, drive_stage=False, image_loop=True,
            scene=f"natural:photons=1e9,magnification_error={error},rotation_deg={rotation_deg}",
        )  # fmt: skip
        doc = client.wait_scan(timeout_s=300)
    assert doc["state"] == "done", doc["error"]
    image = doc["image_motion"]
    assert image is not None and image["loop"] is not None
    loop = image["loop"]
    assert loop["error"] is None and not loop["limited"] and loop["updates"] >= 3
    # docs/motion.md, "Closing the loop on the image": the frames step one row at
    # T* = 1 / u + T_row, u the image's rows a second
    planned = doc["timing"]["tdi_line_period_s"]
    speed_rows_s = (1 + error) / planned
    t_star = 1 / speed_rows_s + T_ROW_S
    with h5py.File(out, "r") as f:
        record = {k: np.asarray(v) for k, v in f["image_loop"].items()}
        assert f["image_loop"].attrs["updates"] == loop["updates"]
    # The first block: the frames stepped 0.995 of a row at the planned period.
    first_s = float(record["shift_along_px_per_line"][0])
    assert first_s == pytest.approx(speed_rows_s * planned / (1 + speed_rows_s * T_ROW_S), abs=2e-3)
    # The loop's last period: T* (0.53 % above the planned one) to within 5e-4, what the last
    # blocks' steps could tell (a step's error maps one to one into the period's: 5e-4 is a
    # few times the blocks' scatter on the simulator's rendered frames)
    assert loop["line_period_s"] == pytest.approx(t_star, rel=5e-4)
    assert t_star / planned - 1 > 0.005
    last = record["shift_along_px_per_line"][-3:]
    assert np.all(np.abs(last - 1.0) < 2e-3)
    # The drift taps follow tan(0.3 deg) = 0.0052 columns a line, within the blocks' scatter
    # across (the simulator's rendered frames: about 0.0005 a block).
    assert loop["cols_per_line"] == pytest.approx(math.tan(math.radians(rotation_deg)), abs=2e-3)
    assert float(np.mean(record["cols_per_line"][-5:])) == pytest.approx(
        math.tan(math.radians(rotation_deg)), abs=1e-3
    )
    status = camctl(daemon.url, "scan", "--status")
    assert f"image loop: {loop['updates']} updates" in status.stdout


def test_binned_frames_rows_are_read_two_row_times_apart(daemon: DaemonProcess) -> None:
    # 2x2 binning on the FPGA: each row of the frames sums two of the sensor's, read one row
    # time apart, so consecutive rows of the frames are two row times apart (§10's lag doubles).
    # Binning needs an even window: 96 rows and a short back path.
    with CamdClient(daemon.url, timeout_s=60) as client:
        client.start_scan(
            16, 200, line_period_s=96 * T_ROW_S + 2e-5, drive_stage=False, binning="2x2",
            scene="natural:photons=1e9", quicklook=False,
        )  # fmt: skip
        doc = client.wait_scan(timeout_s=300)
    assert doc["state"] == "done", doc["error"]
    latest = doc["image_motion"]["latest"]
    assert latest is not None
    period = doc["timing"]["tdi_line_period_s"]
    assert latest["row_lag_lines"] == pytest.approx(2 * T_ROW_S / period, rel=1e-3)
    # the image in step (the ideal stage at the binned pitch's synchronous speed): dV/V near 0;
    # with the sensor's row time instead it would read 0.010, with none 0.021
    mean = doc["image_motion"]["dv_over_v_mean"]
    assert mean is not None and abs(mean) < 0.003, mean
