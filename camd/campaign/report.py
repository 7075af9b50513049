"""A campaign's report: report.md (tables) and report.html (the same tables and the plots).

Both are made from the results.json document alone, so a report can be rebuilt from a
finished run. Plots are PNGs made by matplotlib (Agg backend: the test PCs are headless) in
``out_dir/plots/``; a check's limits are drawn dashed on the plot of its result and points
outside them marked red. Tables put lists of equal length side by side, one row per sweep
value; scalars fill one row.
"""

from __future__ import annotations

import html
import json
from pathlib import Path
from typing import Any

from camd.campaign.baseline import describe
from camd.campaign.spec import CampaignSpec, PlotSpec, TableSpec
from camd.markdown import table as md_table

__all__ = ["write_report"]


def write_report(
    spec: CampaignSpec, doc: dict[str, Any], out_dir: Path, *, restored: list[str] | None = None
) -> Path:
    """Write report.md, report.html and plots/*.png under ``out_dir``; return the HTML's path.
    ``restored``: the daemon's settings put back after the run (camd.campaign.baseline)."""
    baseline = describe(spec.baseline)
    after = restored or []
    results: dict[str, Any] = doc["results"]
    plots_dir = out_dir / "plots"
    plots_dir.mkdir(parents=True, exist_ok=True)
    pngs = [
        _plot(plot, i, results, doc["checks"], plots_dir)
        for i, plot in enumerate(spec.outputs.plots)
    ]
    tables = [(t.title, *_table(t, results)) for t in spec.outputs.tables]
    checks = [
        [c["id"], c["result"], _fmt(c["value"]), _fmt(c["min"]), _fmt(c["max"]),
         "PASS" if c["passed"] else "FAIL"]
        for c in doc["checks"]
    ]  # fmt: skip
    check_header = ["check", "result", "value", "min", "max", "outcome"]
    verdict = "PASSED" if doc["passed"] else "FAILED"

    md = [f"# Campaign {spec.name}: {verdict}", ""]
    if spec.description:
        md += [spec.description.strip(), ""]
    md += [
        f"Profile `{spec.profile}`, seed {spec.seed}"
        + (", quick (CI-sized) run" if doc["quick"] else ""),
        "",
        "## Checks",
        "",
    ]
    md += md_table(check_header, checks) if checks else ["(no checks)"]
    for title, header, rows in tables:
        md += ["", f"## {title}", "", *md_table(header, rows)]
    for plot, png in zip(spec.outputs.plots, pngs, strict=True):
        md += ["", f"## {plot.title}", "", f"![{plot.title}]({png})"]
    if spec.assumptions:
        md += ["", "## Assumptions", ""] + [f"- {a}" for a in spec.assumptions]
    md += ["", "## Baseline", "", "Before the first step:", ""] + [f"- {b}" for b in baseline]
    if after:
        md += ["", "After the run, the daemon's settings were put back: " + ", ".join(after) + "."]
    md += ["", "## Parameters", "", "```json", json.dumps(doc["parameters"], indent=2), "```"]
    (out_dir / "report.md").write_text("\n".join(md) + "\n", encoding="utf-8")

    h = html.escape
    colour = "#1a7f37" if doc["passed"] else "#cf222e"
    body = [
        f"<h1>Campaign {h(spec.name)}: <span style='color:{colour}'>{verdict}</span></h1>",
        f"<p>{h(spec.description.strip())}</p>" if spec.description else "",
        f"<p>Profile <code>{h(spec.profile)}</code>, seed {spec.seed}"
        + (", quick (CI-sized) run" if doc["quick"] else "")
        + "</p>",
        "<h2>Checks</h2>",
        _html_table(check_header, checks) if checks else "<p>(no checks)</p>",
    ]
    for title, header, rows in tables:
        body += [f"<h2>{h(title)}</h2>", _html_table(header, rows)]
    for plot, png in zip(spec.outputs.plots, pngs, strict=True):
        body += [f"<h2>{h(plot.title)}</h2>", f"<img src='{h(png)}' alt='{h(plot.title)}'>"]
    if spec.assumptions:
        body += ["<h2>Assumptions</h2><ul>"]
        body += [f"<li>{h(a)}</li>" for a in spec.assumptions] + ["</ul>"]
    body += ["<h2>Baseline</h2><p>Before the first step:</p><ul>"]
    body += [f"<li>{h(b)}</li>" for b in baseline] + ["</ul>"]
    if after:
        body += [
            f"<p>After the run, the daemon's settings were put back: {h(', '.join(after))}.</p>"
        ]
    body += ["<h2>Parameters</h2>", f"<pre>{h(json.dumps(doc['parameters'], indent=2))}</pre>"]
    page = (
        "<!DOCTYPE html>\n<html><head><meta charset='utf-8'>"
        f"<title>{h(spec.name)}</title><style>{_CSS}</style></head><body>\n"
        + "\n".join(b for b in body if b)
        + "\n</body></html>\n"
    )
    path = out_dir / "report.html"
    path.write_text(page, encoding="utf-8")
    return path


_CSS = (
    "body{font-family:sans-serif;max-width:60em;margin:2em auto}"
    "table{border-collapse:collapse}td,th{border:1px solid #999;padding:.2em .6em}"
    "td.FAIL{color:#cf222e;font-weight:bold}td.PASS{color:#1a7f37}"
)


def _fmt(value: Any) -> str:
    if value is None:
        return "-"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return format(value, ".5g")
    if isinstance(value, list | dict):
        return json.dumps(value, default=str) if len(json.dumps(value)) < 80 else "(see results)"
    return str(value)


def lookup(results: dict[str, Any], path: str) -> Any:
    """A result by name, or inside a mapping result by a dotted path (``model_db.tao12``);
    None when absent."""
    value: Any = results
    for part in path.split("."):
        if not isinstance(value, dict) or part not in value:
            return None
        value = value[part]
    return value


def _table(spec: TableSpec, results: dict[str, Any]) -> tuple[list[str], list[list[str]]]:
    columns = [lookup(results, name) for name in spec.columns]
    lengths = {len(c) for c in columns if isinstance(c, list)}
    if len(lengths) == 1:
        n = lengths.pop()
        rows = [[_fmt(c[i] if isinstance(c, list) else c) for c in columns] for i in range(n)]
    else:  # scalars, or lists of different lengths: one row
        rows = [[_fmt(c) for c in columns]]
    return list(spec.columns), rows


def _html_table(header: list[str], rows: list[list[str]]) -> str:
    h = html.escape
    head = "".join(f"<th>{h(c)}</th>" for c in header)
    lines = [f"<table><tr>{head}</tr>"]
    for row in rows:
        cells = "".join(
            f"<td class='{c}'>{h(c)}</td>" if c in ("PASS", "FAIL") else f"<td>{h(c)}</td>"
            for c in row
        )
        lines.append(f"<tr>{cells}</tr>")
    return "\n".join([*lines, "</table>"])


def _series(values: Any, labels: Any = None) -> list[tuple[str, list[Any]]]:
    """A result as plot series: a list of numbers is one, a list of lists one per inner list
    (labelled ``[i]``, or `` <label>`` from ``labels``)."""
    if isinstance(values, list) and values and all(isinstance(v, list) for v in values):
        names = labels if isinstance(labels, list) and len(labels) == len(values) else None
        return [(f" {names[i]}" if names else f"[{i}]", v) for i, v in enumerate(values)]
    if isinstance(values, list):
        return [("", values)]
    return [("", [values])]


def _plot(
    plot: PlotSpec, index: int, results: dict[str, Any], checks: list[dict[str, Any]], out: Path
) -> str:
    """One PNG; returns its path relative to the report."""
    import matplotlib

    matplotlib.use("Agg")  # headless: before pyplot is imported
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.0), dpi=100)
    x = lookup(results, plot.x)
    xs = x if isinstance(x, list) else [x]
    labels = lookup(results, plot.labels) if plot.labels else None
    missing = [n for n in (plot.x, *plot.y, *plot.model) if lookup(results, n) is None]
    curves = [(name, "o-") for name in plot.y] + [(name, "--") for name in plot.model]
    single = 0  # colours: one per curve, or one per inner list (shared by data and model)
    for name, style in curves:
        series = _series(lookup(results, name), labels)
        for i, (label, ys) in enumerate(series):
            colour = f"C{(i if len(series) > 1 else single) % 10}"
            if len(ys) != len(xs):
                missing.append(f"{name}{label} (length {len(ys)} vs {len(xs)})")
                continue
            pts = [(a, b) for a, b in zip(xs, ys, strict=True) if _num(a) and _num(b)]
            if pts:
                ax.plot([p[0] for p in pts], [p[1] for p in pts], style, color=colour,
                        label=f"{name}{label}")  # fmt: skip
        single += len(series) == 1
        for check in checks:
            if check["result"] != name:
                continue
            for bound in ("min", "max"):
                if check[bound] is not None:
                    ax.axhline(check[bound], ls="--", color="grey", lw=1)
                    ax.annotate(f"{name} {bound}", (0.01, check[bound]), color="grey",
                                xycoords=("axes fraction", "data"), fontsize=8)  # fmt: skip
            if not check["passed"]:
                bad = [
                    (a, b) for a, b in zip(xs, _flat(check["value"]), strict=False)
                    if _num(b) and not _within(b, check["min"], check["max"])
                ]  # fmt: skip
                if bad:
                    ax.plot([p[0] for p in bad], [p[1] for p in bad], "rx", ms=10, mew=2)
    ax.set_title(plot.title)
    ax.set_xlabel(plot.xlabel or plot.x)
    ax.set_ylabel(plot.ylabel or ", ".join(plot.y))
    if plot.logx:
        ax.set_xscale("log")
    if plot.logy:
        ax.set_yscale("log")
    if missing:
        ax.text(0.5, 0.5, "missing: " + ", ".join(missing), transform=ax.transAxes,
                ha="center", color="red")  # fmt: skip
    if ax.get_legend_handles_labels()[0]:
        ax.legend()
    ax.grid(True, alpha=0.3)
    fig.tight_layout()
    name = f"plot{index + 1}_{plot.x.replace('.', '_')}.png"
    fig.savefig(out / name, format="png")
    plt.close(fig)
    return f"plots/{name}"


def _num(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def _flat(value: Any) -> list[Any]:
    return value if isinstance(value, list) else [value]


def _within(value: float, lo: float | None, hi: float | None) -> bool:
    return (lo is None or value >= lo) and (hi is None or value <= hi)
