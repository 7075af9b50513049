"""The scan stage under the simulated camera: where the target is at a given time.

A stage is any object with ``position_m(t_s)``: the object-side position of the target along
track, in metres, at each time of an array (seconds). The camera turns it into image rows with
the optics magnification and the pixel pitch (physics.md §2: v_image = magnification * v_stage,
one row per ``p / v_image`` seconds). ``LinearStage`` moves at a constant speed; a stepper with
ripple and jitter (the next model) only has to provide ``position_m`` too.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.floating[Any]]


class Stage(Protocol):
    """Anything that can say where the target is along track."""

    def position_m(self, t_s: FloatArray) -> FloatArray:
        """Object-side position along track (m) at each time ``t_s`` (s)."""
        ...


@dataclass(frozen=True, slots=True)
class LinearStage:
    """A stage at constant speed: ``x(t) = x0 + v t``."""

    speed_m_s: float
    position0_m: float = 0.0

    def position_m(self, t_s: FloatArray) -> FloatArray:
        """``x0 + v t`` for each time."""
        result: FloatArray = self.position0_m + self.speed_m_s * np.asarray(t_s, dtype=np.float64)
        return result
