"""A campaign whose one stare outlasts the test that uses it (20,000 frames of 64 rows, 26 s at
the camera's rate and longer from the simulator): to stop the daemon while a worker's request
waits for its frames (tests/test_estop.py). Not more: the daemon refuses a stare whose whole
recording (5.2 GB here) does not fit the disk, and 100,000 frames needed 26 GB free."""

from __future__ import annotations

from typing import Any

from camd.campaign.plan import Plan, acquire, configure

CAMPAIGN = {
    "name": "endless_stare",
    "description": "One stare far longer than a test, on the hr400.\n",
    "profile": "hr400",
    "seed": 11,
    "parameters": {"frames": 20000},
    "quick": {"frames": 20000},
}


def count_steps(p: dict[str, Any]) -> int:
    return 2


def plan(p: dict[str, Any]) -> Plan:
    yield configure("window", registers={"WIN_ROWS": 64}, mode="area")
    yield acquire("stare", stare={"frames": p["frames"]})
