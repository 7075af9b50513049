"""Push-broom scans: the stream in TDI mode, every frame through the TDI engine, lines to HDF5.

``ScanService`` is handed the device access and the sensor, stream, motion and simulator
services. A scan (docs/scan.md):

1. claims the acquisition slot (one scan, stare or stream at a time), reads the registers and
   the stage once and plans the whole scan from them (``camd.daemon.scan_plan.plan_scan``: line
   period, window, register writes, synchronous speed, travel, file), refusing it before
   anything is changed; then applies the plan step by step (scene, TDI mode, registers, the
   simulator's ideal stage, the scan stage through ``camd.daemon.scan_motion.ScanMotion`` on
   the motion service's ``StageDrive``, the file), each step with its undo (``camd.daemon.transaction.Apply``): a failure puts back what
   was changed and says so;
2. starts the stream with ``lines + M - 1`` frames and the scan's acquisition pipeline
   (``camd.pipeline.TdiPipeline``): its consumer copies each frame into a batch on the stream's
   dispatcher thread, and its worker thread runs the batches through the TDI engine, works out
   each line's M dV/V from the encoder counts in the frame headers (checked against the
   yellow/red limits of config ``[motion]``) and appends the lines to the HDF5 file;
3. when the stream ends, the pipeline is finished, the file gets its counters and a PNG
   quicklook is written beside it.

A stage change (``set_stages``) takes effect at the next frame the consumer sees, without
stopping the stream: the engine starts a new run there, so the next M - 1 lines are incomplete.

With ``live_lines`` (the session's ``camd.pipeline.live.LiveLines``), each scan's lines also go
to the live view's waterfall: reset as the scan's stream starts, fed by the pipeline's worker,
ended with the scan's final state.

Its parts, one job each: the request made into a plan (``scan_planner``: read, plan, check;
nothing changed), the plan applied with its undo (``scan_apply``), the scan from its stream's
start to its file closed (``scan_run``: the line consumer and the finisher), and the status
document (``scan_status``). ``ScanService`` serves the requests and keeps the current scan.
"""

from __future__ import annotations

import datetime as dt

from camd.daemon.errors import BadRequest
from camd.daemon.models import ScanRequest, ScanResponse
from camd.daemon.scan_apply import ScanApply
from camd.daemon.scan_plan import max_stages, scan_path
from camd.daemon.scan_planner import ScanPlanner
from camd.daemon.scan_run import FINISH_TIMEOUT_S, ScanRun
from camd.daemon.scan_status import mismatch_gauges, scan_response
from camd.tdi import stage_taps

SHUTDOWN_WAIT_S = 8.0  # at shutdown, how long the scan's finisher may take to end it


class ScanService:
    """Start, watch, re-stage and stop push-broom scans."""

    def __init__(self, apply: ScanApply) -> None:
        """``apply`` applies the scans' plans; the service takes the parts it needs from it."""
        self.device = apply.device
        self.stream = apply.stream
        self._lock = apply.lock
        self._scan: ScanRun | None = None
        self._planner = ScanPlanner(apply.sensor, apply.motion, apply.sim, apply.background)
        self._apply = apply

    def mismatch_gauges(self) -> dict[str, float]:
        """The current (or last) scan's M |dV/V| for the metrics: last batch, max, RMS."""
        return mismatch_gauges(self._scan)

    # -- requests -----------------------------------------------------------------------------

    def status(self) -> ScanResponse:
        """The current or last scan (state "none" before the first)."""
        return scan_response(self._scan, self.stream)

    def start(self, request: ScanRequest) -> ScanResponse:
        """Plan the scan whole, then apply it, and return at once (``status`` shows its
        progress). A refused scan changes nothing; a scan that fails while being applied puts
        back what it had changed and says so (``camd.daemon.transaction``)."""
        device = self.device
        what = "until stopped" if request.lines == 0 else f"{request.lines} lines"
        daemon = device.config.daemon
        path = scan_path(request.out, daemon.data_dir, dt.datetime.now(dt.UTC), daemon.record_dirs)
        slot = device.acquisition
        acquisition = slot.claim("scan", f"M = {request.stages}, {what} to {path}")
        try:
            with slot.applying(acquisition):
                # The camera first: a scan that will be refused must not have set the mode
                # or run the stage to find out.
                self.stream.preflight("start a scan")
                planned = self._planner.plan(request, path)
                scan = self._apply.apply(planned, acquisition, self._running)
        except BaseException:
            slot.abandon(acquisition)
            raise
        return scan_response(scan, self.stream)

    def _running(self, scan: ScanRun) -> None:
        with self._lock:
            self._scan = scan

    def stop(self) -> ScanResponse:
        """Stop the running scan (the stream drains first) and wait until its file is closed."""
        scan = self._scan
        if self.request_stop():
            assert scan is not None
            scan.done.wait(FINISH_TIMEOUT_S)
        return scan_response(scan, self.stream)

    def request_stop(self) -> bool:
        """Stop the running scan without waiting for its file (the emergency stop): it ends
        as "stopped". False if no scan is running."""
        scan = self._scan
        if scan is None or scan.done.is_set():
            return False
        scan.stop_requested = True
        self.stream.stop()
        return True

    def set_stages(self, stages: int) -> ScanResponse:
        """Change M from the next frame on, without stopping the stream."""
        scan = self._scan
        if scan is None or scan.done.is_set():
            raise BadRequest("no scan is running; start one with `camctl scan`")
        pipeline, req = scan.pipeline, scan.request
        if stages == pipeline.stages and pipeline.pending_stages is None:
            return scan_response(scan, self.stream)
        taps = stage_taps(
            stages,
            pipeline.width,
            rows_per_line=req.rows_per_line,
            cols_per_line=req.cols_per_line,
            reverse=req.reverse,
        )
        if taps.rows_needed > pipeline.rows:
            raise BadRequest(
                f"stages = {stages} needs {taps.rows_needed} window rows but the scan's frames "
                f"have {pipeline.rows} (docs/physics.md §2 eq 13: M <= M0); choose "
                f"1..{max_stages(req, pipeline.width, pipeline.rows)}"
            )
        pipeline.request_stages(stages)
        self.device.log_event("info", "scan", f"TDI stages -> {stages} from the next frame")
        return scan_response(scan, self.stream)

    def stopping(self) -> None:
        """Daemon shutdown, before the stream is ended: the running scan ends as stopped (not
        done), whichever of its finisher and ``close`` gets there first."""
        scan = self._scan
        if scan is not None and not scan.done.is_set():
            scan.stop_requested = True

    def close(self, timeout_s: float = SHUTDOWN_WAIT_S) -> None:
        """Daemon shutdown, after the stream was ended (``StreamService.shut_down``): the scan's
        finisher ends it as a stopped scan (the pipeline drained, the closed loop and the stage
        stopped, the file closed, the event with its line count), within ``timeout_s``; a scan
        it has not ended by then is ended here."""
        scan = self._scan
        if scan is None or scan.done.is_set():
            return
        scan.close(timeout_s)
