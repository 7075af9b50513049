"""camd.pipeline.image_motion: which frames the live monitor takes and what it makes of them.

The monitor is fed ``ReceivedFrame``s and packed ``FrameBatch``es as the stream's dispatcher
feeds them, cut from the natural texture shifted exactly (tests/test_image_motion.py's windows).
Its result for a block must be ``measure_tdi_motion``'s on that block's frames (the counters it
took, the central columns it kept); the value itself is checked against the truth within the
precision of docs/physics.md §10 (tests/test_image_motion.py holds the accuracy's own tests).
"""

from __future__ import annotations

import math
import time

import numpy as np
import numpy.typing as npt
import pytest

from camd.analysis.image_motion import ImageMotion, flat_from_mean, measure_tdi_motion
from camd.link.frame_types import ReceivedFrame
from camd.link.packed import HEADER_DTYPE, FrameBatch
from camd.pipeline.background import Background
from camd.pipeline.image_motion import ImageMotionMonitor, MotionBlock, MotionLog, summarize
from camd.protocol.stream import StreamMode, frame_header
from tests.test_image_motion import OFFSET_DN, base, noisy, shifted

ROWS = 32
STAGES = 32
DV_OVER_V = -0.012  # the image 1.2 % fast: a magnification error of +1.2 %
THETA_DEG = 0.5
ALONG = 1.0 - DV_OVER_V
ACROSS = ALONG * math.tan(math.radians(THETA_DEG))
WAIT_S = 60.0  # the worker's measurement: milliseconds idle, far longer on a loaded machine


def windows(counters: list[int], seed: int = 0) -> list[npt.NDArray[np.uint16]]:
    rng = np.random.default_rng(seed)
    return [noisy(shifted(base("natural"), c * ALONG, c * ACROSS, ROWS), rng) for c in counters]


def received(pixels: npt.NDArray[np.uint16], counter: int, mode: StreamMode) -> ReceivedFrame:
    header = frame_header(
        pixels,
        counter=counter,
        timestamp_ns=counter * 1000,
        line_period_ns=1000,
        bits=12,
        mode=mode,
        stages=STAGES if mode == StreamMode.TDI else 0,
    )
    return ReceivedFrame(header, pixels, 0, 0, counter)


def packed(frames: list[npt.NDArray[np.uint16]], first: int) -> FrameBatch:
    fields = np.zeros(len(frames), HEADER_DTYPE)
    fields["counter"] = np.arange(first, first + len(frames))
    fields["mode"] = int(StreamMode.TDI)
    fields["stages"] = STAGES
    fields["bits"] = 12
    return FrameBatch(np.stack(frames), fields, 0, 0, first)


def wait_blocks(monitor: ImageMotionMonitor, count: int) -> tuple[MotionBlock, ...]:
    deadline = time.monotonic() + WAIT_S
    while time.monotonic() < deadline:
        blocks = monitor.status().blocks
        if len(blocks) >= count:
            return blocks
        time.sleep(0.01)
    raise AssertionError(f"fewer than {count} blocks measured within {WAIT_S} s")


def test_a_block_is_the_pure_measurement_of_the_frames_it_took() -> None:
    # 8 frames a block of 32-row windows: 4 consecutive, then 4 spread up to 45 % of 32 rows
    # (offsets 0, 1, 2, 3, 4, 7, 11, 14); 128 of the 256 columns: the central ones, [64, 192).
    monitor = ImageMotionMonitor(frames_per_block=8, columns_max=128)
    try:
        counters = [c for c in range(100, 131) if c not in (104, 105)]  # 104 and 105 lost
        frames = dict(zip(counters, windows(counters), strict=True))
        for counter, pixels in frames.items():
            monitor(received(pixels, counter, StreamMode.TDI))
        (block,) = wait_blocks(monitor, 1)
    finally:
        monitor.close()
    # The lost offset 4 is taken by the next frame that came (106).
    taken = [100, 101, 102, 103, 106, 107, 111, 114]
    assert (block.counter_first, block.counter_last, block.frames) == (100, 114, 8)
    assert block.columns == (64, 192) and block.stages == STAGES
    want = measure_tdi_motion([frames[c][:, 64:192] for c in taken], taken)
    assert block.motion == want
    # Lost frames are longer baselines, not a change of speed: the truth within the precision
    # (the reported standard error; 6 of them, and the check is not the accuracy test).
    m = block.motion
    assert m.measurable and m.pairs_used == 7
    assert abs(m.dv_over_v - DV_OVER_V) < 6 * m.dv_over_v_stderr + 2e-3
    assert abs(m.shift_across_px_per_line - ACROSS) < 6 * m.shift_across_stderr_px + 2e-3
    values = block.as_dict()
    assert values["m_dv_over_v"] == pytest.approx(STAGES * m.dv_over_v, rel=1e-12)
    assert values["theta_deg"] == pytest.approx(m.theta_deg, rel=1e-12)


def test_area_frames_are_not_measured() -> None:
    monitor = ImageMotionMonitor(frames_per_block=4)
    try:
        for counter, pixels in enumerate(windows(list(range(8)))):
            monitor(received(pixels, counter, StreamMode.AREA))
        time.sleep(0.2)  # nothing is queued: the worker has nothing to do however long
        status = monitor.status()
    finally:
        monitor.close()
    assert (status.tdi_frames_seen, status.blocks_measured, status.blocks) == (0, 0, ())


def test_a_gap_with_no_overlap_starts_the_block_again() -> None:
    # 40 frames lost: no row of frame 2 is in frame 43 (32-row windows), so the block is
    # frames 43..46, not 1..2 + 43..44.
    monitor = ImageMotionMonitor(frames_per_block=4, columns_max=64)
    try:
        counters = [1, 2, 43, 44, 45, 46]
        for pixels, counter in zip(windows(counters), counters, strict=True):
            monitor(received(pixels, counter, StreamMode.TDI))
        (block,) = wait_blocks(monitor, 1)
    finally:
        monitor.close()
    assert (block.counter_first, block.counter_last) == (43, 46)


def test_packed_batches_and_the_cpu_budget() -> None:
    # A budget of a millionth of a core: after the first block (milliseconds of CPU) the next
    # may start only hours later, so the frames that follow are seen and not measured.
    # 6 frames a block: offsets 0, 1, 2, 3, 4, 14.
    monitor = ImageMotionMonitor(frames_per_block=6, columns_max=64, cpu_fraction=1e-6)
    try:
        frames = windows(list(range(10, 90)))
        for k in range(0, 80, 8):
            monitor.on_batch(packed(frames[k : k + 8], 10 + k))
            if k == 24:
                wait_blocks(monitor, 1)
        status = monitor.status()
    finally:
        monitor.close()
    assert status.blocks_measured == 1 and status.frames_measured == 6
    assert status.tdi_frames_seen == 80
    assert status.blocks[0].counter_first == 10 and status.blocks[0].counter_last == 24
    assert status.cpu_s > 0


def test_the_background_is_subtracted_when_it_has_the_frames_geometry() -> None:
    # A strong column pattern fixed to the sensor would pull the shifts to zero (physics §10);
    # the captured background removes it (its columns cut as the frames' are).
    counters = [0, 1, 2, 3, 4, 5, 7, 8, 10, 11, 13, 14]  # the offsets of 12 frames, 32 rows
    pattern = (np.arange(256) % 7 * 400).astype(np.uint16)[None, :]
    frames = [f + pattern for f in windows(counters)]
    back = np.broadcast_to(pattern + OFFSET_DN, (ROWS, 256)).astype(np.float32)
    background = Background(1, 16, ROWS, 256, "tdi", STAGES, 0, 15, 0.0, 0.0, 0.0, back)
    monitor = ImageMotionMonitor(lambda: background, frames_per_block=12, columns_max=128)
    try:
        for pixels, counter in zip(frames, counters, strict=True):
            monitor(received(pixels, counter, StreamMode.TDI))
        (block,) = wait_blocks(monitor, 1)
    finally:
        monitor.close()
    want = measure_tdi_motion([f[:, 64:192] for f in frames], counters, background=back[:, 64:192])
    assert block.motion == want
    assert abs(block.motion.dv_over_v - DV_OVER_V) < 6 * block.motion.dv_over_v_stderr + 2e-3


def test_a_log_keeps_the_blocks_of_its_recording_and_sums_them_up() -> None:
    monitor = ImageMotionMonitor(frames_per_block=5, columns_max=64)
    try:
        counters = list(range(20))
        frames = windows(counters)
        log = monitor.start_log()
        for pixels, counter in zip(frames[:10], counters[:10], strict=True):
            monitor(received(pixels, counter, StreamMode.TDI))
            if counter == 4:
                wait_blocks(monitor, 1)  # the budget's pause after a block is a few ms
                time.sleep(0.05)
        monitor.stop_log(log, wait_s=WAIT_S)
        arrays = log.arrays()
    finally:
        monitor.close()
    # The log holds what the monitor measured while it was open, as the history has it.
    blocks = [b for b in monitor.status().blocks if b.counter_first < 10]
    assert 1 <= log.count == len(blocks) <= 2 and log.latest == blocks[-1]
    assert arrays["counter_first"].tolist() == [b.counter_first for b in blocks]
    assert arrays["counter_first"][0] == 0 and arrays["counter_last"][0] == 4
    assert arrays["stages"].tolist() == [STAGES] * log.count
    assert arrays["measurable"].dtype == bool and arrays["measurable"].all()
    dv = [b.motion.dv_over_v for b in blocks]
    assert arrays["dv_over_v"].tolist() == pytest.approx(dv, rel=1e-12)
    assert arrays["theta_deg"].tolist() == pytest.approx([b.motion.theta_deg for b in blocks])
    # the log's summary is summarize's, over the same blocks
    assert log.summary() == summarize(blocks)
    summary = log.summary()
    assert summary.blocks == summary.measurable_blocks == len(dv)
    assert summary.dv_over_v_mean == pytest.approx(float(np.mean(dv)))
    assert summary.m_dv_over_v_mean == pytest.approx(STAGES * float(np.mean(dv)))


def test_a_full_log_keeps_counting_the_blocks_it_drops() -> None:
    log = MotionLog(blocks_max=100)
    nan = math.nan
    for k in range(150):
        motion = ImageMotion(1.01, 0.0, 1e-4, 1e-4, 16, 15, True, "15 pairs registered")
        if k % 3 == 0:
            motion = ImageMotion(nan, nan, nan, nan, 16, 0, False, "scene texture too low")
        log.add(MotionBlock(k, k + 15, 16, 8, 2e-3, (0, 64), float(k), 0.01, motion))
    arrays = log.arrays()
    assert (log.count, log.blocks_dropped) == (100, 50)
    assert arrays["counter_first"].tolist() == list(range(100))
    assert np.isnan(arrays["dv_over_v"][::3]).all() and not arrays["measurable"][::3].any()
    summary = log.summary()
    assert (summary.blocks, summary.measurable_blocks) == (100, 66)
    assert summary.dv_over_v_mean == pytest.approx(-0.01)
    assert summary.m_dv_over_v_mean == pytest.approx(-0.08)
    assert summary.latest is not None and summary.latest.counter_first == 149


def test_bad_settings_are_refused_with_the_range() -> None:
    with pytest.raises(ValueError, match="frames_per_block = 2: use 3 or more"):
        ImageMotionMonitor(frames_per_block=2)
    with pytest.raises(ValueError, match="cpu_fraction = 0: use 0 < cpu_fraction <= 1"):
        ImageMotionMonitor(cpu_fraction=0)


def test_a_gain_pattern_is_learnt_from_the_moving_frames_and_divided_out() -> None:
    # A 3 % pixel gain pattern (PRNU) fixed to the sensor pulls the shift towards zero
    # (docs/physics.md §10); once four blocks (64 frames) of the moving scene are averaged,
    # the monitor divides their gain pattern out of the next blocks' frames.
    rng = np.random.default_rng(7)
    gain = (1 + 0.03 * rng.standard_normal((ROWS, 256))).astype(np.float32)
    dark = np.full((ROWS, 256), OFFSET_DN, np.float32)
    background = Background(1, 16, ROWS, 256, "tdi", STAGES, 0, 15, 0.0, 0.0, 0.0, dark)
    monitor = ImageMotionMonitor(lambda: background, frames_per_block=16, columns_max=128)
    taken: list[list[int]] = []
    blocks: list[list[npt.NDArray[np.uint16]]] = []
    try:
        for b in range(6):
            counters = list(range(40 * b, 40 * b + 16))  # 16 frames of 32 rows: consecutive
            frames = [
                ((f.astype(np.float32) - OFFSET_DN) * gain + OFFSET_DN).astype(np.uint16)
                for f in windows(counters, seed=b)
            ]
            for pixels, counter in zip(frames, counters, strict=True):
                monitor(received(pixels, counter, StreamMode.TDI))
            (*_, block) = wait_blocks(monitor, b + 1)
            assert block.counter_first == counters[0] and block.counter_last == counters[-1]
            taken.append(counters)
            blocks.append([f[:, 64:192] for f in frames])
        status = monitor.status()
    finally:
        monitor.close()
    assert [b.counter_first for b in status.blocks] == [40 * b for b in range(6)]
    # Blocks 0..3 are measured as they are; block 4 with the pattern of blocks 0..3's frames.
    d = dark[:, 64:192]
    assert status.blocks[3].motion == measure_tdi_motion(blocks[3], taken[3], background=d)
    mean = sum(np.sum(np.asarray(f, np.float64), axis=0) - len(f) * d for f in blocks[:4])
    flat = flat_from_mean(mean / sum(len(f) for f in blocks[:4]))
    with_flat = measure_tdi_motion(blocks[4], taken[4], background=d, flat=flat)
    assert status.blocks[4].motion == with_flat
    without = measure_tdi_motion(blocks[4], taken[4], background=d)
    # The pattern's pull (seeded: the same numbers every run): without the flat dV/V is off by
    # 0.00066, 2.7 of its standard errors (frames registered on a reference many rows back see
    # the pattern far from their shift, so it pulls little); with the flat of four blocks by
    # 0.00023, 0.7 of them.
    assert abs(with_flat.dv_over_v - DV_OVER_V) < 0.5 * abs(without.dv_over_v - DV_OVER_V)
    assert abs(with_flat.dv_over_v - DV_OVER_V) < 2 * with_flat.dv_over_v_stderr
