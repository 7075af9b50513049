"""The live view's static files: shipped in the package, current, and nothing from outside.

The browser tests (tests/test_live_page.py) check what the page does; these check what it is
made of without a browser: the colour maps are matplotlib's tables as the generator writes
them, the vendored uPlot is the version camd.web names (with its licence), and no file of the
page refers to anything but the daemon itself.
"""

from __future__ import annotations

import json
import re

import matplotlib
import numpy as np

from camd import web
from camd.web import colormaps

LIVE_DIR = web.STATIC_DIR / "live"


def test_the_colour_maps_file_is_what_the_generator_writes() -> None:
    assert colormaps.COLORMAPS_JSON.read_text() == colormaps.render(), (
        "camd/web/static/live/colormaps.json is stale: run `python -m camd.web.colormaps`"
    )


def test_each_colour_map_is_matplotlibs_table_in_256_steps() -> None:
    tables = json.loads(colormaps.COLORMAPS_JSON.read_text())
    assert list(tables) == list(colormaps.COLORMAP_NAMES)
    for name, table in tables.items():
        lut = np.asarray(table)
        assert lut.shape == (256, 3) and lut.min() >= 0 and lut.max() <= 255
        reference = matplotlib.colormaps[name](np.linspace(0, 1, 256))[:, :3]
        assert np.abs(lut - reference * 255).max() <= 0.5 + 1e-9, name
    # gray is the identity ramp: level k is (k, k, k)
    assert tables["gray"][0] == [0, 0, 0] and tables["gray"][255] == [255, 255, 255]
    assert tables["gray"][128] == [128, 128, 128]


def test_the_vendored_uplot_is_the_named_version_with_its_licence() -> None:
    folder = web.STATIC_DIR / "vendor" / "uplot"
    assert {p.name for p in folder.iterdir()} == {
        "LICENSE",
        "README.md",
        "uPlot.iife.min.js",
        "uPlot.min.css",
    }
    assert "The MIT License" in (folder / "LICENSE").read_text()
    assert f"uPlot {web.UPLOT_VERSION}" in (folder / "README.md").read_text()


def test_the_page_refers_only_to_the_daemon() -> None:
    """No absolute URL to another host in the page's own files: offline, every file it needs
    comes from the daemon (the browser test also watches the requests it makes)."""
    for path in LIVE_DIR.iterdir():
        if path.suffix in (".html", ".js", ".css"):
            text = path.read_text()
            assert re.findall(r"https?://", text) == [], path.name
    html = web.LIVE_PAGE.read_text()
    for src in re.findall(r'(?:src|href)="([^"]+)"', html):
        assert src.startswith("/static/") or src.startswith("data:"), src
        if src.startswith("/static/"):
            assert (web.STATIC_DIR / src.removeprefix("/static/")).is_file(), src
