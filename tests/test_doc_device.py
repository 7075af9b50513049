"""A camera built from the documents alone (tests/doc_device) drives the daemon as real
hardware would: a pseudo-terminal as its serial port, no simulator, no USB frame stream.

The daemon must accept it (status idle, ping, registers, training, stage, wheel), and `camd
conform` against it must pass every check that needs no frame stream, while the checks that
need one must not pass. The device imports neither camd nor firmware_models: what it does, it
learnt from docs/ and config/.
"""

from __future__ import annotations

import ast
import json
import os
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from camd.cli._daemon_proc import DaemonProcess
from camd.client import CamdClient
from tests.doc_device.device import DocDevice
from tests.doc_device.server import PtyDevice

ROOT = Path(__file__).resolve().parent.parent
NO_TOKEN = {"CAMD_TOKEN": ""}
WAIT_S = 120.0  # generous: the suite runs on a busy 2-core machine

# The checks that need the USB frame stream, which this device has not got. The conformance
# change in progress reports them "not_run" for want of a stream; until it merges they fail.
STREAM_CHECKS = frozenset({
    "stream.headers", "stream.counters", "stream.crc", "stream.frame_period", "wheel.delay",
})  # fmt: skip
# Commands whose valid case is exercised by a stream check: they cannot pass without one.
STREAM_COMMANDS = frozenset({"cmd.START_STREAM", "cmd.WHEEL_ACQUIRE"})

# Soft limits in the daemon's config, inside the rail's 1.2 m of travel (64000 and 704000
# microsteps of 1.5625 um).
LOW_LIMIT_M, HIGH_LIMIT_M = 0.1, 1.1
POWER_ON_LIMITS = (0, 768000)  # docs/motion.md "Power-on": the whole travel

pytestmark = pytest.mark.slow


def test_the_doc_device_imports_neither_camd_nor_the_simulator() -> None:
    """The point of the exercise: the documents are enough, the code is not consulted."""
    allowed_roots = {"tests", "__future__"} | set(sys.stdlib_module_names)
    for path in sorted((ROOT / "tests" / "doc_device").glob("*.py")):
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                roots = {alias.name.split(".")[0] for alias in node.names}
            elif isinstance(node, ast.ImportFrom):
                roots = {(node.module or "").split(".")[0]}
            else:
                continue
            assert roots <= allowed_roots, f"{path.name} imports {roots - allowed_roots}"
            if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("tests"):
                assert node.module.startswith("tests.doc_device"), f"{path.name}: {node.module}"


@pytest.fixture(scope="module")
def unit(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[PtyDevice, DaemonProcess]]:
    device = PtyDevice(DocDevice()).start()
    tmp = tmp_path_factory.mktemp("doc-device")
    config = tmp / "camd.toml"
    config.write_text(
        f'[link]\ndevice = "{device.port}"\n\n[stage]\nlow_limit_m = {LOW_LIMIT_M}\n'
        f"high_limit_m = {HIGH_LIMIT_M}\n",
        encoding="utf-8",
    )
    daemon = DaemonProcess(
        tmp / "data", env=NO_TOKEN, extra_args=["--config", str(config)], start_timeout_s=WAIT_S
    )
    daemon.command.remove("--sim")  # real hardware: the serial port of link.device
    try:
        with daemon:
            with CamdClient(daemon.url, timeout_s=60) as client:
                client.wait_ready(WAIT_S)
                _wait(lambda: client.status()["state"] == "idle", "the daemon to see the unit idle")
            yield device, daemon
    finally:
        device.stop()


def _wait(condition: Any, what: str, timeout_s: float = WAIT_S) -> None:
    deadline = time.monotonic() + timeout_s
    while not condition():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.1)


def test_the_daemon_accepts_the_doc_device(unit: tuple[PtyDevice, DaemonProcess]) -> None:
    device, daemon = unit
    with CamdClient(daemon.url, timeout_s=60) as client:
        status = client.status()
        assert status["state"] == "idle" and status["reason"] is None
        assert status["link"]["port"] == device.port and status["link"]["sim_pid"] is None
        assert status["device"]["fw_version"] == 0x0100
        ping = client.ping(count=5, size=32)
        assert ping["ok"] == 5
        # The link trained at the registers' reset values (docs/sensors.md LVDS_CTRL).
        training = client.last_training()
        assert training["locked"] is True and training["locked_lanes"] == 8
        client.write_registers({"WIN_ROWS": 100})
        assert client.read_register("WIN_ROWS")["value"] == 100
        assert device.device.sensor.field("WIN_ROWS") == 100
        client.write_registers({"WIN_ROWS": 534})
        wheel = client.wheel()
        assert wheel["speed_deg_s"] == pytest.approx(73.245, rel=1e-6)


def test_stage_limits_are_programmed_when_the_stage_is_enabled_not_on_connect(
    unit: tuple[PtyDevice, DaemonProcess],
) -> None:
    """docs/config.md [stage]: the configured limits go to the camera on enable (as docs/api.md
    says), not when it connects; until then it keeps its power-on limits."""
    device, daemon = unit
    stage = device.device.stage
    text = (ROOT / "docs" / "config.md").read_text(encoding="utf-8")
    assert "They are not sent when the camera connects" in text
    assert "programs into the FPGA's step generator (MOTOR_SET_LIMITS) when the camera" not in text
    with CamdClient(daemon.url, timeout_s=60) as client:
        with device.lock:
            assert (stage.low, stage.high) == POWER_ON_LIMITS
        limits = client.enable_stage(True)["limits"]
        try:
            with device.lock:
                assert (stage.low, stage.high) == (64000, 704000)
            assert limits["low_m"] == pytest.approx(LOW_LIMIT_M)
            assert limits["high_m"] == pytest.approx(HIGH_LIMIT_M)
        finally:
            client.enable_stage(False)
            with device.lock:
                stage.low, stage.high = POWER_ON_LIMITS  # as it powered up, for the next test


def test_the_daemon_drives_the_stage_and_wheel_of_the_doc_device(
    unit: tuple[PtyDevice, DaemonProcess],
) -> None:
    """A move through the daemon (MOTOR_ENABLE, MOTOR_SET_LIMITS, MOTOR_MOVE, MOTOR_GET until
    it stands) and a wheel speed (WHEEL_SET_SPEED, WHEEL_GET) land on the device as docs/motion.md
    and docs/wheel.md describe them."""
    device, daemon = unit
    stage = device.device.stage
    with CamdClient(daemon.url, timeout_s=60) as client:
        start_m = client.motion()["reading"]["position_m"]
        assert start_m == pytest.approx(0.6)  # docs/motion.md: the middle of the 1.2 m rail
        client.enable_stage(True)
        try:
            done = client.move_stage(start_m + 0.01, speed_m_s=0.05)
            assert done["reading"]["position_m"] == pytest.approx(start_m + 0.01, abs=2e-6)
            assert done["reading"]["state"] == "idle"
            with device.lock:
                assert stage.steps(device.now_s()) == 390400  # 0.61 m / 1.5625 um
            client.move_stage(start_m, speed_m_s=0.05)
        finally:
            client.enable_stage(False)
            with device.lock:
                stage.low, stage.high = POWER_ON_LIMITS
        wheel = client.set_wheel_speed(36.0)
        try:
            assert wheel["speed_deg_s"] == pytest.approx(36.0)
            assert device.device.wheel.speed == pytest.approx(36.0)
        finally:
            client.set_wheel_speed(73.245)


def test_camctl_reads_a_write_only_register_as_the_host_copy(
    unit: tuple[PtyDevice, DaemonProcess],
) -> None:
    """docs/cli.md camctl reg read: a write-only register shows the host's copy of the last
    value written, and exits 0 (it exited 1 with an error that quoted the value)."""
    _, daemon = unit
    camctl = [sys.executable, "-m", "camd.cli.camctl", "--url", daemon.url]
    env = {**os.environ, **NO_TOKEN}
    proc = subprocess.run([*camctl, "--json", "reg", "read", "SOFT_RESET"], capture_output=True,
                          text=True, timeout=120, env=env)  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout) == {
        "name": "SOFT_RESET", "address": 3, "value": 0, "fields": {"key": "none"},
    }  # fmt: skip
    proc = subprocess.run([*camctl, "reg", "read", "SOFT_RESET"], capture_output=True, text=True,
                          timeout=120, env=env)  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert "SOFT_RESET" in proc.stdout and "0x0000" in proc.stdout


@pytest.fixture(scope="module")
def conformance(unit: tuple[PtyDevice, DaemonProcess], tmp_path_factory: pytest.TempPathFactory
                ) -> dict[str, Any]:  # fmt: skip
    device, daemon = unit
    out = tmp_path_factory.mktemp("doc-conform")
    # --destructive: motion.home too, so MOTOR_HOME's valid case is exercised; this fixture runs
    # last. From the middle of the rail homing is 0.6 m at 20 mm/s, 30 s; the stage goes to the
    # daemon's low soft limit first at full speed (0.5 m, about 5 s), and homes from 0.1 m (5 s).
    with CamdClient(daemon.url, timeout_s=60) as client:
        client.enable_stage(True)
        try:
            client.move_stage(0.1, speed_m_s=0.1)
        finally:
            client.enable_stage(False)
            with device.lock:
                device.device.stage.low, device.device.stage.high = POWER_ON_LIMITS
    proc = subprocess.run(
        [sys.executable, "-m", "camd", "conform", "--url", daemon.url, "--out", str(out),
         "--json", "--destructive"],
        capture_output=True, text=True, timeout=600, env={**os.environ, **NO_TOKEN},
    )  # fmt: skip
    # 4: nothing failed, but the checks that need a frame stream were not run (docs/conformance.md).
    assert proc.returncode == 4, proc.stderr
    doc: dict[str, Any] = json.loads((out / "conformance.json").read_text(encoding="utf-8"))
    return doc


def test_conformance_passes_every_check_that_needs_no_stream(conformance: dict[str, Any]) -> None:
    outcomes = {c["id"]: c["outcome"] for c in conformance["checks"]}
    reasons = {c["id"]: c["reason"] for c in conformance["checks"]}
    needs_stream = STREAM_CHECKS | STREAM_COMMANDS
    assert needs_stream <= set(outcomes)
    wrong = {i: (o, reasons[i]) for i, o in outcomes.items()
             if i not in needs_stream and o != "pass"}  # fmt: skip
    assert wrong == {}
    assert outcomes["motion.home"] == "pass"
    assert conformance["unit"]["simulated"] is False


def test_conformance_does_not_pass_the_checks_that_need_a_stream(
    conformance: dict[str, Any],
) -> None:
    outcomes = {c["id"]: c["outcome"] for c in conformance["checks"]}
    reasons = {c["id"]: c["reason"] for c in conformance["checks"]}
    # Not failed either: a unit without a stream has not been shown wrong, only not shown right;
    # the commands whose valid case the stream checks exercise are not run with them.
    for check in sorted(STREAM_CHECKS | STREAM_COMMANDS):
        assert outcomes[check] == "not_run", (check, outcomes[check], reasons[check])
    assert any("no frame stream" in reasons[c] for c in STREAM_CHECKS)
    assert conformance["summary"]["verdict"] == "incomplete"
