"""A push-broom scan, planned whole before the camera is touched.

``plan_scan(request, context)`` is pure: from the request and a snapshot of the current
configuration (``ScanContext``: the registers' timing, a preview of what register writes would
set, the optics, the stage) it computes, once, everything a scan needs (docs/scan.md):

- the TDI line period, from a stage speed ``T_line,TDI = p / v_image`` or as given (docs/physics.md §2,
  general form of eq 5), the window that fits it (eqs 6-9, 13: window rows, back path, an
  exposure of at most n_lines - 1 rows, eq 3) and the register writes that set it;
- the timing those writes realise (whole clocks), hence the synchronous stage speed (§6 eq 9),
  the speed the stage runs at (with any deliberate dV/V) and the mismatch
  (``camd.timing.scan_speed``, the one solve ``camctl sync`` uses too);
- for a driven stage: the travel the scan needs, whether the stage must first rewind, and the
  limits it must respect;
- the TDI geometry (rows the engine reads, columns) and the file target with its planned size.

Anything that cannot work is refused here, with a ``BadRequest`` that says what to change, so
that a refused scan changes nothing. ``ScanApply`` then applies the plan step by step and
puts back what it changed if a step fails (``camd.daemon.transaction``).
"""

from __future__ import annotations

import datetime as dt
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from camd.daemon.errors import BadRequest
from camd.daemon.models import SCAN_LINE_PERIOD_MAX_S, ScanRequest, ScanTiming, TimingResponse
from camd.daemon.output_paths import SCANS_FOLDER, resolve_output
from camd.motion.stage import STOPPED_STATES, StageLimits
from camd.sensor.regmap import RegisterMap
from camd.tdi import TdiEngine, stage_taps
from camd.timing import scan_speed, tdi_line_period_s, tdi_window

DRIVEN_MISMATCH_MAX = 0.5  # |dv_over_v| a driven stage takes (0.5 .. 1.5 x synchronous)
STREAM_END_MARGIN_S = 2.0  # stage travel planned beyond the frames' own duration
UNTIL_STOPPED_PLAN_S = 60.0  # a scan "until stopped" is planned (travel, disk) for this long
TRAVEL_MARGIN = 1.05  # a scan asks for 5 % more travel than it needs
SLOW_STREAM_FACTOR = 2.0  # rewind unless there is room for a stream this much slower
LINE_BYTES_OVERHEAD = 32  # per line beside its pixels: index, stages, flags, counter, encoder
FILE_BYTES_OVERHEAD = 1 << 20  # metadata, chunk index, quicklook

Preview = Callable[[Mapping[str, int | str]], TimingResponse]
"""The timing register writes would set (validated as a write would be); nothing is sent."""


@dataclass(frozen=True, slots=True)
class StageContext:
    """The driven scan stage as it is now, and what config allows it."""

    kind: str  # "linear" or "turntable"
    limits: StageLimits  # config [stage], checked against the stage profile
    position_m: float
    state: str  # MOTOR_GET's state
    loop_mode: str  # "off", "step_rate" or "line_period"
    image_scale: float  # image metres per metre of stage travel
    encoder_counts_per_m: float


@dataclass(frozen=True, slots=True)
class ScanContext:
    """What the planner needs to know of the camera now (read before planning)."""

    timing: TimingResponse  # what the registers set now
    preview: Preview
    regmap: RegisterMap
    columns: int  # window columns (unbinned)
    pixel_pitch_m: float  # the camera's, unbinned
    magnification: float  # the camera optics' image/object magnification
    stage: StageContext | None  # None: the scan does not drive a stage
    ideal_stage: bool  # the simulator's ideal stage follows the scan (not driven)
    path: Path  # the file to write (``scan_path``)
    image_measure: bool = True  # config motion.image_measure: the frames' motion is measured
    image_loop: bool = False  # config motion.image_loop: the default of the request's


@dataclass(frozen=True, slots=True)
class StagePlan:
    """The driven stage's part of a scan."""

    speed_m_s: float  # signed: the scan direction; includes the deliberate dV/V
    loop_mode: str
    pixel_pitch_m: float  # on the focal plane (doubled when binned)
    row_time_s: float
    stages: int  # physical rows the closed loop keeps (M, doubled when binned)
    max_lines: int
    offset: float  # the deliberate dV/V the line-period loop keeps
    duration_s: float  # planned travel time (frames + margin)
    travel_m: float  # travel needed, ramps and margin included
    rewind_to_m: float | None  # where to go first when the scan does not fit ahead
    counts_per_pixel: float  # encoder counts per image pitch (the M dV/V monitor)
    must_brake: bool  # the stage still moves: stop it and wait before programming limits
    limits: StageLimits  # programmed before the stage moves (config [stage], as planned with)
    image_scale: float  # image metres per metre of stage travel (the line-period loop)
    encoder_counts_per_m: float  # the closed loop's speed window in counts


@dataclass(frozen=True, slots=True)
class ScanPlan:
    """Everything a scan needs, computed once (module docstring)."""

    request: ScanRequest
    path: Path
    frames: int  # lines + M - 1, or 0 until stopped
    columns: int  # engine width (binned columns when binned)
    rows: int  # rows per frame the engine and batcher take
    register_writes: dict[str, int | str]
    timing: ScanTiming  # predicted after the writes (read back and compared when applied)
    ideal_stage_speed_m_s: float | None  # the simulator's ideal stage speed to set
    stage: StagePlan | None
    planned_bytes: int
    notes: list[str] = field(default_factory=list)  # events to log when the scan starts
    image_loop: bool = False  # the line period and the drift follow the image (docs/motion.md)
    max_lines: int = 0  # the window rows the stream starts with (the trims' ceiling)

    @property
    def binned(self) -> bool:
        return self.request.binning == "2x2"


def travel_needed_m(speed_m_s: float, duration_s: float, limits: StageLimits) -> float:
    """Travel a scan of ``duration_s`` at ``speed_m_s`` needs, ramps and margin included."""
    speed = abs(speed_m_s)
    ramp_m = speed**2 / (2 * limits.accel_m_s2)
    return TRAVEL_MARGIN * (speed * duration_s + 2 * ramp_m)


def max_stages(request: ScanRequest, width: int, rows: int) -> int:
    """The most stages whose taps fit ``rows`` rows."""
    best = 0
    for stages in range(1, rows + 1):
        taps = stage_taps(
            stages,
            width,
            rows_per_line=request.rows_per_line,
            cols_per_line=request.cols_per_line,
            reverse=request.reverse,
        )
        if taps.rows_needed > rows:
            break
        best = stages
    return best


def engine_for(request: ScanRequest, stages: int, cols: int) -> TdiEngine:
    """The TDI engine a scan asks for (ValueError for settings it refuses)."""
    return TdiEngine(
        stages,
        cols,
        mode=request.mode,
        out_bits=request.out_bits,
        rows_per_line=request.rows_per_line,
        cols_per_line=request.cols_per_line,
        reverse=request.reverse,
    )


def check_engine(request: ScanRequest, stages: int, rows: int, cols: int) -> int:
    """Refuse TDI settings the engine cannot run on frames of ``rows`` rows; return the rows
    the engine needs."""
    try:
        engine = engine_for(request, stages, cols)
    except ValueError as exc:
        raise BadRequest(str(exc)) from None
    if engine.rows_needed > rows:
        raise BadRequest(
            f"stages = {stages} needs {engine.rows_needed} window rows but the scan's frames "
            f"have {rows} (docs/physics.md §2 eq 13: M <= M0 = n_lines); choose "
            f"1..{max_stages(request, cols, rows)} stages, or slow the stage (a longer "
            "line period holds more rows)"
        )
    return engine.rows_needed


def window_writes(
    regmap: RegisterMap, now: TimingResponse, n_lines: int, back_path_s: float
) -> tuple[dict[str, int | str], str | None]:
    """Register values for a window of ``n_lines`` rows, that back path, and an exposure that
    fits (eq 3: at most n_lines - 1 rows; kept if it already does); and a note when the map
    cannot set the back path."""
    writes: dict[str, int | str] = {}

    def put(role: str, count: int) -> None:
        write = regmap.role_write(role, count)
        if write is not None:
            writes[write[0]] = write[1]

    if n_lines != now.window_rows:
        put("window_rows", n_lines)
    clocks = round(back_path_s * regmap.timing.clock_hz)
    note = None
    if regmap.role("back_path") is not None:
        put("back_path", clocks)
    elif clocks:
        note = (
            f"sensor {regmap.sensor} has no back-path register: the line period is "
            f"{n_lines} rows, {back_path_s * 1e6:.3f} us short of the one asked for"
        )
    if now.exposure_lines > max(1, n_lines - 1):
        put("exposure_lines", max(1, n_lines - 1))
    return writes, note


def _check_request(request: ScanRequest, stage: StageContext | None) -> None:
    if request.speed_m_s is not None and request.line_period_s is not None:
        raise BadRequest(
            "give either speed_m_s or line_period_s, not both: the line period follows "
            "from the stage speed (docs/physics.md §2)"
        )
    if request.drive_stage and abs(request.dv_over_v) > DRIVEN_MISMATCH_MAX:
        raise BadRequest(
            f"dv_over_v = {request.dv_over_v:g} with the stage driven: it takes "
            f"-{DRIVEN_MISMATCH_MAX:g} .. {DRIVEN_MISMATCH_MAX:g} (the stage at 0.5 .. 1.5 "
            "times the synchronous speed); larger mismatches run on the simulator's ideal "
            "stage (drive_stage false)"
        )
    if stage is not None and stage.state == "estop":
        raise BadRequest(
            "the stage is in emergency stop; check it, then `camctl stage enable` clears it"
        )


def _period_of_speed(speed_m_s: float, pitch_m: float, scale: float) -> float:
    """The TDI line period a stage speed implies; refused beyond the longest a scan takes (a
    tiny speed would give an infinite period, and a window of more rows than exist)."""
    image_speed = scale * speed_m_s
    period_s = pitch_m / image_speed if image_speed > 0.0 else math.inf
    if not period_s <= SCAN_LINE_PERIOD_MAX_S:
        slowest = pitch_m / (scale * SCAN_LINE_PERIOD_MAX_S)
        raise BadRequest(
            f"speed_m_s: {speed_m_s:g} m/s is too slow: it gives a TDI line period of "
            f"{period_s:.4g} s, longer than the {SCAN_LINE_PERIOD_MAX_S:g} s a scan takes; "
            f"give at least {slowest:.4g} m/s"
        )
    return tdi_line_period_s(pitch_m, image_speed)


def scan_path(
    out: str | None, data_dir: Path, now: dt.datetime, record_dirs: Sequence[Path] = ()
) -> Path:
    """The file a scan writes: a time-stamped one in the data directory's scans folder, or
    ``out`` resolved and confined to the data directory and ``record_dirs`` (a relative one
    in the scans folder; ``camd.daemon.output_paths``)."""
    folder = data_dir / SCANS_FOLDER
    if out is None:
        stamp = now.astimezone(dt.UTC).strftime("%Y%m%dT%H%M%S.%fZ")
        return folder / f"scan-{stamp}.h5"
    return resolve_output(
        out, field="out", relative_to=folder, data_dir=data_dir, record_dirs=record_dirs
    )


def plan_scan(request: ScanRequest, context: ScanContext) -> ScanPlan:
    """The whole scan, or a BadRequest saying what to change (module docstring)."""
    _check_request(request, context.stage)
    now = context.timing
    binned = request.binning == "2x2"
    factor = 2 if binned else 1
    cols = context.columns // factor
    pitch = context.pixel_pitch_m * factor
    stage = context.stage if request.drive_stage else None
    # The image scale of stage travel: the stage profile's when the scan drives it, else the
    # camera's magnification (an external or ideal stage).
    scale = stage.image_scale if stage is not None else context.magnification

    # The line period, once: from the stage speed, as given, or the registers'.
    period_s = request.line_period_s
    if request.speed_m_s is not None:
        period_s = _period_of_speed(request.speed_m_s, pitch, scale)
    writes: dict[str, int | str] = {}
    notes: list[str] = []
    if period_s is not None:
        try:
            window = tdi_window(period_s, now.line_period_s)
        except ValueError as exc:
            raise BadRequest(str(exc)) from None
        check_engine(request, request.stages, window.n_lines // factor, cols)
        writes, note = window_writes(context.regmap, now, window.n_lines, window.back_path_s)
        if note:
            notes.append(note)
    after = context.preview(writes) if writes else now
    rows = after.window_rows // factor
    rows_needed = check_engine(request, request.stages, rows, cols)

    # A driven stage runs at the synchronous speed of the line period the registers realise
    # (whole clocks), the simulator's ideal stage at the speed asked for or that one; both
    # offset by any deliberate mismatch asked for (for the ideal stage an exact dV/V for MTF
    # against mismatch, docs/physics.md §6, beyond a real stage's range). An external stage
    # runs as it runs: at the speed given, if one was.
    offset = request.dv_over_v if stage is not None or context.ideal_stage else 0.0
    solved = scan_speed(
        pixel_pitch_m=pitch,
        image_scale=scale,
        line_period_s=after.tdi_line_period_s,
        stage_speed_m_s=None if stage is not None else request.speed_m_s,
        dv_over_v=offset,
    )
    sync = solved.sync_speed_m_s
    speed: float | None = solved.speed_m_s
    ideal: float | None = None
    if stage is None and context.ideal_stage:
        ideal = speed
    elif stage is None and request.speed_m_s is None:
        speed = None
        notes.append(f"run the scan stage at {sync * 1e3:.6g} mm/s (synchronous)")

    frames = 0 if request.lines == 0 else request.lines + request.stages - 1
    if frames == 0 and stage is not None and stage.kind == "linear":
        # "Until stopped" on a linear stage: until stopped or the travel ends, whichever first.
        assert speed is not None
        frames = _frames_the_travel_holds(request, stage.limits, speed, after.tdi_line_period_s)
        if frames:
            span_mm = (stage.limits.high_m - stage.limits.low_m) * 1e3
            notes.append(
                f"until stopped: the stage's travel ({span_mm:.1f} mm between the soft limits, "
                f"at {abs(speed) * 1e3:.6g} mm/s) holds {frames - request.stages + 1} lines; "
                "the scan ends there (state done) unless it is stopped first (state stopped)"
            )
    duration_s = (frames or UNTIL_STOPPED_PLAN_S / after.tdi_line_period_s) * (
        after.tdi_line_period_s
    )
    stage_plan = None
    if stage is not None:
        assert speed is not None
        stage_plan = _plan_stage(request, stage, speed, pitch, after, duration_s)
    image_loop = _image_loop(request, context, stage_plan)
    # Frames may have more rows than the engine reads when a loop trims the line period (the
    # window's rows with it): then the engine's own need is what the batcher keeps.
    if image_loop or (stage_plan is not None and stage_plan.loop_mode == "line_period"):
        rows = rows_needed

    timing = ScanTiming(
        tdi_line_period_s=after.tdi_line_period_s,
        row_period_s=after.line_period_s,
        n_lines=after.window_rows,
        back_path_s=after.back_path_s,
        max_stages=after.max_stages,
        exposure_s=after.exposure_s,
        sync_speed_m_s=sync,
        stage_speed_m_s=speed,
        dv_over_v=None if speed is None else solved.dv_over_v,
    )
    lines = request.lines or (
        frames - request.stages + 1
        if frames
        else round(UNTIL_STOPPED_PLAN_S / after.tdi_line_period_s)
    )
    planned = FILE_BYTES_OVERHEAD + (lines + request.stages) * (cols * 4 + LINE_BYTES_OVERHEAD)
    return ScanPlan(
        request=request,
        path=context.path,
        frames=frames,
        columns=cols,
        rows=rows,
        register_writes=writes,
        timing=timing,
        ideal_stage_speed_m_s=ideal,
        stage=stage_plan,
        planned_bytes=planned,
        notes=notes,
        image_loop=image_loop,
        max_lines=after.window_rows,
    )


def _image_loop(request: ScanRequest, context: ScanContext, stage: StagePlan | None) -> bool:
    """Whether the scan's line period and drift follow the image (the request's, or config's
    when it says nothing); BadRequest when it cannot, saying what to change."""
    wanted = context.image_loop if request.image_loop is None else request.image_loop
    if not wanted:
        return False
    if not context.image_measure:
        raise BadRequest(
            "image_loop needs the image's motion measured from the frames: set "
            "motion.image_measure = true in the daemon's config, or drop image_loop"
        )
    if stage is not None and stage.loop_mode == "line_period":
        raise BadRequest(
            "image_loop trims the line period, which the encoder's loop does too with "
            'motion.correct = "line_period": set motion.correct = "step_rate" (the encoder '
            "holds the stage's speed, the image the line period), or closed_loop false"
        )
    return True


def _frames_the_travel_holds(
    request: ScanRequest, limits: StageLimits, speed_m_s: float, period_s: float
) -> int:
    """The frames a scan until stopped takes before a linear stage's travel between its soft
    limits ends (ramps and margins as ``_plan_stage`` plans them: the most frames it accepts);
    0 when the speed is beyond the stage (``_plan_stage`` refuses it, saying so). BadRequest
    when the travel holds no complete line."""
    speed = abs(speed_m_s)
    if speed > limits.max_speed_m_s:
        return 0
    span = limits.high_m - limits.low_m
    ramps_m = speed**2 / limits.accel_m_s2  # up and down
    duration_s = (span / TRAVEL_MARGIN - ramps_m) / speed - STREAM_END_MARGIN_S
    frames = math.floor(duration_s / period_s) if duration_s > 0 else 0
    if frames < request.stages:
        raise BadRequest(
            f"a scan until stopped at {speed * 1e3:.4g} mm/s: the soft limits leave "
            f"{span * 1e3:.1f} mm of travel, not enough for one complete line of "
            f"{request.stages} stages; scan slower (a longer line period), or widen "
            "stage.low_limit_m / high_limit_m"
        )
    return frames


def _plan_stage(
    request: ScanRequest,
    stage: StageContext,
    speed_m_s: float,
    pitch_m: float,
    after: TimingResponse,
    frames_s: float,
) -> StagePlan:
    """Speed, travel and rewind of a driven stage; refused beyond its limits."""
    limits = stage.limits
    if abs(speed_m_s) > limits.max_speed_m_s:
        raise BadRequest(
            f"stage speed {abs(speed_m_s) * 1e3:.6g} mm/s is above the limit "
            f"{limits.max_speed_m_s * 1e3:.6g} mm/s (stage.max_speed_m_s); go slower (for a "
            "scan: a longer line period or a smaller magnification)"
        )
    duration = frames_s + STREAM_END_MARGIN_S
    signed = -speed_m_s if request.reverse else speed_m_s
    needed = travel_needed_m(signed, duration, limits)
    rewind: float | None = None
    if stage.kind == "linear":
        span = limits.high_m - limits.low_m
        if needed > span:
            raise BadRequest(
                f"the scan needs {needed * 1e3:.1f} mm of travel at {abs(signed) * 1e3:.4g} "
                f"mm/s but the soft limits leave {span * 1e3:.1f} mm; scan fewer lines, or "
                "slower (a longer line period), or widen stage.low_limit_m / high_limit_m"
            )
        # The stage runs in wall time until the last frame is in; a stream that runs slow
        # takes longer than its frames' duration. Rewind unless there is room for twice that.
        comfortable = travel_needed_m(signed, SLOW_STREAM_FACTOR * duration, limits)
        forward = signed > 0
        here = stage.position_m
        ahead = limits.high_m - here if forward else here - limits.low_m
        if comfortable > ahead:
            rewind = limits.low_m if forward else limits.high_m
    factor = 2 if request.binning == "2x2" else 1
    return StagePlan(
        speed_m_s=signed,
        loop_mode=stage.loop_mode,
        pixel_pitch_m=pitch_m,
        row_time_s=after.line_period_s,
        stages=request.stages * factor,
        max_lines=after.window_rows,
        offset=request.dv_over_v,
        duration_s=duration,
        travel_m=needed,
        rewind_to_m=rewind,
        counts_per_pixel=stage.encoder_counts_per_m * pitch_m / stage.image_scale,
        must_brake=stage.state not in STOPPED_STATES,
        limits=limits,
        image_scale=stage.image_scale,
        encoder_counts_per_m=stage.encoder_counts_per_m,
    )
