"""``camd demo`` end to end, as a subprocess: exit 0, the final line, and the summary file."""

from __future__ import annotations

import json
import os
import queue
import re
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import IO

import httpx
import numpy as np
import pytest

import camd
from camd.cli.demo import live_page_url
from tests.campaign_support import report_images

# The demo's runs stream full frames in real time (200 of 534 x 2048 pixels, more than the
# daemon's queue holds, with no overrun asked): ``exclusive``, alone under xdist
# (tests/cpu_share.py), until its streams and scans are done. Its campaigns (step 10) run on
# their own simulated cameras, as tests/test_campaign_tdi.py and test_campaign_mtf.py run the
# same campaigns beside other tests, so other tests may run beside them (``end_exclusive``):
# the exclusive part of the whole demo was 35-37 s, 12-14 s of it before step 10.
# The address test runs nothing.
CAMPAIGN_STEP = "10. test campaigns (short runs)"

REPO_ROOT = str(Path(camd.__file__).resolve().parent.parent)


def demo_env() -> dict[str, str]:
    # The demo's daemon and client would both take $CAMD_TOKEN; run it as a user without one,
    # and without the suite's $CAMD_RECORD_DIRS: its daemons write only where the demo allows.
    env = {
        k: v
        for k, v in os.environ.items()
        if k not in ("CAMD_URL", "CAMD_TOKEN", "CAMD_RECORD_DIRS")
    }
    env["PYTHONPATH"] = os.pathsep.join(p for p in (REPO_ROOT, env.get("PYTHONPATH")) if p)
    env["PYTHONUNBUFFERED"] = "1"
    return env


@pytest.mark.exclusive
def test_demo_runs_and_writes_its_summary(
    tmp_path: Path, end_exclusive: Callable[[], None]
) -> None:
    out = tmp_path / "demo"
    proc = subprocess.Popen(
        [sys.executable, "-m", "camd", "demo", "--out", str(out), "--pings", "200"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=demo_env(),
    )  # fmt: skip
    stderr: list[str] = []
    reader = threading.Thread(target=lambda: stderr.extend(proc.stderr or ()), daemon=True)
    reader.start()
    try:
        stdout: list[str] = []
        for line in proc.stdout or ():
            stdout.append(line)
            if line.startswith(CAMPAIGN_STEP):
                end_exclusive()
        returncode = proc.wait(timeout=300)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    reader.join(timeout=10)
    out_text, err_text = "".join(stdout), "".join(stderr)
    assert returncode == 0, out_text + err_text
    assert "Traceback" not in err_text
    assert any(line.startswith(CAMPAIGN_STEP) for line in stdout), out_text
    summary_path = out / "demo-summary.json"
    final = out_text.strip().splitlines()[-1]
    # The live view's address, early (right after the daemon's) and in the summary.
    summary = json.loads(summary_path.read_text())
    live_url = summary["daemon"]["url"] + "/live"
    assert summary["live_url"] == live_url and "keep" not in summary
    lines = out_text.splitlines()
    assert any(line.startswith(f"live view: {live_url} ") for line in lines[:10]), lines[:10]
    assert final.startswith("demo OK: 200 pings, ")
    assert " 0 failed" in final and final.endswith(f"summary in {summary_path}")

    assert summary["ok"] is True and summary["error"] is None
    assert summary["inject"] == (
        "ber=1e-4,drop=0.01,frame_drop=0.02,frame_corrupt=0.01,frame_short=0.01"
    )

    assert summary["status"]["state"] == "idle"
    assert summary["status"]["device"]["fw_version"] > 0

    ping = summary["ping"]
    assert (ping["count"], ping["ok"], ping["failed"]) == (200, 200, 0)
    assert ping["rtt_ms"]["p50"] <= ping["rtt_ms"]["p99"] <= ping["rtt_ms"]["max"]

    assert {"before", "after"} <= set(summary["link"])
    check = summary["at_most_once"]
    assert check["held"] is True
    assert check["device_executed"] >= 200 and check["host_answered"] >= 200
    assert abs(check["device_executed"] - check["host_answered"]) <= check["tolerance"]

    tel = summary["telemetry"]
    assert tel["samples_after"] > tel["samples_before"]
    assert tel["archive_exists"] is True and Path(tel["archive"]).is_file()
    assert tel["last"]["latest"]
    assert tel["history"]["samples"] > 0

    assert [m["status"]["mode"] for m in summary["modes"]] == ["area", "tdi", "area"]
    assert [m["requested"] for m in summary["modes"]] == [None, "tdi", "area"]
    assert summary["events"]

    stream = summary["stream"]
    tdi, injected = stream["tdi"], stream["injected"]
    assert (tdi["mode"], tdi["stages"], tdi["rows"], tdi["cols"]) == ("tdi", 32, 534, 2048)
    # Every frame the simulator sent is accounted for, and exactly as it was damaged.
    assert tdi["lost"] == injected["dropped"] + injected["stalls"] + injected["undelivered"]
    assert tdi["corrupt"] + tdi["short"] == injected["corrupted"] + injected["shortened"]
    assert tdi["frames"] + tdi["lost"] + tdi["corrupt"] + tdi["short"] == 200
    assert tdi["overruns"] == 0 and tdi["frames_sent"] == 200
    recording = stream["recording"]
    assert recording["frames"] == stream["stare"]["frames"] > 0
    assert recording["crc_mismatches"] == 0 and Path(recording["path"]).is_file()

    scans = summary["scans"]
    assert [s["stages"] for s in scans] == [1, 8, 32]
    for scan in scans:
        assert Path(scan["file"]).is_file() and Path(scan["quicklook"]).is_file()
        assert scan["complete_lines"] >= 100 and scan["lines"] >= scan["complete_lines"]
        # Signal grows as M (docs/physics.md §1 eq 11) ...
        assert scan["signal_dn"] == pytest.approx(scans[0]["signal_dn"] * scan["stages"], rel=0.1)
    # ... and SNR as sqrt(M) (docs/physics.md §5: independent noise per stage), within 1.5 dB here:
    # the TAO12 model (quantisation adding linearly) is 4.6 dB lower at M = 32.
    for scan in scans[1:]:
        assert abs(scan["snr_db"] - scan["model_sqrt_m_db"]) < 1.5, scan
        assert scan["model_tao12_db"] < scan["model_sqrt_m_db"] - 1.0
    assert "TDI scans at M = 1/8/32 with SNR " in final

    # Item 10: short runs of two shipped campaigns, each on its own simulated camera.
    campaigns = summary["campaigns"]
    assert [(c["campaign"], c["profile"]) for c in campaigns] == [
        ("tdi_snr_stages", "ibis5"),
        ("mtf_mismatch", "mt9m001"),
    ]
    for c in campaigns:
        assert c["passed"] is True and c["failed_checks"] == []
        report = Path(c["report"])
        assert report == out.resolve() / "campaigns" / c["campaign"] / "report.html"
        assert f"campaign reports {campaigns[0]['report']}, {campaigns[1]['report']};" in final
        assert len(report_images(report.parent)) >= 2

    daemon = summary["daemon"]
    assert daemon["exit_code"] in (0, -15) and daemon["killed"] is False
    assert Path(daemon["log"]).is_file()
    assert "camd serving http://" in Path(daemon["log"]).read_text()


def test_the_live_view_address_carries_the_token() -> None:
    assert live_page_url("http://127.0.0.1:8422") == "http://127.0.0.1:8422/live"
    assert live_page_url("http://h:1/", "a b&c") == "http://h:1/live?token=a%20b%26c"


def is_camd_serve(pid: int) -> bool:
    try:
        command = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
    except OSError:
        return False
    return b"camd" in command and b"serve" in command


@pytest.mark.exclusive
def test_demo_keep_leaves_the_daemon_running_until_ctrl_c(
    tmp_path: Path, end_exclusive: Callable[[], None]
) -> None:
    """``camd demo --keep``: after its steps the daemon serves a streaming live view at the
    address it printed, until SIGINT; then everything stops and the demo exits 0."""
    out = tmp_path / "demo"
    proc = subprocess.Popen(
        [sys.executable, "-m", "camd", "demo", "--out", str(out), "--pings", "20",
         "--no-campaigns", "--keep"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=demo_env(),
    )  # fmt: skip
    lines: queue.Queue[str | None] = queue.Queue()
    stdout: list[str] = []
    stderr: list[str] = []

    def read(stream: IO[str], into: list[str], forward: bool) -> None:
        for line in stream:
            into.append(line)
            if forward:
                lines.put(line)
        if forward:
            lines.put(None)

    readers = [
        threading.Thread(target=read, args=(proc.stdout, stdout, True), daemon=True),
        threading.Thread(target=read, args=(proc.stderr, stderr, False), daemon=True),
    ]
    for reader in readers:
        reader.start()
    daemon_pid: int | None = None
    try:
        while True:
            line = lines.get(timeout=300)
            assert line is not None, "".join(stdout) + "".join(stderr)
            if match := re.search(r"daemon pid (\d+) serving", line):
                daemon_pid = int(match.group(1))
            if "Ctrl-C to stop" in line:
                # Streams and scans done; what follows checks the kept live view, not a rate.
                end_exclusive()
                break
        addresses = [m.group(1) for x in stdout if (m := re.match(r"live view: (\S+)", x))]
        # Printed early (before the steps) and again, the same, before waiting.
        assert len(addresses) == 2 and addresses[0] == addresses[1], addresses
        live_url = addresses[-1]
        assert re.fullmatch(r"http://127\.0\.0\.1:\d+/live", live_url)
        base = live_url.removesuffix("/live")
        with httpx.Client(base_url=base, timeout=30) as http:
            status = http.get("/api/v1/status")
            assert status.status_code == 200 and status.json()["state"] == "streaming"
            # The newest frame may still be one of the demo's scans (the tap keeps the last
            # frame of any stream): wait for the kept stream's own.
            seq, deadline = 0, time.monotonic() + 120
            while True:
                frame = http.get("/api/v1/live/frame", params={"after": seq, "timeout_s": 5})
                assert frame.status_code == 200, frame.text
                meta = json.loads(frame.headers["X-Camd-Frame"])
                if (meta["mode"], meta["rows"]) == ("area", 534):
                    break
                assert time.monotonic() < deadline, meta
                seq = meta["seq"]
            assert (meta["mode"], meta["rows"], meta["cols"]) == ("area", 534, 2048)
            assert len(frame.content) == 2 * 534 * 2048
            # The bar target, sharp: the stage tracks one row a frame again after the scans.
            pixels = np.frombuffer(frame.content, dtype="<u2")
            spread = np.percentile(pixels, 99) - np.percentile(pixels, 1)
            assert spread > 500, (spread, meta)
            page = http.get("/live")
            assert page.status_code == 200 and "text/html" in page.headers["content-type"]
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=120) == 0, "".join(stdout) + "".join(stderr)
        for reader in readers:
            reader.join(timeout=10)
        assert stdout[-1].startswith("demo OK: 20 pings, "), stdout[-5:]
        assert "campaigns skipped (--no-campaigns)" in stdout[-1]
        summary = json.loads((out / "demo-summary.json").read_text())
        assert summary["ok"] is True and summary["live_url"] == live_url
        assert summary["campaigns"] == []
        keep = summary["keep"]
        assert (keep["signal"], keep["stream_stopped"]) == ("SIGINT", "by the demo")
        assert keep["stream"]["mode"] == "area" and keep["live_url"] == live_url
        assert summary["daemon"]["exit_code"] in (0, -15)
        assert summary["daemon"]["killed"] is False
        with pytest.raises(httpx.ConnectError):
            httpx.get(f"{base}/api/v1/status", timeout=5)
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
            try:
                proc.wait(timeout=60)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        # The daemon runs in its own session: never leave it behind (if it is still this one).
        if daemon_pid is not None and is_camd_serve(daemon_pid):
            os.kill(daemon_pid, signal.SIGTERM)
