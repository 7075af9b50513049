"""The transports' and the recordings' classes stay small enough to read (issue 32: no class over
400 lines; the frame stream's and the TDI scan's parts each a module of at most ~500 lines).

``FrameStream`` (camd/link) and ``TdiRecorder`` (camd/store) had grown to 973 and 493 lines, each
doing several jobs; they are now facades over parts with one job each. These checks read the
source only (no import, no process).
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("camd/link", "camd/store")
CLASS_LINES_MAX = 400
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


def modules() -> list[str]:
    return sorted(str(p.relative_to(ROOT)) for pkg in PACKAGES for p in (ROOT / pkg).glob("*.py"))


@pytest.mark.parametrize("module", modules())
def test_no_class_is_over_400_lines(module: str) -> None:
    tree = ast.parse((ROOT / module).read_text(encoding="utf-8"))
    sizes = {
        node.name: (node.end_lineno or node.lineno) - node.lineno + 1
        for node in ast.walk(tree)
        if isinstance(node, ast.ClassDef)
    }
    over = {name: n for name, n in sizes.items() if n > CLASS_LINES_MAX}
    assert not over, (
        f"{module}: classes over {CLASS_LINES_MAX} lines: {over}; split them by job into "
        "classes of their own, as FrameStream and TdiRecorder are"
    )


@pytest.mark.parametrize("module", PARTS)
def test_each_part_is_a_small_module(module: str) -> None:
    lines = len((ROOT / module).read_text(encoding="utf-8").splitlines())
    assert lines <= PART_LINES_MAX, f"{module} has {lines} lines (at most {PART_LINES_MAX})"
