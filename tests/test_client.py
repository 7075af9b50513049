"""CamdClient against a live daemon (``camd serve --sim`` on loopback), and DaemonProcess itself.

No mocks: a real daemon subprocess, real HTTP, the simulated camera behind a real pty.
"""

from __future__ import annotations

import socket
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest

from camd.cli._daemon_proc import DaemonProcess, DaemonStartError
from camd.client import CamdClient, CamdError, DaemonUnreachable, normalise_url
from camd.client.connection import transport_error

NO_TOKEN = {"CAMD_TOKEN": ""}


def free_port() -> int:
    """A loopback port nothing listens on (bound, then released)."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


@pytest.fixture(scope="module")
def daemon(tmp_path_factory: pytest.TempPathFactory) -> Iterator[DaemonProcess]:
    # The daemon takes $CAMD_TOKEN as its api.token: clear it so that no token is required.
    with DaemonProcess(tmp_path_factory.mktemp("camd-client"), env=NO_TOKEN) as proc:
        yield proc
    assert proc.exit_code in (0, -15), proc.log_path.read_text()


@pytest.fixture
def client(daemon: DaemonProcess, monkeypatch: pytest.MonkeyPatch) -> Iterator[CamdClient]:
    monkeypatch.delenv("CAMD_TOKEN", raising=False)
    with CamdClient(daemon.url, timeout_s=30) as cam:
        cam.wait_ready(15)
        yield cam


def test_status_is_idle_and_names_the_daemon(client: CamdClient, daemon: DaemonProcess) -> None:
    doc = client.status()
    assert doc["state"] == "idle"
    assert doc["mode"] in ("area", "tdi")
    assert doc["link"]["connected"] is True
    assert doc["device"] is not None and isinstance(doc["device"]["fw_version"], int)
    assert doc["daemon"]["pid"] == daemon.pid


def test_ping_link_telemetry_events_metrics(client: CamdClient) -> None:
    before = client.link()
    result = client.ping(count=20, size=32)
    assert (result["count"], result["ok"], result["failed"]) == (20, 20, 0)
    rtt = result["rtt_ms"]
    assert rtt["p50"] is not None and rtt["p99"] is not None and rtt["max"] is not None
    assert 0 < rtt["p50"] <= rtt["p99"] <= rtt["max"]
    after = client.link()
    assert after["host"]["acked"] >= before["host"]["acked"] + 20
    assert after["device"] is not None and before["device"] is not None
    assert after["device"]["executed"] >= before["device"]["executed"] + 20

    tel = client.telemetry()
    assert tel["latest"] and tel["archive"]
    channel = next(iter(tel["latest"]))
    (hist,) = client.history(channel, limit=5)["channels"]
    assert hist["channel"] == channel
    assert len(hist["t_s"]) == len(hist["value"]) == len(hist["source"]) <= 5

    events = client.events(limit=3)
    assert isinstance(events["events"], list) and len(events["events"]) <= 3

    assert client.metrics().strip()


def test_mode_and_reset(client: CamdClient) -> None:
    assert client.set_mode("tdi") == {"mode": "tdi"}
    assert client.status()["mode"] == "tdi"
    doc = client.reset()
    assert doc["state"] == "idle"
    # RESET puts the device back in area mode (protocol.toml).
    assert client.status()["mode"] == "area"


def test_api_errors_carry_code_and_http_status(client: CamdClient) -> None:
    with pytest.raises(CamdError) as info:
        client.ping(count=0)
    assert info.value.code == "bad_request" and info.value.http_status == 400
    assert "count" in info.value.message

    with pytest.raises(CamdError) as info:
        client.set_mode("foo")
    assert info.value.code == "bad_request" and info.value.http_status == 400
    assert "area" in info.value.message and "tdi" in info.value.message
    assert not isinstance(info.value, DaemonUnreachable)

    with pytest.raises(CamdError) as info:
        client.history("no_such_channel")
    assert info.value.http_status in (400, 404)
    assert "no_such_channel" in info.value.message


def test_url_from_environment(daemon: DaemonProcess, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("CAMD_URL", daemon.url)
    with CamdClient() as cam:
        assert cam.url == daemon.url
        assert cam.status()["state"] == "idle"


def test_unreachable_daemon_says_how_to_start_one() -> None:
    url = f"http://127.0.0.1:{free_port()}"
    with CamdClient(url, timeout_s=5) as cam:
        with pytest.raises(DaemonUnreachable) as info:
            cam.status()
        assert info.value.code == "unreachable" and info.value.http_status is None
        assert url in info.value.message and "camd serve --sim" in info.value.message
        assert isinstance(info.value, CamdError)
        with pytest.raises(DaemonUnreachable):
            cam.wait_ready(0.3)


def test_normalise_url() -> None:
    assert normalise_url("localhost:8422") == "http://localhost:8422"
    assert normalise_url("http://127.0.0.1:8422/") == "http://127.0.0.1:8422"
    with pytest.raises(ValueError, match="bad daemon URL"):
        normalise_url("ftp://127.0.0.1:8422")
    with pytest.raises(ValueError, match="timeout_s"):
        CamdClient("http://127.0.0.1:1", timeout_s=0)


def test_daemon_process_reports_a_failed_start(tmp_path: Path) -> None:
    proc = DaemonProcess(
        tmp_path, extra_args=["--no-such-option"], env=NO_TOKEN, start_timeout_s=30
    )
    with pytest.raises(DaemonStartError) as info:
        proc.start()
    message = str(info.value)
    assert "exited with status 2" in message
    assert "--no-such-option" in message  # argparse's complaint, from the stderr tail
    assert str(proc.log_path) in message
    assert proc.exit_code == 2 and not proc.running


def test_daemon_process_logs_and_stops(tmp_path: Path) -> None:
    with DaemonProcess(tmp_path, env=NO_TOKEN) as proc:
        assert proc.url.startswith("http://127.0.0.1:")
        assert proc.running
    assert not proc.running and not proc.killed
    assert proc.exit_code in (0, -15)
    log = proc.log_path.read_text()
    assert "camd serving http://" in log and "exited with status" in log


def test_token_from_argument_or_environment(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.delenv("CAMD_TOKEN", raising=False)
    with DaemonProcess(tmp_path, env={"CAMD_TOKEN": "s3cret"}) as daemon:
        with CamdClient(daemon.url) as cam:
            with pytest.raises(CamdError) as info:
                cam.status()
            assert info.value.code == "unauthorized" and info.value.http_status == 401
        with CamdClient(daemon.url, token="wrong") as cam, pytest.raises(CamdError):
            cam.status()
        with CamdClient(daemon.url, token="s3cret") as cam:
            assert cam.wait_ready(15)["state"] == "idle"
        monkeypatch.setenv("CAMD_TOKEN", "s3cret")
        with CamdClient(daemon.url) as cam:
            assert cam.status()["state"] == "idle"


# The client's TypedDicts (camd/client_types.py) are generated from the daemon's pydantic models;
# tests/test_client_types.py pins them to the models and to a live daemon's answers.


def test_timing_response_carries_every_sensor_timing_field() -> None:
    # GET /api/v1/timing is SensorTiming.as_dict(); the model must not drop or invent a field.
    from camd.daemon.models import TimingResponse
    from camd.sensor.timing_view import SensorTiming

    assert set(SensorTiming.model_fields) == set(TimingResponse.model_fields)


def test_timing_response_is_sensor_timing_under_the_api_name() -> None:
    # One source for the shape: the API's model is the sensor's timing, and declares no field
    # of its own (it used to copy SensorTiming field for field).
    import inspect

    from camd.daemon.models import TimingResponse
    from camd.sensor.timing_view import SensorTiming

    assert issubclass(TimingResponse, SensorTiming)
    assert not inspect.get_annotations(TimingResponse)


def test_a_wait_bounded_by_an_httpx_timeout_says_its_read_limit() -> None:
    """An acquisition's request is bounded by an httpx.Timeout (connect short, read as long as
    the acquisition may take): its timeout names the read limit (it raised TypeError formatting
    the Timeout before)."""
    timeout = httpx.Timeout(30.0, read=70.0)
    error = transport_error(
        "POST", "/api/v1/stream/acquire", "http://h", httpx.ReadTimeout("x"), timeout
    )
    assert error.code == "timeout"
    assert error.message.startswith(
        "POST /api/v1/stream/acquire: the daemon at http://h did not answer within 70 s; "
    )
