"""The three SNR-versus-stages models of docs/physics.md §5 side by side, and fits to measurements.

For M-stage digital TDI from a single-stage measurement (signal ``S`` above black, sensor
temporal noise ``s_CMOS`` and quantisation ``s_AD``, all in DN):

- TAO12 (eqs 27-28): ``SNR_M = SNR_1 * gain``, ``gain = M (s_AD + s_CMOS) / (M s_AD +
  sqrt(M) s_CMOS)``: quantisation adds linearly over the stages (``tdi_snr.snr_gain_tao12``);
- sqrt(M) (DONG16 eqs 1-3): ``SNR_M = sqrt(M) SNR_1`` (``tdi_snr.snr_gain_sqrt_m``);
- quadrature (docs/physics.md: "the standard model with independent quantisation noise"):
  ``SNR_M = M S / sqrt(M (s_AD^2 + s_CMOS^2))`` (``tdi_snr.tdi_noise_quadrature``).

``SNR_1`` is the measured single-stage SNR; without one it is ``S / sqrt(s_AD^2 + s_CMOS^2)``
(what a temporal-noise measurement of one stage gives). Because every stage of digital TDI is
its own ADC conversion, docs/physics.md's quadrature model has quantisation per stage, and it then
predicts exactly ``sqrt(M) SNR_1`` whenever ``SNR_1`` is that quadrature sum: the two columns
differ only when the measured ``SNR_1`` is not explained by ``s_AD`` and ``s_CMOS`` alone.
TAO12's model is the one that predicts a different shape: below sqrt(M), and the more so the
larger ``s_AD / s_CMOS``.

``fit_snr_model`` fits a model's free parameters to measured ``(M, SNR)`` points by least
squares in dB (numpy only).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
import numpy.typing as npt

from camd.analysis.tdi_snr import (
    QUANTISATION_SIGMA_DN,
    db,
    snr_gain_sqrt_m,
    snr_gain_tao12,
    tdi_noise_quadrature,
)

FloatArray = npt.NDArray[np.float64]

SnrModel = Literal["tao12", "sqrt_m", "quadrature"]
"""The names of docs/physics.md §5's three models."""

SNR_MODELS: tuple[SnrModel, ...] = ("tao12", "sqrt_m", "quadrature")

_DB_PER_NEPER = 20.0 / math.log(10.0)  # d(20 lg x) = _DB_PER_NEPER * dx / x


def _stages(stages: Sequence[int] | npt.ArrayLike) -> tuple[int, ...]:
    arr = np.atleast_1d(np.asarray(stages))
    if arr.ndim != 1 or arr.size == 0:
        raise ValueError(f"stages must be a non-empty sequence of integers, got {stages!r}")
    if not np.issubdtype(arr.dtype, np.integer) and not np.all(arr == np.round(arr)):
        raise ValueError(f"stages must be whole numbers, got {stages!r}")
    if int(arr.min()) < 1:
        raise ValueError(f"stages must be >= 1, got {stages!r}")
    return tuple(int(m) for m in arr)


def sensor_sigma_dn(noise_dn: float, sigma_ad_dn: float = QUANTISATION_SIGMA_DN) -> float:
    """``s_CMOS = sqrt(N_1^2 - s_AD^2)``: sensor noise from a measured single-stage noise.

    docs/physics.md §5: the measured temporal noise ``N_1`` of one stage is the sensor's (photon
    shot, dark-current shot and read noise, TAO12's lumped ``s_CMOS``) and quantisation's in
    quadrature.
    """
    if not noise_dn > sigma_ad_dn >= 0.0:
        raise ValueError(
            f"noise_dn ({noise_dn!r}) must exceed sigma_ad_dn ({sigma_ad_dn!r}) >= 0: "
            "a measured noise cannot be below quantisation alone; check units (DN)"
        )
    return math.sqrt(noise_dn**2 - sigma_ad_dn**2)


@dataclass(frozen=True, slots=True)
class SnrModels:
    """Linear SNR of M stages under the three models of docs/physics.md §5, one entry per M."""

    stages: tuple[int, ...]
    tao12: tuple[float, ...]
    sqrt_m: tuple[float, ...]
    quadrature: tuple[float, ...]
    snr_1: float

    @property
    def tao12_db(self) -> tuple[float, ...]:
        """TAO12's model in dB, ``SNR_1[dB] + 20 lg(gain)``."""
        return tuple(db(x) for x in self.tao12)

    @property
    def sqrt_m_db(self) -> tuple[float, ...]:
        """The sqrt(M) model in dB, ``SNR_1[dB] + 10 lg M``."""
        return tuple(db(x) for x in self.sqrt_m)

    @property
    def quadrature_db(self) -> tuple[float, ...]:
        """The quadrature model in dB."""
        return tuple(db(x) for x in self.quadrature)


def snr_models(
    stages: Sequence[int],
    *,
    signal_dn: float,
    sigma_cmos_dn: float,
    sigma_ad_dn: float = QUANTISATION_SIGMA_DN,
    snr_1: float | None = None,
) -> SnrModels:
    """The three SNR-versus-M models of docs/physics.md §5 side by side for ``stages``.

    ``signal_dn`` is one stage's signal above black, ``sigma_cmos_dn`` its sensor temporal
    noise (TAO12's ``s_CMOS``: photon shot, dark-current shot and read noise in quadrature;
    ``sensor_sigma_dn`` derives it from a measured noise), ``sigma_ad_dn`` the quantisation
    noise of one conversion (``1/sqrt(12)`` DN). ``snr_1`` is the measured single-stage SNR the
    TAO12 and sqrt(M) models scale (docs/physics.md: ``SNR_M[dB] = SNR_1[dB] + 20 lg(gain)``);
    by default ``S / sqrt(s_AD^2 + s_CMOS^2)``. The quadrature model is computed from the
    components: ``M S / sqrt(M (s_AD^2 + s_CMOS^2))``.
    """
    ms = _stages(stages)
    if not signal_dn > 0.0:
        raise ValueError(f"signal_dn (signal above black) must be > 0, got {signal_dn!r}")
    if sigma_ad_dn < 0.0 or sigma_cmos_dn < 0.0 or sigma_ad_dn + sigma_cmos_dn == 0.0:
        raise ValueError(
            f"sigma_ad_dn ({sigma_ad_dn!r}) and sigma_cmos_dn ({sigma_cmos_dn!r}) must be >= 0 "
            "and not both 0"
        )
    if snr_1 is None:
        snr_1 = signal_dn / math.hypot(sigma_ad_dn, sigma_cmos_dn)
    elif not snr_1 > 0.0:
        raise ValueError(f"snr_1 must be > 0, got {snr_1!r}")
    return SnrModels(
        stages=ms,
        tao12=tuple(snr_1 * snr_gain_tao12(m, sigma_ad_dn, sigma_cmos_dn) for m in ms),
        sqrt_m=tuple(snr_1 * snr_gain_sqrt_m(m) for m in ms),
        quadrature=tuple(
            m * signal_dn / tdi_noise_quadrature(m, sigma_ad_dn, sigma_cmos_dn) for m in ms
        ),
        snr_1=snr_1,
    )


@dataclass(frozen=True, slots=True)
class SnrFit:
    """A model of docs/physics.md §5 fitted to measured ``(M, SNR)`` points, least squares in dB.

    ``snr_1_db`` is the fitted single-stage SNR, ``sigma_cmos_dn`` the fitted sensor noise
    (None for ``sqrt_m``, which has no such parameter); the ``*_sigma`` fields are their
    standard errors from the residual scatter (``s^2 (J^T J)^-1``, ``s^2 = RSS / dof``; 0 when
    the points fit exactly). ``sigma_ad_dn`` and ``signal_dn`` are the fixed inputs.
    """

    model: SnrModel
    snr_1_db: float
    snr_1_db_sigma: float
    sigma_cmos_dn: float | None
    sigma_cmos_dn_sigma: float | None
    sigma_ad_dn: float
    signal_dn: float | None
    stages: tuple[int, ...]
    residuals_db: tuple[float, ...]
    dof: int

    @property
    def rms_db(self) -> float:
        """Root-mean-square residual in dB."""
        return math.sqrt(sum(r * r for r in self.residuals_db) / len(self.residuals_db))

    def predict_db(self, stages: Sequence[int]) -> tuple[float, ...]:
        """The fitted model's SNR in dB at ``stages``."""
        return tuple(
            self.snr_1_db + _model_gain_db(self.model, m, self.sigma_ad_dn, self.sigma_cmos_dn)
            for m in _stages(stages)
        )


def _model_gain_db(model: SnrModel, m: int, sigma_ad: float, sigma_cmos: float | None) -> float:
    if model == "tao12":
        assert sigma_cmos is not None
        return db(snr_gain_tao12(m, sigma_ad, sigma_cmos))
    return db(snr_gain_sqrt_m(m))  # sqrt_m, and quadrature relative to its own M = 1


def _tao12_gain_db(ms: FloatArray, sigma_ad: float, sigma_cmos: float) -> FloatArray:
    gain: FloatArray = 20.0 * np.log10(
        ms * (sigma_ad + sigma_cmos) / (ms * sigma_ad + np.sqrt(ms) * sigma_cmos)
    )
    return gain


def _tao12_gain_db_dlog_sigma(ms: FloatArray, sigma_ad: float, sigma_cmos: float) -> FloatArray:
    """d(20 lg gain) / d(ln s_CMOS)."""
    inner = 1.0 / (sigma_ad + sigma_cmos) - np.sqrt(ms) / (ms * sigma_ad + np.sqrt(ms) * sigma_cmos)
    out: FloatArray = _DB_PER_NEPER * sigma_cmos * inner
    return out


def _golden(f: Callable[[float], float], lo: float, hi: float, tol: float = 1e-10) -> float:
    """Minimum of a unimodal ``f`` on ``[lo, hi]`` by golden-section search."""
    ratio = (math.sqrt(5.0) - 1.0) / 2.0
    c, d = hi - ratio * (hi - lo), lo + ratio * (hi - lo)
    fc, fd = f(c), f(d)
    while hi - lo > tol:
        if fc < fd:
            hi, d, fd = d, c, fc
            c = hi - ratio * (hi - lo)
            fc = f(c)
        else:
            lo, c, fc = c, d, fd
            d = lo + ratio * (hi - lo)
            fd = f(d)
    return (lo + hi) / 2.0


def fit_snr_model(
    stages: Sequence[int],
    snr: Sequence[float] | npt.ArrayLike,
    *,
    model: SnrModel,
    sigma_ad_dn: float = QUANTISATION_SIGMA_DN,
    signal_dn: float | None = None,
) -> SnrFit:
    """Fit a docs/physics.md §5 model to measured linear SNRs at ``stages``, least squares in dB.

    Free parameters, with the standard errors reported in ``SnrFit``:

    - ``"sqrt_m"``: ``SNR_1`` (1 parameter; ``SNR_M[dB] = SNR_1[dB] + 10 lg M``);
    - ``"tao12"``: ``SNR_1`` and ``s_CMOS`` at the given ``sigma_ad_dn`` (eq 28's gain depends
      only on ``s_CMOS / s_AD``, so one of the two must be fixed; TAO12 fixes
      ``s_AD = 0.03104`` in its signal units). Needs 2 distinct M. Solved exactly for
      ``SNR_1`` at each ``s_CMOS`` and by a bracketed 1-D search over ``ln s_CMOS`` in
      ``[1e-6, 1e6] s_AD``;
    - ``"quadrature"``: ``s_CMOS`` at the given ``signal_dn`` and ``sigma_ad_dn``
      (``SNR_1 = S / sqrt(s_AD^2 + s_CMOS^2)``, the same curve as sqrt(M)).

    Needs more points than parameters (to estimate the uncertainty).
    """
    ms = _stages(stages)
    y_lin = np.asarray(snr, dtype=np.float64)
    if y_lin.shape != (len(ms),):
        raise ValueError(
            f"snr must have one value per stage count: {len(ms)} stages, shape {y_lin.shape}"
        )
    if not np.all(y_lin > 0.0):
        raise ValueError("snr values must be linear ratios > 0 (convert dB with 10**(dB / 20))")
    if not sigma_ad_dn > 0.0:
        raise ValueError(f"sigma_ad_dn must be > 0 (1/sqrt(12) DN), got {sigma_ad_dn!r}")
    if model not in SNR_MODELS:
        raise ValueError(f"model must be one of {SNR_MODELS}, got {model!r}")
    params = 2 if model == "tao12" else 1
    if len(ms) <= params:
        raise ValueError(
            f"fitting {model!r} needs at least {params + 1} points, got {len(ms)}: "
            "measure more stage counts"
        )
    m_arr = np.asarray(ms, dtype=np.float64)
    y = 20.0 * np.log10(y_lin)
    n, dof = len(ms), len(ms) - params

    if model in ("sqrt_m", "quadrature"):
        d1 = float(np.mean(y - 10.0 * np.log10(m_arr)))
        residuals = y - (d1 + 10.0 * np.log10(m_arr))
        s2 = float(residuals @ residuals) / dof
        d1_sigma = math.sqrt(s2 / n)
        sigma_cmos: float | None = None
        sigma_cmos_sigma: float | None = None
        if model == "quadrature":
            if signal_dn is None or not signal_dn > 0.0:
                raise ValueError(
                    "the quadrature fit needs signal_dn (one stage's signal above black, DN); "
                    "without it fit 'sqrt_m' for SNR_1"
                )
            total2 = (signal_dn / 10.0 ** (d1 / 20.0)) ** 2  # s_AD^2 + s_CMOS^2
            if total2 <= sigma_ad_dn**2:
                raise ValueError(
                    f"the fitted SNR_1 ({d1:.2f} dB) exceeds what quantisation alone allows, "
                    f"S / s_AD = {db(signal_dn / sigma_ad_dn):.2f} dB: check signal_dn and "
                    "sigma_ad_dn (DN)"
                )
            sigma_cmos = math.sqrt(total2 - sigma_ad_dn**2)
            # s_CMOS^2 = S^2 10^(-d1/10) - s_AD^2  =>  d s_CMOS / d d1 = -total2 / (DPN s_CMOS)
            sigma_cmos_sigma = total2 / (_DB_PER_NEPER * sigma_cmos) * d1_sigma
        return SnrFit(
            model=model,
            snr_1_db=d1,
            snr_1_db_sigma=d1_sigma,
            sigma_cmos_dn=sigma_cmos,
            sigma_cmos_dn_sigma=sigma_cmos_sigma,
            sigma_ad_dn=sigma_ad_dn,
            signal_dn=signal_dn,
            stages=ms,
            residuals_db=tuple(float(r) for r in residuals),
            dof=dof,
        )

    # TAO12: for a given s_CMOS the best SNR_1[dB] is the mean of y - 20 lg gain (variable
    # projection); the residual sum of squares is then a function of ln s_CMOS alone.
    if len(set(ms)) < 2:
        raise ValueError("fitting 'tao12' needs at least 2 distinct stage counts")

    def rss(log_sigma: float) -> float:
        g = _tao12_gain_db(m_arr, sigma_ad_dn, math.exp(log_sigma))
        r = y - g - float(np.mean(y - g))
        return float(r @ r)

    lo, hi = math.log(sigma_ad_dn * 1e-6), math.log(sigma_ad_dn * 1e6)
    grid = np.linspace(lo, hi, 241)
    values = [rss(float(u)) for u in grid]
    k = int(np.argmin(values))
    if k in (0, len(grid) - 1):
        # At either end of the bracket eq 28 no longer depends on s_CMOS (gain 1 or sqrt(M)).
        raise ValueError(
            f"s_CMOS is not determined by these points (best fit at the end of the search, "
            f"{math.exp(float(grid[k])):.3g} DN for s_AD = {sigma_ad_dn:.3g} DN): the points "
            "follow gain 1 or sqrt(M); fit 'sqrt_m' instead or check sigma_ad_dn"
        )
    u = _golden(rss, float(grid[k - 1]), float(grid[k + 1]))
    sigma_fit = math.exp(u)
    g = _tao12_gain_db(m_arr, sigma_ad_dn, sigma_fit)
    d1 = float(np.mean(y - g))
    residuals = y - g - d1
    s2 = float(residuals @ residuals) / dof
    jac = np.column_stack([np.ones(n), _tao12_gain_db_dlog_sigma(m_arr, sigma_ad_dn, sigma_fit)])
    jtj = jac.T @ jac
    cov = s2 * np.linalg.inv(jtj)
    return SnrFit(
        model=model,
        snr_1_db=d1,
        snr_1_db_sigma=math.sqrt(float(cov[0, 0])),
        sigma_cmos_dn=sigma_fit,
        sigma_cmos_dn_sigma=sigma_fit * math.sqrt(float(cov[1, 1])),
        sigma_ad_dn=sigma_ad_dn,
        signal_dn=signal_dn,
        stages=ms,
        residuals_db=tuple(float(r) for r in residuals),
        dof=dof,
    )
