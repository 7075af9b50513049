"""MTF measurements: along-track MTF of TDI scans of an edge target against velocity mismatch,
and the limiting resolution of a bar target against the stage count (docs/physics.md §6, YUAN13 §4;
the ``mtf_mismatch`` campaign).

- ``mismatch_scan_plan``: the ``dv_over_v``, the number of lines and the edge target's period
  for a scan at ``M dV/V`` (no data; its results feed the scan step as ``${dv_over_v}``,
  ``${scan_lines}``, ``${edge_period}``);
- ``scan_edge_mtf``: the along-track MTF at the focal plane's Nyquist frequency of a scan of a
  slanted-edge target (``camd.analysis.mtf.combined_edge_mtf``), with docs/physics.md §6's model
  (eq 3 times eq 8, ``mtf_tdi_model``) and the rig's complete model
  (``mtf_rolling_tdi_model``), both from what the scan's file records;
- ``mismatch_model_curve``: both models as curves over ``M dV/V``, for the report's plot;
- ``bar_resolution``: the limiting resolution of a scan of a bar target by Rose's criterion
  (``camd.analysis.mtf.bar_target_resolution``), in lp/mm on the target;
- ``resolution_model``: the limits the stage counts should give if M stages raise the bars'
  detectability ``sqrt(M)`` times (docs/physics.md §5's independent noise per stage), from the
  first scan's detectabilities.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np

from camd.analysis.mtf import (
    NYQUIST_CY_PER_PX,
    ROSE_THRESHOLD,
    USAF_BAR_ASPECT,
    bar_target_resolution,
    combined_edge_mtf,
    find_edge_regions,
    limiting_frequency,
    lp_per_mm_on_target,
    mtf_rolling_tdi_model,
    mtf_tdi_model,
    pixel_noise_dn,
    slanted_edge_mtf,
)
from camd.campaign.measurements import Inputs, Results, measurement, require_input

if TYPE_CHECKING:
    from camd.store.tdi_recording import TdiScan

MIN_LINE_PITCH_PX = 0.05
"""A scan whose image moves less than this many rows per line period is refused: its lines
would repeat the same rows (the target stands nearly still)."""


def _scan_file(inputs: Inputs, function: str) -> TdiScan:
    scan = require_input(inputs, "scan", function).scan()
    if scan.metadata.get("scan", {}).get("binning", "off") != "off":
        raise ValueError(f"{function} needs an unbinned scan (binning: off)")
    return scan


def _profile_value(meta: dict[str, Any], key: str) -> Any:
    entry = meta["profile"][key]
    return entry["value"] if isinstance(entry, dict) else entry


def planned_dv_over_v(m_dv_over_v: float, stages: int, max_forward: float = 0.9) -> float:
    """``dV/V`` for a mismatch ``M dV/V``: ``m_dv_over_v / stages`` while it is at most
    ``max_forward`` (the stage at ``1 - dV/V`` of the synchronous speed runs forwards), else
    ``-|m_dv_over_v| / stages`` (the stage faster than synchronous): see
    ``mismatch_scan_plan``."""
    if int(stages) < 1:
        raise ValueError(f"stages must be >= 1, got {stages}")
    size = abs(float(m_dv_over_v)) / int(stages)
    return math.copysign(size, float(m_dv_over_v)) if size <= max_forward else -size


@measurement("mismatch_scan_plan")
def mismatch_scan_plan(
    inputs: Inputs,
    *,
    m_dv_over_v: float,
    stages: int,
    scene_rows: int,
    edge_period_rows: int = 64,
    max_forward: float = 0.9,
) -> Results:
    """The scan for a velocity mismatch ``M dV/V`` at ``stages`` (docs/physics.md §6). Takes no
    data. Results:

    - ``dv_over_v = m_dv_over_v / stages`` (the stage at ``1 - dV/V`` times the synchronous
      speed) while that leaves the stage at least ``1 - max_forward`` of it; beyond, the
      stage cannot run slower (a fixed stage speed must be > 0: the simulator's stage runs
      forwards only), and the mismatch is made the other way, ``-m_dv_over_v / stages`` (eq 8
      depends on ``|M dV/V|``): ``M dV/V = 10`` at ``M = 8`` runs the stage 2.25 times the
      synchronous speed;
    - ``scan_lines``: enough to cover ``scene_rows`` rows of the target when the image moves
      less than a row per line period (``scene_rows / |1 - dV/V|``), else ``scene_rows``
      (as many lines, hence as many edge samples, as a synchronous scan);
    - ``edge_period``: the edge target's period in rows, ``edge_period_rows`` stretched by
      ``|1 - dV/V|`` when the image moves more than a row per line period, so that its edges
      stay as many lines apart (``find_edge_regions`` needs room either side of each).
    """
    m = int(stages)
    dv = planned_dv_over_v(m_dv_over_v, m, max_forward)
    pitch = abs(1.0 - dv)
    if pitch < MIN_LINE_PITCH_PX:
        raise ValueError(
            f"M dV/V = {m_dv_over_v:g} at M = {m} makes dV/V = {dv:g}: the image would move "
            f"{pitch:.3g} rows per line period; choose M dV/V away from M = {m}"
        )
    period = 8 * math.ceil(edge_period_rows * max(1.0, pitch) / 8)
    return {
        "dv_over_v": dv,
        "scan_lines": math.ceil(int(scene_rows) / min(pitch, 1.0)),
        "edge_period": period,
    }


@measurement("scan_edge_mtf")
def scan_edge_mtf(
    inputs: Inputs,
    *,
    cell_px: float = 0.0,
    frequency_cy_per_px: float = NYQUIST_CY_PER_PX,
    fill_width: float | None = None,
) -> Results:
    """Along-track MTF of a TDI scan of a slanted-edge target (the simulator's ``edge``
    scene) at ``frequency_cy_per_px`` on the focal plane (Nyquist by default), against
    docs/physics.md §6's model. Input ``scan``.

    The complete lines are cut into one region per edge (``find_edge_regions``); each goes
    through ``slanted_edge_mtf`` (regions it refuses are counted, not used) and their LSFs are
    averaged (``combined_edge_mtf``) with the lines' pitch on the focal plane, ``|1 - dV/V|``
    pixels (a TDI line per line period, while the image moves ``1 - dV/V`` rows).

    From the scan's file: ``M``, ``dV/V`` (the stage speed against the synchronous one),
    ``T_int / T_L`` (exposure over line period), ``T_row / T_L`` (a rolling shutter's row time,
    0 for a global shutter) and the aperture ``q = sqrt(fill factor)`` (or ``fill_width``).

    Results: ``mtf_nyquist`` and its jackknife standard error ``mtf_nyquist_err``;
    ``model_nyquist``, eq 3 times eq 8 as docs/physics.md §6 writes them (``mtf_tdi_model``) times
    the scene's cells ``sinc(f cell_px)^2``; ``model_nyquist_rig`` the rig's complete model
    (``mtf_rolling_tdi_model``: the rolling shutter's slip, the exposure smear at the image's
    speed, the discrete stages, the cells); ``mtf_dev_model`` and ``mtf_dev_rig``, the
    measurement's absolute deviations from them; ``m_dv_over_v``; ``edges`` used and
    ``edges_refused``; ``edge_snr`` (median edge step over the pixel noise);
    ``integration_ratio``, ``row_skew`` and ``fill_width`` (the models' inputs).
    """
    scan = _scan_file(inputs, "scan_edge_mtf")
    meta = scan.metadata
    lines = np.asarray(scan.lines[scan.complete], dtype=np.float64)
    stages = int(meta["scan"]["stages"])
    timing = meta["timing"]
    dv = float(timing["dv_over_v"])
    line_period_s = float(timing["tdi_line_period_s"])
    ratio = float(timing["exposure_s"]) / line_period_s
    rolling = _profile_value(meta, "shutter") == "rolling"
    skew = float(timing["row_period_s"]) / line_period_s if rolling else 0.0
    q = math.sqrt(float(_profile_value(meta, "fill_factor"))) if fill_width is None else fill_width

    results = []
    refused = 0
    for region in find_edge_regions(lines, axis="along"):
        try:
            results.append(slanted_edge_mtf(lines[region.slices], axis="along"))
        except ValueError:
            refused += 1  # e.g. an edge whose per-line locations scatter in the noise
    if not results:
        raise ValueError(
            f"no edge of the scan could be measured ({refused} refused): raise the light, the "
            "exposure or the stage count, or scan more lines"
        )
    combined = combined_edge_mtf(results, line_pitch_px=abs(1.0 - dv))
    f = float(frequency_cy_per_px)
    measured = combined.mtf_at(f)
    cells = float(np.sinc(f * cell_px) ** 2)
    model = mtf_tdi_model(f, stages=stages, dv_over_v=dv, fill_width=q, integration_ratio=ratio)
    model *= cells
    rig = mtf_rolling_tdi_model(
        f, stages=stages, dv_over_v=dv, fill_width=q, integration_ratio=ratio, row_skew=skew,
        cell_px=cell_px,
    )  # fmt: skip
    k = max(2, min(r.esf.size for r in results) // 10)
    steps = [abs(float(r.esf[-k:].mean() - r.esf[:k].mean())) for r in results]
    return {
        "mtf_nyquist": measured,
        "mtf_nyquist_err": combined.std_error_at(f),
        "model_nyquist": model,
        "model_nyquist_rig": rig,
        "mtf_dev_model": abs(measured - model),
        "mtf_dev_rig": abs(measured - rig),
        "m_dv_over_v": stages * dv,
        "edges": combined.edges,
        "edges_refused": refused,
        # The noise across track, along the edges: their steps do not enter the differences.
        "edge_snr": float(np.median(steps)) / pixel_noise_dn(lines, axis="across"),
        "integration_ratio": ratio,
        "row_skew": skew,
        "fill_width": q,
    }


def _on_grid(grid: list[float], at: list[float], values: list[Any]) -> list[Any]:
    """``values`` measured ``at`` some grid points, None elsewhere (plots skip None)."""
    found = dict(zip(at, values, strict=True))
    return [found.get(x) for x in grid]


@measurement("mismatch_model_curve")
def mismatch_model_curve(
    inputs: Inputs,
    *,
    mismatch: list[float],
    mtf_nyquist: list[float],
    stages: int,
    integration_ratio: list[float],
    row_skew: list[float],
    fill_width: list[float],
    cell_px: float = 0.0,
    frequency_cy_per_px: float = NYQUIST_CY_PER_PX,
    step: float = 0.1,
    max_forward: float = 0.9,
) -> Results:
    """The two models of ``scan_edge_mtf`` as curves over ``M dV/V`` from 0 to the largest
    measured (every ``step``, and at each measured value), with the measurements on the same
    grid (None between them), for a plot. The timing and aperture are the first scan's
    (``from_results`` of the ``scan_edge_mtf`` sweep: the same registers for every scan), and
    ``dV/V`` takes the sign ``mismatch_scan_plan`` gives it (``planned_dv_over_v``): the rig's
    model jumps where the stage changes from slower to faster than synchronous.

    Results: ``mismatch_grid``, ``mtf_nyquist_grid``, ``model_nyquist_grid`` (docs/physics.md §6,
    eq 3 times eq 8, times the cells) and ``model_nyquist_rig_grid``
    (``mtf_rolling_tdi_model``).
    """
    if not mismatch or len(mismatch) != len(mtf_nyquist):
        raise ValueError("mismatch and mtf_nyquist must be lists of one length")
    top = max(float(x) for x in mismatch)
    count = math.floor(top / step + 1e-9)
    grid = sorted({round(k * step, 9) for k in range(count + 1)} | {float(x) for x in mismatch})
    m = int(stages)
    ratio, skew, q = float(integration_ratio[0]), float(row_skew[0]), float(fill_width[0])
    f = float(frequency_cy_per_px)
    cells = float(np.sinc(f * cell_px) ** 2)
    dvs = [planned_dv_over_v(x, m, max_forward) for x in grid]
    sec6 = [
        mtf_tdi_model(f, stages=m, dv_over_v=dv, fill_width=q, integration_ratio=ratio) * cells
        for dv in dvs
    ]
    rig = [
        mtf_rolling_tdi_model(
            f,
            stages=m,
            dv_over_v=dv,
            fill_width=q,
            integration_ratio=ratio,
            row_skew=skew,
            cell_px=cell_px,
        )
        for dv in dvs
    ]
    return {
        "mismatch_grid": grid,
        "mtf_nyquist_grid": _on_grid(grid, [float(x) for x in mismatch], list(mtf_nyquist)),
        "model_nyquist_grid": sec6,
        "model_nyquist_rig_grid": rig,
    }


@measurement("bar_resolution")
def bar_resolution(
    inputs: Inputs,
    *,
    frequencies: list[float],
    band_lines: int,
    margin_lines: int = 3,
    threshold: float = ROSE_THRESHOLD,
    bar_aspect: float = USAF_BAR_ASPECT,
) -> Results:
    """Limiting resolution of a TDI scan of a bar target whose bars vary across track (the
    simulator's ``bars`` scene, ``orientation=across``: groups at ``frequencies`` in bands of
    ``band_lines`` lines), by Rose's criterion (``camd.analysis.mtf.bar_target_resolution``;
    docs/physics.md §6, YUAN13 §4). Input ``scan`` (synchronous: one target row per line).

    Results: ``resolution_cy_per_px`` (the highest group resolved with every coarser one),
    ``resolution_lp_mm`` (on the target: the target-side pixel is pitch / magnification, from
    the scan's file), ``detectability`` (Rose's d per group), ``bar_delta_dn``,
    ``bar_noise_dn``, ``group_frequencies`` (cycles per pixel) and ``lp_mm_per_cy_px``.
    """
    scan = _scan_file(inputs, "bar_resolution")
    meta = scan.metadata
    lines = np.asarray(scan.lines[scan.complete], dtype=np.float64)
    result = bar_target_resolution(
        lines, frequencies, band_lines=band_lines, margin_lines=margin_lines,
        threshold=threshold, bar_aspect=bar_aspect,
    )  # fmt: skip
    scale = lp_per_mm_on_target(
        1.0,
        pitch_m=float(_profile_value(meta, "pitch_m")),
        magnification=float(_profile_value(meta, "magnification")),
    )
    return {
        "resolution_cy_per_px": result.limit_cy_per_px,
        "resolution_lp_mm": result.limit_cy_per_px * scale,
        "detectability": [g.detectability for g in result.groups],
        "bar_delta_dn": [g.delta_dn for g in result.groups],
        "bar_noise_dn": [g.noise_dn for g in result.groups],
        "group_frequencies": [g.frequency_cy_per_px for g in result.groups],
        "lp_mm_per_cy_px": scale,
    }


@measurement("resolution_model")
def resolution_model(
    inputs: Inputs,
    *,
    stages: list[int],
    detectability: list[list[float]],
    frequencies: list[list[float]],
    resolution_lp_mm: list[float],
    lp_mm_per_cy_px: list[float],
    threshold: float = ROSE_THRESHOLD,
) -> Results:
    """The limiting resolutions the stage counts should give, from the first count's scan:
    M stages sum M times the bars' signal and, the noise of each stage being independent,
    ``sqrt(M)`` times the noise (docs/physics.md §5, the quadrature model), so Rose's detectability
    grows as ``sqrt(M)``: ``d_M = d_M0 sqrt(M / M0)`` per group, and the limit follows by the
    same criterion (``limiting_frequency``). Takes the results of the ``bar_resolution``
    sweep (``from_results``).

    Results: ``resolution_model_lp_mm`` per count; ``resolution_gain_lp_mm``, the measured
    limit at the last count minus the first's (YUAN13 §4: more stages resolve finer bars in
    low light); ``resolution_model_groups_off``, the largest number of bar groups between a
    measured limit and its model; ``bar_frequency_cy_per_px`` and ``rose_threshold`` (the
    groups' frequencies and the threshold at each, for plots); ``stages_grid`` (1 .. the
    largest count), ``resolution_model_lp_mm_grid`` (the model at each) and
    ``resolution_lp_mm_grid`` (the measurements on that grid, None between them).
    """
    if not stages or len(detectability) != len(stages) or len(resolution_lp_mm) != len(stages):
        raise ValueError("stages, detectability and resolution_lp_mm must be lists of one length")
    freqs = [float(f) for f in frequencies[0]]
    scale = float(lp_mm_per_cy_px[0])
    base_m = int(stages[0])
    base = np.asarray(detectability[0], dtype=np.float64)
    model_cy = [
        limiting_frequency(freqs, base * math.sqrt(int(m) / base_m), threshold=threshold)
        for m in stages
    ]
    ladder = [0.0, *sorted(freqs)]  # 0: not even the coarsest group

    def rank(limit_lp_mm: float) -> int:
        return int(np.argmin([abs(limit_lp_mm - f * scale) for f in ladder]))

    off = max(
        abs(rank(r) - rank(m * scale)) for r, m in zip(resolution_lp_mm, model_cy, strict=True)
    )
    grid = list(range(1, max(int(m) for m in stages) + 1))
    model_grid = [
        scale * limiting_frequency(freqs, base * math.sqrt(m / base_m), threshold=threshold)
        for m in grid
    ]
    return {
        "resolution_model_lp_mm": [m * scale for m in model_cy],
        "stages_grid": grid,
        "resolution_lp_mm_grid": _on_grid(
            [float(m) for m in grid], [float(m) for m in stages], list(resolution_lp_mm)
        ),
        "resolution_model_lp_mm_grid": model_grid,
        "resolution_gain_lp_mm": float(resolution_lp_mm[-1] - resolution_lp_mm[0]),
        "resolution_model_groups_off": off,
        "bar_frequency_cy_per_px": freqs,
        "rose_threshold": [threshold] * len(freqs),
    }
