"""Sensor checks: every writable register written, read back and restored; read-only
registers refused; write-only ones unreadable; LVDS training (docs/sensors.md §2, docs/protocol.md
§5 0x10-0x21).

The registers are written with raw REG_WRITE frames so that nothing of the host's own checks
stands between the test value and the unit. Each register gets back the value it had.
"""

from __future__ import annotations

from typing import Any

from camd.sensor.regmap import RegisterSpec, RegisterValueError

from .engine import CheckFailed, Evidence, Unit, check_function, conclude
from .raw import ack_values, answer_text, send


def _read(unit: Unit, reg: RegisterSpec) -> int:
    return int(ack_values(unit, "REG_READ", {"address": reg.address})["value"])


def _write(unit: Unit, reg: RegisterSpec, value: int) -> str:
    response = send(unit, "REG_WRITE", fields={"address": reg.address, "value": value})
    return answer_text(response["answers"][0])


def test_value(reg: RegisterSpec, current: int) -> int | None:
    """A value other than ``current`` that the register map allows (so the sensor is never
    put in a state its map forbids), or None if there is none."""
    lsb = min((f.lsb for f in reg.all_fields()), default=0)
    for candidate in (current ^ (1 << lsb), current + (1 << lsb), current - (1 << lsb), reg.reset):
        if candidate == current or not 0 <= candidate <= reg.mask:
            continue
        try:
            reg.check_value(candidate)
        except RegisterValueError:
            continue
        return candidate
    return None


def _writable_for_test(reg: RegisterSpec, unit: Unit) -> bool:
    soft_reset = unit.regmap.soft_reset_register()
    return (
        reg.access == "rw"
        and not reg.volatile
        and not reg.pulse_mask
        and (soft_reset is None or reg.name != soft_reset.name)
    )


@check_function("registers_rw")
def registers_rw_check(unit: Unit) -> Evidence:
    """Every RW non-volatile register: write a test value, read it back, write the old value
    back and read that back. docs/sensors.md §2: RW registers are verified after a write."""
    trained = ack_values(unit, "GET_SENSOR")["trained"] == "yes"
    rows: list[dict[str, Any]] = []
    wrong: list[str] = []
    for reg in unit.regmap.by_address():
        if not _writable_for_test(reg, unit):
            continue
        before = _read(unit, reg)
        value = test_value(reg, before)
        if value is None:
            rows.append({"register": reg.name, "address": reg.address, "before": before,
                         "note": "no other valid value"})  # fmt: skip
            continue
        answer = _write(unit, reg, value)
        read = _read(unit, reg) if answer == "ACK" else None
        restored = _write(unit, reg, before)
        after = _read(unit, reg)
        row = {"register": reg.name, "address": reg.address, "before": before, "written": value,
               "write_answer": answer, "read_back": read, "restore_answer": restored,
               "after_restore": after}  # fmt: skip
        rows.append(row)
        if answer != "ACK" or read != value:
            wrong.append(f"{reg.name} written 0x{value:X} ({answer}), read back "
                         f"{'nothing' if read is None else f'0x{read:X}'}")  # fmt: skip
        elif restored != "ACK" or after != before:
            wrong.append(f"{reg.name} restored to 0x{before:X} ({restored}), reads 0x{after:X}")
    evidence: Evidence = {"registers": rows, "tested": sum("written" in r for r in rows)}
    # Test values of the LVDS registers (training word, test pattern) may untrain the link.
    if trained and ack_values(unit, "GET_SENSOR")["trained"] != "yes":
        evidence["retrained"] = bool(unit.client.train()["trained"])
    return conclude(wrong, evidence)


@check_function("registers_ro")
def registers_ro_check(unit: Unit) -> Evidence:
    """Every RO register: REG_WRITE is refused with REG_READ_ONLY and changes nothing."""
    rows: list[dict[str, Any]] = []
    wrong: list[str] = []
    for reg in unit.regmap.by_address():
        if reg.access != "ro":
            continue
        before = _read(unit, reg)
        attempt = before ^ 1
        answer = _write(unit, reg, attempt)
        after = _read(unit, reg)
        rows.append({"register": reg.name, "address": reg.address, "before": before,
                     "attempted": attempt, "answer": answer, "after": after})  # fmt: skip
        if not answer.startswith("NAK REG_READ_ONLY"):
            wrong.append(f"{reg.name}: REG_WRITE answered {answer}, not NAK REG_READ_ONLY")
        elif not reg.volatile and after != before:
            wrong.append(f"{reg.name} changed from 0x{before:X} to 0x{after:X}")
    evidence: Evidence = {"registers": rows}
    return conclude(wrong, evidence)


@check_function("registers_wo")
def registers_wo_check(unit: Unit) -> Evidence:
    """Every WO register: REG_READ is refused with REG_WRITE_ONLY."""
    rows = []
    for reg in unit.regmap.by_address():
        if reg.access == "wo":
            response = send(unit, "REG_READ", fields={"address": reg.address})
            rows.append({"register": reg.name, "address": reg.address,
                         "answer": answer_text(response["answers"][0])})  # fmt: skip
    evidence: Evidence = {"registers": rows}
    wrong = [r for r in rows if not str(r["answer"]).startswith("NAK REG_WRITE_ONLY")]
    if wrong:
        said = ", ".join(f"{r['register']}: {r['answer']}" for r in wrong)
        raise CheckFailed(f"write-only registers read: {said}", evidence)
    return evidence


@check_function("lvds_training")
def lvds_training_check(unit: Unit) -> Evidence:
    """TRAIN locks every lane with no bit errors in the PRBS verification frame, and each
    lane's GET_LANE says locked (docs/protocol.md 0x20 TRAIN, 0x21 GET_LANE)."""
    result = ack_values(unit, "TRAIN")
    lanes = int(result["lanes"])
    per_lane = [ack_values(unit, "GET_LANE", {"lane": lane}) for lane in range(lanes)]
    sensor = ack_values(unit, "GET_SENSOR")
    evidence: Evidence = {
        "train": result,
        "lanes": per_lane,
        "get_sensor_trained": sensor["trained"],
    }
    problems = []
    if result["locked"] != "yes" or int(result["locked_lanes"]) != lanes:
        problems.append(f"{result['locked_lanes']} of {lanes} lanes locked")
    if int(result["bit_errors"]) != 0:
        problems.append(f"{result['bit_errors']} bit errors in {result['verified_bits']} bits")
    if lanes and int(result["verified_bits"]) == 0:
        problems.append("no bits verified")
    unlocked = [int(lane["lane"]) for lane in per_lane if lane["locked"] != "yes"]
    if unlocked:
        problems.append(f"GET_LANE says lanes {unlocked} are not locked")
    if sensor["trained"] != "yes":
        problems.append("GET_SENSOR says the link is not trained")
    return conclude(problems, evidence)
