"""``camd.tdi.warm_up``: every kernel the engine can call is compiled (or loaded) ahead of the
first scan, in a fresh process (this one may have compiled them already)."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from camd.tdi import numba_available

pytestmark = pytest.mark.skipif(not numba_available(), reason="no numba")

_PROBE = """
import json
from camd.tdi import kernel_numba, warm_up
before = {name: len(getattr(kernel_numba, name).signatures) for name in kernel_numba.KERNELS}
warm_up()
after = {name: [str(s) for s in getattr(kernel_numba, name).signatures]
         for name in kernel_numba.KERNELS}
print(json.dumps({"before": before, "after": after}))
"""


def test_warm_up_compiles_every_kernel_for_both_accumulators() -> None:
    out = subprocess.run(
        [sys.executable, "-c", _PROBE], capture_output=True, text=True, check=True, timeout=300
    )
    doc = json.loads(out.stdout.strip().splitlines()[-1])
    assert set(doc["before"].values()) == {0}  # nothing compiled in a fresh process
    for name, signatures in doc["after"].items():
        assert signatures, f"{name} was not compiled"
    # The interpolating kernels, with the 32-bit ring and the 64-bit one (over 256 stages).
    interpolating = " ".join(
        s for name, sigs in doc["after"].items() if name != "integer_rows" for s in sigs
    )
    assert "uint32" in interpolating and "uint64" in interpolating
