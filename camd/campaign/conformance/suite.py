"""The conformance suite: the plan of checks, each with the clause of the spec it tests
(docs/conformance.md lists them).

A clause is written ``docs/FILE.md §HEADING``, HEADING the exact text of a heading of that
file (tests/test_conformance.py checks that it exists), then after `` — `` what in it is tested.
"""

from __future__ import annotations

from camd.protocol import Dictionary

from .engine import CheckStep, Plan

SUITE = "camd-conformance"
VERSION = 1

P = "docs/protocol.md"
S = "docs/stream.md"
R = "docs/sensors.md"

# Commands whose valid case is not sent by their cmd.NAME check (it would start an acquisition
# behind the daemon's back, or redefine the stage's zero) but by the check named, through the
# daemon: cmd.NAME depends on that check and passes only if it passed.
VALID_CASE_ELSEWHERE: dict[str, tuple[str, str]] = {
    "START_STREAM": ("stream.headers", "POST /api/v1/stream/acquire sends START_STREAM"),
    "WHEEL_ACQUIRE": ("wheel.delay", "POST /api/v1/wheel/acquire sends WHEEL_ACQUIRE"),
    "MOTOR_HOME": ("motion.home", "destructive: homing redefines the stage's zero"),
}
STREAM = ("stream",)  # the checks that take frames: not run without the USB frame stream


def _cmd_clause(dictionary: Dictionary, name: str) -> str:
    spec = dictionary.command(name)
    sim = " (simulator only)" if spec.opcode >= 0xF0 else ""
    return f"{P} §0x{spec.opcode:02X} {spec.name}{sim}; {P} §8. Error codes"


def plan(dictionary: Dictionary) -> Plan:
    """Every check of the suite, in the order they are reported: the link first (it needs
    nothing), then the sensor, the stream (which needs a trained link; each check trains it if
    not) and motion. A cmd.NAME check of VALID_CASE_ELSEWHERE runs after the check it depends
    on (engine.execution_order)."""
    yield CheckStep(
        "link.at_most_once", "at_most_once",
        f"{P} §4. Exchanges — at-most-once execution: a retry is answered from the record",
        "a retried frame (same sequence number) is executed once and answered identically",
    )  # fmt: skip
    yield CheckStep(
        "link.unknown_opcode", "unknown_opcode",
        f"{P} §8. Error codes — UNKNOWN_OPCODE (1)",
        "opcodes the dictionary does not define are refused with UNKNOWN_OPCODE",
    )  # fmt: skip
    for spec in dictionary.commands:
        elsewhere = VALID_CASE_ELSEWHERE.get(spec.name)
        yield CheckStep(
            f"cmd.{spec.name}", "command", _cmd_clause(dictionary, spec.name),
            f"{spec.name}: valid request acknowledged; bad length and out-of-range values "
            "refused with BAD_LENGTH / OUT_OF_RANGE (and the register map's codes)",
            {"command": spec.name},
            depends_on={elsewhere[0]: "its valid case"} if elsewhere else {},
        )  # fmt: skip
    yield CheckStep(
        "sensor.registers_rw", "registers_rw",
        f"{R} §2. Access rules and host behaviour — rw: verified after a write; "
        f"{P} §0x11 REG_WRITE; {P} §0x10 REG_READ",
        "every RW register written, read back and restored",
    )  # fmt: skip
    yield CheckStep(
        "sensor.registers_ro", "registers_ro",
        f"{R} §2. Access rules and host behaviour — ro: write refused; {P} §0x11 REG_WRITE",
        "read-only registers refused with REG_READ_ONLY and unchanged",
    )  # fmt: skip
    yield CheckStep(
        "sensor.registers_wo", "registers_wo",
        f"{R} §2. Access rules and host behaviour — wo: read refused; {P} §0x10 REG_READ",
        "write-only registers cannot be read (REG_WRITE_ONLY)",
    )  # fmt: skip
    yield CheckStep(
        "sensor.lvds_training", "lvds_training",
        f"{P} §0x20 TRAIN; {P} §0x21 GET_LANE",
        "LVDS training locks every lane with no PRBS bit errors",
    )  # fmt: skip
    yield CheckStep(
        "stream.headers", "stream_headers",
        f"{S} §Frame format (version 1) — sizes, mode, stages, line_period_ns, flags",
        "frame headers agree with the stream and the registers",
        needs=STREAM,
    )  # fmt: skip
    yield CheckStep(
        "stream.counters", "stream_counters",
        f"{S} §Frame format (version 1) — counter: +1 per frame; {S} §Reassembly rules",
        "frame counters consecutive from the announced first, none lost",
        needs=STREAM,
    )  # fmt: skip
    yield CheckStep(
        "stream.crc", "stream_crc",
        f"{S} §Frame format (version 1) — payload_crc32, header_crc32: CRC-32/ISO-HDLC",
        "payload CRCs match the payloads, no frame corrupt",
        needs=STREAM,
    )  # fmt: skip
    yield CheckStep(
        "stream.frame_period", "frame_period",
        f"{S} §Frame format (version 1) — line_period_ns = frame period, timestamp_ns; "
        f"{R} §`[timing]`: the line period",
        "frames one register-set frame period apart (1 %)",
        needs=STREAM,
    )  # fmt: skip
    yield CheckStep(
        "motion.move", "stage_move", f"{P} §0x32 MOTOR_MOVE; {P} §0x35 MOTOR_GET",
        "a short stage move reaches its target and comes back",
    )  # fmt: skip
    yield CheckStep(
        "motion.limits", "stage_limits",
        f"{P} §0x32 MOTOR_MOVE — outside the soft limits: OUT_OF_RANGE; "
        f"{P} §0x31 MOTOR_SET_RATE — above the maximum rate: OUT_OF_RANGE",
        "moves past the soft limits and rates above the maximum refused; the stage stays",
    )  # fmt: skip
    yield CheckStep(
        "motion.home", "stage_home", f"{P} §0x34 MOTOR_HOME",
        "homing finds the switch and zeroes the position",
        destructive=True,
    )  # fmt: skip
    yield CheckStep(
        "wheel.speed", "wheel_speed", f"{P} §0x40 WHEEL_SET_SPEED; {P} §0x41 WHEEL_GET",
        "the wheel turns at the speed set",
    )  # fmt: skip
    yield CheckStep(
        "wheel.delay", "wheel_delay",
        f"{P} §0x42 WHEEL_COMPENSATION; {P} §0x43 WHEEL_ACQUIRE — exposure T_delay after the "
        "entry pulse",
        "with compensation on, the exposure is centred on the channel (eq 8)",
        needs=STREAM,
    )  # fmt: skip
