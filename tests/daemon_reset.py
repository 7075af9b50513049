"""A daemon shared by a module's tests, put back through the API after each as it was found.

``Found.of(client)`` notes what a fresh daemon's camera is set to (registers, mode, scene, wheel,
stage); ``put_back(client, found)`` ends what a test left running and sets each of those back,
through the same API a test uses. ``state_documents(client)`` is what a client reads of that
state, without what only counts or times (event logs, counters, clocks, the last acquisition's
summary, the wheel's angle, which turns with time): tests/test_daemon_reset.py checks that a
daemon put back answers it as a fresh one does.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any, cast

from camd.client import CamdClient
from camd.client_types import RegisterConfig

SETTLE_S = 60.0  # generous: the suite runs on a busy 2-core machine
# A reading's position may differ from the one asked for by this much (one microstep: 1.5625 um
# on linear_rail) after a move.
POSITION_TOLERANCE_M = 5e-6


@dataclass(frozen=True)
class Found:
    """What a fresh daemon's camera was set to, to put back."""

    registers: RegisterConfig
    mode: str
    scene: str
    wheel_speed_deg_s: float
    wheel_compensation: bool
    stage_position_m: float
    stage_enabled: bool

    @classmethod
    def of(cls, client: CamdClient) -> Found:
        """Note the daemon's state as it is now (call it on a fresh daemon)."""
        wheel = client.wheel()
        reading = client.motion()["reading"]
        return cls(
            registers=client.register_config(),
            mode=str(client.status()["mode"]),
            scene=str(client.sim_settings()["scene"]),
            wheel_speed_deg_s=float(wheel["speed_deg_s"]),
            wheel_compensation=bool(wheel["compensation"]),
            stage_position_m=float(reading["position_m"]),
            stage_enabled=reading["state"] != "disabled",
        )


def put_back(client: CamdClient, found: Found) -> None:
    """End what runs (a stream, a scan, a stage move), release an emergency stop, set the
    camera, the simulator and the daemon back to ``found``, and train the sensor's link if it
    lost its training; control is held meanwhile and released at the end."""
    client.take_control(60)
    try:
        if client.estop_state()["latched"]:
            client.release_estop()
        if client.scan()["state"] == "running":
            client.stop_scan()
            client.wait_scan(SETTLE_S)
        if client.stream()["streaming"]:
            client.stop_stream()
        client.clear_fail_next()
        client.set_stage_faults()
        client.set_stage(track=True, speed_m_s=0.0)
        client.set_polarizer(None)
        client.set_scene(found.scene)
        client.clear_background()
        if client.status()["mode"] != found.mode:
            client.set_mode(found.mode)
        client.load_register_config(found.registers)
        client.set_wheel_compensation(found.wheel_compensation)
        client.set_wheel_speed(found.wheel_speed_deg_s)
        _stage_back(client, found)
        if not client.last_training()["trained"]:
            client.train()
    finally:
        client.release_control()


def _stage_back(client: CamdClient, found: Found) -> None:
    reading = client.motion()["reading"]
    if reading["state"] not in ("disabled", "idle", "estop"):
        client.stop_stage()
        client.wait_stage()
        reading = client.motion()["reading"]
    if abs(float(reading["position_m"]) - found.stage_position_m) > POSITION_TOLERANCE_M:
        client.enable_stage(True)
        client.move_stage(found.stage_position_m)
    client.enable_stage(found.stage_enabled)
    deadline = time.monotonic() + SETTLE_S
    while client.motion()["reading"]["speed_m_s"] != 0.0:
        assert time.monotonic() < deadline, "the stage did not stand still"
        time.sleep(0.05)


def state_documents(client: CamdClient) -> dict[str, Any]:
    """What a client reads of the state a test may change: the daemon's and the camera's
    status, the registers and the timing they set, the stage, the wheel, the simulator's
    settings, control, the emergency stop, the streams and the background; without counts,
    clocks and the last acquisition's summary (history, not state)."""
    status = cast(dict[str, Any], client.status())
    device = status["device"] or {}
    motion = cast(dict[str, Any], client.motion())
    reading = motion["reading"]
    wheel = cast(dict[str, Any], client.wheel())
    stream = client.stream()
    training = cast(dict[str, Any], client.last_training())
    return {
        "status": {
            "state": status["state"],
            "reason": status["reason"],
            "mode": status["mode"],
            "connected": status["link"]["connected"],
            "device": {k: device.get(k) for k in ("mode", "device_state", "fault_code")},
            # The last acquisition stays in the status once ended (history): only a running
            # one is state.
            "acquisition_running": bool((status["acquisition"] or {}).get("running")),
            "control_holder": status["control"]["holder"],
            "estop_latched": status["estop"]["latched"],
        },
        "registers": client.register_config(),
        "timing": client.timing(),
        "stage": {
            **{k: v for k, v in motion.items() if k not in ("reading", "operation")},
            # The last move stays in the document once ended (history): only a running one is.
            "operation_active": bool((motion["operation"] or {}).get("active")),
            "reading": {
                k: v for k, v in reading.items() if k not in ("time_s", "position_m", "encoder_m")
            },
            # Where it stands, to 10 um: a move back ends within a microstep of its target.
            "position_m": round(float(reading["position_m"]), 5),
        },
        "wheel": {k: v for k, v in wheel.items() if k not in ("angle_deg", "channel", "time_s")},
        "sim": client.sim_settings(),
        "stream": {"streaming": stream["streaming"], "recording": stream["recording"]},
        "scan_running": client.scan()["state"] == "running",
        "background": client.background()["state"],
        "training": {k: training[k] for k in ("sensor", "interface", "trained", "lanes")},
    }
