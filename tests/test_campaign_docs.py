"""docs/campaigns.md names every registered measurement and every shipped campaign, and every
shipped campaign file loads (its steps, references and measurement names valid)."""

from __future__ import annotations

from pathlib import Path

from camd.campaign.loading import load_campaign
from camd.campaign.measurements import MEASUREMENTS
from camd.cli.camctl_campaign import campaigns_dir

CAMPAIGNS_MD = Path(__file__).resolve().parent.parent / "docs" / "campaigns.md"


def test_docs_list_every_measurement_and_campaign() -> None:
    doc = CAMPAIGNS_MD.read_text()
    missing = [name for name in MEASUREMENTS if f"`{name}`" not in doc]
    assert not missing, f"docs/campaigns.md does not list {missing}"
    for path in campaigns_dir().glob("*.yaml"):
        spec = load_campaign(path)
        assert f"`{spec.name}`" in doc, spec.name
        assert spec.assumptions, f"{spec.name} lists no assumptions"
