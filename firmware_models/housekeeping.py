"""Housekeeping model of the simulated camera: temperatures, supplies, current, uptime.

Temperatures warm up exponentially from ambient to an operating point after power-on, with a
slow mean-reverting random walk (an Ornstein-Uhlenbeck process, so it wanders but stays
plausible however long the simulator runs) and small white measurement noise on top. Supplies
and current are nominal values with a little noise. Time is passed in explicitly and the noise
comes from a seeded generator, so a sequence of ``sample`` calls is reproducible.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

AMBIENT_DEGC = 22.0
_RNG_STREAM = 0x484B  # "HK"
_UPTIME_WRAP_MS = 2**32  # the device counts uptime in a u32 of milliseconds


@dataclass(frozen=True, slots=True)
class ThermalParams:
    """One temperature channel: warm-up from ambient plus wander and noise."""

    operating_degc: float
    warmup_tau_s: float
    wander_sigma_degc: float = 0.3  # stationary spread of the slow random walk
    wander_tau_s: float = 60.0  # correlation time of the random walk
    noise_sigma_degc: float = 0.05  # sample-to-sample measurement noise


FPGA_THERMAL = ThermalParams(operating_degc=45.0, warmup_tau_s=180.0)
SENSOR_THERMAL = ThermalParams(operating_degc=35.0, warmup_tau_s=240.0)

SUPPLIES_V = {"vcc_core_v": 1.0, "vcc_io_v": 3.3, "vcc_sensor_v": 3.3}
SUPPLY_NOISE_REL = 0.002
SUPPLY_CURRENT_A = 1.2
SUPPLY_CURRENT_NOISE_A = 0.01


class _Wander:
    """Ornstein-Uhlenbeck process advanced exactly over any time step."""

    def __init__(self, sigma: float, tau_s: float) -> None:
        self.sigma = sigma
        self.tau_s = tau_s
        self.value = 0.0
        self.t_s: float | None = None

    def advance(self, now_s: float, rng: np.random.Generator) -> float:
        if self.t_s is not None:
            dt_s = max(0.0, now_s - self.t_s)
            decay = math.exp(-dt_s / self.tau_s)
            self.value = self.value * decay + self.sigma * math.sqrt(1.0 - decay * decay) * float(
                rng.standard_normal()
            )
        self.t_s = now_s
        return self.value


class HousekeepingModel:
    """Produces HOUSEKEEPING samples for a camera powered on at ``power_on_s``.

    ``sample(now_s)`` returns every HOUSEKEEPING field except ``executed``, which is the FPGA's
    command counter and is added by ``FpgaModel``. A soft RESET restarts the uptime
    (``restart_uptime``) but not the thermal warm-up: the hardware stays powered.
    """

    def __init__(
        self, *, seed: int | None = 0, power_on_s: float = 0.0, ambient_degc: float = AMBIENT_DEGC
    ) -> None:
        # A stream of its own: the fault injector may be seeded with the same number.
        self._rng = np.random.default_rng(None if seed is None else (seed, _RNG_STREAM))
        self.power_on_s = power_on_s
        self.uptime_origin_s = power_on_s
        self.ambient_degc = ambient_degc
        self._fpga_wander = _Wander(FPGA_THERMAL.wander_sigma_degc, FPGA_THERMAL.wander_tau_s)
        self._sensor_wander = _Wander(SENSOR_THERMAL.wander_sigma_degc, SENSOR_THERMAL.wander_tau_s)

    def restart_uptime(self, now_s: float) -> None:
        """Start counting uptime again from ``now_s`` (soft reset)."""
        self.uptime_origin_s = now_s

    def uptime_s(self, now_s: float) -> float:
        """Time since power-on or the last reset, wrapping like the device's u32 ms counter."""
        elapsed_ms = int(max(0.0, now_s - self.uptime_origin_s) * 1000.0)
        return (elapsed_ms % _UPTIME_WRAP_MS) / 1000.0

    def sample(self, now_s: float) -> dict[str, float]:
        """One housekeeping sample at ``now_s`` (same time base as ``power_on_s``)."""
        on_s = max(0.0, now_s - self.power_on_s)
        values = {
            "uptime_s": self.uptime_s(now_s),
            "fpga_temp_degc": self._temperature(FPGA_THERMAL, self._fpga_wander, on_s, now_s),
            "sensor_temp_degc": self._temperature(SENSOR_THERMAL, self._sensor_wander, on_s, now_s),
        }
        for name, nominal_v in SUPPLIES_V.items():
            values[name] = nominal_v * (1.0 + SUPPLY_NOISE_REL * float(self._rng.standard_normal()))
        values["supply_current_a"] = SUPPLY_CURRENT_A + SUPPLY_CURRENT_NOISE_A * float(
            self._rng.standard_normal()
        )
        return values

    def _temperature(
        self, params: ThermalParams, wander: _Wander, on_s: float, now_s: float
    ) -> float:
        rise = (params.operating_degc - self.ambient_degc) * (
            1.0 - math.exp(-on_s / params.warmup_tau_s)
        )
        noise = params.noise_sigma_degc * float(self._rng.standard_normal())
        return self.ambient_degc + rise + wander.advance(now_s, self._rng) + noise
