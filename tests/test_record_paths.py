"""A real daemon writes the files clients name only inside its data directory and the
directories its config allows (docs/api.md, "Files"): every endpoint that takes a path (a
stare's and a stream's ``record``, a scan's ``out``, a wheel run's ``record``, a campaign job's
``out``) gets the same names, over HTTP, as tests/test_output_paths.py gives the function:
``..``, absolute paths into /etc, /root and /dev/shm, a directory symlink and a final symlink
leading out, a loop, NUL, control characters, over-long names. Each is a 400 with its message,
and nothing is created anywhere. Then what is allowed works: an extra directory the config
names, a symlink inside the data directory, relative names (in the folders the API documents),
and camctl sending a relative name and printing where the daemon wrote it.

The daemon here is started without the test suite's ``$CAMD_RECORD_DIRS`` (tests/conftest.py):
only its data directory and one directory of its own (``--record-dir``) are allowed.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import h5py
import httpx
import pytest

from camd.cli._daemon_proc import DaemonProcess
from camd.client import CamdClient
from camd.store import read_recording
from camd.store.tdi_recording import read_tdi_scan
from tests.device_snapshot import snapshot
from tests.test_camctl import camctl, camctl_env, camctl_json
from tests.test_output_paths import NEVER, REFUSED, Tree, fill, listing, make_tree

API = "/api/v1"
CLIENT = "record-paths"
CAMPAIGN = "example_stare"  # shipped, for the hr400 this daemon simulates
WAIT_S = 120.0

# Each endpoint with a body that is valid but for its path field.
ENDPOINTS = {
    "stare": ("/stream/acquire", "record", {"frames": 2}),
    "stream": ("/stream/start", "record", {"frames": 2}),
    "scan": ("/scan/start", "out", {"stages": 4, "lines": 5, "line_period_s": 3e-3,
                                    "drive_stage": False}),
    "wheel": ("/wheel/acquire", "record", {"channels": [1]}),
}  # fmt: skip
# The campaign job's check starts nothing for a refused directory, but a few cases suffice.
CAMPAIGN_CASES = ("etc", "dotdot-relative", "directory-symlink-out", "nul", "long-path")


@dataclass
class Rig:
    url: str
    client: CamdClient
    tree: Tree


@pytest.fixture(scope="module")
def rig(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Rig]:
    tree = make_tree(tmp_path_factory.mktemp("record-paths"))
    with (
        DaemonProcess(
            tree.data,
            record_dirs=[tree.allowed],
            env={"CAMD_TOKEN": "", "CAMD_RECORD_DIRS": ""},  # not the suite's directories
        ) as daemon,
        CamdClient(daemon.url, client=CLIENT, timeout_s=60) as client,
    ):
        client.wait_ready(60)
        client.write_registers({"WIN_ROWS": 16, "EXPOSURE": 4})  # short frames: quick stares
        client.set_mode("area")
        yield Rig(daemon.url, client, tree)
    assert daemon.exit_code in (0, -15), daemon.log_path.read_text()


def daemon_files(tree: Tree) -> list[str]:
    """The tree's files, but for what the daemon itself keeps changing."""
    return [
        p for p in listing(tree.root)
        if not Path(p).name.startswith(("telemetry.sqlite", "daemon.log"))
    ]  # fmt: skip


def cases(endpoint: str) -> list[Any]:
    names = CAMPAIGN_CASES if endpoint == "campaign" else [r[0] for r in REFUSED]
    return [pytest.param(endpoint, r[1], r[2], id=f"{endpoint}-{r[0]}") for r in REFUSED
            if r[0] in names]  # fmt: skip


@pytest.mark.parametrize(
    ("endpoint", "name", "fragments"),
    [case for endpoint in (*ENDPOINTS, "campaign") for case in cases(endpoint)],
)
def test_a_path_outside_the_allowed_directories_is_refused_and_nothing_is_made(
    rig: Rig, endpoint: str, name: str, fragments: list[str]
) -> None:
    if endpoint == "campaign":
        path, field, body = "/campaigns/jobs", "out", {"campaign": CAMPAIGN, "quick": True}
    else:
        path, field, body = ENDPOINTS[endpoint]
    data = rig.tree.data
    before = daemon_files(rig.tree), snapshot(rig.client), rig.client.campaign_jobs()["jobs"]
    # json.dumps escapes what is not ASCII, so that a lone surrogate reaches the daemon too.
    content = json.dumps({**body, field: fill(name, rig.tree)})
    headers = {"X-Camd-Client": CLIENT, "Content-Type": "application/json"}
    with httpx.Client(base_url=rig.url, timeout=60, headers=headers) as h:
        response = h.post(f"{API}{path}", content=content)
        assert h.get(f"{API}/status").json()["state"] == "idle"
    assert response.status_code == 400, response.text
    doc = response.json()
    assert doc["code"] == "bad_request", doc
    folder = {"stare": "recordings", "stream": "recordings", "wheel": "recordings",
              "scan": "scans", "campaign": "campaigns"}[endpoint]  # fmt: skip
    for fragment in fragments:
        text = fill(fragment, rig.tree)
        text = field + text.removeprefix("record") if text.startswith("record") else text
        text = text.replace(f"{data}/recordings", f"{data}/{folder}")
        assert text in doc["error"], doc["error"]
    assert len(response.content) < 1500  # a long name is cut in the message
    # Nothing made: no file, no directory, no job; the camera as it was.
    after = daemon_files(rig.tree), snapshot(rig.client), rig.client.campaign_jobs()["jobs"]
    assert after == before
    for system in ("/etc", "/root", "/dev/shm"):
        assert not os.path.lexists(f"{system}/{NEVER}")


def test_an_allowed_directory_a_symlink_inside_and_a_relative_name_record(rig: Rig) -> None:
    data, client = rig.tree.data, rig.client
    written = {
        str(rig.tree.allowed / "extra.h5"): rig.tree.allowed / "extra.h5",
        str(data / "link_in" / "in.h5"): data / "sub" / "in.h5",
        str(data / "final_in.h5"): data / "sub" / "final-target.h5",
        "rel.h5": data / "recordings" / "rel.h5",
        "../sub/up.h5": data / "sub" / "up.h5",
    }
    for name, file in written.items():
        doc = client.acquire(2, record=name)
        assert doc["stats"]["frames"] == 2
        assert doc["recording"] == str(file), name  # the file, as the daemon resolved it
        assert len(read_recording(file).frames) == 2
    assert (data / "link_in" / "in.h5").samefile(data / "sub" / "in.h5")


def test_a_relative_scan_goes_into_the_scans_folder(rig: Rig) -> None:
    client = rig.client
    client.start_scan(4, 5, out="rel-scan.h5", line_period_s=3e-3, drive_stage=False,
                      quicklook=False)  # fmt: skip
    doc = client.wait_scan(WAIT_S)
    assert doc["state"] == "done", doc
    assert doc["file"] == str(rig.tree.data / "scans" / "rel-scan.h5")
    assert (rig.tree.data / "scans" / "rel-scan.h5").is_file()


# A stare's, a stream's and a scan's compression (docs/api.md), refused with the valid choices.
COMPRESSION_REFUSED = [
    pytest.param("stare", {"compression": "zip"},
                 "compression: 'zip' is not valid (unknown compression 'zip': choose one of "
                 "'off', 'bitshuffle-lz4', 'bitshuffle-zstd', 'blosc2-zstd', 'gzip', 'lzf')",
                 id="stare-unknown-filter"),
    pytest.param("stream", {"compression_level": 3},
                 "compression_level: 3 is not valid (compression_level needs compression: name "
                 "the filter it is a level of (one of 'off', 'bitshuffle-lz4'",
                 id="stream-level-without-filter"),
    pytest.param("scan", {"compression": "gzip", "compression_level": 12},
                 "compression_level: 12 is not valid (compression level 12 is out of range for "
                 "'gzip': choose 1..9 (default 1))", id="scan-level-out-of-range"),
    pytest.param("scan", {"compression": "bitshuffle-lz4", "compression_level": 1},
                 "compression 'bitshuffle-lz4' has no levels", id="scan-level-of-no-levels"),
    pytest.param("stare", {"compression": 7},
                 "compression: 7 is an integer, the wrong type; use null or a string",
                 id="stare-filter-not-a-string"),
]  # fmt: skip


@pytest.mark.parametrize(("endpoint", "compression", "message"), COMPRESSION_REFUSED)
def test_a_bad_compression_is_refused_with_the_valid_choices_and_nothing_is_made(
    rig: Rig, endpoint: str, compression: dict[str, Any], message: str
) -> None:
    path, field, body = ENDPOINTS[endpoint]
    before = daemon_files(rig.tree), snapshot(rig.client)
    headers = {"X-Camd-Client": CLIENT}
    with httpx.Client(base_url=rig.url, timeout=60, headers=headers) as h:
        response = h.post(f"{API}{path}", json={**body, field: "compressed.h5", **compression})
    assert response.status_code == 400, response.text
    assert response.json()["code"] == "bad_request"
    assert message in response.json()["error"], response.json()["error"]
    assert (daemon_files(rig.tree), snapshot(rig.client)) == before


def test_a_request_chooses_its_compression_and_the_config_gives_the_rest(rig: Rig) -> None:
    """By default (camd.toml's store.compression) a stare and a scan are compressed with
    Bitshuffle + LZ4; a request's own compression wins; every one reads back whole."""
    client, data = rig.client, rig.tree.data
    for name, options, expected in (
        ("default.h5", {}, ("bitshuffle-lz4", None, {"32008"})),
        ("off.h5", {"compression": "off"}, ("off", None, set())),
        ("gzip.h5", {"compression": "gzip", "compression_level": 4}, ("gzip", 4,
                                                                      {"shuffle", "gzip"})),
    ):  # fmt: skip
        client.acquire(3, record=name, **options)  # type: ignore[arg-type]
        file = data / "recordings" / name
        stare = read_recording(file)
        assert len(stare.frames) == 3 and stare.crc_mismatches() == []
        with h5py.File(file, "r") as f:
            frames = f["frames"]
            got = (frames.attrs["compression"], frames.attrs.get("compression_level"))
            assert (*got, set(frames._filters)) == expected, name
    client.start_scan(4, 5, out="blosc.h5", line_period_s=3e-3, drive_stage=False,
                      quicklook=False, compression="blosc2-zstd")  # fmt: skip
    assert client.wait_scan(WAIT_S)["state"] == "done"
    with h5py.File(data / "scans" / "blosc.h5", "r") as f:
        lines = f["lines"]
        assert (lines.attrs["compression"], lines.attrs["compression_level"]) == ("blosc2-zstd", 1)
        assert set(lines._filters) == {"32026"}
        assert lines.chunks == (250, 2048)  # what arrives in 0.75 s at 3 ms a line
    # A scan at 2.7 MB/s of lines (under store.scan_compression_max_mbyte_s) takes the default.
    client.start_scan(4, 5, out="default-scan.h5", line_period_s=3e-3, drive_stage=False,
                      quicklook=False)  # fmt: skip
    assert client.wait_scan(WAIT_S)["state"] == "done"
    with h5py.File(data / "scans" / "default-scan.h5", "r") as f:
        assert f["lines"].attrs["compression"] == "bitshuffle-lz4"
    scan = read_tdi_scan(data / "scans" / "blosc.h5")
    assert len(scan.lines) == 5 + 4 - 1 and int(scan.complete.sum()) == 5  # and M - 1 partial


def test_camctl_sends_a_relative_name_and_prints_where_the_daemon_wrote(
    rig: Rig, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)  # camctl runs here; the file must not land here
    doc = camctl_json(rig.url, "stare", "--frames", "2", "--out", "camctl-rel.h5")
    assert doc["out"] == str(rig.tree.data / "recordings" / "camctl-rel.h5")
    assert len(read_recording(Path(doc["out"])).frames) == 2
    proc = camctl(rig.url, "stare", "--frames", "2", "--out", f"/etc/{NEVER}")
    assert proc.returncode == 1, proc.stderr
    assert f"record '/etc/{NEVER}' is outside the directories the daemon may write" in proc.stderr
    assert listing(tmp_path) == []
    assert not os.path.lexists(f"/etc/{NEVER}")


def test_a_campaign_job_with_a_relative_out_runs_in_the_campaigns_folder(rig: Rig) -> None:
    client = rig.client
    job = client.start_campaign(CAMPAIGN, out="rel-job", quick=True)
    try:
        assert job["out_dir"] == str(rig.tree.data / "campaigns" / "rel-job")
    finally:
        client.abort_campaign(job["id"])
        deadline = time.monotonic() + WAIT_S
        while client.campaign_job(job["id"])["state"] not in ("aborted", "passed", "failed"):
            assert time.monotonic() < deadline, client.campaign_job(job["id"])
            time.sleep(0.1)


def test_camctl_campaign_run_sim_lets_its_own_daemon_write_its_output(tmp_path: Path) -> None:
    """``camctl campaign run --sim`` (as ``camd demo`` runs its campaigns) starts a daemon of its
    own in DIR/daemon, which must be allowed to write DIR/raw: without the suite's
    ``$CAMD_RECORD_DIRS``, only what camctl itself allows."""
    out = tmp_path / "run"
    env = {**camctl_env(), "CAMD_RECORD_DIRS": ""}
    proc = subprocess.run(
        [sys.executable, "-m", "camd.cli.camctl", "campaign", "run", "example_stare", "--sim",
         "--quick", "--out", str(out), "--json"],
        capture_output=True, text=True, timeout=300, env=env, check=False,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout)["passed"] is True
    raw = sorted(p.name for p in (out / "raw").iterdir())
    assert raw == ["dark.h5", "light_0__stare.h5", "light_1__stare.h5"]
    assert all(len(read_recording(out / "raw" / name).frames) > 0 for name in raw)
