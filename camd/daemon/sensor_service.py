"""The daemon's sensor side: register access, timing and LVDS link training.

``SensorService`` is handed the device access and a factory of the register bridge the config
names (the FPGA's REG_* commands, or a USB-SPI bridge; ``camd.daemon.backends``). It checks on every (re)connect that the camera
reports the sensor the register map describes, trains the LVDS link when the config asks, and
tells the stream service whether the link is trained (``require_trained``). Every device access
runs inside ``DeviceAccess.device_op()``: one at a time, with link and register errors mapped
to the API's errors.

A register burst (a write of several registers, fields and groups; a configuration's load) is
planned first: the register file read once (``RegisterSnapshot``) and the burst checked whole
against it (``camd.daemon.register_plan``), then sent through an ``Apply``: a burst that fails
after the camera may have taken it (unanswered, a read-back refused or different) puts the
registers it changed back to the snapshot and says so.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Mapping
from typing import Any

from camd.daemon.device import DeviceAccess
from camd.daemon.errors import LinkUntrained, SensorMismatch, SessionError
from camd.daemon.models import (
    LaneResult,
    RegisterConfig,
    RegisterDifference,
    RegisterDiffResponse,
    RegisterReading,
    RegistersResponse,
    RegisterWriteResponse,
    TimingResponse,
    TrainResponse,
)
from camd.daemon.register_plan import (
    RegisterPlan,
    check_configuration,
    plan_configuration,
    plan_write,
)
from camd.daemon.register_plan import (
    RegisterSnapshot as RegisterSnapshot,
)  # ScanPlanner plans on it
from camd.daemon.state import Request, describe
from camd.daemon.transaction import Apply
from camd.sensor.bridge import RegisterBridge
from camd.sensor.profile import list_profiles, load_profile
from camd.sensor.registers import SensorRegisters
from camd.sensor.regmap import RegisterMap, load_register_map

BridgeFactory = Callable[[RegisterMap], RegisterBridge]


log = logging.getLogger(__name__)


class SensorService:
    """Registers, timing and link training of the session's camera."""

    def __init__(self, device: DeviceAccess, make_bridge: BridgeFactory) -> None:
        self.device = device
        self.config = device.config.sensor
        self._make_bridge = make_bridge
        self.regmap: RegisterMap = load_register_map(self.config.name)
        self.device_sensor: str | None = None  # what GET_SENSOR reported at the last connect
        self.interface = self.regmap.output.interface
        self.trained = False
        self.streaming = False  # what GET_SENSOR said at the last connect
        self._training: TrainResponse | None = None
        self._lost: tuple[float, str] | None = None  # when and how the last training was lost
        self._trained_by_event_s: float | None = None  # LINK_TRAINED without TRAIN's answer
        # One connect check at a time: a reset's own check and the probe after its BOOT each
        # used to find the link untrained, and train it twice.
        self._connect_lock = threading.Lock()
        self._bridge: RegisterBridge | None = None
        self._registers: SensorRegisters | None = None

    # -- lifecycle (called by the session) --------------------------------------------------------

    def on_connect(self) -> bool:
        """After a (re)connect or BOOT: identify the sensor, sync the shadow, train if asked.

        Returns True if the camera is streaming (the session then stops the stream).
        """
        with self._connect_lock:
            return self._on_connect()

    def _on_connect(self) -> bool:
        # The camera may have restarted (a power cycle, the simulator restarted): open the
        # register bridge afresh (a USB-SPI bridge may have enumerated anew) and re-read the
        # registers, which are at their power-on values then.
        with self.device.device_op():
            self.close()
        values = self.device.request("GET_SENSOR").values
        self.device_sensor = str(values["sensor"])
        was_trained = self.trained
        self.trained = values["trained"] == "yes"
        self._trained_by_event_s = None
        if was_trained and not self.trained and self._lost is None:
            self._lost = (time.time(), "the camera restarted")
        self.streaming = values["imaging"] == "yes"
        problem = self.mismatch()
        self.device.sensor_problem = problem
        if problem is not None:
            self.device.log_event("error", "sensor", problem)
            return self.streaming
        try:
            with self.device.device_op():
                self._sensor_registers().sync()
        except SessionError as exc:
            self.device.log_event("warning", "sensor", f"could not read the registers: {exc}")
        if not self.streaming and self.config.train_on_connect and not self.trained:
            try:
                self.train(require=False)
            except SessionError as exc:
                self.device.log_event("error", "sensor", f"training on connect failed: {exc}")
        return self.streaming

    def on_event(self, name: str, values: dict[str, Any]) -> bool:
        """Handle a sensor-related device event; True if it was one."""
        if name == "LINK_LOST":
            if self.trained:
                self._lost = (time.time(), "LINK_LOST")
            self.trained = False
            self.device.log_event(
                "warning", "device", "the LVDS link lost its training (LINK_LOST)"
            )
            return True
        if name == "LINK_TRAINED":
            locked = values.get("locked") == "yes"
            lanes = "every lane locked" if locked else "not every lane locked"
            self.device.log_event(
                "info", "device", f"the camera finished LVDS training (LINK_TRAINED): {lanes}, "
                f"{values.get('bit_errors')} bit errors"
            )  # fmt: skip
            if locked and values.get("bit_errors") == 0 and not self.trained:
                # The camera trained although TRAIN's answer never came (a busy camera answered
                # after the host's attempts ran out): its event says the link is trained, and
                # imaging must not be refused as untrained.
                self.trained = True
                self._lost = None
                self._training = None  # an earlier training's figures are not this one's
                self._trained_by_event_s = time.time()
            return True
        return False

    def close(self) -> None:
        """Close the register bridge (the next register access opens it again)."""
        bridge, self._bridge, self._registers = self._bridge, None, None
        if bridge is not None:
            try:
                bridge.close()
            except Exception as exc:  # a bridge whose device went away may fail to let go
                log.info("closing the register bridge: %s", exc)

    # -- registers ---------------------------------------------------------------------------------

    def read(self, key: str) -> RegisterReading:
        """One register by name or address."""
        self._checked(Request.REGISTERS_READ)
        with self.device.device_op():
            registers = self._sensor_registers()
            reading = registers.read(_key(key))
        return RegisterReading.model_validate(reading.as_dict())

    def dump(self) -> RegistersResponse:
        """Every register, in address order."""
        self._checked(Request.REGISTERS_READ)
        with self.device.device_op():
            registers = self._sensor_registers()
            readings = registers.dump()
        return RegistersResponse(
            sensor=self.regmap.sensor,
            bridge=self.config.bridge,
            registers=[RegisterReading.model_validate(r.as_dict()) for r in readings],
        )

    def write(self, values: dict[str, int | str]) -> RegisterWriteResponse:
        """Validate everything, write in one burst, verify; nothing is written if invalid, and
        a write that fails part-way puts back what it changed (module docstring)."""
        self._checked(Request.REGISTERS_WRITE)
        written = self._apply(plan_write(self.snapshot(), values))
        names = ", ".join(f"{k}={v}" for k, v in values.items())
        self.device.log_event("info", "api", f"registers written: {names}")
        return RegisterWriteResponse(
            sensor=self.regmap.sensor,
            written=[RegisterReading.model_validate(r.as_dict()) for r in written],
        )

    def trim(self, values: dict[str, int | str]) -> None:
        """Write timing registers while streaming, for the scan's closed loop (the line
        period follows the stage): validated and verified like ``write``, but legal while
        streaming and not logged as an event (it runs many times a second)."""
        self._checked(Request.REGISTERS_READ)
        with self.device.device_op():
            self._sensor_registers().write(values)

    def diff(self, against: str, values: dict[str, int] | None) -> RegisterDiffResponse:
        """Registers that differ from their reset values or from ``values``."""
        self._checked(Request.REGISTERS_READ)
        target: Any = "reset" if against == "reset" else dict(values or {})
        with self.device.device_op():
            registers = self._sensor_registers()
            diffs = registers.diff(target)
        return RegisterDiffResponse(
            sensor=self.regmap.sensor,
            against=against,
            differences=[
                RegisterDifference(
                    name=d.name, address=d.address, expected=d.expected, actual=d.actual
                )
                for d in diffs
            ],
        )

    def configuration(self) -> RegisterConfig:
        """The configurable registers as they are now (what `camctl reg save` writes)."""
        self._checked(Request.REGISTERS_READ)
        with self.device.device_op():
            registers = self._sensor_registers()
            values = registers.configuration()
        return RegisterConfig(sensor=self.regmap.sensor, registers=values)

    def load_configuration(self, config: RegisterConfig) -> RegisterWriteResponse:
        """Write a saved configuration: refused whole if it is for another sensor or invalid."""
        self._checked(Request.REGISTERS_WRITE)
        with self.device.device_op():
            registers = self._sensor_registers()
        check_configuration(registers, config)  # another sensor's: refused before reading
        written = self._apply(plan_configuration(self.snapshot(), config))
        self.device.log_event(
            "info", "api", f"configuration of {len(config.registers)} registers loaded"
        )
        return RegisterWriteResponse(
            sensor=self.regmap.sensor,
            written=[RegisterReading.model_validate(r.as_dict()) for r in written],
        )

    def timing(self) -> TimingResponse:
        """The timing the sensor's registers set now."""
        self._checked(Request.REGISTERS_READ)
        with self.device.device_op():
            registers = self._sensor_registers()
            timing = registers.timing()
        return TimingResponse.model_validate(timing.as_dict())

    # -- training ----------------------------------------------------------------------------------

    def train(self, *, require: bool = True) -> TrainResponse:
        """TRAIN the LVDS link and read every lane's result. Refused (SensorMismatch) for a
        camera with another sensor; a sensor without LVDS lanes has nothing to train: the
        answer says so, with nothing sent."""
        if require:
            self._checked(Request.TRAIN)
        if self.interface != "lvds":
            return self.last_training()
        values = self.device.request("TRAIN").values
        lanes = int(values["lanes"])
        results = []
        for lane in range(lanes):
            lane_values = self.device.request("GET_LANE", lane=lane).values
            results.append(
                LaneResult(
                    lane=lane,
                    tap=int(lane_values["tap"]),
                    eye_width=int(lane_values["eye_width"]),
                    slips=int(lane_values["slips"]),
                    shift=int(lane_values["shift"]),
                    locked=lane_values["locked"] == "yes",
                )
            )
        locked = values["locked"] == "yes"
        bit_errors = int(values["bit_errors"])
        self.trained = locked and bit_errors == 0
        self._lost = None
        self._trained_by_event_s = None
        self._training = TrainResponse(
            sensor=self.regmap.sensor,
            interface=self.interface,
            trained=self.trained,
            lanes=lanes,
            locked_lanes=int(values["locked_lanes"]),
            locked=locked,
            bit_errors=bit_errors,
            verified_bits=int(values["verified_bits"]),
            lane_results=results,
            t_s=time.time(),
            lost_t_s=None,
            summary="",
        )
        self._training = self._training.model_copy(update={"summary": self.training_summary()})
        level = "info" if self.trained else "error"
        self.device.log_event(level, "sensor", self.training_summary())
        return self._training

    def last_training(self) -> TrainResponse:
        """The last training (``t_s`` None if the daemon has not trained since it started),
        with whether the link has lost it since (``lost_t_s``) and a summary in words."""
        lost_t_s = None if self._lost is None or self.trained else self._lost[0]
        if self._training is not None:
            return self._training.model_copy(
                update={
                    "trained": self.trained,
                    "lost_t_s": lost_t_s,
                    "summary": self.training_summary(),
                }
            )
        parallel = self.interface != "lvds"
        return TrainResponse(
            sensor=self.regmap.sensor,
            interface=self.interface,
            trained=self.trained or parallel,
            lanes=0 if parallel else self.regmap.output.lanes,
            locked_lanes=0,
            locked=self.trained or parallel,
            bit_errors=0,
            verified_bits=0,
            lane_results=[],
            t_s=None,
            lost_t_s=lost_t_s,
            summary=self.training_summary(),
        )

    def training_summary(self) -> str:
        """One sentence on the link's training, for events, refusals and the train document."""
        if self.interface != "lvds":
            return (
                f"{self.regmap.sensor} {self.interface} interface: nothing to train (no LVDS "
                "lanes); the sensor's data reaches the FPGA as it is"
            )
        return lvds_summary(self.trained, self._training, self._lost, self._trained_by_event_s)

    def mismatch(self) -> str | None:
        """What is wrong when the camera reports another sensor than ``sensor.name`` (None
        when they match, or before the first connect): status.reason and refusals say it."""
        found, ours = self.device_sensor, self.regmap.sensor
        if found is None or found == ours:
            return None
        return (
            f"the camera reports sensor {found!r} but sensor.name is {ours!r}: set sensor.name "
            f'= "{found}" in the config (or connect the right camera) and restart camd; register '
            "access, training and imaging are refused until they match"
        )

    def require_trained(self, what: str) -> None:
        """Raise SensorMismatch for a camera with another sensor, LinkUntrained unless the
        sensor's output link is trained."""
        problem = self.mismatch()
        if problem is not None:
            raise SensorMismatch(f"cannot {what}: {problem}")
        if not self.trained:
            raise LinkUntrained(
                f"cannot {what}: {self.training_summary()}; run `camctl train` "
                "(and check the sensor's supply and cabling if it does not lock)"
            )

    def window_columns(self) -> int:
        """Columns per window row: the window-columns role if the map has one, else all."""
        with self.device.device_op():
            registers = self._sensor_registers()
            count = self.regmap.role_count("window_columns", registers.read_value)
        return self.regmap.columns if count is None else count

    def snapshot(self) -> RegisterSnapshot:
        """Every register's raw value now, read once: what a plan is made against and what a
        failed request is restored to."""
        self._checked(Request.REGISTERS_READ)
        with self.device.device_op():
            registers = self._sensor_registers()
            raw = registers.raw_values()
        return RegisterSnapshot(self.regmap, registers, raw)

    def restore(self, snapshot: RegisterSnapshot, names: list[str]) -> None:
        """Write the registers ``names`` back to their values in ``snapshot`` (verified)."""
        self._write_back({name: snapshot.raw[name] for name in names})

    def _write_back(self, values: Mapping[str, int]) -> None:
        """Write raw register values back (verified): what a failed request changed."""
        if values:
            with self.device.device_op():
                self._sensor_registers().write(dict(values))

    def restore_defaults(self) -> list[str]:
        """Write every configurable register that differs back to its reset value (the sensor
        as it powers up); returns the registers written."""
        self._checked(Request.REGISTERS_WRITE)
        with self.device.device_op():
            registers = self._sensor_registers()
            now = registers.configuration()
            changed = {
                name: self.regmap.register(name).reset
                for name, value in now.items()
                if value != self.regmap.register(name).reset
            }
            if changed:
                registers.write(changed)
        return list(changed)

    def register_values(self) -> dict[str, int]:
        """The configurable registers' values now (for recordings' metadata)."""
        self._checked(Request.REGISTERS_READ)
        with self.device.device_op():
            return dict(self._sensor_registers().configuration())

    def profile_metadata(self) -> dict[str, Any]:
        """The camera profile of this sensor as plain values, for recordings (empty if none)."""
        if self.regmap.sensor not in list_profiles():
            return {"sensor": self.regmap.sensor}
        return load_profile(self.regmap.sensor).model_dump(mode="json")

    # -- internals -------------------------------------------------------------------------------

    def _apply(self, plan: RegisterPlan) -> list[Any]:
        """Send a planned burst, its registers written back if it fails after the camera may
        have taken it (it may have reached the sensor before failing)."""
        with Apply(plan.what, self._events, source="api") as apply:
            if plan.restore:
                apply.undo_later(lambda: self._write_back(plan.restore), plan.restore_label)
            with self.device.device_op():
                written = self._sensor_registers().write(plan.writes)
            apply.done()
        return written

    def _events(self, level: str, source: str, message: str) -> None:
        self.device.log_event(level, source, message)

    def _checked(self, request: Request) -> None:
        self.device.require(request)
        problem = self.mismatch()
        if problem is not None:
            raise SensorMismatch(f"cannot {describe(request)}: {problem}")

    def _sensor_registers(self) -> SensorRegisters:
        """The register layer, its bridge opened on first use. Call inside ``device_op()``:
        opening a USB-SPI bridge can fail, and its errors must reach the client mapped."""
        if self._registers is None:
            self._bridge = self._make_bridge(self.regmap)
            self._registers = SensorRegisters(self.regmap, self._bridge)
        return self._registers


def _clock(t_s: float | None) -> str:
    """A Unix time as the UTC time of day, for sentences ("05:40:01 UTC")."""
    if t_s is None:
        return "an unknown time"
    return time.strftime("%H:%M:%S UTC", time.gmtime(t_s))


def _key(text: str) -> str | int:
    """A register key from the CLI: an address ("0x10", "16") or a name."""
    try:
        return int(text, 0)
    except ValueError:
        return text


def lvds_summary(
    trained: bool,
    t: TrainResponse | None,
    lost: tuple[float, str] | None,
    trained_by_event_s: float | None,
) -> str:
    """``SensorService.training_summary`` of an LVDS link: whether it is trained, from the last
    training ``t`` (None: none since the daemon started), when and how it was ``lost``, and
    when a LINK_TRAINED event without TRAIN's answer said it was trained."""
    if not trained and lost is not None:
        lost_s, how = lost
        last = "" if t is None else f", after the last training at {_clock(t.t_s)}"
        return f"LVDS link not trained: it lost its training at {_clock(lost_s)} ({how}){last}"
    if t is None:
        if trained and trained_by_event_s is not None:
            return (
                f"LVDS link trained (the camera's LINK_TRAINED event at "
                f"{_clock(trained_by_event_s)}: every lane locked, 0 bit errors; "
                "TRAIN's answer did not come, so `camctl train` measures its lanes)"
            )
        if trained:
            return (
                "LVDS link trained (found trained when the camera connected; "
                "`camctl train` measures its lanes)"
            )
        return "LVDS link not trained yet"
    unlocked = [str(lane.lane) for lane in t.lane_results if not lane.locked]
    if trained:
        return (
            f"LVDS link trained: {t.locked_lanes}/{t.lanes} lanes locked, "
            f"{t.bit_errors} bit errors in {t.verified_bits} PRBS bits"
        )
    if unlocked:
        return (
            f"LVDS training failed: lane(s) {', '.join(unlocked)} did not lock "
            f"({t.locked_lanes}/{t.lanes} locked)"
        )
    if t.bit_errors:
        return f"LVDS training failed: {t.bit_errors} bit errors in the PRBS check"
    return "LVDS link not trained (lost since the last training)"
