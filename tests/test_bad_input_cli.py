"""Bad input on the command line and in campaign files (issue 17): each case runs the real command
(camctl in process, from its entry point), and gets the documented exit status (2: bad usage or
invalid input), a one-line-ish message naming the fix, no traceback, and nothing created or
changed."""

from __future__ import annotations

import socket
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest
import yaml

from camd.cli._daemon_proc import DaemonProcess
from camd.client import CamdClient
from camd.paths import config_dir
from tests.device_snapshot import snapshot
from tests.test_camctl import NO_TOKEN, REPO_ROOT, camctl, camctl_env

CAMPAIGNS = config_dir() / "campaigns"
EXAMPLE = CAMPAIGNS / "example_stare.yaml"
NO_DAEMON = "http://127.0.0.1:9"  # nothing listens: a command that got that far would exit 3


def refused(proc: subprocess.CompletedProcess[str], code: int, *fragments: str) -> None:
    assert proc.returncode == code, (proc.returncode, proc.stderr)
    assert "Traceback" not in proc.stderr, proc.stderr
    for fragment in fragments:
        assert fragment in proc.stderr, proc.stderr


def tree(root: Path) -> list[str]:
    return sorted(str(p.relative_to(root)) for p in root.rglob("*"))


# -- camctl campaign run: the file ---------------------------------------------------------------


@pytest.mark.parametrize("name", ["nosuch", "nosuch.yaml", "sub/nosuch", "example_stare.yml"])
def test_unknown_campaign_points_at_the_list(tmp_path: Path, name: str) -> None:
    proc = camctl(NO_DAEMON, "campaign", "run", name, "--out", str(tmp_path / "out"))
    refused(proc, 2, f"no campaign {name!r}", "`camctl campaign list`", "example_stare")
    assert str(CAMPAIGNS) not in proc.stderr  # not where camd happens to be installed
    assert tree(tmp_path) == []


def edited(tmp_path: Path, edit: Any) -> Path:
    doc = yaml.safe_load(EXAMPLE.read_text(encoding="utf-8"))
    edit(doc)
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False), encoding="utf-8")
    return path


def set_stare_frames(doc: dict[str, Any], frames: Any) -> None:
    doc["steps"][2]["stare"]["frames"] = frames


def sweep_over_frames(doc: dict[str, Any]) -> None:
    doc["quick"]["photons"] = [6, -1]
    doc["steps"][4]["steps"][1]["stare"]["frames"] = "${photons}"


def set_registers(doc: dict[str, Any], registers: dict[str, Any]) -> None:
    doc["steps"][0]["registers"] = registers


@pytest.mark.parametrize(
    ("edit", "fragments"),
    [
        (lambda d: set_stare_frames(d, -5),
         ["steps[2] (id 'dark').stare.frames: -5 is out of range; allowed: 1 <= frames <= "
          "4294967295"]),
        # A parameter (its --quick override) that makes a step invalid.
        (lambda d: d["quick"].update(frames=-5),
         ["steps[2] (id 'dark'): stare.frames: -5 is out of range; allowed: 1 <= frames <= "
          "4294967295",
          "nothing was done: correct the campaign's parameters (or their quick overrides)"]),
        # ... inside a sweep: the message names the sweep value.
        (sweep_over_frames,
         ["steps[4] (id 'light').steps[1] (id 'stare') with photons = -1: stare.frames: -1 is "
          "out of range; allowed: 1 <= frames <= 4294967295"]),
        (lambda d: set_registers(d, {"NO_SUCH": 3}),
         ["steps[0]", "registers.NO_SUCH: hr400 has no register named 'NO_SUCH'",
          "`camctl reg dump` lists them"]),
        (lambda d: set_registers(d, {"WIN_ROWS.nope": 3}),
         ["registers.WIN_ROWS.nope: register WIN_ROWS has no field 'nope'; fields: rows"]),
        (lambda d: set_registers(d, {"CHIP_ID": 3}),
         ["registers.CHIP_ID: CHIP_ID is read-only on the hr400"]),
        (lambda d: set_registers(d, {"WIN_ROWS": 100000}),
         ["registers.WIN_ROWS: WIN_ROWS.rows: 100000 is out of range (valid: 1 .. 2048"]),
        (lambda d: d.update(profile="no_such_camera"), ["profile: ", "no_such_camera"]),
    ],
    ids=["frames-literal", "frames-parameter", "frames-in-a-sweep", "unknown-register", "unknown-field",
         "read-only-register", "register-value", "unknown-profile"],
)  # fmt: skip
@pytest.mark.parametrize("sim", [False, True], ids=["url", "sim"])
def test_invalid_campaign_exits_2_before_anything_runs(
    tmp_path: Path, edit: Any, fragments: list[str], sim: bool
) -> None:
    bad = edited(tmp_path, edit)
    out = tmp_path / "out"
    args = ["campaign", "run", str(bad), "--out", str(out), "--quick"]
    proc = camctl(NO_DAEMON, *args, *(["--sim"] if sim else []))
    refused(proc, 2, f"{bad}:", *fragments)
    assert not out.exists()  # no output directory, no daemon started for --sim
    assert tree(tmp_path) == ["bad.yaml"]


def test_every_shipped_campaign_passes_the_whole_check() -> None:
    from camd.campaign.checks import check_campaign
    from camd.campaign.loading import load_campaign

    for path in sorted(CAMPAIGNS.glob("*.yaml")):
        spec = load_campaign(path)
        check_campaign(spec, path, quick=False)
        check_campaign(spec, path, quick=True)


# -- camctl campaign run: --out ------------------------------------------------------------------


def test_out_that_is_a_file_or_cannot_be_made_is_refused(tmp_path: Path) -> None:
    file = tmp_path / "F"
    file.write_text("mine\n")
    for out, fragment in [
        (file, f"--out {file}: exists and is not a directory; give a directory"),
        (file / "sub", f"--out {file / 'sub'}: cannot create the directory"),
        (Path("/proc/camd-no-such/out"), "--out /proc/camd-no-such/out: cannot create"),
    ]:
        proc = camctl(NO_DAEMON, "campaign", "run", "example_stare", "--out", str(out), "--quick")
        refused(proc, 2, fragment, "give a directory")
    assert file.read_text() == "mine\n"
    assert tree(tmp_path) == ["F"]


# -- recording into a missing directory: refused, as a scan is -----------------------------------


@pytest.fixture(scope="module")
def url(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    with DaemonProcess(tmp_path_factory.mktemp("camd-bad-input"), env=NO_TOKEN) as daemon:
        yield daemon.url


def test_stare_into_a_missing_directory_is_refused_like_a_scan(url: str, tmp_path: Path) -> None:
    missing = tmp_path / "no" / "dir"
    fix = f"the directory {missing} does not exist; create it first (mkdir -p {missing})"
    refused(camctl(url, "stare", "--frames", "2", "--out", str(missing / "s.h5")), 1, fix)
    refused(camctl(url, "scan", "--stages", "4", "--lines", "5", "--out", str(missing / "t.h5")),
            1, fix)  # fmt: skip
    for path in ("/api/v1/stream/acquire", "/api/v1/stream/start"):
        answer = httpx.post(url + path, json={"frames": 2, "record": str(missing / "s.h5")})
        assert answer.status_code == 400, answer.text
        assert answer.json()["code"] == "bad_request"
        assert fix in answer.json()["error"]
    assert tree(tmp_path) == []  # no directory was made
    assert httpx.get(url + "/api/v1/status").json()["state"] == "idle"


# -- camctl's arguments: one table ------------------------------------------------------------------

# (arguments, exit status, fragments of stderr). Status 2: camctl refused the value itself;
# 1: the daemon refused it (camctl passes its message on). Either way the device is unchanged.
CAMCTL_ROWS = [
    (["ping", "--count", "0"], 2, ["argument --count: must be from 1 to 100000, got 0"]),
    (["ping", "--size", "300"], 2, ["argument --size: must be from 0 to 256, got 300"]),
    (["ping", "--count", "abc"], 2, ["argument --count: 'abc' is not an integer"]),
    (["mode", "median"], 2, ["invalid choice: 'median' (choose from 'area', 'tdi')"]),
    (["reg", "write", "GAIN=-1"], 1, ["GAIN: -1 does not fit 16 bits (valid: 0 .. 0xFFFF)"]),
    (["reg", "write", "GAIN=70000"], 1, ["GAIN: 0x11170 (70000) does not fit 16 bits"]),
    (["reg", "write", "NOSUCH=1"], 1,
     ["hr400 has no register named 'NOSUCH'", "`camctl reg dump` lists them"]),
    (["reg", "write", "CHIP_ID=1"], 1, ["CHIP_ID (0x00) is read-only; it cannot be written"]),
    (["reg", "write", "GAIN"], 2, ["'GAIN' is not NAME=VALUE; e.g. WIN_ROWS=534"]),
    (["reg", "read", "NOSUCH"], 1, ["hr400 has no register named 'NOSUCH'"]),
    (["reg", "load", "{tmp}/none.toml"], 2,
     ["cannot read {tmp}/none.toml: No such file or directory",
      "give a file saved by `camctl reg save`"]),
    (["stage", "move", "nan"], 2, ["argument X: must be a finite number, got nan"]),
    (["stage", "run", "inf"], 2, ["argument X: must be a finite number, got inf"]),
    (["stage", "move", "5"], 1,
     ["position 5.0 m is outside the soft limits [0.0, 1.2] m",
      "widen stage.low_limit_m / high_limit_m"]),
    (["stage", "run", "11"], 1, ["speed_m_s: 11.0 is out of range; use a number in -10..10"]),
    (["stage", "move"], 2, ["stage move needs a value: the position in m from home"]),
    (["scan", "--stages", "0", "--lines", "5", "--out", "{tmp}/s.h5"], 2,
     ["--stages must be at least 1"]),
    (["scan", "--stages", "4", "--lines", "-1", "--out", "{tmp}/s.h5"], 2,
     ["argument --lines: '-1' is not a whole number >= 0"]),
    (["scan", "--stages", "4", "--rows-per-line", "inf", "--out", "{tmp}/s.h5"], 2,
     ["argument --rows-per-line: must be a finite number, got inf"]),
    (["stream", "--frames", "0"], 2,
     ["--frames must be at least 1 (use --start --frames 0 to stream on)"]),
    (["stare", "--frames", "-1", "--out", "{tmp}/s.h5"], 2,
     ["argument --frames: '-1' is not a whole number >= 0"]),
    # Files only inside the daemon's data directory and daemon.record_dirs (docs/api.md, Files).
    (["stare", "--frames", "2", "--out", "/etc/camd-never.h5"], 1,
     ["record '/etc/camd-never.h5' is outside the directories the daemon may write",
      "adds it to daemon.record_dirs in the daemon's config"]),
    (["stare", "--frames", "2", "--out", "../../../../../../../../../../etc/camd-never.h5"], 1,
     ["resolves to '/etc/camd-never.h5', outside the directories the daemon may write"]),
    (["scan", "--stages", "4", "--lines", "5", "--out", "/dev/shm/camd-never.h5"], 1,
     ["out '/dev/shm/camd-never.h5' is outside the directories the daemon may write"]),
    (["wheel", "acquire", "--channels", "1", "--out", "/root/camd-never.h5"], 1,
     ["record '/root/camd-never.h5' is outside the directories the daemon may write"]),
    (["campaign", "start", "example_stare", "--out", "/etc/camd-never"], 1,
     ["out '/etc/camd-never' is outside the directories the daemon may write"]),
    (["stare", "--frames", "2", "--out", "{tmp}/a\x1b[31mb.h5"], 1,
     ["holds the control character U+001B", "remove it"]),
    (["stare", "--frames", "2", "--out", "{tmp}/" + "x" * 256 + ".h5"], 1,
     ["each part of a path may be at most 255 bytes (NAME_MAX): shorten it"]),
    (["wheel", "speed", "-1"], 2, ["'-1' is not a speed in deg/s from 0 to 360"]),
    (["wheel", "speed", "400"], 2, ["'400' is not a speed in deg/s from 0 to 360"]),
    (["control", "take", "--ttl-s", "0"], 2, ["argument --ttl-s: must be > 0, got 0"]),
    (["sim", "scene", "nonsense"], 1,
     ["unknown scene kind 'nonsense'", "correct the scene spec (docs/simulator.md"]),
    (["sim", "stage-faults", "--load", "nan"], 2,
     ["argument --load: must be a finite number, got nan"]),
    (["stages", "0"], 2, ["stages must be at least 1"]),
    (["sync", "--speed-m-s", "0"], 1,
     ["speed_m_s: 0.0 is out of range; use null or a number more than 0 and at most 10"]),
    # issue 31: a unit written after the number, the limit that holds now, a stop of nothing
    (["stage", "move", "100mm"], 2,
     ["argument X: '100mm' is not a number: give the distance in metres, without a unit, e.g. "
      "0.1 for 100 mm"]),
    (["stage", "move", "0.3", "--speed-m-s", "5mm/s"], 2,
     ["argument --speed-m-s: '5mm/s' is not a number: give the speed in m/s, without a unit, "
      "e.g. 0.005 for 5 mm/s"]),
    (["stream", "--frames", "2", "--stages", "5000"], 1,
     ["stages: 5000 is out of range; use null or an integer in 0..4096; the sensor's window now "
      "has 534 rows, so at most 534 stages (M <= the window's rows"]),
    (["scan", "--stages", "5000", "--lines", "5", "--no-stage"], 1,
     ["stages: 5000 is out of range; use an integer in 1..4096; the sensor's window now has 534 "
      "rows, so at most 534 stages"]),
    (["scan", "--stop"], 1,
     ["nothing was running: no scan to stop (`camctl scan --status` shows the last one)"]),
    (["stream", "--stop"], 1,
     ["nothing was running: no stream to stop (`camctl stream --status` shows the last one)"]),
]  # fmt: skip


@pytest.mark.parametrize(
    ("args", "status", "fragments"),
    CAMCTL_ROWS,
    ids=["-".join(a.strip("-") for a in row[0][:3] if "{" not in a) for row in CAMCTL_ROWS],
)
def test_camctl_refuses_bad_arguments_and_changes_nothing(
    url: str, tmp_path: Path, args: list[str], status: int, fragments: list[str]
) -> None:
    with CamdClient(url, client="bad-input-cli", token="") as client:
        before = snapshot(client)
        proc = camctl(url, *(a.replace("{tmp}", str(tmp_path)) for a in args))
        refused(proc, status, *(f.replace("{tmp}", str(tmp_path)) for f in fragments))
        assert proc.stdout == ""  # nothing on stdout with an error
        assert snapshot(client) == before
    assert tree(tmp_path) == []  # no file made


# -- camd serve ----------------------------------------------------------------------------------


def serve(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "camd", "serve", "--sim", *args],
        cwd=REPO_ROOT, env={**camctl_env(), **NO_TOKEN}, capture_output=True, text=True,
        timeout=60, check=False,
    )  # fmt: skip


def test_serve_port_in_use_exits_2(tmp_path: Path) -> None:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        sock.listen()
        port = sock.getsockname()[1]
        proc = serve("--port", str(port), "--data-dir", str(tmp_path / "data"))
    refused(proc, 2, f"cannot listen on 127.0.0.1:{port}", "choose another with --port")
    assert len(proc.stderr.strip().splitlines()) == 1, proc.stderr
    assert proc.stdout == ""
    assert tree(tmp_path) == []  # refused before anything was made or spawned


@pytest.mark.parametrize("under", ["file", "proc"])
def test_serve_unusable_data_dir_exits_2(tmp_path: Path, under: str) -> None:
    (tmp_path / "F").write_text("")
    data = tmp_path / "F" / "data" if under == "file" else Path("/proc/camd-no-such/data")
    proc = serve("--port", "0", "--data-dir", str(data))
    refused(proc, 2, f"cannot use the data directory {data}", "choose another with --data-dir")
    assert len(proc.stderr.strip().splitlines()) == 1, proc.stderr
    assert proc.stdout == ""
    assert tree(tmp_path) == ["F"]


# -- issue 31: what the daemon says is printed as it is, never read as rich markup ------------------

MARKUP_LIKE = 'start the daemon with [sim] profile = "hr400" and [sensor] name = "hr400"'


def test_camctl_prints_bracketed_text_from_the_daemon_as_it_is() -> None:
    """rich took "[sim]" and "[sensor]" for markup and dropped them ("start the daemon with
    profile = ..."): every renderer that shows a text the daemon sent (a job's message, a
    reason, an event, a scan's error, a stream that ended early, a loop error) keeps them."""
    import argparse
    import io

    from rich.console import Console

    from camd.cli import camctl_campaign, camctl_format, camctl_scan, camctl_stream

    def shown(render: Any, *args: Any) -> str:
        buffer = io.StringIO()
        render(Console(file=buffer, width=400, highlight=False, soft_wrap=False), *args)
        return buffer.getvalue()

    job = {"id": 1, "campaign": "x[bold]y", "quick": False, "state": "error", "steps": 12,
           "done": None, "run_time_s": 2.0, "runs": 1, "started_by": "me", "out_dir": "/d",
           "message": MARKUP_LIKE, "report": None}  # fmt: skip
    event = {"t_s": 0.0, "level": "error", "source": "campaign", "message": MARKUP_LIKE}
    outputs = [
        shown(camctl_campaign._render_job, job),
        shown(lambda out: out.print(camctl_format.events_table({"events": [event]}))),
        shown(lambda out: out.print(camctl_format.cell(MARKUP_LIKE))),
    ]
    scan_doc = {"state": "failed", "lost_frames": 0, "stream": {"overruns": 0}, "lines": 1,
                "complete_lines": 1, "stages": 4, "mode": "sum", "width": 4, "timing": None,
                "lines_per_s": 1.0, "elapsed_s": 1.0, "cpu_load": 0.1, "tdi_cpu_s": 0.1,
                "mismatch_level": "ok", "mismatch_max": None, "mismatch_rms": None,
                "motion": {"stage_speed_m_s": 0.01, "closed_loop": True, "loop_samples": 1,
                           "loop_error": MARKUP_LIKE},
                "stage_changes": [[0, 4]], "file": "/d/s.h5", "quicklook": None,
                "error": MARKUP_LIKE}  # fmt: skip
    outputs.append(shown(camctl_scan.render_scan, scan_doc, argparse.Namespace()))
    stream_doc = {"mode": "area", "rows": 4, "cols": 4, "bits": 12, "binning": "off",
                  "stages": None, "frame_period_s": 1e-3, "streaming": False, "frames": 1,
                  "lost": 0, "corrupt": 0, "short": 0, "overruns": 0, "stalls": 0,
                  "mpix_per_s": 1.0, "mbyte_per_s": 1.0, "ended_early": MARKUP_LIKE}  # fmt: skip
    outputs.append(shown(camctl_stream.render_stream, stream_doc, argparse.Namespace()))
    for text in outputs:
        assert "[sim] profile" in text and "[sensor] name" in text, text
    assert "x[bold]y" in outputs[0], outputs[0]


# -- issue 31: a 1 MB bad value is quoted cut, wherever it was written -----------------------------

BIG = "x" * 1_000_000


def test_a_megabyte_value_in_a_campaign_or_register_file_is_quoted_cut(
    url: str, tmp_path: Path
) -> None:
    campaign = edited(tmp_path, lambda d: set_stare_frames(d, BIG))
    registers = tmp_path / "regs.toml"
    registers.write_text(f'sensor = "hr400"\n[registers]\nGAIN = "{BIG}"\n', encoding="utf-8")
    for args, fragment in (
        (["campaign", "run", str(campaign), "--out", str(tmp_path / "out"), "--quick"],
         f"{campaign}:35: steps[2] (id 'dark').stare.frames: 'xxxx"),
        (["reg", "load", str(registers)], f"{registers}:3: registers.GAIN = 'xxxx"),
    ):  # fmt: skip
        proc = camctl(url, *args)
        refused(proc, 2, fragment, "... (100000")  # 1000002 or 3 characters: with quotes
        assert len(proc.stderr) < 1000, len(proc.stderr)
    assert tree(tmp_path) == ["bad.yaml", "regs.toml"]


# -- issue 31: a campaign file's error names its line --------------------------------------------

LINED = """\
name: lines
profile: hr400
seed: 7
parameters:
  frames: 4
  photons: [2.0e+7, 8.0e+7]
steps:
  - id: dark
    kind: acquire
    stare:
      frames: 3
  - id: noise
    kind: measure
    function: dark_noise
    inputs: {frames: dark}
  - id: light
    kind: sweep
    parameter: photons
    values: "${photons}"
    steps:
      - id: scene
        kind: configure
        scene: "flat:photons=${photons}"
      - id: stare
        kind: acquire
        stare: {frames: "${frames}", stages: 1}
  - id: window
    kind: configure
    registers: {WIN_ROWS: 64}
"""
"""A valid campaign whose line numbers the cases below name (line 11: ``frames: 3``)."""


def test_the_lined_campaign_is_valid(tmp_path: Path) -> None:
    from camd.campaign.checks import check_campaign
    from camd.campaign.loading import load_campaign

    path = tmp_path / "lines.yaml"
    path.write_text(LINED, encoding="utf-8")
    check_campaign(load_campaign(path), path, quick=False)


STARE_KEYS = "frames, mode, stages, binning, timeout_s"


@pytest.mark.parametrize(
    ("old", "new", "expected"),
    [
        ("      frames: 3", "      frame: 3",
         "11: steps[0] (id 'dark').stare.frame: unknown key; did you mean `frames`?; known "
         f"keys: {STARE_KEYS}"),
        ("seed: 7", 'seed: "7"',
         "3: seed: '7' is a string, the wrong type; write an integer, without quotes"),
        ("stages: 1}", 'stages: "1"}',
         "26: steps[2] (id 'light').steps[1] (id 'stare').stare.stages: '1' is a string, the "
         "wrong type; write an integer, without quotes (or a ${name} reference)"),
        ("    function: dark_noise\n", "",
         "12: steps[1] (id 'noise').function: missing key; add `function: ...`"),
        ("profile: hr400\n", "", "1: profile: missing key; add `profile: ...`"),
        ("stages: 1}", "stages: 5000}",
         "26: steps[2] (id 'light').steps[1] (id 'stare').stare.stages: 5000 is out of range; "
         "allowed: 1 <= stages <= 4096"),
        ("  - id: dark\n    kind: acquire\n", "  - id: dark\n    kind: acquir\n",
         "9: steps[0] (id 'dark').kind: 'acquir' is not a step kind; give one of configure, "
         "sweep, acquire, measure, check"),
        ("    kind: measure\n", "",
         "12: steps[1] (id 'noise').kind: missing key; add `kind: ...`, one of configure, "
         "sweep, acquire, measure, check"),
        ("inputs: {frames: dark}", "inputs: {frames: dark",
         "16: not valid YAML: expected ',' or '}', but got ':' (while parsing a flow mapping "
         "begun on line 15)"),
        # A key given twice: YAML keeps the last silently, TOML refuses it; so does camd.
        ("  photons: [2.0e+7, 8.0e+7]\n", "  photons: [2.0e+7, 8.0e+7]\n  frames: 5\n",
         "7: not valid YAML: the key 'frames' is given twice (first on line 5); keep one"),
        # What the schema cannot say, checked after it: the line of the key too.
        ("function: dark_noise", "function: dark_nois",
         "14: steps[1] (id 'noise'): function: unknown measurement 'dark_nois'; known: "
         "bar_resolution, dark_noise, "),
        ("inputs: {frames: dark}", "inputs: {frames: noise}",
         "15: steps[1] (id 'noise'): inputs.frames: 'noise' is not the id of an acquire step"),
        ('{frames: "${frames}"', '{frames: "${frame}"',
         "26: steps[2] (id 'light').steps[1] (id 'stare'): stare: ${frame} is neither a "
         "parameter, an enclosing sweep's parameter nor a result declared before it (known: "
         "frames, photons)"),
        ("  - id: window", "  - id: dark",
         "27: steps[3] (id 'dark'): id 'dark' already used by steps[0] (id 'dark')"),
        ("{WIN_ROWS: 64}", "{WIN_ROW: 64}",
         "29: steps[3] (id 'window'): registers.WIN_ROW: hr400 has no register named 'WIN_ROW'"),
        ("{WIN_ROWS: 64}", "{WIN_ROWS: 100000}",
         "29: steps[3] (id 'window'): registers.WIN_ROWS: WIN_ROWS.rows: 100000 is out of range "
         "(valid: 1 .. 2048 (1 .. 2048 row))\nnothing was done"),
        # ... and with the parameters substituted: the line of the key that uses the parameter.
        ("  frames: 4", "  frames: 0",
         "26: steps[2] (id 'light').steps[1] (id 'stare') with photons = 2e+07: stare.frames: 0 "
         "is out of range; allowed: 1 <= frames <= 4294967295\nnothing was done: correct the "
         "campaign's parameters (or their quick overrides) that this step uses"),
    ],
    ids=["typo", "wrong-type", "wrong-type-deep", "missing-key", "missing-top-level-key",
         "out-of-range-deep", "unknown-kind", "missing-kind", "yaml-syntax", "repeated-key", "unknown-function",
         "input-not-acquired", "unknown-reference", "repeated-id", "unknown-register",
         "register-value", "parameter-out-of-range"],
)  # fmt: skip
def test_a_campaign_error_names_its_line(tmp_path: Path, old: str, new: str, expected: str) -> None:
    """Each error starts ``file:LINE:`` with the line of the key (of the mapping a missing key
    belongs in), names the step and says what to write; camctl prints that one line, exit 2."""
    from camd.campaign.checks import check_campaign
    from camd.campaign.loading import load_campaign
    from camd.campaign.spec import CampaignError

    assert LINED.count(old) == 1
    bad = tmp_path / "bad.yaml"
    bad.write_text(LINED.replace(old, new), encoding="utf-8")
    with pytest.raises(CampaignError) as info:
        check_campaign(load_campaign(bad), bad, quick=False)
    message = str(info.value)
    assert message.startswith(f"{bad}:{expected}"), message
    assert message.count("\n") == expected.count("\n"), message  # one line, and what to do
    proc = camctl(NO_DAEMON, "campaign", "run", str(bad), "--out", str(tmp_path / "out"))
    refused(proc, 2)
    assert proc.stderr == f"camctl: error: {message}\n", proc.stderr
    assert tree(tmp_path) == ["bad.yaml"]


def test_the_documented_campaign_errors_are_what_load_campaign_says(tmp_path: Path) -> None:
    """docs/campaigns.md shows the errors of example_stare.yaml with one mistake each."""
    from camd.campaign.loading import load_campaign
    from camd.campaign.spec import CampaignError

    docs = (Path(REPO_ROOT) / "docs" / "campaigns.md").read_text(encoding="utf-8")
    documented = [
        line.strip() for line in docs.splitlines() if line.startswith("    campaign.yaml:")
    ]
    text = EXAMPLE.read_text(encoding="utf-8")
    mistakes = [
        ('stare: {frames: "${frames}"}\n      - id: stats',
         'stare: {frame: "${frames}"}\n      - id: stats'),
        ("seed: 7", 'seed: "7"'),
        ("    function: dark_noise\n", ""),
        ("inputs: {frames: dark}", "inputs: {frames: dark"),
    ]  # fmt: skip
    said = []
    for old, new in mistakes:
        assert text.count(old) == 1, old
        path = tmp_path / "campaign.yaml"
        path.write_text(text.replace(old, new), encoding="utf-8")
        with pytest.raises(CampaignError) as info:
            load_campaign(path)
        said.append(str(info.value).replace(f"{tmp_path}/", ""))
    assert said == documented
