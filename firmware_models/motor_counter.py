"""The stepper controller's counters: the step counter and the encoder, read from the stage.

The step counter (``steps``) is ``round(P - offset)``, ``P`` the commanded position in
microsteps; the encoder counts ``floor((x - reference_m) * counts_per_m)`` from the true
position ``x``. Both count from power-on (offset 0, reference 0) until a homing's trip of the
home switch makes that point 0 microsteps and 0 counts: each change starts an epoch (from its
time on, its offset and reference hold). A homing planned but not yet reached is forgotten
when its motion is replaced (``forget_after``).

The imaging pipeline reads the encoder for every frame header (``encoder_counts`` for a block
of frames, ``revision`` per frame), so these are read straight from here.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from firmware_models.stage import StepperStage

I32_MIN = -(2**31)
I32_MAX = 2**31 - 1


@dataclass(slots=True)
class Epoch:
    """From ``t_s`` on, steps = P - ``offset`` and the encoder counts from ``reference_m``."""

    t_s: float
    offset: float
    reference_m: float
    homed: bool


class StepCounter:
    """The step counter and the encoder of ``stage`` (see the module docstring)."""

    def __init__(self, stage: StepperStage, t0_s: float) -> None:
        self.stage = stage
        self._epochs = [Epoch(t0_s, 0.0, 0.0, homed=False)]
        self._epoch_changes = 0  # see ``revision``

    @property
    def revision(self) -> int:
        """Changes whenever a command changed what the stage does or where the encoder counts
        from: encoder counts looked up at one revision stay true until it changes."""
        return self.stage.revision + self._epoch_changes

    def epoch_at(self, t_s: float) -> Epoch:
        """The epoch in force at ``t_s``."""
        for epoch in reversed(self._epochs):
            if epoch.t_s <= t_s:
                return epoch
        return self._epochs[0]

    def homed(self, t_s: float) -> bool:
        """The home switch has set the counters by ``t_s``."""
        return self.epoch_at(t_s).homed

    def steps(self, t_s: float) -> int:
        """The step counter (commanded position, microsteps) at ``t_s``."""
        with self.stage.lock:
            p, _ = self.stage.commanded_at(t_s)
            return round(p - self.epoch_at(t_s).offset)

    def encoder_count(self, t_s: float) -> int:
        """The encoder count at ``t_s`` (what the FPGA latches into a frame header)."""
        return self.encoder_counts([t_s])[0]

    def encoder_counts(self, times_s: Sequence[float]) -> list[int]:
        """``encoder_count`` at each of ``times_s``, in one look-up of the stage (a block of
        frames' latches at once: one vectorised call costs about what one scalar call does)."""
        with self.stage.lock:
            times = np.asarray(times_s, dtype=np.float64)
            references = {self.epoch_at(float(t)).reference_m for t in times}
            if len(references) == 1:
                return [int(c) for c in self.stage.encoder_counts(times, references.pop())]
            # A homing's trip among them: each time with its own epoch's reference.
            return [
                int(
                    self.stage.encoder_counts(np.array([t]), self.epoch_at(float(t)).reference_m)[0]
                )
                for t in times
            ]

    def encoder_and_rate(self, t_s: float, window_s: float) -> tuple[int, float]:
        """The encoder count at ``t_s`` and its rate in counts per second over the
        ``window_s`` before (a shorter window right after the start or the kept history's
        beginning; 0 at the very start)."""
        since = max(t_s - window_s, self.stage.kept_from_s, self.stage.t0_s)
        now_counts = self.encoder_count(t_s)
        if t_s - since > 0.0:
            before = self.encoder_count(since)
            return now_counts, (now_counts - before) / (t_s - since)
        return now_counts, 0.0

    def forget_after(self, t_s: float) -> None:
        """Forget the epochs that start after ``t_s`` (a homing whose trip is not reached)."""
        self._epochs = [e for e in self._epochs if e.t_s <= t_s]
        self._epoch_changes += 1

    def rezero(self, t_s: float, offset: float, reference_m: float) -> None:
        """From ``t_s`` on (the home switch's trip) steps count from commanded position
        ``offset`` and the encoder from ``reference_m``; the stage is homed."""
        self._epochs.append(Epoch(t_s, offset, reference_m, homed=True))
        self._epoch_changes += 1


def i32(value: int) -> int:
    """A counter as the FPGA's 32-bit register holds it (wrapping, signed)."""
    return (int(value) - I32_MIN) % 2**32 + I32_MIN
