"""The simulator's image motion errors the encoder cannot see (issue 35, item 3).

A magnification error, a camera rotated about the optical axis and a yawing stage move the
image differently from what the stage's encoder says (docs/simulator.md, "Image motion errors").
The image's motion is measured here from the rendered frames themselves, on noise-free charge
of linear ramps (the box integral of a linear function is its centre value, so each pixel's
charge gives the scene position it saw, to float64 precision): along track from a ramp along
the rows, across track from an image that ramps across the columns. The encoder's counts are
read from the frame headers of an in-process FPGA's TDI stream.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

from camd.sensor.profile import Sourced, load_profile
from camd.sensor.regmap import load_register_map
from firmware_models.camera import CameraModel
from firmware_models.fpga import FpgaModel
from firmware_models.scene_spec import SceneSpec, SceneSpecError
from firmware_models.sensor import SensorModel

ROWS = 64
EXPOSURE_LINES = 5
T0_S = 0.05  # row 0 of the first frame ends its exposure here
PHOTONS = 1e9
RAMP_PERIOD_ROWS = 8192  # no wrap of the along-track ramp inside the window
EDGE_COLS = 32  # columns at either side left out: the across-track ramps wrap there
TILT_SCALE = 4200.0  # a tilted ramp's value per pixel of its rise (``tilted_ramp``)


def write(sensor: SensorModel, name: str, value: int) -> None:
    sensor.spi_write(sensor.regmap.register(name).address, value)


def ideal_camera() -> CameraModel:
    """hr400 without a fixed pattern or dark charge, fill factor 1 (the aperture spans whole
    cells, so a ramp of cells integrates exactly as the line), tracking the synchronous speed:
    the image moves one row per TDI line period unless the scene says otherwise."""
    profile = load_profile("hr400")
    values = {"fill_factor": 1.0, "prnu_fraction": 0.0, "dsnu_e_per_s": 0.0}
    values["dark_current_e_per_s"] = 0.0
    update = {k: Sourced[Any](value=v, assumed="test variant") for k, v in values.items()}
    sensor = SensorModel(load_register_map("hr400"))
    write(sensor, "WIN_ROWS", ROWS)
    write(sensor, "EXP_LO", EXPOSURE_LINES)
    return CameraModel(profile.model_copy(update=update), sensor)


@pytest.fixture(scope="module")
def across_ramp(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """An image brighter by one step per column (8 rows, the sensor's 2048 columns)."""
    path = tmp_path_factory.mktemp("scene") / "across_ramp.png"
    ramp = (32 * np.arange(2048, dtype=np.uint16))[np.newaxis, :].repeat(8, axis=0)
    assert cv2.imwrite(str(path), ramp)
    return path


def positions(camera: CameraModel, t_s: float, axis: int) -> np.ndarray:
    """The scene position each pixel saw, in steps of the ramp along ``axis`` (0: rows,
    1: columns): its charge over the charge one step of the ramp gives. Across track that
    step is the difference between neighbouring columns; along track it is the ramp's slope
    (a rolling shutter exposes neighbouring rows at different times, so they differ by more
    than one step)."""
    charge = camera.expected_electrons(t_s, dtype=np.float64)
    if axis == 1:
        return charge / float(np.median(np.diff(charge, axis=1)))
    return charge / ramp_step(camera, RAMP_PERIOD_ROWS)


def ramp_step(camera: CameraModel, period_rows: float) -> float:
    """The charge one row of a ``ramp`` scene of that period adds (or one pixel of a
    ``tilted_ramp``'s rise, ``period_rows`` = TILT_SCALE)."""
    # The response map (QE x (1 + PRNU)) is kept in float32: QE = 0.6 is 0.6 + 2.4e-8 there.
    qe = float(np.float32(camera.profile.quantum_efficiency.value))
    return qe * camera.sensor.timing().exposure_s * PHOTONS / period_rows


def motion_per_line(camera: CameraModel, axis: int, lines: int = 1) -> np.ndarray:
    """How far the image moved along ``axis`` between two frames ``lines`` TDI line periods
    apart, per pixel (the ramp's wrap columns left out across track)."""
    period_s = camera.sensor.timing().tdi_line_period_s
    first = positions(camera, T0_S, axis)
    second = positions(camera, T0_S + lines * period_s, axis)
    moved = (second - first) / lines
    return moved[:, EDGE_COLS:-EDGE_COLS] if axis == 1 else moved


@pytest.mark.parametrize("error", [-0.02, 0.005, 0.02])
def test_magnification_error_moves_the_image_1_plus_e_rows_per_line(error: float) -> None:
    camera = ideal_camera()
    camera.set_scene(f"ramp:photons={PHOTONS},period={RAMP_PERIOD_ROWS}")
    exact = motion_per_line(camera, axis=0)
    assert np.max(np.abs(exact - 1.0)) < 1e-6  # the encoder's speed: one row per line
    camera.set_scene(
        f"ramp:photons={PHOTONS},period={RAMP_PERIOD_ROWS},magnification_error={error}"
    )
    assert np.max(np.abs(motion_per_line(camera, axis=0) - (1.0 + error))) < 1e-6


def tilted_ramp(folder: Path, rotation_deg: float, axis: int) -> Path:
    """An image (float64 TIFF, 1024 x 2048, one pixel per cell) of a ramp that a camera turned
    by ``rotation_deg`` sees along its rows (``axis`` 0) or columns (1): ``(g . (Y, X) + 64) /
    TILT_SCALE`` at the pixel centres, ``g`` the sensor's axis in the scene's frame."""
    r = math.radians(rotation_deg)
    g_y, g_x = (math.cos(r), -math.sin(r)) if axis == 0 else (math.sin(r), math.cos(r))
    y = np.arange(1024, dtype=np.float64)[:, np.newaxis] + 0.5
    x = np.arange(2048, dtype=np.float64)[np.newaxis, :] + 0.5
    ramp = (g_y * y + g_x * x + 64.0) / TILT_SCALE
    path = folder / f"tilted_{rotation_deg:g}_{axis}.tiff"
    assert cv2.imwrite(str(path), ramp)
    return path


@pytest.mark.parametrize("rotation_deg", [-1.0, 0.3, 1.0])
def test_rotation_turns_the_scene_in_the_focal_plane(rotation_deg: float) -> None:
    """A ramp along the direction of travel, seen by a turned camera: it rises ``sin r`` per
    column across the sensor (the sensor's edge columns left out: the turned scene's seam,
    where its tile wraps across track), and still one step per line along the travel."""
    camera = ideal_camera()
    # One cell per pixel and a 1024-row period keep the turned scene small (1024 x 2048 cells;
    # the window sees rows 720 .. 900 of it).
    camera.set_scene(f"ramp:photons={PHOTONS},period=1024,oversample=1,rotation_deg={rotation_deg}")
    seen = camera.expected_electrons(T0_S, dtype=np.float64) / ramp_step(camera, 1024)
    inner = seen[:, EDGE_COLS:-EDGE_COLS]
    across = inner - inner[:, :1]
    want = np.arange(across.shape[1]) * math.sin(math.radians(rotation_deg))
    assert np.max(np.abs(across - want)) < 1e-6
    later_s = T0_S + camera.sensor.timing().tdi_line_period_s
    later = camera.expected_electrons(later_s, dtype=np.float64) / ramp_step(camera, 1024)
    assert np.max(np.abs((later - seen)[:, EDGE_COLS:-EDGE_COLS] - 1.0)) < 1e-6


@pytest.mark.parametrize("rotation_deg", [-1.0, 0.3, 1.0])
def test_rotation_moves_the_image_tan_r_columns_per_row(
    rotation_deg: float, tmp_path: Path
) -> None:
    """Scenes that ramp along the turned sensor's columns and rows (``tilted_ramp``): the
    image moves ``sin r`` columns and ``cos r`` rows per line, ``tan r`` columns per row."""
    camera = ideal_camera()
    camera.set_scene(
        f"image:path={tilted_ramp(tmp_path, rotation_deg, 1)},photons={PHOTONS},"
        f"rotation_deg={rotation_deg}"
    )
    across = motion_per_line(camera, axis=1, lines=4)
    camera.set_scene(
        f"image:path={tilted_ramp(tmp_path, rotation_deg, 0)},photons={PHOTONS},"
        f"rotation_deg={rotation_deg}"
    )
    period_s = camera.sensor.timing().tdi_line_period_s
    # The ramp's step per row is known (the image's own scale): no rolling-shutter question.
    step = ramp_step(camera, TILT_SCALE)
    first = camera.expected_electrons(T0_S, dtype=np.float64) / step
    later = camera.expected_electrons(T0_S + 4 * period_s, dtype=np.float64) / step
    along = ((later - first) / 4)[:, EDGE_COLS:-EDGE_COLS]
    r = math.radians(rotation_deg)
    # Bilinear cells and the render's linear column interpolation are exact on a ramp.
    assert np.max(np.abs(across - math.sin(r))) < 1e-6
    assert np.max(np.abs(along - math.cos(r))) < 1e-6
    assert np.max(np.abs(across / along - math.tan(r))) < 1e-6


def test_stage_yaw_turns_the_motion_with_the_travel(across_ramp: Path) -> None:
    """The image's sideways motion per line is sin(k x) at stage travel x (from position 0)."""
    yaw_deg_per_m = 50.0
    camera = ideal_camera()
    camera.set_scene(f"image:path={across_ramp},photons={PHOTONS},yaw_deg_per_m={yaw_deg_per_m}")
    timing = camera.sensor.timing()
    rows_per_m = camera.profile.magnification.value / camera.profile.pitch_m.value
    speed_m_s = camera.synchronous_speed_m_s()
    kappa = math.radians(yaw_deg_per_m)
    # 4 mm and 50 mm of travel (a 64-row window's line period: 83 mm/s): 0.2 and 2.5 degrees,
    # the image 0.4 and 10 columns aside by then (inside EDGE_COLS).
    for t0_s in (0.05, 0.6):
        charge = [
            camera.expected_electrons(t0_s + n * timing.tdi_line_period_s, dtype=np.float64)
            for n in (0, 1)
        ]
        step = float(np.median(np.diff(charge[0], axis=1)))
        moved = ((charge[1] - charge[0]) / step)[:, EDGE_COLS:-EDGE_COLS]
        # Each row at its own mid-exposure (rolling shutter), the travel's integral of sin.
        i = np.arange(ROWS)[:, np.newaxis]
        mid_s = t0_s + i * timing.line_period_s - timing.exposure_s / 2
        x0, x1 = speed_m_s * mid_s, speed_m_s * (mid_s + timing.tdi_line_period_s)
        want = rows_per_m * (np.cos(kappa * x0) - np.cos(kappa * x1)) / kappa
        assert np.max(np.abs(moved - want)) < 1e-6
        assert abs(float(np.mean(want)) - math.sin(kappa * speed_m_s * t0_s)) < 1e-3


@contextmanager
def fpga_model() -> Iterator[FpgaModel]:
    """An in-process FPGA with an 8-row window whose stream engine's thread is not started:
    frames are asked for here, one by one."""
    model = FpgaModel(seed=1)
    write(model.sensor, "WIN_ROWS", 8)
    model.imaging_path.engine.start = lambda **_: None  # type: ignore[method-assign]
    try:
        yield model
    finally:
        model.close()


def tdi_stream(model: FpgaModel, scene: str, frames: int) -> tuple[list[int], np.ndarray]:
    """The encoder counts and pixels of a TDI stream's first ``frames`` frames, the stepper
    stage running at a constant rate from device time 0."""
    model.camera.set_scene(scene)
    # The target rides the stepper, as MOTOR_ENABLE makes it (firmware_models.fpga_motion).
    model.camera.stage = model.motor.stage
    model.camera.stage_image_scale = model.motor.profile.image_scale(
        model.camera.profile.magnification.value
    )
    model.motor.motor_enable(0.0, enable=True)
    model.motor.motor_set_rate(0.0, rate_hz=20000.0)
    path = model.imaging_path
    geometry = path.start(device_time_s=1.0, mode="tdi", frames=0, stages=8, binning=False)
    made = [path.frame(geometry.first_counter + k) for k in range(frames)]
    path.stop()
    return [header.stage_position for header, _ in made], np.stack([p for _, p in made])


def test_the_encoder_does_not_see_the_errors() -> None:
    with fpga_model() as model:
        exact_counts, exact_frames = tdi_stream(model, "bars:lux=3", 40)
    with fpga_model() as model:
        scene = "bars:lux=3,magnification_error=0.02,rotation_deg=1,yaw_deg_per_m=20"
        counts, frames = tdi_stream(model, scene, 40)
    assert counts == exact_counts and counts[-1] > counts[0]  # the stage moved, counted alike
    assert not np.array_equal(frames, exact_frames)  # but the image went elsewhere


@pytest.mark.parametrize(
    ("text", "message"),
    [
        (
            "bars:magnification_error=0.2",
            "scene magnification_error=0.2 is invalid: magnification_error (the optics' "
            "magnification error e: the image moves (1 + e) times as far as the encoder's "
            "travel at the nominal magnification): Input should be less than or equal to 0.1",
        ),
        (
            "flat:rotation_deg=-11",
            "scene rotation_deg=-11 is invalid: rotation_deg (camera rotation about the optical "
            "axis: tan(rotation) columns across track per row of along-track motion): Input "
            "should be greater than or equal to -10",
        ),
        (
            "natural:yaw_deg_per_m=1e3",
            "scene yaw_deg_per_m=1e3 is invalid: yaw_deg_per_m (stage yaw: the direction of "
            "travel turns this much per metre of travel): Input should be less than or equal "
            "to 100",
        ),
    ],
)
def test_out_of_range_errors_are_refused_with_the_range(text: str, message: str) -> None:
    with pytest.raises(SceneSpecError) as caught:
        SceneSpec.parse(text)
    assert str(caught.value) == message


def test_a_refused_scene_leaves_the_shown_scene_alone() -> None:
    camera = ideal_camera()
    shown = camera.set_scene("bars:magnification_error=0.005")
    with pytest.raises(SceneSpecError, match="rotation_deg=12 is invalid"):
        camera.set_scene("bars:rotation_deg=12")
    assert camera.scene is shown and camera.scene.motion_errors.magnification_error == 0.005


def test_the_errors_read_back_from_the_spec_text() -> None:
    text = "bars:magnification_error=0.005,rotation_deg=0.3,yaw_deg_per_m=-2"
    spec = SceneSpec.parse(text)
    assert (spec.magnification_error, spec.rotation_deg, spec.yaw_deg_per_m) == (0.005, 0.3, -2)
    assert spec.describe() == text and SceneSpec.parse(spec.describe()) == spec


def test_image_motion_compensation_sees_the_magnification_error() -> None:
    """The full-frame ftf5066 with its charge packets clocked along with the image (IMC, the
    clock matched to the nominal speed): with ``magnification_error`` e the frame is the one
    a stage ``1 + e`` times faster gives without it, not the matched one."""
    update = {"prnu_fraction": 0.0, "dsnu_e_per_s": 0.0, "dark_current_e_per_s": 0.0}
    fields = {k: Sourced[Any](value=v, assumed="test variant") for k, v in update.items()}
    sensor = SensorModel(load_register_map("ftf5066"))
    camera = CameraModel(load_profile("ftf5066").model_copy(update=fields), sensor)
    write(sensor, "WIN_ROWS", 64)
    write(sensor, "IMC_CTRL", 2)  # electrode steps
    write(sensor, "IMC_STEP_LO", 62500)  # 0.9 mm/s on the focal plane (REN15's 9 um pixel)
    assert camera.settings().imc[:2] == ("electrode", 62500 / 25e6)  # IMC_STEP in 25 MHz clocks
    nominal_m_s = 0.9e-3 / camera.profile.magnification.value
    edge = "edge:photons=1.4e7,period=16,angle_deg=1,oversample=16,x_oversample=1"

    def frame(scene: str, speed_m_s: float) -> np.ndarray:
        camera.set_scene(scene)
        camera.stage_speed_m_s = speed_m_s
        return camera.expected_electrons(0.5, dtype=np.float64)

    with_error = frame(f"{edge},magnification_error=0.02", nominal_m_s)
    assert np.allclose(with_error, frame(edge, 1.02 * nominal_m_s), rtol=1e-9, atol=1e-6)
    assert not np.allclose(with_error, frame(edge, nominal_m_s), rtol=1e-3)
