"""Protocol checks: every command with valid and invalid arguments, unknown opcodes, and
at-most-once execution of a retried frame (docs/protocol.md §4, §5, §8).

The valid case of a command that changes state sends what leaves the unit as it was (the
mode in force, a register's own value, the stage's own position) or puts back what it changed;
a valid case that would start an acquisition behind the daemon's back is not sent here: the
check names the check that exercises it through the daemon, and the suite makes it depend on
that check (suite.VALID_CASE_ELSEWHERE).
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable, Iterator
from typing import Any

from camd.protocol import CommandSpec

from .engine import CheckFailed, CheckNotRun, Evidence, Unit, check_function
from .raw import ack_values, answer_text, case, invalid_payloads, send
from .suite import VALID_CASE_ELSEWHERE

# Commands that only read: the valid case is the empty request.
READS = frozenset({"GET_STATUS", "GET_HOUSEKEEPING", "GET_LINK_STATS", "GET_SENSOR",
                   "GET_STREAM", "MOTOR_GET", "MOTOR_GET_LIMITS", "WHEEL_GET", "STOP_STREAM",
                   "MOTOR_STOP", "SIM_GET_INJECTED", "SIM_GET_SPI_STATS",
                   "SIM_GET_STREAM_STATS", "SIM_GET_STAGE"})  # fmt: skip
# SIM_SET_SEED and SIM_SET_INJECT: the simulator cannot report the value in force, so any
# value sent would change it.
SIM_SETTERS = "the value in force cannot be read back, so a valid request would change it"
UNUSED_OPCODES = (0x00, 0x7F, 0xEF)  # no command of config/protocol.toml has them


@check_function("command")
def command_check(unit: Unit, *, command: str) -> Evidence:
    """The command's valid case is acknowledged with a response the dictionary decodes; each
    invalid case the dictionary implies is refused with the NAK code the spec promises."""
    spec = unit.dictionary.command(command)
    cases: list[Evidence] = []
    if spec.opcode >= 0xF0 and not unit.simulated:
        # docs/protocol.md §4: hardware answers the simulator-only opcodes UNKNOWN_OPCODE.
        response = send(unit, opcode=spec.opcode, payload=b"")
        cases.append(case("simulator-only opcode on hardware", response, "NAK UNKNOWN_OPCODE"))
    else:
        cases.append(_valid_case(unit, spec))
        for name, payload, expected in invalid_payloads(spec) + _extra_cases(unit, spec):
            cases.append(case(name, send(unit, opcode=spec.opcode, payload=payload), expected))
    evidence = _verdict(f"{spec.name} (0x{spec.opcode:02X})", cases)
    unshown = [c for c in cases if c["sent_hex"] is None and c.get("shown_by") is None]
    if unshown:
        # Conforming means accepted and verified: a valid case nobody sent shows nothing.
        raise CheckNotRun(None, unshown[0]["case"], evidence)
    return evidence


@check_function("unknown_opcode")
def unknown_opcode_check(unit: Unit) -> Evidence:
    """Opcodes the dictionary does not define are refused with UNKNOWN_OPCODE."""
    cases = [
        case(f"opcode 0x{op:02X}", send(unit, opcode=op, payload=b""), "NAK UNKNOWN_OPCODE")
        for op in UNUSED_OPCODES
    ]
    return _verdict("undefined opcodes", cases)


@check_function("at_most_once")
def at_most_once_check(unit: Unit) -> Evidence:
    """A frame sent twice with the same sequence number (a retry after a lost answer) is
    answered twice with the same bytes and executed once: GET_HOUSEKEEPING's answer carries
    the device's count of executed commands, and the device counts the retry as replayed."""
    before = ack_values(unit, "GET_LINK_STATS")
    response = send(unit, "GET_HOUSEKEEPING", repeat=True)
    after = ack_values(unit, "GET_LINK_STATS")
    first, second = response["answers"]
    replayed = int(after["replayed"]) - int(before["replayed"])
    evidence: Evidence = {
        "seq": response["seq"],
        "first_answer_hex": first["payload_hex"],
        "second_answer_hex": second["payload_hex"],
        "executed_in_first": (first["values"] or {}).get("executed"),
        "executed_in_second": (second["values"] or {}).get("executed"),
        "replayed_counter_delta": replayed,
    }
    if first["type"] != "ack" or second["type"] != "ack":
        raise CheckFailed(
            f"GET_HOUSEKEEPING answered {answer_text(first)}, then {answer_text(second)}", evidence
        )
    if first["payload_hex"] != second["payload_hex"]:
        raise CheckFailed(
            "the retried frame got a different answer: the device executed it again", evidence
        )
    if replayed < 1:
        raise CheckFailed("GET_LINK_STATS.replayed did not count the retry", evidence)
    return evidence


def _verdict(what: str, cases: list[Evidence]) -> Evidence:
    evidence: Evidence = {"cases": cases}
    wrong = [c for c in cases if not c["ok"]]
    if wrong:
        said = "; ".join(f"{c['case']}: expected {c['expected']}, got {c['answer']}" for c in wrong)
        raise CheckFailed(f"{what}: {said}", evidence)
    return evidence


# -- valid cases ------------------------------------------------------------------------------------


def _valid_case(unit: Unit, spec: CommandSpec) -> Evidence:
    name = spec.name
    if name in VALID_CASE_ELSEWHERE:
        # The engine makes this check's pass wait on that check's (suite.py, depends_on).
        check, how = VALID_CASE_ELSEWHERE[name]
        return _not_sent(f"valid case exercised by {check} ({how})", shown_by=check)
    if name in READS:
        return case("valid: empty request", send(unit, name, fields={}), "ACK")
    if name == "PING":
        response = send(unit, name, fields={"data": bytes.fromhex("c0ffee")})
        result = case("valid: 3 bytes echoed", response, "ACK")
        echo = (response["answers"][0]["values"] or {}).get("data")
        if result["ok"] and echo != "c0ffee":
            result |= {"ok": False, "detail": f"echo {echo!r} differs from c0ffee"}
        return result
    handler = _VALID.get(name)
    if handler is not None:
        return handler(unit, spec)
    if name.startswith("SIM_"):
        return _not_sent(f"valid case not sent: {SIM_SETTERS}")
    return _not_sent("valid case not defined for this command")  # a new command: add one


def _not_sent(why: str, *, shown_by: str | None = None) -> Evidence:
    """A valid case this check does not send: shown by the check ``shown_by`` (the suite
    makes this one depend on it), or by nothing, and then the command is not run."""
    return {"case": why, "sent_hex": None, "expected": None, "answer": None, "ok": True,
            "shown_by": shown_by}  # fmt: skip


def _no_valid_request(why: str) -> Evidence:
    """No valid request exists for this unit (GET_LANE on a sensor without lanes): its
    invalid cases (every lane refused) are all the command has to show."""
    return {"case": why, "sent_hex": None, "expected": None, "answer": None, "ok": True,
            "shown_by": "its invalid cases"}  # fmt: skip


@contextlib.contextmanager
def _reset_after(unit: Unit) -> Iterator[None]:
    """Reset the unit through the daemon after the block (POST /api/v1/reset: RESET, and the
    daemon leaves its fault state, which a raw RESET does not make it do) and put back what a
    reset changes: the mode (area after it), the sensor link's training (docs/protocol.md
    0x04) and the register configuration."""
    mode = str(ack_values(unit, "GET_STATUS")["mode"])
    trained = ack_values(unit, "GET_SENSOR")["trained"] == "yes"
    registers = unit.client.register_config()
    try:
        yield
    finally:
        _wait_idle(unit, fault_ok=True)  # the BOOT or FAULT event has reached the daemon
        unit.client.reset()
        _wait_idle(unit)
        # The daemon's reset puts the sensor's registers at their defaults: put back the
        # configuration the unit had (only if it differs: nothing is written otherwise).
        if unit.client.register_config() != registers:
            unit.client.load_register_config(registers)
        if mode != "area":
            unit.client.set_mode(mode)
        if trained:
            unit.client.train()


def _reset(unit: Unit, spec: CommandSpec) -> Evidence:
    with _reset_after(unit):
        return case("valid: RESET", send(unit, "RESET", fields={}), "ACK")


def _sim_set_fault(unit: Unit, spec: CommandSpec) -> Evidence:
    code = unit.dictionary.error("INTERNAL").code
    with _reset_after(unit):
        result = case(f"valid: fault {code} (then RESET)",
                      send(unit, spec.name, fields={"fault_code": code}), "ACK")  # fmt: skip
        status = ack_values(unit, "GET_STATUS")
        if result["ok"] and (status["device_state"] != "fault" or status["fault_code"] != code):
            result |= {"ok": False, "detail": f"GET_STATUS then said {status['device_state']}, "
                       f"fault code {status['fault_code']}"}  # fmt: skip
        return result


def _sim_reskew(unit: Unit, spec: CommandSpec) -> Evidence:
    trained = ack_values(unit, "GET_SENSOR")["trained"] == "yes"
    result = case("valid: new lane skews (then TRAIN)",
                  send(unit, spec.name, fields={"seed": 1}), "ACK")  # fmt: skip
    if trained:
        unit.client.train()
    return result


def _sim_settings(unit: Unit) -> dict[str, Any]:
    return dict(unit.client.sim_settings())


def _sim_set_scene(unit: Unit, spec: CommandSpec) -> Evidence:
    scene = str(_sim_settings(unit)["scene"])
    return case(f"valid: the scene in force ({scene!r})",
                send(unit, spec.name, fields={"spec": scene}), "ACK")  # fmt: skip


def _sim_set_stage(unit: Unit, spec: CommandSpec) -> Evidence:
    ideal = _sim_settings(unit)["ideal_stage"]
    fields = {"track": "yes" if ideal["track"] else "no", "speed_m_s": float(ideal["speed_m_s"])}
    return case("valid: the ideal stage in force", send(unit, spec.name, fields=fields), "ACK")


def _sim_set_stage_faults(unit: Unit, spec: CommandSpec) -> Evidence:
    faults = {k: float(v) for k, v in _sim_settings(unit)["stage_faults"].items()}
    return case("valid: the stage faults in force", send(unit, spec.name, fields=faults), "ACK")


def _sim_set_polarizer(unit: Unit, spec: CommandSpec) -> Evidence:
    angle = _sim_settings(unit)["polarizer_deg"]
    fields = {"enable": "off", "angle_deg": 0.0} if angle is None else {
        "enable": "on", "angle_deg": float(angle)}  # fmt: skip
    return case("valid: the polariser as it is", send(unit, spec.name, fields=fields), "ACK")


def _sim_fail_next(unit: Unit, spec: CommandSpec) -> Evidence:
    fields = {
        "action": "off",
        "opcode": 1,
        "skip": 0,
        "error_code": 0,
        "duration_s": 0,
        "frames": 0,
    }
    return case("valid: action off (disarm)", send(unit, spec.name, fields=fields), "ACK")


def _set_mode(unit: Unit, spec: CommandSpec) -> Evidence:
    mode = ack_values(unit, "GET_STATUS")["mode"]
    return case(f"valid: the mode in force ({mode})", send(unit, "SET_MODE", fields={"mode": mode}),
                "ACK")  # fmt: skip


def _first_register(unit: Unit, wanted: Callable[[Any], bool]) -> Any:
    for reg in unit.regmap.by_address():
        if wanted(reg):
            return reg
    return None


def _plain_rw(reg: Any) -> bool:
    return reg.access == "rw" and not reg.volatile and not reg.pulse_mask


def _reg_read(unit: Unit, spec: CommandSpec) -> Evidence:
    reg = _first_register(unit, lambda r: r.readable)
    response = send(unit, "REG_READ", fields={"address": reg.address})
    return case(f"valid: {reg.name} (0x{reg.address:02X})", response, "ACK")


def _reg_write(unit: Unit, spec: CommandSpec) -> Evidence:
    reg = _first_register(unit, _plain_rw)
    value = int(ack_values(unit, "REG_READ", {"address": reg.address})["value"])
    response = send(unit, "REG_WRITE", fields={"address": reg.address, "value": value})
    return case(f"valid: {reg.name} = its own value 0x{value:X}", response, "ACK")


def _reg_write_burst(unit: Unit, spec: CommandSpec) -> Evidence:
    reg = _first_register(unit, _plain_rw)
    value = int(ack_values(unit, "REG_READ", {"address": reg.address})["value"])
    pairs = reg.address.to_bytes(2, "big") + value.to_bytes(2, "big")
    response = send(unit, "REG_WRITE_BURST", fields={"pairs": pairs})
    return case(f"valid: one pair, {reg.name} = its own value 0x{value:X}", response, "ACK")


def _train(unit: Unit, spec: CommandSpec) -> Evidence:
    return case("valid: train the link", send(unit, "TRAIN", fields={}), "ACK")


def _get_lane(unit: Unit, spec: CommandSpec) -> Evidence:
    if int(ack_values(unit, "GET_SENSOR")["lanes"]) == 0:
        return _no_valid_request("no valid case: the sensor has no LVDS lanes")
    return case("valid: lane 0", send(unit, "GET_LANE", fields={"lane": 0}), "ACK")


@contextlib.contextmanager
def stage_kept(unit: Unit) -> Iterator[dict[str, Any]]:
    """The stage as it was (enabled or not) afterwards, and on the simulator its ideal stage
    (which the stepper replaces once enabled). Yields MOTOR_GET's reading."""
    reading = ack_values(unit, "MOTOR_GET")
    ideal = unit.client.sim_settings().get("ideal_stage") if unit.simulated else None
    try:
        yield reading
    finally:
        send(unit, "MOTOR_STOP", fields={})
        wait_stopped(unit)
        was, now = reading["state"], ack_values(unit, "MOTOR_GET")["state"]
        if now == "estop" and was != "estop":
            send(unit, "MOTOR_ENABLE", fields={"enable": "on"})  # only this clears an estop
            now = "idle"
        if was == "disabled" and now != "disabled":
            send(unit, "MOTOR_ENABLE", fields={"enable": "off"})
        elif was == "estop" and now != "estop":
            send(unit, "MOTOR_ESTOP", fields={})
        elif was not in ("disabled", "estop") and now == "disabled":
            send(unit, "MOTOR_ENABLE", fields={"enable": "on"})
        if ideal:
            unit.client.set_stage(track=bool(ideal["track"]), speed_m_s=float(ideal["speed_m_s"]))


def _enabled(unit: Unit, reading: dict[str, Any]) -> None:
    if reading["state"] in ("disabled", "estop"):
        ack_values(unit, "MOTOR_ENABLE", {"enable": "on"})


def _motor_enable(unit: Unit, spec: CommandSpec) -> Evidence:
    with stage_kept(unit) as reading:
        enable = "off" if reading["state"] == "disabled" else "on"
        response = send(unit, "MOTOR_ENABLE", fields={"enable": enable})
        return case(f"valid: enable {enable} (as it is)", response, "ACK")


def _motor_set_rate(unit: Unit, spec: CommandSpec) -> Evidence:
    with stage_kept(unit) as reading:
        _enabled(unit, reading)
        response = send(unit, "MOTOR_SET_RATE", fields={"rate_hz": 0})
        return case("valid: rate 0 (enabled first)", response, "ACK")


def _motor_move(unit: Unit, spec: CommandSpec) -> Evidence:
    with stage_kept(unit) as reading:
        _enabled(unit, reading)
        limits = ack_values(unit, "MOTOR_GET_LIMITS")
        rate = float(limits["max_rate_hz"]) / 2
        fields = {"target_steps": int(reading["steps"]), "rate_hz": rate}
        response = send(unit, "MOTOR_MOVE", fields=fields)
        wait_stopped(unit)
        return case(f"valid: to where it stands ({reading['steps']} steps)", response, "ACK")


def _motor_set_limits(unit: Unit, spec: CommandSpec) -> Evidence:
    limits = ack_values(unit, "MOTOR_GET_LIMITS")
    response = send(unit, "MOTOR_SET_LIMITS", fields=limits)
    return case("valid: the limits in force", response, "ACK")


def _motor_estop(unit: Unit, spec: CommandSpec) -> Evidence:
    with stage_kept(unit):
        return case("valid: emergency stop (then re-enabled as it was)",
                    send(unit, "MOTOR_ESTOP", fields={}), "ACK")  # fmt: skip


def _wheel_set_speed(unit: Unit, spec: CommandSpec) -> Evidence:
    speed = float(ack_values(unit, "WHEEL_GET")["speed_deg_s"])
    response = send(unit, "WHEEL_SET_SPEED", fields={"speed_deg_s": speed})
    return case(f"valid: the speed in force ({speed:g} deg/s)", response, "ACK")


def _wheel_compensation(unit: Unit, spec: CommandSpec) -> Evidence:
    enable = ack_values(unit, "WHEEL_GET")["compensation"]
    response = send(unit, "WHEEL_COMPENSATION", fields={"enable": enable})
    return case(f"valid: {enable} (as it is)", response, "ACK")


_VALID: dict[str, Callable[[Unit, CommandSpec], Evidence]] = {
    "RESET": _reset,
    "SET_MODE": _set_mode,
    "REG_READ": _reg_read,
    "REG_WRITE": _reg_write,
    "REG_WRITE_BURST": _reg_write_burst,
    "TRAIN": _train,
    "GET_LANE": _get_lane,
    "MOTOR_ENABLE": _motor_enable,
    "MOTOR_SET_RATE": _motor_set_rate,
    "MOTOR_MOVE": _motor_move,
    "MOTOR_SET_LIMITS": _motor_set_limits,
    "MOTOR_ESTOP": _motor_estop,
    "WHEEL_SET_SPEED": _wheel_set_speed,
    "WHEEL_COMPENSATION": _wheel_compensation,
    "SIM_SET_FAULT": _sim_set_fault,
    "SIM_RESKEW": _sim_reskew,
    "SIM_SET_SCENE": _sim_set_scene,
    "SIM_SET_STAGE": _sim_set_stage,
    "SIM_SET_STAGE_FAULTS": _sim_set_stage_faults,
    "SIM_SET_POLARIZER": _sim_set_polarizer,
    "SIM_FAIL_NEXT": _sim_fail_next,
}


# -- invalid cases beyond the dictionary's (the register map's and the link's) -----------------


def _extra_cases(unit: Unit, spec: CommandSpec) -> list[tuple[str, bytes, str]]:
    regmap = unit.regmap
    used = {r.address for r in regmap.by_address()}
    unknown = next(a for a in range(0xFFFF, 0, -1) if a not in used)
    ro = _first_register(unit, lambda r: r.access == "ro")
    wo = _first_register(unit, lambda r: r.access == "wo")
    cases: list[tuple[str, bytes, str]] = []

    def u16(*values: int) -> bytes:
        return b"".join(v.to_bytes(2, "big") for v in values)

    if spec.name == "REG_READ":
        cases.append((f"unknown address 0x{unknown:X}", u16(unknown), "NAK REG_UNKNOWN"))
        if wo is not None:
            cases.append((f"write-only {wo.name}", u16(wo.address), "NAK REG_WRITE_ONLY"))
    elif spec.name == "REG_WRITE":
        cases.append((f"unknown address 0x{unknown:X}", u16(unknown, 0), "NAK REG_UNKNOWN"))
        if ro is not None:
            cases.append((f"read-only {ro.name}", u16(ro.address, 0), "NAK REG_READ_ONLY"))
        narrow = _first_register(unit, lambda r: r.writable and r.width < 16)
        if narrow is not None:
            cases.append((f"{narrow.name}: 0x{1 << narrow.width:X} wider than {narrow.width} bits",
                          u16(narrow.address, 1 << narrow.width), "NAK OUT_OF_RANGE"))  # fmt: skip
    elif spec.name == "REG_WRITE_BURST":
        cases.append(("3 bytes: not whole pairs", b"\0\0\0", "NAK BAD_LENGTH"))
        if ro is not None:
            cases.append((f"a pair for read-only {ro.name}", u16(ro.address, 0),
                          "NAK REG_READ_ONLY"))  # fmt: skip
    elif spec.name == "GET_LANE":
        lanes = int(ack_values(unit, "GET_SENSOR")["lanes"])
        if lanes < 32:
            cases.append((f"lane {lanes}: the sensor has {lanes}", bytes([lanes]),
                          "NAK OUT_OF_RANGE"))  # fmt: skip
    return cases


# -- waiting -------------------------------------------------------------------------------------


def wait_stopped(unit: Unit, timeout_s: float = 10.0) -> None:
    deadline = time.monotonic() + timeout_s
    while ack_values(unit, "MOTOR_GET")["state"] in ("moving", "ramping", "running", "homing"):
        if time.monotonic() > deadline:
            raise CheckFailed(f"the stage did not stop within {timeout_s:g} s", {})
        time.sleep(0.05)


def _wait_idle(unit: Unit, timeout_s: float = 10.0, *, fault_ok: bool = False) -> None:
    """Until the daemon has re-probed the unit after a reset (state idle again; or fault)."""
    deadline = time.monotonic() + timeout_s
    time.sleep(0.1)  # the BOOT event reaches the daemon after RESET's acknowledge
    wanted = ("idle", "fault") if fault_ok else ("idle",)
    while unit.client.status()["state"] not in wanted:
        if time.monotonic() > deadline:
            raise CheckFailed(f"the daemon did not see the unit idle within {timeout_s:g} s", {})
        time.sleep(0.05)
