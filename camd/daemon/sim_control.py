"""What only a simulated camera can do, behind one small interface.

The world in front of the simulated camera (scene, reference polariser, the ideal stage's
speed), its random streams, its stage imperfections, its fault counters and failures on purpose
of a coming command (``fail_next``: a NAK, or a dropped line) are set and read with
the simulator's own SIM_* commands. Production services never send those themselves: they ask
a ``SimulatorControl``. ``FirmwareSimulator`` implements it with the SIM_* commands; on real
hardware ``NoSimulator`` refuses every request with a clear 400 instead of sending an opcode
the camera does not know. ``camd.daemon.backends.simulator_control`` picks one from the config.

In the python-microscope manner, the public methods check the daemon's state and the
arguments, then call the ``_do_*`` hooks that the two implementations provide.
"""

from __future__ import annotations

import abc
import logging
from dataclasses import dataclass
from typing import Any

from camd.daemon.device import DeviceAccess
from camd.daemon.errors import BadRequest, DeviceRejected
from camd.daemon.models import (
    SimFailNextRequest,
    SimSettings,
    SimStageFaultsRequest,
    SimStageTruth,
    SimStreamStats,
    StageRequest,
    StageResponse,
)
from camd.daemon.state import Request

# The commands that start a counted stream: SIM_FAIL_NEXT end_stream (fail_next's
# end_after_frames) ends the stream they start.
STREAM_COMMANDS = ("START_STREAM", "WHEEL_ACQUIRE")
# The simulator takes the speed as an f32 and refuses 0: anything below this would reach it as 0.
MIN_FIXED_SPEED_M_S = 1e-9

log = logging.getLogger(__name__)

SCENE_TIMEOUT_S = 2.0  # per attempt: a lost frame on a lossy line costs this much
SCENE_RETRIES = 10


@dataclass(frozen=True, slots=True)
class ArmedFailure:
    """A failure ``fail_next`` arms (SIM_FAIL_NEXT), checked: the command's opcode, the
    commands of it to let through, and one of a NAK's error code, a silence's length and the
    frames after which the camera ends the stream the command starts."""

    opcode: int
    skip: int
    error_code: int  # a NAK of this error (0: not a NAK)
    duration_s: float  # a silence this long (0: not a silence)
    end_after_frames: int | None  # the stream ends after this many frames (None: not that)


class SimulatorControl(abc.ABC):
    """The simulated camera's controls (module docstring)."""

    def __init__(self, device: DeviceAccess) -> None:
        self.device = device
        # What this daemon last set (the simulator has no way to read them back).
        self._scene = device.config.sim.scene or "flat"
        self._ideal_stage: tuple[bool, float] = (True, 0.0)
        self._polarizer_deg: float | None = None
        self._stage_faults = SimStageFaultsRequest()

    @property
    @abc.abstractmethod
    def available(self) -> bool:
        """True when the camera is simulated (its SIM_* commands work)."""

    @property
    def scene(self) -> str:
        """The scene spec this daemon last set (at start: config ``sim.scene``, or the flat
        field the simulator starts with)."""
        return self._scene

    def settings(self) -> SimSettings:
        """What this daemon last set on the simulator (the simulator cannot be asked)."""
        track, speed = self._ideal_stage
        return SimSettings(
            available=self.available,
            scene=self._scene,
            ideal_stage=StageRequest(track=track, speed_m_s=speed),
            polarizer_deg=self._polarizer_deg,
            stage_faults=self._stage_faults,
        )

    @property
    def ideal_stage(self) -> tuple[bool, float]:
        """The ideal stage's (track, speed_m_s) as this daemon last set it."""
        return self._ideal_stage

    def set_scene(self, spec: str) -> None:
        """Put the scene ``spec`` in front of the camera (docs/simulator.md)."""
        self.device.require(Request.SIM)
        self._do_set_scene(spec)
        self._scene = spec
        self.device.log_event("info", "api", f"simulated scene: {spec}")

    def set_seed(self, seed: int) -> None:
        """Restart the temporal noise and frame-fault random streams from ``seed``."""
        self.device.require(Request.SIM)
        self._do_set_seed(seed)
        self.device.log_event("info", "api", f"simulator random streams re-seeded with {seed}")

    def set_ideal_stage(self, *, track: bool, speed_m_s: float) -> StageResponse:
        """The simulator's ideal scan stage: track the synchronous speed, or run at one."""
        self.device.require(Request.SIM)
        if not track and not speed_m_s >= MIN_FIXED_SPEED_M_S:
            raise BadRequest(
                f"speed_m_s: {speed_m_s!r} with track false: a fixed speed must be at least "
                f"{MIN_FIXED_SPEED_M_S:g} m/s; give speed_m_s (up to 10) or track true"
            )
        response = self._do_set_ideal_stage(track, speed_m_s)
        self._ideal_stage = (track, speed_m_s)
        return response

    def stream_stats(self) -> SimStreamStats:
        """Frames the simulated stream engine made, sent and damaged on purpose."""
        self.device.require(Request.SIM)
        return self._do_stream_stats()

    def set_stage_faults(self, request: SimStageFaultsRequest) -> None:
        """The simulated stepper stage's imperfections."""
        self.device.require(Request.SIM)
        self._do_set_stage_faults(request)
        self._stage_faults = request
        faults = ", ".join(f"{name} {value:g}" for name, value in request.model_dump().items())
        self.device.log_event("info", "api", f"simulated stage faults: {faults}")

    def stage_truth(self) -> SimStageTruth:
        """Where the simulated stage really is."""
        self.device.require(Request.SIM)
        return self._do_stage_truth()

    def set_polarizer(self, angle_deg: float | None) -> None:
        """The reference polariser in front of the scene (None: out of the beam)."""
        self.device.require(Request.SIM)
        self._do_set_polarizer(angle_deg)
        self._polarizer_deg = angle_deg
        what = "out of the beam" if angle_deg is None else f"at {angle_deg:g} deg"
        self.device.log_event("info", "api", f"simulated reference polariser {what}")

    def fail_next(self, request: SimFailNextRequest) -> None:
        """Make the (skip + 1)-th next ``command`` fail: a NAK of ``error``, or the device off
        the line for ``duration_s`` (a link drop). Checked here, against the dictionary."""
        self.device.require(Request.SIM)
        dictionary = self.device.dictionary
        name = request.command.strip().upper()
        try:
            opcode = dictionary.command(name).opcode
        except KeyError:
            raise BadRequest(
                f"command: {request.command!r} is not a command of config/protocol.toml; "
                "use one of " + ", ".join(c.name for c in dictionary.commands)
            ) from None
        given = [request.error, request.duration_s, request.end_after_frames]
        if sum(value is not None for value in given) != 1:
            raise BadRequest(
                "give one of error (the command is refused with a NAK, e.g. BUSY), duration_s "
                "(the camera drops off the line for that long) and end_after_frames (the stream "
                "the command starts ends after that many frames), not several or none"
            )
        if request.end_after_frames is not None and name not in STREAM_COMMANDS:
            raise BadRequest(
                f"end_after_frames ends the stream a command starts: give command "
                f"{' or '.join(STREAM_COMMANDS)}, not {name}"
            )
        error_code = 0
        if request.error is not None:
            try:
                error_code = dictionary.error(request.error.strip().upper()).code
            except KeyError:
                raise BadRequest(
                    f"error: {request.error!r} is not an error of config/protocol.toml; use one "
                    "of " + ", ".join(e.name for e in dictionary.errors)
                ) from None
        self._do_fail_next(
            ArmedFailure(
                opcode,
                request.skip,
                error_code,
                request.duration_s or 0.0,
                request.end_after_frames,
            )
        )
        if request.error is not None:
            how = f"refused with {request.error.strip().upper()}"
        elif request.end_after_frames is not None:
            how = (
                f"executed, and the camera ends its stream after {request.end_after_frames} "
                "frames (STREAM_DONE)"
            )
        else:
            how = f"lost: the camera drops off the line for {request.duration_s:g} s"
        self.device.log_event(
            "warning", "api", f"simulator: {name} number {request.skip + 1} from now will be {how}"
        )

    def clear_fail_next(self) -> None:
        """Disarm a failure ``fail_next`` armed (harmless when none is)."""
        self.device.require(Request.SIM)
        self._do_clear_fail_next()

    @abc.abstractmethod
    def injected(self) -> dict[str, Any] | None:
        """The command-line faults the simulator injected so far (None on hardware)."""

    @abc.abstractmethod
    def _do_set_scene(self, spec: str) -> None: ...

    @abc.abstractmethod
    def _do_set_seed(self, seed: int) -> None: ...

    @abc.abstractmethod
    def _do_set_ideal_stage(self, track: bool, speed_m_s: float) -> StageResponse: ...

    @abc.abstractmethod
    def _do_stream_stats(self) -> SimStreamStats: ...

    @abc.abstractmethod
    def _do_set_stage_faults(self, request: SimStageFaultsRequest) -> None: ...

    @abc.abstractmethod
    def _do_stage_truth(self) -> SimStageTruth: ...

    @abc.abstractmethod
    def _do_set_polarizer(self, angle_deg: float | None) -> None: ...

    @abc.abstractmethod
    def _do_fail_next(self, failure: ArmedFailure) -> None: ...

    @abc.abstractmethod
    def _do_clear_fail_next(self) -> None: ...


class FirmwareSimulator(SimulatorControl):
    """The simulated camera of firmware_models, through its SIM_* commands."""

    @property
    def available(self) -> bool:
        return True

    def injected(self) -> dict[str, Any] | None:
        try:
            return dict(self.device.request("SIM_GET_INJECTED").values)
        except DeviceRejected as exc:
            if exc.name != "UNKNOWN_OPCODE":
                raise
            return None  # another device on the simulator's port: no fault injector

    def _do_set_scene(self, spec: str) -> None:
        # Building a finely sampled scene takes the simulator seconds (e.g. an edge at
        # oversample=16): wait longer per attempt, and try more often, than for a command the
        # device answers at once. A re-send is answered from the device's record once built.
        try:
            self.device.request(
                "SIM_SET_SCENE", spec=spec, timeout_s=SCENE_TIMEOUT_S, retries=SCENE_RETRIES
            )
        except DeviceRejected as exc:
            # The simulator answers a spec it cannot build with OUT_OF_RANGE and its reason:
            # the user's mistake (400), not the device's.
            if exc.name != "OUT_OF_RANGE":
                raise
            reason = str(exc).rpartition("SIM_SET_SCENE: ")[2] or str(exc)
            raise BadRequest(
                f"scene {spec!r} cannot be built: {reason}; correct the scene spec "
                "(docs/simulator.md lists the kinds and their keys)"
            ) from None

    def _do_set_seed(self, seed: int) -> None:
        self.device.request("SIM_SET_SEED", seed=seed)

    def _do_set_ideal_stage(self, track: bool, speed_m_s: float) -> StageResponse:
        values = self.device.request(
            "SIM_SET_STAGE", track="yes" if track else "no", speed_m_s=speed_m_s
        ).values
        return StageResponse(
            speed_m_s=float(values["speed_m_s"]),
            sync_speed_m_s=float(values["sync_speed_m_s"]),
            track=track,
        )

    def _do_stream_stats(self) -> SimStreamStats:
        return SimStreamStats.model_validate(self.device.request("SIM_GET_STREAM_STATS").values)

    def _do_set_stage_faults(self, request: SimStageFaultsRequest) -> None:
        self.device.request("SIM_SET_STAGE_FAULTS", **request.model_dump())

    def _do_stage_truth(self) -> SimStageTruth:
        return SimStageTruth.model_validate(self.device.request("SIM_GET_STAGE").values)

    def _do_set_polarizer(self, angle_deg: float | None) -> None:
        self.device.request(
            "SIM_SET_POLARIZER",
            enable="off" if angle_deg is None else "on",
            angle_deg=0.0 if angle_deg is None else angle_deg,
        )

    def _do_fail_next(self, failure: ArmedFailure) -> None:
        if failure.end_after_frames is not None:
            action = "end_stream"
        else:
            action = "nak" if failure.error_code else "silence"
        self.device.request(
            "SIM_FAIL_NEXT",
            action=action,
            opcode=failure.opcode,
            skip=failure.skip,
            error_code=failure.error_code,
            duration_s=failure.duration_s,
            frames=failure.end_after_frames or 0,
        )

    def _do_clear_fail_next(self) -> None:
        self.device.request(
            "SIM_FAIL_NEXT",
            action="off",
            opcode=0,
            skip=0,
            error_code=0,
            duration_s=0.0,
            frames=0,
        )


class NoSimulator(SimulatorControl):
    """Real hardware: every simulator request is refused (400), nothing is sent."""

    @property
    def available(self) -> bool:
        return False

    def injected(self) -> dict[str, Any] | None:
        return None

    def _refuse(self, what: str) -> BadRequest:
        return BadRequest(
            f"{what} is for the simulated camera only, and this daemon drives "
            f"{self.device.port} (link.device); leave it out, or run `camd serve --sim`"
        )

    def _do_set_scene(self, spec: str) -> None:
        raise self._refuse("a scene")

    def _do_set_seed(self, seed: int) -> None:
        raise self._refuse("a simulator seed")

    def _do_set_ideal_stage(self, track: bool, speed_m_s: float) -> StageResponse:
        raise self._refuse("the ideal stage")

    def _do_stream_stats(self) -> SimStreamStats:
        raise self._refuse("the simulated stream's counters")

    def _do_set_stage_faults(self, request: SimStageFaultsRequest) -> None:
        raise self._refuse("stage fault injection")

    def _do_stage_truth(self) -> SimStageTruth:
        raise self._refuse("the stage's true position")

    def _do_set_polarizer(self, angle_deg: float | None) -> None:
        raise self._refuse("the reference polariser")

    def _do_fail_next(self, failure: ArmedFailure) -> None:
        raise self._refuse("a failure on purpose (fail-next)")

    def _do_clear_fail_next(self) -> None:
        raise self._refuse("a failure on purpose (fail-next)")
