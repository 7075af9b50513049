"""A campaign with long acquisitions, to pause and resume in the middle of one
(tests/test_campaign_jobs.py): two stares of ``frames`` frames of a flat field, each measured,
and a check."""

from __future__ import annotations

from typing import Any

from camd.campaign.plan import Plan, acquire, check, configure, measure

CAMPAIGN = {
    "name": "long_stare",
    "description": "Two long stares at a flat field on the hr400, their statistics measured.\n",
    "profile": "hr400",
    "seed": 11,
    "parameters": {"frames": 300, "min_psnr_db": 10.0},
    "quick": {"frames": 40},
}

REGION = [25, 25]


def count_steps(p: dict[str, Any]) -> int:
    return 8


def plan(p: dict[str, Any]) -> Plan:
    yield configure("window", registers={"WIN_ROWS": 64}, mode="area")
    for i, photons in enumerate((5.0e7, 2.0e8)):
        yield configure(f"scene{i}", scene=f"flat:photons={photons}")
        yield acquire(f"stare{i}", stare={"frames": p["frames"]})
        yield measure(f"stats{i}", "stare_stats", inputs={"frames": f"stare{i}"},
                      args={"region": REGION}, results=["mean_dn", "sigma_dn", "psnr_db"])  # fmt: skip
    yield check("psnr_ok", "psnr_db", min=p["min_psnr_db"])
