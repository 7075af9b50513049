"""Campaign runner (docs/campaigns.md): camctl campaign run -> HTTP -> camd serve (simulated
hr400) -> results.json, raw HDF5, report.md/html with PNG plots; resume after an interrupt gives
the same results.json; a failing check exits 1; bad YAML names the file, step and key."""

from __future__ import annotations

import json
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import yaml

from camd.campaign.loading import load_campaign
from camd.campaign.runner import CampaignInterrupted, CampaignRunner
from camd.campaign.spec import CampaignError
from camd.cli._daemon_proc import DaemonProcess
from camd.client import CamdClient
from camd.paths import config_dir
from tests.campaign_support import report_images
from tests.test_sensor_stack import serve

EXAMPLE = config_dir() / "campaigns" / "example_stare.yaml"


@pytest.fixture(scope="module")
def daemon(tmp_path_factory: pytest.TempPathFactory) -> Iterator[DaemonProcess]:
    with serve(tmp_path_factory.mktemp("camd-campaign"), "fpga") as d:
        yield d


def camctl(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "camd.cli.camctl", *args],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip


def results(out: Path) -> dict[str, Any]:
    doc: dict[str, Any] = json.loads((out / "results.json").read_text())
    return doc


def test_run_writes_results_raw_data_and_report(daemon: DaemonProcess, tmp_path: Path) -> None:
    out = tmp_path / "run"
    proc = camctl("--url", daemon.url, "campaign", "run", str(EXAMPLE), "--out", str(out),
                  "--quick", "--json")  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    doc = json.loads(proc.stdout)  # exactly one JSON document
    assert list(doc) == ["campaign", "passed", "results", "report"]
    assert doc["campaign"] == "example_stare" and doc["passed"] is True
    r = doc["results"]
    assert r["photons"] == [2.0e7, 8.0e7]  # the quick override
    assert len(r["psnr_db"]) == len(r["mean_dn"]) == 2
    assert r["mean_dn"][1] > r["mean_dn"][0] > r["dark_mean_dn"]  # more light, more signal
    assert 0 < r["dark_noise_dn"] < 10
    full = results(out)
    assert full["results"] == r and full["passed"] is True
    assert [c["id"] for c in full["checks"]] == ["light[0]/psnr_ok", "light[1]/psnr_ok"]
    for rel in full["files"].values():  # the raw data, one HDF5 file per acquisition
        assert (out / rel).read_bytes()[:8] == b"\x89HDF\r\n\x1a\n"
    assert doc["report"] == str(out / "report.html")
    html = (out / "report.html").read_text()
    md = (out / "report.md").read_text()
    assert len(report_images(out)) == 2
    assert "| photons | mean_dn | sigma_dn | psnr_db |" in md
    assert "PASS" in md and "<td class='PASS'>" in html


def test_interrupted_and_resumed_gives_the_same_results(
    daemon: DaemonProcess, tmp_path: Path
) -> None:
    spec = load_campaign(EXAMPLE)
    with CamdClient(daemon.url) as client:
        straight = CampaignRunner(client, spec, tmp_path / "straight", quick=True).run()
        # Stop after the first light level's acquisition, as Ctrl-C would, then resume.
        stopped = CampaignRunner(
            client, spec, tmp_path / "resumed", quick=True, stop_after="light[0]/stare"
        )
        with pytest.raises(CampaignInterrupted):
            stopped.run()
        state = json.loads((tmp_path / "resumed" / "state.json").read_text())
        assert "light[0]/stare" in state["completed"]
        assert "light[1]/stare" not in state["completed"]
        assert not (tmp_path / "resumed" / "results.json").exists()
        # Something else uses the simulator in between (its noise stream moves on).
        client.set_scene("flat:photons=1e8")
        client.acquire(3)
        resumed = CampaignRunner(client, spec, tmp_path / "resumed", quick=True).run()
    a = (tmp_path / "straight" / "results.json").read_text()
    b = (tmp_path / "resumed" / "results.json").read_text()
    assert a == b
    assert straight.doc == resumed.doc


def test_failing_check_exits_1_after_writing_everything(
    daemon: DaemonProcess, tmp_path: Path
) -> None:
    doc = yaml.safe_load(EXAMPLE.read_text())
    doc["parameters"]["min_psnr_db"] = 100.0  # no flat field is that clean
    bad = tmp_path / "strict.yaml"
    bad.write_text(yaml.safe_dump(doc))
    out = tmp_path / "out"
    proc = camctl("--url", daemon.url, "campaign", "run", str(bad), "--out", str(out),
                  "--quick", "--json")  # fmt: skip
    assert proc.returncode == 1, proc.stderr
    printed = json.loads(proc.stdout)
    assert printed["passed"] is False
    assert "check(s) failed: light[0]/psnr_ok, light[1]/psnr_ok" in proc.stderr
    assert results(out)["passed"] is False
    assert (out / "report.html").exists() and "FAIL" in (out / "report.md").read_text()


def test_campaign_for_another_sensor_is_refused(daemon: DaemonProcess, tmp_path: Path) -> None:
    doc = yaml.safe_load(EXAMPLE.read_text())
    doc["profile"] = "ibis5"
    other = tmp_path / "ibis5.yaml"
    other.write_text(yaml.safe_dump(doc))
    proc = camctl("--url", daemon.url, "campaign", "run", str(other), "--out", str(tmp_path / "o"))
    assert proc.returncode == 1
    assert "written for the ibis5 camera but the daemon simulates hr400" in proc.stderr
    assert "--sim" in proc.stderr


@pytest.mark.parametrize(
    ("edit", "expected"),
    [
        (lambda d: d["steps"][4]["steps"][1]["stare"].update(frame=3),
         "steps[4] (id 'light').steps[1] (id 'stare').stare.frame: unknown key"),
        (lambda d: d["steps"][3].update(function="no_such"),
         "steps[3] (id 'dark_noise'): function: unknown measurement 'no_such'"),
        (lambda d: d["steps"][2]["stare"].update(frames="${nope}"),
         "steps[2] (id 'dark'): stare: ${nope} is neither a parameter"),
        (lambda d: d["steps"][1].pop("kind"), "steps[1] (id 'dark_scene')"),
    ],
)  # fmt: skip
def test_bad_campaign_file_names_file_step_and_key(
    tmp_path: Path, edit: Any, expected: str
) -> None:
    doc = yaml.safe_load(EXAMPLE.read_text())
    edit(doc)
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump(doc, sort_keys=False))
    with pytest.raises(CampaignError) as info:
        load_campaign(bad)
    message = str(info.value)
    assert message.startswith(f"{bad}:"), message
    assert expected in message, message
    proc = camctl("campaign", "run", str(bad), "--out", str(tmp_path / "o"))
    assert proc.returncode == 2 and str(bad) in proc.stderr


def test_list_shows_the_shipped_campaigns() -> None:
    proc = camctl("campaign", "list", "--json")
    assert proc.returncode == 0, proc.stderr
    names = {c["name"]: c for c in json.loads(proc.stdout)["campaigns"]}
    assert names["example_stare"]["profile"] == "hr400"
    assert not names["example_stare"]["description"].startswith("INVALID")


def test_references_to_results_and_keys(tmp_path: Path) -> None:
    """``${result}`` names a result a measure step declared before the step; ``${name.key}`` a
    key of a mapping; both resolve to the value with its type."""
    from camd.campaign.spec import resolve

    doc = yaml.safe_load(EXAMPLE.read_text())
    # The dark noise measured first sets a later scene's level: declared, so accepted.
    doc["steps"][3]["results"] = ["dark_noise_dn"]
    doc["steps"][4]["steps"][0]["scene"] = "flat:photons=${dark_noise_dn}"
    ok = tmp_path / "ok.yaml"
    ok.write_text(yaml.safe_dump(doc, sort_keys=False))
    load_campaign(ok)
    # Referring to it before the step that declares it is refused, naming what is known.
    doc["steps"][2]["stare"]["frames"] = "${dark_noise_dn}"
    early = tmp_path / "early.yaml"
    early.write_text(yaml.safe_dump(doc, sort_keys=False))
    with pytest.raises(CampaignError, match=r"\$\{dark_noise_dn\} is neither a parameter"):
        load_campaign(early)
    names = {"condition": {"lux": 4.0, "name": "4lx"}, "frames": [1, 2]}
    assert resolve({"a": "${condition.lux}", "b": "flat:lux=${condition.lux}"}, names) == {
        "a": 4.0, "b": "flat:lux=4"
    }  # fmt: skip
    assert resolve("${frames}", names) == [1, 2]
    with pytest.raises(KeyError, match="condition has no key 'lx'"):
        resolve("${condition.lx}", names)
