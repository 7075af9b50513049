"""Polarisation azimuth from a rotating reference polariser: a least-squares sinusoid fit.

docs/physics.md §4 [YE23 §4]: the reference polariser is turned 0 .. 360 deg (15 deg steps) in front
of a polarising channel and the signal follows ``I(theta) = a + b cos(2 (theta - phi))``
(Malus's law through two polarisers); ``phi`` is the channel's polarisation azimuth. The fit is
linear: ``I = a + c cos 2 theta + s sin 2 theta`` with ``c = b cos 2 phi``, ``s = b sin 2 phi``.

- ``fit_polarization`` -> ``PolarizationFit``
- ``azimuth_spread_deg``: spread of azimuths on the 180-deg circle (e.g. over exposures)

Angles in degrees. Azimuths are axial (``phi`` and ``phi + 180`` are the same axis).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

ANGLE_TOLERANCE_DEG = 1e-9
"""Reference angles closer than this modulo 180 deg count as the same angle."""


@dataclass(frozen=True, slots=True)
class PolarizationFit:
    """``I(theta) = offset + amplitude * cos(2 (theta - azimuth_deg))`` (docs/physics.md §4).

    ``amplitude`` >= 0 and ``0 <= azimuth_deg < 180``; ``residual_rms`` is the rms of the data
    minus the fit; ``azimuth_error_deg`` the standard error of the azimuth from the fit's
    covariance (residual variance with ``N - 3`` degrees of freedom): NaN with only 3 points (no
    residual to estimate it), infinite when the amplitude is 0 (no azimuth).
    """

    offset: float
    amplitude: float
    azimuth_deg: float
    residual_rms: float
    azimuth_error_deg: float
    points: int


def fit_polarization(theta_deg: npt.ArrayLike, intensity: npt.ArrayLike) -> PolarizationFit:
    """Fit ``I = a + b cos(2 (theta - phi))`` to a reference-polariser scan (docs/physics.md §4).

    Linear least squares on ``[1, cos 2 theta, sin 2 theta]``, then ``b = hypot(c, s)`` and
    ``phi = atan2(s, c) / 2`` mod 180. Needs at least 3 distinct reference angles modulo 180 deg
    (0 and 180 deg are the same polariser position) and finite values.
    """
    theta = _finite_1d("theta_deg", theta_deg)
    values = _finite_1d("intensity", intensity)
    if theta.shape != values.shape:
        raise ValueError(
            f"theta_deg and intensity must have the same length, got {theta.size} angles and "
            f"{values.size} intensities"
        )
    folded = np.mod(theta, 180.0)
    folded[folded > 180.0 - ANGLE_TOLERANCE_DEG] = 0.0
    distinct = np.unique(np.round(folded / ANGLE_TOLERANCE_DEG)).size
    if distinct < 3:
        raise ValueError(
            f"a polarisation fit needs at least 3 distinct reference angles modulo 180 deg, got "
            f"{distinct} among {theta.size} angles; rotate the reference polariser to more "
            "positions (e.g. 0 .. 360 deg in 15 deg steps)"
        )
    twice = np.deg2rad(2.0 * theta)
    design = np.column_stack([np.ones_like(twice), np.cos(twice), np.sin(twice)])
    coefficients, *_ = np.linalg.lstsq(design, values, rcond=None)
    a, c, s = (float(v) for v in coefficients)
    residuals = values - design @ coefficients
    rss = float(residuals @ residuals)
    amplitude = math.hypot(c, s)
    azimuth = math.degrees(math.atan2(s, c)) / 2.0 % 180.0
    if azimuth >= 180.0:  # -tiny % 180 rounds to 180.0
        azimuth = 0.0
    dof = theta.size - 3
    if amplitude == 0.0:
        error = math.inf
    elif dof == 0:
        error = math.nan
    else:
        covariance = rss / dof * np.linalg.inv(design.T @ design)
        # phi = atan2(s, c) / 2: d phi / d c = -s / (2 b^2), d phi / d s = c / (2 b^2).
        jacobian = np.array([0.0, -s, c]) / (2.0 * amplitude**2)
        variance = float(jacobian @ covariance @ jacobian)
        error = math.degrees(math.sqrt(max(variance, 0.0)))
    return PolarizationFit(
        offset=a,
        amplitude=amplitude,
        azimuth_deg=azimuth,
        residual_rms=math.sqrt(rss / theta.size),
        azimuth_error_deg=error,
        points=int(theta.size),
    )


def azimuth_spread_deg(values: npt.ArrayLike) -> float:
    """Spread (max - min) of polarisation azimuths, across the 0/180 deg wrap (docs/physics.md §4).

    Azimuths are axes, so 179 and 1 deg are 2 deg apart. The spread is the shortest arc of the
    180-deg circle that holds every value (180 minus the widest gap between neighbours), which
    is max - min after unwrapping around the circular mean when the values lie within a
    quarter turn of each other.
    """
    azimuths = _finite_1d("values", values)
    if azimuths.size == 0:
        raise ValueError("azimuth_spread_deg needs at least one azimuth, got none")
    ordered = np.sort(np.mod(azimuths, 180.0))
    gaps = np.diff(np.append(ordered, ordered[0] + 180.0))
    return float(max(180.0 - float(gaps.max()), 0.0))


def axial_difference_deg(angle_deg: float) -> float:
    """A difference of two azimuths folded into [-90, 90) deg: azimuths are axes (docs/physics.md
    §4), so 179 - 1 = 178 deg is -2 deg."""
    return (angle_deg + 90.0) % 180.0 - 90.0


def _finite_1d(name: str, values: npt.ArrayLike) -> npt.NDArray[np.float64]:
    array: npt.NDArray[Any] = np.asarray(values)
    if array.dtype == np.bool_ or not (
        np.issubdtype(array.dtype, np.integer) or np.issubdtype(array.dtype, np.floating)
    ):
        raise ValueError(f"{name} must be real numbers, got an array of {array.dtype}")
    result = np.array(array, dtype=np.float64).reshape(-1) if array.ndim <= 1 else None
    if result is None:
        raise ValueError(f"{name} must be one-dimensional, got shape {array.shape}")
    bad = ~np.isfinite(result)
    if bad.any():
        index = int(np.flatnonzero(bad)[0])
        raise ValueError(
            f"{name} must be finite: {int(bad.sum())} value(s) are not, the first at index "
            f"{index} ({result[index]!r})"
        )
    return result
