"""TDI measurements: SNR and noise against the stage count M (docs/physics.md §1, §5; TAO12 §5,
DONG16 §3.1), from scans or from window frames summed on the host by camd's own TDI engine."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import numpy.typing as npt

from camd.analysis.snr_models import SNR_MODELS, fit_snr_model, sensor_sigma_dn, snr_models
from camd.analysis.tdi_snr import QUANTISATION_SIGMA_DN, along_track_snr, periodic_snr
from camd.campaign.measurements import Acquired, Inputs, Results, measurement, require_input
from camd.tdi import tdi_batch


def _stage_list(stages: list[int], rows: int, what: str) -> list[int]:
    ms = [int(m) for m in stages]
    if not ms or any(m < 1 for m in ms):
        raise ValueError(f"{what}: stages must be a non-empty list of M >= 1, got {stages}")
    if max(ms) > rows:
        raise ValueError(
            f"{what}: M = {max(ms)} needs a window of at least {max(ms)} rows; the frames have "
            f"{rows} (configure WIN_ROWS)"
        )
    return ms


def _host_tdi(frames: npt.NDArray[Any], stages: int, mode: str) -> npt.NDArray[np.float64]:
    """The complete TDI lines of ``stages`` window rows of stared TDI-mode frames, summed by
    camd.tdi (the engine the daemon's scans use)."""
    if mode == "sum":
        lines, complete = tdi_batch(frames[:, :stages, :], stages, mode="sum")
    elif mode == "mean":
        lines, complete = tdi_batch(frames[:, :stages, :], stages, mode="mean")
    else:
        raise ValueError(f"mode must be 'sum' or 'mean' (TDI, docs/physics.md §1), got {mode!r}")
    return np.asarray(lines[complete], dtype=np.float64)


@measurement("tdi_stage_snr")
def tdi_stage_snr(
    inputs: Inputs, *, stages: list[int], mode: str = "sum", black_dn: float = 0.0
) -> Results:
    """Along-track SNR of a flat field against M from one stream of TDI-mode window frames
    (docs/physics.md §5; TAO12 §5.2): for each M the first M window rows of every frame go through
    camd's TDI engine (``tdi_batch``), and the complete lines' temporal SNR is
    ``camd.analysis.tdi_snr.along_track_snr``. The black level of a line is taken from the
    optional input ``dark`` (the same frames without light, summed the same way), else
    ``M * black_dn``. Inputs ``frames`` (and ``dark``). Results per M: ``measured_db``,
    ``signal_dn``, ``noise_dn``; and ``stages``."""
    frames = require_input(inputs, "frames", "tdi_stage_snr").frames()
    dark = inputs.get("dark")
    ms = _stage_list(stages, frames.shape[1], "tdi_stage_snr")
    out: dict[str, list[float]] = {"measured_db": [], "signal_dn": [], "noise_dn": []}
    for m in ms:
        if dark is not None:
            black = float(_host_tdi(dark.frames(), m, mode).mean())
        else:
            black = (1.0 if mode == "mean" else m) * black_dn
        snr = along_track_snr(_host_tdi(frames, m, mode), black_dn=black)
        out["measured_db"].append(snr.snr_db)
        out["signal_dn"].append(snr.signal_dn)
        out["noise_dn"].append(snr.noise_dn)
    return {"stages": ms, **out}


@measurement("tdi_stage_noise")
def tdi_stage_noise(inputs: Inputs, *, stages: list[int], mode: str = "mean") -> Results:
    """Temporal noise of dark TDI lines against M, in output LSB (DONG16 §3.1; docs/physics.md §5):
    the first M window rows of stared dark TDI-mode frames through camd's TDI engine, the
    noise each column's lines spread by (``along_track_snr``'s noise: fixed pattern drops
    out). Also the model: M independent stages, ``sigma_1 / sqrt(M)`` in mean mode
    (``sigma_1 sqrt(M)`` in sum mode), from the measured M = 1 noise (the host's mean is not
    rounded: camd.tdi gives float lines, so no quantisation is added). Input ``frames``.
    Results: ``stages``, ``noise_lsb``, ``model_lsb``, ``dark_mean_lsb``."""
    frames = require_input(inputs, "frames", "tdi_stage_noise").frames()
    ms = _stage_list(stages, frames.shape[1], "tdi_stage_noise")
    noise, means = [], []
    for m in ms:
        lines = _host_tdi(frames, m, mode)
        snr = along_track_snr(lines, black_dn=0.0)
        noise.append(snr.noise_dn)
        means.append(snr.signal_dn)
    sigma_1 = noise[ms.index(1)] if 1 in ms else None
    model: list[float | None] = []
    for m in ms:
        if sigma_1 is None:
            model.append(None)
        elif mode == "mean":
            model.append(sigma_1 / math.sqrt(m))
        else:
            model.append(sigma_1 * math.sqrt(m))
    return {"stages": ms, "noise_lsb": noise, "model_lsb": model, "dark_mean_lsb": means}


@measurement("scan_periodic_psnr")
def scan_periodic_psnr(
    inputs: Inputs, *, period: int, black_dn: float = 0.0, bright_fraction: float = 1.0
) -> Results:
    """PSNR of a TDI scan of a textured (natural) scene that repeats every ``period`` lines
    (docs/physics.md §5, TAO12 §5.1): ``mean`` is the scene's mean above black, ``sigma`` the
    temporal noise (the spread of lines one scene period apart, which see the same scene:
    ``camd.analysis.tdi_snr.periodic_snr``), ``psnr_db`` = 20 lg(mean / sigma). The scene's
    own texture is not noise, so it is kept out of sigma. Input ``scan`` (at least two scene
    periods of lines). The black level of the summed line is ``black_dn``."""
    scan = require_input(inputs, "scan", "scan_periodic_psnr")
    lines, index = _scan_lines(scan)
    snr = periodic_snr(
        lines, index, period=int(period), black_dn=black_dn, bright_fraction=bright_fraction
    )
    return {"mean": snr.signal_dn, "sigma": snr.noise_dn, "psnr_db": snr.snr_db}


def _scan_lines(scan: Acquired) -> tuple[npt.NDArray[Any], npt.NDArray[np.int64]]:
    data = scan.scan()
    return data.lines[data.complete], np.asarray(data.line_index)[data.complete]


@measurement("snr_model_compare")
def snr_model_compare(
    inputs: Inputs,
    *,
    stages: list[int],
    measured_db: list[float],
    signal_dn: list[float],
    noise_dn: list[float],
    sigma_ad_dn: float = QUANTISATION_SIGMA_DN,
) -> Results:
    """The three SNR-versus-M models of docs/physics.md §5 (TAO12 eq 28, sqrt(M), quadrature) for
    one condition, from its measured M = 1 point: ``SNR_1``, the signal, and the sensor noise
    ``sigma_CMOS = sqrt(noise^2 - sigma_AD^2)`` (``sensor_sigma_dn``; ``sigma_AD`` the
    quantisation of one output conversion). Results (lists over ``stages``): ``tao12_db``,
    ``sqrt_m_db``, ``quadrature_db``; ``rms_tao12_db``, ``rms_sqrt_m_db``, ``rms_quadrature_db`` (RMS of
    measured - model, dB); and
    the fits of each model's free parameters to all the points (``fit_snr_model``):
    ``fit_rms_db`` {model: x, None with too few points}. No inputs (``from_results``)."""
    del inputs
    ms = [int(m) for m in stages]
    if 1 not in ms:
        raise ValueError("snr_model_compare needs the M = 1 point (the models scale SNR_1)")
    i1 = ms.index(1)
    if not noise_dn[i1] > sigma_ad_dn:
        raise ValueError(
            f"the M = 1 noise, {noise_dn[i1]:.4g} DN, is not above one conversion's "
            f"quantisation noise, {sigma_ad_dn:.4g} DN: the output does not resolve the "
            "sensor's noise (the models need it); raise the analog gain or the light"
        )
    sigma_cmos = sensor_sigma_dn(noise_dn[i1], sigma_ad_dn)
    models = snr_models(
        ms,
        signal_dn=signal_dn[i1],
        sigma_cmos_dn=sigma_cmos,
        sigma_ad_dn=sigma_ad_dn,
        snr_1=10 ** (measured_db[i1] / 20),
    )
    curves = {
        "tao12_db": list(models.tao12_db),
        "sqrt_m_db": list(models.sqrt_m_db),
        "quadrature_db": list(models.quadrature_db),
    }
    measured = np.asarray(measured_db, dtype=np.float64)
    rms = {
        f"rms_{name}": float(np.sqrt(np.mean((measured - np.asarray(c)) ** 2)))
        for name, c in curves.items()
    }
    linear = [10 ** (x / 20) for x in measured_db]
    fit_rms: dict[str, float | None] = {}
    for model in SNR_MODELS:
        try:
            fit = fit_snr_model(
                ms, linear, model=model, sigma_ad_dn=sigma_ad_dn, signal_dn=signal_dn[i1]
            )
            fit_rms[model] = fit.rms_db
        except ValueError:  # fewer points than the model needs (a --quick sweep)
            fit_rms[model] = None
    return {**curves, **rms, "sigma_cmos_dn": sigma_cmos, "fit_rms_db": fit_rms}


@measurement("snr_model_summary")
def snr_model_summary(
    inputs: Inputs,
    *,
    stages: list[int],
    measured_db: list[list[float]],
    tao12_db: list[list[float]],
    sqrt_m_db: list[list[float]],
    quadrature_db: list[list[float]],
    conditions: list[Any] | None = None,
) -> Results:
    """Every condition of a sweep together (docs/physics.md §5): ``model_db`` {model: [per
    condition [per M]]}, ``overall_rms_db`` {model: RMS of measured - model over every point,
    dB}, ``best_model`` (the smallest RMS: which model the camera follows; of models equal to
    1e-9 dB, the first of tao12, sqrt_m, quadrature) and its
    ``best_rms_db``; ``stages``; and ``condition_names`` (each condition's ``name``, or its
    text) to label plots. No inputs (``from_results``)."""
    del inputs
    model_db = {"tao12": tao12_db, "sqrt_m": sqrt_m_db, "quadrature": quadrature_db}
    measured = np.asarray(measured_db, dtype=np.float64)
    rms = {
        name: float(np.sqrt(np.mean((measured - np.asarray(c, dtype=np.float64)) ** 2)))
        for name, c in model_db.items()
    }
    # Models whose curves coincide (quadrature is sqrt(M) when one conversion's noise is
    # negligible) tie to the last bits of a float: the first of them, the simpler, is best.
    order = list(model_db)
    best = min(rms, key=lambda name: (round(rms[name], 9), order.index(name)))
    names = [str(c.get("name", c)) if isinstance(c, dict) else str(c) for c in (conditions or [])]
    return {
        "stages": [int(m) for m in stages],
        "model_db": model_db,
        "overall_rms_db": rms,
        "best_model": best,
        "best_rms_db": rms[best],
        "condition_names": names,
    }


__all__ = [
    "scan_periodic_psnr",
    "snr_model_compare",
    "snr_model_summary",
    "tdi_stage_noise",
    "tdi_stage_snr",
]
