"""The Python twin of config/campaigns/example_stare.yaml (docs/campaigns.md): the same
campaign as a plan. Run both and their results.json are the same, byte for byte."""

from __future__ import annotations

from typing import Any

from camd.campaign.plan import Plan, acquire, check, configure, measure, sweep

CAMPAIGN = {
    "name": "example_stare",
    "description": "PSNR of a flat field against light level on the hr400 (stare, 64-row "
    "window), and the temporal dark noise at the same exposure.\n",
    "profile": "hr400",
    "seed": 7,
    "parameters": {"frames": 6, "photons": [2.0e7, 8.0e7, 3.2e8], "min_psnr_db": 10.0},
    "quick": {"photons": [2.0e7, 8.0e7]},
    "assumptions": [
        "The light levels are chosen to stay well below saturation at the reset exposure."
    ],
    "outputs": {
        "tables": [
            {"title": "Flat-field statistics", "columns": ["photons", "mean_dn", "sigma_dn", "psnr_db"]},
            {"title": "Dark noise", "columns": ["dark_mean_dn", "dark_noise_dn"]},
        ],
        "plots": [
            {"title": "PSNR against light level", "x": "photons", "y": ["psnr_db"],
             "xlabel": "photons / pixel / s", "ylabel": "PSNR (dB)", "logx": True},
            {"title": "Mean signal against light level", "x": "photons", "y": ["mean_dn"],
             "logx": True},
        ],
    },
}  # fmt: skip

REGION = [25, 25]


def count_steps(p: dict[str, Any]) -> int:
    """Step instances in a run: four before the sweep, four per light level."""
    return 4 + 4 * len(p["photons"])


def plan(p: dict[str, Any]) -> Plan:
    yield configure("window", title="64-row window, area mode", registers={"WIN_ROWS": 64},
                    mode="area")  # fmt: skip
    yield configure("dark_scene", scene="flat:photons=1e-6")  # no light to speak of
    yield acquire("dark", title="dark frames", stare={"frames": p["frames"]})
    yield measure("dark_noise", "dark_noise", inputs={"frames": "dark"}, args={"region": REGION})

    def light_level(photons: float) -> Plan:
        yield configure("scene", scene=f"flat:photons={photons}")
        yield acquire("stare", stare={"frames": p["frames"]})
        yield measure("stats", "stare_stats", inputs={"frames": "stare"},
                      args={"region": REGION}, results=["mean_dn", "sigma_dn", "psnr_db"])  # fmt: skip
        yield check("psnr_ok", "psnr_db", min=p["min_psnr_db"])

    yield from sweep("light", "photons", p["photons"], light_level, title="light levels")
