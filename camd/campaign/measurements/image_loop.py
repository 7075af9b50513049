"""Image-loop measurements: what a scan's image did, and its along-track MTF against the YUAN13
rig model at that motion (docs/physics.md §6 and §10; docs/motion.md, "Closing the loop on the
image"; the ``image_motion_loop`` campaign).

- ``image_loop_scan``: one scan of a slanted-edge target with a magnification error and a
  rotation (the simulator's image motion errors): over its settled lines, the along-track MTF
  at Nyquist beside ``mtf_rolling_tdi_model`` evaluated at the image's speed each line had
  (from the encoder's per-line M dV/V and the known magnification error), the encoder's and the
  image's own figures, and the across-track smear the drift taps leave;
- ``image_loop_compare``: the image loop's MTF at Nyquist against the encoder loop's, with the
  standard error of the difference.
"""

from __future__ import annotations

import math
from typing import Any

import h5py
import numpy as np
import numpy.typing as npt

from camd.analysis.mtf import (
    NYQUIST_CY_PER_PX,
    combined_edge_mtf,
    find_edge_regions,
    mtf_rolling_tdi_model,
    pixel_noise_dn,
    slanted_edge_mtf,
)
from camd.campaign.measurements import Inputs, Results, measurement, require_input

FloatArray = npt.NDArray[np.float64]


def image_rows_per_line(
    m_dv_over_v_encoder: npt.ArrayLike, stages: int, magnification_error: float
) -> FloatArray:
    """The image's speed in rows per line period from the encoder's per-line ``M dV/V``: the
    encoder says the stage moved ``1 - M dV/V / M`` pitches of the nominal image a line, and a
    magnification error ``e`` makes the image move ``1 + e`` times that (docs/physics.md §10:
    ``m' = m (1 + e)``, which the encoder cannot see), ``(1 + e)(1 - M dV/V / M)``."""
    mdv = np.asarray(m_dv_over_v_encoder, dtype=np.float64)
    return (1.0 + float(magnification_error)) * (1.0 - mdv / int(stages))


def _profile_value(meta: dict[str, Any], key: str) -> Any:
    entry = meta["profile"][key]
    return entry["value"] if isinstance(entry, dict) else entry


def _read_group(path: str, name: str) -> dict[str, FloatArray] | None:
    with h5py.File(path, "r") as f:
        if name not in f:
            return None
        group = f[name]
        return {k: np.asarray(group[k], dtype=np.float64) for k in group}


def _mean_sem(values: FloatArray) -> tuple[float, float]:
    v = values[np.isfinite(values)]
    if v.size == 0:
        return math.nan, math.nan
    sem = float(np.std(v, ddof=1) / math.sqrt(v.size)) if v.size > 1 else math.nan
    return float(np.mean(v)), sem


@measurement("image_loop_scan")
def image_loop_scan(
    inputs: Inputs,
    *,
    magnification_error: float,
    columns: list[list[int]],
    settled_fraction: float = 0.5,
    cell_px: float = 0.0,
    turn_cell_px: float = 0.0,
    turn_across_cell_px: float = 0.0,
    frequency_cy_per_px: float = NYQUIST_CY_PER_PX,
    sigmas: float = 4.0,
    neglected: float = 0.0,
    mode_name: str = "",
    mode_index: int = 0,
) -> Results:
    """One scan of the ``edge`` scene (slanted edges in the column bands ``columns``, each
    ``[first, last)``; a texture elsewhere for the image motion monitor) under a known
    ``magnification_error`` e and a rotation. Input ``scan`` (a driven stage: its per-line
    encoder ``M dV/V`` is needed). Over the last ``settled_fraction`` of the complete lines
    (after the image loop has settled: the same lines for every mode):

    - the image's speed per line, ``v = (1 + e)(1 - M dV/V_enc / M)`` rows a line period
      (``image_rows_per_line``), and the model: ``mtf_rolling_tdi_model`` at each line's
      ``dV/V = 1 - v`` with ``row_skew = T_row / T`` and ``T_int / T`` at the line period the
      lines had (the image loop's last setting, from the file's ``/image_loop``, else the
      planned one), with the image's across-track slip per stage against the drift taps
      (below) seen along the edges' normal (``across_slip_px``, ``edge_tan``: the edges' fitted
      angle ``edge_angle_deg``), times the scene turn's interpolation (docs/simulator.md: a
      triangle one cell wide each way), ``sinc(f turn_cell_px)^2`` along and, across, cells of
      ``turn_across_cell_px`` that move the slanted edges along by ``tan(angle)`` as much,
      ``sinc(f turn_across_cell_px tan(angle))^2``; averaged over the lines. Beside it
      ``model_nyquist_along``, the same without the across slip: the camera's MTF along track
      alone (the lines' LSFs
      add, so their MTFs average). ``slip_px``: the model's along-track slip over M stages,
      ``M (1 - v (1 - T_row / T))`` (docs/mtf.md), the lines' mean;
    - ``mtf_nyquist``: the along-track MTF at ``frequency_cy_per_px`` from the edges' mean LSF
      (``combined_edge_mtf``, the lines ``v`` pixels apart), its jackknife ``mtf_nyquist_err``;
      ``mtf_dev_model = |measured - model|`` and ``mtf_dev_margin = sigmas * err + neglected -
      mtf_dev_model`` (>= 0: within the tolerance);
    - the encoder: ``encoder_mismatch_rms`` / ``encoder_mismatch_max`` (the scan's, over its
      complete lines) and ``encoder_m_dv_over_v`` (the settled lines' mean);
    - the image, from the file's ``/image_motion`` blocks that start in the settled lines
      (means): ``image_dv_over_v`` (and its standard error), ``image_m_dv_over_v``,
      ``image_theta_deg``; ``drift_cols_per_line``, the image's columns a line,
      ``t / s`` (docs/physics.md §10: ``tan(theta)`` per row, one row a line);
      ``taps_cols_per_line``, the TDI drift taps' over those lines (the image loop's settings
      then in force; 0 without it); ``across_smear_px = M (drift - taps)`` and its standard
      error, and ``across_mtf_factor = |sinc(f across_smear_px)|``, what that smear costs
      across track at ``f``.
    """
    scan = require_input(inputs, "scan", "image_loop_scan").scan()
    meta = scan.metadata
    if meta.get("scan", {}).get("binning", "off") != "off":
        raise ValueError("image_loop_scan needs an unbinned scan (binning: off)")
    if not 0.0 < settled_fraction <= 1.0:
        raise ValueError(f"settled_fraction = {settled_fraction}: give 0 < it <= 1")
    stages = int(meta["scan"]["stages"])
    timing = meta["timing"]
    planned_s = float(timing["tdi_line_period_s"])
    exposure_s = float(timing["exposure_s"])
    rolling = _profile_value(meta, "shutter") == "rolling"
    row_s = float(timing["row_period_s"]) if rolling else 0.0
    q = math.sqrt(float(_profile_value(meta, "fill_factor")))
    path = str(scan.path)
    loop = _read_group(path, "image_loop")
    line_period_s = float(loop["line_period_s"][-1]) if loop else planned_s

    done = np.flatnonzero(scan.complete)
    sel = done[len(done) - max(1, round(settled_fraction * len(done))) :]
    first_line = int(scan.line_index[sel[0]])
    mdv = np.asarray(scan.m_dv_over_v[sel], dtype=np.float64)
    if not np.isfinite(mdv).all():
        raise ValueError(
            "image_loop_scan needs the encoder's M dV/V of every line (a scan that drives the "
            "stage: drive_stage true)"
        )
    speed = image_rows_per_line(mdv, stages, magnification_error)
    f = float(frequency_cy_per_px)
    skew = row_s / line_period_s
    ratio = min(1.0, exposure_s / line_period_s)
    turn_along = float(np.sinc(f * turn_cell_px) ** 2)
    slip = float(np.mean(stages * (1.0 - speed * (1.0 - skew))))

    lines = np.asarray(scan.lines[sel], dtype=np.float64)
    edges = []
    refused = 0
    for first, last in columns:
        band = lines[:, int(first) : int(last)]
        for region in find_edge_regions(band, axis="along"):
            try:
                edges.append(slanted_edge_mtf(band[region.slices], axis="along"))
            except ValueError:
                refused += 1  # e.g. an edge whose per-line locations scatter in the noise
    if not edges:
        raise ValueError(f"no edge of the scan could be measured ({refused} refused)")
    pitch = float(np.mean(speed))
    combined = combined_edge_mtf(edges, line_pitch_px=pitch)
    # The edges' angle to the rows in the scene's sense (y = x tan a): as fitted, 5 deg turned
    # with the camera.
    edge_tan = math.tan(math.radians(combined.edge_angle_deg))
    measured = combined.mtf_at(f)
    error = combined.std_error_at(f)
    k = max(2, min(r.esf.size for r in edges) // 10)
    steps = [abs(float(r.esf[-k:].mean() - r.esf[:k].mean())) for r in edges]
    band = lines[:, int(columns[0][0]) : int(columns[0][1])]

    blocks = _read_group(path, "image_motion")
    image: dict[str, tuple[float, float]] = {}
    drift, drift_err, n_blocks = math.nan, math.nan, 0
    if blocks:
        use = (blocks["line_first"] >= first_line) & (blocks["measurable"] > 0)
        n_blocks = int(use.sum())
        for key in ("dv_over_v", "m_dv_over_v", "theta_deg"):
            image[key] = _mean_sem(blocks[key][use])
        drift, drift_err = _mean_sem(
            blocks["shift_across_px_per_line"][use] / blocks["shift_along_px_per_line"][use]
        )
    taps = 0.0
    if loop:
        # The settings in force over the settled lines: the last made before them, and every
        # one after (a block's counter says when it was measured).
        counter0 = float(scan.frame_counter[sel[0]])
        after = loop["counter_first"] >= counter0
        in_force = np.flatnonzero(after)
        start = max(0, int(in_force[0]) - 1) if in_force.size else len(after) - 1
        taps = float(np.mean(loop["cols_per_line"][start:]))
    across = stages * (drift - taps)
    # The turn's interpolation across (cells of turn_across_cell_px) moves the slanted edges
    # along by tan(a) as much.
    turn = turn_along * float(np.sinc(f * turn_across_cell_px * edge_tan) ** 2)
    values, counts = np.unique(speed, return_counts=True)

    def rig(across_slip_px: float) -> float:
        per_value = [
            mtf_rolling_tdi_model(
                f,
                stages=stages,
                dv_over_v=1.0 - float(v),
                fill_width=q,
                integration_ratio=ratio,
                row_skew=skew,
                cell_px=cell_px,
                across_slip_px=across_slip_px,
                edge_tan=edge_tan,
            )
            for v in values
        ]
        return turn * float(np.average(per_value, weights=counts))

    across_slip = (drift - taps) if math.isfinite(drift) else 0.0
    model = rig(across_slip)
    motion = meta.get("motion", {})
    nan = (math.nan, math.nan)
    return {
        "mode_name": mode_name,
        "mode_index": int(mode_index),
        "mtf_nyquist": measured,
        "mtf_nyquist_err": error,
        "model_nyquist": model,
        "model_nyquist_along": rig(0.0),
        "edge_angle_deg": combined.edge_angle_deg,
        "mtf_dev_model": abs(measured - model),
        "mtf_dev_margin": sigmas * error + neglected - abs(measured - model),
        "edges": combined.edges,
        "edges_refused": refused,
        "edge_snr": float(np.median(steps)) / pixel_noise_dn(band, axis="across"),
        "lines_used": int(sel.size),
        "image_rows_per_line": pitch,
        "model_dv_over_v": 1.0 - pitch,
        "slip_px": slip,
        "line_period_s": line_period_s,
        "row_skew": skew,
        "integration_ratio": ratio,
        "loop_updates": int(loop["line_period_s"].size) if loop else 0,
        "encoder_m_dv_over_v": float(np.mean(mdv)),
        "encoder_mismatch_rms": float(motion.get("mismatch_rms", math.nan)),
        "encoder_mismatch_max": float(motion.get("mismatch_max", math.nan)),
        "image_blocks": n_blocks,
        "image_dv_over_v": image.get("dv_over_v", nan)[0],
        "image_dv_over_v_err": image.get("dv_over_v", nan)[1],
        "image_m_dv_over_v": image.get("m_dv_over_v", nan)[0],
        "image_theta_deg": image.get("theta_deg", nan)[0],
        "drift_cols_per_line": drift,
        "taps_cols_per_line": taps,
        "across_smear_px": across,
        "across_smear_err": stages * drift_err,
        "across_mtf_factor": abs(float(np.sinc(f * across))),
    }


@measurement("image_loop_compare")
def image_loop_compare(
    inputs: Inputs,
    *,
    mode_name: list[str],
    mtf_nyquist: list[float],
    mtf_nyquist_err: list[float],
    encoder: str = "encoder_loop",
    image: str = "image_loop",
) -> Results:
    """The image loop's MTF at Nyquist against the encoder loop's (results of the
    ``image_loop_scan`` sweep, by ``mode_name``): ``image_mtf_gain`` (image minus encoder)
    and its standard error ``image_mtf_gain_err`` (the two scans' in quadrature)."""
    names = list(mode_name)
    i, j = names.index(image), names.index(encoder)
    gain = float(mtf_nyquist[i]) - float(mtf_nyquist[j])
    err = math.hypot(float(mtf_nyquist_err[i]), float(mtf_nyquist_err[j]))
    return {"image_mtf_gain": gain, "image_mtf_gain_err": err}
