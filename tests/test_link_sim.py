"""CommandLink against the simulated FPGA over a real pty, through an injected-fault line.

The acceptance run of the walking skeleton: 10,000 commands over a line with bit errors and
dropped frames; every command acknowledged or failed with a reason, none executed twice.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from camd.link import CommandLink, LinkError
from camd.protocol.dictionary import FieldValue

N_COMMANDS = 10_000


def start_sim(tmp_path: Path, inject: str, *extra: str) -> tuple[subprocess.Popen[str], str]:
    link = tmp_path / "camera.tty"
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "firmware_models",
            "--json",
            "--link",
            str(link),
            "--inject",
            inject,
            "--seed",
            "7",
            *extra,
        ],
        stdout=subprocess.PIPE,
        text=True,
    )
    assert proc.stdout is not None
    info = json.loads(proc.stdout.readline())
    assert Path(info["link"]) == link and os.path.realpath(link) == info["tty"]
    return proc, str(link)


@pytest.fixture
def lossy_sim(tmp_path: Path) -> Iterator[str]:
    proc, link = start_sim(tmp_path, "ber=1e-4,drop=0.01", "--hk-period-s", "0.5")
    yield link
    proc.send_signal(signal.SIGTERM)
    assert proc.wait(timeout=10) == 0


def stats(link: CommandLink) -> dict[str, FieldValue]:
    return link.request("GET_LINK_STATS").values


@pytest.mark.timeout(300)
def test_ten_thousand_commands_over_a_lossy_line(lossy_sim: str) -> None:
    # A short per-attempt timeout keeps the run quick on a pty (each lost frame costs one);
    # retries enough for 2 s per command, so a busy machine's late answer is a replay, not a
    # failure: the outcome does not depend on the 20 ms.
    link = CommandLink(lossy_sim, timeout_s=0.02, retries=100)
    link.open()
    try:
        assert link.wait_connected(5), link.last_error
        before = stats(link)
        acked = 0
        failures: list[str] = []
        modes = ("area", "tdi")
        for i in range(N_COMMANDS):
            try:
                if i % 10 == 3:
                    # A state-changing command: executing a retry twice would be visible here.
                    r = link.request("SET_MODE", mode=modes[i % 2])
                    assert r.values["mode"] == modes[i % 2]
                else:
                    tag = i.to_bytes(4, "big") * 4
                    assert link.request("PING", data=tag).values["data"] == tag
                acked += 1
            except LinkError as exc:
                assert str(exc), "a failure must carry a reason"
                failures.append(f"#{i}: {exc}")
        after = stats(link)
        injected = link.request("SIM_GET_INJECTED").values
        host = link.counters()
    finally:
        link.close()

    summary = {
        "commands": N_COMMANDS,
        "acked": acked,
        "failed": len(failures),
        "host": host,
        "device_executed": int(after["executed"]) - int(before["executed"]),
        "device_replayed": int(after["replayed"]) - int(before["replayed"]),
        "injected": injected,
    }
    print(json.dumps(summary))  # the numbers for the closing note (pytest -s)

    assert failures == [], failures[:5]
    assert acked == N_COMMANDS
    # At most once: the device executed each acknowledged command exactly once (the second
    # GET_LINK_STATS is counted by the device before it answers).
    assert summary["device_executed"] == N_COMMANDS + 1
    # The line really was lossy and the record really was used.
    assert int(injected["bit_errors"]) > 0 and int(injected["dropped_tx"]) > 0
    assert host["retries"] > 0 and summary["device_replayed"] > 0
    # A retry is replayed only when the device had the command already; never more often.
    assert summary["device_replayed"] <= host["retries"]
