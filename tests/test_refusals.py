"""Every refusal changes nothing, and its message names the fix: one table, one test.

Each row is a request that must be refused (over HTTP, or through camctl where the refusal is
camctl's own), the error code it must get (the API's ``code``, or camctl's exit status) and a
fragment of the message that tells what to do instead (the valid range, the command to run).
The camera's state is read back from the device itself (``tests.device_snapshot``: mode from
GET_STATUS, the register file, the stage, the wheel, the simulator's settings) before and
after the refused request; the two must be equal. Some rows need the camera in a given state
first (a stream running, the stage released or emergency-stopped, the wheel stopped, a long
exposure): the row's ``during`` sets it up before the first snapshot and undoes it after the
second.
"""

from __future__ import annotations

import contextlib
import json
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import httpx
import pytest

from camd.client import CamdClient
from camd.paths import config_dir
from tests.device_snapshot import snapshot
from tests.test_camctl import camctl
from tests.test_trust import small_window_daemon

# Not ``exclusive``: every row checks a refusal (its code, its words, the device unchanged);
# the streams and scans some rows start only have to be running. Checked beside
# `stress-ng --cpu 2`.

API = "/api/v1"
CLIENT = "refusals"  # every request comes from one client, which holds what it starts


@dataclass(frozen=True)
class Context:
    """What a row's request runs against."""

    url: str
    client: CamdClient
    tmp: Path


@dataclass(frozen=True)
class Refusal:
    code: str  # the API's error code, or "exit N" for camctl
    message: str


Request = Callable[[Context], Refusal]


def http(method: str, path: str, body: dict[str, Any] | None = None) -> Request:
    """A request to the API; it must fail. ``{tmp}`` in the body is the test's directory."""

    def send(ctx: Context) -> Refusal:
        sent = None if body is None else json.loads(json.dumps(body).replace("{tmp}", str(ctx.tmp)))
        with httpx.Client(base_url=ctx.url, timeout=120, headers={"X-Camd-Client": CLIENT}) as h:
            response = h.request(method, f"{API}{path}", json=sent)
        assert response.status_code >= 400, response.text
        doc = response.json()
        return Refusal(doc["code"], doc["error"])

    return send


def cli(*args: str) -> Request:
    """A camctl command; it must fail. ``{tmp}`` in an argument is the test's directory."""

    def run(ctx: Context) -> Refusal:
        argv = [a.replace("{tmp}", str(ctx.tmp)) for a in args]
        proc = camctl(ctx.url, "--client", CLIENT, *argv)
        assert proc.returncode != 0, proc.stdout
        assert "Traceback" not in proc.stderr, proc.stderr
        return Refusal(f"exit {proc.returncode}", " ".join(proc.stderr.split()))

    return run


def scan(**body: Any) -> Request:
    """POST /scan/start (M = 4, 5 lines), a new file in the test's directory unless ``out``."""
    return http("POST", "/scan/start", {"stages": 4, "lines": 5, "out": "{tmp}/scan.h5", **body})


def bad_campaign(ctx: Context) -> Refusal:
    """A copy of a shipped campaign whose frame count cannot be a frame count."""
    text = (config_dir() / "campaigns" / "example_stare.yaml").read_text(encoding="utf-8")
    assert "  frames: 6\n" in text
    path = ctx.tmp / "bad.yaml"
    path.write_text(text.replace("  frames: 6\n", "  frames: -6\n"), encoding="utf-8")
    return cli("campaign", "run", str(path), "--out", "{tmp}/campaign")(ctx)


# -- what some rows need first ------------------------------------------------------------------


@contextlib.contextmanager
def streaming(client: CamdClient, tmp: Path) -> Iterator[None]:
    client.start_stream(0)
    try:
        yield
    finally:
        client.stop_stream()


@contextlib.contextmanager
def scanning(client: CamdClient, tmp: Path) -> Iterator[None]:
    client.start_scan(4, 0, out=str(tmp / "running.h5"), drive_stage=False)
    try:
        yield
    finally:
        client.stop_scan()
        client.set_mode("area")


@contextlib.contextmanager
def stage_released(client: CamdClient, tmp: Path) -> Iterator[None]:
    client.enable_stage(False)
    try:
        yield
    finally:
        client.enable_stage(True)


@contextlib.contextmanager
def stage_in_estop(client: CamdClient, tmp: Path) -> Iterator[None]:
    client.estop_stage()
    try:
        yield
    finally:
        client.enable_stage(True)  # clears the emergency stop


@contextlib.contextmanager
def wheel_stopped(client: CamdClient, tmp: Path) -> Iterator[None]:
    nominal = client.wheel()["nominal_speed_deg_s"]
    client.set_wheel_speed(0.0)
    try:
        yield
    finally:
        client.set_wheel_speed(nominal)


@contextlib.contextmanager
def long_exposure(client: CamdClient, tmp: Path) -> Iterator[None]:
    # 7000 lines of 20.52 us: a 144 ms frame, longer than a channel's 120 ms light window.
    client.write_registers({"EXPOSURE": 7000})
    try:
        yield
    finally:
        client.write_registers({"EXPOSURE": 4})


During = Callable[[CamdClient, Path], contextlib.AbstractContextManager[None]]


@contextlib.contextmanager
def as_is(client: CamdClient, tmp: Path) -> Iterator[None]:
    yield


@dataclass(frozen=True)
class Row:
    request: Request
    code: str
    fragment: str  # of the message: what to do instead
    during: During = as_is


BUSY_STREAM = "a stream is running"
STOP_STREAM = "stop it with `camctl stream --stop`"

ROWS = [
    # -- scan -------------------------------------------------------------------------------------
    pytest.param(
        Row(scan(line_period_s=3e-3, out="{tmp}/nodir/x.h5"), "bad_request",
            "does not exist; create it first (mkdir -p"),
        id="scan-into-a-missing-directory",
    ),
    pytest.param(
        Row(scan(lines=10_000_000, line_period_s=3e-3), "bad_request",
            "scan fewer lines, or slower (a longer line period), or widen stage.low_limit_m"),
        id="scan-beyond-the-travel",
    ),
    pytest.param(
        Row(scan(stages=40, line_period_s=2e-4), "bad_request",
            "choose 1..9 stages, or slow the stage"),
        id="scan-more-stages-than-window-rows",
    ),
    pytest.param(
        Row(scan(line_period_s=2e-3, speed_m_s=0.01), "bad_request",
            "give either speed_m_s or line_period_s, not both"),
        id="scan-speed-and-line-period",
    ),
    pytest.param(
        Row(scan(line_period_s=1e-6), "bad_request", "slow the scan (longer line period)"),
        id="scan-line-period-below-a-row",
    ),
    pytest.param(
        Row(scan(line_period_s=3e-3), "bad_request", "then `camctl stage enable` clears it",
            stage_in_estop),
        id="scan-with-the-stage-in-emergency-stop",
    ),
    pytest.param(
        Row(scan(drive_stage=False), "busy", STOP_STREAM, streaming),
        id="scan-during-a-stream",
    ),
    # -- stare ------------------------------------------------------------------------------------
    pytest.param(
        Row(http("POST", "/stream/acquire", {"frames": 0}), "bad_request", "use start for 0"),
        id="stare-of-no-frames",
    ),
    pytest.param(
        Row(http("POST", "/stream/acquire", {"frames": 2, "record": "/etc/camd-never.h5"}),
            "bad_request", "is outside the directories the daemon may write"),
        id="stare-recorded-outside-the-allowed-directories",
    ),
    pytest.param(
        Row(cli("stare", "--frames", "2", "--out", "{tmp}/nodir/s.h5"), "exit 1",
            "does not exist; create it first (mkdir -p"),
        id="stare-recorded-into-a-missing-directory",
    ),
    pytest.param(
        Row(http("POST", "/stream/acquire", {"frames": 2, "mode": "tdi", "stages": 17}),
            "bad_request", "choose 1..16 or make the window taller"),
        id="stare-tdi-more-stages-than-rows",
    ),
    pytest.param(
        Row(http("POST", "/stream/acquire", {"frames": 2}), "busy", STOP_STREAM, streaming),
        id="stare-during-a-stream",
    ),
    # -- stream -----------------------------------------------------------------------------------
    pytest.param(
        Row(http("POST", "/stream/start", {"frames": 2, "record": "{tmp}/nodir/r.h5"}),
            "bad_request", "does not exist; create it first"),
        id="stream-recorded-into-a-missing-directory",
    ),
    pytest.param(
        Row(http("POST", "/stream/start", {"frames": 0}), "busy", STOP_STREAM, streaming),
        id="stream-during-a-stream",
    ),
    # -- mode -------------------------------------------------------------------------------------
    pytest.param(
        Row(http("POST", "/mode", {"mode": "foo"}), "bad_request", "use area or tdi"),
        id="mode-unknown",
    ),
    pytest.param(
        Row(http("POST", "/mode", {"mode": "tdi"}), "busy", STOP_STREAM, streaming),
        id="mode-during-a-stream",
    ),
    # -- register writes --------------------------------------------------------------------------
    pytest.param(
        Row(cli("reg", "write", "GAIN=70", "WIN_ROWS=4000"), "exit 1",
            "WIN_ROWS.rows: 4000 is out of range (valid: 1 .. 2048"),
        id="register-out-of-range",
    ),
    pytest.param(
        Row(http("POST", "/registers", {"values": {"GAIN": 70, "CHIP_ID": 1}}), "bad_request",
            "CHIP_ID (0x00) is read-only; it cannot be written"),
        id="register-read-only",
    ),
    pytest.param(
        Row(http("POST", "/registers", {"values": {"NO_SUCH": 1}}), "bad_request",
            "`camctl reg dump` lists them"),
        id="register-unknown",
    ),
    pytest.param(
        Row(http("POST", "/registers", {"values": {"WIN_START": 2000, "WIN_ROWS": 100}}),
            "bad_request", "lower WIN_START or WIN_ROWS (the window must fit rows 0 .. 2047)"),
        id="register-window-beyond-the-array",
    ),
    pytest.param(
        Row(http("PUT", "/registers/config", {"sensor": "ibis5", "registers": {"GAIN": 1}}),
            "bad_request", "load a configuration saved from a hr400 (`camctl reg save FILE`)"),
        id="register-configuration-of-another-sensor",
    ),
    pytest.param(
        Row(http("POST", "/registers", {"values": {"GAIN": 70}}), "busy", STOP_STREAM,
            streaming),
        id="register-write-during-a-stream",
    ),
    # -- the stage --------------------------------------------------------------------------------
    pytest.param(
        Row(http("POST", "/motion/move", {"position_m": 5.0}), "bad_request",
            "move within them or widen stage.low_limit_m / high_limit_m"),
        id="stage-move-beyond-the-limits",
    ),
    pytest.param(
        Row(http("POST", "/motion/move", {"position_m": 0.2, "speed_m_s": 5.0}), "bad_request",
            "is above the limit 100 mm/s (stage.max_speed_m_s, linear_rail profile); go slower"),
        id="stage-move-too-fast",
    ),
    pytest.param(
        Row(http("POST", "/motion/run", {"speed_m_s": -5.0}), "bad_request", "go slower"),
        id="stage-run-too-fast",
    ),
    pytest.param(
        Row(http("POST", "/motion/move", {"position_m": 0.2}), "bad_request",
            "the stage motor is released; `camctl stage enable` first", stage_released),
        id="stage-move-while-released",
    ),
    pytest.param(
        Row(http("POST", "/motion/run", {"speed_m_s": 0.01}), "bad_request",
            "the stage is in emergency stop; check it, then `camctl stage enable` clears it",
            stage_in_estop),
        id="stage-run-in-emergency-stop",
    ),
    pytest.param(
        Row(http("POST", "/motion/home", {}), "bad_request", "`camctl stage enable` clears it",
            stage_in_estop),
        id="stage-home-in-emergency-stop",
    ),
    pytest.param(
        Row(http("POST", "/motion/move", {"position_m": 0.2}), "busy", STOP_STREAM, streaming),
        id="stage-move-during-a-stream",
    ),
    # -- the filter wheel -------------------------------------------------------------------------
    pytest.param(
        Row(http("PUT", "/wheel/speed", {"speed_deg_s": 400}), "bad_request",
            "use a number in 0..360 (a wheel speed in deg/s"),
        id="wheel-speed-out-of-range",
    ),
    pytest.param(
        Row(http("PUT", "/wheel/compensation", {"on": True}), "bad_request",
            "delay compensation not switched on (exposure 7000 lines", long_exposure),
        id="wheel-compensation-that-cannot-fit",
    ),
    pytest.param(
        Row(http("POST", "/wheel/acquire", {"channels": [13]}), "bad_request",
            "choose channels from 0 to 12"),
        id="wheel-acquire-an-unknown-channel",
    ),
    pytest.param(
        Row(http("POST", "/wheel/acquire", {"channels": [1]}), "bad_request",
            "start it first (`camctl wheel speed 73.245`)", wheel_stopped),
        id="wheel-acquire-with-the-wheel-stopped",
    ),
    pytest.param(
        Row(http("PUT", "/wheel/speed", {"speed_deg_s": 10}), "busy", STOP_STREAM, streaming),
        id="wheel-speed-during-a-stream",
    ),
    # -- reset ------------------------------------------------------------------------------------
    pytest.param(
        Row(http("POST", "/reset"), "busy",
            f"cannot reset the camera: {BUSY_STREAM}", streaming),
        id="reset-during-a-stream",
    ),
    pytest.param(
        Row(cli("reset"), "exit 1", "stop it with `camctl scan --stop`", scanning),
        id="reset-during-a-scan",
    ),
    # -- campaigns (camctl runs them through the API; refused before the daemon is asked) ---------
    pytest.param(
        Row(cli("campaign", "run", "no_such_campaign", "--out", "{tmp}/campaign"), "exit 2",
            "one of the shipped campaigns (`camctl campaign list`): "),
        id="campaign-unknown",
    ),
    pytest.param(
        Row(bad_campaign, "exit 2",
            "nothing was done: correct the campaign's parameters (or their quick overrides)"),
        id="campaign-with-a-bad-parameter",
    ),
    # -- the simulator's failures on purpose ------------------------------------------------------
    pytest.param(
        Row(http("POST", "/sim/fail-next", {"command": "NOPE", "error": "BUSY"}),
            "bad_request", "is not a command of config/protocol.toml; use one of PING"),
        id="fail-next-of-an-unknown-command",
    ),
    pytest.param(
        Row(http("POST", "/sim/fail-next", {"command": "PING", "error": "BUSY",
                                            "duration_s": 1.0}),
            "bad_request", "not several or none"),
        id="fail-next-nak-and-silence",
    ),
]  # fmt: skip


@pytest.fixture(scope="module")
def daemon(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[str, CamdClient]]:
    tmp = tmp_path_factory.mktemp("camd-refusals")
    with small_window_daemon(tmp) as url, CamdClient(url, client=CLIENT) as client:
        client.set_mode("area")
        client.enable_stage(True)
        client.move_stage(0.3)  # mid-travel: a refused move would show
        yield url, client


@pytest.mark.parametrize("row", ROWS)
def test_a_refused_request_changes_nothing(
    daemon: tuple[str, CamdClient], tmp_path: Path, row: Row
) -> None:
    url, client = daemon
    with row.during(client, tmp_path):
        before = snapshot(client)
        refusal = row.request(Context(url, client, tmp_path))
        after = snapshot(client)
    assert refusal.code == row.code, refusal.message
    assert row.fragment in refusal.message, refusal.message
    assert after == before
