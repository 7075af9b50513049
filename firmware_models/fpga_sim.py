"""The simulator's own controls: line faults, a device fault, failures on purpose, scene, seed.

SIM_GET_INJECTED, SIM_SET_INJECT, SIM_SET_FAULT, SIM_FAIL_NEXT, SIM_SET_SCENE and SIM_SET_SEED
(docs/simulator.md): commands no camera has, with which the tests and campaigns set up what
they measure. A group of handlers of ``firmware_models.fpga``; the SIM_* commands of one part
of the camera (the stage, the wheel, the stream, the sensor) are in that part's group.
"""

from __future__ import annotations

from camd.protocol import CommandSpec
from camd.protocol.dictionary import FieldValue, f32_decimal
from firmware_models.errors import Nak
from firmware_models.fpga_commands import Handler, Outcome, wrap_u32
from firmware_models.fpga_link import ArmedFailure
from firmware_models.fpga_parts import PartsGroup
from firmware_models.inject import InjectSpec

# The commands that start a counted stream (SIM_FAIL_NEXT end_stream applies).
_STREAM_STARTS = ("START_STREAM", "WHEEL_ACQUIRE")


class SimCommands(PartsGroup):
    """The line's fault injector (``injector``), the device's fault, SIM_FAIL_NEXT (armed on
    ``link``), the scene and the seed of what differs from one acquisition to the next."""

    def handlers(self) -> dict[str, Handler]:
        """The commands of this group."""
        return {
            "SIM_GET_INJECTED": self.sim_get_injected,
            "SIM_SET_INJECT": self.sim_set_inject,
            "SIM_SET_FAULT": self.sim_set_fault,
            "SIM_FAIL_NEXT": self.sim_fail_next,
            "SIM_SET_SCENE": self.sim_set_scene,
            "SIM_SET_SEED": self.sim_set_seed,
        }

    def sim_get_injected(
        self, spec: CommandSpec, request: dict[str, FieldValue], now_s: float
    ) -> Outcome:
        values = {
            **self.parts.injector.counters(),
            "executed_twice": self.parts.link.counters.executed_twice,
        }
        return Outcome(spec.encode_response(**wrap_u32(values)))

    def sim_set_inject(
        self, spec: CommandSpec, request: dict[str, FieldValue], now_s: float
    ) -> Outcome:
        rates = {name: f32_decimal(float(value)) for name, value in request.items()}
        # Keys the command does not carry (added to InjectSpec later) keep their value.
        merged = {**self.parts.injector.spec.model_dump(), **rates}
        try:
            self.parts.injector.set(InjectSpec.checked(**merged))
        except ValueError as exc:
            raise Nak("OUT_OF_RANGE", str(exc)) from None
        self.parts.stream.inject = self.parts.injector.spec  # the frame_* rates, for the next frame
        return Outcome(spec.encode_response())

    def sim_set_fault(
        self, spec: CommandSpec, request: dict[str, FieldValue], now_s: float
    ) -> Outcome:
        code = int(request["fault_code"])
        self.parts.state.fault_code = code
        return Outcome(spec.encode_response(), (self.parts.state.event("FAULT", fault_code=code),))

    def sim_fail_next(
        self, spec: CommandSpec, request: dict[str, FieldValue], now_s: float
    ) -> Outcome:
        action = str(request["action"])
        if action == "off":
            self.parts.link.arm(None)
            return Outcome(spec.encode_response())
        dictionary = self.parts.state.dictionary
        opcode = int(request["opcode"])
        if dictionary.command_for_opcode(opcode) is None:
            raise Nak(
                "OUT_OF_RANGE",
                f"SIM_FAIL_NEXT: opcode 0x{opcode:02X} is not a command of the dictionary",
            )
        code = int(request["error_code"])
        duration_s = float(request["duration_s"])
        if action == "nak":
            try:
                dictionary.error(code)
            except KeyError:
                codes = ", ".join(f"{e.code} {e.name}" for e in dictionary.errors)
                raise Nak(
                    "OUT_OF_RANGE",
                    f"SIM_FAIL_NEXT: error_code {code} is not an error of the dictionary; "
                    f"use one of {codes}",
                ) from None
        elif action == "silence" and duration_s <= 0.0:
            raise Nak("OUT_OF_RANGE", "SIM_FAIL_NEXT: a silence needs duration_s > 0")
        elif action == "end_stream" and opcode not in {
            dictionary.command(name).opcode for name in _STREAM_STARTS
        }:
            raise Nak(
                "OUT_OF_RANGE",
                f"SIM_FAIL_NEXT: end_stream needs a command that starts a stream (START_STREAM, "
                f"WHEEL_ACQUIRE), not opcode 0x{opcode:02X}",
            )
        self.parts.link.arm(
            ArmedFailure(
                action, opcode, int(request["skip"]), code, duration_s, int(request["frames"])
            )
        )
        return Outcome(spec.encode_response())

    def sim_set_scene(
        self, spec: CommandSpec, request: dict[str, FieldValue], now_s: float
    ) -> Outcome:
        try:
            self.parts.camera.set_scene(str(request["spec"]))
        except (ValueError, OSError) as exc:
            raise Nak("OUT_OF_RANGE", f"SIM_SET_SCENE: {exc}") from None
        return Outcome(spec.encode_response())

    def sim_set_seed(
        self, spec: CommandSpec, request: dict[str, FieldValue], now_s: float
    ) -> Outcome:
        # Only the streams that make one acquisition differ from the next: a campaign resumed
        # after a restart re-seeds before each step and so sees the noise it saw the first time.
        seed = int(request["seed"])
        self.parts.camera.reseed_noise(seed)
        self.parts.stream.reseed(seed)
        return Outcome(spec.encode_response())
