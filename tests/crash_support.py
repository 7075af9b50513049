"""Shared by the crash-safety tests: a small file system that fills up, filling it, and the
space a writer holds past the end of its file."""

from __future__ import annotations

import contextlib
import os
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest

from camd.soak.edges import fill_disk, mounted_tmpfs

__all__ = ["REQUIRE_MOUNT", "blocks_past_end", "fill_disk", "small_disk", "wait_for"]

# CI runs as root and sets this, so that the disk-full tests cannot be skipped there.
REQUIRE_MOUNT = os.environ.get("CAMD_REQUIRE_MOUNT") == "1"


@contextmanager
def small_disk(folder: Path, size_mb: int) -> Iterator[Path]:
    """A tmpfs of ``size_mb`` MiB mounted on ``folder`` (root only: skipped otherwise, or a
    failure under CAMD_REQUIRE_MOUNT=1), unmounted afterwards."""
    with contextlib.ExitStack() as stack:
        try:
            mounted = stack.enter_context(mounted_tmpfs(folder, size_mb))
        except OSError as exc:
            if REQUIRE_MOUNT:
                pytest.fail(f"{exc} (CAMD_REQUIRE_MOUNT=1)")
            pytest.skip(f"{exc} (CI runs as root)")
        yield mounted


NO_HEADROOM = 64 << 10  # past a file's end once finished: a block or two of rounding at most


def blocks_past_end(path: Path) -> int:
    """Bytes allocated to ``path`` past its last block: a writer's headroom
    (camd.store.durability.Headroom), under NO_HEADROOM once the file is finished."""
    st = path.stat()
    return st.st_blocks * 512 - -(-st.st_size // 4096) * 4096


def wait_for(what: str, check: Callable[[], Any], timeout_s: float = 120.0) -> Any:
    """Poll ``check`` until it returns something true, and return that; AssertionError naming
    ``what`` after ``timeout_s`` (generous by default: the suite runs on a busy 2-core host)."""
    deadline = time.monotonic() + timeout_s
    while True:
        value = check()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"waited {timeout_s:g} s for {what}")
        time.sleep(0.1)
