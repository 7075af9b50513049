"""A daemon put back after a test answers as a fresh one does (tests/daemon_reset.py): what the
modules that share one daemon between their tests rely on."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from camd.cli._daemon_proc import DaemonProcess
from camd.client import CamdClient
from tests.crash_support import wait_for
from tests.daemon_reset import Found, put_back, state_documents

NO_TOKEN = {"CAMD_TOKEN": ""}


@pytest.fixture(scope="module")
def client(tmp_path_factory: pytest.TempPathFactory) -> Iterator[CamdClient]:
    data = tmp_path_factory.mktemp("camd-reset")
    with (
        DaemonProcess(data, env=NO_TOKEN, start_timeout_s=120.0) as daemon,
        CamdClient(daemon.url, timeout_s=60) as c,
    ):
        c.wait_ready(120)
        yield c
    assert daemon.exit_code in (0, -15), daemon.log_path.read_text()


def differences(a: Any, b: Any, path: str = "") -> list[str]:
    """Where two documents differ, as ``path: a != b`` lines."""
    if isinstance(a, dict) and isinstance(b, dict):
        return [
            line
            for key in sorted(set(a) | set(b), key=str)
            for line in differences(a.get(key), b.get(key), f"{path}.{key}")
        ]
    return [] if a == b else [f"{path}: {a!r} != {b!r}"]


def assert_as_fresh(client: CamdClient, fresh: dict[str, Any]) -> None:
    now = state_documents(client)
    assert now == fresh, "put back, the daemon differs from a fresh one:\n" + "\n".join(
        differences(now, fresh)
    )


def test_a_daemon_put_back_answers_as_a_fresh_one(client: CamdClient, tmp_path: Path) -> None:
    fresh = state_documents(client)
    found = Found.of(client)
    # Everything put_back puts back, changed as a test would, and left so: held control, a
    # stream left running, an armed failure, a latched emergency stop.
    client.take_control(60)
    client.set_mode("tdi")
    client.write_registers({"WIN_ROWS": 64, "EXPOSURE": 3, "OFFSET": 7})
    client.set_scene("bars")
    client.set_polarizer(30.0)
    client.set_stage_faults(ripple=0.01)
    client.set_stage(track=False, speed_m_s=0.01)
    client.set_wheel_compensation(True)
    client.set_wheel_speed(40.0)
    client.enable_stage(True)
    client.move_stage(0.55)
    client.acquire(3, mode="area")
    client.start_scan(8, 20, out=str(tmp_path / "scan.h5"), quicklook=False, drive_stage=False)
    client.wait_scan(120)
    client.start_stream(0, mode="tdi")
    client.capture_background(2)
    wait_for("the background", lambda: client.background()["state"] == "ready")
    client.fail_next("START_STREAM", error="BUSY")
    client.estop()
    changed = state_documents(client)
    settings = {"status", "registers", "timing", "stage", "wheel", "sim", "background"}
    assert {key for key in fresh if changed[key] != fresh[key]} == settings, changed
    put_back(client, found)
    assert_as_fresh(client, fresh)

    # What runs when a test ends: a scan, a stream; and a link that lost its training.
    client.start_scan(8, 0, out=str(tmp_path / "endless.h5"), quicklook=False, drive_stage=False)
    assert state_documents(client)["scan_running"] is True
    put_back(client, found)
    assert_as_fresh(client, fresh)
    client.start_stream(0, mode="area")
    assert state_documents(client)["stream"]["streaming"] is True
    put_back(client, found)
    assert_as_fresh(client, fresh)
    client.link_command(command="SIM_RESKEW", fields={"seed": 99})
    wait_for("the training lost", lambda: not client.last_training()["trained"])
    put_back(client, found)
    assert_as_fresh(client, fresh)
