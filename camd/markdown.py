"""What the generated documents (docs/protocol.md, sensors.md, profiles.md) share: Markdown
tables, where the docs live, the command line, and write-or-check against the file on disk."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path


def cell(text: str) -> str:
    """Text safe inside a Markdown table cell."""
    return text.replace("|", "\\|").replace("\n", " ")


def table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> list[str]:
    """A Markdown table, one line per row (header and rule first)."""
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(cell(c) for c in row) + " |" for row in rows]
    return lines


def doc_path(name: str) -> Path:
    """docs/<name> of this checkout, or of the working directory when camd is installed."""
    root = Path(__file__).resolve().parents[1]
    if (root / "pyproject.toml").is_file():
        return root / "docs" / name
    return Path("docs") / name


def docgen_parser(command: str, description: str, doc_name: str) -> argparse.ArgumentParser:
    """The arguments every generator takes: ``--check`` and ``--output``."""
    parser = argparse.ArgumentParser(prog=command, description=description)
    parser.add_argument(
        "--check",
        action="store_true",
        help="do not write; exit 1 if the file differs from what would be generated",
    )
    parser.add_argument(
        "--output", type=Path, default=doc_path(doc_name), help="file to write or check"
    )
    return parser


def write_or_check(output: Path, text: str, *, check: bool, command: str) -> int:
    """Write a generated doc, or with ``check`` say whether ``output`` already holds ``text``.

    Returns the exit status: 0 written or up to date, 1 missing or stale (the message says to
    run ``command``).
    """
    if check:
        try:
            current: str | None = output.read_text(encoding="utf-8")
        except FileNotFoundError:
            current = None
        if current != text:
            state = "missing" if current is None else "stale"
            print(f"{output} is {state}: run `{command}` and commit the result", file=sys.stderr)
            return 1
        print(f"{output} is up to date")
        return 0
    output.parent.mkdir(parents=True, exist_ok=True)
    output.write_text(text, encoding="utf-8", newline="\n")
    print(f"wrote {output}")
    return 0
