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
from tests.test_camctl import camctl
from tests.test_sensor_stack import serve

MAGNIFICATION_ERROR = 0.01
ROTATION_DEG = 0.5
STAGES = 32
LINES = 1500
LINE_PERIOD_S = 2e-3
SCENE = f"natural:photons=1e9,magnification_error={MAGNIFICATION_ERROR},rotation_deg={ROTATION_DEG}"


@pytest.fixture(scope="module")
def daemon(tmp_path_factory: pytest.TempPathFactory) -> Iterator[DaemonProcess]:
    with serve(tmp_path_factory.mktemp("camd-image-motion"), "fpga") as d:
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
    print(image)
    assert dv == pytest.approx(-MAGNIFICATION_ERROR, abs=0.5 * MAGNIFICATION_ERROR)
    assert image["m_dv_over_v_mean"] == pytest.approx(STAGES * dv, rel=1e-9)
    assert theta == pytest.approx(ROTATION_DEG, abs=0.15)
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
