"""The scan stage's imperfections (docs/motion.md): speed error, ripple, jitter, drift, load.

``StageFaults`` holds them for the simulated stepper stage (``firmware_models.stage``, whose
docstring gives the model each one enters); ``FAULT_RANGES`` the range of each, which
``--inject stage_*`` and SIM_SET_STAGE_FAULTS check.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from camd.motion.stage_profile import StageProfile

# key: (lowest, highest, meaning); the ranges of --inject stage_* and SIM_SET_STAGE_FAULTS.
FAULT_RANGES: dict[str, tuple[float, float, str]] = {
    "error": (-0.1, 0.1, "relative step-rate error"),
    "ripple": (0.0, 0.2, "relative amplitude of the periodic speed ripple"),
    "jitter": (0.0, 0.2, "relative rms random speed jitter"),
    "drift": (-0.1, 0.1, "relative speed drift per second of running"),
    "load": (0.0, 3.0, "load torque as a fraction of the low-speed pull-out torque"),
}


@dataclass(frozen=True, slots=True)
class StageFaults:
    """The stage's imperfections (see the module docstring); all zero is a perfect stage."""

    error: float = 0.0
    ripple: float = 0.0
    jitter: float = 0.0
    drift: float = 0.0
    load: float = 0.0

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            lo, hi, meaning = FAULT_RANGES[f.name]
            if not lo <= value <= hi:  # NaN too
                raise ValueError(
                    f"stage fault {f.name} = {value:g} is out of range: {f.name} ({meaning}) "
                    f"must be from {lo:g} to {hi:g}"
                )

    @classmethod
    def from_profile(cls, profile: StageProfile) -> StageFaults:
        """The profile's ``[sim]`` defaults."""
        sim = profile.sim
        return cls(sim.error, sim.ripple, sim.jitter, sim.drift, sim.load)

    def updated(self, **changes: float | None) -> StageFaults:
        """A copy with the given (non-None) values changed."""
        return replace(self, **{k: float(v) for k, v in changes.items() if v is not None})

    def as_dict(self) -> dict[str, float]:
        return {f.name: float(getattr(self, f.name)) for f in fields(self)}
