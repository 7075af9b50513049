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


# 400 exposure lines make a frame period of 401 lines (8.2 ms, docs/physics.md §3): a stare of
# 300 frames lasts about 2.5 s, long enough for a test on a busy machine to act inside it (at the
# reset exposure of 2 lines a 64-row stare of 300 frames lasts 0.4 s). The flat field's photon
# rate is scaled down by the same 200 so the signal stays 2,000 and 8,000 e-.
EXPOSURE_LINES = 400


def plan(p: dict[str, Any]) -> Plan:
    yield configure("window", registers={"WIN_ROWS": 64, "EXPOSURE": EXPOSURE_LINES}, mode="area")
    for i, photons in enumerate((2.5e5, 1.0e6)):
        yield configure(f"scene{i}", scene=f"flat:photons={photons}")
        yield acquire(f"stare{i}", stare={"frames": p["frames"]})
        yield measure(f"stats{i}", "stare_stats", inputs={"frames": f"stare{i}"},
                      args={"region": REGION}, results=["mean_dn", "sigma_dn", "psnr_db"])  # fmt: skip
    yield check("psnr_ok", "psnr_db", min=p["min_psnr_db"])
