"""camd/client_requests.py: the request models' optional keys, typing the client's keyword
arguments, so that a request's defaults are written once (in the model).

- the committed file is what ``python -m camd.daemon.client_requests_gen`` renders now (that it
  passes the linters unchanged and imports nothing of camd: tests/test_client_types.py);
- ``ScanRequestOptions`` has exactly ``ScanRequest``'s optional fields, and
  ``CamdClient.start_scan`` takes its required fields and those options, with no default of its
  own. It sends only what it was given and the daemon's model fills in the rest: the scans of
  tests/test_client_types.py, test_live_lines.py and the campaign tests run on those defaults;
- the same for every method of ``CLIENT_REQUESTS`` (every client method that sends a request
  model with defaults): its options are its model's optional keys but those it takes as
  parameters of its own, whose default is ``UNSET`` (not sent), of the model's type; no parameter
  repeats a default; every request model with a default is listed there or below, with why not;
- on the wire (a loopback HTTP server that records what it is sent): each method sends only the
  keys it is given, and the daemon's model reads that body as it read the old client's, which
  wrote every default out.
"""

from __future__ import annotations

import inspect
import json
import threading
import typing
from collections.abc import Callable, Iterator
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any, ClassVar

import pytest
from pydantic import BaseModel

import camd.client_requests as client_requests
import camd.daemon.models as api_models
from camd.client import CamdClient
from camd.daemon.client_requests_gen import (
    CLIENT_REQUESTS,
    COMMAND,
    ClientRequest,
    main,
    optional_fields,
    render_client_requests,
)
from camd.daemon.client_types_gen import render_type
from camd.daemon.models import (
    MotionHomeRequest,
    RegisterDiffRequest,
    ScanRequest,
    SnapshotRequest,
    WheelRegion,
)
from camd.daemon.models.common import _Request

ROOT = Path(__file__).resolve().parents[1]
GENERATED = ROOT / "camd" / "client_requests.py"

# Request models with defaults that no method of CLIENT_REQUESTS sends as options, and why.
NOT_CONVERTED: dict[type[BaseModel], str] = {
    RegisterDiffRequest: "diff_registers(values) says 'values' when given values, else 'reset'",
    MotionHomeRequest: "its one key, wait: the client always asks for an answer at once (false)",
    WheelRegion: "held by WheelAcquireRequest.region, which wheel_acquire passes whole",
    SnapshotRequest: "its one key, seq: save_snapshot(seq) takes it as its argument",
}

# Parameters with a default of the converted methods that are no key of their request (or, for
# move_stage's wait, not that key): the client's own.
CLIENT_SIDE: dict[tuple[str, str], str] = {
    ("link_command", "payload"): "bytes, sent as payload_hex",
    ("move_stage", "wait"): "the client polls GET /motion until the stage stands",
    ("move_stage", "progress"): "called with each motion document polled",
}


def test_generated_file_is_up_to_date(capsys: pytest.CaptureFixture[str]) -> None:
    status = main(["--check"])
    assert status == 0, capsys.readouterr().err
    assert GENERATED.read_text(encoding="utf-8") == render_client_requests()


def test_check_mode_says_which_command_to_run(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "client_requests.py"
    assert main(["--check", "--output", str(out)]) == 1
    assert f"{out} is missing: run `{COMMAND}`" in capsys.readouterr().err
    assert main(["--output", str(out)]) == 0
    assert out.read_text(encoding="utf-8") == GENERATED.read_text(encoding="utf-8")


def test_scan_options_are_the_scan_requests_optional_fields() -> None:
    options = client_requests.ScanRequestOptions
    optional = [name for name, f in ScanRequest.model_fields.items() if not f.is_required()]
    assert list(typing.get_type_hints(options)) == optional
    assert len(optional) == 17  # compression and compression_level since issue 33, image_loop 35
    assert not options.__required_keys__


def test_start_scan_writes_no_default_of_its_own() -> None:
    # CamdClient.start_scan used to repeat ScanRequest's 14 defaults by hand.
    parameters = inspect.signature(CamdClient.start_scan).parameters
    assert list(parameters) == ["self", "stages", "lines", "options"]
    assert all(p.default is inspect.Parameter.empty for p in parameters.values())
    assert parameters["options"].kind is inspect.Parameter.VAR_KEYWORD
    required = [name for name, f in ScanRequest.model_fields.items() if f.is_required()]
    assert required == ["stages", "lines"]


def test_every_request_model_with_a_default_is_sent_by_a_listed_method() -> None:
    requests = {
        model
        for name in dir(api_models)
        if isinstance(model := getattr(api_models, name), type)
        and issubclass(model, _Request)
        and model is not _Request
    }
    with_defaults = {model for model in requests if optional_fields(model)}
    listed = {request.model for request in CLIENT_REQUESTS}
    assert with_defaults - listed == set(NOT_CONVERTED)
    assert len(listed) == 15


REQUEST_METHODS = [(request, method) for request in CLIENT_REQUESTS for method in request.methods]
MODEL_OF = {method: request.model for request, method in REQUEST_METHODS}


@pytest.mark.parametrize("request_", CLIENT_REQUESTS, ids=lambda r: r.options_name)
def test_options_are_the_optional_keys_the_method_does_not_take_itself(
    request_: ClientRequest,
) -> None:
    optional = [key for key, _ in optional_fields(request_.model)]
    expected = [k for k in optional if k not in request_.own and k not in request_.not_taken]
    options = getattr(client_requests, request_.options_name, None)
    if not expected:
        assert options is None
        return
    assert options is not None, f"camd/client_requests.py has no {request_.options_name}"
    assert list(typing.get_type_hints(options)) == expected
    assert not options.__required_keys__


def union_members(annotation: str) -> set[str]:
    """The members of a union written as text, ``a | b[c | d]`` -> {a, b[c | d]}."""
    members, depth, start = [], 0, 0
    for i, char in enumerate(annotation):
        depth += {"[": 1, "]": -1}.get(char, 0)
        if char == "|" and depth == 0:
            members.append(annotation[start:i])
            start = i + 1
    return {m.strip() for m in [*members, annotation[start:]]}


@pytest.mark.parametrize(
    ("request_", "method"), REQUEST_METHODS, ids=[m for _, m in REQUEST_METHODS]
)
def test_method_writes_no_default_of_its_own(request_: ClientRequest, method: str) -> None:
    fields = {info.alias or name: info for name, info in request_.model.model_fields.items()}
    parameters = inspect.signature(getattr(CamdClient, method)).parameters
    options = [p for p in parameters.values() if p.kind is inspect.Parameter.VAR_KEYWORD]
    if request_.options():
        assert [p.annotation for p in options] == [f"Unpack[{request_.options_name}]"]
    else:
        assert options == []
    for name, parameter in parameters.items():
        if name == "self" or parameter.kind is inspect.Parameter.VAR_KEYWORD:
            continue
        if name not in fields or name in request_.not_taken:
            # A key of the path (a job's id) or the client's own, listed above.
            if parameter.default is not inspect.Parameter.empty:
                assert (method, name) in CLIENT_SIDE, f"{method}({name}=...) is no request key"
            continue
        info = fields[name]
        if info.is_required():
            assert parameter.default is inspect.Parameter.empty, (method, name)
            continue
        # An optional key of its own: not sent unless given (acquire's frames: always given).
        assert name in request_.own, (method, name)
        assert parameter.default is inspect.Parameter.empty or repr(parameter.default) == "UNSET"
        # Of the model's type (and Unset, when it may be left out).
        rendered = union_members(render_type(info.annotation, name))
        if parameter.default is not inspect.Parameter.empty:
            rendered.add("Unset")
        assert union_members(parameter.annotation) == rendered, (method, name)
    taken = {n for n in parameters if n in fields} | set(request_.not_taken)
    missing = [k for k in request_.own if k not in taken]
    assert missing == (["payload_hex"] if method == "link_command" else [])


# -- on the wire --------------------------------------------------------------------------------


class _Recorder(BaseHTTPRequestHandler):
    """Answers every request with ``{}`` and records (method, path, JSON body)."""

    seen: ClassVar[list[tuple[str, str, Any]]] = []

    def _answer(self) -> None:
        length = int(self.headers.get("Content-Length") or 0)
        raw = self.rfile.read(length) if length else b""
        self.seen.append((self.command, self.path, json.loads(raw) if raw else None))
        body = b"{}"
        self.send_response(200)
        self.send_header("Content-Type", "application/json")
        self.send_header("Content-Length", str(len(body)))
        self.end_headers()
        self.wfile.write(body)

    do_GET = do_POST = do_PUT = do_DELETE = _answer

    def log_message(self, format: str, *args: Any) -> None:
        pass


@pytest.fixture(scope="module")
def recorder() -> Iterator[tuple[CamdClient, list[tuple[str, str, Any]]]]:
    server = ThreadingHTTPServer(("127.0.0.1", 0), _Recorder)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    host, port = server.server_address[:2]
    try:
        with CamdClient(f"http://{host!s}:{port}", timeout_s=10.0, client="wire") as client:
            yield client, _Recorder.seen
    finally:
        server.shutdown()
        server.server_close()


Call = Callable[[CamdClient], object]

# (the call, the path, the body it sends now, the body the client sent before, with every
# default written out)
WIRE: list[tuple[str, Call, str, dict[str, Any], dict[str, Any]]] = [
    ("ping()", lambda c: c.ping(), "/api/v1/ping", {}, {"count": 10, "size": 16}),
    ("ping(5)", lambda c: c.ping(5), "/api/v1/ping", {"count": 5}, {"count": 5, "size": 16}),
    ("ping(count, size)", lambda c: c.ping(count=3, size=32), "/api/v1/ping",
     {"count": 3, "size": 32}, {"count": 3, "size": 32}),
    ("link_command(name)", lambda c: c.link_command("PING"), "/api/v1/link/command",
     {"command": "PING"}, {"command": "PING", "repeat": False}),
    ("link_command(opcode, payload)",
     lambda c: c.link_command(opcode=1, payload=b"\x01\xff", repeat=True),
     "/api/v1/link/command", {"opcode": 1, "payload_hex": "01ff", "repeat": True},
     {"opcode": 1, "payload_hex": "01ff", "repeat": True}),
    ("start_stream()", lambda c: c.start_stream(), "/api/v1/stream/start",
     {}, {"frames": 0, "binning": "off"}),
    ("start_stream(0, mode)", lambda c: c.start_stream(0, mode="area"), "/api/v1/stream/start",
     {"frames": 0, "mode": "area"}, {"frames": 0, "mode": "area", "binning": "off"}),
    ("acquire(3)", lambda c: c.acquire(3), "/api/v1/stream/acquire",
     {"frames": 3}, {"frames": 3, "binning": "off"}),
    ("acquire(3, ...)",
     lambda c: c.acquire(3, mode="tdi", stages=4, binning="2x2", record="a.h5", timeout_s=9.0),
     "/api/v1/stream/acquire",
     {"frames": 3, "mode": "tdi", "stages": 4, "binning": "2x2", "record": "a.h5",
      "timeout_s": 9.0},
     {"frames": 3, "mode": "tdi", "stages": 4, "binning": "2x2", "record": "a.h5",
      "timeout_s": 9.0}),
    ("capture_background()", lambda c: c.capture_background(), "/api/v1/live/background",
     {}, {"frames": 16}),
    ("capture_background(4)", lambda c: c.capture_background(4), "/api/v1/live/background",
     {"frames": 4}, {"frames": 4}),
    ("take_control()", lambda c: c.take_control(), "/api/v1/control", {},
     {"ttl_s": 60.0, "force": False}),
    ("take_control(30, force)", lambda c: c.take_control(30, force=True), "/api/v1/control",
     {"ttl_s": 30, "force": True}, {"ttl_s": 30, "force": True}),
    ("set_activity(text)", lambda c: c.set_activity("focusing"), "/api/v1/control/activity",
     {"text": "focusing"}, {"text": "focusing", "done": None, "total": None}),
    ("set_activity(text, 1, 2)", lambda c: c.set_activity("step", 1, 2),
     "/api/v1/control/activity", {"text": "step", "done": 1, "total": 2},
     {"text": "step", "done": 1, "total": 2}),
    ("enable_stage()", lambda c: c.enable_stage(), "/api/v1/motion/enable", {}, {"on": True}),
    ("enable_stage(False)", lambda c: c.enable_stage(False), "/api/v1/motion/enable",
     {"on": False}, {"on": False}),
    ("move_stage(x)", lambda c: c.move_stage(0.1, wait=False), "/api/v1/motion/move",
     {"position_m": 0.1, "wait": False}, {"position_m": 0.1, "speed_m_s": None, "wait": False}),
    ("move_stage(x, speed)", lambda c: c.move_stage(0.1, speed_m_s=0.05, wait=False),
     "/api/v1/motion/move", {"position_m": 0.1, "speed_m_s": 0.05, "wait": False},
     {"position_m": 0.1, "speed_m_s": 0.05, "wait": False}),
    ("set_stage()", lambda c: c.set_stage(), "/api/v1/sim/stage", {},
     {"track": True, "speed_m_s": 0.0}),
    ("set_stage(track, speed)", lambda c: c.set_stage(track=False, speed_m_s=0.003),
     "/api/v1/sim/stage", {"track": False, "speed_m_s": 0.003},
     {"track": False, "speed_m_s": 0.003}),
    ("set_stage_faults()", lambda c: c.set_stage_faults(), "/api/v1/sim/stage/faults", {},
     {"error": 0.0, "ripple": 0.0, "jitter": 0.0, "drift": 0.0, "load": 0.0}),
    ("set_stage_faults(ripple)", lambda c: c.set_stage_faults(ripple=0.01),
     "/api/v1/sim/stage/faults", {"ripple": 0.01},
     {"error": 0.0, "ripple": 0.01, "jitter": 0.0, "drift": 0.0, "load": 0.0}),
    ("fail_next(command)", lambda c: c.fail_next("PING"), "/api/v1/sim/fail-next",
     {"command": "PING"}, {"command": "PING", "skip": 0}),
    ("fail_next(command, error)", lambda c: c.fail_next("START_STREAM", error="BUSY"),
     "/api/v1/sim/fail-next", {"command": "START_STREAM", "error": "BUSY"},
     {"command": "START_STREAM", "skip": 0, "error": "BUSY"}),
    ("wheel_acquire(channels)", lambda c: c.wheel_acquire([1, 2]), "/api/v1/wheel/acquire",
     {"channels": [1, 2]}, {"channels": [1, 2], "passes": 1}),
    ("wheel_acquire(..., region)",
     lambda c: c.wheel_acquire([3], passes=2, exposure_s=0.01, compensated=True,
                               region={"row": 1, "rows": 2, "col": 0, "cols": 4}, timeout_s=5.0),
     "/api/v1/wheel/acquire",
     {"channels": [3], "passes": 2, "exposure_s": 0.01, "compensated": True,
      "region": {"row": 1, "rows": 2, "col": 0, "cols": 4}, "timeout_s": 5.0},
     {"channels": [3], "passes": 2, "exposure_s": 0.01, "compensated": True,
      "region": {"row": 1, "rows": 2, "col": 0, "cols": 4}, "timeout_s": 5.0}),
    ("start_scan(8, 100)", lambda c: c.start_scan(8, 100), "/api/v1/scan/start",
     {"stages": 8, "lines": 100}, {"stages": 8, "lines": 100}),
    ("start_campaign(name)", lambda c: c.start_campaign("mtf"), "/api/v1/campaigns/jobs",
     {"campaign": "mtf"}, {"campaign": "mtf", "quick": False}),
    ("start_campaign(name, out, quick)",
     lambda c: c.start_campaign("mtf", out="o", quick=True), "/api/v1/campaigns/jobs",
     {"campaign": "mtf", "out": "o", "quick": True},
     {"campaign": "mtf", "out": "o", "quick": True}),
    ("pause_campaign(3)", lambda c: c.pause_campaign(3), "/api/v1/campaigns/jobs/3/pause",
     {}, {"force": False}),
    ("abort_campaign(3, force)", lambda c: c.abort_campaign(3, force=True),
     "/api/v1/campaigns/jobs/3/abort", {"force": True}, {"force": True}),
]  # fmt: skip


@pytest.mark.parametrize(("name", "call", "path", "body", "before"), WIRE, ids=[w[0] for w in WIRE])
def test_method_sends_only_the_keys_given(
    recorder: tuple[CamdClient, list[tuple[str, str, Any]]],
    name: str,
    call: Call,
    path: str,
    body: dict[str, Any],
    before: dict[str, Any],
) -> None:
    client, seen = recorder
    seen.clear()
    call(client)
    assert [(p, b) for _, p, b in seen] == [(path, body)]
    # The daemon reads the body as it read the old one, every default written out.
    model = MODEL_OF[name.partition("(")[0]]
    assert model.model_validate(body) == model.model_validate(before)


def test_every_converted_method_is_seen_on_the_wire() -> None:
    called = {name.partition("(")[0] for name, *_ in WIRE}
    assert called == set(MODEL_OF)
