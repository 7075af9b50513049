"""Sensor registers over the full stack, as a user drives them.

camctl (in process; one test as a command) -> HTTP on loopback -> camd serve -> CommandLink -> real
pty -> simulated FPGA -> SPI master model -> sensor register file; and the same with the register
bridge switched to the simulated MCP2210 USB-SPI chip (pyusb API -> simulated backend -> Unix
socket -> the simulator's SPI bus). Values are random but in range, from the register map itself.
"""

from __future__ import annotations

import json
import random
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest

from camd.cli._daemon_proc import DaemonProcess
from camd.client import CamdClient
from camd.sensor.regmap import RegisterSpec, load_register_map
from tests.realtime_support import as_the_unit
from tests.test_camctl import NO_TOKEN, camctl, camctl_command_json, camctl_json

HR400 = load_register_map("hr400")
T_LINE_S = 513 / 25e6  # docs/physics.md §3: one line = 513 sequencer clocks (25 MHz assumed)


@contextmanager
def serve(
    tmp: Path, bridge: str, *, train_on_connect: bool = True, inject: str = ""
) -> Iterator[DaemonProcess]:
    """A daemon on the simulated hr400 with the given register bridge, camera connected; started
    as systemd/camd.service starts it (its nice and real-time limit: tests/realtime_support.py),
    since the stream, scan and wheel stacks' real-time tests run on it."""
    config = tmp / "camd.toml"
    config.write_text(
        f'[sensor]\nname = "hr400"\nbridge = "{bridge}"\n'
        f"train_on_connect = {'true' if train_on_connect else 'false'}\n"
    )
    with DaemonProcess(
        tmp,
        inject=inject,
        extra_args=["--config", str(config)],
        env=NO_TOKEN,
        wrapper=as_the_unit(),
    ) as daemon:
        with CamdClient(daemon.url) as client:
            client.wait_ready(60)
        yield daemon


@pytest.fixture(scope="module", params=["fpga", "usb-spi"])
def url(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    with serve(tmp_path_factory.mktemp(f"camd-{request.param}"), request.param) as daemon:
        yield daemon.url
    assert daemon.exit_code in (0, -15), daemon.log_path.read_text()


@pytest.fixture(autouse=True)
def registers_as_found(request: pytest.FixtureRequest) -> Iterator[None]:
    """A test on the module's daemon leaves its registers as it found them: the daemon is
    shared, and a random configuration left behind (LVDS_CTRL and TRAINING_WORD among it) made a
    later test's `camctl train` fail its lanes, depending on which tests ran before it."""
    if "url" not in request.fixturenames:
        yield
        return
    url = request.getfixturevalue("url")
    with CamdClient(url) as client:
        found = client.register_config()
    yield
    with CamdClient(url) as client:
        client.load_register_config(found)


def random_value(reg: RegisterSpec, rng: random.Random) -> int:
    """A random register value with every field inside its valid range."""
    value = 0
    for field in reg.all_fields():
        if field.enum:
            raw = rng.choice(list(field.enum.values()))
        else:
            raw = rng.randint(field.lo, field.hi)
        value = field.insert(value, raw)
    return value


def random_configuration(seed: int) -> dict[str, int]:
    """Random values for every RW register of hr400 (consistent across registers)."""
    rng = random.Random(seed)
    values = {reg.name: random_value(reg, rng) for reg in HR400.registers if reg.access == "rw"}
    # Holding the group would latch the exposure registers and fail their read-back by design.
    values["GROUP_HOLD"] = 0
    # The window must fit the 2048-row array (a cross-register check).
    values["WIN_ROWS"] = rng.randint(1, 2048)
    values["WIN_START"] = rng.randint(0, 2048 - values["WIN_ROWS"])
    return values


def dump(url: str) -> dict[str, int]:
    doc = camctl_json(url, "reg", "dump")
    return {r["name"]: r["value"] for r in doc["registers"]}


def test_every_rw_register_written_read_back_and_verified(url: str) -> None:
    for seed in range(3):
        values = random_configuration(seed)
        doc = camctl_json(url, "reg", "write", *(f"{k}={v}" for k, v in values.items()))
        assert {r["name"]: r["value"] for r in doc["written"]} == values
        after = dump(url)
        assert {name: after[name] for name in values} == values
    for name in ("WIN_ROWS", "OFFSET"):
        read = camctl_json(url, "reg", "read", name)
        assert set(read) == {"name", "address", "value", "fields"}
        assert (read["name"], read["address"], read["value"]) == (
            name,
            HR400.register(name).address,
            values[name],
        )


def test_read_by_address_and_fields(url: str) -> None:
    camctl_command_json(url, "reg", "write", "GAIN.analog=x4", "GAIN.digital=96")
    read = camctl_command_json(url, "reg", "read", "0x20")
    assert read["name"] == "GAIN"
    assert read["fields"] == {"analog": "x4", "digital": 96}
    assert read["value"] == (2 << 8) | 96


@pytest.mark.parametrize(
    ("assignment", "message"),
    [
        ("WIN_ROWS=4000", "WIN_ROWS.rows: 4000 is out of range (valid: 1 .. 2048"),
        ("GAIN.analog=x16", "GAIN.analog: 'x16' is not valid; use one of x1 (0), x2 (1), x4 (2), x8 (3)"),
        ("CHIP_ID=1", "CHIP_ID"),
        ("NO_SUCH_REG=1", "hr400 has no register named 'NO_SUCH_REG'"),
    ],
)  # fmt: skip
def test_invalid_writes_refused_with_reason_and_nothing_changed(
    url: str, assignment: str, message: str
) -> None:
    before = dump(url)
    # A valid assignment in the same command must not be written either.
    proc = camctl(url, "reg", "write", "OFFSET=1", assignment, "--json")
    assert proc.returncode == 1
    assert proc.stdout == ""
    assert message in proc.stderr
    assert dump(url) == before


def test_read_only_write_names_the_access(url: str) -> None:
    proc = camctl(url, "reg", "write", "CHIP_ID=1")
    assert proc.returncode == 1
    assert "read-only" in proc.stderr and "CHIP_ID" in proc.stderr


def test_save_load_round_trips_bit_exactly(url: str, tmp_path: Path) -> None:
    camctl_json(url, "reg", "write", *(f"{k}={v}" for k, v in random_configuration(7).items()))
    saved = tmp_path / "a.toml"
    doc = camctl_json(url, "reg", "save", str(saved))
    original = dump(url)
    camctl_json(url, "reg", "write", *(f"{k}={v}" for k, v in random_configuration(8).items()))
    assert camctl_json(url, "reg", "diff", str(saved))["differences"]
    camctl_json(url, "reg", "load", str(saved))
    assert dump(url) == original
    assert camctl_json(url, "reg", "diff", str(saved))["differences"] == []
    again = tmp_path / "b.toml"
    camctl_json(url, "reg", "save", str(again))
    assert again.read_bytes() == saved.read_bytes()
    assert doc["sensor"] == "hr400"


def test_load_refuses_another_sensors_file_and_writes_nothing(url: str, tmp_path: Path) -> None:
    before = dump(url)
    path = tmp_path / "other.toml"
    path.write_text('sensor = "ibis5"\n[registers]\nOFFSET = 3\n')
    proc = camctl(url, "reg", "load", str(path))
    assert proc.returncode == 1
    assert "'ibis5'" in proc.stderr and "'hr400'" in proc.stderr
    assert dump(url) == before


def test_diff_against_reset(url: str) -> None:
    reset = {r.name: r.reset for r in HR400.registers if r.configurable}
    camctl_json(
        url,
        "reg",
        "write",
        *(f"{k}={v}" for k, v in reset.items() if HR400.register(k).access == "rw"),
    )
    assert camctl_json(url, "reg", "diff")["differences"] == []
    camctl_json(url, "reg", "write", "OFFSET=321")
    diffs = camctl_json(url, "reg", "diff")["differences"]
    assert diffs == [
        {
            "name": "OFFSET",
            "address": 0x21,
            "expected": HR400.register("OFFSET").reset,
            "actual": 321,
        }
    ]


def test_timing_follows_the_registers(url: str) -> None:
    camctl_json(url, "reg", "write", "WIN_START=757", "WIN_ROWS=534", "EXPOSURE=2", "BACK_PATH=0")
    doc = camctl_json(url, "timing")
    assert doc["line_period_s"] == pytest.approx(20.52e-6, rel=1e-12)
    assert doc["window_start_row"] == 757 and doc["window_rows"] == 534
    assert doc["exposure_lines"] == 2
    assert doc["exposure_s"] == pytest.approx(2 * T_LINE_S, rel=1e-12)
    assert doc["frame_time_s"] == pytest.approx(537 * T_LINE_S, rel=1e-12)  # (n + k + 1) T_line
    assert doc["max_stages"] == 534
    camctl_json(url, "reg", "write", "EXPOSURE=600")  # n >= k: frame period n + 1 lines
    doc = camctl_json(url, "timing")
    assert doc["frame_time_s"] == pytest.approx((600 + 534 + 1) * T_LINE_S, rel=1e-12)
    assert doc["frame_period_s"] == pytest.approx(601 * T_LINE_S, rel=1e-12)


def test_train_reports_every_lane_locked(url: str) -> None:
    # Every lane and the clock enabled (LVDS_CTRL's reset): the random configurations other
    # tests of this module write may have turned lanes off on this worker's daemon, and a lane
    # turned off does not lock (the camera honours the enable bits).
    camctl_json(url, "reg", "write", f"LVDS_CTRL={HR400.register('LVDS_CTRL').reset}")
    doc = camctl_json(url, "train")
    assert doc["trained"] is True and doc["locked"] is True
    assert doc["lanes"] == 8 and doc["locked_lanes"] == 8 and doc["bit_errors"] == 0
    assert [lane["lane"] for lane in doc["lane_results"]] == list(range(8))
    assert all(lane["locked"] and lane["eye_width"] > 0 for lane in doc["lane_results"])


def test_untrained_daemon_refuses_to_stream(tmp_path: Path) -> None:
    with serve(tmp_path, "fpga", train_on_connect=False) as daemon:
        proc = camctl(daemon.url, "stream", "--frames", "3")
        assert proc.returncode == 1
        assert "cannot start a stream: LVDS link not trained yet; run `camctl train`" in proc.stderr
        assert camctl_json(daemon.url, "status")["state"] == "idle"
        assert camctl_json(daemon.url, "train")["trained"] is True
        camctl_json(daemon.url, "reg", "write", "WIN_ROWS=16")
        started = camctl_json(daemon.url, "stream", "--start", "--frames", "0")
        assert started["streaming"] is True and started["frames_requested"] == 0
        assert camctl_json(daemon.url, "status")["state"] == "streaming"
        proc = camctl(daemon.url, "reg", "write", "OFFSET=2")
        assert proc.returncode == 1
        assert "cannot write sensor registers: a stream is running" in proc.stderr
        assert "stop it with `camctl stream --stop`" in proc.stderr
        # The camera's first frame of this window comes once its first-frame work is done
        # (docs/simulator.md): stop after frames came, so that there is something to drain.
        with CamdClient(daemon.url) as client:
            deadline = time.monotonic() + 60
            while client.stream()["stats"]["frames"] < 1 and time.monotonic() < deadline:
                time.sleep(0.05)
        stopped = camctl_json(daemon.url, "stream", "--stop")
        assert stopped["streaming"] is False
        # Stopping drains: every frame the camera made was delivered, none lost.
        assert stopped["frames"] == stopped["frames_sent"] > 0 and stopped["lost"] == 0
        assert camctl_json(daemon.url, "status")["state"] == "idle"


def test_daemon_trains_on_connect(tmp_path: Path) -> None:
    with serve(tmp_path, "fpga") as daemon:
        doc = camctl_json(daemon.url, "status")
        assert doc["state"] == "idle"
        camctl_json(daemon.url, "reg", "write", "WIN_ROWS=16")
        last = json.loads(camctl(daemon.url, "--json", "stream", "--frames", "4").stdout)
        assert (last["frames"], last["lost"], last["rows"]) == (4, 0, 16)


def test_writes_survive_a_lossy_line(tmp_path: Path) -> None:
    with serve(tmp_path, "fpga", inject="drop=0.05,ber=1e-4") as daemon:
        for seed in range(3):
            values = random_configuration(100 + seed)
            camctl_json(daemon.url, "reg", "write", *(f"{k}={v}" for k, v in values.items()))
            after = dump(daemon.url)
            assert {name: after[name] for name in values} == values
        link: Any = camctl_json(daemon.url, "link")
        assert link["host"]["retries"] > 0
