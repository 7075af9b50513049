"""MTF: the models of docs/physics.md §6 and measurements by slanted edge and bar target.

Spatial frequencies are in cycles per pixel (``f_cy_per_px``, i.e. ``p f`` for ``f`` in cycles
per metre and pitch ``p``); the Nyquist frequency is 0.5 cycles per pixel. All MTFs are moduli
normalised to 1 at zero frequency.

Models (docs/physics.md §6, [YUAN13] §3.2-3.4):

- ``sinc``: the normalised ``sin(pi x) / (pi x)``;
- ``mtf_detector``: eq 3, ``sinc(f q) * sinc(f T_int / T_L)`` (aperture and exposure-time smear);
- ``tdi_integration_ratio``: ``T_int / T_L = M / (M + 1)`` for an M-stage TDI-CMOS sensor;
- ``mtf_velocity_mismatch``: eq 8, ``|sinc(f M dV/V)|`` (smear of ``M |dV/V|`` pixels);
- ``mtf_tdi_model``: the product of eq 3 and eq 8, the part of eq 2 that the TDI timing sets;
- ``mtf_rolling_tdi_model``: the same terms as a rolling-shutter digital TDI scan makes them
  (the rolling shutter's slip per stage, the exposure smear at the image's actual speed, the M
  discrete stages, a simulated target's cells).

Measurements (pure functions of arrays):

- ``slanted_edge_mtf``: ISO 12233-style slanted-edge SFR (edge fit, 4x oversampled ESF, LSF,
  Hamming window, FFT, derivative and binning corrections); ``find_edge_regions`` crops one
  edge at a time out of a periodic edge target (the simulator's ``edge`` scene);
- ``bar_modulation`` and ``mtf_from_bars``: eq 1, ``MTF = M_out / M_in``, with
  ``sine_mtf_from_ctf`` (Coltman's series) for the square-wave bars;
- ``edge_width_10_90_px``: the 10-90 % rise distance of an edge spread function;
- ``combined_edge_mtf``: one MTF from the mean LSF of several edges (noise averaged before the
  modulus), on the focal plane of a scan whose lines are ``|1 - dV/V|`` pixels apart;
- the limiting resolution of a bar target (YUAN13 §4): ``bar_detectability`` (Rose's SNR of a
  USAF bar), ``limiting_frequency``, ``lp_per_mm_on_target`` and ``bar_target_resolution``.

docs/mtf.md describes the algorithm, its choices and the accuracy measured on exact edges.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Literal, TypeVar

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]
# A model of a frequency takes a float or an array of them and answers in kind.
FloatOrArray = TypeVar("FloatOrArray", float, FloatArray)

NYQUIST_CY_PER_PX = 0.5
"""The sampling (Nyquist) frequency of a pixel grid, 1 / (2 p), in cycles per pixel."""

MIN_EDGE_ANGLE_DEG = 1.0
"""Below this slant the ESF cannot be supersampled from a region of practical size."""

MAX_EDGE_ANGLE_DEG = 45.0
"""Beyond this the edge is closer to the other orientation: measure it along the other axis."""

MIN_LINES = 8
"""Fewest lines (rows or columns crossing the edge) ``slanted_edge_mtf`` accepts."""

MIN_LINE_LENGTH = 8
"""Fewest pixels along each line ``slanted_edge_mtf`` accepts."""

_MAX_CORRECTION = 10.0  # cap of the derivative/binning correction factors (as sfrmat does)
_EDGE_TO_NOISE = 5.0  # a step below this many noise sigmas is not an edge
_MAX_FIT_RMS_PX = 1.0  # edge locations scattering more than this about a line: not one edge
_END_MARGIN_PX = 2.0  # the fitted edge must stay this far inside every line

Axis = Literal["along", "across"]


# -- models (docs/physics.md §6) -------------------------------------------------------------------------


def _as_float_array(name: str, value: float | npt.ArrayLike) -> FloatArray:
    arr = np.asarray(value, dtype=np.float64)
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite, got {value!r}")
    return arr


def _out(value: FloatArray | float) -> Any:
    """A 0-d result as a Python float, an array as itself."""
    arr = np.asarray(value, dtype=np.float64)
    return float(arr) if arr.ndim == 0 else arr


def sinc(x: FloatOrArray) -> FloatOrArray:
    """Normalised ``sinc(x) = sin(pi x) / (pi x)``, ``sinc(0) = 1`` (docs/physics.md §6, after eq 3)."""
    result: FloatOrArray = _out(np.sinc(_as_float_array("x", x)))
    return result


def _stages(stages: int) -> int:
    if isinstance(stages, bool) or not isinstance(stages, int | np.integer) or stages < 1:
        raise ValueError(f"stages must be a whole number >= 1, got {stages!r}")
    return int(stages)


def mtf_velocity_mismatch(f_cy_per_px: FloatOrArray, stages: int, dv_over_v: float) -> FloatOrArray:
    """Velocity-mismatch MTF ``|sinc(p f M dV/V)|`` (docs/physics.md §6 eq 8, [YUAN13]).

    Over ``M`` stages the image smears by ``M p |dV/V|``; the line spread function is a
    rectangle of that width. ``f_cy_per_px`` is ``p f``. At Nyquist (0.5) ``M dV/V = 1`` gives
    ``2 / pi = 0.637`` and ``M dV/V = 2`` gives 0. The modulus is returned: beyond the first
    zero the optical transfer function ``sinc`` is negative (contrast reversal).

    docs/physics.md notes that YUAN13 eqs 4-6 put an extra factor M inside V; this is the consistent
    form (smear = M stages times the per-stage slip ``p dV/V``). ``dv_over_v`` is
    ``camd.timing.velocity_mismatch``.
    """
    m = _stages(stages)
    dv = float(_as_float_array("dv_over_v", dv_over_v))
    f = _as_float_array("f_cy_per_px", f_cy_per_px)
    result: FloatOrArray = _out(np.abs(np.sinc(f * m * dv)))
    return result


def tdi_integration_ratio(stages: int) -> float:
    """``T_int / T_L = M / (M + 1)`` for an M-stage TDI-CMOS sensor (docs/physics.md §6, after eq 3)."""
    m = _stages(stages)
    return m / (m + 1.0)


def _fraction(name: str, value: float, what: str) -> float:
    v = float(value)
    if not (math.isfinite(v) and 0.0 <= v <= 1.0):
        raise ValueError(f"{name} must be in [0, 1] ({what}), got {value!r}")
    return v


def mtf_detector(
    f_cy_per_px: FloatOrArray, *, fill_width: float, integration_ratio: float
) -> FloatOrArray:
    """Detector MTF ``sinc(f q) * sinc(f p T_int / T_L)`` (docs/physics.md §6 eq 3, [YUAN13]).

    ``MTF_geo = sinc(f q)``: the photosensitive width ``q`` as a fraction of the pitch
    (``fill_width = q / p``; a square aperture of fill factor FF has ``q / p = sqrt(FF)``).
    ``MTF_discrete = sinc(f p T_int / T_L)``: the image moves one pitch per line period ``T_L``
    and the pixel integrates for ``T_int`` (``integration_ratio = T_int / T_L``, see
    ``tdi_integration_ratio``). At Nyquist: ``sinc(q / 2p) * sinc(T_int / 2 T_L)``.
    """
    q = _fraction("fill_width", fill_width, "photosensitive width q over pitch p")
    ratio = _fraction(
        "integration_ratio",
        integration_ratio,
        "T_int / T_L: the pixel integrates for at most one line period",
    )
    f = _as_float_array("f_cy_per_px", f_cy_per_px)
    result: FloatOrArray = _out(np.abs(np.sinc(f * q) * np.sinc(f * ratio)))
    return result


def mtf_tdi_model(
    f_cy_per_px: FloatOrArray,
    *,
    stages: int,
    dv_over_v: float,
    fill_width: float,
    integration_ratio: float | None = None,
) -> FloatOrArray:
    """``MTF_detector * MTF_dV``: eq 3 times eq 8 of docs/physics.md §6 [YUAN13].

    Of eq 2 (``MTF_optics * MTF_detector * MTF_sampling * MTF_readout * MTF_dV``) this includes
    only the detector aperture (``sinc(f q)``), the exposure-time smear
    (``sinc(f T_int / T_L)``) and the velocity-mismatch smear (``sinc(f M dV/V)``). Optics,
    sampling (phase, aliasing) and readout (charge transfer, electronics) are *not* included:
    the caller multiplies by them when they are known (1 for a simulated camera without
    optics). ``integration_ratio`` defaults to ``M / (M + 1)`` (``tdi_integration_ratio``); give
    the measured ``T_int / T_L`` for a sensor whose exposure is set otherwise.
    """
    ratio = tdi_integration_ratio(stages) if integration_ratio is None else integration_ratio
    f = _as_float_array("f_cy_per_px", f_cy_per_px)
    det = mtf_detector(f, fill_width=fill_width, integration_ratio=ratio)
    dv = mtf_velocity_mismatch(f, stages, dv_over_v)
    result: FloatOrArray = _out(det * dv)
    return result


# -- slanted edge (ISO 12233 style) -----------------------------------------------------------------


@dataclass(frozen=True, slots=True, eq=False)
class SlantedEdgeMtf:
    """Result of ``slanted_edge_mtf``.

    ``frequencies_cy_per_px`` are along the edge normal (cycles per pixel pitch); ``mtf`` is
    normalised to 1 at 0 and corrected for the finite difference (and, if asked, the binning).
    ``esf`` (DN, as measured: rising or falling) and ``lsf`` (DN per bin, made positive, before
    the window) are sampled every ``sample_spacing_px`` along the normal at
    ``esf_positions_px`` (0 at the edge). ``edge_angle_deg`` is the edge's slant to the lines'
    normal: the edge's position along the lines moves ``tan(angle)`` pixels per line.
    """

    frequencies_cy_per_px: FloatArray
    mtf: FloatArray
    edge_angle_deg: float
    esf: FloatArray
    lsf: FloatArray
    esf_positions_px: FloatArray
    sample_spacing_px: float
    lines_used: int
    rising: bool
    axis: Axis

    def mtf_at(self, freq_cy_per_px: float) -> float:
        """The MTF at ``freq_cy_per_px`` by linear interpolation (0 .. highest frequency)."""
        f = float(freq_cy_per_px)
        top = float(self.frequencies_cy_per_px[-1])
        if not 0.0 <= f <= top:
            raise ValueError(f"freq_cy_per_px must be in [0, {top:g}], got {freq_cy_per_px!r}")
        return float(np.interp(f, self.frequencies_cy_per_px, self.mtf))

    @property
    def mtf_nyquist(self) -> float:
        """The MTF at the Nyquist frequency, 0.5 cycles per pixel."""
        return self.mtf_at(NYQUIST_CY_PER_PX)

    @property
    def edge_width_10_90_px(self) -> float:
        """The 10-90 % rise distance of the oversampled ESF, in pixels along the normal."""
        return edge_width_10_90_px(self.esf, self.sample_spacing_px)


def _lines_view(image: npt.ArrayLike, axis: str, what: str) -> FloatArray:
    """The image as (lines, positions): each row of the result crosses the edge."""
    if axis not in ("along", "across"):
        raise ValueError(
            f"axis must be 'along' (ESF along axis 0, edge across track) or 'across', got {axis!r}"
        )
    arr = np.asarray(image, dtype=np.float64)
    if arr.ndim != 2:
        raise ValueError(f"{what} needs a 2-D image (rows, columns), got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{what}: the image holds NaN or infinite pixels; crop them out")
    return arr.T if axis == "along" else arr


def _hamming(n: int, centre: FloatArray | float) -> FloatArray:
    """sfrmat's shifted Hamming window: 0.54 + 0.46 cos over a half-width reaching both ends.

    ``centre`` may be one value or one per line (broadcast along the last axis of length n).
    """
    x = np.arange(n, dtype=np.float64)
    c = np.asarray(centre, dtype=np.float64)[..., None]
    half = np.maximum(np.maximum(c, n - 1 - c), 1.0)
    return 0.54 + 0.46 * np.cos(np.pi * (x - c) / half)


def _centroids(deriv: FloatArray, centre: FloatArray | float) -> FloatArray:
    weighted = deriv * _hamming(deriv.shape[1], centre)
    x = np.arange(deriv.shape[1], dtype=np.float64)
    total = weighted.sum(axis=1)
    total = np.where(total == 0.0, np.nan, total)
    result: FloatArray = (weighted @ x) / total
    return result


def _noise_sigma(work: FloatArray) -> float:
    """Robust pixel noise from second differences along the lines (edges are outliers)."""
    if work.shape[1] < 3:
        return 0.0
    d2 = np.diff(work, n=2, axis=1).ravel()
    mad = float(np.median(np.abs(d2 - np.median(d2))))
    return 1.4826 * mad / math.sqrt(6.0)


def slanted_edge_mtf(
    image: npt.ArrayLike,
    *,
    axis: Axis = "along",
    oversample: int = 4,
    window: bool = True,
    derivative: Literal["central", "forward"] = "central",
    correct_binning: bool = True,
    saturation_dn: float | None = None,
) -> SlantedEdgeMtf:
    """MTF from one slanted edge, ISO 12233 style (the sfrmat algorithm).

    What it measures is the presampling MTF along the edge normal: the product of docs/physics.md
    §6 eq 2 without the sampling term (the slant samples every phase), to compare with
    ``mtf_tdi_model`` times the optics' MTF.

    ``axis="along"``: the edge lies across track and the ESF varies along axis 0 (rows), each
    column is a line crossing the edge; ``"across"``: the ESF varies along axis 1, each row is a
    line. The image must hold one straight edge (rising or falling), slanted by 1 .. 45 degrees,
    crossing every line at least 2 pixels from its ends (``find_edge_regions`` crops such
    regions out of a periodic target).

    1. Per line, the edge location is the centroid of the derivative ``[-0.5, 0, 0.5]``
       weighted by a Hamming window; twice, the second time with the window centred on the
       first fit (as sfrmat3 does). A straight line fitted to the locations gives the angle.
    2. The lines are trimmed to a whole number of phase cycles (``floor(n tan) / tan`` lines,
       centred); every pixel is projected onto the edge normal, ``(x - x_edge(line)) cos``,
       and averaged into bins of ``1 / oversample`` pixel (empty bins interpolated).
    3. ``derivative="central"``: LSF = ``[-0.5, 0, 0.5]`` difference of the ESF (``"forward"``:
       ``[-1, 1]``); ``window``: Hamming window centred on the LSF centroid; FFT; normalise to DC.
    4. Divide by the difference kernel's transfer function, ``sinc(2 f d)`` for the central
       difference (``sinc(f d)`` forward) at the bin spacing ``d`` and, with
       ``correct_binning``, by ``sinc(f d)`` for the bin averaging (a box of one bin); both
       capped at a factor 10. Frequencies up to ``min(1, oversample / 4)`` cycles per pixel.

    ``saturation_dn``: refuse an image that reaches it (clipped edges overstate the MTF).
    Refused with a message: not 2-D, NaN, fewer than 8 lines or 8 pixels per line, flat or
    without an edge, an edge that is not straight or leaves a line, an angle below 1 degree
    or beyond 45 degrees, too few lines for one pixel of phase at that angle.
    """
    work = _lines_view(image, axis, "slanted_edge_mtf")
    n_lines, n_pos = work.shape
    if isinstance(oversample, bool) or not isinstance(oversample, int) or not 2 <= oversample <= 16:
        raise ValueError(
            f"oversample must be a whole number in 2 .. 16 (ISO: 4), got {oversample!r}"
        )
    if derivative not in ("central", "forward"):
        raise ValueError(f"derivative must be 'central' or 'forward', got {derivative!r}")
    line_name = "columns" if axis == "along" else "rows"
    if n_lines < MIN_LINES:
        raise ValueError(
            f"too few lines: {n_lines} {line_name} cross the edge, need at least {MIN_LINES}; "
            "take a wider region along the edge"
        )
    if n_pos < MIN_LINE_LENGTH:
        raise ValueError(
            f"lines too short: {n_pos} pixels across the edge, need at least {MIN_LINE_LENGTH}; "
            "take a longer region across the edge"
        )
    if saturation_dn is not None:
        clipped = int(np.count_nonzero(work >= saturation_dn))
        if clipped:
            raise ValueError(
                f"{clipped} pixels at or above saturation_dn={saturation_dn:g}: a clipped edge "
                "overstates the MTF; lower the exposure, gain or light level"
            )
    lo, hi = float(work.min()), float(work.max())
    if hi == lo:
        raise ValueError(f"the image is flat (every pixel {lo:g} DN): there is no edge to measure")

    # No edge: the step between the two ends of the lines against the pixel noise.
    k = max(2, n_pos // 8)
    step = float(np.median(work[:, -k:].mean(axis=1) - work[:, :k].mean(axis=1)))
    sigma = _noise_sigma(work)
    if abs(step) <= _EDGE_TO_NOISE * sigma or abs(step) <= 1e-9 * max(abs(lo), abs(hi)):
        raise ValueError(
            f"no edge found: the lines step by {step:.3g} DN from end to end against "
            f"{sigma:.3g} DN of noise (need {_EDGE_TO_NOISE:g}x); crop a region around one "
            "edge (find_edge_regions) or raise the contrast"
        )
    sign = 1.0 if step > 0 else -1.0
    steps = sign * (work[:, -k:].mean(axis=1) - work[:, :k].mean(axis=1))
    missing = np.flatnonzero(steps < 0.5 * abs(step))
    if missing.size:
        j = int(missing[0])
        raise ValueError(
            f"the edge leaves the region: line {j} ({line_name[:-1]} {j} of the region) steps "
            f"by {sign * steps[j]:.3g} DN from end to end, the median line by {step:.3g} DN; "
            "crop so that the edge crosses every line (find_edge_regions)"
        )

    # 1. Edge location per line (centroid of the windowed derivative), twice; line fit.
    deriv = sign * np.gradient(work, axis=1)
    lines = np.arange(n_lines, dtype=np.float64)
    loc = _centroids(deriv, (n_pos - 1) / 2.0)
    fit = _fit_line(lines, loc)
    loc = _centroids(deriv, np.clip(fit[0] * lines + fit[1], 0.0, n_pos - 1.0))
    slope, intercept = _fit_line(lines, loc)
    fitted = slope * lines + intercept
    rms = float(np.sqrt(np.nanmean((loc - fitted) ** 2)))
    if not rms <= _MAX_FIT_RMS_PX:
        raise ValueError(
            f"the edge locations scatter by {rms:.2f} px about a straight line: the region "
            "holds more than one edge or a curved one; crop a region around one edge "
            "(find_edge_regions)"
        )
    angle_deg = math.degrees(math.atan(slope))
    other = "across" if axis == "along" else "along"
    if abs(angle_deg) < MIN_EDGE_ANGLE_DEG:
        raise ValueError(
            f"edge angle {angle_deg:.2f} deg is too close to 0: the ESF cannot be "
            f"supersampled below {MIN_EDGE_ANGLE_DEG:g} deg; slant the target by 2 .. 10 deg "
            "(the simulator's edge scene: angle_deg=5)"
        )
    if abs(angle_deg) > MAX_EDGE_ANGLE_DEG:
        raise ValueError(
            f"edge angle {angle_deg:.1f} deg is beyond {MAX_EDGE_ANGLE_DEG:g} deg: this edge "
            f"is closer to the other orientation; measure it with axis={other!r}"
        )
    ends = fitted[[0, -1]]
    if ends.min() < _END_MARGIN_PX or ends.max() > n_pos - 1 - _END_MARGIN_PX:
        bad = 0 if not _END_MARGIN_PX <= ends[0] <= n_pos - 1 - _END_MARGIN_PX else n_lines - 1
        raise ValueError(
            f"the edge leaves the region: at line {bad} it is at {fitted[bad]:.1f} px of "
            f"0 .. {n_pos - 1}; crop so that it crosses every line at least "
            f"{_END_MARGIN_PX:g} px from the ends (find_edge_regions)"
        )

    # 2. A whole number of phase cycles, centred; projection onto the normal; binning.
    tan = abs(slope)
    cycles = math.floor(n_lines * tan + 1e-9)
    if cycles < 1:
        need = math.ceil(1.0 / tan)
        raise ValueError(
            f"too few lines: at {abs(angle_deg):.2f} deg the edge moves {n_lines * tan:.2f} px "
            f"over {n_lines} {line_name}; one pixel of phase needs at least {need}; take a "
            "wider region along the edge or a larger slant"
        )
    used = min(n_lines, max(MIN_LINES, round(cycles / tan)))
    first = (n_lines - used) // 2
    rows = slice(first, first + used)
    cos = math.cos(math.atan(slope))
    spacing = 1.0 / oversample
    dist = (np.arange(n_pos, dtype=np.float64)[None, :] - fitted[rows, None]) * cos
    bins = np.floor(dist / spacing + 0.5).astype(np.int64).ravel()
    kmin = int(bins.min())
    bins -= kmin
    counts = np.bincount(bins)
    sums = np.bincount(bins, weights=work[rows].ravel())
    filled = counts > 0
    idx = np.arange(counts.size, dtype=np.float64)
    esf = np.interp(idx, idx[filled], sums[filled] / counts[filled])
    positions = (idx + kmin) * spacing

    # 3. LSF, window, FFT.
    if derivative == "central":
        lsf = np.empty_like(esf)
        lsf[1:-1] = 0.5 * (esf[2:] - esf[:-2])
        lsf[0], lsf[-1] = lsf[1], lsf[-2]
    else:
        lsf = np.diff(esf, append=esf[-1])
        lsf[-1] = lsf[-2]
    lsf = sign * lsf
    freqs, mtf = _lsf_mtf(
        lsf,
        oversample,
        window=window,
        derivative=derivative,
        correct_binning=correct_binning,
    )

    return SlantedEdgeMtf(
        frequencies_cy_per_px=freqs,
        mtf=mtf,
        edge_angle_deg=angle_deg,
        esf=esf,
        lsf=lsf,
        esf_positions_px=positions,
        sample_spacing_px=spacing,
        lines_used=used,
        rising=sign > 0,
        axis=axis,
    )


def _lsf_mtf(
    lsf: FloatArray,
    oversample: int,
    *,
    window: bool,
    derivative: Literal["central", "forward"],
    correct_binning: bool,
    f_max: float | None = None,
) -> tuple[FloatArray, FloatArray]:
    """Steps 3-4 of ``slanted_edge_mtf``: a positive LSF sampled every ``1 / oversample``
    pixel -> (frequencies, MTF) up to ``f_max`` (default ``min(1, oversample / 4)``) cycles
    per pixel."""
    spacing = 1.0 / oversample
    windowed = lsf
    if window:
        idx = np.arange(lsf.size, dtype=np.float64)
        total = float(lsf.sum())
        centre = float((lsf @ idx) / total) if total > 0 else float(np.argmax(lsf))
        windowed = lsf * _hamming(lsf.size, min(max(centre, 0.0), lsf.size - 1.0))[0]
    n_fft = max(1 << (lsf.size - 1).bit_length(), 64 * oversample)
    spectrum = np.abs(np.fft.rfft(windowed, n=n_fft))
    if spectrum[0] <= 0.0:
        raise ValueError("the LSF sums to zero: no edge in the region; crop around one edge")
    freqs: FloatArray = np.fft.rfftfreq(n_fft, d=spacing).astype(np.float64)
    top = min(1.0, oversample / 4.0) if f_max is None else f_max
    keep = freqs <= top + 1e-12
    freqs, mtf = freqs[keep], spectrum[keep] / spectrum[0]

    # 4. Corrections for the difference kernel and the bin averaging.
    kernel = np.sinc(2.0 * freqs * spacing) if derivative == "central" else np.sinc(freqs * spacing)
    if correct_binning:
        kernel = kernel * np.sinc(freqs * spacing)
    mtf = mtf / np.maximum(kernel, 1.0 / _MAX_CORRECTION)
    return freqs, mtf


def _fit_line(x: FloatArray, y: FloatArray) -> tuple[float, float]:
    good = np.isfinite(y)
    if good.sum() < 2:
        raise ValueError("no edge found in the lines (the derivative sums to zero); crop one edge")
    slope, intercept = np.polyfit(x[good], y[good], 1)
    return float(slope), float(intercept)


@dataclass(frozen=True, slots=True)
class EdgeRegion:
    """One edge of a periodic edge target: ``image[region.slices]`` holds it alone.

    ``position_px`` is the edge's mean position along the ESF axis in the full image, ``rising``
    whether the level increases along that axis, ``lines`` the (first, stop) lines it covers.
    """

    slices: tuple[slice, slice]
    position_px: float
    rising: bool
    lines: tuple[int, int]


def find_edge_regions(
    image: npt.ArrayLike,
    *,
    axis: Axis = "along",
    margin_px: int = 6,
    min_lines: int = 16,
) -> list[EdgeRegion]:
    """Rectangular regions that each hold one edge of a target of parallel (slanted) edges.

    For the simulator's ``edge`` scene (edges across track every half period, slanted by
    ``angle_deg``) use ``axis="along"``. The edges are found on the middle line as peaks of
    the derivative (above half the median line's strongest), followed line by line (within 2
    pixels, same sign), and fitted by straight lines. Each region spans half the spacing of
    neighbouring edges on either side of its edge; where the edge drifts too far for that
    over all lines, the lines are split into blocks so that the edge stays ``margin_px`` away
    from the region's ends and from the neighbouring edges. Blocks of fewer than
    ``min_lines`` lines are dropped. Pass each ``image[region.slices]`` to
    ``slanted_edge_mtf`` with the same ``axis``.
    """
    work = _lines_view(image, axis, "find_edge_regions")
    n_lines, n_pos = work.shape
    if n_lines < 1 or n_pos < 4:
        raise ValueError(f"find_edge_regions needs at least 4 pixels per line, got {work.shape}")
    if margin_px < 1 or min_lines < 1:
        raise ValueError("margin_px and min_lines must be >= 1")
    grad = np.gradient(work, axis=1) if n_pos > 1 else np.zeros_like(work)
    # Seeds and tracks use the derivative averaged over a few neighbouring lines, and each edge
    # is the centre of a run above the threshold: noise, and the flat top of a smeared edge's
    # derivative (a box M dV/V pixels wide), would otherwise split one edge into several.
    half_lines = min(_TRACK_HALF_LINES, (n_lines - 1) // 2)
    smooth = _mean_over_lines(grad, half_lines)
    strength = float(np.median(np.abs(smooth).max(axis=1)))
    # The averaged central difference of independent pixel noise sigma has sigma / sqrt(2 n).
    noise = _noise_sigma(work) / math.sqrt(2.0 * (2 * half_lines + 1))
    if strength <= 0.0 or strength <= _EDGE_TO_NOISE * noise:
        raise ValueError("no edges found: the lines have no step above the noise")
    threshold = 0.5 * strength
    mid = n_lines // 2
    seeds = _runs(smooth[mid], threshold)
    if not seeds:
        raise ValueError("no edges found on the middle line; check the axis")
    # slope, intercept, first line, stop line, sign, width of the edge's derivative
    tracks: list[tuple[float, float, int, int, float, float]] = []
    for seed, seed_width, s in seeds:
        found = {mid: seed}
        widths = [seed_width]
        for direction in (-1, 1):
            pos = seed
            j = mid + direction
            while 0 <= j < n_lines:
                run = _run_near(smooth[j], pos, s, threshold)
                if run is None:
                    break
                pos, width = run
                found[j] = pos
                widths.append(width)
                j += direction
        js = np.array(sorted(found), dtype=np.float64)
        ps = np.array([found[int(j)] for j in js])
        if js.size >= 2:
            slope, intercept = (float(v) for v in np.polyfit(js, ps, 1))
        else:
            slope, intercept = 0.0, float(ps[0])
        tracks.append((slope, intercept, int(js[0]), int(js[-1]) + 1, s, float(np.median(widths))))
    centres = sorted(seed for seed, _, _ in seeds)
    gaps = np.diff(centres)
    spacing = float(np.median(gaps)) if gaps.size else float(2 * n_pos)
    regions: list[EdgeRegion] = []
    for slope, intercept, j0, j1, s, width in tracks:
        half = spacing / 2.0
        # The ESF must reach its levels inside the region: the margin is counted from the
        # ends of the edge's transition (half its derivative's width either side).
        margin = margin_px + width / 2.0
        # The region spans [p0, p1) with its ends rounded from centre -/+ half (half a pixel
        # either way) and its last position p1 - 1: the edge may drift 3 px less than the
        # spacing minus the margins, or every block would fail the margin test below.
        drift_max = spacing - 2.0 * margin - 3.0
        if drift_max <= 0:
            continue
        n = j1 - j0
        per_block = n if abs(slope) * n <= drift_max else int(drift_max / abs(slope))
        if per_block < min_lines:
            continue
        blocks = math.ceil(n / per_block)
        size = n // blocks
        for b in range(blocks):
            a0 = j0 + b * size
            a1 = j1 if b == blocks - 1 else a0 + size
            locs = slope * np.arange(a0, a1, dtype=np.float64) + intercept
            centre = float(locs.mean())
            p0 = max(0, math.floor(centre - half + 0.5))
            p1 = min(n_pos, math.floor(centre + half + 0.5))
            if locs.min() - p0 < margin or p1 - 1 - locs.max() < margin:
                continue
            along = slice(p0, p1)
            lines = slice(a0, a1)
            slices = (along, lines) if axis == "along" else (lines, along)
            regions.append(EdgeRegion(slices, centre, s > 0, (a0, a1)))
    regions.sort(key=lambda r: (r.position_px, r.lines[0]))
    return regions


_TRACK_HALF_LINES = 4  # find_edge_regions averages the derivative over 2 * 4 + 1 lines


def _mean_over_lines(grad: FloatArray, half: int) -> FloatArray:
    """Moving mean over ``2 half + 1`` lines (axis 0), over the lines that exist at the ends."""
    n = grad.shape[0]
    padded = np.concatenate([np.zeros((1, grad.shape[1])), np.cumsum(grad, axis=0)])
    lo = np.clip(np.arange(n) - half, 0, n)
    hi = np.clip(np.arange(n) + half + 1, 0, n)
    result: FloatArray = (padded[hi] - padded[lo]) / (hi - lo)[:, None]
    return result


def _runs(row: FloatArray, threshold: float) -> list[tuple[float, float, float]]:
    """The edges on one line: runs where ``|row| >= threshold`` with one sign, as (centre,
    width, sign). Runs of one sign split by a short dip (shorter than the runs) are one edge
    (noise on a smeared edge's flat derivative); the centre is the ``|row|``-weighted mean."""
    mag = np.abs(row)
    spans: list[list[int]] = []  # [first, stop, sign]
    for i in np.flatnonzero(mag >= threshold):
        sign = 1 if row[i] > 0 else -1
        # Contiguous, or after a dip shorter than the run so far: the same edge.
        if spans and spans[-1][2] == sign and i - spans[-1][1] < spans[-1][1] - spans[-1][0] + 2:
            spans[-1][1] = int(i) + 1
        else:
            spans.append([int(i), int(i) + 1, sign])
    out = []
    for first, stop, sign in spans:
        x = np.arange(first, stop, dtype=np.float64)
        w = np.clip(sign * row[first:stop], 0.0, None)
        centre = float((w @ x) / w.sum()) if w.sum() > 0 else float(x.mean())
        out.append((centre, float(stop - first), float(sign)))
    return out


def _run_near(
    row: FloatArray, pos: float, sign: float, threshold: float
) -> tuple[float, float] | None:
    """The run of ``sign * row >= threshold`` through the strongest sample within 2 of
    ``pos``, as (weighted centre, width); None if that sample is below the threshold."""
    n = row.size
    lo, hi = max(round(pos) - 2, 0), min(round(pos) + 3, n)
    if lo >= hi:
        return None
    cand = lo + int(np.argmax(sign * row[lo:hi]))
    if sign * row[cand] < threshold:
        return None
    first, stop = cand, cand + 1
    while first > 0 and sign * row[first - 1] >= threshold:
        first -= 1
    while stop < n and sign * row[stop] >= threshold:
        stop += 1
    x = np.arange(first, stop, dtype=np.float64)
    w = sign * row[first:stop]
    return float((w @ x) / w.sum()), float(stop - first)


# -- edge width -------------------------------------------------------------------------------------


def edge_width_10_90_px(esf: npt.ArrayLike, spacing_px: float) -> float:
    """10-90 % rise distance of an ESF sampled every ``spacing_px`` pixels, in pixels.

    The low and high levels are the means of the first and last 10 % of the samples (at least
    2); a falling ESF is flipped. The crossings are interpolated linearly, walking outwards
    from the 50 % crossing. An ideal pixel-wide box gives 0.8 px, a Gaussian of sigma s 2.563 s.
    """
    arr = np.asarray(esf, dtype=np.float64)
    if arr.ndim != 1 or arr.size < 4 or not np.all(np.isfinite(arr)):
        raise ValueError(f"esf must be a finite 1-D array of at least 4 samples, got {arr.shape}")
    if not (math.isfinite(spacing_px) and spacing_px > 0):
        raise ValueError(f"spacing_px must be > 0, got {spacing_px!r}")
    k = max(2, arr.size // 10)
    low, high = float(arr[:k].mean()), float(arr[-k:].mean())
    if high == low:
        raise ValueError("the ESF has the same level at both ends: no edge")
    norm = (arr - low) / (high - low)
    i50 = int(np.argmax(norm >= 0.5))
    if norm[i50] < 0.5:
        raise ValueError("the ESF never crosses 50 %")

    def crossing(level: float) -> float:
        if level < 0.5:
            i = i50
            while i > 0 and norm[i - 1] >= level:
                i -= 1
            if i == 0:
                raise ValueError(f"the ESF does not fall below {level:.0%} before its edge")
            a, b = i - 1, i  # norm[a] < level <= norm[b]
        else:
            i = i50
            while i < arr.size and norm[i] < level:
                i += 1
            if i == arr.size:
                raise ValueError(f"the ESF does not reach {level:.0%} after its edge")
            a, b = i - 1, i  # norm[a] < level <= norm[b]
        return a + (level - float(norm[a])) / float(norm[b] - norm[a])

    return (crossing(0.9) - crossing(0.1)) * spacing_px


# -- bar targets ------------------------------------------------------------------------------------


def bar_modulation(
    values: npt.ArrayLike,
    frequency_cy_per_px: float,
    *,
    axis: int = -1,
    method: Literal["extrema", "halves", "fundamental"] = "extrema",
) -> float:
    """Modulation ``(max - min) / (max + min)`` of a bar group at ``frequency_cy_per_px``.

    ``values``: a profile across the bars, or an image region (averaged over the axes other
    than ``axis``, the one along which the bars vary). Levels must be above black (subtract
    the black level first).

    - ``"extrema"``: the profile is cut into windows of ``ceil(1 / f)`` samples starting every
      period; max and min are the means of the windows' maxima and minima (every window holds
      a bright and a dark bar). Exact for a square wave whose bars are whole pixels, at any
      phase; noise biases it upwards (max of noisy samples).
    - ``"halves"``: max and min are the means of the upper and lower halves of the sorted
      values: robust to noise, but below the peak-to-peak value for anything that is not a
      square wave (a sampled sine gives 2 / pi of it).
    - ``"fundamental"``: the amplitude of the least-squares fit ``a + b cos(2 pi f x) +
      c sin(2 pi f x)`` over the mean ``a``: the modulation of the profile's fundamental.
      For square-wave bars of contrast ``M_in`` it is ``4/pi M_in`` times the sine MTF at f
      (harmonics aliased onto f aside): ``mtf_from_bars(..., fundamental=True)``.

    At Nyquist (0.5) the result depends on the bars' phase to the pixels (aligned: full
    modulation; shifted half a pixel: none): sampling is not in eq 2's detector terms.
    """
    f = float(frequency_cy_per_px)
    if not (math.isfinite(f) and 0.0 < f <= NYQUIST_CY_PER_PX):
        raise ValueError(
            f"frequency_cy_per_px must be in (0, 0.5] (Nyquist): above it the bars alias; "
            f"got {frequency_cy_per_px!r}"
        )
    arr = np.asarray(values, dtype=np.float64)
    if arr.ndim == 0:
        raise ValueError("values must be a profile or an image region, got a scalar")
    if not -arr.ndim <= axis < arr.ndim:
        raise ValueError(f"axis {axis} does not exist for values of shape {arr.shape}")
    profile = np.moveaxis(arr, axis, -1).reshape(-1, arr.shape[axis]).mean(axis=0)
    if not np.all(np.isfinite(profile)):
        raise ValueError("values hold NaN or infinite samples")
    period = 1.0 / f
    width = math.ceil(period - 1e-9)
    if profile.size < width:
        raise ValueError(
            f"a profile of {profile.size} samples holds no full period at {f:g} cy/px "
            f"({period:g} px); give at least {width} samples"
        )
    if method == "extrema":
        starts = [
            round(k * period)
            for k in range(int(profile.size / period) + 1)
            if round(k * period) + width <= profile.size
        ]
        windows = np.stack([profile[s : s + width] for s in starts])
        top, bottom = float(windows.max(axis=1).mean()), float(windows.min(axis=1).mean())
    elif method == "halves":
        ordered = np.sort(profile)
        half = ordered.size // 2
        top, bottom = float(ordered[-half:].mean()), float(ordered[:half].mean())
    elif method == "fundamental":
        phase = 2.0 * np.pi * f * np.arange(profile.size, dtype=np.float64)
        design = np.stack([np.ones_like(phase), np.cos(phase), np.sin(phase)], axis=1)
        coef = np.linalg.lstsq(design, profile, rcond=None)[0]  # sin column is 0 at Nyquist
        mean, amplitude = float(coef[0]), float(math.hypot(coef[1], coef[2]))
        if mean <= 0.0:
            raise ValueError(f"the mean level {mean:g} must be above black; subtract black only")
        return amplitude / mean
    else:
        raise ValueError(f"method must be 'extrema', 'halves' or 'fundamental', got {method!r}")
    if bottom < 0.0 or top + bottom <= 0.0:
        raise ValueError(
            f"levels must be above black (min {bottom:g}, max {top:g}); subtract the black "
            "level, not more"
        )
    return (top - bottom) / (top + bottom)


SQUARE_WAVE_FUNDAMENTAL = 4.0 / math.pi
"""A square wave of modulation m has a fundamental of modulation ``4/pi m`` (Fourier series)."""


def mtf_from_bars(modulation: float, target_contrast: float, *, fundamental: bool = False) -> float:
    """``MTF = M_out / M_in`` (docs/physics.md §6 eq 1) for one bar group.

    ``target_contrast`` is the target's Michelson contrast ``M_in`` (the simulator's
    ``contrast``). With a peak-to-peak ``modulation`` (``bar_modulation`` methods
    ``"extrema"``, ``"halves"``) of square-wave bars the ratio is the contrast transfer
    function (CTF), which exceeds the sine MTF (the harmonics pass too): convert a CTF curve
    with ``sine_mtf_from_ctf``. ``fundamental=True``: ``modulation`` is the fundamental's
    (method ``"fundamental"``) and the input's is ``4/pi M_in``, so the ratio is the sine MTF.
    """
    m_in = float(target_contrast)
    m_out = float(modulation)
    if not (math.isfinite(m_in) and 0.0 < m_in <= 1.0):
        raise ValueError(f"target_contrast must be in (0, 1], got {target_contrast!r}")
    top = SQUARE_WAVE_FUNDAMENTAL if fundamental else 1.0
    if not (math.isfinite(m_out) and 0.0 <= m_out <= top + 1e-9):
        raise ValueError(f"modulation must be in [0, {top:.4g}], got {modulation!r}")
    return m_out / (m_in * top)


def _coltman_coefficient(k: int) -> int:
    """B_k of Coltman's series: 0 if k has a squared prime factor, else (-1)^m (-1)^((k-1)/2)."""
    m, n, p = 0, k, 3
    while p * p <= n:
        if n % p == 0:
            n //= p
            if n % p == 0:
                return 0
            m += 1
        p += 2
    if n > 1:
        m += 1
    return -1 if (m + (k - 1) // 2) % 2 else 1


def sine_mtf_from_ctf(
    frequencies_cy_per_px: npt.ArrayLike, ctf: npt.ArrayLike, *, terms: int = 8
) -> FloatArray:
    """Sine-wave MTF from a square-wave CTF curve by Coltman's series (J. Opt. Soc. Am. 1954).

        MTF(f) = pi/4 [CTF(f) + CTF(3f)/3 - CTF(5f)/5 + CTF(7f)/7 + CTF(11f)/11 - ...]

    summed over odd ``k`` (``terms`` of them, B_k = 0 when k has a squared factor). The CTF
    is interpolated linearly between the measured frequencies and taken as 0 beyond the
    highest (so above a third of it, ``MTF = pi/4 CTF``). Coltman's series holds for continuous
    square waves; sampled bars near Nyquist also depend on phase.
    """
    f = np.asarray(frequencies_cy_per_px, dtype=np.float64)
    c = np.asarray(ctf, dtype=np.float64)
    if f.ndim != 1 or f.shape != c.shape or f.size < 1:
        raise ValueError(f"frequencies and ctf must be 1-D of one length, got {f.shape}, {c.shape}")
    if not (np.all(np.isfinite(f)) and np.all(np.isfinite(c)) and np.all(np.diff(f) > 0)):
        raise ValueError("frequencies must be finite and increasing, ctf finite")
    if f[0] <= 0.0:
        raise ValueError("frequencies must be > 0")
    if terms < 1:
        raise ValueError(f"terms must be >= 1, got {terms}")
    out = np.zeros_like(f)
    for k in range(1, 2 * terms, 2):
        b = _coltman_coefficient(k)
        if b:
            out += b / k * np.interp(k * f, f, c, right=0.0)
    return (math.pi / 4.0) * out


@dataclass(frozen=True, slots=True)
class PeriodicEdgeMtf:
    """The slanted-edge MTF of every edge of a periodic edge target, summarised.

    ``mtf_nyquist`` and ``edge_width_px`` (10-90 %) are means over the ``regions`` edges that
    could be measured, ``mtf_nyquist_std`` their spread (an estimate of the measurement noise);
    ``results`` holds each edge's full measurement.
    """

    mtf_nyquist: float
    mtf_nyquist_std: float
    edge_width_px: float
    regions: int
    results: tuple[SlantedEdgeMtf, ...]


def periodic_edge_mtf(
    image: npt.ArrayLike, *, axis: Axis = "along", oversample: int = 4
) -> PeriodicEdgeMtf:
    """Slanted-edge MTF (ISO 12233 style, ``slanted_edge_mtf``) of each edge that
    ``find_edge_regions`` finds in a periodic edge target, e.g. a TDI scan of the simulator's
    ``edge`` scene (docs/physics.md §6: the along-track MTF that velocity mismatch degrades).
    Edges the measurement refuses (too short, clipped) are skipped; none measurable is a
    ValueError."""
    data = np.asarray(image, dtype=np.float64)
    results: list[SlantedEdgeMtf] = []
    refusals: list[str] = []
    for region in find_edge_regions(data, axis=axis):
        try:
            results.append(slanted_edge_mtf(data[region.slices], axis=axis, oversample=oversample))
        except ValueError as exc:
            refusals.append(str(exc))
    if not results:
        why = refusals[0] if refusals else "no edge regions"
        raise ValueError(f"no edge of the target could be measured: {why}")
    nyquist = np.array([r.mtf_nyquist for r in results])
    widths = np.array([r.edge_width_10_90_px for r in results])
    return PeriodicEdgeMtf(
        mtf_nyquist=float(nyquist.mean()),
        mtf_nyquist_std=float(nyquist.std(ddof=1)) if nyquist.size > 1 else 0.0,
        edge_width_px=float(widths.mean()),
        regions=len(results),
        results=tuple(results),
    )


# -- velocity mismatch on a rolling-shutter TDI scan (docs/physics.md §6, YUAN13 §4) ---------------------


def _dirichlet(x: FloatArray, m: int) -> FloatArray:
    """``|sin(pi m x) / (m sin(pi x))|``: the transfer function of ``m`` equal copies spaced
    ``x`` periods apart (1 where ``sin(pi x) = 0``, its limit)."""
    den = m * np.sin(np.pi * x)
    small = np.abs(den) < 1e-12
    ratio = np.sin(np.pi * m * x) / np.where(small, 1.0, den)
    result: FloatArray = np.where(small, 1.0, np.abs(ratio))
    return result


def mtf_rolling_tdi_model(
    f_cy_per_px: FloatOrArray,
    *,
    stages: int,
    dv_over_v: float,
    fill_width: float,
    integration_ratio: float,
    row_skew: float = 0.0,
    cell_px: float = 0.0,
    across_slip_px: float = 0.0,
    edge_tan: float = 0.0,
) -> FloatOrArray:
    """Along-track MTF of M-stage digital TDI on a rolling-shutter sensor under velocity
    mismatch: the terms of docs/physics.md §6 eq 3 and eq 8 [YUAN13] as this rig makes them, with
    what ``mtf_tdi_model`` (eq 3 times eq 8 as written) leaves out. ``f_cy_per_px`` is on the
    focal plane (cycles per pitch); the product of

    - the aperture, ``sinc(f q)`` (eq 3's MTF_geo, ``fill_width = q / p``);
    - the exposure smear at the image's actual speed: during ``T_int`` the image moves
      ``(1 - dV/V) T_int / T_L`` pitches, so ``sinc(f (1 - dV/V) T_int / T_L)`` (eq 3's
      MTF_discrete assumes the synchronous speed, ``sinc(f T_int / T_L)``);
    - the M stages: a rolling shutter reads row ``i + 1`` one row time ``T_row`` after row
      ``i``, so between stage ``i`` of one frame and stage ``i + 1`` of the next the image
      moves ``(1 - dV/V)(1 - T_row / T_L)`` rows and slips ``s = 1 - (1 - dV/V)(1 - row_skew)``
      rows against the stage it should meet (``row_skew = T_row / T_L``; 0 for a global
      shutter: ``s = dV/V``, eq 8's slip). The M exposures sit ``s`` apart: their transfer
      function is ``|sin(pi f M s) / (M sin(pi f s))|``, whose continuous limit (``f s`` small)
      is eq 8's ``|sinc(f M dV/V)|`` with ``dV/V -> s``;
    - the scene's cells (the simulator's radiance is constant on cells of ``cell_px`` pixels:
      a box on the target, and another where the aperture integrates the cell-sampled
      target), ``sinc(f cell_px)^2`` (docs/mtf.md; 0 for a real target).

    With ``row_skew = 0``, ``cell_px = 0`` and small ``f M dV/V`` it is ``mtf_tdi_model``
    to first order in ``dV/V`` times the exposure term's change. ``dv_over_v`` may exceed 1
    (the image moves backwards); ``integration_ratio`` is ``T_int / T_L`` of the registers.

    Measured on slanted edges (``edge_tan = tan`` of their angle to the rows, signed as the
    scene's ``y = x tan(angle)``) while the image also slips ``across_slip_px`` columns per
    stage against the drift taps (a turned camera: ``tan(theta)`` minus the taps' columns a
    line), the M exposures lie along a line that is not along track, and what the edges see is
    their spread along the edges' normal: the slip becomes ``s + across_slip_px * edge_tan``
    (docs/mtf.md). Both 0: along track alone.
    """
    m = _stages(stages)
    dv = float(_as_float_array("dv_over_v", dv_over_v))
    q = _fraction("fill_width", fill_width, "photosensitive width q over pitch p")
    ratio = _fraction("integration_ratio", integration_ratio, "T_int / T_L")
    skew = _fraction("row_skew", row_skew, "T_row / T_L of a rolling shutter, 0 for global")
    cell = float(cell_px)
    if not (math.isfinite(cell) and 0.0 <= cell <= 1.0):
        raise ValueError(f"cell_px must be in [0, 1] pixel, got {cell_px!r}")
    f = _as_float_array("f_cy_per_px", f_cy_per_px)
    speed = 1.0 - dv  # image rows per line period
    slip = 1.0 - speed * (1.0 - skew) + float(across_slip_px) * float(edge_tan)
    result: FloatOrArray = _out(
        np.abs(np.sinc(f * q) * np.sinc(f * speed * ratio))
        * _dirichlet(f * slip, m)
        * np.sinc(f * cell) ** 2
    )
    return result


COMBINED_MAX_CY_PER_BIN = 0.3
"""``combined_edge_mtf`` reports up to 0.3 cycles per ESF bin (1.2 cycles per line at 4x
oversampling, 60 % of the bins' Nyquist, where the derivative and binning corrections reach
2.3): beyond ISO 12233's 1 cycle per line, for lines coarser than the pixels (a scan whose
image moves more than one row per line period)."""


@dataclass(frozen=True, slots=True, eq=False)
class CombinedEdgeMtf:
    """Result of ``combined_edge_mtf``: one MTF from the mean LSF of several slanted edges.

    ``frequencies_cy_per_px`` are along axis 0 of the image the edges were measured on (along
    track for ``axis="along"``), in cycles per focal-plane pixel: the edge-normal frequencies
    times ``cos(angle)`` over ``line_pitch_px``. ``mtf_std_error`` is the jackknife standard
    error over the edges (NaN for a single edge).
    """

    frequencies_cy_per_px: FloatArray
    mtf: FloatArray
    mtf_std_error: FloatArray
    edges: int
    edge_angle_deg: float
    line_pitch_px: float

    def _at(self, values: FloatArray, freq_cy_per_px: float) -> float:
        f = float(freq_cy_per_px)
        top = float(self.frequencies_cy_per_px[-1])
        if not 0.0 <= f <= top:
            raise ValueError(
                f"freq_cy_per_px must be in [0, {top:g}] (the lines' pitch on the focal plane "
                f"is {self.line_pitch_px:g} px), got {freq_cy_per_px!r}"
            )
        return float(np.interp(f, self.frequencies_cy_per_px, values))

    def mtf_at(self, freq_cy_per_px: float) -> float:
        """The MTF at ``freq_cy_per_px`` (focal plane) by linear interpolation."""
        return self._at(self.mtf, freq_cy_per_px)

    def std_error_at(self, freq_cy_per_px: float) -> float:
        """The jackknife standard error of ``mtf_at(freq_cy_per_px)``."""
        return self._at(self.mtf_std_error, freq_cy_per_px)


def combined_edge_mtf(
    results: tuple[SlantedEdgeMtf, ...] | list[SlantedEdgeMtf], *, line_pitch_px: float = 1.0
) -> CombinedEdgeMtf:
    """One slanted-edge MTF from several edges of one image (ISO 12233 style, docs/physics.md §6).

    Averaging each edge's MTF (``periodic_edge_mtf``) keeps every edge's noise in its modulus:
    at low SNR the noise's power adds to the MTF, most where the MTF is small (near Nyquist,
    and under velocity mismatch). Here each edge's LSF (``SlantedEdgeMtf.lsf``, sampled in
    bins centred on its fitted edge) is normalised to unit area and the LSFs are averaged bin
    by bin (over the edges that reach the bin) before the window and FFT of
    ``slanted_edge_mtf`` (steps 3-4), so the noise averages down before the modulus is taken.
    ``mtf_std_error`` is the jackknife over the edges (each left out in turn).

    ``line_pitch_px``: the pitch of the image's lines (axis 0) on the focal plane, in pixels.
    A TDI line is taken every line period, while the image moves ``1 - dV/V`` rows, so a scan
    under velocity mismatch has ``|1 - dV/V|`` (docs/physics.md §6); 1 for a synchronous scan.
    The edge-normal frequency ``nu`` (cycles per line) becomes the along-track frequency
    ``nu cos(angle) / line_pitch_px`` (cycles per pixel). Its across-track component,
    ``nu sin(angle)``, is neglected: on the focal plane it is ``f`` times the tangent of the
    target's slant whatever the line pitch, 0.044 cycles per pixel for a 5-degree edge at
    Nyquist, where a 0.71-pixel aperture loses 0.2 %.
    """
    if not results:
        raise ValueError("combined_edge_mtf needs at least one edge (slanted_edge_mtf results)")
    pitch = float(line_pitch_px)
    if not (math.isfinite(pitch) and pitch > 0.0):
        raise ValueError(f"line_pitch_px must be > 0, got {line_pitch_px!r}")
    spacing = results[0].sample_spacing_px
    axis = results[0].axis
    if any(r.sample_spacing_px != spacing or r.axis != axis for r in results):
        raise ValueError("the edges were measured with different oversampling or axes")
    oversample = round(1.0 / spacing)
    starts = [round(float(r.esf_positions_px[0]) / spacing) for r in results]
    first = min(starts)
    size = max(s + r.lsf.size for s, r in zip(starts, results, strict=True)) - first
    sums = np.zeros((len(results), size))
    present = np.zeros((len(results), size))
    for i, (start, r) in enumerate(zip(starts, results, strict=True)):
        area = float(r.lsf.sum())
        if not area > 0.0:
            raise ValueError(f"edge {i}: its LSF sums to {area:g}; not an edge")
        sums[i, start - first : start - first + r.lsf.size] = r.lsf / area
        present[i, start - first : start - first + r.lsf.size] = 1.0
    total, count = sums.sum(axis=0), present.sum(axis=0)
    # Only the bins at least half the edges reach: a bin few edges reach keeps their noise.
    covered = np.flatnonzero(count >= 0.5 * len(results))
    span = slice(int(covered[0]), int(covered[-1]) + 1)

    def mtf_of(lsf_sum: FloatArray, n: FloatArray) -> tuple[FloatArray, FloatArray]:
        lsf = lsf_sum[span] / np.maximum(n[span], 1.0)
        return _lsf_mtf(
            lsf,
            oversample,
            window=True,
            derivative="central",
            correct_binning=True,
            f_max=COMBINED_MAX_CY_PER_BIN * oversample,
        )

    freqs, mtf = mtf_of(total, count)
    edges = len(results)
    if edges > 1:
        leave_one_out = np.stack(
            [mtf_of(total - sums[i], count - present[i])[1] for i in range(edges)]
        )
        spread = leave_one_out - leave_one_out.mean(axis=0)
        error: FloatArray = np.sqrt((edges - 1) / edges * (spread**2).sum(axis=0))
    else:
        error = np.full_like(mtf, np.nan)
    angle = float(np.mean([abs(r.edge_angle_deg) for r in results]))
    along: FloatArray = freqs * math.cos(math.radians(angle)) / pitch
    return CombinedEdgeMtf(
        frequencies_cy_per_px=along,
        mtf=mtf,
        mtf_std_error=error,
        edges=edges,
        edge_angle_deg=angle,
        line_pitch_px=pitch,
    )


def pixel_noise_dn(image: npt.ArrayLike, *, axis: Axis = "along") -> float:
    """Per-pixel noise of an image of edges: the standard deviation of the second differences
    along ``axis`` over ``sqrt(6)`` (independent pixel noise ``sigma`` gives ``sqrt(6)
    sigma``), without the differences more than 5 robust sigmas from their median (the
    edges). The robust sigma (from the median absolute deviation, at least 1 DN) only gates:
    on whole-DN data it comes in steps of 1.48 DN, too coarse for the noise itself."""
    work = _lines_view(image, axis, "pixel_noise_dn")
    if work.shape[1] < 3:
        raise ValueError("pixel_noise_dn needs at least 3 pixels along the axis")
    d2 = np.diff(work, n=2, axis=1).ravel()
    centre = float(np.median(d2))
    gate = 5.0 * max(1.4826 * float(np.median(np.abs(d2 - centre))), 1.0)
    kept = d2[np.abs(d2 - centre) <= gate]
    return float(kept.std()) / math.sqrt(6.0)


# -- limiting resolution of a bar target (docs/physics.md §6, YUAN13 §4) --------------------------------

ROSE_THRESHOLD = 5.0
"""Rose's detection threshold: an object is seen when its signal over its area exceeds about 5
times the noise in that area (A. Rose, J. Opt. Soc. Am. 38:196, 1948)."""

USAF_BAR_ASPECT = 5.0
"""Length over width of a bar of the USAF-1951 (MIL-STD-150A) resolution target."""


def bar_detectability(
    delta_dn: float,
    noise_dn: float,
    frequency_cy_per_px: float,
    *,
    bar_aspect: float = USAF_BAR_ASPECT,
) -> float:
    """Rose's signal-to-noise ratio of one bar of a group at ``frequency_cy_per_px``:

        d = delta sqrt(A) / sigma,   A = bar_aspect w^2,   w = 1 / (2 f)

    ``delta_dn`` is the difference between the bright and the dark bars' levels, ``noise_dn``
    the noise of one pixel, ``A`` the bar's area in pixels (``w`` its width; a USAF-1951 bar
    is 5 widths long): the bar's signal summed over its area against the noise of that sum.
    YUAN13 §4 judged the finest resolved group by eye, and an observer sees a bar when ``d``
    exceeds about 5 (``ROSE_THRESHOLD``): the criterion makes the limiting resolution depend
    on the noise as the eye's does (docs/physics.md §6; §5: M stages raise ``delta`` M times and
    the noise ``sqrt(M)`` times).
    """
    f = float(frequency_cy_per_px)
    if not (math.isfinite(f) and 0.0 < f <= NYQUIST_CY_PER_PX):
        raise ValueError(f"frequency_cy_per_px must be in (0, 0.5], got {frequency_cy_per_px!r}")
    sigma, delta, aspect = float(noise_dn), float(delta_dn), float(bar_aspect)
    if not (math.isfinite(sigma) and sigma > 0.0):
        raise ValueError(f"noise_dn must be > 0, got {noise_dn!r}")
    if not math.isfinite(delta):
        raise ValueError(f"delta_dn must be finite, got {delta_dn!r}")
    if not (math.isfinite(aspect) and aspect > 0.0):
        raise ValueError(f"bar_aspect must be > 0, got {bar_aspect!r}")
    width = 1.0 / (2.0 * f)
    return delta * math.sqrt(aspect * width * width) / sigma


def limiting_frequency(
    frequencies_cy_per_px: npt.ArrayLike,
    detectability: npt.ArrayLike,
    *,
    threshold: float = ROSE_THRESHOLD,
) -> float:
    """The limiting resolution of a bar target (YUAN13 §4): the highest group frequency such
    that it and every coarser group are resolved (``detectability >= threshold``), in cycles
    per pixel; 0 when even the coarsest is not. Reading up from the coarsest group, as an
    observer does, a lucky fine group above an unresolved one does not count."""
    f = np.asarray(frequencies_cy_per_px, dtype=np.float64)
    d = np.asarray(detectability, dtype=np.float64)
    if f.ndim != 1 or f.shape != d.shape or f.size == 0:
        raise ValueError(
            f"frequencies and detectability must be 1-D of one length, got {f.shape}, {d.shape}"
        )
    if not np.all(np.isfinite(f)) or np.any(f <= 0):
        raise ValueError("frequencies must be finite and > 0")
    limit = 0.0
    for i in np.argsort(f, kind="stable"):
        if not d[i] >= threshold:  # NaN counts as unresolved
            break
        limit = float(f[i])
    return limit


def lp_per_mm_on_target(f_cy_per_px: float, *, pitch_m: float, magnification: float) -> float:
    """A focal-plane frequency in cycles per pixel as line pairs per mm on the target: the
    target-side pixel is ``pitch / magnification`` (docs/physics.md §6, ``n_mag``)."""
    f, p, m = float(f_cy_per_px), float(pitch_m), float(magnification)
    if not (math.isfinite(p) and p > 0 and math.isfinite(m) and m > 0 and math.isfinite(f)):
        raise ValueError(f"need finite f, pitch_m > 0 and magnification > 0; got {f}, {p}, {m}")
    return f / (p / m) / 1e3


@dataclass(frozen=True, slots=True)
class BarGroup:
    """One group of a bar target as ``bar_target_resolution`` measured it.

    ``top_dn`` and ``bottom_dn``: the bright and dark bars' levels (mean of each bar pair's
    maximum and minimum over one phase cycle of the pixels); ``noise_dn`` the pixel noise along
    the bars; ``detectability`` Rose's ``d`` (``bar_detectability``); ``lines`` how many image
    lines the group's band gave.
    """

    frequency_cy_per_px: float
    top_dn: float
    bottom_dn: float
    noise_dn: float
    detectability: float
    lines: int

    @property
    def delta_dn(self) -> float:
        """Bright minus dark bar level."""
        return self.top_dn - self.bottom_dn


@dataclass(frozen=True, slots=True)
class BarTargetResolution:
    """Result of ``bar_target_resolution``: the groups and the limiting frequency."""

    groups: tuple[BarGroup, ...]
    limit_cy_per_px: float
    threshold: float
    bar_aspect: float
    band_offset_lines: int


def _phase_cycle(f: float, n: int) -> int:
    """Pixels after which bars at ``f`` meet the pixel grid in the same phase again."""
    from fractions import Fraction

    cycle = Fraction(f).limit_denominator(1000).denominator
    if 2 * cycle > n:
        raise ValueError(
            f"bars at {f:g} cy/px repeat their phase every {cycle} px; the lines have only {n}"
        )
    return cycle


def bar_target_resolution(
    image: npt.ArrayLike,
    frequencies_cy_per_px: npt.ArrayLike,
    *,
    band_lines: int,
    margin_lines: int = 3,
    threshold: float = ROSE_THRESHOLD,
    bar_aspect: float = USAF_BAR_ASPECT,
) -> BarTargetResolution:
    """Limiting resolution of an image of a bar target whose bars vary across (axis 1) and
    whose groups follow each other along axis 0 in bands of ``band_lines`` lines, in the order
    of ``frequencies_cy_per_px``, repeating (the simulator's ``bars`` scene with
    ``orientation=across`` in a synchronous scan: 32 lines per band). YUAN13 §4, docs/physics.md §6.

    1. Bands: each line's power at each group frequency (normalised by that frequency's mean
       over the lines) is summed over the lines for every offset of the band pattern; the best
       offset assigns the lines to groups. ``margin_lines`` at each end of a band are dropped
       (the edge between bands is blurred along track).
    2. Levels: the group's lines are averaged into one profile across the bars; the profile is
       folded over the pixels after which the bars meet the pixel grid in the same phase again
       (2 pixels at 0.5 cy/px, 10 at 0.3), so the noise averages down over the whole line
       before the levels are taken; ``top`` and ``bottom`` are the means over the bar pairs of
       one such cycle of their maximum and minimum (``bar_modulation``'s "extrema").
    3. Noise: the pixels' standard deviation along the bars (axis 0, within the group's lines,
       where the target is uniform), pooled over the columns.
    4. ``bar_detectability`` with ``top - bottom``, the noise and the USAF bar area; the limit
       is ``limiting_frequency`` at ``threshold`` (Rose's 5).
    """
    data = np.asarray(image, dtype=np.float64)
    freqs = np.asarray(frequencies_cy_per_px, dtype=np.float64)
    if data.ndim != 2 or not np.all(np.isfinite(data)):
        raise ValueError(f"image must be a finite 2-D array (lines, columns), got {data.shape}")
    if freqs.ndim != 1 or freqs.size == 0:
        raise ValueError("give the groups' frequencies in band order")
    if band_lines < 2 * margin_lines + 2 or margin_lines < 0:
        raise ValueError(
            f"band_lines {band_lines} leaves fewer than 2 lines per band after a margin of "
            f"{margin_lines} at each end"
        )
    n_lines, n_cols = data.shape
    groups_n = freqs.size
    period = groups_n * band_lines
    if n_lines < period:
        raise ValueError(
            f"{n_lines} lines hold no full cycle of the target's {groups_n} bands of "
            f"{band_lines} lines; take at least {period}"
        )
    x = np.arange(n_cols, dtype=np.float64)
    centred = data - data.mean(axis=1, keepdims=True)
    power = np.abs(centred @ np.exp(-2j * np.pi * freqs[None, :] * x[:, None])) ** 2
    power /= np.maximum(power.mean(axis=0), 1e-300)
    lines = np.arange(n_lines)
    scores = [power[lines, ((lines + o) % period) // band_lines].sum() for o in range(period)]
    offset = int(np.argmax(scores))
    phase = (lines + offset) % period
    groups: list[BarGroup] = []
    for g, f in enumerate(freqs):
        if not 0.0 < f <= NYQUIST_CY_PER_PX:
            raise ValueError(f"group frequency {f:g} is outside (0, 0.5] cy/px")
        inside = phase - g * band_lines
        rows = np.flatnonzero((inside >= margin_lines) & (inside < band_lines - margin_lines))
        if rows.size < 2:
            raise ValueError(f"the group at {f:g} cy/px has {rows.size} line(s); scan longer")
        block = data[rows]
        profile = block.mean(axis=0)
        cycle = _phase_cycle(float(f), n_cols)
        folded = profile[: n_cols // cycle * cycle].reshape(-1, cycle).mean(axis=0)
        twice = np.concatenate([folded, folded])
        width = math.ceil(1.0 / f - 1e-9)
        pairs = round(f * cycle)
        windows = [twice[round(k / f) : round(k / f) + width] for k in range(pairs)]
        top = float(np.mean([w.max() for w in windows]))
        bottom = float(np.mean([w.min() for w in windows]))
        noise = math.sqrt(float(block.var(axis=0, ddof=1).mean()))
        detect = bar_detectability(top - bottom, noise, float(f), bar_aspect=bar_aspect)
        groups.append(BarGroup(float(f), top, bottom, noise, detect, int(rows.size)))
    limit = limiting_frequency(
        [g.frequency_cy_per_px for g in groups],
        [g.detectability for g in groups],
        threshold=threshold,
    )
    return BarTargetResolution(tuple(groups), limit, float(threshold), float(bar_aspect), offset)
