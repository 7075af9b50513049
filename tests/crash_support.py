"""Shared by the crash-safety tests: a small file system that fills up, filling it, and the
space a writer holds past the end of its file."""

from __future__ import annotations

import os
import subprocess
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest

# CI runs as root and sets this, so that the disk-full tests cannot be skipped there.
REQUIRE_MOUNT = os.environ.get("CAMD_REQUIRE_MOUNT") == "1"


@contextmanager
def small_disk(folder: Path, size_mb: int) -> Iterator[Path]:
    """A tmpfs of ``size_mb`` MiB mounted on ``folder`` (root only), unmounted afterwards."""
    folder.mkdir(parents=True, exist_ok=True)
    why = None
    if os.geteuid() != 0:
        why = "mounting a small file system needs root (CI runs as root)"
    else:
        done = subprocess.run(
            ["mount", "-t", "tmpfs", "-o", f"size={size_mb}m,mode=0755", "tmpfs", str(folder)],
            capture_output=True,
            text=True,
            check=False,
        )
        if done.returncode != 0:
            why = f"cannot mount a tmpfs: {done.stderr.strip()}"
    if why is not None:
        if REQUIRE_MOUNT:
            pytest.fail(f"{why} (CAMD_REQUIRE_MOUNT=1)")
        pytest.skip(why)
    try:
        yield folder
    finally:
        subprocess.run(["umount", "-l", str(folder)], check=False)


def fill_disk(folder: Path) -> int:
    """Write zeros to ``folder/filler`` until the disk is full; the bytes written."""
    fd = os.open(folder / "filler", os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
    written = 0
    try:
        for size in (1 << 20, 4096):  # big blocks, then down to the last page
            block = bytes(size)
            try:
                while True:
                    written += os.write(fd, block)
            except OSError:
                pass
    finally:
        os.close(fd)
    return written


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
