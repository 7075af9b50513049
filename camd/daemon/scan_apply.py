"""A scan's plan applied step by step, each step with its undo, up to its running stream.

``ScanApply`` is handed the device access, the sensor, stream, motion and simulator services,
and the live view's background and waterfall; the scan service (``camd.daemon.scan_service``)
is handed it, takes those parts from it and shares its lock (held around the current scan, and
handed to each scan's run). It applies a plan made by ``camd.daemon.scan_planner`` through an ``Apply``
(``camd.daemon.transaction``): the scene, the TDI mode, the registers (read back: they must
set the planned timing), the simulator's ideal stage, the scan stage through
``camd.daemon.scan_motion.ScanMotion`` on the motion service's ``StageDrive`` (with the closed
loop's hand on the line period), the file (noted on the journal of open recordings first),
then the scan's run (``camd.daemon.scan_run.ScanRun``) and its stream. A step that fails puts
back what the steps before it changed, newest first, and the error says what was restored.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable
from dataclasses import KW_ONLY, dataclass, field
from typing import Any

import numpy as np

from camd.daemon.acquisition import Acquisition
from camd.daemon.device import DeviceAccess
from camd.daemon.errors import BadRequest, DeviceRejected, SessionError
from camd.daemon.models import ScanTiming
from camd.daemon.motion_service import MotionService
from camd.daemon.scan_motion import ScanMotion
from camd.daemon.scan_plan import ScanPlan, window_writes
from camd.daemon.scan_planner import PlannedScan
from camd.daemon.scan_run import ScanRun
from camd.daemon.sensor_service import SensorService
from camd.daemon.sim_control import SimulatorControl
from camd.daemon.stream_service import StreamService
from camd.daemon.transaction import Apply
from camd.motion.closed_loop import LinePeriodSetting
from camd.pipeline.background import Background, BackgroundCapture
from camd.pipeline.image_motion import ImageMotionMonitor
from camd.pipeline.live import LiveLines
from camd.store.durability import FLUSH_PERIOD_S
from camd.store.journal import RecordingJournal
from camd.store.recording import RecordingError
from camd.store.tdi_layout import MODES, chunk_lines_for
from camd.store.tdi_recording import TdiRecorder


@dataclass(eq=False)
class ScanApply:
    """Apply scan plans, with their undo (module docstring)."""

    device: DeviceAccess
    sensor: SensorService
    stream: StreamService
    motion: MotionService
    sim: SimulatorControl
    _: KW_ONLY
    background: BackgroundCapture | None  # the live view's, stored in the scan's file when ready
    live_lines: LiveLines | None  # the live view's waterfall (None: no live lines)
    # The image's motion from blocks of the scan's frames, for its file and status.
    image_motion: ImageMotionMonitor | None = None
    # The scan service's lock too, handed to each scan's run.
    lock: threading.Lock = field(default_factory=threading.Lock, init=False)

    def apply(
        self,
        planned: PlannedScan,
        acquisition: Acquisition,
        running: Callable[[ScanRun], None],
    ) -> ScanRun:
        """Change the camera as planned, step by step, and start the stream; ``running(scan)``
        is told once its stream runs, before the last of its setup (a failure after it is
        still undone). On a failure the steps done so far are undone (newest first) and the
        error says what was restored."""
        plan, snapshot, stage_position = planned.plan, planned.snapshot, planned.stage_position_m
        device, sim, sensor = self.device, self.sim, self.sensor
        with Apply("scan start", self._events, source="scan") as apply:
            if plan.request.scene is not None:
                scene, before = plan.request.scene, sim.scene
                apply.step(
                    lambda: sim.set_scene(scene), lambda: sim.set_scene(before), f"scene {before}"
                )
            if device.mode != "tdi":
                mode = device.mode or "area"
                apply.step(
                    lambda: device.set_mode("tdi"), lambda: device.set_mode(mode), f"mode {mode}"
                )
            if plan.register_writes:
                changed = snapshot.changed(plan.register_writes)
                apply.step(
                    lambda: sensor.write(plan.register_writes),
                    lambda: sensor.restore(snapshot, changed),
                    "registers " + ", ".join(changed or list(plan.register_writes)),
                )
                self._check_timing(plan)
            if plan.ideal_stage_speed_m_s is not None:
                track, speed = sim.ideal_stage
                apply.step(
                    lambda: sim.set_ideal_stage(
                        track=False, speed_m_s=plan.ideal_stage_speed_m_s or 0
                    ),
                    lambda: sim.set_ideal_stage(track=track, speed_m_s=speed),
                    "the simulator's ideal stage",
                )
            motion = None
            if plan.stage is not None:
                motion = ScanMotion(
                    self.motion.scan_drive(),
                    plan.stage,
                    device.config.motion,
                    self._line_period_writer(plan.timing),
                )
                apply.undo_later(
                    lambda: motion.restore(stage_position),
                    f"stage stopped and back at {stage_position * 1e3:.3f} mm",
                )
                motion.start()
            background = self.background.ready() if self.background is not None else None
            recorder = self._recorder(plan, background)
            apply.undo_later(
                lambda: _discard(recorder, self.device.recordings), f"file {plan.path} removed"
            )
            scan = ScanRun(
                plan,
                motion,
                recorder,
                acquisition,
                device=device,
                stream=self.stream,
                live_lines=self.live_lines,
                lock=self.lock,
                image_motion=self.image_motion,
                line_period_writer=self._line_period_writer(plan.timing)
                if plan.image_loop
                else None,
            )
            if self.live_lines is not None:
                self.live_lines.reset(plan.columns, scan=str(plan.path), lines_planned=plan.frames)
            scan.start_stream(plan.rows, plan.columns)
            if background is not None:
                assert self.background is not None
                self.background.note_saved(background, str(plan.path))
            running(scan)
            for note in plan.notes:
                device.log_event("info", "scan", note)
            apply.done()
        return scan

    def _events(self, level: str, source: str, message: str) -> None:
        self.device.log_event(level, source, message)

    def _check_timing(self, plan: ScanPlan) -> None:
        """The registers read back set the planned timing (else the plan is not what runs)."""
        now = self.sensor.timing()
        want = plan.timing
        if now.window_rows != want.n_lines or not math.isclose(
            now.tdi_line_period_s, want.tdi_line_period_s, rel_tol=1e-9
        ):
            raise DeviceRejected(
                f"the registers read back set a {now.window_rows}-row window and a "
                f"{now.tdi_line_period_s * 1e6:.3f} us line period, not the planned "
                f"{want.n_lines} rows and {want.tdi_line_period_s * 1e6:.3f} us; check "
                "`camctl timing` and the register map",
                "TIMING_MISMATCH",
            )

    def _line_period_writer(self, timing: ScanTiming) -> Callable[[LinePeriodSetting], None]:
        """The closed loop's hand on the line period: window rows and back path registers,
        written only when they change (docs/physics.md §2 eqs 8-9)."""
        sensor = self.sensor
        clock_hz = sensor.regmap.timing.clock_hz
        last = [timing.n_lines, round(timing.back_path_s * clock_hz)]

        def apply(setting: LinePeriodSetting) -> None:
            clocks = round(setting.back_path_s * clock_hz)
            if [setting.n_lines, clocks] == last:
                return
            now = sensor.timing()
            writes, _ = window_writes(sensor.regmap, now, setting.n_lines, setting.back_path_s)
            writes.pop(sensor.regmap.role("exposure_lines") or "", None)
            if writes:
                sensor.trim(writes)
            last[:] = [setting.n_lines, clocks]

        return apply

    def _recorder(self, plan: ScanPlan, background: Background | None = None) -> TdiRecorder:
        """The scan's file, noted on the journal of open recordings before it is made."""
        sensor = self.sensor
        request = plan.request
        scan_meta = request.model_dump(exclude={"out"})
        scan_meta.update(frames_requested=plan.frames, width=plan.columns)
        # On the journal before the file exists: a daemon killed at any point after leaves an
        # entry, and the next one repairs the file (or finds it was never made).
        journal = self.device.recordings
        try:
            journal.opened(plan.path, "scan")
        except OSError as exc:
            raise SessionError(
                f"cannot note the scan in {journal.folder}: {exc}; check the data directory"
            ) from None
        lines_bytes = plan.columns * np.dtype(MODES[request.mode]).itemsize  # one line, stored
        try:
            recorder = TdiRecorder(
                plan.path,
                width=plan.columns,
                mode=request.mode,
                metadata={
                    "profile": sensor.profile_metadata(),
                    "registers": sensor.register_values(),
                    "timing": plan.timing.model_dump(),
                    "scan": scan_meta,
                    **self._file_context(request.scene),
                },
                background_dn=None if background is None else background.pixels,
                background_attrs=None if background is None else background.recording_attrs(),
                chunk_lines=chunk_lines_for(plan.timing.tdi_line_period_s, FLUSH_PERIOD_S),
                compression=self.device.config.store.compression_for(
                    request.compression,
                    request.compression_level,
                    mbyte_s=lines_bytes / plan.timing.tdi_line_period_s / 1e6,
                ),
            )
        except (RecordingError, ValueError) as exc:
            journal.closed(plan.path)  # no file was left (TdiRecorder removes what it began)
            raise BadRequest(str(exc)) from None
        return recorder

    def _file_context(self, scene: str | None) -> dict[str, dict[str, Any]]:
        """The scan file's context (``DeviceAccess.file_context``), with the scene the scan
        asks for (set while the scan starts, maybe after this file is made)."""
        context = self.device.file_context()
        if scene is not None:
            context["sample"] = {"scene": scene}
        return context


def _discard(recorder: TdiRecorder, journal: RecordingJournal) -> None:
    """Close and delete a scan file that never got a line (a scan that did not start)."""
    try:
        recorder.close({"state": "failed"}, {})
    finally:
        recorder.path.unlink(missing_ok=True)
        journal.closed(recorder.path)
