"""The daemon's C heap (glibc malloc): a few arenas, and free memory given back to the system.

glibc gives a new thread its own malloc arena, up to eight per core (tests/test_heap.py: eight
threads, nine heaps), and an arena keeps what its threads freed. The daemon runs many short-lived threads
(the API's worker threads, one per acquisition and finisher), and numpy's frame and batch
buffers come and go in them, so over hours the arenas multiply and fragment: `camd soak`
measured the daemon's RSS at 396 MB after its warm-up and 402 to 433 MB 20 minutes later, with
a new arena of about 20 MB every few minutes. Two arenas and a periodic ``malloc_trim`` are
there to keep it flat.

Elsewhere than glibc (musl, macOS) these are no-ops that say so.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import logging
from functools import cache
from typing import Any

log = logging.getLogger(__name__)

_M_ARENA_MAX = -8  # glibc's malloc.h


@cache
def _libc() -> Any:
    """glibc's handle if it has mallopt and malloc_trim, else None."""
    name = ctypes.util.find_library("c")
    try:
        libc = ctypes.CDLL(name)
    except OSError:
        return None
    if not (hasattr(libc, "mallopt") and hasattr(libc, "malloc_trim")):
        return None
    libc.mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    libc.malloc_trim.argtypes = [ctypes.c_size_t]
    return libc


def limit_arenas(count: int) -> bool:
    """At most ``count`` malloc arenas from now on (0: leave glibc's default). Call it before
    the daemon starts its threads: arenas made before stay. True if the C library took it."""
    if count <= 0:
        return False
    libc = _libc()
    if libc is None:
        log.info("malloc arenas not limited: the C library is not glibc")
        return False
    return bool(libc.mallopt(_M_ARENA_MAX, count))


def give_back() -> bool:
    """Return the heap's free pages to the system (``malloc_trim(0)``): RSS then shows what the
    daemon holds, not what it once held. A few milliseconds; True if memory was released."""
    libc = _libc()
    return bool(libc.malloc_trim(0)) if libc is not None else False
