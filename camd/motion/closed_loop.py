"""Closed-loop scan synchronisation: the encoder's speed against the synchronous speed.

Pure logic, no I/O (``camd.daemon.motion_service`` polls the stage and applies the results).
TAO12 (docs/physics.md §2) proposes re-computing the timing in real time from the measured scan
speed instead of trusting a fixed line period; with a stage encoder camd does that, either by
trimming the stepper's rate so the stage meets the line period (``SpeedTrim``) or by trimming
the line period to the stage (``LinePeriodTrim``: coarse by n_lines, fine by the back path).

Both act on the ratio ``g = measured speed / commanded speed`` that the stage's imperfections
(clock error, ripple, drift) make: an error in the step clock scales every speed alike, so a
ratio learnt at one command predicts the next. ``g`` is smoothed with gain ``gain`` per sample
(1 = dead-beat: trusts each sample fully, and passes encoder noise and jitter straight on);
with ``predict`` it is extrapolated one poll ahead from its last change, which takes out most of
the loop's lag on a smooth (slow ripple) disturbance at the price of doubling the noise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from camd.timing import tdi_window
from camd.timing._checks import positive


@dataclass(frozen=True, slots=True)
class EncoderSample:
    """One reading of the stage at one device time (s): the encoder's position and the step
    generator's commanded position (m), latched together."""

    time_s: float
    position_m: float
    commanded_m: float


class SpeedEstimator:
    """Measured and commanded speeds (m/s) over the readings of the last ``window_s``.

    Both are least-squares slopes of positions latched at the same device times, so their
    ratio is exact however the command changed inside the window (a correction lands a round
    trip after the reading it answers), and the quantisation of the encoder and of the step
    counter averages down over the window, which spans at least ``window_s`` and ``min_span_m``
    of travel. ``centre_s`` is the window's mean time: what the estimate describes.
    """

    def __init__(self, window_s: float = 0.04, *, min_span_m: float = 0.0) -> None:
        self.window_s = positive("window_s", window_s)
        self.span_s = 0.0  # time the last estimate's readings span
        # A coarse encoder (few counts per poll) needs a longer baseline: the window also spans
        # at least this much travel.
        self.min_span_m = min_span_m
        self._samples: list[EncoderSample] = []
        self.centre_s = math.nan

    def add(self, sample: EncoderSample) -> tuple[float, float] | None:
        """(measured speed, commanded speed) over the window up to ``sample``; None until the
        window holds two readings at different times."""
        samples = self._samples
        samples.append(sample)
        while (
            len(samples) > 2
            and sample.time_s - samples[1].time_s >= self.window_s
            and abs(sample.position_m - samples[1].position_m) >= self.min_span_m
        ):
            samples.pop(0)
        t = np.array([s.time_s for s in samples])
        if len(samples) < 2 or t[-1] - t[0] <= 0.0:
            return None
        self.centre_s = float(t.mean())
        self.span_s = float(t[-1] - t[0])
        dt = t - self.centre_s
        norm = float(dt @ dt)
        measured = float(dt @ np.array([s.position_m for s in samples])) / norm
        commanded = float(dt @ np.array([s.commanded_m for s in samples])) / norm
        return measured, commanded


class SpeedTrim:
    """Trim the commanded stage speed so the measured speed meets ``target_m_s``.

    ``update(measured, commanded, ...)`` learns ``g = measured / commanded`` and returns the
    next command ``target / g``, clamped to ``max_trim`` (relative) of the target: a loop that
    would need more than that is fighting something it cannot fix (a stall, a wrong profile),
    and a runaway command is worse than an uncorrected scan. With ``predict``, ``g`` is
    extrapolated from the time its estimate describes (``at_s``) to the time the correction
    will act (``until_s``) along its last change.
    """

    def __init__(
        self,
        target_m_s: float,
        *,
        gain: float = 0.6,
        max_trim: float = 0.1,
        predict: bool = False,
    ) -> None:
        if not 0.0 < gain <= 1.0:
            raise ValueError(f"gain = {gain}: use 0 < gain <= 1 (1 = dead-beat)")
        if not 0.0 < max_trim < 1.0:
            raise ValueError(f"max_trim = {max_trim}: use a fraction between 0 and 1")
        if target_m_s == 0.0 or not math.isfinite(target_m_s):
            raise ValueError(f"target_m_s = {target_m_s}: the stage must move")
        self.target_m_s = target_m_s
        self.gain = gain
        self.max_trim = max_trim
        self.predict = predict
        self.ratio = 1.0
        self._history: list[tuple[float, float]] = []  # (time the estimate describes, ratio)

    def update(
        self,
        measured_m_s: float,
        commanded_m_s: float,
        *,
        at_s: float = math.nan,
        until_s: float = math.nan,
        baseline_s: float = 0.0,
    ) -> float:
        """The next commanded speed (m/s) after a measurement made under ``commanded_m_s``.

        ``baseline_s``: the slope for the prediction is taken over estimates at least this far
        apart (the estimator's window: closer ones share most of their readings, and their
        difference would be mostly the encoder's quantisation)."""
        if commanded_m_s != 0.0 and math.isfinite(measured_m_s):
            sample = measured_m_s / commanded_m_s
            if sample > 0.0:
                self.ratio += self.gain * (sample - self.ratio)
        ratio = self.ratio
        history = self._history
        previous = None
        for then_s, then_ratio in reversed(history):
            if at_s - then_s >= baseline_s:
                previous = (then_s, then_ratio)
                break
        if self.predict and previous is not None and at_s > previous[0] and until_s > at_s:
            # The estimate describes ``at_s``; the correction acts until ``until_s``: a smooth
            # disturbance (ripple) moves on meanwhile.
            slope = (self.ratio - previous[1]) / (at_s - previous[0])
            ratio += slope * (until_s - at_s)
        if math.isfinite(at_s):
            history.append((at_s, self.ratio))
            # Keep what the next baselines can reach back to.
            while len(history) > 2 and at_s - history[1][0] > 2 * baseline_s + 1.0:
                history.pop(0)
        command = self.target_m_s / ratio
        lo = abs(self.target_m_s) * (1.0 - self.max_trim)
        hi = abs(self.target_m_s) * (1.0 + self.max_trim)
        return math.copysign(min(max(abs(command), lo), hi), self.target_m_s)


@dataclass(frozen=True, slots=True)
class LinePeriodSetting:
    """A line period and the window that realises it (docs/physics.md §2 eqs 8-9)."""

    line_period_s: float
    n_lines: int
    back_path_s: float


class LinePeriodTrim:
    """Trim the TDI line period to the measured image speed (TAO12: coarse by n_lines, fine by
    the back path; docs/physics.md §2 eqs 5, 8, 9).

    The period that matches a measured image speed v is ``p (1 - offset) / v`` (``offset`` a
    deliberate dV/V; 0 normally); the window is ``tdi_window`` of it, with n_lines clamped to
    ``min_lines`` (the stage count: fewer rows could not hold M stages) — at the clamp the
    period cannot shorten further and the loop reports ``limited`` — and to ``max_lines`` (the
    rows of the frames the stream started with: the host's frame size is fixed per stream),
    beyond which the back path takes the rest, even if that is a row period or more.
    """

    def __init__(
        self,
        *,
        pixel_pitch_m: float,
        row_time_s: float,
        min_lines: int,
        max_lines: int | None = None,
        gain: float = 0.6,
        offset: float = 0.0,
    ) -> None:
        self.pitch_m = positive("pixel_pitch_m", pixel_pitch_m)
        self.row_time_s = positive("row_time_s", row_time_s)
        self.min_lines = min_lines
        self.max_lines = max_lines
        self.gain = gain
        self.offset = offset
        self.speed_m_s: float | None = None
        self.limited = False

    def update(self, image_speed_m_s: float) -> LinePeriodSetting:
        """The line period setting for a new measurement of the image speed (m/s)."""
        speed = abs(image_speed_m_s)
        if self.speed_m_s is None:
            self.speed_m_s = speed
        elif speed > 0.0 and math.isfinite(speed):
            self.speed_m_s += self.gain * (speed - self.speed_m_s)
        period = self.pitch_m * (1.0 - self.offset) / self.speed_m_s
        setting, self.limited = period_setting(
            period, self.row_time_s, min_lines=self.min_lines, max_lines=self.max_lines
        )
        return setting


def period_setting(
    period_s: float, row_time_s: float, *, min_lines: int, max_lines: int | None
) -> tuple[LinePeriodSetting, bool]:
    """The window that realises a line period (docs/physics.md §2 eqs 8-9), with n_lines
    clamped to ``min_lines`` (the stage count: the period cannot shorten further, and the
    second value, ``limited``, is then True) and to ``max_lines`` (the rows of the frames the
    stream started with), beyond which the back path takes the rest."""
    shortest = min_lines * row_time_s
    limited = period_s < shortest
    period = max(period_s, shortest)
    window = tdi_window(period, row_time_s)
    if max_lines is not None and window.n_lines > max_lines:
        back = period - max_lines * row_time_s
        return LinePeriodSetting(period, max_lines, back), limited
    return LinePeriodSetting(period, window.n_lines, window.back_path_s), limited
