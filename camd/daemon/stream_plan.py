"""A stream or a stare, planned whole before the camera is touched.

A stream start (POST /stream/start), a stare (POST /stream/acquire) and the counted streams
other services start through the stream service (a wheel acquisition's WHEEL_ACQUIRE) are
planned by pure code, in two steps that keep the order in which their refusals have always
come:

- ``check_request``, before the acquisition slot is claimed: a stare takes at least one frame,
  and the file a ``record`` names is resolved and confined to the data directory and
  ``daemon.record_dirs`` (``camd.daemon.output_paths``);
- ``plan_stream``, after the preflight (``StreamService.preflight``: the state, the sensor's
  link, the frame device) and from what the camera is now (``StreamContext``: its mode, the
  window its registers set, the live view's background): the mode to set first and the one to
  put back, the TDI stage count (docs/physics.md §2 eq 13: 1 <= M <= the window's rows), the
  largest frame the reader must take, and the recording's planned size, checked against its
  directory and disk (``camd.store.recording.check_new_file``).

Every refusal is a ``BadRequest`` that says what to change, raised here, so that a refused
request changes nothing. ``StreamService`` then applies the plan step by step and puts back
what it changed if a step fails (``camd.daemon.transaction``).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from camd.daemon.config_sections import DaemonSection
from camd.daemon.errors import BadRequest
from camd.daemon.models import StreamStartRequest
from camd.daemon.output_paths import RECORDINGS_FOLDER, resolve_output
from camd.protocol.stream import HEADER_BYTES
from camd.store.recording import RecordingError, check_new_file


@dataclass(frozen=True, slots=True)
class StreamStart:
    """A device command that starts a counted area-mode stream instead of START_STREAM.

    ``command`` is sent with ``fields``; its answer must carry ``frames`` (how many the stream
    will send), ``first_counter``, ``rows`` and ``cols``, and the device ends the stream with
    STREAM_DONE like a counted START_STREAM. ``frame_period_s`` is the longest the host should
    expect per frame (it sizes the acquisition's timeout and the lost-STREAM_DONE check: a
    wheel frame may wait up to a revolution for its channel). ``metadata`` goes into a
    recording's ``stream`` group.
    """

    command: str
    fields: Mapping[str, Any]
    frame_period_s: float
    metadata: Mapping[str, Any] = field(default_factory=dict)


@dataclass(frozen=True, slots=True)
class StreamContext:
    """What the planner needs to know of the camera now (read after the preflight)."""

    mode: str | None  # the device's imaging mode (None: not known since it connected)
    window_rows: int  # the window the sensor's registers set
    columns: int  # window columns (unbinned)
    background_bytes: int = 0  # the live view's background, stored in a recording (0: none)


@dataclass(frozen=True, slots=True)
class StreamPlan:
    """A stream start checked whole: what to change, in order, and what to put back."""

    request: StreamStartRequest  # its ``record`` resolved (``check_request``)
    start: StreamStart | None  # the command that starts the stream (None: START_STREAM)
    mode_change: tuple[str, str] | None  # (mode now, mode to set) before the stream; None: none
    stages: int  # TDI stages recorded with the frames (0 in area mode)
    max_frame_bytes: int  # the largest frame the reader must take, header included
    record: Path | None  # the new file the frames are recorded to
    planned_bytes: int  # the most the recording needs: every frame at its largest, background


def resolve_record(record: str, daemon: DaemonSection) -> Path:
    """The file a client's ``record`` names, resolved and confined to the data directory and
    ``daemon.record_dirs`` (a relative one in the recordings folder); BadRequest otherwise."""
    return resolve_output(
        record,
        field="record",
        relative_to=daemon.data_dir / RECORDINGS_FOLDER,
        data_dir=daemon.data_dir,
        record_dirs=daemon.record_dirs,
    )


def check_request(
    request: StreamStartRequest, daemon: DaemonSection, *, stare: bool
) -> StreamStartRequest:
    """What can be checked before the slot is claimed; returns ``request`` with its ``record``
    resolved (everything after names the file it will write). ``stare``: it returns when its
    frames are in (POST /stream/acquire), so it takes at least one."""
    if stare and request.frames < 1:
        raise BadRequest("frames must be at least 1 for an acquisition; use start for 0")
    if request.record is None:
        return request
    record = resolve_record(request.record, daemon)
    return request.model_copy(update={"record": str(record)})


def claim_description(request: StreamStartRequest) -> str:
    """What the acquisition slot says runs ("20 frames to /data/x.h5")."""
    what = "until stopped" if request.frames == 0 else f"{request.frames} frames"
    if request.record:
        what += f" to {request.record}"
    return what


def plan_stream(
    request: StreamStartRequest,
    context: StreamContext,
    *,
    start: StreamStart | None = None,
    max_rows: int | None = None,
) -> StreamPlan:
    """The stream ``request`` (``check_request``'s) asks for, checked whole against the camera
    as it is (``context``). ``start``: the command that starts it instead of START_STREAM (its
    request's mode, stages and binning do not apply). ``max_rows``: the most rows a frame may
    have if the window may grow while the stream runs (a scan's line-period loop)."""
    set_mode = request.mode if start is None else None
    mode = set_mode or context.mode or "area"
    mode_change = None
    if set_mode is not None and context.mode != set_mode:
        mode_change = (context.mode or "area", set_mode)
    stages = 0
    if mode == "tdi" and start is None:
        rows = context.window_rows
        stages = rows if request.stages is None else request.stages
        if not 1 <= stages <= rows:
            raise BadRequest(
                f"stages = {stages} does not fit the window of {rows} rows (docs/physics.md §2 "
                f"eq 13: 1 <= M <= M0 = n_lines); choose 1..{rows} or make the window taller"
            )
    # Frames as large as the window may become while the stream runs: a frame larger than the
    # reader's slots would be refused as corrupt, every one of them.
    rows = max(context.window_rows, max_rows or 0)
    max_frame_bytes = HEADER_BYTES + 2 * rows * context.columns
    # The file holds the frames and, if the live view has one, the background.
    planned_bytes = request.frames * max_frame_bytes + context.background_bytes
    record = None if request.record is None else Path(request.record)
    if record is not None:
        try:
            check_new_file(record, planned_bytes)
        except RecordingError as exc:
            raise BadRequest(str(exc)) from None
    return StreamPlan(
        request=request,
        start=start,
        mode_change=mode_change,
        stages=stages,
        max_frame_bytes=max_frame_bytes,
        record=record,
        planned_bytes=planned_bytes,
    )
