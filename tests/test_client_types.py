"""camd/client_types.py: generated from the API's pydantic models, and true to the daemon.

- the committed file is what ``python -m camd.daemon.client_types_gen`` renders now, passes the
  linters unchanged and imports nothing of camd;
- every ``response_model`` of the FastAPI app (and every model nested in one) has a TypedDict of
  the same name with exactly the JSON keys of the model's serialisation schema;
- the answers of a real daemon (``camd serve --sim`` on loopback, driven through ``CamdClient``)
  have exactly the keys of their TypedDict, recursively, with values of the declared types; and
  between them they show every TypedDict of the module.
"""

from __future__ import annotations

import ast
import datetime
import shutil
import subprocess
import sys
import time
import types
import typing
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, Literal, Union

import fastapi.routing
import httpx
import pytest
from fastapi.routing import APIRoute
from pydantic import BaseModel, ConfigDict, Field, computed_field

import camd.client_types as client_types
from camd.client import CamdClient
from camd.daemon.api import create_app
from camd.daemon.client_types_gen import COMMAND, ClientTypesError, main, render_client_types
from camd.daemon.config import Config
from camd.daemon.session import DeviceSession
from tests.test_sensor_stack import serve

ROOT = Path(__file__).resolve().parents[1]
GENERATED = ROOT / "camd" / "client_types.py"


def typed_dicts() -> dict[str, type]:
    return {
        name: value
        for name, value in vars(client_types).items()
        if isinstance(value, type) and typing.is_typeddict(value)
    }


# -- the generated file -----------------------------------------------------------------------------


def test_generated_file_is_up_to_date(capsys: pytest.CaptureFixture[str]) -> None:
    status = main(["--check"])
    assert status == 0, capsys.readouterr().err
    assert GENERATED.read_text(encoding="utf-8") == render_client_types()


def test_check_mode_says_which_command_to_run(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "client_types.py"
    assert main(["--check", "--output", str(out)]) == 1
    assert f"{out} is missing: run `{COMMAND}`" in capsys.readouterr().err
    assert main(["--output", str(out)]) == 0
    assert out.read_text(encoding="utf-8") == GENERATED.read_text(encoding="utf-8")
    assert main(["--check", "--output", str(out)]) == 0
    out.write_text(out.read_text(encoding="utf-8").replace("    pid: int\n", ""), encoding="utf-8")
    assert main(["--check", "--output", str(out)]) == 1
    assert f"{out} is stale: run `{COMMAND}`" in capsys.readouterr().err


def test_command_line_check_passes() -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "camd.daemon.client_types_gen", "--check"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 0, proc.stderr
    assert "is up to date" in proc.stdout


def test_header_names_the_source_and_the_command() -> None:
    head = GENERATED.read_text(encoding="utf-8")[:1200]
    assert "camd/daemon/models/" in head
    assert COMMAND in head
    assert client_types.StatusResponse.__doc__ == "GET /api/v1/status and POST /api/v1/reset."


# camd/client_requests.py (tests/test_client_requests.py) is generated the same way, for the same
# client: the same two checks hold for it.
GENERATED_FILES = [GENERATED, ROOT / "camd" / "client_requests.py"]


@pytest.mark.skipif(shutil.which("ruff") is None, reason="ruff is not installed")
@pytest.mark.parametrize("generated", GENERATED_FILES, ids=lambda p: p.name)
def test_generated_file_passes_ruff_unchanged(generated: Path) -> None:
    ruff = shutil.which("ruff")
    assert ruff is not None
    for args in (["format", "--check"], ["check"]):
        proc = subprocess.run(
            [ruff, *args, str(generated)], cwd=ROOT, capture_output=True, text=True, timeout=60
        )
        assert proc.returncode == 0, (args, proc.stdout, proc.stderr)


@pytest.mark.parametrize("generated", GENERATED_FILES, ids=lambda p: p.name)
def test_client_types_imports_nothing_of_camd(generated: Path) -> None:
    # The client sits below the daemon: loading the shapes must not load camd.daemon.
    imported = set()
    for node in ast.walk(ast.parse(generated.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            imported |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom):
            imported.add(node.module or "")
    assert imported == {"__future__", "typing"}
    proc = subprocess.run(
        [
            sys.executable,
            "-c",
            "import sys, camd.client; "
            "print(sorted(m for m in sys.modules if m.startswith('camd.daemon') or m == 'pydantic'))",
        ],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "[]"


class _Inner(BaseModel):
    """An inner document.

    Only the first paragraph is kept."""

    n: int


class _Aliased(BaseModel):
    model_config = ConfigDict(populate_by_name=True)

    plain: Literal[1, 2] | None
    renamed: str = Field(alias="renamedKey", description="emitted under its alias")
    out_only: float = Field(serialization_alias="outKey")
    hidden: int = Field(default=0, exclude=True)
    pair: tuple[int, float]
    many: tuple[str, ...]
    by_number: dict[int, _Inner]
    inner: list[_Inner] | None

    @computed_field  # type: ignore[prop-decorator]
    @property
    def total(self) -> int:
        return self.hidden + 1


def test_rendered_keys_are_the_keys_pydantic_emits_by_alias(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # Features the API's models do not use yet: aliases, excluded and computed fields, tuples,
    # non-string dict keys, integer literals. The rendered module is loaded as a module.
    text = render_client_types([_Inner, _Aliased])
    module = types.ModuleType("client_types_example")
    monkeypatch.setitem(sys.modules, module.__name__, module)
    exec(compile(text, "client_types_example.py", "exec"), module.__dict__)
    namespace = module.__dict__
    doc = _Aliased.model_validate(
        {
            "plain": 2,
            "renamedKey": "x",
            "out_only": 1.5,
            "pair": (1, 2.5),
            "many": ("a",),
            "by_number": {3: {"n": 4}},
            "inner": [{"n": 5}],
        }
    ).model_dump(mode="json", by_alias=True)
    assert set(doc) == {
        "plain",
        "renamedKey",
        "outKey",
        "pair",
        "many",
        "by_number",
        "inner",
        "total",
    }
    typed = namespace["_Aliased"]
    assert mismatches(doc, typed, "doc", seen := set()) == []
    assert seen == {"_Aliased", "_Inner"}
    assert typed.__required_keys__ == set(doc)
    hints = typing.get_type_hints(typed)
    assert hints["pair"] == list[int | float] and hints["many"] == list[str]
    assert hints["by_number"] == dict[str, namespace["_Inner"]]
    assert namespace["_Inner"].__doc__ == "An inner document."
    assert "    # emitted under its alias\n    renamedKey: str\n" in text


def test_a_type_json_cannot_carry_is_refused() -> None:
    class Stamped(BaseModel):
        at: datetime.datetime

    with pytest.raises(ClientTypesError, match=r"Stamped\.at: cannot express"):
        render_client_types([Stamped])


# -- the app's response models ----------------------------------------------------------------------


@pytest.fixture(scope="module")
def routes(tmp_path_factory: pytest.TempPathFactory) -> list[APIRoute]:
    """The routes of the app ``camd serve`` builds (its session is never started)."""
    data_dir = tmp_path_factory.mktemp("camd-app")
    session = DeviceSession(Config.model_validate({"daemon": {"data_dir": str(data_dir)}}))
    app = create_app(session)
    # FastAPI from 0.137 keeps an included router as one entry of app.routes; its
    # iter_route_contexts (0.137.2) lists the routes inside.
    flatten = getattr(fastapi.routing, "iter_route_contexts", None)
    found = [c.original_route for c in flatten(app.routes)] if flatten else app.routes
    return [r for r in found if isinstance(r, APIRoute)]


def json_keys(model: type[BaseModel], by_alias: bool = True) -> dict[str, set[str]]:
    """Model name -> the JSON keys of its serialisation, for the model and every nested one."""
    schema = model.model_json_schema(mode="serialization", by_alias=by_alias)
    out = {model.__name__: set(schema["properties"])}
    for name, sub in schema.get("$defs", {}).items():
        out[name] = set(sub["properties"])
    return out


def test_the_app_has_response_models(routes: list[APIRoute]) -> None:
    models = {r.response_model for r in routes if r.response_model is not None}
    assert len(routes) > 40 and len(models) > 25
    assert client_types.ScanResponse.__name__ in {m.__name__ for m in models}


def test_every_response_model_has_its_typed_dict(routes: list[APIRoute]) -> None:
    typed = typed_dicts()
    checked: set[str] = set()
    for route in routes:
        model = route.response_model
        if model is None:
            continue
        where = f"{sorted(route.methods)} {route.path} ({model.__name__})"
        # Every key is emitted (none excluded as unset, default or None), by alias: what the
        # TypedDicts say by declaring every key required under its JSON name.
        assert route.response_model_by_alias, where
        assert not route.response_model_exclude_unset, where
        assert not route.response_model_exclude_defaults, where
        assert not route.response_model_exclude_none, where
        for name, keys in json_keys(model, route.response_model_by_alias).items():
            assert name in typed, f"{where}: camd.client_types has no {name}; run `{COMMAND}`"
            td = typed[name]
            assert set(td.__annotations__) == keys, (where, name)
            assert td.__required_keys__ == keys, (where, name)
            checked.add(name)
    assert {"StatusResponse", "DeviceStatus", "ScanTiming", "WheelFrame"} <= checked


def test_the_client_returns_the_generated_types() -> None:
    hints = typing.get_type_hints(CamdClient.status)
    assert hints["return"] is client_types.StatusResponse
    assert typing.get_type_hints(CamdClient.sim_settings)["return"] is client_types.SimSettings


# -- a real daemon's answers ------------------------------------------------------------------------


def mismatches(value: Any, annotation: Any, path: str, seen: set[str]) -> list[str]:
    """What in ``value`` (decoded JSON) does not fit ``annotation`` (a TypedDict or a field
    type of one); the TypedDicts met with a value are added to ``seen``."""
    if typing.is_typeddict(annotation):
        if not isinstance(value, dict):
            return [f"{path}: expected a {annotation.__name__} object, got {value!r}"]
        seen.add(annotation.__name__)
        hints = typing.get_type_hints(annotation)
        problems = []
        missing = annotation.__required_keys__ - set(value)
        extra = set(value) - set(hints)
        if missing or extra:
            problems.append(
                f"{path} ({annotation.__name__}): missing {sorted(missing)}, extra {sorted(extra)}"
            )
        for key, hint in hints.items():
            if key in value:
                problems += mismatches(value[key], hint, f"{path}.{key}", seen)
        return problems
    origin, args = typing.get_origin(annotation), typing.get_args(annotation)
    if origin in (Union, types.UnionType):
        for arg in args:
            trial: set[str] = set()
            if not mismatches(value, arg, path, trial):
                seen |= trial
                return []
        return [f"{path}: {value!r} is none of {annotation}"]
    if origin is Literal:
        return [] if value in args else [f"{path}: {value!r} is not one of {args}"]
    if origin is list:
        if not isinstance(value, list):
            return [f"{path}: expected a list, got {value!r}"]
        return [
            p for i, v in enumerate(value) for p in mismatches(v, args[0], f"{path}[{i}]", seen)
        ]
    if origin is dict:
        if not isinstance(value, dict) or not all(isinstance(k, str) for k in value):
            return [f"{path}: expected an object, got {value!r}"]
        return [p for k, v in value.items() for p in mismatches(v, args[1], f"{path}.{k}", seen)]
    fits: dict[Any, Callable[[Any], bool]] = {
        type(None): lambda v: v is None,
        bool: lambda v: isinstance(v, bool),
        int: lambda v: isinstance(v, int) and not isinstance(v, bool),
        float: lambda v: isinstance(v, int | float) and not isinstance(v, bool),
        str: lambda v: isinstance(v, str),
        Any: lambda v: True,
    }
    if annotation not in fits:
        return [f"{path}: the test does not know the type {annotation!r}"]
    return [] if fits[annotation](value) else [f"{path}: {value!r} is not a {annotation}"]


# (label, TypedDict) of each answer below, in the order the daemon is driven.
ANSWERS: list[tuple[str, str]] = [
    ("take_control", "ControlInfo"),
    ("set_activity", "ControlInfo"),
    ("ping", "PingResponse"),
    ("link", "LinkResponse"),
    ("telemetry", "TelemetryResponse"),
    ("history", "HistoryResponse"),
    ("set_mode", "ModeResponse"),
    ("registers", "RegistersResponse"),
    ("read_register", "RegisterReading"),
    ("write_registers", "RegisterWriteResponse"),
    ("diff_registers", "RegisterDiffResponse"),
    ("register_config", "RegisterConfig"),
    ("load_register_config", "RegisterWriteResponse"),
    ("timing", "TimingResponse"),
    ("train", "TrainResponse"),
    ("acquire", "StreamResponse"),
    ("stream_headers", "StreamHeadersResponse"),
    ("link_command", "LinkCommandResponse"),
    ("background", "BackgroundStatus"),
    ("add_roi", "RoiList"),
    ("roi_stats", "RoiStatsResponse"),
    ("focus", "FocusResponse"),
    ("delete_roi", "RoiList"),
    ("live_pixel", "LivePixel"),
    ("save_snapshot", "SnapshotSaved"),
    ("scan", "ScanResponse"),
    ("image_motion", "ImageMotionResponse"),
    ("image_loop_scan", "ScanResponse"),
    ("motion", "MotionStatus"),
    ("move_stage", "MotionStatus"),
    ("sync", "SyncResponse"),
    ("stage_truth", "SimStageTruth"),
    ("set_stage", "StageResponse"),
    ("wheel", "WheelStatus"),
    ("wheel_acquire", "WheelAcquireResponse"),
    ("sim_settings", "SimSettings"),
    ("sim_stream_stats", "SimStreamStats"),
    ("events", "EventsResponse"),
    ("status", "StatusResponse"),
    ("estop", "EstopResponse"),
    ("estop_state", "EstopState"),
    ("release_estop", "EstopState"),
    ("release_control", "ControlInfo"),
    ("campaign_job", "CampaignJob"),
    ("campaign_jobs", "CampaignJobsResponse"),
    ("error", "ErrorResponse"),
]


@pytest.fixture(scope="module")
def answers(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, Any]]:
    """The JSON answers of a real daemon on the simulated camera, by label (ANSWERS)."""
    tmp = tmp_path_factory.mktemp("camd-client-types")
    docs: dict[str, Any] = {}
    with serve(tmp, "fpga") as daemon, CamdClient(daemon.url, timeout_s=60) as client:
        docs["take_control"] = client.take_control(120)
        docs["set_activity"] = client.set_activity("checking the client types", 1, 2)
        docs["ping"] = client.ping(count=5)
        docs["link"] = client.link()
        docs["telemetry"] = client.telemetry()
        channel = sorted(docs["telemetry"]["latest"])[0]
        docs["history"] = client.history(channel, limit=5)
        docs["set_mode"] = client.set_mode("area")
        before = client.register_config()
        docs["registers"] = client.registers()
        docs["read_register"] = client.read_register("WIN_ROWS")
        docs["write_registers"] = client.write_registers({"WIN_ROWS": 64})
        docs["diff_registers"] = client.diff_registers()
        docs["register_config"] = client.register_config()
        docs["load_register_config"] = client.load_register_config(before)
        docs["timing"] = client.timing()
        docs["train"] = client.train()
        docs["acquire"] = client.acquire(3, timeout_s=60)
        docs["stream_headers"] = client.stream_headers()
        docs["link_command"] = client.link_command("SET_MODE", fields={"mode": "area"}, repeat=True)
        docs["add_roi"] = client.add_roi("dark", 0, 0, 4, 4)
        client.start_stream(0)
        client.capture_background(2)
        deadline = time.monotonic() + 30
        while client.background()["state"] == "capturing" and time.monotonic() < deadline:
            time.sleep(0.05)
        # The focus aid measures once asked (a figure of the frame and of the ROI, and a best).
        while client.focus()["latest"] is None and time.monotonic() < deadline:
            time.sleep(0.05)
        client.stop_stream()
        docs["background"] = client.background()
        docs["roi_stats"] = client.roi_stats(history=3)
        docs["focus"] = client.focus(history=3)
        docs["live_pixel"] = client.live_pixel(0, 0)
        docs["save_snapshot"] = client.save_snapshot()  # of the stream's last live frame
        docs["delete_roi"] = client.delete_roi("dark")
        client.start_scan(4, 20, out=str(tmp / "scan.h5"), quicklook=False)
        docs["scan"] = client.wait_scan(120)
        docs["motion"] = client.motion()
        docs["move_stage"] = client.move_stage(0.61)  # with its operation (docs/motion.md)
        docs["sync"] = client.sync()
        docs["stage_truth"] = client.stage_truth()
        docs["set_stage"] = client.set_stage(track=True)
        docs["wheel"] = client.wheel()
        region = client_types.WheelRegion(row=0, rows=4, col=0, cols=8)
        docs["wheel_acquire"] = client.wheel_acquire([0, 1], region=region, timeout_s=60)
        docs["sim_settings"] = client.sim_settings()
        docs["sim_stream_stats"] = client.sim_stream_stats()
        docs["events"] = client.events(limit=20)
        docs["status"] = client.status()
        docs["estop"] = client.estop()
        docs["estop_state"] = client.estop_state()
        docs["release_estop"] = client.release_estop()
        docs["release_control"] = client.release_control()
        # The image motion monitor's first block: 16 consecutive frames of a 20-row window
        # (0.41 ms is 20 row times of hr400; the simulator's ideal stage keeps up with it),
        # with the image loop (its state in the scan's document).
        client.start_scan(
            4, 40, quicklook=False, line_period_s=4.1e-4, drive_stage=False, image_loop=True
        )
        client.wait_scan(120)
        docs["image_motion"] = client.image_motion(history=2)
        docs["image_loop_scan"] = client.scan()
        # A campaign job (a short plan), followed to its end: its document then has them all.
        job = client.start_campaign("example_stare", quick=True)
        deadline = time.monotonic() + 120
        while job["state"] in ("running", "pausing", "aborting") and time.monotonic() < deadline:
            time.sleep(0.1)
            job = client.campaign_job(job["id"])
        docs["campaign_job"] = job
        docs["campaign_jobs"] = client.campaign_jobs()
        error = httpx.post(f"{daemon.url}/api/v1/ping", json={"count": 0}, timeout=30)
        assert error.status_code == 400
        docs["error"] = error.json()
        yield docs
    assert daemon.exit_code in (0, -15), daemon.log_path.read_text()


@pytest.mark.parametrize(("label", "name"), ANSWERS, ids=[label for label, _ in ANSWERS])
def test_answer_has_exactly_the_keys_and_types_of_its_typed_dict(
    answers: dict[str, Any], label: str, name: str
) -> None:
    problems = mismatches(answers[label], getattr(client_types, name), label, set())
    assert not problems, "\n".join(problems)


def test_the_answers_reach_the_nested_documents(answers: dict[str, Any]) -> None:
    # The nested optional documents were really there, so the walk above checked them.
    assert answers["status"]["device"] is not None
    assert answers["status"]["acquisition"] is not None
    assert answers["status"]["acquisition"]["kind"] == "wheel"
    assert answers["scan"]["state"] == "done"
    assert answers["scan"]["timing"] is not None and answers["scan"]["motion"] is not None
    assert answers["scan"]["stage_changes"] == [[0, 4]]  # a tuple in the model, a list in JSON
    assert answers["link"]["device"] is not None
    assert len(answers["stream_headers"]["frames"]) == 3
    assert [a["type"] for a in answers["link_command"]["answers"]] == ["ack", "ack"]
    assert answers["write_registers"]["written"][0]["name"] == "WIN_ROWS"
    assert "WIN_ROWS" in {d["name"] for d in answers["diff_registers"]["differences"]}
    assert answers["wheel_acquire"]["region"] == {"row": 0, "rows": 4, "col": 0, "cols": 8}
    assert len(answers["wheel_acquire"]["frames"]) == 2
    assert answers["error"]["code"] == "bad_request"
    assert answers["background"]["state"] == "ready"
    assert answers["move_stage"]["operation"]["kind"] == "move"


def test_the_answers_show_every_typed_dict(answers: dict[str, Any]) -> None:
    seen: set[str] = set()
    for label, name in ANSWERS:
        mismatches(answers[label], getattr(client_types, name), label, seen)
    assert seen == set(typed_dicts()), f"never seen in an answer: {set(typed_dicts()) - seen}"


def test_each_error_status_lists_every_code_it_carries() -> None:
    """OpenAPI's description of a route's 409 (or 503 ...) names every code the daemon answers
    with that status: one per status overwrote the others (409 said only no_control)."""
    from camd.daemon.api_errors import ERROR_MAP
    from camd.daemon.api_errors import ERROR_RESPONSES as _ERROR_RESPONSES

    for _, status, code in ERROR_MAP:
        assert code in _ERROR_RESPONSES[status]["description"].split(", "), (status, code)
    assert _ERROR_RESPONSES[409]["description"].startswith("illegal_state, link_untrained")
