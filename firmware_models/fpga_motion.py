"""The FPGA's scan-stage commands: the MOTOR_* commands and the stage the target rides on.

The MOTOR_* commands (and SIM_SET_STAGE_FAULTS, SIM_GET_STAGE) go to the stepper controller
(``firmware_models.motor``, docs/motion.md). The target rides on the stepper stage once the
motor has been enabled; until then (or after SIM_SET_STAGE) an ideal stage moves it, tracking
the line period, so a plain stream needs no motion set-up. A group of handlers of
``firmware_models.fpga``.
"""

from __future__ import annotations

from camd.motion.stage_profile import StageProfile
from camd.protocol import CommandSpec
from camd.protocol.dictionary import FieldValue, f32_decimal
from firmware_models.errors import Nak
from firmware_models.fpga_commands import Handler, Outcome
from firmware_models.fpga_parts import PartsGroup
from firmware_models.inject import InjectSpec
from firmware_models.stage import StageFaults

# Stopping the stage, and reading it, are always allowed: a fault must not keep it moving.
_ALLOWED_IN_FAULT = ("MOTOR_ESTOP", "MOTOR_STOP", "MOTOR_GET", "MOTOR_GET_LIMITS", "SIM_GET_STAGE")


class MotionCommands(PartsGroup):
    """The stepper controller's commands, and which stage moves the target."""

    def handlers(self) -> dict[str, Handler]:
        """The commands of this group."""
        return {
            **{name: self.motor_command for name in self.parts.motor.commands},
            "SIM_SET_STAGE": self.sim_set_stage,
        }

    def motor_command(
        self, spec: CommandSpec, request: dict[str, FieldValue], now_s: float
    ) -> Outcome:
        state = self.parts.state
        if spec.name not in _ALLOWED_IN_FAULT:
            state.require_no_fault(spec)
        t = now_s - state.power_on_s
        values = {
            k: f32_decimal(v) if isinstance(v, float) and spec.name.startswith("SIM_")
            else v
            for k, v in request.items()
        }  # fmt: skip
        answer = self.parts.motor.handle(spec.name, t, values)
        if spec.name == "MOTOR_ENABLE" and request["enable"] == "on":
            self._ride_the_stepper()
        events = tuple(state.event(n, **v) for n, v in self.parts.motor.poll_events(t))
        return Outcome(spec.encode_response(**answer), events)

    def _ride_the_stepper(self) -> None:
        """From now on the target moves with the stepper stage (module docs)."""
        profile = self.parts.motor.profile
        self.parts.camera.stage = self.parts.motor.stage
        self.parts.camera.stage_image_scale = profile.image_scale(
            self.parts.camera.profile.magnification.value
        )

    def sim_set_stage(
        self, spec: CommandSpec, request: dict[str, FieldValue], now_s: float
    ) -> Outcome:
        track = request["track"] == "yes"
        speed = f32_decimal(float(request["speed_m_s"]))
        if not track and speed <= 0.0:
            raise Nak("OUT_OF_RANGE", "SIM_SET_STAGE: a fixed speed must be > 0 m/s")
        self.parts.camera.stage_speed_m_s = None if track else speed
        self.parts.camera.stage = None  # an ideal stage from now on, not the stepper
        sync = self.parts.camera.synchronous_speed_m_s()
        now = sync if track else speed
        return Outcome(spec.encode_response(speed_m_s=now, sync_speed_m_s=sync))


def stage_faults(profile: StageProfile, spec: InjectSpec) -> StageFaults:
    """The stage's imperfections: the profile's defaults, overridden by --inject stage_*."""
    given = {
        key.removeprefix("stage_"): getattr(spec, key)
        for key in spec.model_fields_set
        if key.startswith("stage_")
    }
    return StageFaults.from_profile(profile).updated(**given)
