"""Campaigns as Python plans (camd.campaign.plan, docs/campaigns.md): a plan and its YAML twin
give the same results.json; a plan adds an acquisition kind without touching the runner and
decides on what it gets back; a resumed plan gives the same results; a plan that breaks the
rules is stopped with a message that says how."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from camd.campaign.loading import load_campaign
from camd.campaign.plan import load_plan
from camd.campaign.runner import CampaignInterrupted, CampaignRunner
from camd.campaign.spec import CampaignError
from camd.cli._daemon_proc import DaemonProcess
from camd.client import CamdClient
from camd.paths import config_dir
from tests.test_sensor_stack import serve

EXAMPLE = config_dir() / "campaigns" / "example_stare.yaml"
TWIN = Path(__file__).parent / "plans" / "example_stare.py"

HEADER = """
CAMPAIGN = {"name": "plan_test", "profile": "hr400", "seed": 3, "parameters": {"frames": 4}}
"""

# A new acquisition kind, registered by the plan's own module: the runner is not edited.
NEW_KIND = (
    """
from camd.campaign.acquisitions import acquisition
from camd.campaign.plan import acquire, check, configure, measure
"""
    + HEADER
    + """
SEEN = []

@acquisition("dark_burst")
def dark_burst(client, path, *, frames):
    client.set_scene("flat:photons=1e-6")
    doc = client.acquire(frames, record=str(path))
    return {"frames": doc["stats"]["frames"], "made_by": "dark_burst"}

def plan(p):
    yield configure("window", registers={"WIN_ROWS": 64}, mode="area")
    got = yield acquire("burst", kind="dark_burst", args={"frames": p["frames"]})
    SEEN.append(got)
    if got["frames"] == p["frames"]:  # the plan decides on what came back
        noise = yield measure("noise", "dark_noise", inputs={"frames": "burst"},
                              args={"region": [25, 25]})
        SEEN.append(noise)
        yield check("quiet", "dark_noise_dn", max=10.0)
"""
)


@pytest.fixture(scope="module")
def daemon(tmp_path_factory: pytest.TempPathFactory) -> Iterator[DaemonProcess]:
    with serve(tmp_path_factory.mktemp("camd-plan"), "fpga") as d:
        yield d


def write_plan(tmp_path: Path, name: str, text: str) -> Path:
    path = tmp_path / f"{name}.py"
    path.write_text(text, encoding="utf-8")
    return path


def test_the_python_twin_gives_the_yaml_campaigns_results_json(
    daemon: DaemonProcess, tmp_path: Path
) -> None:
    spec = load_campaign(EXAMPLE)
    twin = load_plan(TWIN)
    # The same campaign: the header is the YAML file's, field for field.
    assert twin.spec.model_dump(exclude={"steps"}) == spec.model_dump(exclude={"steps"})
    with CamdClient(daemon.url) as client:
        CampaignRunner(client, spec, tmp_path / "yaml", quick=True).run()
    proc = subprocess.run(
        [sys.executable, "-m", "camd.cli.camctl", "--url", daemon.url, "campaign", "run",
         str(TWIN), "--out", str(tmp_path / "py"), "--quick", "--json"],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout)["passed"] is True
    yaml_doc = (tmp_path / "yaml" / "results.json").read_text()
    plan_doc = (tmp_path / "py" / "results.json").read_text()
    assert plan_doc == yaml_doc
    assert json.loads(plan_doc)["results"]["photons"] == [2.0e7, 8.0e7]
    # The reports are the same too (tables and plots from the same results).
    assert (tmp_path / "py" / "report.md").read_text() == (
        tmp_path / "yaml" / "report.md"
    ).read_text()


def test_a_plan_adds_an_acquisition_kind_and_decides_on_its_answer(
    daemon: DaemonProcess, tmp_path: Path
) -> None:
    plan = load_plan(write_plan(tmp_path, "new_kind", NEW_KIND))
    with CamdClient(daemon.url) as client:
        outcome = CampaignRunner(client, None, tmp_path / "out", plan=plan).run()
    module: Any = sys.modules["camd_campaign_plan_new_kind"]
    assert [{"frames": 4, "made_by": "dark_burst"}, outcome.doc["results"]] == module.SEEN
    doc = outcome.doc
    assert doc["passed"] is True
    assert 0 < doc["results"]["dark_noise_dn"] < 10  # measured on the new kind's frames
    assert doc["files"] == {"burst": "raw/burst.h5"}
    assert (tmp_path / "out" / "raw" / "burst.h5").read_bytes()[:8] == b"\x89HDF\r\n\x1a\n"
    state = json.loads((tmp_path / "out" / "state.json").read_text())
    assert state["completed"]["burst"]["how"] == "dark_burst"
    assert state["completed"]["burst"]["doc"] == {"frames": 4, "made_by": "dark_burst"}
    assert [c["id"] for c in doc["checks"]] == ["quiet"]


def test_a_resumed_plan_sees_the_replayed_answers_and_gives_the_same_results(
    daemon: DaemonProcess, tmp_path: Path
) -> None:
    path = write_plan(tmp_path, "resumable", NEW_KIND)
    with CamdClient(daemon.url) as client:
        straight = CampaignRunner(client, None, tmp_path / "a", plan=load_plan(path)).run()
        first = load_plan(path)
        with pytest.raises(CampaignInterrupted):
            CampaignRunner(client, None, tmp_path / "b", plan=first, stop_after="burst").run()
        client.set_scene("flat:photons=1e8")  # the simulator's noise moves on meanwhile
        client.acquire(3)
        again = load_plan(path)
        resumed = CampaignRunner(client, None, tmp_path / "b", plan=again).run()
    assert resumed.doc == straight.doc
    assert (tmp_path / "a" / "results.json").read_text() == (
        tmp_path / "b" / "results.json"
    ).read_text()


BROKEN: dict[str, tuple[str, str]] = {
    "not a step": ("def plan(p):\n    yield 'acquire 10 frames'\n", "the plan yielded str"),
    "an id twice": (
        "from camd.campaign.plan import configure\n"
        "def plan(p):\n    yield configure('a', mode='area')\n    yield configure('a', mode='tdi')\n",
        "step a: its id is used twice at one level",
    ),
    "an open sweep": (
        "from camd.campaign.plan import BeginSweep\n"
        "def plan(p):\n    yield BeginSweep('s', 'x', (1, 2))\n",
        "the plan ended inside a sweep",
    ),
    "not a generator": ("def plan(p):\n    return [1]\n", "must be a generator"),
    "an unknown kind": (
        "from camd.campaign.plan import acquire\n"
        "def plan(p):\n    yield acquire('x', kind='no_such_kind')\n",
        "no acquisition kind 'no_such_kind' is registered",
    ),
}


@pytest.mark.parametrize("case", sorted(BROKEN))
def test_a_plan_that_breaks_the_rules_is_stopped_with_a_message(
    daemon: DaemonProcess, tmp_path: Path, case: str
) -> None:
    body, message = BROKEN[case]
    plan = load_plan(write_plan(tmp_path, "broken", HEADER + body))
    with CamdClient(daemon.url) as client, pytest.raises(CampaignError, match=message):
        CampaignRunner(client, None, tmp_path / "out", plan=plan).run()


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("x = 1\n", " a Python campaign defines CAMPAIGN .* and plan\\(parameters\\)"),
        # The header's errors name the line of the key in the CAMPAIGN dict, as a YAML file's do.
        ("CAMPAIGN = {'name': 'x'}\ndef plan(p):\n    yield from ()\n",
         "1: CAMPAIGN: profile: missing key; add `profile: \\.\\.\\.`$"),
        ("CAMPAIGN = {\n    'name': 'x',\n    'profile': 'hr400',\n    'seed': '3',\n}\n"
         "def plan(p):\n    yield from ()\n",
         "4: CAMPAIGN: seed: '3' is a string, the wrong type; write an integer, without quotes$"),
        ("CAMPAIGN = dict(\n    name='x',\n    profile='hr400',\n    parameters={'n': 1},\n"
         "    quick={'m': 2},\n)\ndef plan(p):\n    yield from ()\n",
         "5: CAMPAIGN: quick: m not in `parameters`"),
        ("import no_such_module\n", " importing the plan failed: ModuleNotFoundError"),
    ],
)  # fmt: skip
def test_a_bad_python_campaign_names_the_file_and_what_is_missing(
    tmp_path: Path, text: str, message: str
) -> None:
    path = write_plan(tmp_path, "bad", text)
    with pytest.raises(CampaignError, match=f"^{re.escape(str(path))}:{message}"):
        load_plan(path)
