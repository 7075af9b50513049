"""The FPGA's imaging path: sensor frames through the LVDS link, binning, the USB stream.

``ImagingPipeline`` is what START_STREAM starts. For every frame it asks the camera model
(``firmware_models.camera``: scene, stage, sensor physics) for the window frame the sensor's
registers set, receives it through the LVDS link's current alignment (an untrained or
mis-trained link garbles it, as on the bench), bins it 2x2 if asked (docs/physics.md §3), stamps the
header of docs/stream.md and hands it to the stream engine (``firmware_models.fx3``), which
paces, injects faults and sends it on the bulk endpoint.

Frame k of a stream that started at device time t0 starts its exposure (window row 0's reset)
at ``t_k``: ``t_0 = t0`` and ``t_(k+1) = t_k + T_frame``, T_frame the frame period the
registers set when frame k was made (the TDI line period, docs/physics.md §2 eqs 6-7; a host may
re-program the back path while streaming to trim it). So the scene's motion and every timestamp
follow model time, not how fast this process happens to render. A wheel acquisition instead
gives each frame's start time (``schedule_s``): it waits for the wheel. Frames are made when
the engine asks, which may be later than their model time (a slow render): register writes the
FPGA receives while streaming are therefore kept with their device time (``note_registers``)
and a frame uses the registers that were in force at its own start (a change made by another
path, the USB-SPI bridge's own bus, takes effect from the next frame made). The header's
timestamp
is when row 0's exposure ends, ``t_k + exposure``; its ``stage_position`` is the stage encoder
latched at ``t_k`` (``encoder_at``), or the wheel angle for wheel frames.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from camd.protocol.stream import FrameFlags, FrameHeader, StreamMode, frame_header
from camd.tdi.binning import bin2x2
from firmware_models.camera import CameraModel
from firmware_models.defects import FRAME_PERIOD_FACTOR, HEADER_PERIOD_FACTOR, NONE
from firmware_models.fx3 import StreamEngine
from firmware_models.sensor import SensorModel
from firmware_models.sensor_link import SensorLink

NS_PER_S = 1_000_000_000
# Encoder counts are looked up for the frames starting within this much model time of the one
# being made, at most ENCODER_BLOCK_FRAMES of them: one stage look-up costs about the same for
# one time as for 64, and a command in between (a new revision) makes the rest looked up again.
ENCODER_AHEAD_S = 2e-3
ENCODER_BLOCK_FRAMES = 64
# The frames the stream engine makes together (``prepare``: those due within ``BLOCK_S``)
# are rendered together, in blocks of at most this many pixels (frames x window pixels; a
# larger frame alone): the per-frame cost of a render (about 1 ms of Python, against the
# hr400's 41 us line period at one row) is paid once per block.
RENDER_BLOCK_PIXELS = 1 << 18


class StreamRefused(ValueError):
    """START_STREAM cannot run with these settings; the message says what to change."""


@dataclass(frozen=True, slots=True)
class StreamGeometry:
    """What one stream's frames look like (START_STREAM's answer)."""

    mode: str
    rows: int
    cols: int
    bits: int
    frame_period_s: float
    first_counter: int
    stages: int
    binning: bool


class ImagingPipeline:
    """Frames from the camera model, through the link and binning, into the stream engine.

    ``lock`` is the FPGA's lock: register state is read under it, so a frame never mixes the
    registers of before and after a command.
    """

    def __init__(
        self,
        camera: CameraModel,
        sensor: SensorModel,
        sensor_link: SensorLink,
        engine: StreamEngine,
        *,
        lock: threading.RLock,
    ) -> None:
        self.camera = camera
        self.sensor = sensor
        self.sensor_link = sensor_link
        self.engine = engine
        self.lock = lock
        self.geometry: StreamGeometry | None = None
        self.defects = NONE  # deliberate defects (firmware_models.defects), off
        # Stage encoder counts at device times, latched into each frame header (None: 0), and
        # the revision of what the stage was commanded: counts looked up at one revision hold
        # until it changes.
        self.encoder_at: Callable[[Sequence[float]], list[int]] | None = None
        self.encoder_revision: Callable[[], int] = lambda: 0
        self._encoder_ahead: dict[float, int] = {}  # frame start time -> its count
        self._encoder_ahead_revision = -1
        # Start time of frame k (row 0's reset) for the frame made next, and k.
        self._next_k = 0
        self._next_start_s = 0.0
        self._period_s = 0.0
        self._schedule: Sequence[float] | None = None
        self._stamps: Sequence[int] | None = None
        # (device time, register snapshot) of every change during the stream, oldest first.
        self._history: list[tuple[float, SensorModel]] = []
        self._rendered_s = -math.inf  # start time of the last frame made
        self._mode = StreamMode.AREA
        self._adc_max = 0
        # Replay: render the first ``frame_bank`` frames of a stream, then send them again in a
        # loop (fresh headers), for throughput tests at line rates the renderer cannot reach.
        self.frame_bank = 0
        # Benchmarks: frames as fast as the host takes them, not on the sensor's clock.
        self.unpaced = False
        self._bank: dict[int, tuple[npt.NDArray[np.uint16], FrameFlags]] = {}
        # Frames the engine announced it will ask for next (``prepare``), and frames made
        # ahead in a block, waiting to be asked for: counter -> frame.
        self._announced: tuple[int, int] = (0, 0)  # (first counter, count)
        self._ready_window: tuple[int, int, int, int] | None = None  # warmed for (ready)
        self._made: dict[int, tuple[FrameHeader, npt.NDArray[np.uint16]]] = {}

    @property
    def streaming(self) -> bool:
        return self.engine.running

    @property
    def next_counter(self) -> int:
        """The counter the next frame gets (the current stream's frames all counted)."""
        if self.geometry is None:
            return self.engine.next_counter
        return (self.geometry.first_counter + self.engine.frames_produced) % (1 << 32)

    def start(
        self,
        *,
        device_time_s: float,
        mode: str,
        frames: int,
        stages: int,
        binning: bool,
        schedule_s: Sequence[float] | None = None,
        stamps: Sequence[int] | None = None,
        end_after: int | None = None,
    ) -> StreamGeometry:
        """Check the settings against the registers, then start the engine. ``device_time_s``
        (seconds since power-on, passed in: the model never reads a clock) is when START_STREAM
        arrived: frame 0 starts its exposure then, frame k one frame period after frame k - 1.
        ``schedule_s`` (one start time per frame, ``frames`` of them) replaces that clock, with
        ``stamps`` the header's stage_position of each frame; such a stream is not paced in
        wall time (the simulator does not wait for the wheel). ``end_after``: the camera ends
        the stream after that many frames (SIM_FAIL_NEXT end_stream; ``StreamEngine.start``)."""
        if schedule_s is not None and (len(schedule_s) != frames or frames == 0):
            raise StreamRefused(f"a schedule needs one start time per frame ({frames})")
        timing = self.sensor.timing()
        rows = timing.window_rows
        cols = self.camera.columns
        if mode == "tdi" and not 1 <= stages <= rows:
            raise StreamRefused(
                f"stages = {stages} does not fit the window of {rows} rows; "
                f"use 1..{rows} (M <= M0 = n_lines)"
            )
        if binning and (rows % 2 or cols % 2):
            raise StreamRefused(
                f"2x2 binning needs an even window; it is {rows} x {cols}: "
                "make WIN_ROWS even or stream without binning"
            )
        bits = self.camera.bits + (2 if binning else 0)
        geometry = StreamGeometry(
            mode=mode,
            rows=rows // 2 if binning else rows,
            cols=cols // 2 if binning else cols,
            bits=bits,
            frame_period_s=timing.frame_period_s,
            first_counter=self.next_counter,
            stages=stages if mode == "tdi" else 0,
            binning=binning,
        )
        self.geometry = geometry
        self._bank = {}
        self._announced = (0, 0)
        self._made = {}
        self._mode = StreamMode.TDI if mode == "tdi" else StreamMode.AREA
        self._adc_max = (1 << self.camera.bits) - 1
        self._history = [(-math.inf, self.sensor.snapshot())]
        self._noted_version = self.sensor.version
        self._rendered_s = -math.inf
        self._next_k = 0
        self._next_start_s = device_time_s if schedule_s is None else schedule_s[0]
        self.camera.stream_started(self._next_start_s)
        self._period_s = timing.frame_period_s
        self._schedule = schedule_s
        self._stamps = stamps
        self.engine.start(
            frames=frames,
            period_s=timing.frame_period_s,
            pace=schedule_s is None and not self.unpaced,
            first_counter=geometry.first_counter,
            end_after=end_after,
        )
        return geometry

    def note_registers(self, t_s: float) -> None:
        """The registers changed at device time ``t_s`` (under the FPGA's lock): frames that
        start from then on use them, frames of earlier model time the ones before."""
        if not self.streaming:
            return
        # Changes older than the last frame made can no longer matter but the latest of them.
        while len(self._history) > 1 and self._history[1][0] <= self._rendered_s:
            self._history.pop(0)
        self._history.append((t_s, self.sensor.snapshot()))
        self._noted_version = self.sensor.version

    def _registers_at(self, t_s: float) -> SensorModel:
        """The register snapshot in force at model time ``t_s``."""
        chosen = self._history[0][1]
        for changed_s, snapshot in self._history:
            if changed_s > t_s:
                break
            chosen = snapshot
        return chosen

    def stop(self) -> tuple[int, int]:
        """Stop after the frame in progress; (frames produced, next counter). Never waits for
        the engine's thread (the caller may hold the lock ``frame`` takes). The caller reports
        the end (STOP_STREAM's acknowledge, or its own event): no STREAM_DONE from here."""
        produced = self.engine.stop(notify=False)
        return produced, self.next_counter

    def ready(self) -> None:
        """The stream engine's ``ready``: the camera's first-frame work for the present window
        (``CameraModel.warm_up``), once per window, before a stream's clock starts. Not under
        the FPGA's lock, which commands need meanwhile (the work changes no register state)."""
        with self.lock:
            window = self.camera.window()
        if window != self._ready_window:
            self.camera.warm_up()
            self._ready_window = window

    def prepare(self, first_counter: int, count: int) -> None:
        """The stream engine will ask for frames ``first_counter`` .. ``+ count - 1`` next (all
        due already): ``frame`` makes them in blocks (``RENDER_BLOCK_PIXELS``)."""
        self._announced = (first_counter % (1 << 32), count)

    def frame(self, counter: int) -> tuple[FrameHeader, npt.NDArray[np.uint16]]:
        """The stream engine's source: frame ``counter`` of the running stream."""
        geometry = self.geometry
        assert geometry is not None
        counter %= 1 << 32
        made = self._made.pop(counter, None)
        if made is not None:
            return made
        self._made.clear()  # made ahead but not asked for: the stream was stopped or restarted
        k = (counter - geometry.first_counter) % (1 << 32)
        first, announced = self._announced
        ahead = (counter - first) % (1 << 32)
        count = 1
        if ahead < announced:
            window_pixels = max(1, self.camera.rows * self.camera.columns)
            count = max(1, min(announced - ahead, RENDER_BLOCK_PIXELS // window_pixels))
        frames = self._make(k, count)
        for i, made in enumerate(frames[1:], start=1):
            self._made[(counter + i) % (1 << 32)] = made
        return frames[0]

    def _make(self, k0: int, count: int) -> list[tuple[FrameHeader, npt.NDArray[np.uint16]]]:
        """Frames ``k0 .. k0 + count - 1`` of the stream, each with the registers in force at
        its own start; frames with the same registers are rendered in one go."""
        geometry = self.geometry
        assert geometry is not None
        clock = [self._frame_start(k) for k in range(k0, k0 + count)]
        with self.lock:
            registers = [self._registers_at(start_s) for start_s, _ in clock]
            self._rendered_s = max(self._rendered_s, clock[-1][0])
        made: list[tuple[FrameHeader, npt.NDArray[np.uint16]]] = []
        i = 0
        while i < count:
            j = i + 1  # frames i .. j - 1 share their registers
            while j < count and registers[j] is registers[i]:
                j += 1
            exposure_s = registers[i].timing().exposure_s
            times = [start_s + exposure_s for start_s, _ in clock[i:j]]
            if self.frame_bank:
                rendered = [
                    self._banked(k0 + i + n, t_s, geometry, registers[i])
                    for n, t_s in enumerate(times)
                ]
            else:
                rendered = self._render(times, geometry, registers[i])
            stamped = HEADER_PERIOD_FACTOR if self.defects.header_line_period_1pct else 1.0
            for n, (pixels, flags) in enumerate(rendered):
                start_s, period_s = clock[i + n]
                header = frame_header(
                    pixels,
                    counter=geometry.first_counter + k0 + i + n,
                    timestamp_ns=round(times[n] * NS_PER_S),
                    # header_line_period_1pct: a header field stamped wrong, the frame right.
                    line_period_ns=round(period_s * NS_PER_S * stamped),
                    bits=geometry.bits,
                    mode=self._mode,
                    stages=geometry.stages,
                    stage_position=self._stage_position(k0 + i + n, start_s),
                    flags=flags,
                )
                made.append((header, pixels))
            i = j
        return made

    def _banked(
        self, k: int, t_s: float, geometry: StreamGeometry, registers: SensorModel
    ) -> tuple[npt.NDArray[np.uint16], FrameFlags]:
        """Frame k from the replay bank: rendered the first time round, replayed after."""
        banked = self._bank.get(k % self.frame_bank)
        if banked is None:
            banked = self._render([t_s], geometry, registers)[0]
            self._bank[k % self.frame_bank] = banked
        return banked

    def _frame_start(self, k: int) -> tuple[float, float]:
        """(start time, frame period) of frame k. Frames are made in order, so the clock
        advances one frame at a time with the period the registers hold when each is made."""
        if self._schedule is not None:
            start = self._schedule[min(k, len(self._schedule) - 1)]
            return start, self._period_s
        while self._next_k <= k:
            start = self._next_start_s
            with self.lock:
                if self.sensor.version != self._noted_version:
                    # Written by a path that gave no time (the USB-SPI bridge's own SPI bus):
                    # in force from this frame on.
                    self.note_registers(max(start, self._history[-1][0]))
                period = self._registers_at(start).timing().frame_period_s
            if period != self._period_s:
                self._period_s = period
                self.engine.set_period(period)
            # frame_period_5pct: a slow line clock spaces the frames out; the firmware still
            # believes (and stamps in the header) the period the registers set.
            slow = FRAME_PERIOD_FACTOR if self.defects.frame_period_5pct else 1.0
            self._next_start_s = start + period * slow
            self._next_k += 1
        return start, self._period_s

    def _stage_position(self, k: int, start_s: float) -> int:
        """The header's stage_position: the scheduled stamp, or the encoder at frame start."""
        if self._stamps is not None:
            return int(self._stamps[min(k, len(self._stamps) - 1)])
        if self.encoder_at is None:
            return 0
        with self.lock:
            revision = self.encoder_revision()
            count = self._encoder_ahead.get(start_s)
            if count is None or revision != self._encoder_ahead_revision:
                count = self._look_up_encoder(start_s, revision)
        # The header field is a signed 32-bit count; an encoder wraps like the hardware's.
        return (count + (1 << 31)) % (1 << 32) - (1 << 31)

    def _look_up_encoder(self, start_s: float, revision: int) -> int:
        """The encoder count at ``start_s``, looked up with those of the frames that follow
        it within ENCODER_AHEAD_S at the present frame period: one stage look-up for a block
        of frames (docs/simulator.md, "Speed"). A frame finds its count again only at the
        same revision (no command since) and at exactly the start time predicted, the sum
        ``_frame_start`` makes, so the counts are those a look-up per frame would give."""
        assert self.encoder_at is not None
        period = self._period_s
        n = 1 if period <= 0 else max(1, min(ENCODER_BLOCK_FRAMES, int(ENCODER_AHEAD_S / period)))
        times = [start_s]
        for _ in range(n - 1):
            times.append(times[-1] + period)
        counts = self.encoder_at(times)
        self._encoder_ahead = dict(zip(times, counts, strict=True))
        self._encoder_ahead_revision = revision
        return counts[0]

    def _render(
        self, times: list[float], geometry: StreamGeometry, registers: SensorModel
    ) -> list[tuple[npt.NDArray[np.uint16], FrameFlags]]:
        """The window frames at ``times`` with those registers, through the link and binning,
        with their flags."""
        # Not under the lock: a render takes milliseconds, and commands (the stage's closed
        # loop polls every 10 ms) must not wait for it.
        raw, maxima = self.camera.render_block(times, sensor=registers)
        count = len(times)
        with self.lock:
            received = self.sensor_link.capture_block(raw, int(maxima.max()))
            self.sensor.note_frame(count)
        if received is not raw:
            maxima = received.reshape(count, -1).max(axis=1)
        flags = FrameFlags(0)
        if self.camera.settings(registers).test_pattern is not None:
            flags |= FrameFlags.TEST_PATTERN
        pixels = np.ascontiguousarray(received, dtype=np.uint16)
        if geometry.binning:
            pixels = bin2x2(pixels).astype(np.uint16)
            flags |= FrameFlags.BINNED_2X2
        saturated = maxima >= self._adc_max
        return [
            (pixels[n], flags | FrameFlags.SATURATED if saturated[n] else flags)
            for n in range(count)
        ]
