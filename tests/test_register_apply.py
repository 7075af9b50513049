"""A register burst that fails part-way puts back every register it changed, and says so.

Over the full stack (HTTP -> camd serve -> simulated camera with an mt9m001, whose GLOBAL_GAIN
register sets the four colour gains at once), the simulated camera fails one coming REG_READ or
REG_WRITE_BURST on purpose (POST /api/v1/sim/fail-next; ``tests/test_apply_faults.py``
explains the injection). A write reads the register file first (one REG_READ per readable
register: the snapshot it is planned against and restored to), reads the registers whose fields
it sets, sends one burst, then reads back each register written: failing a read-back is a
failure after the burst went through. The camera's state, read back from the device itself
(``tests.device_snapshot``), must be the same after the error as before.

The planner's refusals (``camd.daemon.register_plan``) are tested without a daemon in
tests/test_register_plan.py.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import pytest

from camd.cli._daemon_proc import DaemonProcess
from camd.client import CamdClient
from camd.sensor.regmap import load_register_map
from tests.device_snapshot import snapshot
from tests.test_apply_faults import failing, refused
from tests.test_camctl import NO_TOKEN

MT9M001 = load_register_map("mt9m001")
READABLE = sum(reg.readable for reg in MT9M001.registers)  # REG_READs of a write's snapshot
GAINS = ["GAIN_GREEN1", "GAIN_BLUE", "GAIN_RED", "GAIN_GREEN2"]  # what GLOBAL_GAIN sets
SILENCE_S = 4.5  # as tests/test_apply_faults.py: outlasts the host's attempts, ends in the wait


@pytest.fixture(scope="module")
def client(tmp_path_factory: pytest.TempPathFactory) -> Iterator[CamdClient]:
    tmp = tmp_path_factory.mktemp("camd-register-apply")
    config = tmp / "camd.toml"
    config.write_text(
        '[sim]\nprofile = "mt9m001"\n[sensor]\nname = "mt9m001"\nbridge = "fpga"\n',
        encoding="utf-8",
    )
    daemon = DaemonProcess(tmp, extra_args=["--config", str(config)], env=NO_TOKEN)
    with daemon, CamdClient(daemon.url, timeout_s=120) as client:
        client.wait_ready(60)
        yield client
    assert daemon.exit_code in (0, -15), daemon.log_path.read_text()


def values(client: CamdClient, names: list[str]) -> dict[str, int]:
    registers = {r["name"]: r["value"] for r in client.registers()["registers"]}
    return {name: registers[name] for name in names}


def test_global_gain_sets_the_four_colour_gains(client: CamdClient) -> None:
    """What the next test relies on: a GLOBAL_GAIN write changes four other registers."""
    before = values(client, GAINS)
    client.write_registers({"GLOBAL_GAIN": 0x20})
    assert values(client, GAINS) == dict.fromkeys(GAINS, 0x20)
    client.write_registers(dict(before))
    assert values(client, GAINS) == before


def test_a_global_gain_write_that_fails_at_a_read_back_puts_the_colour_gains_back(
    client: CamdClient,
) -> None:
    before = snapshot(client)
    assert {before["registers"][name] for name in GAINS} != {0x20}
    # Read back: TEST_DATA, then (GLOBAL_GAIN reads back nothing: volatile) the four gains it
    # set; the second read-back is refused.
    with failing(client, "REG_READ", skip=READABLE + 1, error="BUSY"):
        error = refused(lambda: client.write_registers({"TEST_DATA": 7, "GLOBAL_GAIN": 0x20}))
    assert (error.http_status, error.code) == (502, "device_nak"), error.message
    assert error.message.startswith("REG_READ refused by the device: BUSY (5)")
    assert error.message.endswith(
        "; restored: registers TEST_DATA, GAIN_GREEN1, GAIN_BLUE, GAIN_RED, GAIN_GREEN2"
    ), error.message
    assert snapshot(client) == before


def test_a_write_of_several_fields_that_fails_part_way_is_put_back(client: CamdClient) -> None:
    before = snapshot(client)
    writes: dict[str, int | str] = {
        "READ_OPTIONS2.mirror_rows": 1,
        "CAL_THRESHOLD.high": 50,
        "OFFSET_G1": 5,
    }
    # The snapshot, then the two registers whose fields are set (read to keep their other
    # fields), then the read-backs: the third is refused.
    with failing(client, "REG_READ", skip=READABLE + 2 + 2, error="BUSY"):
        error = refused(lambda: client.write_registers(dict(writes)))
    assert (error.http_status, error.code) == (502, "device_nak"), error.message
    assert error.message.endswith(
        "; restored: registers READ_OPTIONS2, CAL_THRESHOLD, OFFSET_G1"
    ), error.message
    assert snapshot(client) == before


def changed_configuration(client: CamdClient) -> Any:
    """The configuration now, with three registers changed."""
    config = client.register_config()
    registers = dict(config["registers"])
    registers.update(GAIN_RED=registers["GAIN_RED"] + 3, TEST_DATA=9, OFFSET_G2=3)
    return {**config, "registers": registers}


def test_a_configuration_load_that_fails_at_a_read_back_is_put_back(client: CamdClient) -> None:
    before = snapshot(client)
    config = changed_configuration(client)
    with failing(client, "REG_READ", skip=READABLE + 4, error="BUSY"):
        error = refused(lambda: client.load_register_config(config))
    assert (error.http_status, error.code) == (502, "device_nak"), error.message
    assert error.message.endswith("; restored: registers GAIN_RED, TEST_DATA, OFFSET_G2"), (
        error.message
    )
    assert snapshot(client) == before
    events = [e["message"] for e in client.events(limit=5)["events"]]
    assert any(m.startswith("configuration load failed: REG_READ refused") for m in events)


def test_a_configuration_load_whose_burst_is_lost_is_put_back(client: CamdClient) -> None:
    before = snapshot(client)
    config = changed_configuration(client)
    with failing(client, "REG_WRITE_BURST", duration_s=SILENCE_S):
        error = refused(lambda: client.load_register_config(config))
    assert (error.http_status, error.code) == (504, "timeout"), error.message
    assert error.message.startswith("REG_WRITE_BURST: no answer from the device on ")
    # The camera may have taken the burst and lost only its answer: written back all the same.
    assert error.message.endswith("; restored: registers GAIN_RED, TEST_DATA, OFFSET_G2"), (
        error.message
    )
    assert snapshot(client) == before


def test_a_refused_configuration_changes_nothing(client: CamdClient) -> None:
    before = snapshot(client)
    config = changed_configuration(client)
    config["registers"]["OFFSET_G1"] = 1 << 16  # wider than the register
    error = refused(lambda: client.load_register_config(config))
    assert (error.http_status, error.code) == (400, "bad_request")
    assert error.message.startswith("the configuration: OFFSET_G1")
    assert error.message.endswith("; nothing was written")
    assert snapshot(client) == before
