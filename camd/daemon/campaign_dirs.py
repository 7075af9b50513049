"""Which campaigns a daemon's campaign job may run: those in the operator's campaign
directories (``[campaigns] dirs``, in order) and then the shipped ones, named by name, never by
a path (docs/campaigns.md, "Campaign jobs"). A Python plan is code run with the daemon's rights:
only the operator, who writes the config, decides which files may run.
"""

from __future__ import annotations

import contextlib
import re
from collections.abc import Sequence
from pathlib import Path

from camd.daemon.error_body import cut
from camd.daemon.errors import BadRequest
from camd.paths import config_dir

__all__ = ["CAMPAIGN_NAME", "CAMPAIGN_SUFFIXES", "CampaignDirs"]

CAMPAIGN_NAME = re.compile(r"[a-z][a-z0-9_]{0,99}")  # a campaign's name (its file's stem)
CAMPAIGN_SUFFIXES = (".yaml", ".py")  # a YAML campaign, a Python plan


class CampaignDirs:
    """The operator's campaign directories, then the shipped ``config/campaigns``."""

    def __init__(self, operator_dirs: Sequence[Path] = ()) -> None:
        # The operator's first: they may override a shipped campaign by name.
        self.dirs = [*operator_dirs, config_dir() / "campaigns"]

    def available(self) -> list[str]:
        """The campaigns a job may name: every campaign file's name in the directories."""
        names: set[str] = set()
        for folder in self.dirs:
            with contextlib.suppress(OSError):
                names.update(
                    p.stem
                    for p in folder.iterdir()
                    if p.suffix in CAMPAIGN_SUFFIXES and CAMPAIGN_NAME.fullmatch(p.stem)
                )
        return sorted(names)

    def find(self, name: str) -> Path:
        """The campaign file ``name`` names: the first ``name.yaml`` or ``name.py`` of the
        directories. BadRequest (nothing loaded) for anything but a known name."""
        dirs = ", ".join(str(d) for d in self.dirs)
        known = ", ".join(self.available()) or "none"
        if not CAMPAIGN_NAME.fullmatch(name):
            raise BadRequest(
                f"campaign {cut(name)!r}: give a campaign's name (lowercase letters, digits "
                "and _, as `camctl campaign list` shows them), not a path: the daemon runs only "
                f"the campaigns in its campaign directories ({dirs}); put yours in a directory "
                f"of [campaigns] dirs in camd.toml. Campaigns here: {known}"
            )
        for folder in self.dirs:
            for suffix in CAMPAIGN_SUFFIXES:
                path = folder / f"{name}{suffix}"
                if path.is_file():
                    return path.resolve()
        raise BadRequest(
            f"no campaign {name!r} in the daemon's campaign directories ({dirs}); campaigns "
            f"here: {known}; add yours to a directory of [campaigns] dirs in camd.toml"
        )
