"""camd.bluesky against `camd serve --sim`, with the real bluesky, ophyd-async and event-model.

A RunEngine runs `count` of stares, a stage `scan` with the stare detector and the push-broom
scan as a fly scan (camd.bluesky.plans.push_broom); every document emitted is validated with
event-model's schemas, and the data read back through the StreamResource/StreamDatum documents
(the file the resource names, the indices the datums give) equal camd's own readers'. Control:
taken while staged, under the bluesky client's name, given back after; refused with the
daemon's words while another client holds it. A scan the camera ends early fails `complete`
with what the daemon said. The window is 16 rows with a 4-line exposure, so that each
acquisition takes a fraction of a second.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from bluesky import RunEngine
from bluesky import plan_stubs as bps
from bluesky import plans as bp
from bluesky.preprocessors import finalize_wrapper, run_decorator, stage_decorator
from bluesky.utils import FailedStatus
from event_model import DocumentNames, schema_validators
from ophyd_async.core import TriggerInfo, init_devices

from camd.bluesky import (
    CamdConnection,
    CamdFilterWheel,
    CamdScanDetector,
    CamdStage,
    CamdStareDetector,
    push_broom,
    read_stream_datum,
)
from camd.cli._daemon_proc import DaemonProcess
from camd.client import CamdClient, CamdError, default_client_name
from camd.store.recording_reading import read_recording
from camd.store.tdi_reading import read_tdi_scan
from tests.test_sensor_stack import serve

ROWS = 16  # the window's rows: small frames, short acquisitions


@pytest.fixture(scope="module")
def url(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    with serve(tmp_path_factory.mktemp("camd-bluesky"), "fpga") as daemon:
        with CamdClient(daemon.url) as client:
            client.write_registers({"WIN_ROWS": ROWS, "EXPOSURE": 4})
        yield daemon.url
    assert daemon.exit_code in (0, -15), daemon.log_path.read_text()


@pytest.fixture(scope="module")
def engine() -> RunEngine:
    return RunEngine({}, call_returns_result=True)


@pytest.fixture
def connection(url: str) -> CamdConnection:
    return CamdConnection(url, client="bluesky:test")


class Documents:
    """Every document a run emits, each validated against event-model's schema as it comes."""

    def __init__(self) -> None:
        self.docs: list[tuple[str, dict[str, Any]]] = []

    def __call__(self, name: str, doc: dict[str, Any]) -> None:
        schema_validators[DocumentNames(name)].validate(doc)
        self.docs.append((name, doc))

    def named(self, name: str) -> list[dict[str, Any]]:
        return [doc for kind, doc in self.docs if kind == name]

    def data(self, key: str) -> list[tuple[Path, tuple[int, int], np.ndarray]]:
        """Each stream datum of ``key``: its file, its indices, and its data read through the
        resource (``read_stream_datum``: the file the resource names, sliced at the indices)."""
        resources = {r["uid"]: r for r in self.named("stream_resource") if r["data_key"] == key}
        out = []
        for datum in self.named("stream_datum"):
            resource = resources.get(datum["stream_resource"])
            if resource is not None:
                indices = (datum["indices"]["start"], datum["indices"]["stop"])
                path = Path(resource["uri"].removeprefix("file://localhost"))
                out.append((path, indices, read_stream_datum(resource, datum)))
        return out


def run(engine: RunEngine, plan: Any) -> Documents:
    docs = Documents()
    engine(plan, docs)
    assert docs.docs[0][0] == "start"
    assert docs.named("stop")[0]["exit_status"] == "success"
    return docs


def control_holder(url: str) -> str | None:
    with CamdClient(url) as client:
        return client.control()["holder"]


def control_doc(url: str) -> dict[str, Any]:
    with CamdClient(url) as client:
        return dict(client.control())


def test_count_of_stares_points_into_the_recordings(url: str, engine: RunEngine) -> None:
    # A lease of 3 s, renewed every second, outlives a run of 3 s and more.
    connection = CamdConnection(url, client="bluesky:test", lease_ttl_s=3.0)
    with init_devices():
        cam = CamdStareDetector(connection)
    seen: list[dict[str, Any]] = []
    token = engine.subscribe(lambda name, doc: seen.append(control_doc(url)), "event")
    try:
        docs = run(engine, bp.count([cam], num=3, delay=1.5))
    finally:
        engine.unsubscribe(token)
    # Control held for the run, under its name, and renewed; then given back.
    assert [doc["holder"] for doc in seen] == ["bluesky:test"] * 3
    assert [doc["why"] for doc in seen] == ["lease"] * 3
    # Renewed: the expiry moved on (by how much depends on when the renewer ran, 1.0-4.0 s
    # seen: a busy host delays it; the same `since_t_s` below shows the lease never lapsed).
    assert seen[-1]["expires_t_s"] > seen[0]["expires_t_s"]
    assert seen[-1]["since_t_s"] == seen[0]["since_t_s"]  # one lease, not three
    assert control_holder(url) is None
    (descriptor,) = docs.named("descriptor")
    key = descriptor["data_keys"]["cam"]
    assert (key["shape"], key["dtype_numpy"], key["external"]) == (
        [1, ROWS, 2048],
        "<u2",
        "STREAM:",
    )
    assert len(docs.named("event")) == 3
    data = docs.data("cam")
    assert len(data) == len(docs.named("stream_resource")) == 3  # one recording per stare
    assert len({path for path, _, _ in data}) == 3
    for seq, datum in enumerate(docs.named("stream_datum")):
        assert datum["seq_nums"] == {"start": seq + 1, "stop": seq + 2}
    for path, indices, frames in data:
        assert indices == (0, 1)
        recording = read_recording(path)
        assert frames.shape == (1, 1, ROWS, 2048)
        assert np.array_equal(frames[0], recording.frames)  # camd's own reader
        assert recording.frames.shape == (1, ROWS, 2048) and recording.frames.any()


def test_stage_scan_takes_a_stare_at_each_position(url: str, engine: RunEngine) -> None:
    # A short lease: a renewal left running after the run would take control back within 0.5 s.
    connection = CamdConnection(url, client="bluesky:test", lease_ttl_s=1.5)
    with init_devices():
        cam = CamdStareDetector(connection)
        stage = CamdStage(connection)
    with CamdClient(url) as client:
        reading = client.motion()["reading"]
    assert reading["state"] == "disabled"  # as powered up
    # Millimetres from where it stands (the simulated stage powers up inside its travel):
    # short moves, a short test.
    targets = [reading["position_m"] + step for step in (0.001, 0.002, 0.003)]
    docs = run(engine, bp.scan([cam], stage, targets[0], targets[-1], 3))
    events = docs.named("event")
    positions = [event["data"]["stage"] for event in events]
    assert positions == pytest.approx(targets, abs=2e-6)  # an encoder count
    (descriptor,) = docs.named("descriptor")
    assert descriptor["data_keys"]["stage"]["units"] == "m"
    for (path, _, frames), position in zip(docs.data("cam"), positions, strict=True):
        recording = read_recording(path)
        assert np.array_equal(frames[0], recording.frames)
        # The frames' headers say where the stage stood: the stare was taken there.
        counts_per_m = 1e6  # the simulated stage's encoder (config/stages)
        assert recording.columns["stage_position"].tolist() == [round(position * counts_per_m)]
    with CamdClient(url) as client:
        motion = client.motion()
        # Staging energised the released motor, unstaging released it again; it stays where
        # the scan left it, and reads so.
        assert motion["reading"]["state"] == "disabled"
        assert motion["reading"]["position_m"] == pytest.approx(targets[-1], abs=2e-6)
    # The detector and the stage were staged at once (bluesky's stage_all): one lease, given
    # back once, and nothing renews it afterwards.
    assert control_holder(url) is None
    time.sleep(2.0)
    assert control_holder(url) is None
    with pytest.raises(FailedStatus) as caught:
        engine(bps.mv(stage, 5.0))  # beyond the travel: the daemon's refusal, nothing moved
    error = caught.value.__cause__
    assert isinstance(error, CamdError) and error.code == "bad_request"
    assert error.message.startswith("position 5.0 m is outside the soft limits [0.0, 1.2] m")
    with CamdClient(url) as client:
        assert client.motion()["reading"]["position_m"] == pytest.approx(targets[-1], abs=2e-6)


def test_push_broom_fly_scan_collects_the_scan_file(
    url: str, engine: RunEngine, connection: CamdConnection
) -> None:
    with init_devices():
        tdi = CamdScanDetector(connection, stages=4, options={"drive_stage": False})
    docs = run(engine, push_broom(tdi, 20))
    (resource,) = docs.named("stream_resource")
    assert resource["parameters"]["dataset"] == "/lines"
    ((path, indices, lines),) = docs.data("tdi")
    assert indices == (0, 23)  # 20 complete lines and the M - 1 = 3 before them
    scan = read_tdi_scan(path)
    assert scan.lines.shape == (23, 2048) and scan.complete.tolist() == [False] * 3 + [True] * 20
    assert np.array_equal(lines[:, 0], scan.lines)  # camd's own reader
    (descriptor,) = docs.named("descriptor")
    assert descriptor["name"] == "primary"
    assert descriptor["data_keys"]["tdi"]["shape"] == [1, 2048]
    assert descriptor["data_keys"]["tdi"]["dtype_numpy"] == "<u4"
    assert descriptor["configuration"]["tdi"]["data"]["tdi-stages"] == 4
    assert control_holder(url) is None


def test_a_scan_ended_early_fails_complete_with_the_daemons_words(
    url: str, engine: RunEngine, connection: CamdConnection
) -> None:
    with init_devices():
        tdi = CamdScanDetector(connection, stages=4, options={"drive_stage": False})
    with CamdClient(url) as client:
        client.fail_next("START_STREAM", end_after_frames=5)
    with pytest.raises(FailedStatus) as caught:
        engine(push_broom(tdi, 200))
    error = caught.value.__cause__
    assert isinstance(error, CamdError) and error.code == "scan_ended_early"
    assert (
        error.message.startswith("the scan ") and " ended ended_early, not done: " in error.message
    )
    assert "the camera ended the stream after 5 of 203 frames" in error.message
    assert error.message.endswith("(5 lines on disk)")
    assert control_holder(url) is None


def test_control_held_elsewhere_refuses_the_run_and_changes_nothing(
    url: str, engine: RunEngine, connection: CamdConnection
) -> None:
    with init_devices():
        cam = CamdStareDetector(connection)
    with CamdClient(url, client="alice@bench") as alice:
        alice.take_control(60)
        before = alice.stream()["recording"]
        try:
            with pytest.raises(FailedStatus) as caught:
                engine(bp.count([cam], num=1))
            error = caught.value.__cause__
            assert isinstance(error, CamdError) and error.code == "not_in_control"
            assert error.message.startswith("alice@bench holds control since ")
            assert alice.stream()["recording"] == before  # nothing recorded
        finally:
            alice.release_control()
    assert control_holder(url) is None


def test_filter_wheel_is_set_by_its_speed_and_read(
    url: str, engine: RunEngine, connection: CamdConnection
) -> None:
    with init_devices():
        wheel = CamdFilterWheel(connection)

    def plan() -> Any:
        yield from bps.mv(wheel, 90.0)
        return (yield from bps.rd(wheel.speed_deg_s))

    assert engine(plan()).plan_result == 90.0
    with CamdClient(url) as client:
        assert client.wheel()["speed_deg_s"] == 90.0
    docs = run(engine, bp.count([wheel], num=1))
    (event,) = docs.named("event")
    assert event["data"]["wheel-speed_deg_s"] == 90.0
    assert 0.0 <= event["data"]["wheel-angle_deg"] < 360.0
    engine(bps.mv(wheel, 0.0))
    with CamdClient(url) as client:
        assert client.wheel()["speed_deg_s"] == 0.0


def test_a_plan_that_fails_mid_scan_stops_the_scan_and_gives_control_back(
    url: str, engine: RunEngine, connection: CamdConnection
) -> None:
    with init_devices():
        tdi = CamdScanDetector(connection, stages=4, options={"drive_stage": False})

    def broken() -> Any:
        yield from bps.stage(tdi, wait=True)
        yield from bps.open_run()
        yield from bps.prepare(tdi, TriggerInfo(number_of_events=100_000), wait=True)
        yield from bps.kickoff(tdi, wait=True)
        with CamdClient(url) as client:
            for _ in range(300):  # until lines are on disk: at most 60 s
                if client.scan()["lines_flushed"] > 0:
                    break
                yield from bps.sleep(0.2)
        raise RuntimeError("the plan broke")

    with pytest.raises(RuntimeError, match="the plan broke"):
        engine(finalize_wrapper(broken(), bps.unstage(tdi, wait=True)))
    with CamdClient(url) as client:
        scan = client.scan()
    assert scan["state"] == "stopped"  # unstaging stopped it: 100,000 lines take minutes
    assert 0 < scan["lines_flushed"] < 100_000
    assert read_tdi_scan(scan["file"]).lines.shape[0] == scan["lines_flushed"]
    assert control_holder(url) is None


def test_the_client_is_named_as_bluesky_by_default(url: str) -> None:
    assert CamdConnection(url).client == "bluesky:" + default_client_name()


def test_a_stare_kicked_off_for_events_of_two_frames_writes_one_file(
    url: str, engine: RunEngine, connection: CamdConnection
) -> None:
    with init_devices():
        cam = CamdStareDetector(connection)

    @stage_decorator([cam])
    @run_decorator()
    def fly() -> Any:
        info = TriggerInfo(number_of_events=3, collections_per_event=2)
        yield from bps.prepare(cam, info, wait=True)
        yield from bps.kickoff(cam, wait=True)
        yield from bps.declare_stream(cam, name="primary", collect=True)
        yield from bps.complete(cam, wait=True)
        yield from bps.collect(cam, name="primary")

    docs = run(engine, fly())
    ((path, indices, frames),) = docs.data("cam")
    assert indices == (0, 3)
    recording = read_recording(path)  # one stream of 3 x 2 frames
    assert recording.frames.shape == (6, ROWS, 2048)
    assert frames.shape == (3, 2, ROWS, 2048)
    assert np.array_equal(frames.reshape(6, ROWS, 2048), recording.frames)
    (descriptor,) = docs.named("descriptor")
    # Declared before the stream's first answer: the frame's size was not known yet.
    assert descriptor["data_keys"]["cam"]["shape"] == [2, None, None]


def test_the_token_comes_from_camd_token(
    engine: RunEngine, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    with DaemonProcess(tmp_path, env={"CAMD_TOKEN": "s3cret"}) as daemon:
        with CamdClient(daemon.url, token="s3cret") as client:
            client.wait_ready(60)
        monkeypatch.setenv("CAMD_TOKEN", "s3cret")
        with init_devices():
            wheel = CamdFilterWheel(CamdConnection(daemon.url))
        monkeypatch.delenv("CAMD_TOKEN")
        with init_devices():
            stranger = CamdFilterWheel(CamdConnection(daemon.url))
        docs = run(engine, bp.count([wheel], num=1))  # staged (control), read, unstaged
        assert len(docs.named("event")) == 1
        with pytest.raises(FailedStatus) as caught:
            engine(bp.count([stranger], num=1))
    error = caught.value.__cause__
    assert isinstance(error, CamdError) and (error.http_status, error.code) == (401, "unauthorized")


def test_stopping_the_stage_ends_its_move_where_it_stands(
    url: str, engine: RunEngine, connection: CamdConnection
) -> None:
    with init_devices():
        stage = CamdStage(connection)

    def plan() -> Any:
        yield from bps.stage(stage, wait=True)
        start = yield from bps.rd(stage)
        yield from bps.mv(stage.speed_m_s, 0.01)
        yield from bps.abs_set(stage, start + 0.05, group="move")  # 5 s at 10 mm/s
        yield from bps.sleep(0.5)
        yield from bps.stop(stage)
        try:
            yield from bps.wait(group="move")
            failure = None
        except FailedStatus as exc:
            failure = exc.__cause__
        yield from bps.sleep(0.5)
        location = yield from bps.locate(stage)
        yield from bps.unstage(stage, wait=True)
        return start, failure, location

    start, failure, location = engine(plan()).plan_result
    assert str(failure) == "Device stage was stopped."  # the move did not succeed
    assert location["setpoint"] == pytest.approx(start + 0.05)
    with CamdClient(url) as client:
        reading = client.motion()["reading"]
    assert start < reading["position_m"] < start + 0.04  # stopped well short of the target
    assert reading["position_m"] == pytest.approx(location["readback"], abs=2e-6)


def test_a_scan_that_does_not_fit_is_refused_at_kickoff_and_nothing_is_written(
    url: str, engine: RunEngine, connection: CamdConnection
) -> None:
    with init_devices():
        tdi = CamdScanDetector(connection, stages=100, options={"drive_stage": False})
    with CamdClient(url) as client:
        before = client.scan()["file"]
    with pytest.raises(FailedStatus) as caught:
        engine(push_broom(tdi, 10))
    error = caught.value.__cause__
    assert isinstance(error, CamdError) and (error.http_status, error.code) == (400, "bad_request")
    assert error.message.startswith("stages = 100 needs 100 window rows but the scan's frames")
    with CamdClient(url) as client:
        assert client.scan()["file"] == before  # no scan started
    assert control_holder(url) is None
