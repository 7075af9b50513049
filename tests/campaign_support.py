"""Running a shipped campaign through the CLI and checking its report, for the campaign tests."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import matplotlib.image as mpimg

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def run_shipped(name: str, out: Path) -> dict[str, Any]:
    """``camctl campaign run NAME --sim --quick --json --out OUT`` (a simulated camera of the
    campaign's profile, started for the run): its one JSON document, checked for the issue's
    contract (keys in order, the name, passed, the report's path)."""
    proc = subprocess.run(
        [sys.executable, "-m", "camd.cli.camctl", "campaign", "run", name, "--sim", "--quick",
         "--json", "--out", str(out)],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stdout + proc.stderr[-3000:]
    doc: dict[str, Any] = json.loads(proc.stdout)  # exactly one JSON document
    assert list(doc) == ["campaign", "passed", "results", "report"]
    assert doc["campaign"] == name and doc["passed"] is True
    assert doc["report"] == str(out / "report.html")
    return doc


def report_images(out: Path) -> list[str]:
    """The images report.html shows, each checked to exist, be a PNG and decode to a picture
    (matplotlib's PNG reader), and to be linked from report.md too."""
    html = (out / "report.html").read_text()
    md = (out / "report.md").read_text()
    images = [line.split("src='")[1].split("'")[0] for line in html.splitlines() if "<img" in line]
    for rel in images:
        assert (out / rel).read_bytes()[:8] == PNG_SIGNATURE, rel
        pixels = mpimg.imread(out / rel)
        assert pixels.shape[0] > 100 and pixels.shape[1] > 100, rel
        assert f"({rel})" in md, rel
    return images
