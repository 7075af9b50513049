"""camd/daemon/heap.py against glibc itself: the arena limit holds with many threads
allocating at once (counted in glibc's own malloc_info report), and trimming is harmless."""

from __future__ import annotations

import subprocess
import sys
import textwrap

import pytest

from camd.daemon import heap

glibc = pytest.mark.skipif(heap._libc() is None, reason="the C library is not glibc")

# A child process (the limit must come before its threads): N threads allocate and free
# concurrently, holding each other off the arenas, then glibc's report counts the heaps.
CHILD = textwrap.dedent(
    """
    import ctypes, ctypes.util, re, sys, tempfile, threading
    from camd.daemon import heap
    limit = int(sys.argv[1])
    print(heap.limit_arenas(limit))
    barrier = threading.Barrier(8)
    def work():
        barrier.wait()
        for _ in range(2000):
            blocks = [bytearray(4096) for _ in range(16)]
            del blocks
    threads = [threading.Thread(target=work) for _ in range(8)]
    for t in threads: t.start()
    for t in threads: t.join()
    libc = ctypes.CDLL(ctypes.util.find_library("c"))
    libc.fopen.restype = ctypes.c_void_p
    libc.malloc_info.argtypes = [ctypes.c_int, ctypes.c_void_p]
    libc.fclose.argtypes = [ctypes.c_void_p]
    with tempfile.NamedTemporaryFile("r") as f:
        fp = libc.fopen(f.name.encode(), b"w")
        libc.malloc_info(0, fp)
        libc.fclose(fp)
        print(len(re.findall(r'<heap nr="', f.read())))
    """
)


def arenas_with(limit: int) -> tuple[str, int]:
    proc = subprocess.run(
        [sys.executable, "-c", CHILD, str(limit)], capture_output=True, text=True, timeout=120,
        check=True,
    )  # fmt: skip
    took, count = proc.stdout.split()
    return took, int(count)


@glibc
def test_the_arena_limit_holds_with_eight_threads_allocating() -> None:
    took, count = arenas_with(2)
    assert took == "True"
    assert 1 <= count <= 2


@glibc
def test_zero_leaves_glibcs_default_of_more_arenas() -> None:
    took, count = arenas_with(0)
    assert took == "False"
    assert count > 2  # eight threads at once: glibc's default makes more (9 measured)


@glibc
def test_giving_back_returns_freed_pages() -> None:
    # Freed small blocks stay in the heap until trimmed: glibc then says it released some.
    blocks = [bytearray(1 << 12) for _ in range(5000)]  # 20 MB in 4 KB blocks, on the heap
    del blocks
    assert heap.give_back() is True
