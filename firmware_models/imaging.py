"""The FPGA's imaging path: sensor frames through the LVDS link, binning, the USB stream.

``ImagingPipeline`` is what START_STREAM starts. For every frame it asks the camera model
(``firmware_models.camera``: scene, stage, sensor physics) for the window frame the sensor's
registers set, receives it through the LVDS link's current alignment (an untrained or
mis-trained link garbles it, as on the bench), bins it 2x2 if asked (physics.md §3), stamps the
header of docs/stream.md and hands it to the stream engine (``firmware_models.fx3``), which
paces, injects faults and sends it on the bulk endpoint.

Frame k of a stream that started at device time t0 ends window row 0's exposure at
``t0 + exposure + k * T_frame`` where T_frame is the frame period the registers set (the TDI
line period, physics.md §2 eqs 6-7), so the scene's motion and every timestamp follow model
time, not how fast this process happens to render.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from camd.protocol.stream import FrameFlags, FrameHeader, StreamMode, frame_header
from camd.tdi.binning import bin2x2
from firmware_models.camera import CameraModel
from firmware_models.fx3 import StreamEngine
from firmware_models.sensor import SensorModel
from firmware_models.sensor_link import SensorLink

NS_PER_S = 1_000_000_000


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
        self._t0_s = 0.0
        self._mode = StreamMode.AREA
        self._adc_max = 0
        # Replay: render the first ``frame_bank`` frames of a stream, then send them again in a
        # loop (fresh headers), for throughput tests at line rates the renderer cannot reach.
        self.frame_bank = 0
        self._bank: dict[int, tuple[npt.NDArray[np.uint16], FrameFlags]] = {}

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
        self, *, device_time_s: float, mode: str, frames: int, stages: int, binning: bool
    ) -> StreamGeometry:
        """Check the settings against the registers, then start the engine. ``device_time_s``
        (seconds since power-on, passed in: the model never reads a clock) is when START_STREAM
        arrived; frame k's row 0 ends its exposure one exposure and k frame periods later."""
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
        self._mode = StreamMode.TDI if mode == "tdi" else StreamMode.AREA
        self._adc_max = (1 << self.camera.bits) - 1
        self._t0_s = device_time_s + timing.exposure_s
        self.engine.start(
            frames=frames,
            period_s=timing.frame_period_s,
            first_counter=geometry.first_counter,
        )
        return geometry

    def stop(self) -> tuple[int, int]:
        """Stop after the frame in progress; (frames produced, next counter). Never waits for
        the engine's thread (the caller may hold the lock ``frame`` takes). The caller reports
        the end (STOP_STREAM's acknowledge, or its own event): no STREAM_DONE from here."""
        produced = self.engine.stop(notify=False)
        return produced, self.next_counter

    def frame(self, counter: int) -> tuple[FrameHeader, npt.NDArray[np.uint16]]:
        """The stream engine's source: frame ``counter`` of the running stream."""
        geometry = self.geometry
        assert geometry is not None
        k = (counter - geometry.first_counter) % (1 << 32)
        t_s = self._t0_s + k * geometry.frame_period_s
        banked = self._bank.get(k % self.frame_bank) if self.frame_bank else None
        if banked is None:
            pixels, flags = self._render(t_s, geometry)
            if self.frame_bank:
                self._bank[k % self.frame_bank] = (pixels, flags)
        else:
            pixels, flags = banked
        header = frame_header(
            pixels,
            counter=counter,
            timestamp_ns=round(t_s * NS_PER_S),
            line_period_ns=round(geometry.frame_period_s * NS_PER_S),
            bits=geometry.bits,
            mode=self._mode,
            stages=geometry.stages,
            stage_position=0,
            flags=flags,
        )
        return header, pixels

    def _render(
        self, t_s: float, geometry: StreamGeometry
    ) -> tuple[npt.NDArray[np.uint16], FrameFlags]:
        """The window frame at ``t_s`` through the link and binning, and its flags."""
        with self.lock:
            raw = self.camera.render(t_s)
            received = self.sensor_link.capture(raw)
            self.sensor.note_frame()
        flags = FrameFlags(0)
        if int(received.max()) >= self._adc_max:
            flags |= FrameFlags.SATURATED
        if self.sensor.test_pattern not in ("off", 0):
            flags |= FrameFlags.TEST_PATTERN
        pixels = np.ascontiguousarray(received, dtype=np.uint16)
        if geometry.binning:
            pixels = bin2x2(pixels).astype(np.uint16)
            flags |= FrameFlags.BINNED_2X2
        return pixels, flags
