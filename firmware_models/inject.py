"""Fault injection on the simulated RS-422 line: bit errors, dropped frames, garbage, latency.

``InjectSpec`` is the contract of ``--inject`` and of the SIM_SET_INJECT command (the
``stage_*`` keys set the simulated scan stage's imperfections, as SIM_SET_STAGE_FAULTS does);
``FaultInjector`` applies it with a seeded numpy Generator so that a failing test can be
replayed exactly. The injector works on bytes and decisions only; where it sits in the byte
path is the transport's business (see ``firmware_models.pty_server``).
"""

from __future__ import annotations

import math
from typing import Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from firmware_models.spec_text import key_values

Direction = Literal["rx", "tx"]

GARBAGE_MAX_BYTES = 32
# The keys that set the stepper stage's imperfections rather than line faults.
STAGE_KEYS = ("stage_error", "stage_ripple", "stage_jitter", "stage_drift", "stage_load")


class InjectSpecError(ValueError):
    """An ``--inject`` text or value is invalid; the message says which key and what is allowed."""


def _knob(lo: float, hi: float, description: str) -> Any:
    """A fault knob of ``InjectSpec``: 0 (off) by default, accepted from ``lo`` to ``hi``."""
    return Field(default=0.0, ge=lo, le=hi, description=description)


class InjectSpec(BaseModel):
    """Fault rates for the simulated line. All zero (the default) means a perfect line."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    ber: float = _knob(0.0, 0.01, "bit error rate per bit, each direction")
    drop: float = _knob(0.0, 0.5, "probability a frame is dropped, each direction")
    garbage: float = _knob(
        0.0,
        0.5,
        f"probability of a burst of 1..{GARBAGE_MAX_BYTES} random bytes before a sent frame",
    )
    delay_ms: float = _knob(0.0, 1000.0, "latency added to every response, milliseconds")
    # The USB frame stream (firmware_models.fx3.StreamEngine), rates per frame.
    frame_drop: float = _knob(
        0.0, 0.5, "probability a stream frame is not sent (its counter is used up)"
    )
    frame_corrupt: float = _knob(
        0.0, 0.5, "probability a stream frame is sent with one payload bit flipped after its CRC"
    )
    frame_short: float = _knob(
        0.0, 0.5, "probability a stream frame's USB transfer ends early (a truncated frame)"
    )
    frame_stall: float = _knob(
        0.0,
        0.5,
        "probability the bulk endpoint halts instead of sending a frame "
        "(the frame is lost; nothing is sent until the host clears the halt)",
    )

    # The stepper scan stage (firmware_models.stage / firmware_models.motor): its
    # imperfections, the knobs SIM_SET_STAGE_FAULTS sets; not line faults (FaultInjector
    # ignores them; ``stage_faults()`` hands them to MotorController.set_faults). 0: none.
    stage_error: float = _knob(
        -0.1,
        0.1,
        "stage: relative step-rate error (speed too high by this fraction; "
        "5e-5 is a clock 50 ppm fast)",
    )
    stage_ripple: float = _knob(
        0.0,
        0.2,
        "stage: relative amplitude of the periodic speed ripple "
        "(period: the stage profile's ripple_period_m)",
    )
    stage_jitter: float = _knob(
        0.0,
        0.2,
        "stage: relative rms random speed jitter "
        "(correlated over the stage profile's jitter_corr_s)",
    )
    stage_drift: float = _knob(
        -0.1, 0.1, "stage: relative speed drift per second of continuous running"
    )
    stage_load: float = _knob(
        0.0,
        3.0,
        "stage: load torque as a fraction of the motor's pull-out torque "
        "(above what the motor delivers at the speed, it misses steps)",
    )

    @classmethod
    def known_keys(cls) -> list[str]:
        """The keys ``parse`` accepts, in declaration order."""
        return list(cls.model_fields)

    @classmethod
    def valid_range(cls, key: str) -> tuple[float, float]:
        """(lowest, highest) accepted value of ``key``, read from the field's constraints."""
        lo, hi = -math.inf, math.inf
        for meta in cls.model_fields[key].metadata:
            lo = float(getattr(meta, "ge", lo))
            hi = float(getattr(meta, "le", hi))
        return lo, hi

    @classmethod
    def parse(cls, text: str) -> InjectSpec:
        """Parse ``"ber=1e-4,drop=0.01"``; an empty (or blank) text means no faults.

        Raises InjectSpecError naming the offending key, its value and the valid range, or
        listing the known keys for an unknown one."""
        items = key_values(
            text,
            what="--inject",
            example="ber=1e-4,drop=0.01",
            keys_note=f"keys: {', '.join(cls.known_keys())}",
            error=InjectSpecError,
        )
        return cls(**{key: cls._check_value(key, raw) for key, raw in items})

    @classmethod
    def checked(cls, **values: float) -> InjectSpec:
        """Build a spec from keyword values with the same messages as ``parse``."""
        for key, value in values.items():
            cls._check_value(key, f"{value:g}", value)
        return cls(**values)

    @classmethod
    def _check_value(cls, key: str, raw: str, value: float | None = None) -> float:
        if key not in cls.model_fields:
            raise InjectSpecError(
                f"unknown --inject key {key!r}; known keys: {', '.join(cls.known_keys())}"
            )
        if value is None:
            try:
                value = float(raw)
            except ValueError:
                value = math.nan
        lo, hi = cls.valid_range(key)
        if not lo <= value <= hi:  # also false for NaN, so non-numbers land here
            meaning = cls.model_fields[key].description
            raise InjectSpecError(
                f"--inject {key}={raw} is invalid: {key} ({meaning}) must be a number "
                f"from {lo:g} to {hi:g}"
            )
        return float(value)

    def stage_faults(self) -> dict[str, float]:
        """The ``stage_*`` values by their SIM_SET_STAGE_FAULTS names (``error``, ``ripple``,
        ``jitter``, ``drift``, ``load``), for ``MotorController.set_faults``."""
        return {key.removeprefix("stage_"): getattr(self, key) for key in STAGE_KEYS}

    @property
    def active(self) -> bool:
        """True if any fault is enabled."""
        return any(getattr(self, key) for key in self.known_keys())

    def describe(self) -> str:
        """The enabled faults as ``"ber=0.0001 drop=0.01"``, or ``"none"``."""
        parts = [f"{key}={getattr(self, key):g}" for key in self.known_keys() if getattr(self, key)]
        return " ".join(parts) if parts else "none"


class FaultInjector:
    """Applies an InjectSpec to the line, reproducibly for a given seed, and counts what it did.

    Counters (the SIM_GET_INJECTED fields): ``bit_errors`` (bits flipped, both directions),
    ``dropped_rx`` / ``dropped_tx`` (frames discarded host-to-device / device-to-host),
    ``garbage_bursts`` and ``delayed`` (frames sent late).
    """

    def __init__(self, spec: InjectSpec | None = None, seed: int | None = 0) -> None:
        self.spec = spec if spec is not None else InjectSpec()
        self._rng = np.random.default_rng(seed)
        self.bit_errors = 0
        self.dropped_rx = 0
        self.dropped_tx = 0
        self.garbage_bursts = 0
        self.delayed = 0

    def set(self, spec: InjectSpec) -> None:
        """Change the rates from now on; the counters keep counting."""
        self.spec = spec

    def corrupt(self, data: bytes) -> bytes:
        """Return ``data`` with each bit flipped independently with probability ``ber``.

        The number of flips is drawn binomially and their positions without replacement, so the
        cost is proportional to the number of flips, not to the number of bits."""
        ber = self.spec.ber
        if ber <= 0.0 or not data:
            return data
        n_bits = len(data) * 8
        n_flips = int(self._rng.binomial(n_bits, ber))
        if n_flips == 0:
            return data
        positions = self._rng.choice(n_bits, size=n_flips, replace=False)
        buf = np.frombuffer(data, dtype=np.uint8).copy()
        masks = np.left_shift(1, 7 - (positions & 7)).astype(np.uint8)
        # .at, not fancy-index assignment: two flips may land in the same byte.
        np.bitwise_xor.at(buf, positions >> 3, masks)
        self.bit_errors += n_flips
        return buf.tobytes()

    def drop(self, direction: Direction = "rx") -> bool:
        """Decide whether the next frame travelling in ``direction`` is lost (and count it)."""
        if self.spec.drop <= 0.0 or self._rng.random() >= self.spec.drop:
            return False
        if direction == "rx":
            self.dropped_rx += 1
        else:
            self.dropped_tx += 1
        return True

    def garbage(self) -> bytes:
        """Random bytes to put on the line before the next sent frame; usually empty."""
        if self.spec.garbage <= 0.0 or self._rng.random() >= self.spec.garbage:
            return b""
        self.garbage_bursts += 1
        n = int(self._rng.integers(1, GARBAGE_MAX_BYTES, endpoint=True))
        return self._rng.integers(0, 256, size=n, dtype=np.uint8).tobytes()

    def response_delay_s(self) -> float:
        """Latency to add to the next response frame, in seconds (counted when non-zero)."""
        delay_s = self.spec.delay_ms / 1000.0
        if delay_s > 0.0:
            self.delayed += 1
        return delay_s

    def counters(self) -> dict[str, int]:
        """The counters, named as the SIM_GET_INJECTED response fields."""
        return {
            "bit_errors": self.bit_errors,
            "dropped_rx": self.dropped_rx,
            "dropped_tx": self.dropped_tx,
            "garbage_bursts": self.garbage_bursts,
            "delayed": self.delayed,
        }
