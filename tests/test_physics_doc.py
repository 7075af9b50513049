"""docs/physics.md against the repository's citations of it.

Code, configuration and documents cite the physics reference as ``docs/physics.md §N``, often with an
equation: ``docs/physics.md §2 eq 4``, ``§2 eqs 5-9, 13``, ``§4 eqs 1, 4-8``, ``§2 eqs 5-9 and 13``,
``§6 eq 3 and eq 8``, ``§5 (TAO12 eq 28, ...)``, ``§6 [YUAN13 eq 9]``, ``§2 eqs 5-9, 13; §6 eq 9``,
``§3 (and §4 eq 6)``, ``§2-§3``, ``§7-8``. Every cited section must exist in docs/physics.md as a
heading ``## N. Title``, and every cited equation must be defined in that section: inside a code
block, a line that ends with a tag ``[PAPER eq K]`` or ``[PAPER eqs K-L]`` (PAPER one of the
short names of the Papers section).

How a citation is read: from ``physics.md`` to the end of the line (or, when ``physics.md`` ends
the line, the next line), up to the first ``:``, ``|``, quote, backtick, sentence end or bracket
that closes one opened before ``physics.md``. In that span ``§N`` (not ``§N.M``, which is a
paper's own section) opens a section, ``eq K`` / ``eqs K-L, M`` / ``eqs K-L and M`` name
equations of the last section opened, and a paper's name followed by its sections (``YE23 §3.1,
§3.3, §4``, ``REN15 §3``) is a reference to the paper, not to physics.md. Equations named before
any section (``docs/physics.md eqs 9-13``) are not checked.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PHYSICS_MD = ROOT / "docs" / "physics.md"
SCANNED_DIRS = ("camd", "firmware_models", "docs", "config", "bench", "tests")
SCANNED_FILES = ("README.md",)
SCANNED_SUFFIXES = (".py", ".md", ".toml", ".yaml")
PAPERS = ("TAO12", "YUAN13", "YE23", "DONG16", "REN15")
_PAPER = "|".join(PAPERS)

# -- docs/physics.md --------------------------------------------------------------------------------

SECTION_HEADING = re.compile(r"^## (\d+)\. \S")
OTHER_HEADING = re.compile(r"^## ")
_NUMBERS = r"\d+(?:\s*[-–]\s*\d+)?(?:(?:\s*,\s*|\s+and\s+)\d+(?:\s*[-–]\s*\d+)?)*"
EQUATION_TAG = re.compile(rf"\[(?:{_PAPER}) eqs? (?P<numbers>{_NUMBERS})\]\s*$")


def expand(numbers: str) -> list[int]:
    """``"5-9, 13"`` -> [5, 6, 7, 8, 9, 13]; ``"1, 4-8"``, ``"5-9 and 13"`` alike."""
    result: list[int] = []
    for item in re.split(r"\s*,\s*|\s+and\s+", numbers.strip()):
        lo, _, hi = re.sub(r"\s*[-–]\s*", "-", item).partition("-")
        result.extend(range(int(lo), int(hi or lo) + 1))
    return result


def read_doc() -> str:
    return PHYSICS_MD.read_text(encoding="utf-8")


def doc_sections(text: str) -> dict[str, list[str]]:
    """The lines of each ``## `` section by heading text ("1", "2", ... or e.g. "Papers")."""
    sections: dict[str, list[str]] = {}
    current: list[str] | None = None
    for line in text.splitlines():
        numbered = SECTION_HEADING.match(line)
        if numbered or OTHER_HEADING.match(line):
            key = numbered.group(1) if numbered else line[3:].strip()
            assert key not in sections, f"docs/physics.md: section {key!r} appears twice"
            current = sections[key] = []
        elif current is not None:
            current.append(line)
    return sections


def doc_equations(text: str) -> dict[int, set[int]]:
    """Equation numbers defined per numbered section (tags at line ends inside code blocks)."""
    equations: dict[int, set[int]] = {}
    for key, lines in doc_sections(text).items():
        if not key.isdigit():
            continue
        found = equations.setdefault(int(key), set())
        in_code = False
        for line in lines:
            if line.lstrip().startswith("```"):
                in_code = not in_code
            elif in_code and (tag := EQUATION_TAG.search(line)):
                found.update(expand(tag.group("numbers")))
    return equations


# -- citations in the repository --------------------------------------------------------------------

TOKEN = re.compile(
    rf"(?P<paper>\b(?:{_PAPER})\b(?P<paper_close>\])?(?:\s*,?\s*§\d+(?:\.\d+)*(?!\.\d|\d))*)"
    r"|(?P<section>§(?P<first>\d+)(?!\.\d|\d)(?:\s*[-–]\s*§?(?P<last>\d+)(?!\.\d|\d))?)"
    rf"|(?P<equation>\beqs?\s+(?P<numbers>{_NUMBERS})(?!\d|\.\d))"
    r"|(?P<open>[(\[{])"
    r"|(?P<close>[)\]}])"
    r"|(?P<stop>[:|`\"']|\.(?=\s|$))"
)
MENTION = re.compile(r"physics\.md")
CONTINUATION_PREFIX = re.compile(r"^[\s#*>/-]*")


@dataclass(frozen=True, slots=True)
class Citation:
    where: str  # path:line
    text: str  # the citation as written, from "physics.md" to where it ends
    section: int
    equations: tuple[int, ...]


def parse_citation(span: str) -> list[tuple[int, tuple[int, ...]]]:
    """The (section, equations) pairs of one span of text that follows ``physics.md``."""
    cited: list[tuple[int, list[int]]] = []
    depth = 0
    for token in TOKEN.finditer(span):
        kind = token.lastgroup
        if token.group("paper") is not None:
            if token.group("paper_close"):
                depth -= 1
                if depth < 0:
                    break
        elif token.group("section") is not None:
            first = int(token.group("first"))
            last = int(token.group("last") or first)
            cited.extend((n, []) for n in range(first, max(first, last) + 1))
        elif token.group("equation") is not None:
            if cited:
                cited[-1][1].extend(expand(token.group("numbers")))
        elif kind == "open":
            depth += 1
        elif kind == "close":
            depth -= 1
            if depth < 0:
                break
        else:  # stop
            break
    return [(section, tuple(eqs)) for section, eqs in cited]


def citation_span(lines: list[str], index: int, start: int) -> str:
    """The text after ``physics.md`` at ``lines[index][start:]`` (or on the next line)."""
    span = lines[index][start:]
    if not span.strip() and index + 1 < len(lines):
        span = " " + CONTINUATION_PREFIX.sub("", lines[index + 1])
    return span


def scanned_files() -> list[Path]:
    own = Path(__file__).resolve()
    files = [ROOT / name for name in SCANNED_FILES]
    for folder in SCANNED_DIRS:
        for path in sorted((ROOT / folder).rglob("*")):
            if (
                path.suffix in SCANNED_SUFFIXES
                and path.is_file()
                and path.resolve() != own
                and not any(part.startswith(".") for part in path.relative_to(ROOT).parts)
            ):
                files.append(path)
    return files


def find_citations() -> list[Citation]:
    citations: list[Citation] = []
    for path in scanned_files():
        lines = path.read_text(encoding="utf-8", errors="replace").splitlines()
        for index, line in enumerate(lines):
            for mention in MENTION.finditer(line):
                span = citation_span(lines, index, mention.end())
                where = f"{path.relative_to(ROOT)}:{index + 1}"
                text = ("physics.md" + span).strip()[:100]
                for section, equations in parse_citation(span):
                    citations.append(Citation(where, text, section, equations))
    return citations


# -- tests ------------------------------------------------------------------------------------------


def test_sections_are_numbered_from_one_in_order() -> None:
    numbers = [int(m.group(1)) for m in map(SECTION_HEADING.match, read_doc().splitlines()) if m]
    assert numbers == list(range(1, len(numbers) + 1)), numbers
    assert len(numbers) >= 8, f"docs/physics.md needs sections 1..8, has {numbers}"


def test_every_section_names_its_implementation() -> None:
    sections = doc_sections(read_doc())
    missing = [
        key
        for key in sections
        if key.isdigit() and not any("**In camd:**" in line for line in sections[key])
    ]
    assert not missing, f"sections without an 'In camd:' line: {missing}"


def test_the_parser_reads_the_citation_shapes_in_use() -> None:
    assert parse_citation(" §2 eqs 5-9, 13; §6 eq 9) for") == [(2, (5, 6, 7, 8, 9, 13)), (6, (9,))]
    assert parse_citation(" §4 [YE23 §3.1, §3.3, §4, eqs 1, 4-8]. The") == [(4, (1, 4, 5, 6, 7, 8))]
    assert parse_citation(" §3 (and §4 eq 6) [YE23]: a") == [(3, ()), (4, (6,))]
    assert parse_citation(" §6 eq 3 and eq 8 [YUAN13] as") == [(6, (3, 8))]
    assert parse_citation(" §2 eqs 5-9 and 13 [TAO12] give") == [(2, (5, 6, 7, 8, 9, 13))]
    assert parse_citation(" §1 (TAO12 eq 11): line k") == [(1, (11,))]
    assert parse_citation(" §5, TAO12 §5.1") == [(5, ())]
    assert parse_citation(" §7, REN15 §3; docs/imc.md") == [(7, ())]
    assert parse_citation(" §6, [YUAN13] §3.2-3.4") == [(6, ())]
    assert parse_citation(" §7-8: 9 um") == [(7, ()), (8, ())]
    assert parse_citation(" §2-§3 (pure") == [(2, ()), (3, ())]
    assert parse_citation(" §4), the eq 8 error budget") == [(4, ())]
    assert parse_citation(" §2 eq 4): 3.5 us blanking") == [(2, (4,))]
    assert parse_citation(" eqs 9-13 (camd") == []


def test_every_citation_names_a_section_and_equation_that_exist() -> None:
    equations = doc_equations(read_doc())
    citations = find_citations()
    # A regular expression that silently stopped matching would pass everything.
    assert len(citations) > 300, f"only {len(citations)} citations found: is the scan broken?"
    assert sum(len(c.equations) for c in citations) > 100
    bad: list[str] = []
    for c in citations:
        if c.section not in equations:
            bad.append(f"{c.where}: §{c.section} does not exist: {c.text}")
            continue
        missing = sorted(set(c.equations) - equations[c.section])
        if missing:
            eqs = ", ".join(map(str, missing))
            bad.append(f"{c.where}: §{c.section} defines no eq {eqs}: {c.text}")
    assert not bad, "citations of docs/physics.md that it does not have:\n" + "\n".join(bad)


def test_papers_section_gives_journal_and_year_of_every_paper() -> None:
    lines = doc_sections(read_doc()).get("Papers")
    assert lines is not None, "docs/physics.md has no '## Papers' section"
    rows = [
        [cell.strip() for cell in line.strip().strip("|").split("|")]
        for line in lines
        if line.startswith("|") and not re.match(r"^\|[-| :]+\|$", line.strip())
    ]
    header = [cell.lower() for cell in rows[0]]
    journal, year = header.index("journal"), header.index("year")
    by_name = {row[0].strip("*"): row for row in rows[1:]}
    for paper in PAPERS:
        assert paper in by_name, f"the Papers table has no row for {paper}"
        row = by_name[paper]
        assert re.fullmatch(r"(19|20)\d\d", row[year]), f"{paper}: year {row[year]!r}"
        assert re.search(r"[A-Za-z]{4}", row[journal]), f"{paper}: journal {row[journal]!r}"


@pytest.mark.parametrize("word", ["shared/", "spec/"])
def test_the_document_stands_alone(word: str) -> None:
    assert word not in read_doc().lower()
