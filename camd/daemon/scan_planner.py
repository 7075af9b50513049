"""A scan request made into a plan: what the plan needs read once, then planned; nothing changed.

``ScanPlanner`` is handed the sensor, motion and simulator services and the live view's
background. For a scan request it reads the registers (``SensorService.snapshot``), the stage
as it stands when the scan drives it (``MotionService.stage_context``) and the camera's optics,
plans the whole scan from them (``camd.daemon.scan_plan.plan_scan``: line period, window,
register writes, synchronous speed, travel, file), loads the TDI kernel the scan will run, and
checks that the file fits on its disk. Any of these refuses the scan before anything is
changed (the daemon's own data folder is made, if the file goes there); the scan service then
applies the plan (``camd.daemon.scan_apply``).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from camd.daemon.errors import BadRequest
from camd.daemon.models import ScanRequest
from camd.daemon.motion_service import MotionService
from camd.daemon.scan_plan import ScanContext, ScanPlan, StageContext, engine_for, plan_scan
from camd.daemon.sensor_service import RegisterSnapshot, SensorService
from camd.daemon.sim_control import SimulatorControl
from camd.pipeline.background import BackgroundCapture
from camd.store.recording import RecordingError, check_new_file
from camd.store.tdi_recording import TdiRecorder


@dataclass(frozen=True, slots=True)
class PlannedScan:
    """A scan's plan and what it was made from: the registers read (to put back the ones the
    plan writes, if a later step fails) and where the stage stood (to take it back there)."""

    plan: ScanPlan
    snapshot: RegisterSnapshot
    stage_position_m: float


@dataclass(eq=False)
class ScanPlanner:
    """Read, plan and check a scan before anything is changed (module docstring)."""

    sensor: SensorService
    motion: MotionService
    sim: SimulatorControl
    # The live view's background: stored in every scan started while it is ready.
    background: BackgroundCapture | None

    def plan(self, request: ScanRequest, path: Path) -> PlannedScan:
        """The scan of ``request`` into the file ``path``, planned and checked; BadRequest
        (or the plan's own refusal) if it cannot run as asked."""
        planned = self._read_and_plan(request, path)
        plan = planned.plan
        self._warm_engine(plan)
        # The file holds the lines and, if the live view has one, the background; its
        # recorder keeps a headroom besides.
        reserve = TdiRecorder.reserve_bytes(plan.columns, request.mode)
        background = self.background.ready() if self.background is not None else None
        extra = 0 if background is None else background.pixels.nbytes
        try:
            check_new_file(plan.path, plan.planned_bytes + extra, reserve)
        except RecordingError as exc:
            raise BadRequest(str(exc)) from None
        return planned

    def _read_and_plan(self, request: ScanRequest, path: Path) -> PlannedScan:
        """Read what the plan needs (registers, stage), then plan: nothing is changed."""
        if request.scene is not None and not self.sim.available:
            raise BadRequest("scene is for the simulated camera only; drop --scene")
        snapshot = self.sensor.snapshot()
        stage: StageContext | None = None
        position_m = 0.0
        if request.drive_stage:
            stage = self.motion.stage_context(request.closed_loop)
            position_m = stage.position_m
        pitch, magnification = self.motion.camera_optics()
        context = ScanContext(
            timing=snapshot.timing(),
            preview=snapshot.preview,
            regmap=self.sensor.regmap,
            columns=snapshot.columns(),
            pixel_pitch_m=pitch,
            magnification=magnification,
            stage=stage,
            ideal_stage=self.sim.available and not request.drive_stage,
            path=path,
            image_measure=self.motion.config.image_measure,
            image_loop=self.motion.config.image_loop,
        )
        plan = plan_scan(request, context)
        if request.out is None:
            plan.path.parent.mkdir(parents=True, exist_ok=True)  # the daemon's own folder
        return PlannedScan(plan, snapshot, position_m)

    @staticmethod
    def _warm_engine(plan: ScanPlan) -> None:
        """Load (or compile) the TDI kernel now: doing it on the worker thread mid-stream would
        hold the GIL for a second or more and starve the USB reader."""
        engine = engine_for(plan.request, plan.request.stages, plan.columns)
        engine.push_many(np.zeros((2, engine.rows_needed, plan.columns), dtype=np.uint16))
