"""Campaigns from a known baseline, and the daemon's settings put back afterwards.

A campaign's results must not depend on what was done to the daemon before it. Before its
first step the runner records the settings the daemon has (``capture``), then brings the camera
to the campaign's declared baseline (``apply_baseline``):

- ``camctl reset``: the imaging mode back to area, a fault cleared, and the sensor's
  configurable registers back at their power-up values;
- on the simulated camera: the baseline scene (a flat field unless the campaign says
  otherwise), the reference polariser out, the ideal stage tracking, no stage faults;
- the scan stage stopped where it stands (``stage: stop``, the default: on the simulator the
  scene then moves with the ideal stage, so the stepper's position does not matter), or
  enabled and homed (``stage: home``: on a bench whose scans drive the stage; homing approaches
  the switch slowly, up to half a minute from mid-travel on the shipped rail), or stopped with
  the motor released (``stage: release``);
- the filter wheel turning at its nominal speed (as from power-on), delay compensation off.

When the campaign ends, or fails, ``restore`` puts back what was recorded (registers, mode, the
simulator's settings, the stage's position and whether it was enabled, the wheel) and returns
what it restored, in words, for the report. Everything goes through ``camd.client``: the
runner never touches the device itself.
"""

from __future__ import annotations

import contextlib
import time
from dataclasses import dataclass
from typing import Any

from camd.campaign.spec import BaselineSpec
from camd.client import CamdClient, CamdError
from camd.client_types import SimSettings

HOME_TIMEOUT_S = 120.0  # homing from the far end of the shipped rail at 20 mm/s, with margin
STAGE_TOLERANCE_M = 1e-6  # a stage this close to where it stood is back
NO_FAULTS = {"error": 0.0, "ripple": 0.0, "jitter": 0.0, "drift": 0.0, "load": 0.0}


def describe(baseline: BaselineSpec) -> list[str]:
    """The baseline in words, for the report."""
    parts = [
        "camera reset (mode area, fault cleared, sensor registers at their power-up values)",
        f"simulated camera: scene {baseline.scene}, polariser out, ideal stage tracking, no "
        "stage faults",
        "filter wheel at its nominal speed, delay compensation off",
        {
            "stop": "scan stage stopped where it stood",
            "home": "scan stage enabled and homed",
            "release": "scan stage stopped, motor released",
        }[baseline.stage],
    ]
    return parts


@dataclass(frozen=True, slots=True)
class Settings:
    """The daemon's settings before a campaign (what ``restore`` puts back)."""

    registers: dict[str, Any]  # the register configuration document
    mode: str | None
    sim: SimSettings | None  # the simulator settings, None on hardware
    stage_position_m: float | None  # None: no stage could be read
    stage_enabled: bool
    wheel_speed_deg_s: float | None
    wheel_compensation: bool | None


def capture(client: CamdClient) -> Settings:
    """Record the settings the daemon has now."""
    status = client.status()
    sim = client.sim_settings()
    position: float | None = None
    enabled = False
    with contextlib.suppress(CamdError):
        reading = client.motion()["reading"]
        position = float(reading["position_m"])
        enabled = reading["state"] not in ("disabled", "estop")
    speed: float | None = None
    compensation: bool | None = None
    with contextlib.suppress(CamdError):
        wheel = client.wheel()
        speed = float(wheel["speed_deg_s"])
        compensation = bool(wheel["compensation"])
    return Settings(
        registers=dict(client.register_config()),
        mode=status["mode"],
        sim=sim if sim.get("available") else None,
        stage_position_m=position,
        stage_enabled=enabled,
        wheel_speed_deg_s=speed,
        wheel_compensation=compensation,
    )


def apply_baseline(client: CamdClient, baseline: BaselineSpec) -> None:
    """Bring the camera to the baseline (module docstring); CamdError if it cannot."""
    client.reset()
    if client.sim_settings().get("available"):
        client.set_scene(baseline.scene)
        client.set_polarizer(None)
        client.set_stage(track=True, speed_m_s=0.0)
        client.set_stage_faults(**NO_FAULTS)
    with contextlib.suppress(CamdError):  # a camera without a wheel
        wheel = client.wheel()
        client.set_wheel_compensation(False)
        client.set_wheel_speed(float(wheel["nominal_speed_deg_s"]))
    client.stop_stage()
    if baseline.stage == "home":
        client.enable_stage(True)
        client.home_stage(wait=False)
        deadline = time.monotonic() + HOME_TIMEOUT_S
        while not client.motion()["reading"]["homed"] or (
            client.motion()["reading"]["state"] != "idle"
        ):
            if time.monotonic() > deadline:
                raise CamdError(
                    f"the scan stage did not reach its home switch within {HOME_TIMEOUT_S:g} s; "
                    "check it (`camctl stage`), or use `baseline: {stage: stop}`",
                    code="timeout",
                )
            time.sleep(0.2)
    elif baseline.stage == "release":
        client.enable_stage(False)


def restore(client: CamdClient, before: Settings) -> list[str]:
    """Put back ``before``; returns what was restored and what could not be, in words."""
    done: list[str] = []

    def attempt(what: str, action: Any) -> None:
        try:
            action()
        except CamdError as exc:
            done.append(f"{what} NOT restored ({exc.message})")
        else:
            done.append(what)

    attempt("registers", lambda: client.load_register_config(before.registers))  # type: ignore[arg-type]
    if before.mode is not None:
        mode = before.mode
        attempt(f"mode {mode}", lambda: client.set_mode(mode))
    sim = before.sim
    if sim is not None:

        def put_sim() -> None:
            client.set_scene(str(sim["scene"]))
            client.set_polarizer(sim["polarizer_deg"])
            ideal = sim["ideal_stage"]
            client.set_stage(track=bool(ideal["track"]), speed_m_s=float(ideal["speed_m_s"]))
            client.set_stage_faults(**sim["stage_faults"])

        attempt(f"simulated scene {sim['scene']} and stage settings", put_sim)
    if before.stage_position_m is not None:
        position = before.stage_position_m

        def put_stage() -> None:
            reading = client.motion()["reading"]
            if abs(float(reading["position_m"]) - position) > STAGE_TOLERANCE_M:
                client.enable_stage(True)
                client.move_stage(position, wait=True)
            if not before.stage_enabled:
                client.enable_stage(False)

        attempt(f"stage at {position * 1e3:.3f} mm", put_stage)
    if before.wheel_speed_deg_s is not None:
        speed, compensation = before.wheel_speed_deg_s, bool(before.wheel_compensation)

        def put_wheel() -> None:
            client.set_wheel_compensation(compensation)
            client.set_wheel_speed(speed)

        attempt(f"wheel at {speed:g} deg/s", put_wheel)
    return done
