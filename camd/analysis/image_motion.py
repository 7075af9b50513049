"""Image motion measured from the frames: velocity mismatch and drift angle by registration.

docs/physics.md §10, "Image motion from the frames", gives the relations and the precision
expected; this module implements them. Pure: numpy and OpenCV, no I/O, no daemon types.

Convention (the simulator's, ``firmware_models.scene``): between two frames the scene's image
has moved by ``(s, t)`` pixels when the later frame ``B`` shows at ``(r, c)`` what the earlier
frame ``A`` showed at ``(r + s, c + t)``: ``B(r, c) = A(r + s, c + t)``. In TDI mode the camera
sends a window every line period and, with the image in step with the line transfer, ``s`` is
exactly 1 row per line with a global shutter. The image's speed over the synchronous speed is
``v = V_m / V = s / (1 - s lambda)`` (``lambda`` a rolling shutter's ``T_row / T_line``, 0 for a
global one: §10 "A rolling shutter"), so the velocity mismatch of docs/physics.md §6,
``dV/V = (V - V_m) / V``, is ``1 - v`` (positive when the image moves slower than one row per
line, the sign camd's encoder figures use, so the two can be compared and subtracted as they
are). A drift angle ``theta`` moves the image ``tan(theta)``
columns per row of its motion, ``t = s tan(theta)`` columns per line, so ``theta = atan2(t, s)``:
the direction of the image's motion (positive towards higher column indices, the simulator's
``drift_deg``, whose lateral shift is the displacement times ``tan(drift_deg)``).

The registration of a pair (why this method): a Gauss-Newton least-squares fit of the
translation (Lucas-Kanade; the criterion ECC maximises, without ECC's normalisation), started at
the nominal shift (the frame-counter gap in TDI mode, the stage's step in area mode), warping
with bicubic interpolation (``cv2.remap``) over the overlap only. Compared on the simulator's
windows (natural texture and bar target, 32 and 96 rows x 256 columns, shift 1.013 rows and
0.0123 columns per line): ``cv2.phaseCorrelate`` with a Hanning window scattered 0.01-0.1 px per
pair and was biased by 0.02-0.05 px (the Hanning window discards most of a short window's rows,
and its centroid peak interpolation pulls towards whole pixels); it failed outright on 8-row
windows. ``cv2.findTransformECC`` scattered 0.002-0.004 px but diverged on 8-row windows of the
bar target and, warping the whole window, was biased by its border (0.03 px at 32 rows). The
fit over the overlap, started at the known nominal shift, needs no coarse search (the nominal is
within a few hundredths of a pixel per line of the truth) and reaches the noise limit of the
physics section. Its cost on one core (one thread): 0.3 ms per 8 x 256 window, 1.1 ms per
96 x 256, 7 ms per 96 x 2048 (one bicubic warp per iteration, about 3 iterations per pair when
started at the previous pair's motion).

Interpolation bias (docs/physics.md §10, "Interpolation bias"): OpenCV's bicubic kernel
(Keys' cubic convolution, ``a = -0.75``) moves each spatial frequency of the warped frame by a
slightly wrong amount, so the fit is biased by a fraction of the shift's distance from a whole
pixel that depends on the scene's spectrum (3-4 % on the simulator's natural texture, 14-16 % on
its bar target). ``interpolation_bias_px`` predicts it from a scene's power spectrum and the
kernel's frequency response; the measured shifts are not corrected by it (a window's own
spectrum, 8 rows tall, is too poor an estimate of the scene's). Removing it at the source was
tried and left: OpenCV's Lanczos kernel reads 3-4 pixels either side, which an 8-row window's
4-row overlap does not have; warping both frames symmetrically about the fraction where the
kernel's phase error is stationary (about 0.21 px), with gradients smoothed against the
frequencies near Nyquist, cut the bias to about 1 % (natural) and 2-3 % (bars) on 32- and 96-row
windows at 1.1-1.2 times the cost, but not on 8-row ones (3 % and 4-11 %), and left 2-5 sigma
on the bar target at 96 rows.

Which pairs (docs/physics.md §10, "Which pairs"): every frame is registered on the first, its
search started where the fit so far predicts, until its predicted shift would pass half the
window (``MAX_BASELINE_FRACTION``); the previous frame is then the next reference. The rate is
the weighted least-squares slope of the shifts against the baselines (the frame counters'
distances: a dropped frame is a longer baseline, not motion), one intercept per reference
(its own error, which its pairs share), each pair weighing its overlap's pixels
(``rate_coefficients``). Long baselines give the precision, keep the pairs far from the zero
shift a fixed pattern pulls towards, and spread the pairs' fractions of a pixel, over which the
interpolation's bias averages out.

Fixed-pattern noise (a pattern fixed to the sensor correlates at zero shift and pulls an
estimate towards 0): ``background`` (a dark or background frame, same shape as the windows) is
subtracted first when given; otherwise the per-column mean over the whole sequence (every row
of every window) is subtracted, which removes column offsets (the dominant fixed pattern of a
TDI window) while the moving scene averages out over the sequence. ``flat`` (a gain pattern of
mean 1, ``flat_from_mean`` of many moving windows) then divides the pixel gains out.

Low texture: a pair's gradient energy is compared with the noise's own. The noise variance
comes from the fit's residual; the gradients of white noise of variance ``sigma^2`` (central
differences) carry ``sigma^2 / 2`` per pixel. A sequence whose scene gradient energy along or
across track is below ``TEXTURE_SNR_MIN`` times the noise's is reported ``measurable=False``
with the reason, not as a number.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

TEXTURE_SNR_MIN = 1.0
"""Scene gradient energy over the noise's gradient energy, per axis, below which a pair is not
measured (a flat scene gives 0 +- sqrt(2 / pixels); a textured one tens to thousands)."""

FIT_ITERATIONS_MAX = 12
FIT_TOLERANCE_PX = 1e-4
MAX_BASELINE_FRACTION = 0.5
"""The longest shift (rows) a frame may have from its reference, over the window's rows: a
pair over a smaller overlap adds little precision and its interpolation error depends more on
what the few rows it sees hold (docs/physics.md §10, "Which pairs")."""
SEARCH_PX = 0.25
"""How far (pixels) a pair's shift may lie from the nominal (the counter gap, the stage's step):
the fit starts there and a shift further off is not this pair's (the pair is left out)."""
CUBIC_A = -0.75
"""The parameter ``a`` of OpenCV's bicubic kernel (``cv2.INTER_CUBIC``, Keys' cubic convolution)."""
INTERPOLATION_BIAS_ITERATIONS = 20


@dataclass(frozen=True)
class RegisteredPair:
    """A frame registered on a reference frame: their indices in the sequence, the steps
    between them (lines, or rows of stage motion: the baseline) and the overlap's pixels the
    shift was fitted over (its weight in the rate's fit)."""

    reference: int
    frame: int
    baseline: float
    overlap_px: int


@dataclass(frozen=True)
class ImageMotion:
    """The image's motion per line period measured from a sequence of frames.

    ``shift_along_px_per_line`` (rows) and ``shift_across_px_per_line`` (columns) follow the
    module's convention; their standard errors come from the scatter of the pair estimates
    about the fit (NaN with fewer than 3 pairs). When ``measurable`` is False the shifts are
    NaN and ``why`` says what is missing.
    """

    shift_along_px_per_line: float
    shift_across_px_per_line: float
    shift_along_stderr_px: float
    shift_across_stderr_px: float
    frames_used: int
    pairs_used: int
    measurable: bool
    why: str

    registered: tuple[RegisteredPair, ...] = ()
    """The pairs the rates were fitted from (converged ones), in the order registered."""
    row_lag_lines: float = 0.0
    """A rolling shutter's lag between consecutive rows, in line periods (``T_row / T_line``;
    0 for a global or frame-transfer shutter), signed as ``measure_tdi_motion`` says."""

    @property
    def image_speed_px_per_line(self) -> float:
        """Rows the image moves per line period, ``v = s / (1 - s lambda)`` (docs/physics.md
        §10, "A rolling shutter"): the shift between frames ``s`` is the image's speed only
        when every row is exposed at once (``lambda = 0``)."""
        s = self.shift_along_px_per_line
        return s / (1.0 - s * self.row_lag_lines)

    @property
    def dv_over_v(self) -> float:
        """Velocity mismatch ``dV/V = 1 - v`` (docs/physics.md §6's sign: positive when the
        image moves slower than one row per line; §10 for ``v``)."""
        return 1.0 - self.image_speed_px_per_line

    @property
    def dv_over_v_stderr(self) -> float:
        """``dv/ds = 1 / (1 - s lambda)^2`` times the standard error of ``s``."""
        s = self.shift_along_px_per_line
        return self.shift_along_stderr_px / (1.0 - s * self.row_lag_lines) ** 2

    def m_dv_over_v(self, stages: int) -> float:
        """``M dV/V``: the along-track smear in rows over ``stages`` TDI stages (signed)."""
        if stages < 1:
            raise ValueError(f"stages must be >= 1, got {stages}")
        return stages * self.dv_over_v

    @property
    def theta_deg(self) -> float:
        """Drift angle ``atan2(shift_across, shift_along)`` in degrees: the direction of the
        image's motion (``atan(shift_across)`` to within ``dV/V`` of it)."""
        return math.degrees(math.atan2(self.shift_across_px_per_line, self.shift_along_px_per_line))


@dataclass(frozen=True)
class PairShift:
    """One registered pair: its shift (rows, columns) and the fit's quality figures."""

    along_px: float
    across_px: float
    texture_snr_along: float
    texture_snr_across: float
    noise_sigma_dn: float
    converged: bool
    overlap_px: int = 0  # pixels the shift was fitted over


def measure_tdi_motion(
    frames: Sequence[npt.ArrayLike],
    frame_counters: Sequence[int],
    *,
    background: npt.ArrayLike | None = None,
    flat: npt.ArrayLike | None = None,
    row_lag_lines: float = 0.0,
) -> ImageMotion:
    """The image motion per line from TDI window frames in the order received.

    ``frames``: windows of equal shape ``(rows, cols)`` (uint16 or any real type), one per line
    period; ``frame_counters``: the camera's frame counter of each, strictly increasing (a gap
    of ``g`` means ``g - 1`` frames were dropped). Pairs whose gap leaves fewer than 3 rows of
    overlap are skipped. ``background``: a dark or background frame subtracted from every
    window (else the per-column mean over the sequence is, module doc). ``row_lag_lines``: a
    rolling shutter's ``T_row / T_line``, positive when the image moves towards the rows read
    first (a forward scan on a sensor read from row 0), negative the other way, 0 for a global
    shutter; it converts the shift between frames into the image's speed (``ImageMotion``).
    """
    counters = [int(c) for c in frame_counters]
    if len(counters) != len(frames):
        raise ValueError(
            f"{len(frames)} frames but {len(counters)} frame counters: give one counter per frame"
        )
    gaps = np.diff(np.asarray(counters, dtype=np.int64))
    if np.any(gaps <= 0):
        raise ValueError(
            "frame counters must increase strictly in the order of the frames; sort the frames "
            "by counter and drop repeated ones"
        )
    if not (math.isfinite(row_lag_lines) and abs(row_lag_lines) < 0.5):
        raise ValueError(
            f"row_lag_lines = {row_lag_lines}: a rolling shutter's T_row / T_line is below 0.5 "
            "(a window of 2 rows or more); give 0 for a global shutter"
        )
    result = _measure(frames, [float(g) for g in gaps], background, flat)
    return dataclasses.replace(result, row_lag_lines=float(row_lag_lines))


def measure_area_motion(
    frames: Sequence[npt.ArrayLike],
    step_rows: Sequence[float],
    *,
    background: npt.ArrayLike | None = None,
    flat: npt.ArrayLike | None = None,
) -> ImageMotion:
    """The image motion per row of stage motion from successive area frames.

    ``step_rows[i]``: the stage's motion between ``frames[i]`` and ``frames[i + 1]`` in rows of
    the image (the encoder's displacement over the pixel's footprint); the result's
    ``shift_along_px_per_line`` is the image's motion per row of stage motion (``1 - dV/V``: a
    magnification error ``m'/m - 1`` shows as ``dV/V = -(m'/m - 1)``) and ``shift_across_px_per_line`` the columns per row
    (tan(theta)).
    """
    steps = [float(s) for s in step_rows]
    if len(steps) != len(frames) - 1:
        raise ValueError(
            f"{len(frames)} frames need {len(frames) - 1} steps between them, got {len(steps)}"
        )
    if not all(math.isfinite(s) and s > 0.0 for s in steps):
        raise ValueError("every stage step must be a finite number of rows above 0")
    return _measure(frames, steps, background, flat)


def register_pair(
    earlier: npt.NDArray[np.float32],
    later: npt.NDArray[np.float32],
    nominal_along_px: float,
    nominal_across_px: float = 0.0,
    *,
    start: tuple[float, float] | None = None,
) -> PairShift | None:
    """The shift ``(s, t)`` with ``later(r, c) = earlier(r + s, c + t)`` by Gauss-Newton within
    ``SEARCH_PX`` of the nominal, started at ``start`` (the previous pair's motion: fewer
    iterations) or at the nominal; None when the overlap is too small to fit (fewer than 3 rows
    or columns)."""
    rows, cols = earlier.shape
    s, t = float(nominal_along_px), float(nominal_across_px)
    # One overlap for every iteration, with room for the fit to move SEARCH_PX from the
    # nominal: an overlap that followed the estimate would change its pixels whenever the
    # shift crossed a whole pixel, and the fit could oscillate between two sets.
    window = _overlap(rows, cols, s, t, SEARCH_PX)
    if window is None:
        return None
    r0, r1, c0, c1 = window
    # The gradients are the later frame's, over the fixed overlap: at the solution the warped
    # earlier frame equals it, so the Gauss-Newton step is the same to first order, and the
    # Hessian is computed once (one warp per iteration instead of three). Central differences
    # leave out the pixel itself, so a gradient's noise is independent of the residual's.
    grad_rows, grad_cols = _central_gradients(later)
    gy = grad_rows[r0:r1, c0:c1].ravel().astype(np.float64)
    gx = grad_cols[r0:r1, c0:c1].ravel().astype(np.float64)
    hessian = np.array([[gy @ gy, gy @ gx], [gx @ gy, gx @ gx]])
    singular = bool(np.linalg.cond(hessian) > 1e12)
    target = later[r0:r1, c0:c1].ravel().astype(np.float64)
    grid_y, grid_x = np.meshgrid(
        np.arange(r0, r1, dtype=np.float64), np.arange(c0, c1, dtype=np.float64), indexing="ij"
    )
    if start is not None and abs(start[0] - s) < SEARCH_PX and abs(start[1] - t) < SEARCH_PX:
        s, t = start
    converged = False
    residual = np.zeros(0, dtype=np.float64)
    for _ in range(0 if singular else FIT_ITERATIONS_MAX):
        if abs(s - nominal_along_px) > SEARCH_PX or abs(t - nominal_across_px) > SEARCH_PX:
            break  # left the search range: not this pair's shift
        map_y = (grid_y + s).astype(np.float32)
        map_x = (grid_x + t).astype(np.float32)
        warped = cv2.remap(earlier, map_x, map_y, cv2.INTER_CUBIC, borderMode=cv2.BORDER_REPLICATE)
        residual = target - warped.ravel()
        step = np.linalg.solve(hessian, np.array([gy @ residual, gx @ residual]))
        s += float(step[0])
        t += float(step[1])
        if abs(step[0]) < FIT_TOLERANCE_PX and abs(step[1]) < FIT_TOLERANCE_PX:
            converged = True
            break
    if residual.size == 0:
        residual = target - earlier[r0:r1, c0:c1].ravel()
    # residual = noise of both frames (variance 2 sigma^2) once fitted
    sigma2 = max(float(np.var(residual)) / 2.0, 1e-12)
    noise_gradient = sigma2 / 2.0
    return PairShift(
        along_px=s,
        across_px=t,
        texture_snr_along=(float(np.mean(gy * gy)) - noise_gradient) / noise_gradient,
        texture_snr_across=(float(np.mean(gx * gx)) - noise_gradient) / noise_gradient,
        noise_sigma_dn=math.sqrt(sigma2),
        converged=converged,
        overlap_px=(r1 - r0) * (c1 - c0),
    )


def cubic_response(fraction: float, omega: npt.ArrayLike) -> npt.NDArray[np.complex128]:
    """The frequency response ``H_f(omega) = sum_k h(f - k) exp(i omega k)`` (k = -1..2) of
    OpenCV's bicubic interpolation read at ``fraction`` ``f`` in [0, 1) of a pixel past a sample:
    a sampled ``exp(i omega n)`` comes out as ``H_f(omega) exp(i omega n)`` where an exact shift
    gives ``exp(i omega (n + f))`` (docs/physics.md §10, "Interpolation bias")."""
    w = np.asarray(omega, dtype=np.float64)
    response = np.zeros(w.shape, dtype=np.complex128)
    for k in (-1, 0, 1, 2):
        response += _cubic_weight(fraction - k) * np.exp(1j * w * k)
    return response


def interpolation_bias_px(
    scene: npt.ArrayLike, shift_along_px: float, shift_across_px: float
) -> tuple[float, float]:
    """The bias ``(along, across)`` in pixels of ``register_pair``'s shift for a pair whose later
    frame is the earlier moved by exactly ``(shift_along_px, shift_across_px)``, in a scene with
    the power spectrum of ``scene`` (one period of a periodic scene, rows x columns).

    docs/physics.md §10, "Interpolation bias": the fit stops where the residual is orthogonal to
    the later frame's central-difference gradients; per spatial frequency the warped frame holds
    ``G_s(omega_y) G_t(omega_x)`` (the bicubic kernel's response at the shift, ``cubic_response``)
    where the later frame holds ``exp(i omega . (s, t))``, so the estimate ``(s', t')`` solves

        sum_omega P(omega) sin(omega_a) Im(exp(-i omega . (s, t)) G_s'(omega_y) G_t'(omega_x)) = 0

    for ``a`` = along and across, with ``P`` the scene's power spectrum (Newton's method, started
    at the true shift). The bias is ``(s' - s, t' - t)``; noise adds no bias to first order.
    """
    image = np.asarray(scene, dtype=np.float64)
    if image.ndim != 2 or min(image.shape) < 2:
        raise ValueError(f"scene must be a 2-D image of at least 2 x 2 pixels, got {image.shape}")
    power = np.abs(np.fft.fft2(image - image.mean())) ** 2
    omega_y = (2 * np.pi * np.fft.fftfreq(image.shape[0])[:, None]).astype(np.float64)
    omega_x = (2 * np.pi * np.fft.fftfreq(image.shape[1])[None, :]).astype(np.float64)
    weight_y = power * np.sin(omega_y)
    weight_x = power * np.sin(omega_x)
    truth_y = np.exp(-1j * omega_y * shift_along_px)
    truth_x = np.exp(-1j * omega_x * shift_across_px)

    def balance(estimate: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        moved = (truth_y * _warp_response(float(estimate[0]), omega_y)) * (
            truth_x * _warp_response(float(estimate[1]), omega_x)
        )
        return np.array([np.sum(weight_y * moved.imag), np.sum(weight_x * moved.imag)])

    truth = np.array([shift_along_px, shift_across_px], dtype=np.float64)
    estimate = truth.copy()
    step_px = 1e-6  # the kernel is C1, so a forward difference gives the Jacobian closely
    for _ in range(INTERPOLATION_BIAS_ITERATIONS):
        value = balance(estimate)
        jacobian = np.column_stack(
            [(balance(estimate + step_px * unit) - value) / step_px for unit in np.eye(2)]
        )
        if np.linalg.cond(jacobian) > 1e12:
            raise ValueError(
                "the scene has no texture along one axis: no shift, so no bias, can be found"
            )
        change = np.linalg.solve(jacobian, value)
        estimate -= change
        if float(np.max(np.abs(change))) < 1e-12:
            break
    return float(estimate[0] - truth[0]), float(estimate[1] - truth[1])


def _cubic_weight(x: float) -> float:
    """Keys' cubic convolution kernel with OpenCV's ``a`` (``CUBIC_A``)."""
    a = CUBIC_A
    u = abs(x)
    if u <= 1.0:
        return (a + 2) * u**3 - (a + 3) * u**2 + 1
    if u < 2.0:
        return a * u**3 - 5 * a * u**2 + 8 * a * u - 4 * a
    return 0.0


def _warp_response(shift_px: float, omega: npt.NDArray[np.float64]) -> npt.NDArray[np.complex128]:
    """What ``cv2.remap`` bicubic makes of ``exp(i omega n)`` read at ``n + shift_px``: the
    whole pixels exactly, the fraction through ``cubic_response``."""
    whole = math.floor(shift_px)
    response: npt.NDArray[np.complex128] = np.exp(1j * omega * whole) * cubic_response(
        shift_px - whole, omega
    )
    return response


def _central_gradients(
    image: npt.NDArray[np.float32],
) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.float32]]:
    """Central differences along rows and columns (the edge pixels copy their neighbour's):
    white noise of variance ``sigma^2`` gives them ``sigma^2 / 2`` each."""
    grad_rows = np.empty_like(image)
    grad_cols = np.empty_like(image)
    grad_rows[1:-1] = (image[2:] - image[:-2]) / 2
    grad_rows[0], grad_rows[-1] = grad_rows[1], grad_rows[-2]
    grad_cols[:, 1:-1] = (image[:, 2:] - image[:, :-2]) / 2
    grad_cols[:, 0], grad_cols[:, -1] = grad_cols[:, 1], grad_cols[:, -2]
    return grad_rows, grad_cols


def _overlap(
    rows: int, cols: int, s: float, t: float, search_px: float
) -> tuple[int, int, int, int] | None:
    """The later frame's rows [r0, r1) and columns [c0, c1) whose positions shifted by
    ``(s, t)`` +- ``search_px`` lie inside the earlier frame with the interpolation's margin."""
    # bicubic reads pixels floor(y) - 1 .. floor(y) + 2: y in [1, n - 2] reads at most one
    # pixel past the edge, replicated (cv2.BORDER_REPLICATE), which a window of 8 rows needs
    r0 = max(0, math.ceil(1 - s + search_px))
    r1 = min(rows, math.floor(rows - 2 - s - search_px) + 1)
    c0 = max(0, math.ceil(1 - t + search_px))
    c1 = min(cols, math.floor(cols - 2 - t - search_px) + 1)
    if r1 - r0 < 3 or c1 - c0 < 3:
        return None
    return r0, r1, c0, c1


def _not_measurable(frames_used: int, pairs_used: int, why: str) -> ImageMotion:
    nan = float("nan")
    return ImageMotion(nan, nan, nan, nan, frames_used, pairs_used, False, why)


def _measure(
    frames: Sequence[npt.ArrayLike],
    steps: Sequence[float],
    background: npt.ArrayLike | None,
    flat: npt.ArrayLike | None = None,
) -> ImageMotion:
    """Each frame registered on the first, the shifts fitted as ``shift = c + rate * position``
    (module docstring, "Which pairs")."""
    if len(frames) < 2:
        raise ValueError(f"need at least 2 frames to measure motion, got {len(frames)}")
    stack = _prepared(frames, background, flat)
    positions = np.concatenate([[0.0], np.cumsum(np.asarray(steps, dtype=np.float64))])
    groups: list[list[tuple[RegisteredPair, PairShift]]] = [[]]  # one reference frame each
    skipped = 0
    # Where the next pair's search starts: the nominal (one row per step) until the pairs
    # fitted so far say better; a pair's prediction is then off by the rate's error times its
    # baseline, well inside SEARCH_PX while the baselines grow a step at a time.
    rate, offset = (1.0, 0.0), (0.0, 0.0)
    ref, k = 0, 1
    while k < stack.shape[0]:
        g = float(positions[k] - positions[ref])
        predicted = offset[0] + rate[0] * g
        shift = None
        if abs(predicted) <= MAX_BASELINE_FRACTION * stack.shape[1] or k - ref == 1:
            shift = register_pair(stack[ref], stack[k], predicted, offset[1] + rate[1] * g)
        if shift is None:
            # The overlap with the reference ran out: the previous frame is the next one's
            # reference; a frame that overlaps not even its predecessor is left out.
            if k - ref == 1:
                skipped += 1
                ref, k = k, k + 1
            else:
                ref = k - 1
            groups.append([])
            offset = (0.0, 0.0)
            continue
        groups[-1].append((RegisteredPair(ref, k, g, shift.overlap_px), shift))
        fit = _fit(groups)
        if fit is not None:
            rate, offset = (fit.rate_along, fit.rate_across), fit.last_intercepts
        elif shift.converged and g > 0:
            rate = (shift.along_px / g, shift.across_px / g)  # one pair so far: its own rate
        k += 1
    pairs = [pair for group in groups for pair in group]
    frames_used = len(frames)
    if not pairs:
        return _not_measurable(
            frames_used,
            0,
            f"no frame overlaps the first by 3 rows or more ({skipped} skipped): take "
            "consecutive frames or a smaller step",
        )
    snr_along = float(np.median([p.texture_snr_along for _, p in pairs]))
    snr_across = float(np.median([p.texture_snr_across for _, p in pairs]))
    if snr_along < TEXTURE_SNR_MIN or snr_across < TEXTURE_SNR_MIN:
        return _not_measurable(
            frames_used,
            len(pairs),
            f"scene texture too low: gradient energy over the noise's {snr_along:.3g} along "
            f"and {snr_across:.3g} across track (needs {TEXTURE_SNR_MIN:g} on both): point "
            "the camera at a textured scene or raise the light level",
        )
    fit = _fit(groups)
    if fit is None:
        n = sum(1 for _, p in pairs if p.converged)
        return _not_measurable(
            frames_used,
            len(pairs),
            f"{n} frame(s) registered on a reference: a rate needs 2 on one reference (give "
            "more frames that overlap)",
        )
    n = len(fit.registered)
    rate_along, rate_across = fit.rate_along, fit.rate_across
    se_along, se_across = fit.stderr_along, fit.stderr_across
    why = f"{n} frames registered on {fit.references} reference frame(s)"
    if skipped or n < len(pairs):
        why += f"; {skipped + len(pairs) - n} left out (no overlap or not converged)"
    return ImageMotion(
        shift_along_px_per_line=rate_along,
        shift_across_px_per_line=rate_across,
        shift_along_stderr_px=se_along,
        shift_across_stderr_px=se_across,
        frames_used=frames_used,
        pairs_used=n,
        measurable=True,
        why=why,
        registered=fit.registered,
    )


def _prepared(
    frames: Sequence[npt.ArrayLike],
    background: npt.ArrayLike | None,
    flat: npt.ArrayLike | None,
) -> npt.NDArray[np.float32]:
    """The frames as one float32 stack, the fixed pattern taken out (module docstring)."""
    stack = np.stack([np.asarray(f, dtype=np.float32) for f in frames])
    if stack.ndim != 3:
        raise ValueError(f"frames must be 2-D images of one shape, got a stack {stack.shape}")
    if not np.all(np.isfinite(stack)):
        raise ValueError("the frames hold NaN or infinite pixels")
    for name, image in (("background", background), ("flat", flat)):
        if image is not None and np.shape(image) != stack.shape[1:]:
            raise ValueError(
                f"{name} is {np.shape(image)}, the frames {stack.shape[1:]}: give a {name} "
                "of the windows' shape"
            )
    if background is not None:
        stack -= np.asarray(background, dtype=np.float32)
    else:
        stack -= stack.mean(axis=(0, 1), dtype=np.float64).astype(np.float32)
    if flat is not None:
        gain = np.asarray(flat, dtype=np.float32)
        if not (np.all(np.isfinite(gain)) and np.all(gain > 0)):
            raise ValueError("the flat holds pixels that are not finite and above 0")
        stack /= gain
    return stack


def _centred(pairs: Sequence[RegisteredPair]) -> tuple[npt.NDArray[np.float64], ...]:
    """(weights summing to 1, baselines centred on their reference's weighted mean)."""
    w = np.array([p.overlap_px for p in pairs], dtype=np.float64)
    g = np.array([p.baseline for p in pairs], dtype=np.float64)
    dg = np.empty_like(g)
    refs = np.array([p.reference for p in pairs])
    for ref in np.unique(refs):
        on = refs == ref
        dg[on] = g[on] - float(w[on] @ g[on]) / float(w[on].sum())
    return w / w.sum(), dg


def rate_coefficients(pairs: Sequence[RegisteredPair]) -> npt.NDArray[np.float64]:
    """The coefficients ``c_k`` of the rate the measurement fits, ``rate = sum c_k y_k`` for
    per-pair shifts ``y_k`` (docs/physics.md §10, "Which pairs"): the weighted least-squares
    slope against the baselines, one intercept per reference frame, each pair weighing its
    overlap's pixels. The rate's error from per-pair errors ``e_k`` is ``sum c_k e_k``."""
    w, dg = _centred(pairs)
    coefficients: npt.NDArray[np.float64] = w * dg / float(w @ (dg * dg))
    return coefficients


def rate_from_pairs(pairs: Sequence[RegisteredPair], values: npt.ArrayLike) -> float:
    """The rate fitted to per-pair ``values`` (``rate_coefficients``)."""
    return float(rate_coefficients(pairs) @ np.asarray(values, dtype=np.float64))


def rate_sigma(pairs: Sequence[RegisteredPair], sigmas: npt.ArrayLike) -> float:
    """The rate's standard deviation for independent per-pair errors of standard deviations
    ``sigmas`` (docs/physics.md §10, "Precision"): ``sqrt(sum c_k^2 sigma_k^2)``."""
    c = rate_coefficients(pairs)
    return math.sqrt(float(np.sum((c * np.asarray(sigmas, dtype=np.float64)) ** 2)))


@dataclass(frozen=True)
class _Fit:
    rate_along: float
    rate_across: float
    stderr_along: float
    stderr_across: float
    references: int  # reference frames with 2 or more pairs
    last_intercepts: tuple[float, float]  # the last reference's (0 if it has no line yet)
    registered: tuple[RegisteredPair, ...]


def _fit(groups: Sequence[Sequence[tuple[RegisteredPair, PairShift]]]) -> _Fit | None:
    """``rate_from_pairs`` along and across over the converged pairs of the references that
    have two or more (None until one has), with standard errors from the scatter about the
    lines (the weights taken as the inverse variances up to a common factor; NaN without a
    residual degree of freedom), and the last reference's intercepts (where the next pair's
    search starts)."""
    used = [[(r, p) for r, p in group if p.converged] for group in groups]
    used = [group for group in used if len(group) >= 2]
    if not used:
        return None
    pairs = [r for group in used for r, _ in group]
    shifts = [p for group in used for _, p in group]
    w, dg = _centred(pairs)
    sxx = float(w @ (dg * dg))
    if sxx <= 0.0:
        return None
    dof = len(pairs) - len(used) - 1
    refs = np.array([r.reference for r in pairs])
    rates: list[float] = []
    errors: list[float] = []
    for values in ([p.along_px for p in shifts], [p.across_px for p in shifts]):
        y = np.array(values)
        rate = rate_from_pairs(pairs, y)
        residual = np.empty_like(y)
        for ref in np.unique(refs):
            on = refs == ref
            residual[on] = y[on] - float(w[on] @ y[on]) / float(w[on].sum()) - rate * dg[on]
        rates.append(rate)
        # The weights sum to 1 and stand for the inverse variances up to a factor k:
        # k = dof / sum(w r^2), and the rate's variance is 1 / (k sum(w dg^2)).
        errors.append(
            math.sqrt(float(w @ (residual * residual)) / dof / sxx) if dof >= 1 else math.nan
        )
    intercepts = (0.0, 0.0)
    last = [(r, p) for r, p in groups[-1] if p.converged]
    if last:
        lw = np.array([r.overlap_px for r, _ in last], dtype=np.float64)
        lg = np.array([r.baseline for r, _ in last])
        g_mean = float(lw @ lg) / lw.sum()
        intercepts = (
            float(lw @ np.array([p.along_px for _, p in last])) / lw.sum() - rates[0] * g_mean,
            float(lw @ np.array([p.across_px for _, p in last])) / lw.sum() - rates[1] * g_mean,
        )
    return _Fit(rates[0], rates[1], errors[0], errors[1], len(used), intercepts, tuple(pairs))


FLAT_BOX_ROWS = 9
"""Rows of the running mean that ``flat_from_mean`` divides by (odd)."""


def flat_from_mean(mean_frame: npt.ArrayLike) -> npt.NDArray[np.float32]:
    """A gain pattern fixed to the sensor (PRNU) from the mean of many moving windows
    (docs/physics.md §10, "Fixed pattern"): in a push-broom scan every row of a column sees the
    same ground passing, so the mean frame is the column's mean ground times each pixel's gain;
    over a running mean of ``FLAT_BOX_ROWS`` rows along each column (fewer in a shorter window)
    the smooth part (the ground, and what is left of it from a finite number of frames) divides
    out and the pixel-to-pixel pattern stays. ``mean_frame`` must have the offset (background
    or dark) removed; the result is positive, of mean 1, for ``measure_tdi_motion``'s ``flat``.
    """
    mean = np.asarray(mean_frame, dtype=np.float32)
    if mean.ndim != 2 or mean.shape[0] < 3:
        raise ValueError(f"the mean frame must be 2-D with 3 rows or more, got {mean.shape}")
    box = min(FLAT_BOX_ROWS, mean.shape[0] - (1 - mean.shape[0] % 2))
    smooth = cv2.blur(mean, (1, box), borderType=cv2.BORDER_REFLECT)
    floor = max(float(np.median(np.abs(smooth))) * 1e-3, 1e-6)
    flat = mean / np.where(np.abs(smooth) > floor, smooth, np.nan)
    flat[~np.isfinite(flat) | (flat <= 0)] = 1.0
    flat /= float(flat.mean())
    out: npt.NDArray[np.float32] = flat.astype(np.float32)
    return out
