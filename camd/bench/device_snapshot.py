"""The camera's state as the device itself reports it, to compare before and after a request.

``snapshot(client)`` reads, over the daemon's API: the daemon's state, the imaging mode from the
device's GET_STATUS, every non-volatile register of the sensor's register file (write-only ones
from the daemon's copy), the stage (MOTOR_GET: state, commanded position, which is where it
goes or stands, encoder, speed, limits in force), the filter wheel (speed and delay
compensation; its angle and channel only when it stands, since it turns otherwise), and what
the daemon last set on the simulator (scene, ideal stage, polariser, stage faults). Volatile
registers (status counters, flags) change by themselves and are left out.

The tests (``tests/device_snapshot.py``) and ``camd bench fuzz`` compare it before and after a
refused request: a refusal changes nothing.
"""

from __future__ import annotations

from typing import Any

from camd.client import CamdClient
from camd.sensor.regmap import load_register_map


def snapshot(client: CamdClient) -> dict[str, Any]:
    """The device's state as the device reports it (module docstring)."""
    status = client.status()
    device = status["device"]
    assert device is not None, "the camera does not answer GET_STATUS"
    regmap = load_register_map(client.timing()["sensor"])
    volatile = {reg.name for reg in regmap.registers if reg.volatile}
    registers = {
        r["name"]: r["value"] for r in client.registers()["registers"] if r["name"] not in volatile
    }
    motion = client.motion()
    reading = motion["reading"]
    wheel = client.wheel()
    wheel_state: dict[str, Any] = {
        "speed_deg_s": wheel["speed_deg_s"],
        "compensation": wheel["compensation"],
    }
    if wheel["speed_deg_s"] == 0.0:
        wheel_state.update(angle_deg=wheel["angle_deg"], channel=wheel["channel"])
    return {
        "state": status["state"],
        "mode": device["mode"],
        "registers": registers,
        "stage": {
            key: reading[key]
            for key in ("state", "homed", "position_m", "encoder_m", "speed_m_s", "at_limit")
        },
        "stage_limits": motion["limits"],
        "wheel": wheel_state,
        "sim": client.sim_settings(),
    }
