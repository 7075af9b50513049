"""What the suite sets up for the processes its tests start (tests/conftest.py)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import camd


def test_the_processes_the_tests_start_keep_their_bytecode() -> None:
    # About 100 daemons and their simulated cameras start in a run; where the environment says
    # PYTHONDONTWRITEBYTECODE, each compiled camd's modules anew (0.2-0.3 s of a core apiece).
    # The suite gives them a bytecode cache outside the checkout instead: a process that
    # imported a camd module leaves its compiled form for the next.
    source = Path(camd.__file__).resolve().parent / "paths.py"
    where = subprocess.run(
        [sys.executable, "-c", "import importlib.util as u, camd.paths as m; "
         "print(u.cache_from_source(m.__file__))"],
        capture_output=True, text=True, check=True, timeout=60,
    ).stdout.strip()  # fmt: skip
    assert Path(where).is_file(), f"no bytecode kept for {source} (looked for {where})"
