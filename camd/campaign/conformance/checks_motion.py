"""Motion checks: the scan stage's moves and soft limits, homing (destructive), the filter
wheel's speed and its exposure delay (docs/protocol.md §5 0x30-0x43, docs/wheel.md).

The stage is driven with raw MOTOR_* frames in steps, exactly as the dictionary defines them,
and left enabled or not and where it stood; the wheel at the speed and compensation it had.
"""

from __future__ import annotations

import time

from camd.client_types import StreamFrameHeader

from .checks_link import stage_kept, wait_stopped
from .checks_stream import frame_stream_used
from .engine import CheckFailed, Evidence, Unit, check_function, conclude
from .raw import ack_values, answer_text, send

MOVE_STEPS = 200  # a short move: tens of milliseconds at half the maximum rate
WHEEL_TEST_SPEED_FACTOR = 1.5
WHEEL_SPEED_TOLERANCE = 0.01  # relative; the speed is read from the wheel's own clock
WHEEL_READ_GAP_S = 0.2


def _move(unit: Unit, target: int, rate_hz: float) -> tuple[str, dict[str, object]]:
    response = send(unit, "MOTOR_MOVE", fields={"target_steps": target, "rate_hz": rate_hz})
    answer = answer_text(response["answers"][0])
    if answer == "ACK":
        wait_stopped(unit)
    return answer, ack_values(unit, "MOTOR_GET")


@check_function("stage_move")
def stage_move_check(unit: Unit) -> Evidence:
    """MOTOR_MOVE by MOVE_STEPS and back: the stage stops at each target, idle, at no limit."""
    with stage_kept(unit) as reading:
        if reading["state"] in ("disabled", "estop"):
            ack_values(unit, "MOTOR_ENABLE", {"enable": "on"})
        limits = ack_values(unit, "MOTOR_GET_LIMITS")
        start = int(reading["steps"])
        rate = float(limits["max_rate_hz"]) / 2
        # Away from the nearer limit, so that the move stays inside them.
        direction = 1 if start + MOVE_STEPS <= int(limits["high_steps"]) else -1
        target = start + direction * MOVE_STEPS
        out_answer, out = _move(unit, target, rate)
        back_answer, back = _move(unit, start, rate)
        evidence: Evidence = {
            "start_steps": start,
            "target_steps": target,
            "rate_hz": rate,
            "out": {"answer": out_answer, "steps": out["steps"], "state": out["state"],
                    "encoder": out["encoder"], "at_limit": out["at_limit"]},
            "back": {"answer": back_answer, "steps": back["steps"], "state": back["state"],
                     "encoder": back["encoder"], "at_limit": back["at_limit"]},
        }  # fmt: skip
        problems = []
        for name, answer, got, want in (("out", out_answer, out, target),
                                        ("back", back_answer, back, start)):  # fmt: skip
            if answer != "ACK":
                problems.append(f"move {name} to {want} answered {answer}")
            elif int(str(got["steps"])) != want or got["state"] != "idle":
                problems.append(
                    f"move {name}: stopped at {got['steps']} steps ({got['state']}), not {want}"
                )
        return conclude(problems, evidence)


@check_function("stage_limits")
def stage_limits_check(unit: Unit) -> Evidence:
    """A move beyond either soft limit and a rate above the maximum are refused with
    OUT_OF_RANGE, and the stage does not move."""
    with stage_kept(unit) as reading:
        if reading["state"] in ("disabled", "estop"):
            ack_values(unit, "MOTOR_ENABLE", {"enable": "on"})
        limits = ack_values(unit, "MOTOR_GET_LIMITS")
        start = int(reading["steps"])
        max_rate = float(limits["max_rate_hz"])
        attempts = {
            f"MOVE to high + 1 ({int(limits['high_steps']) + 1})": (
                "MOTOR_MOVE", {"target_steps": int(limits["high_steps"]) + 1, "rate_hz": max_rate / 2}),
            f"MOVE to low - 1 ({int(limits['low_steps']) - 1})": (
                "MOTOR_MOVE", {"target_steps": int(limits["low_steps"]) - 1, "rate_hz": max_rate / 2}),
            f"MOVE at max rate + 1 Hz ({max_rate + 1:g})": (
                "MOTOR_MOVE", {"target_steps": start, "rate_hz": max_rate + 1}),
            f"SET_RATE max + 1 Hz ({max_rate + 1:g})": ("MOTOR_SET_RATE", {"rate_hz": max_rate + 1}),
        }  # fmt: skip
        cases = []
        for name, (command, fields) in attempts.items():
            answer = answer_text(send(unit, command, fields=fields)["answers"][0])
            cases.append({"case": name, "answer": answer,
                          "ok": answer.startswith("NAK OUT_OF_RANGE")})  # fmt: skip
        send(unit, "MOTOR_STOP", fields={})
        wait_stopped(unit)
        after = int(ack_values(unit, "MOTOR_GET")["steps"])
        evidence: Evidence = {"limits": limits, "start_steps": start, "after_steps": after,
                              "cases": cases}  # fmt: skip
        wrong = [f"{c['case']}: {c['answer']}" for c in cases if not c["ok"]]
        if after != start:
            wrong.append(f"the stage moved from {start} to {after} steps")
        return conclude(wrong, evidence)


@check_function("stage_home")
def stage_home_check(unit: Unit, timeout_s: float = 120.0) -> Evidence:
    """MOTOR_HOME runs to the home switch and defines it as 0 steps and 0 encoder counts.
    Destructive: the stage's old coordinates are gone."""
    with stage_kept(unit) as reading:
        if reading["state"] in ("disabled", "estop"):
            ack_values(unit, "MOTOR_ENABLE", {"enable": "on"})
        answer = answer_text(send(unit, "MOTOR_HOME", fields={})["answers"][0])
        deadline = time.monotonic() + timeout_s
        got = ack_values(unit, "MOTOR_GET")
        while answer == "ACK" and got["state"] == "homing" and time.monotonic() < deadline:
            time.sleep(0.1)
            got = ack_values(unit, "MOTOR_GET")
        evidence: Evidence = {"answer": answer, "after": got, "before_steps": reading["steps"]}
        if answer != "ACK" or got["homed"] != "yes" or int(got["steps"]) != 0:
            raise CheckFailed(f"homing answered {answer}, then {got['state']} at "
                              f"{got['steps']} steps, homed {got['homed']}", evidence)  # fmt: skip
        return evidence


@check_function("wheel_speed")
def wheel_speed_check(unit: Unit) -> Evidence:
    """WHEEL_SET_SPEED: the wheel then turns at that speed (its angle against its clock)."""
    before = ack_values(unit, "WHEEL_GET")
    nominal = float(unit.client.wheel()["nominal_speed_deg_s"])
    speed = min(360.0, nominal * WHEEL_TEST_SPEED_FACTOR)
    try:
        ack_values(unit, "WHEEL_SET_SPEED", {"speed_deg_s": speed})
        first = ack_values(unit, "WHEEL_GET")
        time.sleep(WHEEL_READ_GAP_S)
        second = ack_values(unit, "WHEEL_GET")
    finally:
        ack_values(unit, "WHEEL_SET_SPEED", {"speed_deg_s": float(before["speed_deg_s"])})
    dt = float(second["time_s"]) - float(first["time_s"])
    turned = (float(second["angle_deg"]) - float(first["angle_deg"])) % 360.0
    measured = turned / dt if dt > 0 else float("nan")
    evidence: Evidence = {"set_deg_s": speed, "reported_deg_s": second["speed_deg_s"],
                          "angles_deg": [first["angle_deg"], second["angle_deg"]],
                          "device_times_s": [first["time_s"], second["time_s"]],
                          "measured_deg_s": measured, "restored_deg_s": before["speed_deg_s"]}  # fmt: skip
    if not abs(measured / speed - 1) <= WHEEL_SPEED_TOLERANCE:
        raise CheckFailed(
            f"set {speed:g} deg/s, the wheel turned at {measured:.3f} deg/s", evidence
        )
    return evidence


def _header_brief(h: StreamFrameHeader) -> dict[str, object]:
    return {k: h[k] for k in ("counter", "timestamp_ns", "stage_position", "rows", "cols")}


@check_function("wheel_delay")
def wheel_delay_check(unit: Unit) -> Evidence:
    """With delay compensation on, a wheel exposure starts T_delay after the channel's entry
    pulse, so the frame's imaging centre (start angle + w T_frame / 2, from its header) is
    the channel centre within the eq 8 error (docs/wheel.md, docs/physics.md §4)."""
    client = unit.client
    wheel = client.wheel()
    compensation = bool(wheel["compensation"])
    speed = float(wheel["speed_deg_s"])
    if ack_values(unit, "GET_SENSOR")["trained"] != "yes":
        client.train()
    # The channel two ahead of the one in front: its entry pulse is less than a third of a
    # revolution away.
    count = len(wheel["channels"])
    channel = ((wheel["channel"] if wheel["channel"] is not None else 0) + 2) % count
    try:
        # T_center holds at the nominal speed only (docs/wheel.md): measure there.
        if speed != wheel["nominal_speed_deg_s"]:
            client.set_wheel_speed(float(wheel["nominal_speed_deg_s"]))
        with frame_stream_used():
            result = client.wheel_acquire([channel], compensated=True, timeout_s=30.0)
    finally:
        client.set_wheel_compensation(compensation)
        if speed != wheel["nominal_speed_deg_s"]:
            client.set_wheel_speed(speed)
    # The start angle from the frame's header as the daemon kept it: this check must not
    # depend on the payload CRC (a frame it rejects is not in ``result["frames"]``). The frame
    # is told by its device counter, from the one WHEEL_ACQUIRE announced on: a header counted
    # before it is an earlier stream's, come late, and is not measured (a counter that jumps
    # ahead is stream.counters' to judge, not this check's).
    first_counter = int(result["stream"]["first_counter"])
    log = client.stream_headers()["frames"]
    headers = [h for h in log if (h["counter"] - first_counter) % 2**32 < 2**31]
    exposure = result["exposure"]
    evidence: Evidence = {
        "channel": channel,
        "speed_deg_s": result["speed_deg_s"],
        "frame_time_s": exposure["frame_time_s"],
        "delay_s": exposure["delay_s"],
        "device_delay_s": result["device_delay_s"],
        "frames_delivered": len(result["frames"]),
        "first_counter": first_counter,
        "headers_of_earlier_streams": len(log) - len(headers),
    }
    if not headers or exposure["centre_error_deg"] is None:
        raise CheckFailed(
            f"the wheel acquisition left no frame header from counter {first_counter} (the one "
            "WHEEL_ACQUIRE announced) on to measure",
            evidence,
        )
    # Device values only: the angle the FPGA latched at the exposure start, the speed and
    # T_frame the unit runs at. Nothing here is timed by the host, so a busy host cannot move
    # the result.
    evidence["header"] = _header_brief(headers[0])
    start_deg = headers[0]["stage_position"] * 1e-4  # docs/protocol.md 0x43: units of 1e-4 deg
    centre_deg = start_deg + result["speed_deg_s"] * exposure["frame_time_s"] / 2.0
    wanted_deg = wheel["channels"][channel]["centre_deg"] + (exposure["centre_offset_deg"] or 0.0)
    error = (centre_deg - wanted_deg + 180.0) % 360.0 - 180.0
    tolerance = exposure["centre_error_deg"]
    evidence |= {
        "start_angle_deg": start_deg,
        "imaging_centre_deg": centre_deg % 360.0,
        "channel_centre_deg": wanted_deg % 360.0,
        "error_deg": error,
        "tolerance_deg": tolerance,
    }
    if abs(error) > tolerance:
        raise CheckFailed(
            f"imaging centre {centre_deg % 360.0:.4f} deg, channel centre {wanted_deg % 360.0:.4f} "
            f"deg: {error:+.4f} deg off (eq 8 allows {tolerance:.4f}); an exposure at the entry "
            f"pulse is {result['speed_deg_s'] * exposure['delay_s']:.4f} deg early",
            evidence,
        )
    return evidence
