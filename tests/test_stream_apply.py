"""A stream or a stare that fails while being applied puts back what it had changed.

Over the full stack (HTTP -> camd serve -> simulated camera), the simulated camera fails its
next START_STREAM on purpose (POST /api/v1/sim/fail-next): refused with a NAK, or lost because
the camera drops off the line for a few seconds (``tests/test_apply_faults.py`` explains the
injection). The request asked for a mode change and a recording first, so that the failure
comes part-way: after the mode was set and the file made. The camera's state, read back from
the device itself (``tests.device_snapshot``), must be the same after the error as before; the
file must be gone and off the journal of open recordings; and the acquisition slot free, so
that the next stare runs.

The planner's refusals (``camd.daemon.stream_plan``) are tested without a daemon in
tests/test_stream_plan.py; one of them is checked here to change nothing on the device.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from camd.client import CamdClient
from tests.device_snapshot import snapshot
from tests.test_apply_faults import failing, refused
from tests.test_trust import small_window_daemon

ROWS = 16  # small_window_daemon's window
SILENCE_S = 4.5  # as tests/test_apply_faults.py: outlasts the host's attempts, ends in the wait


@pytest.fixture(scope="module")
def rig(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[CamdClient, Path]]:
    """The client of a daemon in area mode, and the daemon's data directory."""
    data_dir = tmp_path_factory.mktemp("camd-stream-apply")
    with small_window_daemon(data_dir) as url, CamdClient(url, timeout_s=120) as client:
        client.set_mode("area")
        yield client, data_dir


def open_recordings(data_dir: Path) -> list[str]:
    """The journal's entries: the recordings the daemon holds open."""
    folder = data_dir / "open-recordings"
    return sorted(p.name for p in folder.iterdir()) if folder.is_dir() else []


def assert_nothing_left(
    client: CamdClient, data_dir: Path, before: dict[str, Any], out: Path
) -> None:
    """The device as ``before``, and no file ``out``, nor on the journal."""
    assert snapshot(client) == before
    assert not out.exists()
    assert open_recordings(data_dir) == []


def assert_idle_and_free(client: CamdClient, tmp_path: Path) -> None:
    """Nothing streams, and the slot is free: the next stare runs to its end."""
    assert client.stream()["streaming"] is False
    status = client.status()
    assert status["state"] == "idle"
    assert status["acquisition"] is None or not status["acquisition"]["running"]
    done = client.acquire(2, record=str(tmp_path / "next.h5"))
    assert (done["stats"]["frames"], done["recording"]) == (2, str(tmp_path / "next.h5"))


def test_a_stream_start_refused_by_the_camera_puts_the_mode_back_and_leaves_no_file(
    rig: tuple[CamdClient, Path], tmp_path: Path
) -> None:
    client, data_dir = rig
    before = snapshot(client)
    out = tmp_path / "refused.h5"
    with failing(client, "START_STREAM", error="BUSY"):
        error = refused(lambda: client.start_stream(0, mode="tdi", stages=4, record=str(out)))
    assert (error.http_status, error.code) == (502, "device_nak"), error.message
    assert error.message.startswith("START_STREAM refused by the device: BUSY (5)")
    assert error.message.endswith("; restored: mode area"), error.message
    assert_nothing_left(client, data_dir, before, out)
    events = [e["message"] for e in client.events(limit=10)["events"]]
    assert any(
        m.startswith("stream start failed: START_STREAM refused by the device: BUSY (5)")
        and m.endswith("; restored: mode area")
        for m in events
    ), events
    assert_idle_and_free(client, tmp_path)


def test_a_stare_whose_start_is_lost_is_stopped_its_mode_put_back_and_its_file_removed(
    rig: tuple[CamdClient, Path], tmp_path: Path
) -> None:
    client, data_dir = rig
    before = snapshot(client)
    out = tmp_path / "lost.h5"
    with failing(client, "START_STREAM", duration_s=SILENCE_S):
        error = refused(lambda: client.acquire(3, mode="tdi", stages=4, record=str(out)))
    assert (error.http_status, error.code) == (504, "timeout"), error.message
    assert error.message.startswith("START_STREAM: no answer from the device on ")
    # The camera might have started streaming and lost only its answer: it is stopped.
    assert error.message.endswith("; restored: stream stopped, mode area"), error.message
    assert_nothing_left(client, data_dir, before, out)
    assert_idle_and_free(client, tmp_path)


def test_a_stare_refused_by_its_plan_changes_nothing(
    rig: tuple[CamdClient, Path], tmp_path: Path
) -> None:
    client, data_dir = rig
    before = snapshot(client)
    out = tmp_path / "never.h5"
    error = refused(lambda: client.acquire(2, mode="tdi", stages=ROWS + 1, record=str(out)))
    assert (error.http_status, error.code) == (400, "bad_request")
    assert error.message == (
        f"stages = {ROWS + 1} does not fit the window of {ROWS} rows (docs/physics.md §2 eq 13: "
        f"1 <= M <= M0 = n_lines); choose 1..{ROWS} or make the window taller"
    )
    assert_nothing_left(client, data_dir, before, out)
