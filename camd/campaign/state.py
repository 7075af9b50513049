"""What survives a campaign run that stopped before its end, so that it can be resumed.

Every executed step instance is recorded in ``out_dir/state.json`` as soon as it completes
(``CampaignState``); a run into the same directory replays the recorded instances instead of
executing them, provided the state file was written by the same campaign, run the same way
(``spec_digest``).

Pause and abort (a campaign job of the daemon, ``camd.campaign.worker``): the runner asks its
``interrupt`` hook before each step it executes, and again after an acquisition (whether it
ended or failed: a pause stops the daemon's stream or scan, and a stopped acquisition is
never recorded). ``"pause"`` raises ``CampaignPaused``, ``"abort"`` ``CampaignAborted``; both
leave the state file as an interrupt does, so a resumed run executes the stopped step again
(``CampaignState.checkpoint``).

The daemon's settings before the first step are kept in ``settings_before.json`` until the run
ends, so that a run resumed after a pause, a crash or a daemon restart puts back the settings
the campaign found, not the ones it left (``CampaignState.settings_before``).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import zlib
from collections.abc import Callable
from pathlib import Path
from typing import Any

from camd.campaign.baseline import Settings, capture
from camd.campaign.spec import CampaignError, CampaignSpec
from camd.client import CamdClient

__all__ = [
    "STATE_FORMAT",
    "STATE_VERSION",
    "CampaignAborted",
    "CampaignInterrupted",
    "CampaignPaused",
    "CampaignState",
    "instance_seed",
    "spec_digest",
]

STATE_FORMAT = "camd-campaign-state"
STATE_VERSION = 1


class CampaignInterrupted(Exception):
    """The run stopped before its end (Ctrl-C or ``stop_after``); the state file has every
    completed step, so running again into the same directory resumes."""


class CampaignPaused(CampaignInterrupted):
    """Paused on request (the ``interrupt`` hook said "pause"); resumable."""


class CampaignAborted(CampaignInterrupted):
    """Aborted on request (the ``interrupt`` hook said "abort")."""


def instance_seed(seed: int, key: str) -> int:
    """The simulator seed of one step instance: the campaign's seed and the instance's key
    hashed to 32 bits (stable across runs and Python versions, unlike ``hash``)."""
    return zlib.crc32(f"{seed}/{key}".encode())


def spec_digest(spec: CampaignSpec, quick: bool, source: str | None = None) -> str:
    """What a state file must have been made by to be resumed: the campaign (a Python
    campaign's ``source`` too) and --quick."""
    doc: dict[str, Any] = {"spec": spec.model_dump(mode="json"), "quick": quick}
    if source is not None:
        doc["source"] = source
    text = json.dumps(doc, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()


class CampaignState:
    """The state file of a run into ``out_dir`` (``state.json``: the completed step instances'
    records by key) and the settings the run found (``settings_before.json``).

    ``source`` is a Python campaign's source (None for a YAML campaign): a state file is
    resumed only by the campaign, source and --quick that wrote it.
    """

    def __init__(
        self, out_dir: Path, spec: CampaignSpec, quick: bool, source: str | None = None
    ) -> None:
        self.path = out_dir / "state.json"
        self.settings_path = out_dir / "settings_before.json"
        self.campaign = spec.name
        self.quick = quick
        self.digest = spec_digest(spec, quick, source)
        self.completed: dict[str, dict[str, Any]] = {}

    def load(self) -> None:
        """Read the completed instances of an earlier run, if there is a state file;
        CampaignError if it cannot be read or was written by another campaign."""
        if not self.path.exists():
            return
        try:
            state = json.loads(self.path.read_text(encoding="utf-8"))
        except (OSError, ValueError) as exc:
            raise CampaignError(
                f"{self.path}: unreadable state file ({exc}); remove it to start over"
            ) from None
        if state.get("format") != STATE_FORMAT or state.get("version") != STATE_VERSION:
            raise CampaignError(f"{self.path} is not a campaign state file; remove it")
        if state.get("digest") != self.digest:
            raise CampaignError(
                f"{self.path} was written by another version of campaign "
                f"{state.get('campaign')!r} (or with{'out' if self.quick else ''} --quick): "
                "choose a new --out directory or remove the state file to start over"
            )
        self.completed = dict(state["completed"])

    def record(self, key: str, record: dict[str, Any]) -> None:
        """Record a completed instance and write the state file at once."""
        self.completed[key] = record
        self.save()

    def save(self) -> None:
        state = {
            "format": STATE_FORMAT,
            "version": STATE_VERSION,
            "campaign": self.campaign,
            "digest": self.digest,
            "completed": self.completed,
        }
        tmp = self.path.with_suffix(".json.tmp")
        tmp.write_text(json.dumps(state, indent=1) + "\n", encoding="utf-8")
        os.replace(tmp, self.path)  # atomic: an interrupt never leaves half a file

    def checkpoint(self, interrupt: Callable[[], str | None] | None) -> None:
        """Raise CampaignPaused or CampaignAborted if the ``interrupt`` hook asks for it."""
        if interrupt is None:
            return
        asked = interrupt()
        if asked == "pause":
            raise CampaignPaused(
                f"paused; {len(self.completed)} completed step(s) saved in {self.path}"
            )
        if asked == "abort":
            raise CampaignAborted(
                f"aborted; {len(self.completed)} completed step(s) saved in {self.path}"
            )

    def settings_before(self, client: CamdClient) -> Settings:
        """The settings to put back at the end: those this run (or the run it resumes) found
        before its first step, kept on disk until the run ends."""
        if self.settings_path.exists():
            try:
                return Settings(**json.loads(self.settings_path.read_text(encoding="utf-8")))
            except (OSError, ValueError, TypeError):
                pass  # unreadable: capture afresh (the settings now are the best guess left)
        before = capture(client)
        tmp = self.settings_path.with_suffix(".json.tmp")
        tmp.write_text(json.dumps(dataclasses.asdict(before), indent=1) + "\n", encoding="utf-8")
        os.replace(tmp, self.settings_path)
        return before

    def settings_put_back(self) -> None:
        """The run has ended and put the settings back: nothing is left to put back."""
        self.settings_path.unlink(missing_ok=True)
