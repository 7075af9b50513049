"""Plans for camd's devices that bluesky's own do not cover: the push-broom scan as a fly scan.

``count`` of stares and a stage ``scan`` with the stare detector are bluesky's own
(``bluesky.plans.count``, ``bluesky.plans.scan``); docs/bluesky.md shows them.
"""

from __future__ import annotations

from typing import Any

import bluesky.plan_stubs as bps
from bluesky.preprocessors import run_decorator, stage_decorator
from bluesky.utils import MsgGenerator
from ophyd_async.core import TriggerInfo

from camd.bluesky.detector import CamdScanDetector

STREAM = "primary"


def push_broom(
    detector: CamdScanDetector,
    lines: int,
    *,
    stream: str = STREAM,
    md: dict[str, Any] | None = None,
) -> MsgGenerator[str]:
    """A push-broom TDI scan of ``lines`` complete lines as a fly scan, in one run: the
    detector staged (control taken), prepared for the file's lines + M - 1 events (its first
    M - 1 lines lack stages, docs/scan.md), kicked off (the scan starts), its stream declared,
    completed (the scan has ended ``done``; otherwise the daemon's error) and collected (the
    StreamResource and StreamDatum documents of its file's ``/lines``); then unstaged (control
    given back). Returns the run's uid."""
    if lines < 1:
        raise ValueError(f"lines must be >= 1 complete lines, got {lines}")

    # bluesky's preprocessors are untyped.
    @stage_decorator([detector])  # type: ignore[untyped-decorator]
    @run_decorator(md={"plan_name": "push_broom", "lines": lines, **(md or {})})  # type: ignore[untyped-decorator]
    def inner() -> MsgGenerator[None]:
        stages = yield from bps.rd(detector.stages)
        info = TriggerInfo(number_of_events=lines + int(stages) - 1)
        yield from bps.prepare(detector, info, wait=True)
        yield from bps.kickoff(detector, wait=True)
        # Declared once the scan has started: its answer gives the lines' width and type.
        yield from bps.declare_stream(detector, name=stream, collect=True)
        yield from bps.complete(detector, wait=True)
        yield from bps.collect(detector, name=stream)

    uid = yield from inner()
    return str(uid)
