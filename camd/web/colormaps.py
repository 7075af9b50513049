"""The live view's colour maps, as data: ``static/live/colormaps.json``.

The page colours a frame through a 256-entry lookup table per map. The tables are matplotlib's
(perceptually uniform viridis, inferno and cividis, the grey ramp, and turbo for fine level
differences), sampled once here rather than copied by hand into the JavaScript:
``python -m camd.web.colormaps`` rewrites the file, and a test checks that it is current.
"""

from __future__ import annotations

import json
from pathlib import Path

import matplotlib

from camd.web import STATIC_DIR

COLORMAPS_JSON = STATIC_DIR / "live" / "colormaps.json"
COLORMAP_NAMES = ("gray", "viridis", "inferno", "cividis", "turbo")
"""In the order the page offers them; the first is the default."""
LUT_SIZE = 256


def colormap_tables() -> dict[str, list[list[int]]]:
    """Each map as 256 ``[r, g, b]`` triples, 0..255 (index 0 = the low end of the contrast)."""
    tables: dict[str, list[list[int]]] = {}
    for name in COLORMAP_NAMES:
        cmap = matplotlib.colormaps[name].resampled(LUT_SIZE)
        tables[name] = [[round(channel * 255) for channel in cmap(i)[:3]] for i in range(LUT_SIZE)]
    return tables


def render() -> str:
    """The file's text: one line per map, so that a diff shows which map changed."""
    tables = colormap_tables()
    lines = [f"  {json.dumps(name)}: {json.dumps(tables[name])}" for name in COLORMAP_NAMES]
    return "{\n" + ",\n".join(lines) + "\n}\n"


def main() -> None:
    path = Path(COLORMAPS_JSON)
    path.write_text(render())
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
