"""README's Layout section and docs/architecture.md against the tree and the layering contracts.

- every package of ``camd/`` (a folder with ``__init__.py``) and every top-level module (but
  ``__init__`` and ``__main__``) is a row of README's Layout table and is named in
  docs/architecture.md; a new package (e.g. ``camd/pipeline``) fails here until both describe it;
- every module of ``camd/daemon`` (but ``__init__``) is named in docs/architecture.md;
- every ``camd/...`` path either document names exists;
- every import-linter contract id of pyproject.toml is named in docs/architecture.md;
- every relative link of docs/architecture.md resolves.
"""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
CAMD = ROOT / "camd"
README = ROOT / "README.md"
ARCHITECTURE = ROOT / "docs" / "architecture.md"

# A ``camd/...`` path as written in prose or a table: not inside a longer path or a dotted name.
CAMD_PATH = re.compile(r"(?<![\w/.-])camd/[\w./-]*\w")
LINK = re.compile(r"\]\(([^)#\s]+)(?:#[^)]*)?\)")


def packages() -> list[str]:
    """``camd/xxx`` for every package directly under camd/."""
    return sorted(
        f"camd/{p.name}" for p in CAMD.iterdir() if p.is_dir() and (p / "__init__.py").is_file()
    )


def top_modules() -> list[str]:
    """``camd/xxx.py`` for every top-level module of camd/ but __init__ and __main__."""
    return sorted(
        f"camd/{p.name}" for p in CAMD.glob("*.py") if p.stem not in ("__init__", "__main__")
    )


def daemon_modules() -> list[str]:
    return sorted(p.name for p in (CAMD / "daemon").glob("*.py") if p.stem != "__init__")


def layout_section() -> str:
    text = README.read_text(encoding="utf-8")
    match = re.search(r"^## Layout\n(.*?)(?=^## )", text, re.S | re.M)
    assert match, "README.md has no '## Layout' section followed by another '## ' section"
    return match.group(1)


def layout_table_names() -> set[str]:
    """The first cell of each row of the Layout section's table, backticks removed."""
    names = set()
    for line in layout_section().splitlines():
        if line.startswith("|") and not line.startswith("|---"):
            names.add(line.split("|")[1].strip().strip("`"))
    return names


def architecture() -> str:
    return ARCHITECTURE.read_text(encoding="utf-8")


def names(text: str, name: str) -> bool:
    """True when ``text`` names ``name`` as a whole path: ``camd/tdi`` is not named by
    ``camd/tdi/engine.py`` or ``camd/tdi_x``; a sentence's full stop after it is fine."""
    return re.search(rf"(?<![\w/.-]){re.escape(name)}(?![\w/-]|\.\w)", text) is not None


@pytest.mark.parametrize("name", packages() + top_modules())
def test_package_or_module_is_in_the_readme_layout_table(name: str) -> None:
    assert name in layout_table_names(), (
        f"{name} is missing from README.md's Layout table: add a row `{name}` | its job"
    )


@pytest.mark.parametrize("name", packages() + top_modules())
def test_package_or_module_is_named_in_architecture_md(name: str) -> None:
    named = names(architecture(), name)
    assert named, (
        f"{name} is not named in docs/architecture.md: add it to the package layers (and, for a "
        "package, say where it stands in the `camd-layers` contract)"
    )


@pytest.mark.parametrize("where", ["README.md's Layout section", "docs/architecture.md"])
def test_every_camd_path_named_exists(where: str) -> None:
    text = layout_section() if where.startswith("README") else architecture()
    named = {m.rstrip(".") for m in CAMD_PATH.findall(text)}
    missing = sorted(n for n in named if not (ROOT / n).exists())
    assert not missing, f"{where} names paths that are not in the tree: {', '.join(missing)}"


@pytest.mark.parametrize("module", daemon_modules())
def test_daemon_module_is_named_in_architecture_md(module: str) -> None:
    text = architecture()
    named = names(text, f"camd/daemon/{module}") or names(text, module)
    assert named, (
        f"camd/daemon/{module} is not named in docs/architecture.md: add a row for it to the "
        "daemon's module table"
    )


def test_every_daemon_module_named_exists() -> None:
    named = set(re.findall(r"(?<![\w/.-])camd/daemon/(\w+\.py)", architecture()))
    missing = sorted(named - set(daemon_modules()))
    assert not missing, "docs/architecture.md names camd/daemon modules that do not exist: " + (
        ", ".join(f"camd/daemon/{m}" for m in missing)
    )


def contract_ids() -> list[str]:
    with (ROOT / "pyproject.toml").open("rb") as f:
        contracts = tomllib.load(f)["tool"]["importlinter"]["contracts"]
    return [str(c["id"]) for c in contracts]


def test_there_are_contracts() -> None:
    assert contract_ids(), "pyproject.toml has no [[tool.importlinter.contracts]]"


@pytest.mark.parametrize("contract", contract_ids())
def test_contract_is_named_in_architecture_md(contract: str) -> None:
    named = re.search(rf"(?<![\w-]){re.escape(contract)}(?![\w-])", architecture()) is not None
    assert named, (
        f"import-linter contract {contract!r} (pyproject.toml) is not named in "
        "docs/architecture.md: add it to the table of contracts with the rule it keeps"
    )


def test_architecture_md_links_resolve() -> None:
    links = {m for m in LINK.findall(architecture()) if "://" not in m}
    missing = sorted(m for m in links if not (ARCHITECTURE.parent / m).exists())
    assert not missing, f"docs/architecture.md links to missing files: {', '.join(missing)}"


def test_architecture_md_is_in_the_readme_documentation_table() -> None:
    text = README.read_text(encoding="utf-8")
    assert "[docs/architecture.md](docs/architecture.md)" in text, (
        "README.md's Documentation table has no row for docs/architecture.md"
    )
