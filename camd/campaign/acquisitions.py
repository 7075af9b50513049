"""Acquisition kinds registered in Python: new ways to take data without editing the runner.

The runner knows four acquisitions (stare, scan, wheel, polarization: ``camd.campaign.spec``).
Any other is a function registered by name, typically in a Python campaign's module::

    @acquisition("dark_pair")
    def dark_pair(client: CamdClient, path: Path, *, frames: int = 4) -> dict[str, Any]:
        ...  # the daemon through its client only; write the data to ``path`` (HDF5)
        return {"frames": frames}

and a plan yields ``acquire("darks", kind="dark_pair", args={"frames": 4})``. The runner calls
the function for that step (re-seeding the simulator first, as for every acquisition), with
the file it must write and the step's ``args`` as keyword arguments; the document it returns
is what the plan gets back and what measurements see (``Acquired.doc``, ``how`` = the kind's
name). The function is the part that touches the camera: the plan only names it.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from camd.campaign.spec import CampaignError

if TYPE_CHECKING:
    from camd.client import CamdClient

__all__ = ["ACQUISITIONS", "Acquisition", "acquisition"]

Acquisition = Callable[..., dict[str, Any]]  # (client, path, **args) -> document
ACQUISITIONS: dict[str, Acquisition] = {}
_NAME = re.compile(r"^[a-z][a-z0-9_]*$")


def acquisition(name: str) -> Callable[[Acquisition], Acquisition]:
    """Register ``fn(client, path, **args) -> dict`` as the acquisition kind ``name``.

    Registering a name again replaces the function (a plan module loaded twice)."""
    if not _NAME.fullmatch(name):
        raise ValueError(f"acquisition kind {name!r}: use lower-case letters, digits and _")

    def register(fn: Acquisition) -> Acquisition:
        ACQUISITIONS[name] = fn
        return fn

    return register


def run_acquisition(
    kind: str, client: CamdClient, path: Path, args: dict[str, Any]
) -> dict[str, Any]:
    """Run the registered acquisition ``kind``; CampaignError naming the kinds known if it
    is not registered, TypeError if it does not return a document."""
    fn = ACQUISITIONS.get(kind)
    if fn is None:
        known = ", ".join(sorted(ACQUISITIONS)) or "none"
        raise CampaignError(
            f"no acquisition kind {kind!r} is registered (known: {known}); register it with "
            "@acquisition in the campaign's Python module"
        )
    doc = fn(client, path, **args)
    if not isinstance(doc, dict):
        raise TypeError(f"acquisition {kind!r} returned {type(doc).__name__}, not a dict")
    return doc
