"""The stream and stare planner (``camd.daemon.stream_plan``), without a daemon.

A stream start or a stare is checked whole before the camera is touched: what can be checked
before the acquisition slot is claimed (a stare's frame count, the recording's path confined to
the daemon's directories), then, against the camera as it is, the mode to set and to put back,
the TDI stage count, the largest frame and the recording's file and size (real files in the
test's directory). Every refusal has the message the API answers. tests/test_stream_apply.py
applies plans on a real daemon and makes them fail part-way.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from camd.daemon.config import DaemonSection
from camd.daemon.errors import BadRequest
from camd.daemon.models import StreamStartRequest
from camd.daemon.stream_plan import (
    StreamContext,
    StreamStart,
    check_request,
    claim_description,
    plan_stream,
)
from camd.protocol.stream import HEADER_BYTES

ROWS, COLS = 16, 2048
AREA = StreamContext(mode="area", window_rows=ROWS, columns=COLS)


def refusal(call: object, *args: object, **kwargs: object) -> str:
    with pytest.raises(BadRequest) as info:
        call(*args, **kwargs)  # type: ignore[operator]
    return str(info.value)


def daemon(tmp_path: Path) -> DaemonSection:
    return DaemonSection(data_dir=tmp_path / "data", record_dirs=[tmp_path / "allowed"])


# -- before the slot is claimed ------------------------------------------------------------------


def test_a_stare_takes_at_least_one_frame(tmp_path: Path) -> None:
    request = StreamStartRequest(frames=0)
    assert refusal(check_request, request, daemon(tmp_path), stare=True) == (
        "frames must be at least 1 for an acquisition; use start for 0"
    )
    assert check_request(request, daemon(tmp_path), stare=False) == request


def test_the_record_is_resolved_into_the_recordings_folder(tmp_path: Path) -> None:
    checked = check_request(
        StreamStartRequest(frames=2, record="run/x.h5"), daemon(tmp_path), stare=True
    )
    assert checked.record == str(tmp_path / "data" / "recordings" / "run" / "x.h5")
    assert claim_description(checked) == f"2 frames to {checked.record}"
    assert claim_description(StreamStartRequest()) == "until stopped"


def test_a_record_outside_the_allowed_directories_is_refused(tmp_path: Path) -> None:
    message = refusal(
        check_request, StreamStartRequest(frames=2, record="/etc/x.h5"), daemon(tmp_path),
        stare=True,
    )  # fmt: skip
    assert message.startswith(
        "record '/etc/x.h5' is outside the directories the daemon may write: "
    )
    # The frame count is checked first, as it always was.
    message = refusal(
        check_request, StreamStartRequest(frames=0, record="/etc/x.h5"), daemon(tmp_path),
        stare=True,
    )  # fmt: skip
    assert message.startswith("frames must be at least 1")


# -- the plan -------------------------------------------------------------------------------------


def test_an_area_stream_changes_nothing_first() -> None:
    plan = plan_stream(StreamStartRequest(frames=5), AREA)
    assert (plan.mode_change, plan.stages, plan.record) == (None, 0, None)
    assert plan.max_frame_bytes == HEADER_BYTES + 2 * ROWS * COLS
    assert plan.planned_bytes == 5 * plan.max_frame_bytes


@pytest.mark.parametrize(
    ("mode_now", "asked", "change"),
    [
        ("area", "tdi", ("area", "tdi")),
        ("tdi", "area", ("tdi", "area")),
        ("tdi", "tdi", None),
        ("tdi", None, None),
        # The mode is not known (not read since the camera connected): set it, and put back
        # area (the camera's mode after a start or a reset).
        (None, "area", ("area", "area")),
        (None, "tdi", ("area", "tdi")),
    ],
)
def test_the_mode_is_set_first_and_put_back_on_failure(
    mode_now: str | None, asked: str | None, change: tuple[str, str] | None
) -> None:
    context = StreamContext(mode=mode_now, window_rows=ROWS, columns=COLS)
    request = StreamStartRequest.model_validate({"frames": 1, "mode": asked, "stages": 4})
    assert plan_stream(request, context).mode_change == change


def test_tdi_stages_default_to_the_window_and_must_fit_it() -> None:
    tdi = StreamStartRequest.model_validate({"mode": "tdi"})
    assert plan_stream(tdi, AREA).stages == ROWS
    assert plan_stream(tdi.model_copy(update={"stages": 4}), AREA).stages == 4
    for stages in (0, ROWS + 1):
        assert refusal(plan_stream, tdi.model_copy(update={"stages": stages}), AREA) == (
            f"stages = {stages} does not fit the window of {ROWS} rows (docs/physics.md §2 eq "
            f"13: 1 <= M <= M0 = n_lines); choose 1..{ROWS} or make the window taller"
        )
    # In the camera's tdi mode too, when the request does not name one.
    tdi_now = StreamContext(mode="tdi", window_rows=ROWS, columns=COLS)
    assert refusal(plan_stream, StreamStartRequest(stages=ROWS + 1), tdi_now).startswith(
        f"stages = {ROWS + 1} does not fit"
    )
    # Ignored in area mode.
    assert plan_stream(StreamStartRequest(stages=ROWS + 1), AREA).stages == 0


def test_a_command_that_starts_the_stream_itself_sets_no_mode_and_no_stages() -> None:
    start = StreamStart(command="WHEEL_ACQUIRE", fields={"passes": 1}, frame_period_s=0.5)
    request = StreamStartRequest.model_validate({"frames": 3, "mode": "tdi", "stages": 99})
    plan = plan_stream(request, AREA, start=start)
    assert (plan.start, plan.mode_change, plan.stages) == (start, None, 0)


def test_frames_are_sized_for_the_largest_window_the_stream_may_have() -> None:
    plan = plan_stream(StreamStartRequest(frames=2), AREA, max_rows=4 * ROWS)
    assert plan.max_frame_bytes == HEADER_BYTES + 2 * 4 * ROWS * COLS
    assert plan_stream(StreamStartRequest(), AREA, max_rows=1).max_frame_bytes == (
        HEADER_BYTES + 2 * ROWS * COLS
    )


def test_the_recording_is_planned_with_the_background(tmp_path: Path) -> None:
    context = StreamContext(mode="area", window_rows=ROWS, columns=COLS, background_bytes=4096)
    out = tmp_path / "x.h5"
    plan = plan_stream(StreamStartRequest(frames=3, record=str(out)), context)
    assert plan.record == out
    assert plan.planned_bytes == 3 * (HEADER_BYTES + 2 * ROWS * COLS) + 4096
    assert not out.exists()  # planning makes no file


def test_a_recording_that_cannot_be_written_is_refused(tmp_path: Path) -> None:
    existing = tmp_path / "there.h5"
    existing.write_bytes(b"keep me")
    assert refusal(plan_stream, StreamStartRequest(frames=1, record=str(existing)), AREA) == (
        f"{existing} already exists; choose another file or remove it"
    )
    assert existing.read_bytes() == b"keep me"
    missing = tmp_path / "nodir" / "x.h5"
    assert refusal(plan_stream, StreamStartRequest(frames=1, record=str(missing)), AREA) == (
        f"the directory {missing.parent} does not exist; create it first (mkdir -p "
        f"{missing.parent}) or choose another file"
    )
    # More frames than any disk holds.
    huge = StreamStartRequest(frames=0xFFFF_FFFF, record=str(tmp_path / "huge.h5"))
    message = refusal(plan_stream, huge, AREA)
    frame_bytes = HEADER_BYTES + 2 * ROWS * COLS
    assert message.startswith(
        f"the recording needs about {0xFFFF_FFFF * frame_bytes / 1e6:.1f} MB, and "
    )
    assert message.endswith("free some space, choose another disk, or record less")
    assert not (tmp_path / "huge.h5").exists()
