"""The conformance suite (camd.campaign.conformance, docs/conformance.md) on a conforming
simulated camera: every check passes (the destructive one skipped), the report says so with
each check's clause and evidence, the NAK codes seen are the dictionary's, the raw-command
endpoint refuses what it must, and both command lines run it.

The defects that make each check fail are tests/test_conformance_defects.py."""

from __future__ import annotations

import html
import json
import os
import re
import shutil
import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest

from camd.campaign.conformance import check_ids, run_conformance
from camd.campaign.conformance.raw import invalid_payloads
from camd.campaign.conformance.suite import plan
from camd.cli._daemon_proc import DaemonProcess
from camd.cli.camd_main import main as camd_main
from camd.client import CamdClient
from camd.protocol import PayloadError, load_dictionary
from firmware_models.defects import DEFECTS, crc32c
from tests.realtime_support import wait_hog_running

ROOT = Path(__file__).resolve().parent.parent
DICTIONARY = load_dictionary()
NO_TOKEN = {"CAMD_TOKEN": ""}


# -- without a daemon ----------------------------------------------------------------------------


def _headings(doc: str) -> set[str]:
    text = (ROOT / doc).read_text(encoding="utf-8")
    return {m.group(1).strip() for m in re.finditer(r"^#+ (.+)$", text, re.M)}


@pytest.mark.parametrize("step", list(plan(DICTIONARY)), ids=lambda s: s.id)
def test_every_clause_names_a_real_heading_of_the_spec(step: Any) -> None:
    # 'docs/protocol.md §4. Exchanges — at-most-once ...; docs/sensors.md §...'
    for part in step.clause.split("; "):
        doc, _, rest = part.partition(" §")
        heading = rest.split(" — ")[0]
        assert doc in ("docs/protocol.md", "docs/stream.md", "docs/sensors.md"), part
        assert heading in _headings(doc), f"{step.id}: {doc} has no heading {heading!r}"


def test_the_suite_has_a_check_for_every_command_of_the_dictionary() -> None:
    ids = check_ids()
    assert len(ids) == len(set(ids))
    assert {f"cmd.{c.name}" for c in DICTIONARY.commands} <= set(ids)
    assert {"link.at_most_once", "sensor.registers_rw", "sensor.registers_ro",
            "sensor.lvds_training", "stream.headers", "stream.counters", "stream.crc",
            "stream.frame_period", "motion.move", "motion.limits", "wheel.speed",
            "wheel.delay"} <= set(ids)  # fmt: skip


@pytest.mark.parametrize("command", DICTIONARY.commands, ids=lambda c: c.name)
def test_invalid_payloads_are_what_the_dictionary_refuses(command: Any) -> None:
    """Each invalid payload really is invalid for the dictionary's own decoder (the host's
    codec), and the code expected is one the dictionary defines."""
    for _, payload, expected in invalid_payloads(command):
        name = expected.removeprefix("NAK ")
        assert DICTIONARY.error(name).name == name
        if name == "BAD_LENGTH":
            with pytest.raises(PayloadError):
                command.decode_request(payload)
        else:  # OUT_OF_RANGE: decodes (right length) to a value outside its enum or range
            try:
                values = command.decode_request(payload)
            except PayloadError:
                continue  # an enum value the codec does not know
            assert any(
                (f.min is not None and float(values[f.name]) < f.min)
                or (f.max is not None and float(values[f.name]) > f.max)
                for f in command.request
                if f.type not in ("bytes", "str")
            ), values


def test_the_wrong_polynomial_is_crc32c() -> None:
    # CRC-32C check value (RFC 3720), against zlib's CRC-32 0xCBF43926 (docs/stream.md).
    assert crc32c(b"123456789") == 0xE3069283


# -- one conforming simulated camera ---------------------------------------------------------------


@pytest.fixture(scope="module")
def daemon(tmp_path_factory: pytest.TempPathFactory) -> Iterator[DaemonProcess]:
    tmp = tmp_path_factory.mktemp("conform")
    with DaemonProcess(tmp, env=NO_TOKEN) as proc:
        with CamdClient(proc.url) as client:
            client.wait_ready(60)
        yield proc
    assert proc.exit_code in (0, -15), proc.log_path.read_text()


@pytest.fixture(scope="module")
def report(daemon: DaemonProcess, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    out = tmp_path_factory.mktemp("report")
    with CamdClient(daemon.url, timeout_s=60) as client:
        # Not the power-up state: the suite must put back what it found, not the defaults.
        client.write_registers({"WIN_ROWS": 100, "OFFSET": 90})
        client.set_mode("tdi")
        before = client.register_config()
        mode = client.status()["mode"]
        wheel = client.wheel()
        motion = client.motion()["reading"]
        result = run_conformance(client, out)
        # The unit is left as it was found.
        assert client.register_config() == before
        assert client.status()["mode"] == mode
        assert client.wheel()["speed_deg_s"] == pytest.approx(wheel["speed_deg_s"])
        assert client.wheel()["compensation"] == wheel["compensation"]
        after = client.motion()["reading"]
        assert after["position_m"] == motion["position_m"]
        assert (after["state"] == "disabled") == (motion["state"] == "disabled")
        assert client.control()["holder"] is None
    doc = json.loads(result.json_path.read_text())
    assert doc == json.loads(json.dumps(result.doc))
    return {"doc": doc, "html": result.html_path.read_text(), "out": out}


def _check(report: dict[str, Any], check_id: str) -> dict[str, Any]:
    return next(c for c in report["doc"]["checks"] if c["id"] == check_id)


# Commands whose valid case nothing sends on the simulator (it would change a value the unit
# cannot report back): not shown to conform, so not run.
UNSENT = {"cmd.SIM_SET_SEED", "cmd.SIM_SET_INJECT"}


def test_every_check_passes_but_those_not_shown(report: dict[str, Any]) -> None:
    doc = report["doc"]
    outcomes = {c["id"]: c["outcome"] for c in doc["checks"]}
    assert list(outcomes) == check_ids()
    failed = {i: _check(report, i)["reason"] for i, o in outcomes.items() if o == "fail"}
    assert failed == {}
    assert {i for i, o in outcomes.items() if o == "skipped"} == {"motion.home"}
    assert _check(report, "motion.home")["destructive"] is True
    # MOTOR_HOME's valid case is homing: not sent, so the command is not shown to conform.
    assert {i for i, o in outcomes.items() if o == "not_run"} == {"cmd.MOTOR_HOME"} | UNSENT
    for check_id in UNSENT:
        check = _check(report, check_id)
        assert check["reason"] == (
            "valid case not sent: the value in force cannot be read back, so a valid request "
            "would change it"
        )
        # Its invalid cases ran and were refused as they must be.
        sent = [c for c in check["evidence"]["cases"] if c["sent_hex"] is not None]
        assert len(sent) >= 1 and all(c["ok"] for c in sent)
    assert _check(report, "cmd.MOTOR_HOME")["reason"] == (
        "its valid case is exercised by motion.home, which was skipped: destructive: it "
        "changes what the unit cannot get back; run with --destructive"
    )
    # The acquisitions that exercise START_STREAM and WHEEL_ACQUIRE passed: so do they.
    for command, check in (("START_STREAM", "stream.headers"), ("WHEEL_ACQUIRE", "wheel.delay")):
        assert outcomes[f"cmd.{command}"] == "pass"
        assert _check(report, f"cmd.{command}")["depends_on"] == [check]
    assert doc["summary"] == {"pass": len(outcomes) - 4, "fail": 0, "not_run": 3, "skipped": 1,
                              "checks": len(outcomes), "conforms": False,
                              "verdict": "incomplete"}  # fmt: skip
    assert doc["failed"] == [] and set(doc["not_run"]) == {"cmd.MOTOR_HOME"} | UNSENT
    assert doc["unit"]["sensor"] == "hr400" and doc["unit"]["simulated"] is True


def test_the_html_report_names_each_check_with_its_clause_and_outcome(
    report: dict[str, Any],
) -> None:
    page = report["html"]
    assert "camd conformance: NOT SHOWN TO CONFORM" in page
    for check in report["doc"]["checks"]:
        row = page.split(f'<tr id="{check["id"]}">')[1].split("</tr>")[0]
        assert html.escape(check["clause"]) in row
        assert check["outcome"].replace("_", " ").upper() in row


def test_nak_codes_seen_are_those_of_the_dictionary(report: dict[str, Any]) -> None:
    cases = _check(report, "cmd.SET_MODE")["evidence"]["cases"]
    assert [c["answer"] for c in cases] == [
        "ACK",
        f"NAK BAD_LENGTH ({DICTIONARY.error('BAD_LENGTH').code})",
        f"NAK OUT_OF_RANGE ({DICTIONARY.error('OUT_OF_RANGE').code})",
    ]
    assert cases[2]["sent_hex"] == "02"  # mode 2: neither area (0) nor tdi (1)
    reg_write = {
        c["case"]: c["answer"] for c in _check(report, "cmd.REG_WRITE")["evidence"]["cases"]
    }
    assert (
        reg_write["read-only CHIP_ID"]
        == f"NAK REG_READ_ONLY ({DICTIONARY.error('REG_READ_ONLY').code})"
    )
    unknown = _check(report, "link.unknown_opcode")["evidence"]["cases"]
    assert {c["answer"] for c in unknown} == {"NAK UNKNOWN_OPCODE (1)"}


def test_evidence_holds_the_numbers_seen(report: dict[str, Any]) -> None:
    once = _check(report, "link.at_most_once")["evidence"]
    assert once["first_answer_hex"] == once["second_answer_hex"]
    assert once["executed_in_first"] == once["executed_in_second"]
    assert once["replayed_counter_delta"] >= 1
    rw = _check(report, "sensor.registers_rw")["evidence"]
    assert rw["tested"] == 12  # hr400: every RW register (docs/sensors.md §4)
    assert all(r["read_back"] == r["written"] for r in rw["registers"])
    period = _check(report, "stream.frame_period")["evidence"]
    assert abs(period["relative_error"]) < 1e-6
    crc = _check(report, "stream.crc")["evidence"]
    assert crc["mismatched"] == 0 and crc["frames"] == 12
    delay = _check(report, "wheel.delay")["evidence"]
    assert abs(delay["error_deg"]) < delay["tolerance_deg"]
    assert delay["delay_s"] == pytest.approx(delay["device_delay_s"])


@pytest.mark.exclusive  # it hogs every CPU: nothing else should run beside it
def test_timing_checks_pass_under_a_cpu_hog(daemon: DaemonProcess, tmp_path: Path) -> None:
    """The timing checks measure with the unit's clock only (docs/conformance.md, "Timing
    against the device's clock"): beside `stress-ng --cpu 4` (twice the cores here, at normal
    priority like the daemon) they pass, and their inputs are the device's own values."""
    if shutil.which("stress-ng") is None:
        pytest.skip("stress-ng is not installed (apt install stress-ng)")
    hog = subprocess.Popen(
        ["stress-ng", "--cpu", "4", "--timeout", "120s", "--quiet"], start_new_session=True
    )
    try:
        wait_hog_running(hog.pid, 4)  # its own process group: its 4 workers spinning
        with CamdClient(daemon.url, timeout_s=60) as client:
            result = run_conformance(
                client, tmp_path, only=["stream.headers", "stream.frame_period", "wheel.*"]
            )
            log = client.stream_headers()["frames"]  # the last stream: wheel.delay's frame
        load_1min = os.getloadavg()[0]
    finally:
        os.killpg(hog.pid, signal.SIGTERM)
        hog.wait(timeout=30)
    outcomes = {r.id: (r.outcome, r.reason) for r in result.records}
    assert outcomes == {i: ("pass", "") for i in ("stream.headers", "stream.frame_period",
                                                 "wheel.speed", "wheel.delay")}, load_1min  # fmt: skip
    records = {r.id: r.evidence for r in result.records}
    delay = records["wheel.delay"]
    # The angle measured is the one the FPGA latched in the header of the announced frame.
    header = next(h for h in log if h["counter"] == delay["header"]["counter"])
    assert header["counter"] == delay["first_counter"]  # a conforming unit's counter
    assert delay["header"]["stage_position"] == header["stage_position"]
    assert delay["start_angle_deg"] == pytest.approx(header["stage_position"] * 1e-4, abs=1e-12)
    assert abs(delay["error_deg"]) < delay["tolerance_deg"]
    # The period is the headers' timestamps: exact to the nanosecond rounding, whatever the load.
    period = records["stream.frame_period"]
    assert abs(period["relative_error"]) < 1e-6
    assert records["wheel.speed"]["device_times_s"][1] > records["wheel.speed"]["device_times_s"][0]


def test_link_command_refuses_bad_requests(daemon: DaemonProcess) -> None:
    url = f"{daemon.url}/api/v1/link/command"
    cases = [
        ({"command": "PING", "opcode": 1}, "either command"),
        ({"command": "PING", "fields": {"data": "00"}, "payload_hex": "00"}, "either fields"),
        ({"command": "NO_SUCH"}, "NO_SUCH"),
        ({"command": "SET_MODE", "fields": {"mode": "median"}}, "SET_MODE"),
        ({"command": "GET_LANE", "fields": {"lane": 40}}, "0 .. 31"),
        ({"opcode": 300}, "opcode"),
        ({"opcode": 1, "payload_hex": "0g"}, "payload_hex"),
    ]
    for body, said in cases:
        answer = httpx.post(url, json=body, timeout=30)
        assert answer.status_code == 400, (body, answer.text)
        assert said in answer.json()["error"], (body, answer.text)
    # Control: another client holding it refuses the request, as for any change.
    with CamdClient(daemon.url, client="holder") as holder, holder.holding_control(30):
        answer = httpx.post(url, json={"command": "PING"}, headers={"X-Camd-Client": "x"})
        assert answer.status_code == 423, answer.text
        assert "holder" in answer.json()["error"]


def test_camctl_conform_runs_against_the_daemon(daemon: DaemonProcess, tmp_path: Path) -> None:
    run = subprocess.run(
        [sys.executable, "-m", "camd.cli.camctl", "--url", daemon.url, "--json", "conform",
         "--only", "cmd.PING", "--only", "link.*", "--out", str(tmp_path)],
        capture_output=True, text=True, timeout=120, env=None,
    )  # fmt: skip
    assert run.returncode == 0, run.stderr
    doc = json.loads(run.stdout)
    assert doc["conforms"] is True and doc["failed"] == [] and doc["not_run"] == []
    assert doc["verdict"] == "conforms"
    assert doc["summary"] == {"checks": 3, "pass": 3, "fail": 0, "not_run": 0, "skipped": 0}
    assert "PASS link.at_most_once" in run.stderr
    assert (tmp_path / "conformance.html").is_file()


def test_camd_conform_refuses_bad_options_before_doing_anything(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    cases = [
        (["--defect", "stream_crc_polynomial"], "--defect goes with --sim"),
        (["--sim", "--only", "nope.*"], "no such check"),
        (["--sim", "--defect", "nope"], "invalid choice"),
    ]
    for extra, said in cases:
        argv = ["conform", "--out", str(tmp_path / "x"), *extra]
        status: int | str | None
        try:
            status = camd_main(argv)
        except SystemExit as exc:  # argparse's own refusals
            status = exc.code
        assert status == 2, argv
        assert said in capsys.readouterr().err
        assert not (tmp_path / "x").exists()


def test_every_defect_is_documented() -> None:
    text = (ROOT / "docs" / "conformance.md").read_text(encoding="utf-8")
    for name in DEFECTS:
        assert f"`{name}`" in text, name
