"""The conformance suite: checks any unit the daemon drives against the spec
(docs/protocol.md, docs/stream.md, docs/sensors.md) and reports each check with its clause,
its outcome (pass, fail, not run, skipped) and the evidence (docs/conformance.md).

- ``engine``: a plan of checks carried out through ``camd.client.CamdClient`` (the plan never
  touches the unit; check functions are registered by name);
- ``suite``: the plan, every check with its clause;
- ``checks_link``, ``checks_sensor``, ``checks_stream``, ``checks_motion``: the check
  functions (raw frames through POST /api/v1/link/command, and the daemon's endpoints);
- ``raw``: raw command frames and the refusals the dictionary implies;
- ``report``: conformance.json and conformance.html.
"""

from __future__ import annotations

import fnmatch
import time
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

from camd.client import CamdClient

from . import checks_link, checks_motion, checks_sensor, checks_stream  # noqa: F401 (register)
from .engine import CheckRecord, ProgressFn, Unit, run_plan
from .report import document, write
from .suite import SUITE, VERSION, plan

CONTROL_TTL_S = 60.0

__all__ = ["ConformanceResult", "check_ids", "run_conformance"]


@dataclass(frozen=True)
class ConformanceResult:
    """A finished run: the records, the JSON document and where the report went."""

    records: list[CheckRecord]
    doc: dict[str, object]
    json_path: Path
    html_path: Path

    @property
    def failed(self) -> list[str]:
        return [r.id for r in self.records if r.outcome == "fail"]

    @property
    def not_run(self) -> list[str]:
        return [r.id for r in self.records if r.outcome == "not_run"]


def check_ids() -> list[str]:
    """Every check id of the suite, in order (the plan needs only the dictionary)."""
    from camd.protocol import load_dictionary

    return [step.id for step in plan(load_dictionary())]


def run_conformance(
    client: CamdClient,
    out_dir: Path,
    *,
    destructive: bool = False,
    only: Sequence[str] = (),
    progress: ProgressFn | None = None,
    defects: Sequence[str] = (),
) -> ConformanceResult:
    """Run the suite on the unit behind ``client`` (holding control) and write the report to
    ``out_dir``. ``only``: check ids or shell patterns (``stream.*``) to run; ``defects``: the
    simulator's defects, recorded in the report's header."""
    t0 = time.monotonic()
    started = datetime.now(UTC).isoformat(timespec="seconds")

    def selected(check_id: str) -> bool:
        return any(fnmatch.fnmatchcase(check_id, pattern) for pattern in only)

    with client.holding_control(CONTROL_TTL_S):
        unit = Unit.probe(client)
        records = run_plan(
            unit,
            plan(unit.dictionary),
            destructive=destructive,
            only=selected if only else None,
            progress=progress,
        )
    daemon = unit.status.get("daemon") or {}
    header: dict[str, object] = {
        "suite": SUITE,
        "version": VERSION,
        "started": started,
        "duration_s": round(time.monotonic() - t0, 2),
        "destructive": destructive,
        "unit": {
            "daemon": client.url,
            "daemon_version": daemon.get("version") if isinstance(daemon, dict) else None,
            "sensor": unit.sensor,
            "simulated": unit.simulated,
            "defects": list(defects),
            "port": (unit.status.get("link") or {}).get("port"),
        },
    }
    doc = document(header, records)
    json_path, html_path = write(out_dir, doc)
    return ConformanceResult(records, doc, json_path, html_path)
