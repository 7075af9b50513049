"""A campaign whose one stare outlasts any test (100,000 frames): to stop the daemon, pause or
e-stop while a worker's request waits for its frames (tests/test_estop.py)."""

from __future__ import annotations

from typing import Any

from camd.campaign.plan import Plan, acquire, configure

CAMPAIGN = {
    "name": "endless_stare",
    "description": "One stare far longer than a test, on the hr400.\n",
    "profile": "hr400",
    "seed": 11,
    "parameters": {"frames": 100000},
    "quick": {"frames": 100000},
}


def count_steps(p: dict[str, Any]) -> int:
    return 2


def plan(p: dict[str, Any]) -> Plan:
    yield configure("window", registers={"WIN_ROWS": 64}, mode="area")
    yield acquire("stare", stare={"frames": p["frames"]})
