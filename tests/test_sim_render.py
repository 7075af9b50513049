"""The simulated camera keeps the camera's time: compiled passes and blocks of frames.

The compiled kernels (firmware_models.render_numba) give the bits of their numpy references
(firmware_models.render_kernels), which do the per-pass float32 work the renderer always did;
a block of frames is the frames of one render each; the imaging pipeline makes the frames the
stream engine announces together, and they are the frames it makes one at a time; the LVDS
lane model of a block is that of its frames. How fast a frame renders is a benchmark's to say,
not a test's (`camd bench sim --kinds render`, docs/simulator.md): a time would be a busy
machine's to fail.
"""

from __future__ import annotations

import numpy as np
import pytest

from camd.sensor.profile import load_profile
from camd.sensor.regmap import load_register_map
from firmware_models import render_kernels
from firmware_models.camera import CameraModel
from firmware_models.fpga import FpgaModel
from firmware_models.lvds import DEFAULT_TRAINING_WORD, Alignment, LvdsLink
from firmware_models.lvds_training import train
from firmware_models.noise_bank import NoiseBank
from firmware_models.render_kernels import Readout, read_out, weighted_rows
from firmware_models.sensor import SensorModel


def write(sensor: SensorModel, name: str, value: int) -> None:
    sensor.spi_write(sensor.regmap.register(name).address, value)


def test_the_compiled_kernels_are_loaded() -> None:
    assert render_kernels.compiled() is not None  # numba is a dependency: the fast path runs


@pytest.mark.parametrize("one_column", [True, False])
@pytest.mark.parametrize("shift_bits", [0, 2])
@pytest.mark.parametrize("gain_dn_per_e", [0.1234, 0.3])  # full well clips first; the ADC does
def test_compiled_readout_gives_the_bits_of_the_numpy_reference(
    one_column: bool, shift_bits: int, gain_dn_per_e: float
) -> None:
    rng = np.random.default_rng(7)
    frames, rows, cols = 3, 24, 256
    width = 1 if one_column else cols
    # Photons from none to far beyond full well, maps as window views of larger arrays
    # (strided rows), a filter's transmission per row; black level 0, so read noise clips at 0.
    photons = (10.0 ** rng.uniform(-3.0, 6.0, (frames * rows, width))).astype(np.float32)
    response = (0.6 + 0.01 * rng.standard_normal((rows + 8, cols + 40))).astype(np.float32)
    dark = (20.0 + 2.0 * rng.standard_normal((rows + 8, cols + 40))).astype(np.float32)
    row_factor = rng.uniform(0.2, 1.0, frames * rows).astype(np.float32)
    readout = Readout(225.0, 20000.0, gain_dn_per_e, 0.0, 4095, shift_bits)
    noise = NoiseBank(3).take(np.random.default_rng(1), frames, rows * cols)
    args = (photons, response[4 : 4 + rows, 20 : 20 + cols], dark[4 : 4 + rows, 20 : 20 + cols])
    fast, fast_max = read_out(*args, row_factor, 0.01, noise, readout)
    slow, slow_max = read_out(*args, row_factor, 0.01, noise, readout, use_compiled=False)
    assert np.array_equal(fast, slow)
    assert list(fast_max) == list(slow_max) == [int(f.max()) for f in fast.reshape(frames, -1)]
    top = min(round(20000.0 * np.float32(gain_dn_per_e)), 4095) >> shift_bits
    assert fast.min() == 0 and fast.max() == top  # both clips were reached


def test_compiled_scene_rows_give_the_bits_of_the_numpy_reference() -> None:
    rng = np.random.default_rng(2)
    table = rng.uniform(0.0, 1e6, (160, 512)).astype(np.float32)
    cell_index = (rng.integers(0, 150, (40, 1)) + np.arange(7)).astype(np.int64)
    weights = rng.uniform(0.0, 1e-3, (40, 7)).astype(np.float32)
    fast = weighted_rows(table, cell_index, weights)
    assert np.array_equal(fast, weighted_rows(table, cell_index, weights, use_compiled=False))


def camera(name: str, rows: int, *, seed: int = 0) -> CameraModel:
    sensor = SensorModel(load_register_map(name))
    write(sensor, "WIN_ROWS", rows)
    return CameraModel(load_profile(name), sensor, seed=seed)


@pytest.mark.parametrize(
    ("name", "scene"),
    [
        ("hr400", "bars:lux=3,drift_deg=0.5"),  # rolling shutter, drift: columns interpolated
        ("hr400", "natural"),  # one cell per pixel
        ("uvccd", "edge:photons=1e7,angle_deg=5"),  # frame transfer
        ("ibis5", "flat"),  # one column: the same value across each row
    ],
)
def test_a_block_of_frames_is_the_frames_of_one_render_each(name: str, scene: str) -> None:
    block_camera, single_camera = camera(name, 16, seed=4), camera(name, 16, seed=4)
    for cam in (block_camera, single_camera):
        cam.set_scene(scene)
        cam.stage_speed_m_s = 1.03 * cam.synchronous_speed_m_s()  # 3 % too fast: motion blur
    times = 0.25 + 1.7e-3 * np.arange(12)
    frames, maxima = block_camera.render_block(times)
    singles = np.stack([single_camera.render(float(t)) for t in times])
    assert frames.shape == (12, 16, block_camera.columns)
    assert np.array_equal(frames, singles)
    assert list(maxima) == [int(f.max()) for f in singles]
    assert not np.array_equal(frames[0], frames[1])  # the scene moved, the noise changed


def test_a_block_asks_for_each_frames_transmission_alone() -> None:
    """A filter wheel's transmission is a function of one frame's rows (its channel is the
    wheel's at that frame): a block asks for it frame by frame."""
    asked: list[int] = []

    def every_other_frame_dimmed(start_s: np.ndarray, end_s: np.ndarray) -> np.ndarray:
        asked.append(start_s.size)
        frame = round(float(end_s[0]) / 0.01)
        return np.full(start_s.shape, 0.25 if frame % 2 else 1.0)

    block_camera, single_camera = camera("hr400", 16, seed=4), camera("hr400", 16, seed=4)
    for cam in (block_camera, single_camera):
        cam.set_scene("flat:photons=1e9")
        cam.transmission = every_other_frame_dimmed
    times = 0.01 * np.arange(1, 7)
    frames, _ = block_camera.render_block(times)
    assert asked == [16] * 6
    assert np.array_equal(frames, np.stack([single_camera.render(float(t)) for t in times]))
    assert frames[1].mean() > 2 * frames[0].mean()  # frame 0 ends at 10 ms: dimmed


def test_the_pipeline_makes_announced_frames_together_and_the_same() -> None:
    """hr400 at M = 8 (164 us frames, the engine's blocks of six): frames made as the stream
    engine announces them (``prepare``, then one ``frame`` call each) are the frames made one
    at a time, header and pixels; a register written while streaming takes effect at the
    frame whose start follows it, also in the middle of an announced block."""
    models = [FpgaModel(seed=1), FpgaModel(seed=1)]
    got: list[list[tuple[object, bytes]]] = [[], []]
    for model, frames in zip(models, got, strict=True):
        write(model.sensor, "WIN_ROWS", 8)
        model.camera.set_scene("bars:photons=2e8")  # 5,000 e- in the 41 us exposure
        assert model.sensor_link.train().locked
        path = model.imaging_path
        # Unpaced with no host connected, the engine makes no frames itself (it waits for a
        # host): the test asks for them, as the engine would, and the stream is on.
        path.unpaced = True
        geometry = path.start(device_time_s=1.0, mode="tdi", frames=0, stages=8, binning=False)
        first = geometry.first_counter
        for block in range(8):
            if block == 4:  # analog x2 from frame 26 on (after 25.5 periods), block 4's third
                with model.lock:
                    write(model.sensor, "GAIN", (1 << 8) | 64)
                    path.note_registers(1.0 + 25.5 * geometry.frame_period_s)
            counters = range(first + 6 * block, first + 6 * block + 6)
            if model is models[0]:
                path.prepare(counters[0], 6)
            for counter in counters:
                header, pixels = path.frame(counter)
                frames.append((header, pixels.tobytes()))
        model.close()
    assert got[0] == got[1]
    signal = [np.frombuffer(b, dtype=np.uint16).mean() - 100.0 for _, b in got[0]]
    assert signal[26] == pytest.approx(2 * signal[25], rel=0.05)  # the gain, from frame 26


def test_the_lane_model_of_a_block_is_that_of_its_frames() -> None:
    """A link trained but off by a bit on some lanes (no metastable samples: no noise drawn):
    the block's scrambled frames are each frame's; and a bit-exact alignment is recognised."""
    link = LvdsLink(seed=3)
    rng = np.random.default_rng(0)
    frames = rng.integers(0, 4096, (5, 6, 64), dtype=np.uint16)
    exact = train(link, DEFAULT_TRAINING_WORD, rng_seed=1).alignment
    assert link.bit_exact(exact)
    assert np.array_equal(link.receive_block(frames, exact), frames)
    skewed = Alignment(list(exact.taps), list(exact.slips), list(exact.shifts), exact.latency)
    skewed.slips[2] = (skewed.slips[2] + 1) % 12
    assert not link.bit_exact(skewed)
    block = link.receive_block(frames, skewed)
    assert np.array_equal(block, np.stack([link.receive(f, skewed) for f in frames]))
    assert not np.array_equal(block, frames)


def test_a_warm_up_changes_no_frame() -> None:
    """``CameraModel.warm_up`` (a simulator's first-frame work, done when it starts) draws
    nothing from the temporal noise stream and grows the noise bank only with the values
    frames of that size take: a warmed camera makes the frames a cold one makes, also after
    the window shrinks (a TDI window after the default one)."""
    warm, cold = camera("hr400", 534, seed=2), camera("hr400", 534, seed=2)
    warm.warm_up()  # the default window: its noise bank is larger than a TDI window's
    assert render_kernels.compiled() is not None
    for cam in (warm, cold):
        cam.set_scene("bars:lux=3")
        write(cam.sensor, "WIN_ROWS", 64)
    assert np.array_equal(warm.render_block([0.1, 0.2])[0], cold.render_block([0.1, 0.2])[0])
    for cam in (warm, cold):
        write(cam.sensor, "WIN_ROWS", 534)
    assert np.array_equal(warm.render(0.3), cold.render(0.3))


def test_the_optics_blur_is_in_what_the_camera_renders() -> None:
    # blur_px is applied to the scene the camera integrates (area frames, stares, wheel and TDI
    # scans all render from it): a bar group at 0.25 cycles/pixel keeps exp(-2 pi^2 2^2 0.25^2)
    # = 0.7 % of its modulation under a 2-pixel blur, and the light is kept.
    cam = camera("hr400", 40)
    cam.set_scene("bars:photons=1e8")
    sharp = cam.expected_dn(0.01)
    cam.set_scene("bars:photons=1e8,blur_px=2")
    blurred = cam.expected_dn(0.01)
    column = 1000  # in the fourth of seven groups across 2048 columns: 0.25 cycles/pixel
    assert np.ptp(sharp[:, column]) > 50  # DN between bright and dark bars
    assert np.ptp(blurred[:, column]) < 0.05 * np.ptp(sharp[:, column])
    assert blurred.mean() == pytest.approx(sharp.mean(), rel=0.01)
