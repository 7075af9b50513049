"""The conformance report: ``conformance.json`` (every check with its clause, outcome and
evidence) and ``conformance.html`` (the same, for a person), written side by side."""

from __future__ import annotations

import html
import json
import math
from pathlib import Path
from typing import Any

from .engine import OUTCOME_WORDS, OUTCOMES, CheckRecord

JSON_NAME = "conformance.json"
HTML_NAME = "conformance.html"


def _clean(value: Any) -> Any:
    """JSON values: NaN and infinities as null (strict JSON)."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {str(k): _clean(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_clean(v) for v in value]
    return value


VERDICTS = {
    "conforms": "CONFORMS",
    "does_not_conform": "DOES NOT CONFORM",
    "incomplete": "NOT SHOWN TO CONFORM",
}
"""The run's verdict (JSON ``summary.verdict``) in words: ``conforms`` only when every check
ran and passed; ``does_not_conform`` when one failed; else ``incomplete``: none failed, but
some were not run or skipped, so what they test was not shown."""


def verdict(counts: dict[str, int]) -> str:
    """``conforms``, ``does_not_conform`` or ``incomplete`` (VERDICTS) for outcome counts."""
    if counts.get("fail", 0):
        return "does_not_conform"
    if counts.get("not_run", 0) or counts.get("skipped", 0) or not counts.get("pass", 0):
        return "incomplete"
    return "conforms"


def counts_text(counts: dict[str, int]) -> str:
    """'54 passed, 0 failed, 1 not run, 1 skipped of 56' (the summary line's counts)."""
    return (
        f"{counts['pass']} passed, {counts['fail']} failed, {counts['not_run']} not run, "
        f"{counts['skipped']} skipped of {counts['checks']}"
    )


def document(header: dict[str, Any], records: list[CheckRecord]) -> dict[str, Any]:
    """The JSON report: ``header`` (suite, unit, times) and the checks."""
    counts: dict[str, int] = {o: sum(r.outcome == o for r in records) for o in OUTCOMES}
    said = verdict(counts)
    doc: dict[str, Any] = _clean({
        **header,
        "summary": {**counts, "checks": len(records), "conforms": said == "conforms",
                    "verdict": said},
        "failed": [r.id for r in records if r.outcome == "fail"],
        "not_run": [r.id for r in records if r.outcome == "not_run"],
        "checks": [r.as_dict() for r in records],
    })  # fmt: skip
    return doc


def write(out_dir: Path, doc: dict[str, Any]) -> tuple[Path, Path]:
    """Write both files; their paths (JSON, HTML)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    json_path = out_dir / JSON_NAME
    html_path = out_dir / HTML_NAME
    json_path.write_text(json.dumps(doc, indent=2, allow_nan=False) + "\n", encoding="utf-8")
    html_path.write_text(render_html(doc), encoding="utf-8")
    return json_path, html_path


_COLOURS = {"pass": "#1a7f37", "fail": "#cf222e", "not_run": "#6e7781", "skipped": "#9a6700"}


def render_html(doc: dict[str, Any]) -> str:
    """A self-contained page: the summary, then one row per check with its evidence."""
    e = html.escape
    s = doc["summary"]
    unit = doc.get("unit", {})
    rows = []
    for c in doc["checks"]:
        colour = _COLOURS[c["outcome"]]
        evidence = json.dumps(c["evidence"], indent=1)
        rows.append(
            f'<tr id="{e(c["id"])}"><td><code>{e(c["id"])}</code>'
            f"{' <em>(destructive)</em>' if c['destructive'] else ''}<br>{e(c['title'])}</td>"
            f"<td>{e(c['clause'])}</td>"
            f'<td style="color:{colour};font-weight:bold">'
            f"{e(OUTCOME_WORDS[c['outcome']].upper())}</td>"
            f"<td>{e(c['reason'])}<details><summary>evidence</summary>"
            f"<pre>{e(evidence)}</pre></details></td></tr>"
        )
    said = VERDICTS[s["verdict"]]
    unit_rows = "".join(
        f"<tr><th>{e(str(k))}</th><td>{e(str(v))}</td></tr>" for k, v in unit.items()
    )
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>camd conformance: {e(said)}</title>
<style>body{{font-family:sans-serif;margin:2em}}table{{border-collapse:collapse}}
td,th{{border:1px solid #ccc;padding:4px 8px;vertical-align:top;text-align:left}}
pre{{max-width:60em;overflow:auto;font-size:85%}}</style></head><body>
<h1>camd conformance: {e(said)}</h1>
<p>{e(counts_text(s))} checks; a unit conforms only when every check ran and passed;
suite {e(str(doc.get("suite")))} version {e(str(doc.get("version")))}, {e(str(doc.get("started")))},
{doc.get("duration_s", 0):.1f} s. Clauses refer to docs/protocol.md, docs/stream.md and
docs/sensors.md; docs/conformance.md describes every check.</p>
<table>{unit_rows}</table>
<h2>Checks</h2>
<table><tr><th>check</th><th>clause</th><th>result</th><th>reason and evidence</th></tr>
{"".join(rows)}
</table></body></html>
"""
