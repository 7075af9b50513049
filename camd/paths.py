"""Where camd finds its shipped data files (the repository's config/ directory).

An installed wheel carries config/ as ``camd/_data/config``; a source checkout (editable install)
uses the repository's own ``config/`` so that edits there take effect without reinstalling.
"""

from __future__ import annotations

from pathlib import Path

_PACKAGE_DIR = Path(__file__).resolve().parent


def config_dir() -> Path:
    """Return the directory holding the shipped config files (dictionary, profiles, defaults)."""
    packaged = _PACKAGE_DIR / "_data" / "config"
    if packaged.is_dir():
        return packaged
    source = _PACKAGE_DIR.parent / "config"
    if source.is_dir():
        return source
    raise FileNotFoundError(
        f"camd's config directory is missing: looked in {packaged} and {source}; "
        "reinstall camd (pip install .) or run from a source checkout"
    )
