"""A request that fails part-way puts back what it had changed, and says so.

The simulated camera fails one coming command on purpose (POST /api/v1/sim/fail-next, the
SIM_FAIL_NEXT command): a NAK (the device refusing it) or a silence of a couple of seconds (the
line drops; the host's retries time out; then it answers again). Over the full stack (HTTP ->
camd serve -> simulated camera), the camera's state is read back from the device itself
(``tests.device_snapshot``) before the request and after its error, and must be equal; the
error is the failing command's (same HTTP status) followed by what was restored.

How a register write reaches the device (camd.sensor.registers, FpgaBridge): the daemon reads
the register file (one REG_READ per readable register: the snapshot it restores from), sends
all the values in one REG_WRITE_BURST, then reads back each register written (REG_READ). The
burst is all-or-nothing on the device, so a write fails "part-way" when the burst has been
applied and a read-back then fails: the third read-back is the "third register" of a write of
three.

The last tests check ``Apply`` itself, without a daemon.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from camd.client import CamdClient, CamdError
from camd.daemon.errors import DeviceRejected, DeviceTimeout, SessionError
from camd.daemon.transaction import Apply
from camd.sensor.regmap import load_register_map
from tests.device_snapshot import snapshot
from tests.test_camctl import camctl
from tests.test_trust import small_window_daemon

# Not ``exclusive``: these check a rollback (the device's state before and after, the error's
# words), not a deadline. The link's silences are seconds long with seconds to spare for a busy
# machine's late retries; a stream or scan that starts lives a few frames. Checked beside
# `stress-ng --cpu 2`.

HR400 = load_register_map("hr400")
READABLE = sum(reg.readable for reg in HR400.registers)  # REG_READs of a write's snapshot
WRITES = {"GAIN": 0x150, "OFFSET": 120, "BACK_PATH": 30}  # plain registers, each read back
# The link's defaults (config/camd.toml): reconnect_max_s + (1 + retries) x timeout_s + 5 s.
RESTORE_WAIT_S = 2.0 + 21 * 0.1 + 5.0  # sim.link_retries = 20 (docs/config.md)
# A dropped line that comes back: it outlasts the host's 2.1 s of attempts (2.4 s to spare for
# a busy machine's late retries) and ends well inside the restore's wait (4.6 s to spare).
SILENCE_S = 4.5


@pytest.fixture(scope="module")
def client(tmp_path_factory: pytest.TempPathFactory) -> Iterator[CamdClient]:
    with (
        small_window_daemon(tmp_path_factory.mktemp("camd-faults")) as url,
        CamdClient(url, timeout_s=120) as client,
    ):
        client.set_mode("area")
        client.enable_stage(True)
        client.move_stage(0.3)
        yield client


@contextlib.contextmanager
def failing(client: CamdClient, command: str, **how: Any) -> Iterator[None]:
    """Arm one failure of ``command``; disarmed afterwards if it did not fire."""
    client.fail_next(command, **how)
    try:
        yield
    finally:
        client.clear_fail_next()


def refused(call: Any) -> CamdError:
    with pytest.raises(CamdError) as info:
        call()
    return info.value


def wait_answering(client: CamdClient, timeout_s: float = 60.0) -> None:
    """Until the camera answers GET_STATUS again (after a silence)."""
    deadline = time.monotonic() + timeout_s
    while client.status()["device"] is None:
        assert time.monotonic() < deadline, "the camera did not answer again"
        time.sleep(0.2)


def restored(labels: str) -> str:
    return f"; restored: {labels}"


def small_window(client: CamdClient) -> None:
    """The window the daemon started with (a scan that ran leaves its own)."""
    client.write_registers({"WIN_ROWS": 16, "EXPOSURE": 4, "BACK_PATH": 0})


# -- (a) a register write ------------------------------------------------------------------------


def test_a_register_write_refused_at_its_third_read_back_puts_the_registers_back(
    client: CamdClient,
) -> None:
    before = snapshot(client)
    with failing(client, "REG_READ", skip=READABLE + 2, error="BUSY"):
        error = refused(lambda: client.write_registers(dict(WRITES)))
    assert (error.http_status, error.code) == (502, "device_nak")
    assert error.message.startswith(
        "REG_READ refused by the device: BUSY (5): the device is busy with a previous command: "
        "REG_READ failed on purpose (SIM_FAIL_NEXT)"
    )
    assert error.message.endswith(restored("registers GAIN, OFFSET, BACK_PATH"))
    assert snapshot(client) == before
    events = [e["message"] for e in client.events(limit=5)["events"]]
    assert any(m.startswith("register write failed: REG_READ refused") for m in events)


def test_camctl_reg_write_says_what_was_restored(client: CamdClient) -> None:
    before = snapshot(client)
    with failing(client, "REG_READ", skip=READABLE + 2, error="BUSY"):
        proc = camctl(client.url, "reg", "write", *(f"{k}={v}" for k, v in WRITES.items()))
    assert proc.returncode == 1
    assert "camctl: error: REG_READ refused by the device: BUSY (5)" in proc.stderr
    assert "; restored: registers GAIN, OFFSET, BACK_PATH" in proc.stderr
    assert snapshot(client) == before


# -- (b) a scan's apply ---------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("command", "drive_stage", "labels"),
    [
        # The register step itself fails: the mode it had set before goes back.
        ("REG_WRITE_BURST", False, "registers WIN_ROWS, BACK_PATH, mode area"),
        # The last step fails: everything before it goes back, the stage included.
        (
            "START_STREAM",
            True,
            "file {file} removed, stage stopped and back at 300.000 mm, "
            "registers WIN_ROWS, BACK_PATH, mode area",
        ),
    ],
)
def test_a_scan_that_fails_while_being_applied_is_put_back_and_frees_the_slot(
    client: CamdClient, tmp_path: Path, command: str, drive_stage: bool, labels: str
) -> None:
    small_window(client)
    if drive_stage:
        client.enable_stage(False)  # the scan enables it; put back, it is released again
    try:
        before = snapshot(client)
        out = tmp_path / "failed.h5"
        with failing(client, command, error="BUSY"):
            error = refused(
                lambda: client.start_scan(
                    4, 5, out=str(out), line_period_s=3e-3, drive_stage=drive_stage
                )
            )
        assert (error.http_status, error.code) == (502, "device_nak"), error.message
        assert error.message.startswith(f"{command} refused by the device: BUSY (5)")
        assert error.message.endswith(restored(labels.format(file=out))), error.message
        assert snapshot(client) == before
        assert not out.exists()
        status = client.status()
        assert status["acquisition"] is None or not status["acquisition"]["running"]
    finally:
        client.enable_stage(True)
    # The slot is free: the next scan starts and runs to its end.
    client.start_scan(4, 5, out=str(tmp_path / "next.h5"), line_period_s=3e-3, drive_stage=False)
    assert client.wait_scan(120)["state"] == "done"
    client.set_mode("area")


# -- (c) a link drop ------------------------------------------------------------------------------


def test_a_scan_whose_line_drops_at_its_register_write_is_put_back(
    client: CamdClient, tmp_path: Path
) -> None:
    small_window(client)
    before = snapshot(client)
    with failing(client, "REG_WRITE_BURST", duration_s=SILENCE_S):
        error = refused(
            lambda: client.start_scan(
                4, 5, out=str(tmp_path / "x.h5"), line_period_s=3e-3, drive_stage=False
            )
        )
    assert (error.http_status, error.code) == (504, "timeout"), error.message
    assert error.message.startswith("REG_WRITE_BURST: no answer from the device on ")
    # The mode was changed before the line dropped: it is put back once the camera answers.
    assert error.message.endswith(restored("registers WIN_ROWS, BACK_PATH, mode area"))
    assert snapshot(client) == before


def test_a_register_write_whose_line_drops_after_the_burst_is_put_back(
    client: CamdClient,
) -> None:
    before = snapshot(client)
    # The burst went through; the line drops at the second read-back.
    with failing(client, "REG_READ", skip=READABLE + 1, duration_s=SILENCE_S):
        error = refused(lambda: client.write_registers(dict(WRITES)))
    assert (error.http_status, error.code) == (504, "timeout"), error.message
    assert error.message.startswith("REG_READ: no answer from the device on ")
    assert error.message.endswith(restored("registers GAIN, OFFSET, BACK_PATH"))
    assert snapshot(client) == before


def test_a_stream_whose_start_is_lost_is_stopped_and_its_mode_put_back(
    client: CamdClient,
) -> None:
    before = snapshot(client)
    with failing(client, "START_STREAM", duration_s=SILENCE_S):
        error = refused(lambda: client.start_stream(0, mode="tdi", stages=4))
    assert (error.http_status, error.code) == (504, "timeout"), error.message
    assert error.message.endswith(restored("stream stopped, mode area"))
    assert snapshot(client) == before
    assert not client.stream()["streaming"]


def test_a_mode_change_whose_answer_is_lost_puts_the_mode_back(client: CamdClient) -> None:
    before = snapshot(client)
    with failing(client, "SET_MODE", duration_s=SILENCE_S):
        error = refused(lambda: client.set_mode("tdi"))
    assert (error.http_status, error.code) == (504, "timeout"), error.message
    # The camera might have changed mode and lost only its answer: the mode is set back.
    assert error.message.endswith(restored("mode area"))
    assert snapshot(client) == before


def test_a_wheel_speed_whose_answer_is_lost_puts_the_speed_back(client: CamdClient) -> None:
    before = snapshot(client)
    speed_before = client.wheel()["speed_deg_s"]
    with failing(client, "WHEEL_SET_SPEED", duration_s=SILENCE_S):
        error = refused(lambda: client.set_wheel_speed(12.5))
    assert (error.http_status, error.code) == (504, "timeout"), error.message
    assert error.message.endswith(restored(f"wheel speed {speed_before:g} deg/s"))
    assert snapshot(client) == before


def test_when_the_camera_does_not_come_back_the_error_says_what_was_not_restored(
    client: CamdClient, tmp_path: Path
) -> None:
    small_window(client)
    before = snapshot(client)
    # Armed without ``failing``: it fires, and the camera cannot be asked to disarm meanwhile.
    # Silent until well after the restore gave up (~8 s after the command): 8 s to spare for a
    # busy machine's late give-up.
    client.fail_next("REG_WRITE_BURST", duration_s=RESTORE_WAIT_S + 8.0)
    error = refused(
        lambda: client.start_scan(
            4, 5, out=str(tmp_path / "x.h5"), line_period_s=3e-3, drive_stage=False
        )
    )
    assert (error.http_status, error.code) == (504, "timeout"), error.message
    assert (
        "; could NOT restore: registers WIN_ROWS, BACK_PATH, mode area (the camera did not "
        f"answer again within {RESTORE_WAIT_S:.3g} s: "
    ) in error.message
    assert error.message.endswith("check them by hand once the camera answers (`camctl status`)")
    wait_answering(client)
    # Exactly what the message names is left to check: the mode (the burst was never
    # executed, so the registers are as they were).
    after = snapshot(client)
    assert after["mode"] == "tdi"
    assert {**after, "mode": before["mode"]} == before
    client.set_mode("area")


# -- a stage enable -------------------------------------------------------------------------------


def test_an_enable_refused_after_the_limits_were_programmed_puts_the_limits_back(
    client: CamdClient,
) -> None:
    client.enable_stage(False)
    try:
        before = snapshot(client)
        with failing(client, "MOTOR_ENABLE", error="BUSY"):
            error = refused(lambda: client.enable_stage(True))
        assert (error.http_status, error.code) == (502, "device_nak"), error.message
        assert error.message.endswith(restored("stage limits"))
        assert snapshot(client) == before
    finally:
        client.enable_stage(True)


def test_a_stage_move_whose_answer_is_lost_is_stopped_where_it_stood(
    client: CamdClient,
) -> None:
    before = snapshot(client)
    with failing(client, "MOTOR_MOVE", duration_s=SILENCE_S):
        error = refused(lambda: client.move_stage(0.2))
    assert (error.http_status, error.code) == (504, "timeout"), error.message
    assert error.message.endswith(restored("stage stopped and back at 300.000 mm"))
    assert snapshot(client) == before


# -- (d) a wheel acquisition's apply -------------------------------------------------------------

# hr400: 513 sequencer clocks of 25 MHz per line; 3 ms of exposure is round(3e-3 / T_line) = 146
# lines, which the EXPOSURE group (EXP_HI, EXP_LO) holds in EXP_LO alone.
WHEEL_EXPOSURE_S = 0.003
WHEEL_LINES = 146


@pytest.mark.parametrize(
    ("command", "labels"),
    [
        # The compensation switch fails: the exposure written before it goes back.
        ("WHEEL_COMPENSATION", "registers EXP_LO"),
        # The acquisition's start fails: the compensation and the exposure go back.
        ("WHEEL_ACQUIRE", "delay compensation {was}, registers EXP_LO"),
    ],
)
def test_a_wheel_acquisition_that_fails_while_being_applied_is_put_back(
    client: CamdClient, command: str, labels: str
) -> None:
    small_window(client)
    wheel = client.wheel()
    assert wheel["speed_deg_s"] > 0  # the simulated wheel turns from power-on
    was = wheel["compensation"]
    before = snapshot(client)
    assert before["registers"]["EXP_LO"] != WHEEL_LINES
    with failing(client, command, error="BUSY"):
        error = refused(
            lambda: client.wheel_acquire(
                [3], exposure_s=WHEEL_EXPOSURE_S, compensated=not was, timeout_s=30
            )
        )
    assert (error.http_status, error.code) == (502, "device_nak"), error.message
    assert error.message.startswith(f"{command} refused by the device: BUSY (5)")
    word = "on" if was else "off"
    assert error.message.endswith(restored(labels.format(was=word))), error.message
    assert snapshot(client) == before
    events = [e["message"] for e in client.events(limit=5)["events"]]
    assert any(m.startswith(f"wheel acquisition failed: {command} refused") for m in events)
    status = client.status()
    assert status["acquisition"] is None or not status["acquisition"]["running"]


def test_a_wheel_acquisition_the_camera_ends_early_puts_back_what_it_set(
    client: CamdClient,
) -> None:
    # Part-way in the strictest sense: the acquisition ran, one of its two frames came, then the
    # camera ended the stream. What the request had set (exposure, compensation) goes back.
    small_window(client)
    was = client.wheel()["compensation"]
    before = snapshot(client)
    with failing(client, "WHEEL_ACQUIRE", end_after_frames=1):
        error = refused(
            lambda: client.wheel_acquire(
                [3, 9], exposure_s=WHEEL_EXPOSURE_S, compensated=not was, timeout_s=60
            )
        )
    assert (error.http_status, error.code) == (502, "ended_early"), error.message
    word = "on" if was else "off"
    assert error.message.endswith(restored(f"delay compensation {word}, registers EXP_LO"))
    assert snapshot(client) == before
    # The slot is free: the same acquisition, asked again, runs.
    doc = client.wheel_acquire([3], exposure_s=WHEEL_EXPOSURE_S, compensated=not was)
    assert doc["exposure"]["exposure_lines"] == WHEEL_LINES and len(doc["frames"]) == 1
    client.set_wheel_compensation(was)


# -- Apply itself -----------------------------------------------------------------------------------


def test_nested_applies_say_everything_once() -> None:
    events: list[tuple[str, str, str]] = []
    done: list[str] = []
    log = lambda *e: events.append(e)  # noqa: E731

    def inner_request() -> None:
        with Apply("inner", log) as inner:
            inner.step(lambda: None, lambda: done.append("b"), "registers B")
            raise DeviceTimeout("B: no answer")

    with pytest.raises(DeviceTimeout) as info, Apply("outer", log, source="scan") as outer:
        outer.step(lambda: None, lambda: done.append("a"), "mode area")
        inner_request()
    assert str(info.value) == "B: no answer; restored: registers B, mode area"
    assert done == ["b", "a"]
    assert events == [
        ("warning", "scan", f"outer failed: B: no answer; restored: {'registers B, mode area'}")
    ]


def test_an_undo_waits_for_the_link_once_and_names_what_it_could_not_reach() -> None:
    waits: list[int] = []
    done: list[str] = []

    def link_wait() -> str | None:
        waits.append(1)
        return "the camera did not answer again within 1 s"

    def inner_request() -> None:
        with Apply("inner", lambda *e: None) as inner:
            inner.step(lambda: None, lambda: done.append("b"), "registers B")
            lost = DeviceTimeout("B: no answer")
            lost.link_wait = link_wait
            raise lost

    with pytest.raises(DeviceTimeout) as info, Apply("outer", lambda *e: None) as outer:
        outer.step(lambda: None, lambda: done.append("a"), "mode area")
        inner_request()
    assert waits == [1] and done == []
    assert str(info.value) == (
        "B: no answer; could NOT restore: registers B, mode area (the camera did not answer "
        "again within 1 s); check them by hand once the camera answers (`camctl status`)"
    )


@pytest.mark.parametrize(
    ("error", "note"),
    [
        (
            DeviceRejected("SET_MODE refused by the device: BUSY", "BUSY"),
            "nothing had been changed",
        ),
        (DeviceTimeout("SET_MODE: no answer"), "restored: mode area"),
    ],
)
def test_a_step_whose_answer_was_lost_is_undone_too(error: SessionError, note: str) -> None:
    # A NAK: the device did not do it. A lost answer: it may have: undo it (harmless if not).
    error.link_wait = None if isinstance(error, DeviceRejected) else (lambda: None)
    done: list[str] = []

    def fail() -> None:
        raise error

    with pytest.raises(type(error)) as info, Apply("mode change", lambda *e: None) as apply:
        apply.step(fail, lambda: done.append("area"), "mode area")
    assert str(info.value) == f"{error}; {note}"
    assert done == ([] if isinstance(error, DeviceRejected) else ["area"])
