"""The frame stream's and the TDI scan's parts each a module of at most ~500 lines (issue 32;
tests/test_shape.py holds every class to 400).

``FrameStream`` (camd/link) and ``TdiRecorder`` (camd/store) had grown to 973 and 493 lines, each
doing several jobs; they are now facades over parts with one job each. These checks read the
source only (no import, no process).
"""

from __future__ import annotations

from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
# The modules of the two split classes: the facades and their parts.
PARTS = (
    "camd/link/frame_stream.py",
    "camd/link/frame_reader.py",
    "camd/link/frame_dispatcher.py",
    "camd/link/frame_queue.py",
    "camd/link/frame_ledger.py",
    "camd/link/stream_device.py",
    "camd/link/frame_types.py",
    "camd/store/tdi_recording.py",
    "camd/store/tdi_layout.py",
    "camd/store/tdi_reading.py",
)
PART_LINES_MAX = 500


@pytest.mark.parametrize("module", PARTS)
def test_each_part_is_a_small_module(module: str) -> None:
    lines = len((ROOT / module).read_text(encoding="utf-8").splitlines())
    assert lines <= PART_LINES_MAX, f"{module} has {lines} lines (at most {PART_LINES_MAX})"
