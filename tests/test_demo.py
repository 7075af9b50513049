"""``camd demo`` end to end, as a subprocess: exit 0, the final line, and the summary file."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

import camd
from tests.campaign_support import report_images

# Real-time streaming / control loops: alone under xdist (tests/conftest.py).
pytestmark = pytest.mark.exclusive

REPO_ROOT = str(Path(camd.__file__).resolve().parent.parent)


def test_demo_runs_and_writes_its_summary(tmp_path: Path) -> None:
    out = tmp_path / "demo"
    # The demo's daemon and client would both take $CAMD_TOKEN; run it as a user without one.
    env = {k: v for k, v in os.environ.items() if k not in ("CAMD_URL", "CAMD_TOKEN")}
    env["PYTHONPATH"] = os.pathsep.join(p for p in (REPO_ROOT, env.get("PYTHONPATH")) if p)
    proc = subprocess.run(
        [sys.executable, "-m", "camd", "demo", "--out", str(out), "--pings", "200"],
        capture_output=True,
        text=True,
        timeout=300,
        env=env,
        check=False,
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "Traceback" not in proc.stderr
    summary_path = out / "demo-summary.json"
    final = proc.stdout.strip().splitlines()[-1]
    assert final.startswith("demo OK: 200 pings, ")
    assert " 0 failed" in final and final.endswith(f"summary in {summary_path}")

    summary = json.loads(summary_path.read_text())
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
