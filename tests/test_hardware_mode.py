"""A daemon on a real serial port, as on a rig: hardware mode, preflight, and a missing USB device.

The camera is the simulated one run on its own (``python -m firmware_models --link PATH``, as a
vendor's unit or an emulator would be on a serial port): it answers on a pseudo-terminal, but
serves no USB frame stream (no ``--usb-socket``), like a camera whose USB cable is out. The daemon
is started as the README says for real hardware, ``camd serve --serial PORT``; it must then take
its frames from libusb (which finds no FX3 here) and never from the simulator (docs/hardware.md),
say so in its status, refuse every acquisition before it changes anything (no mode change, no
stage movement, no register write), and answer 503 ``no_frame_device`` naming the USB device it
looked for (docs/api.md).

One camera and one daemon for the module; the config's choice of backends (``camd serve``'s
flags over a config file) is tested in-process.
"""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from camd.cli._daemon_proc import DaemonProcess
from camd.cli.camd_main import build_parser
from camd.client import CamdClient, CamdError
from camd.daemon import backends
from camd.daemon.config import Config, ConfigError
from camd.daemon.serve import build_config
from camd.daemon.simulator import SimulatorProcess
from camd.link.frame_stream import FrameStream, StreamError
from camd.sensor.bridge import BridgeError
from camd.sensor.mcp2210 import Mcp2210Bridge
from camd.sensor.regmap import load_register_map
from tests.device_snapshot import snapshot
from tests.test_camctl import NO_TOKEN, camctl, camctl_env, camctl_json

FX3 = "04b4:00f1"  # the frame stream's USB id (config [stream])
WHEEL_SPEED_DEG_S = 73.245  # config/wheel.toml


@dataclass
class Rig:
    """The daemon's URL and log, and the camera's serial port."""

    url: str
    port: str
    log_path: Path


@pytest.fixture(scope="module")
def rig(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Rig]:
    tmp = tmp_path_factory.mktemp("camd-hw")
    camera = SimulatorProcess(tmp / "camera" / "camera.tty", profile="hr400")
    camera.start()
    try:
        daemon = DaemonProcess(tmp / "daemon", env=NO_TOKEN)
        port = str(tmp / "camera" / "camera.tty")
        daemon.command = [c for c in daemon.command if c != "--sim"] + ["--serial", port]
        with daemon:
            with CamdClient(daemon.url) as client:
                client.wait_ready(60)
                # Trained on connect over the FPGA's REG_* commands, as a rig's camera is.
                assert client.last_training()["trained"], client.events()
            yield Rig(daemon.url, port, daemon.log_path)
        assert daemon.exit_code in (0, -15), daemon.log_path.read_text()
    finally:
        camera.stop()


@pytest.fixture
def client(rig: Rig) -> Iterator[CamdClient]:
    with CamdClient(rig.url, timeout_s=60) as c:
        yield c


def refusal(call: Any) -> CamdError:
    with pytest.raises(CamdError) as info:
        call()
    return info.value


# -- item 1: --serial selects the hardware backends, and the status says which ------------------

HARDWARE_MD = Path(__file__).resolve().parent.parent / "docs" / "hardware.md"


def test_hardware_md_quotes_the_errors_as_the_code_gives_them(tmp_path: Path) -> None:
    """docs/hardware.md's messages are the code's: those this PC can produce are produced here
    (libusb finds no FX3 nor MCP2210 on a test PC) and must appear in it word for word."""
    doc = " ".join(HARDWARE_MD.read_text(encoding="utf-8").split())
    messages = []
    stream = FrameStream()  # libusb, the stream's default ids
    try:
        stream.open()
    except StreamError as exc:
        messages.append(str(exc))
    else:
        stream.close()
        pytest.skip("a camera's FX3 is plugged into this PC")
    try:
        Mcp2210Bridge(load_register_map("hr400").spi)  # libusb, the MCP2210's default ids
    except BridgeError as exc:
        messages.append(str(exc))
    for argv in (["--hardware"], ["--hardware", "--sim"]):
        with pytest.raises(ConfigError) as info:
            serve_config(tmp_path, *argv)
        messages.append(str(info.value))
    missing = [m for m in messages if m not in doc]
    assert not missing, f"docs/hardware.md does not quote: {missing}"


def serve_config(tmp_path: Path, *argv: str, toml: str = "") -> Config:
    """The config ``camd serve ARGV`` would run with, over a config file holding ``toml``."""
    path = tmp_path / "camd.toml"
    path.write_text(toml)
    args = build_parser().parse_args(["serve", "--config", str(path), *argv])
    return build_config(args)


def test_the_link_is_the_switch_and_a_mix_is_named(tmp_path: Path) -> None:
    sim = backends.describe(serve_config(tmp_path))
    assert (sim.camera, sim.link.backend, sim.stream.backend) == ("sim", "sim", "sim")
    serial = backends.describe(serve_config(tmp_path, "--serial", "/dev/ttyUSB0"))
    assert (serial.camera, serial.stream.detail) == ("hardware", f"USB {FX3}")
    bridge = '[sensor]\nbridge = "usb-spi"\n'
    usb_spi = backends.describe(serve_config(tmp_path, "--serial", "/dev/ttyUSB0", toml=bridge))
    assert (usb_spi.camera, usb_spi.registers.detail) == ("hardware", "MCP2210 USB 04d8:00de")
    # A config that asks for the simulator's stream on a real link gets it, named as a mix.
    mixed = backends.describe(
        serve_config(tmp_path, "--serial", "/dev/ttyUSB0", toml='[stream]\nbackend = "sim"\n')
    )
    assert mixed.camera == "mixed"
    assert backends.mixed_parts(mixed) == (
        "link=serial /dev/ttyUSB0, stream=sim, registers=fpga REG_* commands over the command link"
    )
    # --hardware overrides the file: nothing simulated is left.
    forced = serve_config(
        tmp_path,
        "--hardware",
        "--serial",
        "/dev/ttyUSB0",
        toml='[stream]\nbackend = "sim"\n'
        '[sensor]\nbridge = "usb-spi"\n[sensor.usb_spi]\nbackend = "sim"\n',
    )
    assert backends.describe(forced).camera == "hardware"
    assert (forced.stream_backend, forced.usb_spi_backend) == ("libusb", "libusb")


def test_hardware_without_a_port_is_refused(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"--hardware needs the camera's serial port: give "):
        serve_config(tmp_path, "--hardware")
    with pytest.raises(ConfigError, match="--hardware and --sim exclude each other"):
        serve_config(tmp_path, "--hardware", "--sim")
    # A port in the file is enough.
    on_file = serve_config(tmp_path, "--hardware", toml='[link]\ndevice = "/dev/camd-rs422"\n')
    assert backends.describe(on_file).link.detail == "/dev/camd-rs422"


@pytest.mark.slow
def test_serial_alone_takes_frames_from_usb_and_status_says_so(rig: Rig) -> None:
    status = camctl_json(rig.url, "status")
    assert status["backends"] == {
        "camera": "hardware",
        "link": {"kind": "hardware", "backend": "serial", "detail": rig.port},
        "stream": {"kind": "hardware", "backend": "libusb", "detail": f"USB {FX3}"},
        "registers": {
            "kind": "hardware",
            "backend": "fpga",
            "detail": "REG_* commands over the command link",
        },
    }
    human = subprocess.run(
        [sys.executable, "-m", "camd.cli.camctl", "--url", rig.url, "status"],
        capture_output=True,
        text=True,
        timeout=120,
        env={**camctl_env(), "COLUMNS": "300"},  # one row per line: no wrapping to match across
        check=False,
    )
    assert human.returncode == 0, human.stderr
    assert f"hardware: link serial {rig.port}, stream libusb USB {FX3}" in human.stdout
    # A hardware user is never sent to the simulator.
    stream = camctl(rig.url, "stream", "--frames", "5")
    assert stream.returncode == 1
    assert "simulat" not in stream.stderr and "firmware_models" not in stream.stderr
    assert f"no USB frame-stream device {FX3}" in stream.stderr
    log = rig.log_path.read_text()
    assert f"camera backends (hardware): link serial {rig.port}, stream libusb USB {FX3}" in log


# -- item 2: every acquisition checks its devices before it changes anything ---------------------


@pytest.mark.slow
def test_acquisitions_without_a_frame_device_change_nothing(client: CamdClient) -> None:
    client.set_wheel_speed(WHEEL_SPEED_DEG_S)  # a wheel run needs it turning
    try:
        refused_without_a_change(client)
    finally:
        client.set_wheel_speed(0.0)


def refused_without_a_change(client: CamdClient) -> None:
    before = snapshot(client)
    assert before["mode"] == "area"
    compensated = bool(before["wheel"]["compensation"])
    events_before = client.events()["events"]
    attempts = {
        # A scan that drives the stage: before, it set TDI mode and ran the stage (ramp,
        # closed loop, stop, back) before it found no frame stream.
        "scan": lambda: client.start_scan(8, 50, drive_stage=True),
        # A stream in another mode: before, it set the mode first.
        "stream": lambda: client.start_stream(5, mode="tdi"),
        "stare": lambda: client.acquire(5, mode="tdi"),
        # A wheel run with another exposure and compensation: before, it wrote them first.
        "wheel run": lambda: client.wheel_acquire(
            [2, 7], exposure_s=0.002, compensated=not compensated
        ),
    }
    for what, attempt in attempts.items():
        error = refusal(attempt)
        assert error.http_status == 503, (what, error)
        assert f"no USB frame-stream device {FX3} found" in error.message, (what, error)
    assert snapshot(client) == before
    new_events = client.events()["events"][len(events_before) :]
    assert new_events == [], new_events


# -- item 3: a missing USB device has its own error code -----------------------------------------


@pytest.mark.slow
def test_a_missing_usb_device_is_no_frame_device_not_disconnected(client: CamdClient) -> None:
    error = refusal(lambda: client.acquire(3))
    assert (error.http_status, error.code) == (503, "no_frame_device")
    assert error.message.startswith(f"no USB frame-stream device {FX3} found"), error.message
    assert f"lsusb -d {FX3}" in error.message and "udev" in error.message
    # The serial link is fine: the daemon stays connected and the camera answers.
    assert client.status()["state"] == "idle"
    assert client.ping(3)["ok"] == 3
